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

/// `--bound` picks what a budget cut ranks by: both bounds fill the budget, they choose
/// different cuts of the CAD assembly (whose flat plates the surface error lets fold), and the
/// option is refused beside a threshold, which always holds the vertex bound.
#[test]
fn budget_cuts_rank_by_the_bound_asked_for() {
    let dir = temp_dir("bound");
    let file = dir.join("as1.vdt");
    std::fs::write(&file, vdt_bytes(&mut load("as1_assembly.obj"))).unwrap();
    let cut = |bound: &str| {
        let out = dir.join(format!("{bound}.ply"));
        let result = vds_cut()
            .arg(&file)
            .arg("-o")
            .arg(&out)
            .args([
                "--budget",
                "500",
                "--view-independent",
                "--json",
                "--verify",
            ])
            .args(["--bound", bound])
            .output()
            .unwrap();
        assert!(
            result.status.success(),
            "{}",
            String::from_utf8_lossy(&result.stderr)
        );
        let report: serde_json::Value = serde_json::from_slice(&result.stdout).unwrap();
        assert!(report["triangles"].as_u64().unwrap() <= 500);
        std::fs::read(&out).unwrap()
    };
    assert_ne!(cut("surface"), cut("vertex"));
    let result = vds_cut()
        .arg(&file)
        .arg("-o")
        .arg(dir.join("threshold.ply"))
        .args(["--threshold", "1", "--bound", "vertex"])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&result.stderr).contains("--budget"));
    assert!(!dir.join("threshold.ply").exists());
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

/// A small `.vdt` file in `dir`.
fn small_vdt(dir: &std::path::Path) -> std::path::PathBuf {
    let file = dir.join("cow.vdt");
    std::fs::write(&file, vdt_bytes(&mut load("cow.obj"))).unwrap();
    file
}

#[test]
fn cut_refuses_an_output_that_is_its_input() {
    let dir = temp_dir("same");
    let file = small_vdt(&dir);
    let before = std::fs::read(&file).unwrap();
    // The same file under another name, an .obj one: the names differ, the inode does not.
    let same = dir.join("same.obj");
    std::fs::hard_link(&file, &same).unwrap();
    let result = vds_cut()
        .arg(&file)
        .arg("-o")
        .arg(&same)
        .args(["--threshold", "1"])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    let message = String::from_utf8_lossy(&result.stderr);
    assert!(
        message.contains("same.obj") && message.contains("is the input"),
        "{message}"
    );
    assert!(
        std::fs::read(&file).unwrap() == before,
        "the input was replaced"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[cfg(unix)]
#[test]
fn cut_refuses_an_output_that_links_to_a_device() {
    let dir = temp_dir("device");
    let file = small_vdt(&dir);
    // A link, so that if the refusal broke, the rename would replace the link and not the
    // device.
    let null = dir.join("null.ply");
    std::os::unix::fs::symlink("/dev/null", &null).unwrap();
    let result = vds_cut()
        .arg(&file)
        .arg("-o")
        .arg(&null)
        .args(["--budget", "100"])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    let message = String::from_utf8_lossy(&result.stderr);
    assert!(
        message.contains("null.ply") && message.contains("character device"),
        "{message}"
    );
    assert!(std::fs::symlink_metadata(&null).unwrap().is_symlink());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn cut_rejects_nan_and_out_of_range_numbers_naming_the_option() {
    let dir = temp_dir("numbers");
    let file = dir.join("never-read.vdt");
    let out = dir.join("out.obj");
    for (option, value) in [
        ("--silhouette-factor", "nan"),
        ("--silhouette-factor", "1.5"),
        ("--threshold", "nan"),
        ("--threshold", "-1"),
        ("--threshold", "inf"),
        ("--budget", "0"),
        ("--fov", "180"),
        ("--fov", "nan"),
        ("--size", "0x100"),
        ("--size", "100x20000"),
        ("--gaze-falloff", "-0.5"),
        ("--up", "0,0,0"),
        ("--eye", "nan,0,0"),
    ] {
        let mut command = vds_cut();
        command.arg(&file).arg("-o").arg(&out);
        if option != "--threshold" && option != "--budget" {
            command.args(["--threshold", "1"]);
        }
        let result = command.arg(format!("{option}={value}")).output().unwrap();
        let message = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{option} {value}: {message}");
        assert!(message.contains(option), "{option} {value}: {message}");
    }
    assert!(!out.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn cut_names_the_file_that_is_not_a_vdt() {
    let dir = temp_dir("magic");
    let garbage = dir.join("garbage.vdt");
    std::fs::write(&garbage, vec![0u8; 4096]).unwrap();
    let result = vds_cut()
        .arg(&garbage)
        .arg("-o")
        .arg(dir.join("out.obj"))
        .args(["--threshold", "1"])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    let message = String::from_utf8_lossy(&result.stderr);
    assert!(
        message.contains("garbage.vdt") && message.contains("not a .vdt file"),
        "{message}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

/// The CSV rows of a replay, header first.
fn replay(file: &std::path::Path, stats: &std::path::Path, extra: &[&str]) -> Vec<Vec<String>> {
    let result = vds_cut()
        .arg(file)
        .args(["--threshold", "1", "--stats"])
        .arg(stats)
        .args(extra)
        .output()
        .unwrap();
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    assert!(String::from_utf8_lossy(&result.stdout).contains("adjust median"));
    std::fs::read_to_string(stats)
        .unwrap()
        .lines()
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect()
}

#[test]
fn replays_orbits_flights_and_path_files_without_a_gpu() {
    let dir = temp_dir("replay");
    let mut scene = load("cow.obj");
    let file = dir.join("cow.vdt");
    std::fs::write(&file, vdt_bytes(&mut scene)).unwrap();
    let stats = dir.join("stats.csv");
    let header = |rows: &[Vec<String>]| rows[0].join(",");
    let orbit = replay(&file, &stats, &["--orbit", "--frames", "12"]);
    assert_eq!(orbit.len(), 13, "a header and one row per frame");
    assert!(
        header(&orbit).starts_with("frame,adjust_ms,active_triangles,added,removed,changed"),
        "{}",
        header(&orbit)
    );
    assert!(header(&orbit).ends_with(
        "resident_bytes,pages_resident,pages_loaded,pages_evicted,pages_pending,effective_threshold,\
         rss_anon_bytes,pinned_bytes,refusals"
    ));
    let triangles = |row: &Vec<String>| row[2].parse::<u32>().unwrap();
    assert!(orbit[1..].iter().all(|row| triangles(row) > 0));
    // Synchronous loading never leaves a page pending.
    let at = |name: &str| orbit[0].iter().position(|h| h == name).unwrap();
    let (pending, deferred) = (at("pages_pending"), at("deferred_unfolds"));
    assert!(
        orbit[1..]
            .iter()
            .all(|row| row[pending] == "0" && row[deferred] == "0")
    );

    // A path file: two cameras; -o writes the last frame's cut.
    let path = dir.join("path.json");
    let camera = |z: f32| {
        format!(
            r#"{{"eye":[0,0,{z}],"target":[0,0,0],"up":[0,1,0],"fov_y_degrees":45,"width":320,"height":240,"near":0.01}}"#
        )
    };
    std::fs::write(
        &path,
        format!(r#"{{"cameras":[{},{}]}}"#, camera(10.0), camera(3.0)),
    )
    .unwrap();
    let last = dir.join("last.obj");
    let rows = replay(
        &file,
        &stats,
        &[
            "--camera-path",
            path.to_str().unwrap(),
            "-o",
            last.to_str().unwrap(),
        ],
    );
    assert_eq!(rows.len(), 3);
    let mesh = vds_import::load_file(&last, &Default::default()).unwrap();
    assert_eq!(mesh.stats.input_triangles, u64::from(triangles(&rows[2])));

    // Background loading, paced like a display. When pages arrive depends on what the
    // machine gives the loader's threads, so what is checked holds whatever the timing: the
    // flight needs more than the root's page from its first frame on, so each frame's pages
    // are resident or asked for, and every page loaded is resident or was evicted.
    let fly = replay(
        &file,
        &stats,
        &[
            "--fly",
            "--frames",
            "30",
            "--loading",
            "background",
            "--pace-ms",
            "20",
        ],
    );
    assert_eq!(fly.len(), 31);
    let number = |row: &Vec<String>, name: &str| row[at(name)].parse::<u64>().unwrap();
    for row in &fly[1..] {
        let (resident, asked) = (number(row, "pages_resident"), number(row, "pages_pending"));
        assert!(resident + asked > 1, "frame {}: no page asked for", row[0]);
    }
    for row in &fly[1..] {
        assert_eq!(
            number(row, "pages_loaded") - number(row, "pages_evicted"),
            number(row, "pages_resident"),
            "frame {}",
            row[0]
        );
    }

    // Adjusting by sweeps: the same orbit, every frame with triangles and nothing waiting;
    // it takes neither fold prevention nor test threads.
    let swept = replay(&file, &stats, &["--orbit", "--frames", "12", "--sweep"]);
    assert_eq!(swept.len(), 13);
    assert!(swept[1..].iter().all(|row| triangles(row) > 0));
    assert!(
        swept[1..]
            .iter()
            .all(|row| row[pending] == "0" && row[deferred] == "0")
    );
    for other in ["--prevent-folds", "--adjust-threads=2"] {
        let refused = vds_cut()
            .arg(&file)
            .args(["--orbit", "--threshold", "1", "--sweep", other])
            .output()
            .unwrap();
        assert_eq!(refused.status.code(), Some(2), "--sweep with {other}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn replay_refuses_an_unusable_camera_path_naming_it() {
    let dir = temp_dir("replay-bad");
    let mut scene = load("cow.obj");
    let file = dir.join("cow.vdt");
    std::fs::write(&file, vdt_bytes(&mut scene)).unwrap();
    let path = dir.join("bad-path.json");
    std::fs::write(
        &path,
        r#"{"cameras":[{"eye":[0,0,0],"target":[0,0,0],"up":[0,1,0],"fov_y_degrees":45,"width":320,"height":240,"near":0.01}]}"#,
    )
    .unwrap();
    let result = vds_cut()
        .arg(&file)
        .args(["--threshold", "1", "--camera-path"])
        .arg(&path)
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert_eq!(result.status.code(), Some(1), "{stderr}");
    assert!(
        stderr.contains("bad-path.json") && stderr.contains("camera 0"),
        "{stderr}"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_memory_budget_that_is_not_a_size_is_refused_naming_it() {
    let dir = temp_dir("budget-bad");
    let mut scene = load("cow.obj");
    let file = dir.join("cow.vdt");
    std::fs::write(&file, vdt_bytes(&mut scene)).unwrap();
    for bad in ["12parsecs", "-1MiB", "lots"] {
        let flag = format!("--memory-budget={bad}");
        let result = vds_cut()
            .arg(&file)
            .args(["--orbit", "--threshold", "1", &flag])
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{bad}: {stderr}");
        assert!(
            stderr.contains("--memory-budget") && stderr.contains(bad),
            "{stderr}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn a_single_camera_cut_under_a_tight_budget_fits_and_reports_the_raised_threshold() {
    let dir = temp_dir("budget-single");
    let mut scene = load("bunny.obj");
    let file = dir.join("bunny.vdt");
    std::fs::write(&file, vdt_bytes(&mut scene)).unwrap();
    let out = dir.join("cut.obj");
    let result = vds_cut()
        .arg(&file)
        .args([
            "--threshold",
            "0.5",
            "--memory-budget",
            "512KiB",
            "--json",
            "-o",
        ])
        .arg(&out)
        .output()
        .unwrap();
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    let report: serde_json::Value = serde_json::from_slice(&result.stdout).unwrap();
    let held = report["resident_bytes"].as_u64().unwrap();
    let effective = report["effective_threshold"].as_f64().unwrap();
    assert!(held <= 512 << 10, "{held} bytes held");
    assert!(
        effective > 0.5,
        "a 512 KiB budget held the bunny's 0.5 px cut"
    );
    // The cut meets the threshold it reports.
    let deviation = report["max_deviation_px"].as_f64().unwrap();
    assert!(
        deviation <= effective * (1.0 + 1e-4) + 1e-4,
        "{deviation} px > {effective} px"
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn every_corner_tracking_exports_the_same_cut_and_ranks_refuse_fold_prevention() {
    let dir = temp_dir("corners");
    let file = small_vdt(&dir);
    let mut exports = Vec::new();
    for corners in ["incidence", "lazy", "ranks"] {
        let out = dir.join(format!("{corners}.ply"));
        let result = vds_cut()
            .arg(&file)
            .arg("-o")
            .arg(&out)
            .args(["--threshold", "2", "--corners", corners])
            .output()
            .unwrap();
        assert!(
            result.status.success(),
            "{corners}: {}",
            String::from_utf8_lossy(&result.stderr)
        );
        exports.push(std::fs::read(&out).unwrap());
    }
    assert!(exports[0].len() > 1000, "the cut is not empty");
    assert!(
        exports.iter().all(|e| *e == exports[0]),
        "the exports differ"
    );
    let refused = dir.join("refused.ply");
    let result = vds_cut()
        .arg(&file)
        .arg("-o")
        .arg(&refused)
        .args(["--threshold", "2", "--corners", "ranks", "--prevent-folds"])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    let message = String::from_utf8_lossy(&result.stderr);
    assert!(message.contains("--prevent-folds"), "{message}");
    assert!(!refused.exists());
    std::fs::remove_dir_all(&dir).unwrap();
}
