//! What every importer target does with its input: read it as one format through the public
//! `vds_import::read_bytes`, weld the soup (exactly, and with a tolerance), and hold the scene
//! to what the builder relies on. Included by each `import_*` target (`#[path]` module).
//!
//! Any input must give an error or a valid scene: never a panic, overflow, hang or an
//! allocation out of proportion to the input.

use vds_import::{Format, MeshSoup, Scene, Weld};

/// Reads `data` as `format`, welds it both ways and checks each scene.
pub fn import(data: &[u8], format: Format) {
    let mut soup = MeshSoup::default();
    if vds_import::read_bytes(data, format, "fuzzed", &mut soup).is_err() {
        return;
    }
    check(&vds_import::weld(soup.clone(), Weld::Exact));
    check(&vds_import::weld(soup, Weld::Relative(1e-3)));
}

/// The scene invariants `vds_import::Scene` documents and the builder indexes by: corners in
/// range and distinct, one part per triangle, parts named, part records valid, positions
/// finite, every position used.
fn check(scene: &Scene) {
    assert_eq!(scene.triangles.len(), scene.triangle_parts.len());
    let mut used = vec![false; scene.positions.len()];
    for (t, &[a, b, c]) in scene.triangles.iter().enumerate() {
        assert!(a != b && b != c && a != c, "triangle {t} repeats a corner");
        for v in [a, b, c] {
            *used.get_mut(v as usize).expect("corner in range") = true;
        }
    }
    assert!(used.iter().all(|&u| u), "an unused position");
    for &part in &scene.triangle_parts {
        assert!(
            (part as usize) < scene.part_names.len(),
            "part {part} has no name"
        );
    }
    assert!(
        scene.positions.iter().flatten().all(|c| c.is_finite()),
        "a position is not finite"
    );
    // What the .vdt writer requires of the part records: one per name, parents earlier,
    // colours within 0..=1.
    assert_eq!(scene.parts.len(), scene.part_names.len());
    for (i, part) in scene.parts.iter().enumerate() {
        assert!(
            part.parent.is_none_or(|p| (p as usize) < i),
            "part {i}'s parent"
        );
        assert!(
            part.color
                .is_none_or(|c| c.iter().all(|v| (0.0..=1.0).contains(v))),
            "part {i}'s colour"
        );
    }
}
