//! Hostile inputs through the command lines, as a batch job would meet them: each must end in
//! exit 1 with a message naming the file, quickly, and leave no output file behind.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use std::time::{Duration, Instant};

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vds-hostile-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// Runs a binary, failing the test if it has not finished within ten seconds (a FIFO that
/// is opened for reading blocks forever).
fn run(binary: &str, args: &[&str]) -> Output {
    let mut child = Command::new(binary)
        .args(args)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while child.try_wait().unwrap().is_none() {
        if start.elapsed() > Duration::from_secs(10) {
            child.kill().unwrap();
            panic!("{binary} {args:?} still running after 10 s");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    child.wait_with_output().unwrap()
}

fn build(args: &[&str]) -> Output {
    run(env!("CARGO_BIN_EXE_vds-build"), args)
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Exit 1, stderr naming `name` (and `also`), and no file at `out`.
fn assert_refused(output: &Output, name: &str, also: &str, out: &Path) {
    let stderr = String::from_utf8_lossy(&output.stderr);
    assert_eq!(output.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains(name) && stderr.contains(also),
        "{stderr} should name {name} and say {also}"
    );
    assert!(!stderr.contains("panicked"), "{stderr}");
    assert!(!out.exists(), "{} was written", out.display());
}

#[cfg(unix)]
fn make_fifo(path: &Path) {
    assert!(Command::new("mkfifo").arg(path).status().unwrap().success());
}

#[cfg(unix)]
#[test]
fn info_refuses_a_fifo_without_blocking() {
    let dir = temp_dir("info-fifo");
    let fifo = dir.join("pipe.vdt");
    make_fifo(&fifo);
    let output = run(env!("CARGO_BIN_EXE_vds-info"), &[path(&fifo)]);
    assert_refused(&output, "pipe.vdt", "not a regular file", &dir.join("none"));
    std::fs::remove_dir_all(dir).unwrap();
}

#[cfg(unix)]
#[test]
fn build_refuses_a_fifo_and_a_link_to_a_device_without_blocking() {
    let dir = temp_dir("build-fifo");
    let fifo = dir.join("pipe.obj");
    make_fifo(&fifo);
    let link = dir.join("zero.obj");
    std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
    let out = dir.join("out.vdt");
    for input in [&fifo, &link] {
        let output = build(&[path(input), "-o", path(&out)]);
        let name = input.file_name().unwrap().to_str().unwrap();
        assert_refused(&output, name, "not a regular file", &out);
    }
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn build_refuses_a_gltf_buffer_outside_the_model_folder() {
    let dir = temp_dir("gltf-uri");
    std::fs::create_dir_all(dir.join("model")).unwrap();
    std::fs::write(dir.join("secret.bin"), [0u8; 48]).unwrap();
    let model = dir.join("model/leak.gltf");
    let gltf = r#"{"asset":{"version":"2.0"},"scene":0,"scenes":[{"nodes":[0]}],
        "nodes":[{"mesh":0}],
        "meshes":[{"primitives":[{"attributes":{"POSITION":0}}]}],
        "buffers":[{"byteLength":36,"uri":"../secret.bin"}],
        "bufferViews":[{"buffer":0,"byteLength":36}],
        "accessors":[{"bufferView":0,"componentType":5126,"count":3,"type":"VEC3","min":[0,0,0],"max":[0,0,0]}]}"#;
    std::fs::write(&model, gltf).unwrap();
    let out = dir.join("out.vdt");
    let output = build(&[path(&model), "-o", path(&out)]);
    assert_refused(&output, "leak.gltf", "--allow-external-uris", &out);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn build_of_an_input_without_triangles_fails_naming_it_with_or_without_output() {
    let dir = temp_dir("empty");
    let model = dir.join("lines.obj");
    std::fs::write(&model, "v 0 0 0\nv 1 0 0\nv 0 1 0\nl 1 2 3\n").unwrap();
    let out = dir.join("out.vdt");
    assert_refused(
        &build(&[path(&model), "-o", path(&out)]),
        "lines.obj",
        "no triangles",
        &out,
    );
    assert_refused(&build(&[path(&model)]), "lines.obj", "no triangles", &out);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn build_refuses_a_gzip_input_past_the_decompression_limit() {
    use std::io::Write;
    let dir = temp_dir("gzip");
    let model = dir.join("bomb.ply.gz");
    let mut encoder = flate2::write::GzEncoder::new(
        std::fs::File::create(&model).unwrap(),
        flate2::Compression::fast(),
    );
    encoder.write_all(&vec![b' '; 8 << 20]).unwrap();
    encoder.finish().unwrap();
    let out = dir.join("out.vdt");
    let output = build(&[
        path(&model),
        "-o",
        path(&out),
        "--max-decompressed-bytes",
        "1MiB",
    ]);
    assert_refused(&output, "bomb.ply.gz", "--max-decompressed-bytes", &out);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn limits_must_be_positive_sizes_and_counts() {
    for args in [
        ["--max-triangles", "0"],
        ["--max-decompressed-bytes", "0"],
        ["--max-decompressed-bytes", "12 parsecs"],
        ["--max-decompressed-bytes", "99999999999T"],
    ] {
        let output = build(&args);
        let stderr = String::from_utf8_lossy(&output.stderr);
        assert_eq!(output.status.code(), Some(2), "{args:?}: {stderr}");
        assert!(stderr.contains(args[0]), "{args:?}: {stderr}");
    }
}
