//! The threshold pass tests every active entry before it acts on any (and can test them on
//! several threads); the pass that tests and acts on one entry at a time is its reference.
//! Along camera paths whose groups reuse their tests, with the camera pausing now and then
//! (still passes), both must give the same cut on every adjust, whatever the number of
//! threads, and every boundary node must pass its test.

mod common;

use common::*;
use vds_runtime::{
    CameraPath, CornerTracking, Criteria, Decision, Frame, Goal, Judge, Runtime, Viewpoint,
};

/// How a path is played.
struct Play<'a> {
    name: &'a str,
    bytes: &'a [u8],
    tracking: CornerTracking,
    criteria: Criteria,
    /// Thresholds taken in turn, 30 frames each, so that a change of threshold starts a new
    /// generation of reused tests now and then.
    t: [f32; 2],
}

/// What a play went through, summed over its adjusts.
#[derive(Default)]
struct Seen {
    reused: [u64; 3],
    failed: u64,
    changes: u64,
    most_active: u32,
}

/// Plays `path` through the one-step reference and through the two-step pass on 1 and 3
/// threads, adjusting each seventh camera three times (the camera pausing), and checks after
/// every adjust that all three have the same boundary and made the same changes, and that
/// every boundary node passes its test.
fn same_cuts(play: &Play, path: &CameraPath) -> Seen {
    let Play {
        name,
        bytes,
        tracking,
        criteria,
        t,
    } = *play;
    let mut runtimes: Vec<Runtime> = [0, 1, 3]
        .into_iter()
        .map(|threads| {
            let mut runtime = runtime(bytes, tracking);
            match threads {
                0 => runtime.set_one_step_pass(true),
                n => runtime.set_adjust_threads(n),
            }
            runtime
        })
        .collect();
    let mut seen = Seen::default();
    for (frame, camera) in path.cameras.iter().enumerate() {
        let t = t[frame / 30 % 2];
        let (view, goal) = (Viewpoint::Camera(*camera), Goal::Threshold(t));
        for pause in 0..if frame % 7 == 3 { 3 } else { 1 } {
            let frames: Vec<Frame> = runtimes
                .iter_mut()
                .map(|runtime| runtime.adjust(&view, &criteria, goal).unwrap())
                .collect();
            let what = format!("{name} frame {frame} adjust {pause}");
            let expected = &frames[0].stats;
            for (k, got) in frames.iter().enumerate().skip(1) {
                let counts = |s: &vds_runtime::AdjustStats| {
                    (s.unfolds, s.folds, s.refused_folds, s.deferred_unfolds)
                };
                assert_eq!(
                    counts(&got.stats),
                    counts(expected),
                    "{what}, two-step pass {k}: other changes"
                );
                assert!(
                    runtimes[k].cut().boundary() == runtimes[0].cut().boundary(),
                    "{what}, two-step pass {k}: another cut"
                );
            }
            for (k, frame) in frames.iter().enumerate() {
                seen.reused[k] += u64::from(frame.stats.groups_reused);
            }
            seen.failed += u64::from(expected.groups_failed);
            seen.changes += u64::from(expected.unfolds + expected.folds);
        }
        let cut = runtimes[0].cut();
        seen.most_active = seen.most_active.max(cut.active_node_count());
        // The threshold guarantee, node by node: reused records that were wrong would show
        // here even if both passes shared them.
        let judge = Judge::new(&view, &criteria);
        for id in cut.boundary() {
            let node = cut.store().tested(id);
            assert!(
                node.hot.child_count == 0 || judge.decide(node, t) != Decision::Unfold,
                "{name} frame {frame}: boundary node {id} needs unfolding"
            );
        }
    }
    for runtime in &mut runtimes {
        runtime.cut_mut().check().unwrap();
    }
    // The paths exercise what the two steps must agree on: reused tests (in every runtime),
    // groups whose children are tested one by one, and folds and unfolds.
    assert!(
        seen.reused.iter().all(|&r| r > 0) && seen.failed > 0 && seen.changes > 0,
        "{name}: {:?} reused, {} failed groups, {} changes",
        seen.reused,
        seen.failed,
        seen.changes
    );
    seen
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
                let other = [2.0, 0.5, 4.0][k];
                let mut play = Play {
                    name,
                    bytes: &bytes,
                    tracking,
                    criteria: Criteria::default(),
                    t: [1.0, other],
                };
                same_cuts(
                    &play,
                    &CameraPath::fly_through(center, radius * distance, 60, 480, 320),
                );
                play.t = [other, 1.0];
                same_cuts(
                    &play,
                    &CameraPath::orbit(center, radius * distance, 60, 640, 480),
                );
            }
        }
    }
}

/// Mesh-fold prevention refuses folds that a later fold or unfold of the same pass can make
/// possible, which depends on the order of everything the pass does: the pass then runs one
/// step at a time, as the reference does.
#[test]
fn with_mesh_fold_prevention_the_pass_is_the_one_step_pass() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let play = Play {
        name: "bunny.obj, preventing mesh folds",
        bytes: &bytes,
        tracking: CornerTracking::Incidence,
        criteria: Criteria {
            prevent_mesh_folds: true,
            ..Criteria::default()
        },
        t: [1.0, 3.0],
    };
    same_cuts(
        &play,
        &CameraPath::fly_through(center, radius * 1.5, 60, 480, 320),
    );
}

/// A scene whose cut is large enough that the entries are tested on several threads.
#[test]
fn the_two_step_pass_on_several_threads_gives_the_one_step_cut() {
    let (bytes, center, radius) = generated(300_000);
    let play = Play {
        name: "generated",
        bytes: &bytes,
        tracking: CornerTracking::Ranks,
        criteria: Criteria::default(),
        t: [0.25, 0.15],
    };
    let seen = same_cuts(
        &play,
        &CameraPath::fly_through(center, radius, 90, 1920, 1080),
    );
    assert!(
        seen.most_active > 3 * 4096,
        "{} active nodes at most: too few to be tested on three threads",
        seen.most_active
    );
}
