//! Same-winding repeats: no cut draws two triangles with the same three current corners in the
//! same winding, a budget counts each such class once, and the journal a renderer replays
//! draws the same set, along random camera paths and budgets, for every builder and both
//! corner-tracking strategies.

mod common;

use std::collections::HashSet;

use common::*;
use vds_runtime::{
    ActiveTriangle, CornerTracking, Criteria, FrustumMode, Goal, Runtime, Viewpoint,
};

/// `corners` rotated to start at the smallest node id: equal for repeats, different for a
/// triangle and its reverse.
fn class(corners: [u32; 3]) -> [u32; 3] {
    let k = (0..3).min_by_key(|&k| corners[k]).unwrap();
    [corners[k], corners[(k + 1) % 3], corners[(k + 2) % 3]]
}

fn replay(mirror: &mut Vec<Option<ActiveTriangle>>, runtime: &mut Runtime, dirty: &[u32]) {
    let cut = runtime.cut_mut();
    mirror.resize(cut.slot_count() as usize, None);
    for &slot in dirty {
        mirror[slot as usize] = cut.slot(slot);
    }
    mirror.truncate(cut.slot_count() as usize);
}

#[test]
fn no_cut_draws_a_repeat_and_budgets_count_each_class_once() {
    let mut hidden_by_octree = 0u64;
    for name in ["bunny.obj", "as1_assembly.obj", "airplane.obj"] {
        for builder in BUILDERS {
            let mut scene = load(name);
            let bytes = vdt_bytes_by(&mut scene, builder);
            let (center, radius) = bounds(&scene.positions);
            for tracking in [
                CornerTracking::Incidence,
                CornerTracking::Lazy,
                CornerTracking::Ranks,
            ] {
                let what = format!("{name}, {} builder, {tracking:?}", builder.name());
                let mut runtime = runtime(&bytes, tracking);
                let mut mirror = Vec::new();
                let mut rng = Rng(11);
                let mut camera = random_camera(&mut rng, center, radius);
                for step in 0..48u32 {
                    next_camera(&mut rng, &mut camera, (step, 8), (center, radius), 0.08);
                    let (viewpoint, goal) = match step % 6 {
                        0 | 1 => (Viewpoint::Camera(camera), Goal::Threshold(1.5)),
                        2 => (Viewpoint::Camera(camera), Goal::Threshold(8.0)),
                        3 | 4 => (Viewpoint::Camera(camera), Goal::Budget(300 + 97 * step)),
                        _ => (Viewpoint::Independent, Goal::Budget(200 + 61 * step)),
                    };
                    let criteria = Criteria {
                        frustum: [FrustumMode::Fold, FrustumMode::Ignore][step as usize % 2],
                        ..Criteria::default()
                    };
                    let frame = runtime.adjust(&viewpoint, &criteria, goal).unwrap();
                    runtime.cut_mut().check().unwrap();
                    replay(&mut mirror, &mut runtime, &frame.changes.dirty_slots);

                    let drawn = runtime.cut_mut().active_triangles();
                    let mut seen = HashSet::new();
                    for t in &drawn {
                        assert!(
                            seen.insert(class(t.corners)),
                            "{what} step {step}: triangle {} repeats corners {:?}",
                            t.triangle,
                            t.corners
                        );
                    }
                    let count = runtime.cut().active_triangle_count();
                    assert_eq!(count as usize, drawn.len(), "{what} step {step}");
                    if let Goal::Budget(budget) = goal {
                        assert!(count <= budget, "{what} step {step}: {count} > {budget}");
                    }
                    // Rank tracking has no slots to mirror (`tests/ranks.rs` mirrors its
                    // node changes).
                    if tracking != CornerTracking::Ranks {
                        let mut mirrored: Vec<_> = mirror.iter().flatten().copied().collect();
                        let mut drawn = drawn;
                        mirrored.sort_unstable();
                        drawn.sort_unstable();
                        assert!(
                            mirrored == drawn,
                            "{what} step {step}: a renderer's mirror draws another set"
                        );
                    }
                    let with_repeats = runtime.cut().active_triangle_count_with_repeats();
                    if builder == vds_build::Builder::Octree {
                        hidden_by_octree += u64::from(with_repeats - count);
                    }
                }
            }
        }
    }
    // The octree's cuts do hold repeats (tens in a cut of the bunny), so the checks above had
    // something to catch.
    assert!(hidden_by_octree > 0, "no repeat was ever hidden");
}
