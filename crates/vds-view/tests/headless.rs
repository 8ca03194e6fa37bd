//! The headless viewer on the software adapter: the files it promises, asynchronous frames
//! that are always complete cuts across a camera jump, and clear failures.

use std::path::PathBuf;
use std::process::Command;

use vds_runtime::{Camera, CameraPath};

fn vds_view() -> Command {
    Command::new(env!("CARGO_BIN_EXE_vds-view"))
}

/// Fails the test with the process's error output unless it succeeded.
fn assert_succeeded(result: &std::process::Output) {
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vds-view-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

#[test]
fn headless_orbit_writes_every_frame_and_a_row_per_frame() {
    let dir = temp_dir("orbit");
    let result = vds_view()
        .args([
            "--headless",
            "--orbit",
            "--frames",
            "5",
            "--size",
            "200x150",
        ])
        .arg("--out")
        .arg(dir.join("frames"))
        .arg("--stats")
        .arg(dir.join("stats.csv"))
        .output()
        .unwrap();
    assert_succeeded(&result);
    for frame in 0..5 {
        let png = dir.join(format!("frames/frame-{frame:05}.png"));
        let image = vds_render::Image::read_png(&png).unwrap();
        assert_eq!((image.width, image.height), (200, 150));
        let background = &image.rgba[..4];
        assert!(
            image
                .rgba
                .chunks_exact(4)
                .filter(|p| p != &background)
                .count()
                > 1000,
            "frame {frame} shows nothing"
        );
    }
    let csv = std::fs::read_to_string(dir.join("stats.csv")).unwrap();
    let lines: Vec<&str> = csv.lines().collect();
    assert_eq!(lines.len(), 6);
    let header: Vec<&str> = lines[0].split(',').collect();
    for column in [
        "frame",
        "adjust_ms",
        "upload_bytes",
        "gpu_ms",
        "cpu_frame_ms",
        "active_triangles",
        "added",
        "removed",
        "changed",
    ] {
        assert!(header.contains(&column), "missing column {column}");
    }
    let active = header
        .iter()
        .position(|c| *c == "active_triangles")
        .unwrap();
    for line in &lines[1..] {
        let fields: Vec<&str> = line.split(',').collect();
        assert_eq!(fields.len(), header.len());
        assert!(fields[active].parse::<u32>().unwrap() > 0);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn asynchronous_frames_are_complete_cuts_across_a_camera_jump() {
    let dir = temp_dir("async");
    // The demo assembly is centred near (90, 74, 38) with a bounding radius near 190: orbit
    // it from afar, jump close in, then back out.
    let center = [90.0, 74.0, 38.0];
    let far = CameraPath::orbit(center, 200.0, 12, 240, 180);
    let near = CameraPath::orbit(center, 25.0, 12, 240, 180);
    let mut cameras: Vec<Camera> = far.cameras.clone();
    cameras.extend(near.cameras.iter().copied());
    cameras.extend(far.cameras.iter().copied());
    let path = dir.join("path.json");
    std::fs::write(
        &path,
        serde_json::to_string(&CameraPath { cameras }).unwrap(),
    )
    .unwrap();
    let result = vds_view()
        .args(["--headless", "--async", "--verify", "--threshold", "0.5"])
        .arg("--camera-path")
        .arg(&path)
        .arg("--stats")
        .arg(dir.join("stats.csv"))
        .output()
        .unwrap();
    // --verify makes the run fail if any frame drew a state that is not exactly the cut after
    // one complete adjust (checked against that adjust's fingerprint) or any cut is
    // inconsistent.
    assert_succeeded(&result);
    let csv = std::fs::read_to_string(dir.join("stats.csv")).unwrap();
    assert_eq!(csv.lines().count(), 37);
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn failures_are_named() {
    let dir = temp_dir("fail");

    let bad = dir.join("bad.json");
    std::fs::write(&bad, "{\"cameras\": 3}").unwrap();
    let result = vds_view()
        .args(["--headless"])
        .arg("--camera-path")
        .arg(&bad)
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&result.stderr).contains("bad.json"));

    let result = vds_view()
        .arg(dir.join("missing.vdt"))
        .arg("--headless")
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&result.stderr).contains("missing.vdt"));
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn view_rejects_nan_and_out_of_range_numbers_naming_the_option() {
    for (option, value) in [
        ("--threshold", "nan"),
        ("--threshold", "-1"),
        ("--budget", "0"),
        ("--frames", "0"),
        ("--frames", "100000000"),
        ("--path-frames", "0"),
        ("--gaze-falloff", "inf"),
        ("--size", "0x10"),
    ] {
        let result = vds_view()
            .args(["--headless", "--orbit", &format!("{option}={value}")])
            .output()
            .unwrap();
        let message = String::from_utf8_lossy(&result.stderr);
        assert_eq!(result.status.code(), Some(2), "{option} {value}: {message}");
        assert!(message.contains(option), "{option} {value}: {message}");
    }
}

#[test]
fn view_names_the_file_that_is_not_a_vdt() {
    let dir = temp_dir("magic");
    let garbage = dir.join("garbage.vdt");
    std::fs::write(&garbage, vec![0u8; 4096]).unwrap();
    let result = vds_view()
        .arg(&garbage)
        .args(["--headless", "--orbit", "--frames", "1"])
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

#[test]
fn headless_background_loading_reports_pages_and_keeps_every_frame_a_whole_cut() {
    let dir = temp_dir("background");
    // The bunny in small pages, so that the flight needs many.
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bunny.obj");
    let mut scene = vds_import::load_file(&shared, &Default::default()).unwrap();
    let options = vds_format::WriteOptions {
        zstd_level: 1,
        page_bytes: 4096,
    };
    let bytes = vds_build::encode_scene(&mut scene, "test", &options).unwrap();
    let file = dir.join("bunny.vdt");
    std::fs::write(&file, bytes).unwrap();
    let pages = vds_format::VdtFile::open(&file).unwrap().directory().len();
    let result = vds_view()
        .arg(&file)
        .args([
            "--headless",
            "--fly",
            "--frames",
            "20",
            "--size",
            "160x120",
            "--loading",
            "background",
            "--verify",
        ])
        .arg("--stats")
        .arg(dir.join("stats.csv"))
        .output()
        .unwrap();
    assert_succeeded(&result);
    let csv = std::fs::read_to_string(dir.join("stats.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), 21);
    let column = |name: &str| rows[0].iter().position(|c| *c == name).unwrap();
    let number = |row: &[&str], name: &str| -> u64 { row[column(name)].parse().unwrap() };
    // When pages arrive depends on how the system schedules the loader's threads (a loaded
    // machine may run all twenty frames before the first page is decoded), so what is
    // checked holds whatever the timing: the flight needs more than the root's page from
    // its first frame on, so every frame's pages are resident or asked for, and pages are
    // counted consistently.
    for row in &rows[1..] {
        let (resident, pending) = (number(row, "pages_resident"), number(row, "pages_pending"));
        assert!(
            resident + pending > 1 && resident as usize <= pages,
            "frame {}: {resident} of {pages} pages resident, {pending} asked for",
            row[0]
        );
        let (loaded, evicted) = (number(row, "pages_loaded"), number(row, "pages_evicted"));
        assert_eq!(loaded - evicted, resident, "frame {}", row[0]);
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn headless_memory_budget_holds_evicts_and_keeps_the_mirror_whole() {
    let dir = temp_dir("budget");
    let shared = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared/data/bunny.obj");
    let mut scene = vds_import::load_file(&shared, &Default::default()).unwrap();
    let options = vds_format::WriteOptions {
        zstd_level: 1,
        page_bytes: 4096,
    };
    let bytes = vds_build::encode_scene(&mut scene, "test", &options).unwrap();
    let file = dir.join("bunny.vdt");
    std::fs::write(&file, bytes).unwrap();
    let budget: u64 = 1 << 20;
    let result = vds_view()
        .arg(&file)
        .args(["--headless", "--fly", "--frames", "40", "--size", "320x240"])
        .args(["--memory-budget", "1MiB", "--verify", "--stats"])
        .arg(dir.join("stats.csv"))
        .output()
        .unwrap();
    assert_succeeded(&result);
    let csv = std::fs::read_to_string(dir.join("stats.csv")).unwrap();
    let rows: Vec<Vec<&str>> = csv.lines().map(|l| l.split(',').collect()).collect();
    let column = |name: &str| rows[0].iter().position(|c| *c == name).unwrap();
    let (held, evicted, threshold) = (
        column("resident_bytes"),
        column("pages_evicted"),
        column("effective_threshold"),
    );
    for row in &rows[1..] {
        let bytes: u64 = row[held].parse().unwrap();
        assert!(
            bytes <= budget,
            "{bytes} bytes held over a budget of {budget}"
        );
        assert!(row[threshold].parse::<f32>().unwrap() >= 1.0);
    }
    let evicted: u64 = rows.last().unwrap()[evicted].parse().unwrap();
    assert!(evicted > 0, "a 1 MiB budget evicted nothing");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn adjusting_by_sweeps_draws_what_the_incremental_pass_draws() {
    let dir = temp_dir("sweep");
    let render = |name: &str, extra: &[&str]| {
        let result = vds_view()
            .args([
                "--headless",
                "--orbit",
                "--frames",
                "6",
                "--size",
                "200x150",
            ])
            .args(extra)
            .arg("--out")
            .arg(dir.join(name))
            .output()
            .unwrap();
        assert_succeeded(&result);
        (0..6)
            .map(|frame| {
                vds_render::Image::read_png(&dir.join(format!("{name}/frame-{frame:05}.png")))
                    .unwrap()
            })
            .collect::<Vec<_>>()
    };
    let incremental = render("incremental", &[]);
    let swept = render("swept", &["--sweep"]);
    for (frame, (a, b)) in incremental.iter().zip(&swept).enumerate() {
        // The two cuts may differ in a node whose parent passes while it fails (the sweep
        // folds the parent at once), so a few pixels may; a broken mirror would show far
        // more.
        let differing = a
            .rgba
            .chunks_exact(4)
            .zip(b.rgba.chunks_exact(4))
            .filter(|(p, q)| p != q)
            .count();
        assert!(
            differing * 200 < a.rgba.len() / 4,
            "frame {frame}: {differing} pixels differ"
        );
        let background = &b.rgba[..4];
        assert!(
            b.rgba.chunks_exact(4).filter(|p| p != &background).count() > 1000,
            "frame {frame} shows nothing"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
