//! Hostile input, as an attacker or an unlucky user would hand it over: files that try to read
//! other files, inputs that never end or grow without bound, and the small lies of text
//! formats. Each case must end in a typed error naming the file and place, quickly, with
//! memory bounded by a limit (asserted on the limit, not on the machine).

use std::io::Write;
use std::path::{Path, PathBuf};

use vds_import::{ImportError, ImportOptions, Problem, load_file};

/// A fresh folder under the system's temporary directory, removed when dropped.
struct TempDir(PathBuf);

impl TempDir {
    fn new(name: &str) -> TempDir {
        let dir = std::env::temp_dir().join(format!("vds-hostile-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        TempDir(dir)
    }
    fn join(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// One triangle's buffer: three float positions, then three u32 indices (48 bytes).
fn triangle_buffer() -> Vec<u8> {
    let mut bytes = Vec::new();
    for p in [[0f32, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]] {
        for c in p {
            bytes.extend(c.to_le_bytes());
        }
    }
    for i in 0u32..3 {
        bytes.extend(i.to_le_bytes());
    }
    bytes
}

/// A glTF document whose one buffer (48 bytes: a triangle) is at `uri`, drawn by `nodes`
/// (JSON for the node array; node 0 is the scene's root).
fn gltf_document(uri: &str, nodes: &str) -> String {
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
        "nodes":{nodes},
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1}}]}}],
        "buffers":[{{"byteLength":48,"uri":"{uri}"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":36}},
                       {{"buffer":0,"byteOffset":36,"byteLength":12}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}},
                     {{"bufferView":1,"componentType":5125,"count":3,"type":"SCALAR"}}]}}"#
    )
}

const ONE_MESH_NODE: &str = r#"[{"name":"part","mesh":0}]"#;

/// Writes `model.gltf` into `dir` with its buffer at `uri`, and loads it.
fn load_gltf_with_uri(
    dir: &TempDir,
    uri: &str,
    options: &ImportOptions,
) -> Result<vds_import::Scene, ImportError> {
    let model = dir.join("model.gltf");
    std::fs::write(&model, gltf_document(uri, ONE_MESH_NODE)).unwrap();
    load_file(&model, options)
}

fn assert_refused_uri(result: Result<vds_import::Scene, ImportError>, reason: &str) {
    let error = result.unwrap_err();
    let message = error.to_string();
    assert!(
        matches!(error.problem(), Some(Problem::RefusedUri { reason: r, .. }) if r.contains(reason)),
        "{message}"
    );
    assert!(
        message.contains("model.gltf") && message.contains("buffer 0"),
        "{message}"
    );
}

/// A file outside the model's folder, as `/etc/passwd` would be.
fn secret_outside(dir: &TempDir) -> PathBuf {
    let secret = dir.join("secret.bin");
    std::fs::write(&secret, triangle_buffer()).unwrap();
    std::fs::create_dir_all(dir.join("model")).unwrap();
    secret
}

// ---------- glTF URIs ----------

#[test]
fn gltf_buffer_uri_that_is_an_absolute_path_is_refused() {
    let dir = TempDir::new("absolute");
    let secret = secret_outside(&dir);
    let result = load_gltf_with_uri(&dir, secret.to_str().unwrap(), &ImportOptions::default());
    assert_refused_uri(result, "absolute");
}

#[test]
fn gltf_buffer_uri_that_climbs_out_of_the_folder_is_refused() {
    let dir = TempDir::new("climb");
    secret_outside(&dir);
    let inner = TempDir(dir.join("model"));
    for uri in ["../secret.bin", "sub/../../secret.bin", "%2E%2E/secret.bin"] {
        assert_refused_uri(
            load_gltf_with_uri(&inner, uri, &ImportOptions::default()),
            "..",
        );
    }
    std::mem::forget(inner); // `dir` removes it.
}

#[cfg(unix)]
#[test]
fn gltf_buffer_uri_through_a_link_out_of_the_folder_is_refused() {
    let dir = TempDir::new("link-out");
    let secret = secret_outside(&dir);
    let inner = TempDir(dir.join("model"));
    std::os::unix::fs::symlink(&secret, inner.join("innocent.bin")).unwrap();
    assert_refused_uri(
        load_gltf_with_uri(&inner, "innocent.bin", &ImportOptions::default()),
        "outside",
    );
    std::mem::forget(inner);
}

#[test]
fn gltf_buffer_uri_with_a_scheme_is_refused() {
    let dir = TempDir::new("scheme");
    for uri in ["http://127.0.0.1/x.bin", "file:///etc/passwd"] {
        assert_refused_uri(
            load_gltf_with_uri(&dir, uri, &ImportOptions::default()),
            "scheme",
        );
    }
}

#[test]
fn gltf_buffer_uri_inside_the_folder_is_read_percent_decoded() {
    let dir = TempDir::new("inside");
    std::fs::create_dir_all(dir.join("buffers")).unwrap();
    std::fs::write(dir.join("buffers/tri angle.bin"), triangle_buffer()).unwrap();
    let scene =
        load_gltf_with_uri(&dir, "buffers/tri%20angle.bin", &ImportOptions::default()).unwrap();
    assert_eq!(scene.triangles.len(), 1);
}

#[test]
fn gltf_external_uris_are_read_when_allowed() {
    let dir = TempDir::new("allowed");
    let secret = secret_outside(&dir);
    let inner = TempDir(dir.join("model"));
    let allow = ImportOptions {
        allow_external_uris: true,
        ..Default::default()
    };
    for uri in [secret.to_str().unwrap(), "../secret.bin"] {
        let scene = load_gltf_with_uri(&inner, uri, &allow).unwrap();
        assert_eq!(scene.triangles.len(), 1);
    }
    std::mem::forget(inner);
}

// ---------- unbounded reads ----------

#[cfg(unix)]
#[test]
fn gltf_buffer_naming_a_device_is_refused_even_when_external_uris_are_allowed() {
    let dir = TempDir::new("device-buffer");
    let allow = ImportOptions {
        allow_external_uris: true,
        ..Default::default()
    };
    let error = load_gltf_with_uri(&dir, "/dev/zero", &allow).unwrap_err();
    let message = error.to_string();
    assert!(message.contains("not a regular file"), "{message}");
}

#[test]
fn gltf_buffer_is_read_no_further_than_its_byte_length() {
    // The buffer file is 1 MiB; byteLength says 48. Only 48 bytes are read, so a larger file
    // (or one that grows while read) cannot make the reader allocate more.
    let dir = TempDir::new("byte-length");
    let mut bytes = triangle_buffer();
    bytes.resize(1 << 20, 0xAB);
    std::fs::write(dir.join("big.bin"), &bytes).unwrap();
    let scene = load_gltf_with_uri(&dir, "big.bin", &ImportOptions::default()).unwrap();
    assert_eq!(scene.triangles.len(), 1);
    // And a file shorter than byteLength is a truncation, named as such.
    std::fs::write(dir.join("short.bin"), &bytes[..40]).unwrap();
    let error = load_gltf_with_uri(&dir, "short.bin", &ImportOptions::default()).unwrap_err();
    assert!(
        matches!(
            error.problem(),
            Some(Problem::Truncated {
                needed: 48,
                available: 40
            })
        ),
        "{error}"
    );
}

#[cfg(unix)]
fn make_fifo(path: &Path) {
    let status = std::process::Command::new("mkfifo")
        .arg(path)
        .status()
        .expect("mkfifo runs");
    assert!(status.success());
}

#[cfg(unix)]
#[test]
fn fifo_input_is_refused_without_blocking() {
    let dir = TempDir::new("fifo");
    let fifo = dir.join("pipe.obj");
    make_fifo(&fifo);
    let error = load_file(&fifo, &ImportOptions::default()).unwrap_err();
    assert!(
        matches!(error, ImportError::NotAFile { kind: "a FIFO", .. }),
        "{error}"
    );
    assert!(error.to_string().contains("pipe.obj"), "{error}");
}

#[cfg(unix)]
#[test]
fn gltf_buffer_naming_a_fifo_is_refused_without_blocking() {
    let dir = TempDir::new("fifo-buffer");
    make_fifo(&dir.join("pipe.bin"));
    let error = load_gltf_with_uri(&dir, "pipe.bin", &ImportOptions::default()).unwrap_err();
    assert!(error.to_string().contains("FIFO"), "{error}");
}

#[cfg(unix)]
#[test]
fn link_to_a_device_is_refused() {
    let dir = TempDir::new("link-device");
    let link = dir.join("x.obj");
    std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
    let error = load_file(&link, &ImportOptions::default()).unwrap_err();
    assert!(
        matches!(
            error,
            ImportError::NotAFile {
                kind: "a character device",
                ..
            }
        ),
        "{error}"
    );
}

#[test]
fn directory_input_is_refused() {
    let dir = TempDir::new("directory");
    let folder = dir.join("looks-like.obj");
    std::fs::create_dir_all(&folder).unwrap();
    let error = load_file(&folder, &ImportOptions::default()).unwrap_err();
    assert!(matches!(error, ImportError::NotAFile { .. }), "{error}");
}

// ---------- decompression ----------

/// Writes `block` `times` times over as one gzip file (a bomb: a few KB for many MB).
fn write_gzip_of_repeats(path: &Path, block: &[u8], times: usize) {
    let mut encoder = flate2::write::GzEncoder::new(
        std::fs::File::create(path).unwrap(),
        flate2::Compression::fast(),
    );
    for _ in 0..times {
        encoder.write_all(block).unwrap();
    }
    encoder.finish().unwrap();
}

#[test]
fn gzip_bomb_is_refused_at_the_decompression_limit() {
    // 64 MiB of comment lines compress to about 64 KB; an OBJ file is streamed, so it never
    // sits in memory whole, and the limit of 4 MiB stops the stream after 4 MiB + 1 byte.
    let dir = TempDir::new("gzip-bomb");
    let path = dir.join("bomb.obj.gz");
    write_gzip_of_repeats(&path, &b"#\n".repeat(1 << 19), 64);
    let options = ImportOptions {
        max_decompressed_bytes: 4 << 20,
        ..Default::default()
    };
    let error = load_file(&path, &options).unwrap_err();
    let message = error.to_string();
    assert!(
        matches!(
            error.problem(),
            Some(Problem::LimitExceeded { amount, limit, .. }) if *amount == *limit + 1 && *limit == 4 << 20
        ),
        "{message}"
    );
    assert!(message.contains("bomb.obj.gz") && message.contains("--max-decompressed-bytes"));
}

#[test]
fn gzip_ply_bomb_is_refused_at_the_decompression_limit() {
    // Other formats are decompressed into a temporary file, within the same limit.
    let dir = TempDir::new("gzip-ply-bomb");
    let path = dir.join("bomb.ply.gz");
    write_gzip_of_repeats(&path, &[0; 1 << 20], 64);
    let options = ImportOptions {
        max_decompressed_bytes: 4 << 20,
        ..Default::default()
    };
    let error = load_file(&path, &options).unwrap_err();
    assert!(
        matches!(
            error.problem(),
            Some(Problem::LimitExceeded { amount, limit, .. }) if *amount == *limit + 1
        ),
        "{error}"
    );
}

#[test]
fn gzip_obj_without_line_breaks_is_refused_at_the_line_limit() {
    // 64 MiB of zeros: streamed, the reader holds at most one line (1 MiB) and a chunk.
    let dir = TempDir::new("gzip-zeros");
    let path = dir.join("zeros.obj.gz");
    write_gzip_of_repeats(&path, &[0; 1 << 20], 64);
    let error = load_file(&path, &ImportOptions::default()).unwrap_err();
    assert!(
        matches!(
            error,
            ImportError::Malformed {
                location: vds_import::Location::Line(1),
                problem: Problem::LineTooLong { .. },
                ..
            }
        ),
        "{error}"
    );
}

#[test]
fn gzip_input_under_the_limit_reads() {
    let dir = TempDir::new("gzip-ok");
    let path = dir.join("tri.obj.gz");
    let mut encoder = flate2::write::GzEncoder::new(
        std::fs::File::create(&path).unwrap(),
        flate2::Compression::default(),
    );
    encoder
        .write_all(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
        .unwrap();
    encoder.finish().unwrap();
    let options = ImportOptions {
        max_decompressed_bytes: 64,
        ..Default::default()
    };
    assert_eq!(load_file(&path, &options).unwrap().triangles.len(), 1);
}

// ---------- instancing ----------

/// 40 nested nodes, each listing the next twice: 2⁴⁰ instances of the last one's triangle.
fn doubling_chain(levels: usize) -> String {
    let mut nodes: Vec<String> = (0..levels - 1)
        .map(|i| format!(r#"{{"name":"level{i}","children":[{0},{0}]}}"#, i + 1))
        .collect();
    nodes.push(r#"{"name":"leaf","mesh":0}"#.into());
    format!("[{}]", nodes.join(","))
}

fn write_gltf_nodes(dir: &TempDir, nodes: &str) -> PathBuf {
    let data = base64::Engine::encode(
        &base64::engine::general_purpose::STANDARD,
        triangle_buffer(),
    );
    let model = dir.join("instances.gltf");
    let uri = format!("data:application/octet-stream;base64,{data}");
    std::fs::write(&model, gltf_document(&uri, nodes)).unwrap();
    model
}

#[test]
fn gltf_instance_tree_of_two_to_the_forty_is_refused_naming_the_node() {
    let dir = TempDir::new("doubling");
    let model = write_gltf_nodes(&dir, &doubling_chain(41));
    let start = std::time::Instant::now();
    let error = load_file(&model, &ImportOptions::default()).unwrap_err();
    let message = error.to_string();
    // 2^28 is the default limit: level 12 expands to 2^28 leaf instances, level 11 to 2^29.
    assert!(
        matches!(error.problem(), Some(Problem::LimitExceeded { amount, .. }) if *amount == 1 << 29),
        "{message}"
    );
    assert!(
        message.contains("node 11") && message.contains("level11"),
        "{message}"
    );
    assert!(start.elapsed().as_secs() < 5, "counted, not expanded");
}

#[test]
fn gltf_many_instances_of_one_mesh_are_refused_above_the_limit() {
    let dir = TempDir::new("wide");
    let children: Vec<String> = (1..=20_000).map(|i| i.to_string()).collect();
    let mut nodes = vec![format!(
        r#"{{"name":"assembly","children":[{}]}}"#,
        children.join(",")
    )];
    nodes.extend((0..20_000).map(|_| r#"{"mesh":0}"#.to_string()));
    let model = write_gltf_nodes(&dir, &format!("[{}]", nodes.join(",")));
    let options = ImportOptions {
        max_triangles: 10_000,
        ..Default::default()
    };
    let error = load_file(&model, &options).unwrap_err();
    let message = error.to_string();
    assert!(
        matches!(
            error.problem(),
            Some(Problem::LimitExceeded {
                amount: 20_000,
                limit: 10_000,
                ..
            })
        ),
        "{message}"
    );
    assert!(
        message.contains("'assembly'") && message.contains("--max-triangles"),
        "{message}"
    );
    // The same file within a limit that holds it reads every instance: a part each, under
    // the 'assembly' part.
    let options = ImportOptions {
        max_triangles: 20_000,
        ..Default::default()
    };
    assert_eq!(
        load_file(&model, &options).unwrap().part_names.len(),
        20_001
    );
}

#[test]
fn triangle_limit_counts_every_format() {
    let dir = TempDir::new("limit-obj");
    let path = dir.join("two.obj");
    std::fs::write(
        &path,
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n",
    )
    .unwrap();
    let options = ImportOptions {
        max_triangles: 1,
        ..Default::default()
    };
    let error = load_file(&path, &options).unwrap_err();
    assert!(
        matches!(
            error.problem(),
            Some(Problem::LimitExceeded {
                amount: 2,
                limit: 1,
                ..
            })
        ),
        "{error}"
    );
}

// ---------- text details ----------

fn load_obj_text(name: &str, text: &[u8]) -> Result<vds_import::Scene, ImportError> {
    let dir = TempDir::new(name);
    let path = dir.join("model.obj");
    std::fs::write(&path, text).unwrap();
    load_file(&path, &ImportOptions::default())
}

#[test]
fn obj_line_longer_than_the_limit_is_refused_with_its_line() {
    let mut text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf".to_vec();
    while text.len() < 2 << 20 {
        text.extend_from_slice(b" 1 2 3");
    }
    text.push(b'\n');
    let error = load_obj_text("long-line", &text).unwrap_err();
    assert!(
        matches!(
            error,
            ImportError::Malformed {
                location: vds_import::Location::Line(4),
                problem: Problem::LineTooLong { .. },
                ..
            }
        ),
        "{error}"
    );
}

#[test]
fn obj_polylines_are_ignored_not_triangulated() {
    let text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nl 1 2 3\n  l 2 3 4 1\nf 1 2 3\n";
    let scene = load_obj_text("polyline", text).unwrap();
    assert_eq!(scene.triangles.len(), 1);
    // A file of nothing but polylines has no triangle, and says so.
    let error =
        load_obj_text("only-polylines", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2 3\n").unwrap_err();
    assert!(matches!(error, ImportError::NoTriangles { .. }), "{error}");
}

#[test]
fn obj_with_a_byte_order_mark_reads() {
    let scene = load_obj_text("bom", b"\xEF\xBB\xBFv 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    assert_eq!(scene.triangles.len(), 1);
}

#[test]
fn obj_with_cr_only_line_endings_reads_and_counts_lines() {
    let scene = load_obj_text("cr", b"v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r").unwrap();
    assert_eq!(scene.triangles.len(), 1);
    let error = load_obj_text("cr-bad", b"v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 9\r").unwrap_err();
    assert!(
        matches!(
            error,
            ImportError::Malformed {
                location: vds_import::Location::Line(4),
                ..
            }
        ),
        "{error}"
    );
}

// ---------- coordinates ----------

#[test]
fn coordinates_beyond_the_limit_are_refused_with_their_line() {
    let error = load_obj_text("huge", b"v 0 0 0\nv 3e38 0 0\nv 0 1 0\nf 1 2 3\n").unwrap_err();
    assert!(
        matches!(
            error,
            ImportError::Malformed {
                location: vds_import::Location::Line(2),
                problem: Problem::CoordinateOutOfRange { .. },
                ..
            }
        ),
        "{error}"
    );
}

#[test]
fn gltf_transform_that_scales_past_the_limit_is_refused() {
    let dir = TempDir::new("huge-transform");
    let model = write_gltf_nodes(&dir, r#"[{"name":"part","mesh":0,"scale":[1e30,1,1]}]"#);
    let error = load_file(&model, &ImportOptions::default()).unwrap_err();
    assert!(
        matches!(error.problem(), Some(Problem::CoordinateOutOfRange { .. })),
        "{error}"
    );
}

// ---------- empty input ----------

#[test]
fn file_without_triangles_is_named() {
    let error = load_obj_text("empty", b"# nothing here\nv 0 0 0\n").unwrap_err();
    assert!(matches!(error, ImportError::NoTriangles { .. }), "{error}");
    assert!(error.to_string().contains("model.obj"), "{error}");
}

#[test]
fn scene_whose_triangles_are_all_degenerate_names_its_inputs() {
    let error = load_obj_text("degenerate", b"v 0 0 0\nv 0 0 0\nv 1 0 0\nf 1 2 3\n").unwrap_err();
    assert!(
        matches!(error, ImportError::NoUsableTriangles { .. }),
        "{error}"
    );
    assert!(error.to_string().contains("model.obj"), "{error}");
}

#[test]
fn gltf_missing_accessor_is_an_error_not_a_panic() {
    // gltf-json's validator would index past the accessors; the reader checks first, so no
    // panic (and no panic message on stderr) ever happens: a panic would fail this test.
    let dir = TempDir::new("missing-accessor");
    let model = dir.join("model.gltf");
    let text = gltf_document("x.bin", ONE_MESH_NODE).replace(r#""POSITION":0"#, r#""POSITION":7"#);
    std::fs::write(&model, text).unwrap();
    let error = load_file(&model, &ImportOptions::default()).unwrap_err();
    assert!(error.to_string().contains("accessor"), "{error}");
}

#[cfg(unix)]
#[test]
fn gltf_buffers_naming_one_file_share_one_read() {
    // 200 buffers naming one 1 MiB file (directly, by a symbolic link and by a hard link)
    // would be 200 MiB read separately; they share one read (the unit test
    // `buffers_naming_one_file_share_its_bytes` checks the sharing), and each still sees
    // only its own byteLength.
    let dir = TempDir::new("shared-buffer");
    let mut bytes = triangle_buffer();
    bytes.resize(1 << 20, 0);
    std::fs::write(dir.join("data.bin"), &bytes).unwrap();
    std::os::unix::fs::symlink("data.bin", dir.join("soft.bin")).unwrap();
    std::fs::hard_link(dir.join("data.bin"), dir.join("hard.bin")).unwrap();
    let names = ["data.bin", "soft.bin", "hard.bin"];
    let buffers: Vec<String> = (0..200)
        .map(|i| format!(r#"{{"byteLength":{},"uri":"{}"}}"#, 48 + i, names[i % 3]))
        .collect();
    let text = gltf_document("data.bin", ONE_MESH_NODE).replace(
        r#""buffers":[{"byteLength":48,"uri":"data.bin"}]"#,
        &format!(r#""buffers":[{}]"#, buffers.join(",")),
    );
    let model = dir.join("model.gltf");
    std::fs::write(&model, text).unwrap();
    let scene = load_file(&model, &ImportOptions::default()).unwrap();
    assert_eq!(scene.triangles.len(), 1);
}

#[test]
fn obj_texture_and_normal_indices_are_not_read_even_out_of_range() {
    // tobj 4.0 panics (with overflow checks) on a relative texture or normal index before
    // the first one; the tree needs positions only, so corners are read as their vertex.
    let text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\nf 1/-5 2/1/1 3//-9\n";
    let scene = load_obj_text("texcoords", text).unwrap();
    assert_eq!(scene.triangles.len(), 1);
    // A bad vertex index in such a face is still named with its line.
    let text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nf 1/1 2/1 9/1\n";
    let error = load_obj_text("texcoords-bad", text).unwrap_err();
    assert!(
        matches!(
            error,
            ImportError::Malformed {
                location: vds_import::Location::Line(5),
                problem: Problem::IndexOutOfRange { index: 9, .. },
                ..
            }
        ),
        "{error}"
    );
}

#[test]
fn obj_statements_split_on_unicode_whitespace_as_tobj_does() {
    // A vertical tab separates words for tobj: the polyline is still a polyline, and the
    // face's texture indices are still not read.
    let text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nl\x0B1 2 3\nf\x0B1/-5 2/-5 3/-5\n";
    let scene = load_obj_text("unicode-space", text).unwrap();
    assert_eq!(scene.triangles.len(), 1);
}

#[test]
fn obj_with_cr_endings_and_a_later_cr_lf_counts_lines_once() {
    let text = b"v 0 0 0\rv 1 0 0\r\nv 0 1 0\rf 1 2 9\r";
    let error = load_obj_text("cr-crlf", text).unwrap_err();
    assert!(
        matches!(
            error,
            ImportError::Malformed {
                location: vds_import::Location::Line(4),
                ..
            }
        ),
        "{error}"
    );
}

#[test]
fn glb_whose_header_length_is_below_its_header_is_refused() {
    let dir = TempDir::new("glb-header");
    let path = dir.join("short.glb");
    let mut bytes = b"glTF".to_vec();
    bytes.extend(2u32.to_le_bytes());
    bytes.extend(0u32.to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    let error = load_file(&path, &ImportOptions::default()).unwrap_err();
    assert!(
        error
            .to_string()
            .contains("shorter than the 12-byte header"),
        "{error}"
    );
}

#[test]
fn gltf_external_buffers_count_against_the_memory_limit() {
    let dir = TempDir::new("buffer-limit");
    std::fs::write(dir.join("data.bin"), triangle_buffer()).unwrap();
    let options = ImportOptions {
        max_decompressed_bytes: 40,
        ..Default::default()
    };
    let error = load_gltf_with_uri(&dir, "data.bin", &options).unwrap_err();
    assert!(
        matches!(
            error.problem(),
            Some(Problem::LimitExceeded {
                amount: 48,
                limit: 40,
                ..
            })
        ),
        "{error}"
    );
}

#[test]
fn gltf_part_names_are_not_multiplied_by_empty_instances() {
    // A mesh without triangles instanced 20,000 times leaves no part name per instance.
    let dir = TempDir::new("empty-instances");
    let children: Vec<String> = (2..20_002).map(|i| i.to_string()).collect();
    let nodes = format!(
        r#"[{{"name":"root","children":[1,{}]}},{{"name":"part","mesh":0}}{}]"#,
        children.join(","),
        r#",{"mesh":1}"#.repeat(20_000)
    );
    let model = write_gltf_nodes(&dir, &nodes);
    // Put an empty mesh first: the triangle mesh becomes mesh 1, "part" is pointed at it,
    // and the 20,000 instances (replaced in pairs) at the empty mesh 0.
    let text = std::fs::read_to_string(&model)
        .unwrap()
        .replace(r#""meshes":["#, r#""meshes":[{"primitives":[]},"#)
        .replace(r#""mesh":0}"#, r#""mesh":1}"#)
        .replace(r#"{"mesh":1},{"mesh":1}"#, r#"{"mesh":0},{"mesh":0}"#);
    std::fs::write(&model, text).unwrap();
    let scene = load_file(&model, &ImportOptions::default()).unwrap();
    assert_eq!(scene.triangles.len(), 1);
    // The root is a part too (the assembly above "part"), once, not once per instance.
    assert_eq!(scene.part_names, vec!["root", "part"]);
}
