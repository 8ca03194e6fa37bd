//! The threshold pass tests every active entry before it acts on any (and can test them on
//! several threads); the pass that tests and acts on one entry at a time is its reference.
//! Along camera paths whose groups reuse their tests, both must give the same cut on every
//! frame, whatever the number of threads.

mod common;

use common::*;
use vds_runtime::{CameraPath, CornerTracking, Criteria, Goal, Runtime, Viewpoint};

/// Plays `paths` at thresholds `t` (30 frames each in turn) through the one-step reference
/// and through the two-step pass on 1 and 3 threads, and checks that every frame leaves all
/// three with the same boundary. Returns the most active nodes a frame had.
fn same_cuts(
    name: &str,
    bytes: &[u8],
    tracking: CornerTracking,
    paths: &[CameraPath],
    t: [f32; 2],
) -> u32 {
    let mut reference = runtime(bytes, tracking);
    reference.set_one_step_pass(true);
    let mut runtimes: Vec<Runtime> = [1, 3]
        .into_iter()
        .map(|threads| {
            let mut runtime = runtime(bytes, tracking);
            runtime.set_adjust_threads(threads);
            runtime
        })
        .collect();
    let (mut reused, mut failed, mut changes) = (0u64, 0u64, 0u64);
    let mut most_active = 0;
    for (p, path) in paths.iter().enumerate() {
        for (frame, camera) in path.cameras.iter().enumerate() {
            // Two thresholds, so that a frame's change of threshold starts a new generation
            // of reused tests now and then.
            let t = t[frame / 30 % 2];
            let (view, goal) = (Viewpoint::Camera(*camera), Goal::Threshold(t));
            let criteria = Criteria::default();
            let expected = reference.adjust(&view, &criteria, goal).unwrap();
            reused += u64::from(expected.stats.groups_reused);
            failed += u64::from(expected.stats.groups_failed);
            changes += u64::from(expected.stats.folds + expected.stats.unfolds);
            most_active = most_active.max(reference.cut().active_node_count());
            for runtime in &mut runtimes {
                let threads = runtime.adjust_threads();
                let got = runtime.adjust(&view, &criteria, goal).unwrap();
                assert_eq!(
                    (got.stats.unfolds, got.stats.folds),
                    (expected.stats.unfolds, expected.stats.folds),
                    "{name} path {p} frame {frame}, {threads} threads: other changes"
                );
                assert!(
                    runtime.cut().boundary() == reference.cut().boundary(),
                    "{name} path {p} frame {frame}, {threads} threads: another cut"
                );
            }
        }
    }
    for runtime in &mut runtimes {
        runtime.cut_mut().check().unwrap();
    }
    // The paths exercise what the two steps must agree on: reused tests, groups whose
    // children are tested one by one, and folds and unfolds on most frames.
    assert!(
        reused > 0 && failed > 0 && changes > 0,
        "{name}: {reused} reused, {failed} failed groups, {changes} changes"
    );
    most_active
}

#[test]
fn the_two_step_pass_gives_the_one_step_cut_on_every_frame() {
    for name in ["bunny.obj", "as1_assembly.obj"] {
        let mut scene = load(name);
        let bytes = vdt_bytes(&mut scene);
        let (center, radius) = bounds(&scene.positions);
        for tracking in [CornerTracking::Incidence, CornerTracking::Ranks] {
            for (k, distance) in [1.2f32, 1.5, 2.0].into_iter().enumerate() {
                // Each path from a fresh cut: what a frame must act on depends on the cut
                // the frames before left.
                let fly = CameraPath::fly_through(center, radius * distance, 60, 480, 320);
                same_cuts(name, &bytes, tracking, &[fly], [1.0, [2.0, 0.5, 4.0][k]]);
                let orbit = CameraPath::orbit(center, radius * distance, 60, 640, 480);
                same_cuts(name, &bytes, tracking, &[orbit], [[2.0, 0.5, 4.0][k], 1.0]);
            }
        }
    }
}

/// A scene whose cut is large enough that the entries are tested on several threads.
#[test]
fn the_two_step_pass_on_several_threads_gives_the_one_step_cut() {
    let (bytes, center, radius) = generated(300_000);
    let path = CameraPath::fly_through(center, radius, 90, 1920, 1080);
    let most_active = same_cuts(
        "generated",
        &bytes,
        CornerTracking::Ranks,
        &[path],
        [0.25, 0.15],
    );
    assert!(
        most_active > 3 * 4096,
        "{most_active} active nodes at most: too few to be tested on three threads"
    );
}
