//! Part records through a `.vdt` file: written by the builder, read back, refused when they
//! lie, and shown by `vds-info`.

use std::path::{Path, PathBuf};
use std::process::Command;

use vds_format::{VdtError, VdtFile};
use vds_import::{PartInfo, Scene};

/// Two triangles of `Bolt` under `Block`, one of `Nut` at the top, `Block` without its own.
fn assembly() -> Scene {
    Scene {
        positions: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 1.0, 0.5],
            [2.0, 0.0, 0.0],
        ],
        triangles: vec![[0, 1, 2], [1, 3, 2], [1, 4, 3]],
        triangle_parts: vec![1, 1, 2],
        part_names: vec!["Block".into(), "Bolt".into(), "Nut".into()],
        parts: vec![
            PartInfo::default(),
            PartInfo {
                parent: Some(0),
                color: Some([0.25, 0.5, 0.75, 1.0]),
            },
            PartInfo {
                parent: None,
                color: Some([1.0, 0.0, 0.0, 0.5]),
            },
        ],
        stats: vds_import::ImportStats {
            input_vertices: 5,
            input_triangles: 3,
            ..Default::default()
        },
        warnings: Vec::new(),
    }
}

fn encoded() -> Vec<u8> {
    vds_build::encode_scene(&mut assembly(), "test", &Default::default()).unwrap()
}

#[test]
fn part_records_round_trip_through_a_file() {
    let file = VdtFile::from_bytes(encoded()).unwrap();
    let m = file.metadata();
    assert_eq!(m.part_names, ["Block", "Bolt", "Nut"]);
    let parents: Vec<u32> = m.parts.iter().map(|p| p.parent).collect();
    assert_eq!(parents, [vds_format::NO_PART, 0, vds_format::NO_PART]);
    assert_eq!(m.part_color(1), Some([0.25, 0.5, 0.75, 1.0]));
    assert_eq!(m.part_color(0), None);
    let triangles: Vec<u64> = m.parts.iter().map(|p| p.triangles).collect();
    assert_eq!(triangles, [0, 2, 1]);
    assert_eq!(m.part_path(1), "Block/Bolt");
    vds_build::verify_file(&file).unwrap();
}

#[test]
fn part_records_are_deterministic() {
    assert_eq!(encoded(), encoded());
}

#[test]
fn writer_refuses_part_records_a_reader_would_refuse() {
    let mut scene = assembly();
    let grid = vds_build::snap_to_grid(&mut scene);
    let tree = vds_build::build_tree(&scene);
    let mut parts = vds_build::part_records(&scene);
    parts[0].parent = 2; // after its child: a cycle is possible
    let metadata = vds_format::Metadata {
        part_names: scene.part_names.clone(),
        parts,
        degree_histogram: tree.degree_histogram(),
        ..Default::default()
    };
    let content = vds_build::tree_content(&tree, &scene, metadata, grid);
    let error = vds_format::encode(&content, &Default::default()).unwrap_err();
    assert!(error.to_string().contains("part 0: parent 2"), "{error}");
}

#[test]
fn version_5_files_are_refused_naming_both_versions() {
    let mut bytes = encoded();
    bytes[8..12].copy_from_slice(&5u32.to_le_bytes());
    let sum = xxhash_rust::xxh3::xxh3_64(&bytes[..120]);
    bytes[120..128].copy_from_slice(&sum.to_le_bytes());
    let error = VdtFile::from_bytes(bytes).err().unwrap();
    assert!(
        matches!(
            error,
            VdtError::Version {
                got: 5,
                expected: 6,
                oldest: 6
            }
        ),
        "{error}"
    );
    let message = error.to_string();
    assert!(
        message.contains("version 5") && message.contains("version 6 only"),
        "{message}"
    );
}

#[test]
fn verify_holds_part_triangle_counts_to_the_pages() {
    let file = VdtFile::from_bytes(encoded()).unwrap();
    let mut figures = vds_format::TreeFigures::of_file(&file).unwrap();
    file.check_figures(&figures).unwrap();
    figures.part_triangles[1] -= 1;
    figures.part_triangles[2] += 1;
    match file.check_figures(&figures) {
        Err(VdtError::Misstated {
            field: vds_format::StatedField::PartTriangles(1),
            stated: 2,
            counted: 1,
        }) => {}
        other => panic!("{other:?}"),
    }
}

fn temp_dir(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("vds-parts-cli-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

fn info(file: &Path, flag: &str) -> String {
    let run = Command::new(env!("CARGO_BIN_EXE_vds-info"))
        .arg(file)
        .arg(flag)
        .output()
        .unwrap();
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    String::from_utf8(run.stdout).unwrap()
}

#[test]
fn vds_info_lists_parts_in_json_and_as_a_tree() {
    let dir = temp_dir("info");
    let file = dir.join("assembly.vdt");
    std::fs::write(&file, encoded()).unwrap();
    let json: serde_json::Value = serde_json::from_str(&info(&file, "--json")).unwrap();
    let parts = json["part_list"].as_array().unwrap();
    assert_eq!(parts.len(), 3);
    assert_eq!(parts[1]["name"], "Bolt");
    assert_eq!(parts[1]["path"], "Block/Bolt");
    assert_eq!(parts[1]["parent"], 0);
    assert_eq!(parts[1]["triangles"], 2);
    assert_eq!(parts[1]["color"], serde_json::json!([0.25, 0.5, 0.75, 1.0]));
    assert_eq!(parts[0]["color"], serde_json::Value::Null);
    assert_eq!(parts[0]["parent"], serde_json::Value::Null);
    let text = info(&file, "--parts");
    let tree: Vec<&str> = text
        .lines()
        .skip_while(|l| *l != "parts:")
        .skip(1)
        .collect();
    assert_eq!(
        tree,
        [
            "  Block  (0 triangles)",
            "    Bolt  (2 triangles, colour #4080bfff)",
            "  Nut  (1 triangles, colour #ff000080)",
        ]
    );
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn vds_info_counts_part_triangles_of_a_file_without_part_records() {
    let mut scene = assembly();
    scene.parts.clear();
    let grid = vds_build::snap_to_grid(&mut scene);
    let tree = vds_build::build_tree(&scene);
    let metadata = vds_format::Metadata {
        part_names: scene.part_names.clone(),
        degree_histogram: tree.degree_histogram(),
        ..Default::default()
    };
    let content = vds_build::tree_content(&tree, &scene, metadata, grid);
    let (bytes, _) = vds_format::encode(&content, &Default::default()).unwrap();
    let dir = temp_dir("no-records");
    let file = dir.join("names.vdt");
    std::fs::write(&file, bytes).unwrap();
    let json: serde_json::Value = serde_json::from_str(&info(&file, "--json")).unwrap();
    let counts: Vec<u64> = json["part_list"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| p["triangles"].as_u64().unwrap())
        .collect();
    assert_eq!(counts, [0, 2, 1]);
    std::fs::remove_dir_all(&dir).unwrap();
}
