//! Replays every input kept under `fuzz/regressions/<target>/` through what its importer fuzz
//! target runs (`fuzz/fuzz_targets/import_common.rs`, included here as is): read as the
//! target's format, welded both ways, the scene held to its invariants. An input a fuzzer once
//! crashed stays fixed in the ordinary suite, with no cargo-fuzz installed.
//!
//! Inputs that still crash wait in `fuzz/regressions/unfixed/` (not replayed) until the
//! importer is fixed; then they move into their target's folder.

use std::path::PathBuf;

use vds_import::Format;

#[path = "../../../fuzz/fuzz_targets/import_common.rs"]
mod import_common;

#[test]
fn importer_fuzz_regressions_give_errors_or_valid_scenes() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fuzz/regressions");
    let mut replayed = 0;
    let mut panicked = Vec::new();
    for (target, format) in [
        ("import_obj", Format::Obj),
        ("import_ply", Format::Ply),
        ("import_stl", Format::Stl),
        ("import_gltf", Format::Gltf),
    ] {
        let Ok(entries) = std::fs::read_dir(root.join(target)) else {
            continue;
        };
        let mut paths: Vec<PathBuf> = entries.map(|e| e.unwrap().path()).collect();
        paths.sort();
        for path in paths {
            let bytes = std::fs::read(&path).unwrap();
            replayed += 1;
            if std::panic::catch_unwind(|| import_common::import(&bytes, format)).is_err() {
                panicked.push(path.display().to_string());
            }
        }
    }
    assert!(
        replayed > 0,
        "no inputs under {}: the replay tests nothing",
        root.display()
    );
    assert!(panicked.is_empty(), "panicked on {panicked:?}");
}
