//! Fuzzes the sharded build's `.vdtpart` reader (whole, and skimmed for its head, as the
//! merge's first pass reads it) and the merge behind it: a part for a
//! one-shard plan of a small grid (with pages small enough that the part holds regions of
//! pages) is read from the input; one that reads is merged into a file. Any input must give an
//! error or a file, never a panic, hang or huge allocation.
//!
//! The body's checksum is checked once it has been read, so mutations reach the parser; the
//! unit test `shard::part_file::tests::damaged_bodies_with_valid_checksums_never_panic`
//! damages bodies behind valid checksums, which a fuzzer rarely makes.
#![no_main]

use std::sync::OnceLock;

use libfuzzer_sys::fuzz_target;
use vds_build::shard::{
    PartHead, Plan, PlanMetadata, merge, part_from_bytes, part_head_from_bytes, plan,
};

/// The plan every input is read against: one shard of a 16 × 16 grid of triangles, pages of
/// 256 bytes (regions of 64 leaves).
fn the_plan() -> &'static Plan {
    static PLAN: OnceLock<Plan> = OnceLock::new();
    PLAN.get_or_init(|| {
        let n = 16u32;
        let mut scene = vds_import::Scene::default();
        for y in 0..n {
            for x in 0..n {
                scene
                    .positions
                    .push([x as f32, y as f32, ((x + y) % 3) as f32]);
            }
        }
        for y in 0..n - 1 {
            for x in 0..n - 1 {
                let v = y * n + x;
                scene.triangles.push([v, v + 1, v + n]);
                scene.triangles.push([v + 1, v + n + 1, v + n]);
            }
        }
        scene.triangle_parts = vec![0; scene.triangles.len()];
        let grid = vds_build::snap_to_grid(&mut scene);
        plan(
            &scene.positions,
            scene.triangles.len() as u64,
            grid,
            1,
            PlanMetadata {
                page_bytes: 256,
                ..Default::default()
            },
        )
        .expect("a plan of a grid")
    })
}

fuzz_target!(|data: &[u8]| {
    let plan = the_plan();
    // The merge's first pass skims a part (its pages and leaves passed over); a part that
    // reads whole skims to its own head.
    let head = part_head_from_bytes(data, plan);
    let Ok(part) = part_from_bytes(data, plan) else {
        return;
    };
    assert!(head.is_ok_and(|head| head.same_head(&PartHead::of(&part))));
    let _ = merge(plan, vec![part]);
});
