//! The review options of the headless viewer on the bundled demo (the AS1 assembly, parts
//! named and coloured): `--pick` names the part under a pixel as a brute-force draw does,
//! `--hide`, `--isolate` and `--section` change what is picked, `--measure` snaps to original
//! vertices, and without a display the demo is rendered to a PNG.

use std::path::PathBuf;
use std::process::Command;

use serde_json::Value;

fn vds_view() -> Command {
    Command::new(env!("CARGO_BIN_EXE_vds-view"))
}

/// One frame of the demo from the first orbit camera at 320 × 240, with `extra` options;
/// the JSON lines it prints.
fn demo(extra: &[&str]) -> Vec<Value> {
    let result = vds_view()
        .args([
            "--headless",
            "--orbit",
            "--frames",
            "1",
            "--size",
            "320x240",
        ])
        .args(extra)
        .output()
        .unwrap();
    assert!(
        result.status.success(),
        "{extra:?}: {}",
        String::from_utf8_lossy(&result.stderr)
    );
    String::from_utf8(result.stdout)
        .unwrap()
        .lines()
        .filter(|l| l.starts_with('{'))
        .map(|l| serde_json::from_str(l).unwrap())
        .collect()
}

/// The part picked at `pixel` (none: background).
fn picked(pixel: &str, extra: &[&str]) -> Value {
    let mut options = vec!["--pick", pixel];
    options.extend_from_slice(extra);
    demo(&options)[0]["pick"].clone()
}

/// Pixels of the first orbit view that show some part.
const PIXELS: [&str; 5] = ["160,120", "150,118", "175,125", "140,122", "165,112"];

#[test]
fn the_demo_opens_with_its_parts_named() {
    let pick = picked("160,120", &[]);
    let name = pick["name"].as_str().expect("the centre shows a part");
    let path = pick["path"].as_str().unwrap();
    assert!(path.starts_with("as1/") && path.ends_with(name), "{pick}");
    assert!(!name.starts_with("solid_"), "{pick}");
    assert!(pick["triangles"].as_u64().unwrap() > 100, "{pick}");
    assert_eq!(pick["world"].as_array().unwrap().len(), 3);
}

#[test]
fn picks_name_the_part_a_brute_force_draw_shows_at_0_1_and_8_px() {
    for pixel in PIXELS {
        let truth = picked(pixel, &["--brute-force"]);
        for threshold in ["0", "1", "8"] {
            let got = picked(pixel, &["--threshold", threshold, "--no-backface"]);
            assert_eq!(
                got["part"], truth["part"],
                "pixel {pixel} at {threshold} px: {got} vs {truth}"
            );
        }
    }
}

#[test]
fn hidden_and_isolated_parts_change_what_is_picked() {
    let first = picked("160,120", &[]);
    let name = first["name"].as_str().unwrap().to_string();
    for threshold in ["0", "1", "8"] {
        let hidden = picked("160,120", &["--hide", &name, "--threshold", threshold]);
        assert_ne!(hidden["part"], first["part"], "{threshold} px: {hidden}");
        let isolated = picked("160,120", &["--isolate", &name, "--threshold", threshold]);
        assert_eq!(
            isolated["part"], first["part"],
            "{threshold} px: {isolated}"
        );
        // Isolating another part leaves this one unpickable.
        let other = if name == "plate" { "rod" } else { "plate" };
        let isolated = picked("160,120", &["--isolate", other, "--threshold", threshold]);
        assert!(
            isolated["part"].is_null() || isolated["name"] == other,
            "{threshold} px: {isolated}"
        );
    }
    // A glob that matches nothing is an error that names it.
    let result = vds_view()
        .args([
            "--headless",
            "--orbit",
            "--frames",
            "1",
            "--hide",
            "no-such-part*",
        ])
        .output()
        .unwrap();
    assert_eq!(result.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&result.stderr).contains("no-such-part*"));
}

#[test]
fn a_section_leaves_only_its_kept_side_pickable() {
    let first = picked("160,120", &[]);
    let world: Vec<f64> = first["world"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_f64().unwrap())
        .collect();
    let unsectioned: Vec<Value> = PIXELS.iter().map(|p| picked(p, &[])).collect();
    let mut changed = 0;
    // Planes through the picked point: what lies beyond is cut away.
    for (axis, sign) in [(0, 1.0), (1, -1.0), (2, 1.0)] {
        let mut normal = [0.0; 3];
        normal[axis] = sign;
        let d = -sign * world[axis] + 1e-3;
        let section = format!("{},{},{},{}", normal[0], normal[1], normal[2], d - 2e-3);
        for (pixel, before) in PIXELS.iter().zip(&unsectioned) {
            let pick = picked(pixel, &["--section", &section]);
            changed += usize::from(&pick != before);
            if let Some(w) = pick["world"].as_array() {
                let w: Vec<f64> = w.iter().map(|v| v.as_f64().unwrap()).collect();
                let side = sign * w[axis] + d - 2e-3;
                assert!(side <= 1e-3, "{section} at {pixel}: {pick}");
            }
        }
    }
    assert!(changed > 0, "no section changed any pick");
    for bad in ["0,0,0,1", "1,0,0", "1,0,0,nan", "a,b,c,d"] {
        let result = vds_view()
            .args(["--headless", "--orbit", "--frames", "1", "--section", bad])
            .output()
            .unwrap();
        assert_eq!(result.status.code(), Some(2), "{bad}");
        assert!(
            String::from_utf8_lossy(&result.stderr).contains("--section"),
            "{bad}"
        );
    }
}

/// The demo's original vertices.
fn demo_vertices() -> Vec<[f64; 3]> {
    let obj = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../testdata/as1_assembly.obj");
    std::fs::read_to_string(obj)
        .unwrap()
        .lines()
        .filter_map(|l| l.strip_prefix("v "))
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            [v[0], v[1], v[2]]
        })
        .collect()
}

#[test]
fn measurements_snap_to_original_vertices() {
    let vertices = demo_vertices();
    for threshold in ["0", "8"] {
        let out = demo(&["--measure", "150,118,175,125", "--threshold", threshold]);
        let measure = &out[0]["measure"];
        let snapped: Vec<[f64; 3]> = measure["snapped"]
            .as_array()
            .expect("both pixels show parts")
            .iter()
            .map(|p| {
                let p: Vec<f64> = p
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_f64().unwrap())
                    .collect();
                [p[0], p[1], p[2]]
            })
            .collect();
        let distance = |a: [f64; 3], b: [f64; 3]| {
            ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
        };
        for (end, pick) in snapped.iter().zip(measure["picks"].as_array().unwrap()) {
            // An original vertex (to the file's grid)...
            let nearest_original = vertices
                .iter()
                .map(|v| distance(*v, *end))
                .fold(f64::MAX, f64::min);
            assert!(nearest_original < 1e-2, "{end:?} is no vertex of the model");
            // ...and the nearest one to the picked point.
            let world: Vec<f64> = pick["world"]
                .as_array()
                .unwrap()
                .iter()
                .map(|v| v.as_f64().unwrap())
                .collect();
            let world = [world[0], world[1], world[2]];
            let best = vertices
                .iter()
                .map(|v| distance(*v, world))
                .fold(f64::MAX, f64::min);
            assert!(
                (distance(*end, world) - best).abs() < 1e-2,
                "{threshold} px: snapped {end:?} at {} from the pick, the nearest vertex at {best}",
                distance(*end, world)
            );
        }
        let expected = distance(snapped[0], snapped[1]);
        let got = measure["distance"].as_f64().unwrap();
        assert!(
            (got - expected).abs() < 1e-3 * expected.max(1.0),
            "{got} vs {expected}"
        );
        assert_eq!(measure["snap_exact"], true);
    }
}

#[test]
fn without_a_display_the_demo_is_rendered_to_a_png() {
    let dir = std::env::temp_dir().join(format!("vds-view-test-nodisplay-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let result = vds_view()
        .current_dir(&dir)
        .env_remove("DISPLAY")
        .env_remove("WAYLAND_DISPLAY")
        .args(["--size", "320x200"])
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&result.stdout);
    assert!(
        result.status.success(),
        "{}",
        String::from_utf8_lossy(&result.stderr)
    );
    let png = dir.join("vds-view-demo.png");
    assert!(stdout.contains(&png.display().to_string()), "{stdout}");
    assert!(stdout.contains("--headless"), "{stdout}");
    let image = vds_render::Image::read_png(&png).unwrap();
    assert_eq!((image.width, image.height), (320, 200));
    let background = &image.rgba[..4];
    let covered = image
        .rgba
        .chunks_exact(4)
        .filter(|p| p != &background)
        .count();
    assert!(covered > 5000, "the demo covers {covered} pixels");
    std::fs::remove_dir_all(&dir).unwrap();
}
