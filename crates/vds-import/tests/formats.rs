//! Every format reads, every malformed case from the import issue yields its typed error,
//! and mutated files never panic a reader.

use std::path::PathBuf;

use base64::Engine as _;
use proptest::prelude::*;
use vds_import::{Format, Location, MeshSoup, Problem, Weld, read_bytes, weld};

fn read(bytes: &[u8], format: Format) -> Result<MeshSoup, vds_import::FormatError> {
    let mut soup = MeshSoup::default();
    read_bytes(bytes, format, "test", &mut soup).map(|()| soup)
}

fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name)
}

// ---------- OBJ ----------

const TWO_OBJECTS: &str =
    "o plate\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\no bolt\nv 0 0 1\nf 1 2 5\n";

#[test]
fn obj_objects_become_named_parts_and_quads_are_triangulated() {
    let soup = read(TWO_OBJECTS.as_bytes(), Format::Obj).unwrap();
    assert_eq!(soup.part_names, vec!["plate", "bolt"]);
    assert_eq!(soup.triangles.len(), 3);
    assert_eq!(soup.triangle_parts, vec![0, 0, 1]);
    let scene = weld(soup, Weld::Exact);
    // The bolt's copies of the plate's corners weld to the plate's vertices.
    assert_eq!(scene.positions.len(), 5);
}

#[test]
fn obj_rejects_non_finite_coordinate_with_its_line() {
    let error = read(b"v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n", Format::Obj).unwrap_err();
    assert_eq!(error.problem, Problem::NonFiniteCoordinate);
    assert_eq!(error.location, Location::Line(2));
}

#[test]
fn obj_rejects_out_of_range_index_with_its_line() {
    let error = read(
        b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\n",
        Format::Obj,
    )
    .unwrap_err();
    assert_eq!(error.location, Location::Line(5));
    assert!(matches!(
        error.problem,
        Problem::IndexOutOfRange {
            index: 9,
            vertex_count: 3
        }
    ));
}

#[test]
fn obj_rejects_unparsable_position_with_its_line() {
    let error = read(b"v 0 0 0\nv 1 zero 0\n", Format::Obj).unwrap_err();
    assert_eq!(error.location, Location::Line(2));
}

#[test]
fn obj_reads_the_bunny() {
    let scene = vds_import::load_file(shared("bunny.obj"), &Default::default()).unwrap();
    assert_eq!(scene.positions.len(), 28_088);
    assert_eq!(scene.triangles.len(), 56_172);
}

#[test]
fn obj_reads_the_cad_assembly_as_eighteen_parts() {
    let scene = vds_import::load_file(shared("as1_assembly.obj"), &Default::default()).unwrap();
    assert_eq!(scene.part_names.len(), 18);
    assert_eq!(scene.stats.input_triangles, 10_896);
    assert!(
        scene.stats.welded_vertices > 0,
        "B-rep seams are unwelded in the file"
    );
}

// ---------- PLY ----------

fn ply_header(format: &str, vertices: usize, faces: usize) -> String {
    format!(
        "ply\nformat {format} 1.0\ncomment made by a test\nelement vertex {vertices}\nproperty float x\n\
         property uchar flags\nproperty float y\nproperty double z\nelement face {faces}\n\
         property list uchar int vertex_indices\nproperty uchar red\nend_header\n"
    )
}

const SQUARE: [[f32; 3]; 4] = [
    [0.0, 0.0, 0.0],
    [1.0, 0.0, 0.0],
    [1.0, 1.0, 0.0],
    [0.0, 1.0, 0.0],
];

fn binary_ply(big_endian: bool, faces: &[&[i32]]) -> Vec<u8> {
    let format = if big_endian {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let mut out = ply_header(format, SQUARE.len(), faces.len()).into_bytes();
    let f32b = |x: f32| {
        if big_endian {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    let f64b = |x: f64| {
        if big_endian {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    let i32b = |x: i32| {
        if big_endian {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    for p in SQUARE {
        out.extend(f32b(p[0]));
        out.push(7);
        out.extend(f32b(p[1]));
        out.extend(f64b(f64::from(p[2])));
    }
    for face in faces {
        out.push(face.len() as u8);
        for &i in *face {
            out.extend(i32b(i));
        }
        out.push(255);
    }
    out
}

#[test]
fn ply_binary_both_endiannesses_read_extra_properties_and_quads() {
    for big_endian in [false, true] {
        let soup = read(&binary_ply(big_endian, &[&[0, 1, 2, 3]]), Format::Ply).unwrap();
        assert_eq!(soup.positions, SQUARE.to_vec());
        assert_eq!(soup.triangles, vec![[0, 1, 2], [0, 2, 3]]);
    }
}

/// A PLY file laid out as `vds-gen` writes them (`float` x/y/z, a `uchar` count with `index`
/// corners, optionally a `uint part`), with enough faces for several parallel chunks.
fn float_ply(
    big_endian: bool,
    index: &str,
    with_part: bool,
) -> (Vec<u8>, Vec<[f32; 3]>, Vec<[u32; 3]>) {
    let (vertex_count, face_count) = (5_000u32, 40_000u32);
    let positions: Vec<[f32; 3]> = (0..vertex_count)
        .map(|i| {
            [
                i as f32 * 0.5,
                (i % 97) as f32 - 3.25,
                (i * 7 % 13) as f32 * 1e-3,
            ]
        })
        .collect();
    let triangles: Vec<[u32; 3]> = (0..face_count)
        .map(|f| {
            [
                f % vertex_count,
                (f * 7 + 1) % vertex_count,
                (f * 13 + 2) % vertex_count,
            ]
        })
        .collect();
    let format = if big_endian {
        "binary_big_endian"
    } else {
        "binary_little_endian"
    };
    let part = if with_part {
        "property uint part\n"
    } else {
        ""
    };
    let mut out = format!(
        "ply\nformat {format} 1.0\nelement vertex {vertex_count}\nproperty float x\n\
         property float y\nproperty float z\nelement face {face_count}\n\
         property list uchar {index} vertex_indices\n{part}end_header\n"
    )
    .into_bytes();
    let word = |x: u32| {
        if big_endian {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        }
    };
    for p in &positions {
        for c in p {
            out.extend(word(c.to_bits()));
        }
    }
    for (f, t) in triangles.iter().enumerate() {
        out.push(3);
        for &v in t {
            out.extend(word(v));
        }
        if with_part {
            out.extend(word(1_000 + f as u32 / 1_000));
        }
    }
    (out, positions, triangles)
}

#[test]
fn ply_fast_layouts_read_as_the_generic_reader_does() {
    for index in ["int", "uint"] {
        for with_part in [false, true] {
            // Little-endian files of this layout take the specialised readers; big-endian
            // ones the generic reader.
            let (little, positions, triangles) = float_ply(false, index, with_part);
            let (big, ..) = float_ply(true, index, with_part);
            let fast = read(&little, Format::Ply).unwrap();
            let generic = read(&big, Format::Ply).unwrap();
            assert_eq!(fast.positions, positions);
            assert_eq!(fast.triangles, triangles);
            assert_eq!(fast.positions, generic.positions);
            assert_eq!(fast.triangles, generic.triangles);
            assert_eq!(fast.triangle_parts, generic.triangle_parts);
            assert_eq!(fast.part_names, generic.part_names);
            let parts = if with_part { 40 } else { 1 };
            assert_eq!(fast.part_names.len(), parts, "{index} {with_part}");
        }
    }
}

#[test]
fn ply_ascii_reads() {
    let mut text = ply_header("ascii", 4, 1);
    for p in SQUARE {
        text += &format!("{} 3 {} {}\n", p[0], p[1], p[2]);
    }
    text += "4 0 1 2 3 9\n";
    let soup = read(text.as_bytes(), Format::Ply).unwrap();
    assert_eq!(soup.positions, SQUARE.to_vec());
    assert_eq!(soup.triangles.len(), 2);
}

#[test]
fn ply_ascii_rejects_non_finite_vertex() {
    let mut text = ply_header("ascii", 2, 0);
    text += "0 0 0 0\n1 0 inf 0\n";
    let error = read(text.as_bytes(), Format::Ply).unwrap_err();
    assert_eq!(error.problem, Problem::NonFiniteCoordinate);
    assert_eq!(
        error.location,
        Location::Element {
            kind: "vertex".into(),
            index: 1
        }
    );
}

#[test]
fn ply_rejects_out_of_range_index() {
    let error = read(&binary_ply(false, &[&[0, 1, 4]]), Format::Ply).unwrap_err();
    assert_eq!(
        error.problem,
        Problem::IndexOutOfRange {
            index: 4,
            vertex_count: 4
        }
    );
    assert_eq!(
        error.location,
        Location::Element {
            kind: "face".into(),
            index: 0
        }
    );
    let error = read(&binary_ply(false, &[&[0, -1, 2]]), Format::Ply).unwrap_err();
    assert!(matches!(
        error.problem,
        Problem::IndexOutOfRange { index: -1, .. }
    ));
}

#[test]
fn ply_rejects_truncated_binary() {
    let bytes = binary_ply(false, &[&[0, 1, 2]]);
    let error = read(&bytes[..bytes.len() - 3], Format::Ply).unwrap_err();
    assert!(
        matches!(error.problem, Problem::Truncated { .. }),
        "{error:?}"
    );
}

#[test]
fn ply_rejects_count_larger_than_file_before_allocating() {
    let mut bytes = ply_header("binary_little_endian", 4_000_000_000, 0).into_bytes();
    bytes.extend([0u8; 64]);
    let error = read(&bytes, Format::Ply).unwrap_err();
    assert!(
        matches!(
            error.problem,
            Problem::CountExceedsFile {
                count: 4_000_000_000,
                ..
            }
        ),
        "{error:?}"
    );
}

#[test]
fn ply_reads_bone_with_extra_vertex_properties() {
    let scene = vds_import::load_file(shared("bone.ply"), &Default::default()).unwrap();
    assert_eq!(scene.stats.input_vertices, 1_872);
    assert_eq!(
        scene.triangles.len() as u64 + scene.stats.degenerate_triangles_dropped,
        3_022
    );
}

#[test]
fn ply_reads_gzipped_ascii_dragon() {
    let scene = vds_import::load_file(shared("dragon.ply.gz"), &Default::default()).unwrap();
    assert_eq!(scene.stats.input_vertices, 437_645);
    assert_eq!(scene.stats.input_triangles, 871_414);
}

// ---------- STL ----------

fn binary_stl(triangles: &[[[f32; 3]; 3]]) -> Vec<u8> {
    let mut out = vec![b' '; 80];
    out.extend((triangles.len() as u32).to_le_bytes());
    for t in triangles {
        out.extend([0u8; 12]);
        for p in t {
            for c in p {
                out.extend(c.to_le_bytes());
            }
        }
        out.extend([0u8; 2]);
    }
    out
}

const TWO_TRIANGLES: [[[f32; 3]; 3]; 2] = [
    [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0]],
    [[0.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]],
];

#[test]
fn stl_binary_welds_shared_corners() {
    let scene = weld(
        read(&binary_stl(&TWO_TRIANGLES), Format::Stl).unwrap(),
        Weld::Exact,
    );
    assert_eq!(scene.positions.len(), 4);
    assert_eq!(scene.stats.welded_vertices, 2);
}

#[test]
fn stl_ascii_reads_solids_as_parts() {
    let text = "solid first\nfacet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 1 1 0\n\
                endloop\nendfacet\nendsolid first\nsolid second\nfacet normal 0 0 1\nouter loop\n\
                vertex 0 0 0\nvertex 1 1 0\nvertex 0 1 0\nendloop\nendfacet\nendsolid\n";
    let soup = read(text.as_bytes(), Format::Stl).unwrap();
    assert_eq!(soup.part_names, vec!["first", "second"]);
    assert_eq!(weld(soup, Weld::Exact).positions.len(), 4);
}

#[test]
fn stl_rejects_truncated_binary() {
    let bytes = binary_stl(&TWO_TRIANGLES);
    let error = read(&bytes[..bytes.len() - 10], Format::Stl).unwrap_err();
    assert!(
        matches!(error.problem, Problem::Truncated { .. }),
        "{error:?}"
    );
}

#[test]
fn stl_rejects_non_finite_vertex_naming_the_triangle() {
    let mut t = TWO_TRIANGLES;
    t[1][2][0] = f32::INFINITY;
    let error = read(&binary_stl(&t), Format::Stl).unwrap_err();
    assert_eq!(error.problem, Problem::NonFiniteCoordinate);
    assert_eq!(
        error.location,
        Location::Element {
            kind: "triangle".into(),
            index: 1
        }
    );
}

#[test]
fn stl_ascii_rejects_bad_vertex_with_line() {
    let text = "solid s\nfacet normal 0 0 1\nouter loop\nvertex 0 0\n";
    let error = read(text.as_bytes(), Format::Stl).unwrap_err();
    assert_eq!(error.location, Location::Line(4));
}

#[test]
fn stl_ascii_names_the_byte_of_bad_utf8_and_the_last_line_of_an_open_loop() {
    // A CRLF file whose third line holds a byte that is not UTF-8.
    let mut bytes = b"solid s\r\nfacet normal 0 0 1\r\nouter lo".to_vec();
    let bad_at = bytes.len();
    bytes.extend_from_slice(b"\xffop\r\n");
    let error = read(&bytes, Format::Stl).unwrap_err();
    assert_eq!(error.location, Location::Byte(bad_at as u64));
    // A loop still open at the end: the last line is named, with or without its newline.
    for ending in ["\n", ""] {
        let text = format!("solid s\nfacet normal 0 0 1\nouter loop\n\nvertex 0 0 0{ending}");
        let error = read(text.as_bytes(), Format::Stl).unwrap_err();
        assert_eq!(error.location, Location::Line(5), "ending {ending:?}");
        assert!(
            format!("{:?}", error.problem).contains("outer loop"),
            "{error:?}"
        );
    }
}

// ---------- glTF ----------

/// A glTF JSON document with one embedded buffer holding `positions` then `indices`.
fn gltf(positions: &[[f32; 3]], indices: &[u32], mode: u32, translation: [f32; 3]) -> String {
    let mut buffer = Vec::new();
    for p in positions {
        for c in p {
            buffer.extend(c.to_le_bytes());
        }
    }
    let position_bytes = buffer.len();
    for i in indices {
        buffer.extend(i.to_le_bytes());
    }
    let data = base64::engine::general_purpose::STANDARD.encode(&buffer);
    format!(
        r#"{{"asset":{{"version":"2.0"}},"scene":0,"scenes":[{{"nodes":[0]}}],
        "nodes":[{{"name":"root","children":[1]}},{{"name":"bracket","mesh":0,"translation":[{},{},{}]}}],
        "meshes":[{{"primitives":[{{"attributes":{{"POSITION":0}},"indices":1,"mode":{mode}}}]}}],
        "buffers":[{{"byteLength":{},"uri":"data:application/octet-stream;base64,{data}"}}],
        "bufferViews":[{{"buffer":0,"byteOffset":0,"byteLength":{position_bytes}}},
                       {{"buffer":0,"byteOffset":{position_bytes},"byteLength":{}}}],
        "accessors":[{{"bufferView":0,"componentType":5126,"count":{},"type":"VEC3","min":[0,0,0],"max":[1,1,1]}},
                     {{"bufferView":1,"componentType":5125,"count":{},"type":"SCALAR"}}]}}"#,
        translation[0],
        translation[1],
        translation[2],
        buffer.len(),
        buffer.len() - position_bytes,
        positions.len(),
        indices.len()
    )
}

#[test]
fn gltf_applies_world_transforms_and_names_parts_after_nodes() {
    let text = gltf(&SQUARE, &[0, 1, 2, 0, 2, 3], 4, [10.0, 0.0, 0.0]);
    let soup = read(text.as_bytes(), Format::Gltf).unwrap();
    // The transforming root node is the assembly above the bracket.
    assert_eq!(soup.part_names, vec!["root", "bracket"]);
    assert_eq!(soup.parts[1].parent, Some(0));
    assert_eq!(soup.triangle_parts, [1, 1]);
    assert_eq!(soup.triangles.len(), 2);
    assert_eq!(soup.positions[1], [11.0, 0.0, 0.0]);
}

#[test]
fn gltf_converts_strips_and_fans() {
    let strip = read(
        gltf(&SQUARE, &[0, 1, 3, 2], 5, [0.0; 3]).as_bytes(),
        Format::Gltf,
    )
    .unwrap();
    assert_eq!(strip.triangles, vec![[0, 1, 3], [3, 1, 2]]);
    let fan = read(
        gltf(&SQUARE, &[0, 1, 2, 3], 6, [0.0; 3]).as_bytes(),
        Format::Gltf,
    )
    .unwrap();
    assert_eq!(fan.triangles, vec![[0, 1, 2], [0, 2, 3]]);
}

#[test]
fn gltf_rejects_line_primitives() {
    let error = read(
        gltf(&SQUARE, &[0, 1, 1, 2], 1, [0.0; 3]).as_bytes(),
        Format::Gltf,
    )
    .unwrap_err();
    assert!(
        matches!(error.problem, Problem::UnsupportedPrimitiveMode(_)),
        "{error:?}"
    );
}

#[test]
fn gltf_rejects_out_of_range_index() {
    let error = read(
        gltf(&SQUARE, &[0, 1, 7], 4, [0.0; 3]).as_bytes(),
        Format::Gltf,
    )
    .unwrap_err();
    assert!(matches!(
        error.problem,
        Problem::IndexOutOfRange {
            index: 7,
            vertex_count: 4
        }
    ));
}

#[test]
fn gltf_rejects_non_finite_position() {
    let mut square = SQUARE;
    square[2][1] = f32::NAN;
    let error = read(
        gltf(&square, &[0, 1, 2], 4, [0.0; 3]).as_bytes(),
        Format::Gltf,
    )
    .unwrap_err();
    assert_eq!(error.problem, Problem::NonFiniteCoordinate);
}

#[test]
fn gltf_rejects_position_accessor_that_does_not_exist() {
    // gltf-json's validator itself panics on this; the reader must return an error.
    let text = gltf(&SQUARE, &[0, 1, 2], 4, [0.0; 3]).replace(r#""POSITION":0"#, r#""POSITION":9"#);
    let error = read(text.as_bytes(), Format::Gltf).unwrap_err();
    assert!(matches!(error.problem, Problem::Syntax(_)), "{error:?}");
}

#[test]
fn gltf_rejects_accessor_larger_than_its_buffer() {
    let text =
        gltf(&SQUARE, &[0, 1, 2], 4, [0.0; 3]).replace(r#""count":4"#, r#""count":4000000000"#);
    assert!(read(text.as_bytes(), Format::Gltf).is_err());
}

/// Wraps a JSON document and a binary chunk as GLB.
fn glb(json: &str, bin: &[u8]) -> Vec<u8> {
    let mut json = json.as_bytes().to_vec();
    while !json.len().is_multiple_of(4) {
        json.push(b' ');
    }
    let mut bin = bin.to_vec();
    while !bin.len().is_multiple_of(4) {
        bin.push(0);
    }
    let total = 12 + 8 + json.len() + 8 + bin.len();
    let mut out = Vec::new();
    out.extend(b"glTF");
    out.extend(2u32.to_le_bytes());
    out.extend((total as u32).to_le_bytes());
    out.extend((json.len() as u32).to_le_bytes());
    out.extend(b"JSON");
    out.extend(&json);
    out.extend((bin.len() as u32).to_le_bytes());
    out.extend(b"BIN\0");
    out.extend(&bin);
    out
}

#[test]
fn glb_reads_binary_chunk_and_rejects_truncation() {
    let mut bin = Vec::new();
    for p in SQUARE {
        for c in p {
            bin.extend(c.to_le_bytes());
        }
    }
    let json = r#"{"asset":{"version":"2.0"},"scenes":[{"nodes":[0]}],"nodes":[{"mesh":0}],
        "meshes":[{"name":"plate","primitives":[{"attributes":{"POSITION":0}}]}],
        "buffers":[{"byteLength":48}],"bufferViews":[{"buffer":0,"byteLength":48}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":4,"type":"VEC3","min":[0,0,0],"max":[1,1,0]}]}"#;
    let bytes = glb(json, &bin);
    let soup = read(&bytes, Format::Gltf).unwrap();
    assert_eq!(
        soup.triangles.len(),
        1,
        "non-indexed: one triangle from four vertices"
    );
    assert_eq!(soup.part_names, vec!["plate"]);
    assert!(read(&bytes[..bytes.len() - 20], Format::Gltf).is_err());
}

// ---------- welding ----------

#[test]
fn degenerate_triangles_are_dropped_and_counted() {
    let text = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 0 0\nf 1 2 3\nf 1 2 4\n";
    let scene = weld(read(text.as_bytes(), Format::Obj).unwrap(), Weld::Exact);
    assert_eq!(scene.triangles.len(), 1);
    assert_eq!(scene.stats.degenerate_triangles_dropped, 1);
}

#[test]
fn tolerance_weld_joins_near_vertices_only() {
    let text =
        "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1.0000001 0 0\nv 0 1.01 0\nv 0 0 1\nf 1 2 3\nf 4 5 6\n";
    let scene = weld(
        read(text.as_bytes(), Format::Obj).unwrap(),
        Weld::Relative(1e-4),
    );
    assert_eq!(
        scene.stats.welded_vertices, 1,
        "1.0000001 joins 1.0; 1.01 stays apart"
    );
    assert_eq!(scene.positions.len(), 5);
}

#[test]
fn unknown_extension_is_a_typed_error() {
    let error = vds_import::load_file("model.xyz", &Default::default()).unwrap_err();
    assert!(matches!(
        error,
        vds_import::ImportError::UnknownFormat { .. }
    ));
    assert!(error.to_string().contains("model.xyz"));
}

#[test]
fn errors_name_the_file() {
    let dir = std::env::temp_dir().join(format!("vds-import-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("broken.obj");
    std::fs::write(&path, "v 0 0 0\nv 1 nan 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let message = vds_import::load_file(&path, &Default::default())
        .unwrap_err()
        .to_string();
    assert!(
        message.contains("broken.obj") && message.contains("line 2"),
        "{message}"
    );
    std::fs::remove_dir_all(dir).unwrap();
}

// ---------- hostile input ----------

fn valid_inputs() -> Vec<(Vec<u8>, Format)> {
    let mut ascii_ply = ply_header("ascii", 4, 1);
    for p in SQUARE {
        ascii_ply += &format!("{} 3 {} {}\n", p[0], p[1], p[2]);
    }
    ascii_ply += "4 0 1 2 3 9\n";
    vec![
        (TWO_OBJECTS.as_bytes().to_vec(), Format::Obj),
        (binary_ply(false, &[&[0, 1, 2, 3]]), Format::Ply),
        (binary_ply(true, &[&[0, 1, 2]]), Format::Ply),
        (ascii_ply.into_bytes(), Format::Ply),
        (binary_stl(&TWO_TRIANGLES), Format::Stl),
        (
            gltf(&SQUARE, &[0, 1, 2, 0, 2, 3], 4, [1.0; 3]).into_bytes(),
            Format::Gltf,
        ),
    ]
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(400))]

    /// Bit flips, byte overwrites and truncation never panic a reader.
    #[test]
    fn mutated_files_never_panic(
        which in 0usize..6,
        flips in prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        cut in any::<prop::sample::Index>(),
        truncate in any::<bool>(),
    ) {
        let (mut bytes, format) = valid_inputs().swap_remove(which);
        for (at, value) in flips {
            let i = at.index(bytes.len());
            bytes[i] ^= value;
        }
        if truncate {
            bytes.truncate(cut.index(bytes.len() + 1));
        }
        let _ = read(&bytes, format);
    }
}
