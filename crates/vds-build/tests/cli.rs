//! The `vds-build` and `vds-info` command lines: what a CI script relies on (exit codes,
//! files written or not, JSON reports, error messages naming the file and line).

use std::path::{Path, PathBuf};
use std::process::Command;

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vds-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn demo_model() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/as1_assembly.obj")
}

fn build(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_vds-build"))
        .args(args)
        .output()
        .unwrap()
}

fn info(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_vds-info"))
        .args(args)
        .output()
        .unwrap()
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

#[test]
fn build_writes_a_file_that_verifies_and_reports_json() {
    let dir = temp_dir("build");
    let out = dir.join("as1.vdt");
    let run = build(&[path(&demo_model()), "-o", path(&out), "--json"]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(report["parts"], 18);
    assert_eq!(
        report["output"]["bytes"].as_u64().unwrap(),
        std::fs::metadata(&out).unwrap().len()
    );
    let verify = info(&[path(&out), "--verify", "--json"]);
    assert!(
        verify.status.success(),
        "{}",
        String::from_utf8_lossy(&verify.stderr)
    );
    let described: serde_json::Value = serde_json::from_slice(&verify.stdout).unwrap();
    assert_eq!(described["triangles"], 10_896);
    assert_eq!(described["verified"], true);
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn identical_inputs_give_byte_identical_files_on_any_thread_count() {
    let dir = temp_dir("determinism");
    let (a, b) = (dir.join("a.vdt"), dir.join("b.vdt"));
    assert!(
        build(&[path(&demo_model()), "-o", path(&a), "--threads", "1", "-q"])
            .status
            .success()
    );
    assert!(
        build(&[path(&demo_model()), "-o", path(&b), "--threads", "2", "-q"])
            .status
            .success()
    );
    assert!(std::fs::read(&a).unwrap() == std::fs::read(&b).unwrap());
    std::fs::remove_dir_all(dir).unwrap();
}

/// `--builder qem` writes a file that verifies, the same bytes on one and two threads, and
/// another tree than the default; an unknown builder is a usage error that writes nothing.
#[test]
fn the_qem_builder_writes_a_deterministic_file_that_verifies() {
    let dir = temp_dir("qem");
    let (one, two, octree) = (dir.join("1.vdt"), dir.join("2.vdt"), dir.join("o.vdt"));
    let model = demo_model();
    for (out, threads) in [(&one, "1"), (&two, "2")] {
        let run = build(&[
            path(&model),
            "-o",
            path(out),
            "--builder",
            "qem",
            "--threads",
            threads,
            "--json",
            "--verify",
        ]);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let report: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        assert_eq!(report["builder"], "qem");
        // Binary: one inner node per leaf but one.
        assert_eq!(
            report["degree_histogram"][2].as_u64(),
            report["vertices"].as_u64().map(|v| v - 1)
        );
    }
    assert!(std::fs::read(&one).unwrap() == std::fs::read(&two).unwrap());
    assert!(
        build(&[path(&model), "-o", path(&octree), "-q"])
            .status
            .success()
    );
    assert!(std::fs::read(&one).unwrap() != std::fs::read(&octree).unwrap());
    let verify = info(&[path(&one), "--verify"]);
    assert!(
        verify.status.success(),
        "{}",
        String::from_utf8_lossy(&verify.stderr)
    );

    let bad = dir.join("bad.vdt");
    let run = build(&[path(&model), "-o", path(&bad), "--builder", "sloppy"]);
    assert_eq!(run.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&run.stderr).contains("'sloppy' is not a builder"));
    assert!(!bad.exists());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn malformed_input_fails_naming_file_and_line_and_writes_nothing() {
    let dir = temp_dir("malformed");
    let input = dir.join("broken.obj");
    std::fs::write(&input, "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n").unwrap();
    let out = dir.join("broken.vdt");
    let run = build(&[path(&input), "-o", path(&out)]);
    assert_eq!(run.status.code(), Some(1));
    let message = String::from_utf8_lossy(&run.stderr);
    assert!(
        message.contains("broken.obj") && message.contains("line 4"),
        "{message}"
    );
    let leftovers: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(leftovers.len(), 1, "{leftovers:?}");
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn batch_goes_on_past_failures_and_exits_nonzero() {
    let dir = temp_dir("batch");
    let bad_count = dir.join("short.stl");
    let mut bytes = vec![0u8; 84];
    bytes[80..84].copy_from_slice(&1000u32.to_le_bytes()); // 1000 triangles promised, none there.
    std::fs::write(&bad_count, bytes).unwrap();
    let out_dir = dir.join("out");
    let run = build(&[
        "--batch",
        path(&demo_model()),
        path(&bad_count),
        "--out-dir",
        path(&out_dir),
        "--json",
    ]);
    assert_eq!(run.status.code(), Some(1));
    let reports: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
    assert_eq!(reports.as_array().unwrap().len(), 2);
    assert!(reports[1]["error"].as_str().unwrap().contains("truncated"));
    assert!(out_dir.join("as1_assembly.vdt").exists());
    assert!(!out_dir.join("short.vdt").exists());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn info_rejects_a_corrupted_file() {
    let dir = temp_dir("corrupt");
    let out = dir.join("as1.vdt");
    assert!(
        build(&[path(&demo_model()), "-o", path(&out), "-q"])
            .status
            .success()
    );
    let mut bytes = std::fs::read(&out).unwrap();
    let n = bytes.len();
    bytes[n - 3] ^= 0xFF;
    std::fs::write(&out, bytes).unwrap();
    let run = info(&[path(&out), "--verify"]);
    assert_eq!(run.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&run.stderr).contains("checksum"));
    std::fs::remove_dir_all(dir).unwrap();
}

/// A header whose depth is false, its checksum recomputed so only the lie remains: `--verify`
/// fails naming the field and both values, and prints none of the figures.
#[test]
fn info_verify_refuses_a_false_header_depth() {
    let dir = temp_dir("false-depth");
    let out = dir.join("as1.vdt");
    assert!(
        build(&[path(&demo_model()), "-o", path(&out), "-q"])
            .status
            .success()
    );
    let mut bytes = std::fs::read(&out).unwrap();
    let depth = u32::from_le_bytes(bytes[52..56].try_into().unwrap());
    let nodes = u64::from_le_bytes(bytes[24..32].try_into().unwrap());
    // The deepest a header may claim and still open: below the node count.
    let claimed = (nodes - 1) as u32;
    assert!(claimed > depth);
    bytes[52..56].copy_from_slice(&claimed.to_le_bytes());
    let sum = xxhash_rust::xxh3::xxh3_64(&bytes[..120]);
    bytes[120..128].copy_from_slice(&sum.to_le_bytes());
    std::fs::write(&out, bytes).unwrap();
    // Without --verify the file opens (what open checks holds) and shows the lie.
    let shown = info(&[path(&out), "--json"]);
    assert!(shown.status.success());
    let described: serde_json::Value = serde_json::from_slice(&shown.stdout).unwrap();
    assert_eq!(described["depth"], claimed);
    let run = info(&[path(&out), "--verify"]);
    assert_eq!(run.status.code(), Some(1));
    let message = String::from_utf8_lossy(&run.stderr);
    assert!(
        message.contains("max_depth")
            && message.contains(&claimed.to_string())
            && message.contains(&depth.to_string()),
        "{message}"
    );
    assert!(
        run.stdout.is_empty(),
        "{}",
        String::from_utf8_lossy(&run.stdout)
    );
    std::fs::remove_dir_all(dir).unwrap();
}

/// `--verify` with `-o` reads the written file back and verifies it as `vds-info --verify`
/// does: a file it lets through verifies there too.
#[test]
fn build_verify_checks_the_written_file() {
    let dir = temp_dir("build-verify");
    let out = dir.join("as1.vdt");
    let run = build(&[path(&demo_model()), "-o", path(&out), "--verify", "-q"]);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(info(&[path(&out), "--verify"]).status.success());
    std::fs::remove_dir_all(dir).unwrap();
}

#[test]
fn smaller_pages_make_more_pages_that_verify() {
    let dir = temp_dir("page-bytes");
    let model = demo_model();
    let mut pages = Vec::new();
    for size in ["128KiB", "8KiB"] {
        let out = dir.join(format!("{size}.vdt"));
        let run = build(&[
            path(&model),
            "-o",
            path(&out),
            "--page-bytes",
            size,
            "--json",
        ]);
        assert!(
            run.status.success(),
            "{}",
            String::from_utf8_lossy(&run.stderr)
        );
        let report: serde_json::Value = serde_json::from_slice(&run.stdout).unwrap();
        pages.push(report["output"]["pages"].as_u64().unwrap());
        let verify = info(&[path(&out), "--verify"]);
        assert!(
            verify.status.success(),
            "{}",
            String::from_utf8_lossy(&verify.stderr)
        );
    }
    assert!(pages[1] > pages[0], "{pages:?}");
    for bad in ["1KiB", "2MiB", "x"] {
        let run = build(&[
            path(&model),
            "-o",
            path(&dir.join("bad.vdt")),
            "--page-bytes",
            bad,
        ]);
        assert_eq!(run.status.code(), Some(2), "{bad}");
        assert!(String::from_utf8_lossy(&run.stderr).contains("--page-bytes"));
    }
}
