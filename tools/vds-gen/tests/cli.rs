//! The `vds-gen` command line: counts it refuses before generating anything.

use std::process::Command;

#[test]
fn gen_rejects_nan_and_out_of_range_counts_naming_the_option() {
    let dir = std::env::temp_dir().join(format!("vds-gen-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let out = dir.join("never.ply");
    // NaN once became 0 triangles, and 1e30 saturated to u64::MAX: generating until memory
    // ran out.
    for value in ["nan", "0", "-5", "1e30", "inf", "2000M", "x"] {
        let result = Command::new(env!("CARGO_BIN_EXE_vds-gen"))
            .args([&format!("--triangles={value}"), "--out"])
            .arg(&out)
            .output()
            .unwrap();
        let message = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{value}: {message}");
        assert!(message.contains("--triangles"), "{value}: {message}");
    }
    assert!(!out.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
