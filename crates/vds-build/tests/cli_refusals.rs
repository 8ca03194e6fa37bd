//! What the `vds-build` command line refuses (issue #22, hostile input): outputs that would
//! replace an input or something that is not a regular file, and numbers out of range. And
//! what it cleans up and keeps the same: partials of killed builds, inputs however spelt.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vds-refuse-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A small model (the demo assembly) copied into `dir` as `name`.
fn model_in(dir: &Path, name: &str) -> PathBuf {
    let source = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/as1_assembly.obj");
    let copy = dir.join(name);
    std::fs::copy(source, &copy).unwrap();
    copy
}

fn build(args: &[&Path]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_vds-build"))
        .args(args)
        .output()
        .unwrap()
}

fn names(dir: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

#[test]
fn build_refuses_to_overwrite_its_own_input() {
    let dir = temp_dir("own-input");
    let input = model_in(&dir, "model.obj");
    let before = std::fs::read(&input).unwrap();
    let hard = dir.join("hard.vdt");
    std::fs::hard_link(&input, &hard).unwrap();
    // The same path, the same file spelt another way, and a hard link to it.
    let dotted = dir.join(".").join("model.obj");
    for output in [&input, &dotted, &hard] {
        let run = build(&[&input, Path::new("-o"), output, Path::new("-q")]);
        assert_eq!(run.status.code(), Some(1), "{}", output.display());
        let message = String::from_utf8_lossy(&run.stderr);
        assert!(
            message.contains(&*output.to_string_lossy()) && message.contains("is the input"),
            "{message}"
        );
        assert!(
            std::fs::read(&input).unwrap() == before,
            "the input was replaced"
        );
    }
    assert_eq!(names(&dir), ["hard.vdt", "model.obj"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[cfg(unix)]
#[test]
fn build_refuses_an_output_that_is_a_directory_or_links_to_a_device() {
    let dir = temp_dir("not-regular");
    let input = model_in(&dir, "model.obj");
    let directory = dir.join("sub.vdt");
    std::fs::create_dir(&directory).unwrap();
    // A link to /dev/null rather than /dev/null itself: if the refusal broke, the rename
    // would replace the link, not the machine's /dev/null.
    let null = dir.join("null.vdt");
    std::os::unix::fs::symlink("/dev/null", &null).unwrap();
    for (output, kind) in [(&directory, "a directory"), (&null, "character device")] {
        let run = build(&[&input, Path::new("-o"), output]);
        assert_eq!(run.status.code(), Some(1));
        let message = String::from_utf8_lossy(&run.stderr);
        assert!(
            message.contains(&*output.to_string_lossy()) && message.contains(kind),
            "{message}"
        );
    }
    assert!(directory.is_dir());
    assert!(std::fs::symlink_metadata(&null).unwrap().is_symlink());
    assert_eq!(names(&dir), ["model.obj", "null.vdt", "sub.vdt"]);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[cfg(unix)]
#[test]
fn batch_refuses_outputs_that_are_an_input_or_a_directory_and_goes_on() {
    let dir = temp_dir("batch");
    let a = model_in(&dir, "a.obj");
    let b = model_in(&dir, "b.obj");
    let c = model_in(&dir, "c.obj");
    let before = std::fs::read(&a).unwrap();
    let out = dir.join("out");
    std::fs::create_dir(&out).unwrap();
    // out/a.vdt links to the input a.obj; out/b.vdt is a directory; c builds.
    std::os::unix::fs::symlink(&a, out.join("a.vdt")).unwrap();
    std::fs::create_dir(out.join("b.vdt")).unwrap();
    let run = build(&[
        Path::new("--batch"),
        &a,
        &b,
        &c,
        Path::new("--out-dir"),
        &out,
        Path::new("-q"),
    ]);
    assert_eq!(run.status.code(), Some(1));
    let message = String::from_utf8_lossy(&run.stderr);
    assert!(
        message.contains("a.vdt: is the input") && message.contains("b.vdt: is a directory"),
        "{message}"
    );
    assert!(
        std::fs::read(&a).unwrap() == before,
        "the input was replaced"
    );
    assert!(out.join("b.vdt").is_dir());
    assert!(std::fs::metadata(out.join("c.vdt")).unwrap().is_file());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn build_removes_stale_partials_of_its_output_only() {
    let dir = temp_dir("partials");
    let input = model_in(&dir, "model.obj");
    // What killed builds leave: PIDs above Linux's largest pid_max (2^22) belong to no process.
    let stale = dir.join(".model.vdt.99999999.partial");
    let other = dir.join(".other.vdt.99999999.partial");
    std::fs::write(&stale, b"half a tree").unwrap();
    std::fs::write(&other, b"half another tree").unwrap();
    let run = build(&[
        &input,
        Path::new("-o"),
        &dir.join("model.vdt"),
        Path::new("-q"),
    ]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert_eq!(
        names(&dir),
        [".other.vdt.99999999.partial", "model.obj", "model.vdt"]
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn build_rejects_nan_and_out_of_range_numbers_naming_the_option() {
    let dir = temp_dir("numbers");
    let out = dir.join("never.vdt");
    for (option, value) in [
        ("--weld", "nan"),
        ("--weld", "inf"),
        ("--weld", "1"),
        ("--weld", "-0.01"),
        ("--threads", "0"),
        ("--threads", "100000"),
        ("--zstd-level", "0"),
        ("--zstd-level", "23"),
    ] {
        let run = Command::new(env!("CARGO_BIN_EXE_vds-build"))
            .args(["no-such-input.obj", &format!("{option}={value}"), "-o"])
            .arg(&out)
            .output()
            .unwrap();
        let message = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(2), "{option} {value}: {message}");
        assert!(message.contains(option), "{option} {value}: {message}");
    }
    assert_eq!(names(&dir), Vec::<String>::new());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn building_by_relative_or_absolute_path_gives_identical_bytes() {
    let dir = temp_dir("spelling");
    let input = model_in(&dir, "model.obj");
    let by_absolute = dir.join("absolute.vdt");
    let run = build(&[&input, Path::new("-o"), &by_absolute, Path::new("-q")]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let run = Command::new(env!("CARGO_BIN_EXE_vds-build"))
        .current_dir(&dir)
        .args(["./model.obj", "-o", "relative.vdt", "-q"])
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let (absolute, relative) = (
        std::fs::read(&by_absolute).unwrap(),
        std::fs::read(dir.join("relative.vdt")).unwrap(),
    );
    assert!(
        absolute == relative,
        "the bytes depend on how the input was spelt"
    );
    // What is kept: the name alone, and the content hash that says which file it was.
    let file = vds_format::VdtFile::from_bytes(absolute).unwrap();
    let inputs = &file.metadata().inputs;
    assert_eq!(inputs.len(), 1);
    assert_eq!(inputs[0].name, "model.obj");
    assert_eq!(
        inputs[0].content_hash,
        xxhash_rust::xxh3::xxh3_64(&std::fs::read(&input).unwrap())
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn batch_refuses_a_second_input_of_the_same_name_instead_of_replacing_the_first() {
    let dir = temp_dir("batch-names");
    std::fs::create_dir_all(dir.join("x")).unwrap();
    std::fs::create_dir_all(dir.join("y")).unwrap();
    let first = model_in(&dir.join("x"), "part.obj");
    // The second has other content (fewer parts), so its file would differ.
    let second = dir.join("y/part.obj");
    std::fs::write(&second, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n").unwrap();
    let out = dir.join("out");
    let run = build(&[
        Path::new("--batch"),
        &first,
        &second,
        Path::new("--out-dir"),
        &out,
        Path::new("-q"),
    ]);
    assert_eq!(run.status.code(), Some(1));
    let message = String::from_utf8_lossy(&run.stderr);
    assert!(message.contains("is already the output of"), "{message}");
    let kept = std::fs::read(out.join("part.vdt")).unwrap();
    let alone = dir.join("alone.vdt");
    assert!(
        build(&[&first, Path::new("-o"), &alone, Path::new("-q")])
            .status
            .success()
    );
    assert_eq!(
        kept,
        std::fs::read(&alone).unwrap(),
        "the first input's file was replaced"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}
