//! The `vds-cut` command line: what it writes, what it reports, how it fails.

mod common;

use std::process::Command;

use common::{load, vdt_bytes};

fn vds_cut() -> Command {
    Command::new(env!("CARGO_BIN_EXE_vds-cut"))
}

fn temp_dir(name: &str) -> std::path::PathBuf {
    let dir = std::env::temp_dir().join(format!("vds-cut-test-{name}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn exports_obj_and_ply_and_reports_json() {
    let dir = temp_dir("export");
    let mut scene = load("cow.obj");
    let file = dir.join("cow.vdt");
    std::fs::write(&file, vdt_bytes(&mut scene)).unwrap();
    for (output, extra) in [
        ("cut.obj", vec!["--threshold", "2"]),
        ("cut.ply", vec!["--budget", "1000", "--view-independent"]),
    ] {
        let out = dir.join(output);
        let result = vds_cut()
            .arg(&file)
            .arg("-o")
            .arg(&out)
            .args(&extra)
            .args(["--json", "--verify"])
            .output()
            .unwrap();
        assert!(
            result.status.success(),
            "{}",
            String::from_utf8_lossy(&result.stderr)
        );
        let report: serde_json::Value = serde_json::from_slice(&result.stdout).unwrap();
        let triangles = report["triangles"].as_u64().unwrap();
        assert!(triangles > 0);
        // The exported mesh reads back with the same triangle count.
        let back = vds_import::load_file(&out, &Default::default()).unwrap();
        assert_eq!(back.stats.input_triangles, triangles, "{output}");
        if output.ends_with(".obj") {
            assert!(report["max_deviation_px"].as_f64().unwrap() <= 2.0 + 1e-3);
        } else {
            assert!(triangles <= 1000);
            assert!(report["max_deviation_px"].is_null());
        }
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn bad_inputs_fail_with_a_message_and_no_output() {
    let dir = temp_dir("bad");
    let missing = dir.join("missing.vdt");
    let out = dir.join("out.obj");
    let result = vds_cut()
        .arg(&missing)
        .arg("-o")
        .arg(&out)
        .args(["--threshold", "1"])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&result.stderr).contains("missing.vdt"));
    assert!(!out.exists());

    let garbage = dir.join("garbage.vdt");
    std::fs::write(&garbage, b"not a vdt file at all").unwrap();
    let result = vds_cut()
        .arg(&garbage)
        .arg("-o")
        .arg(&out)
        .args(["--threshold", "1"])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    assert!(!out.exists());

    let result = vds_cut()
        .arg(&garbage)
        .arg("-o")
        .arg(&out)
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(2), "a goal is required");
    let result = vds_cut()
        .arg(&garbage)
        .args(["-o", "x.stl", "--threshold", "1"])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    std::fs::remove_dir_all(&dir).unwrap();
}
