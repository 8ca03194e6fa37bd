//! The sweep (`vds_runtime::sweep`) against the obvious evaluation of the same cut: a
//! recursion from the root that unfolds a node when the criteria ask for it. Along camera
//! paths with jumps, thresholds and every frustum mode, the sweep's active nodes are the
//! recursion's (on one, two and three threads), its lists of changes are the differences
//! of consecutive cuts, and those lists, applied to a runtime's cut by its own fold and
//! unfold, give a cut that passes the cut's consistency check and the screen-space
//! guarantee, and whose change report the sweep's own report from its bits
//! (`Sweep::report`) matches.

mod common;

use std::collections::BTreeSet;

use common::*;
use vds_runtime::sweep::{Sweep, SweepStats};
use vds_runtime::{
    CameraPath, Changes, CornerTracking, Criteria, Decision, FrustumMode, Goal, Judge, Loading,
    NodeStore, Runtime, Viewpoint, measure,
};

/// As in `cut.rs`: room for the rounding of a bound computed in `f32` against a projection
/// in `f64`.
fn slack(t: f32) -> f64 {
    f64::from(t) * 1e-4 + 1e-4
}

/// The cut the criteria give, by recursion from the root: a node with children is active
/// when the criteria unfold it (or keep it, and it was active in `before`) and its parent is.
fn recursive_cut(
    store: &NodeStore,
    judge: &Judge,
    t: f32,
    before: &BTreeSet<u32>,
) -> BTreeSet<u32> {
    let mut active = BTreeSet::new();
    let mut stack = vec![0u32];
    while let Some(id) = stack.pop() {
        let node = store.node(id);
        if node.is_leaf() {
            continue;
        }
        let unfold = match judge.decide(store.tested(id), t) {
            Decision::Unfold => true,
            Decision::Fold => false,
            Decision::Keep => before.contains(&id),
        };
        if unfold {
            active.insert(id);
            stack.extend(node.children());
        }
    }
    active
}

#[test]
fn a_sweep_finds_the_recursive_cut_and_its_changes_keep_the_threshold() {
    for name in ["bunny.obj", "cow.obj", "as1_assembly.obj"] {
        let mut scene = load(name);
        let bytes = vdt_bytes(&mut scene);
        let (center, radius) = bounds(&scene.positions);
        let mut runtime = runtime(&bytes, CornerTracking::Ranks);
        runtime.load_every_page().unwrap();
        let positions = runtime.leaf_positions().unwrap();
        let mut sweep = Sweep::new();
        // The same sweeps on two and three threads.
        let mut parallel = [2, 3].map(|threads| {
            let mut sweep = Sweep::new();
            sweep.set_threads(threads);
            sweep
        });
        let mut before = BTreeSet::new();
        // Subtrees the threads shared, over the path.
        let mut shared = 0;
        let mut rng = Rng(name.len() as u64 + 11);
        let mut camera = random_camera(&mut rng, center, radius);
        let mut seen = 0;
        for step in 0..36 {
            // Small moves, with a jump every 9 frames.
            next_camera(
                &mut rng,
                &mut camera,
                (step as u32, 9),
                (center, radius),
                0.04,
            );
            let t = [1.0f32, 0.5, 4.0][step % 3];
            let criteria = Criteria {
                frustum: [FrustumMode::Fold, FrustumMode::Ignore, FrustumMode::Off][step / 3 % 3],
                silhouette_factor: [Some(0.25), None][step / 9 % 2],
                backface: step % 2 == 0,
                ..Criteria::default()
            };
            let judge = Judge::new(&Viewpoint::Camera(camera), &criteria);
            let stats = sweep.run(runtime.cut().store(), &judge, t);
            let store = runtime.cut().store();
            let expected = recursive_cut(store, &judge, t, &before);
            let found: BTreeSet<u32> = sweep.active_nodes(store).into_iter().collect();
            assert!(
                found == expected,
                "{name} step {step}: the sweep's cut differs from the recursion's \
                 ({} against {} active nodes)",
                found.len(),
                expected.len()
            );
            assert_eq!(stats.active as usize, found.len(), "{name} step {step}");
            assert_eq!(
                stats.deferred, 0,
                "{name} step {step}: every page is resident"
            );
            let unfolded: Vec<u32> = found.difference(&before).copied().collect();
            let folded: Vec<u32> = before.difference(&found).copied().collect();
            assert_eq!(sweep.unfolded(), unfolded, "{name} step {step}: unfolded");
            assert_eq!(sweep.folded(), folded, "{name} step {step}: folded");
            assert!(found.iter().all(|&id| sweep.is_active(store, id)));
            for other in &mut parallel {
                let other_stats = other.run(store, &judge, t);
                shared += other_stats.shared;
                let other_stats = SweepStats {
                    shared: 0,
                    ..other_stats
                };
                assert_eq!(other_stats, stats, "{name} step {step}: on threads");
                assert_eq!(
                    other.active_nodes(store),
                    sweep.active_nodes(store),
                    "{name} step {step}: on threads"
                );
                assert_eq!(other.unfolded(), sweep.unfolded(), "{name} step {step}");
                assert_eq!(other.folded(), sweep.folded(), "{name} step {step}");
                let mut deferred = sweep.deferred().to_vec();
                deferred.sort_unstable();
                assert_eq!(other.deferred(), deferred, "{name} step {step}");
            }

            // The changes, applied by the cut's own operations: folds deepest first, then
            // unfolds parents first.
            let cut = runtime.cut_mut();
            for &id in sweep.folded().iter().rev() {
                assert!(cut.fold_node(id, false), "{name} step {step}: fold {id}");
            }
            for &id in sweep.unfolded() {
                cut.unfold_node(id).unwrap();
            }
            cut.check().unwrap();
            let active: BTreeSet<u32> = cut.active_entries().iter().map(|e| e.id).collect();
            assert!(
                active == found,
                "{name} step {step}: the applied cut differs"
            );
            // The report from the sweep's bits is the cut's own, node for node.
            let changes = cut.take_changes();
            let reported = sweep.report(cut.store()).expect("every page is resident");
            assert_same_report(&reported, &changes, &format!("{name} step {step}"));
            if criteria.frustum != FrustumMode::Ignore {
                let facing = criteria.backface.then(|| {
                    measure::facing_vertices(runtime.cut().store(), &positions, camera.view().eye)
                        .unwrap()
                });
                let deviation = measure::screen_deviation(
                    runtime.cut(),
                    &camera.view(),
                    &positions,
                    facing.as_deref(),
                );
                assert!(
                    deviation.max_px <= f64::from(t) + slack(t),
                    "{name} step {step}: a vertex moved {} px > {t} px",
                    deviation.max_px
                );
                seen += usize::from(deviation.visible_vertices > 0);
            }
            before = found;
        }
        assert!(seen >= 8, "{name}: too few cameras saw the model");
        // The cow's cuts never hold 256 subtrees waiting at once: the threads get none.
        if name != "cow.obj" {
            assert!(shared > 0, "{name}: the threads shared no subtree");
        }
    }
}

/// Asserts that two change reports list the same nodes (in any order) and triangle counts;
/// repeats are not compared (a sweep's report does not look for them).
fn assert_same_report(reported: &Changes, expected: &Changes, context: &str) {
    let sorted = |nodes: &[u32]| {
        let mut nodes = nodes.to_vec();
        nodes.sort_unstable();
        nodes
    };
    let lists = |c: &Changes| {
        [&c.unfolded, &c.folded, &c.joined_boundary, &c.left_boundary].map(|l| sorted(l))
    };
    for (kind, (found, wanted)) in [
        "unfolded",
        "folded",
        "joined the boundary",
        "left the boundary",
    ]
    .iter()
    .zip(lists(reported).iter().zip(&lists(expected)))
    {
        assert_eq!(found, wanted, "{context}: nodes that {kind}");
    }
    assert_eq!(
        (reported.added, reported.removed),
        (expected.added, expected.removed),
        "{context}: triangles added and removed"
    );
}

/// The active nodes of `runtime`'s cut, ascending.
fn active_nodes(runtime: &Runtime) -> BTreeSet<u32> {
    runtime
        .cut()
        .active_entries()
        .iter()
        .map(|e| e.id)
        .collect()
}

#[test]
fn adjusts_by_sweeps_load_their_pages_and_give_the_recursive_cut() {
    for (name, tracking) in [
        ("bunny.obj", CornerTracking::Ranks),
        ("as1_assembly.obj", CornerTracking::Ranks),
        ("cow.obj", CornerTracking::Incidence),
    ] {
        let mut scene = load(name);
        let bytes = vdt_bytes(&mut scene);
        let (center, radius) = bounds(&scene.positions);
        // Every page resident: what the recursion reads.
        let mut reference = runtime(&bytes, CornerTracking::Ranks);
        reference.load_every_page().unwrap();
        let positions = reference.leaf_positions().unwrap();
        // Pages loaded as the sweeps reach them.
        let mut swept = runtime(&bytes, tracking);
        swept.set_sweep(true);
        // Sweeps on its store before each adjust loads what the view needs, on one thread and
        // two: they leave nodes waiting for pages, the same ones.
        let mut waiting = [1, 2].map(|threads| {
            let mut sweep = Sweep::new();
            sweep.set_threads(threads);
            sweep
        });
        let mut waited = 0;
        let mut rng = Rng(name.len() as u64 + 5);
        let mut camera = random_camera(&mut rng, center, radius);
        for step in 0..40 {
            next_camera(
                &mut rng,
                &mut camera,
                (step as u32, 8),
                (center, radius),
                0.05,
            );
            let criteria = Criteria {
                frustum: [FrustumMode::Fold, FrustumMode::Ignore][step / 4 % 2],
                ..Criteria::default()
            };
            let viewpoint = Viewpoint::Camera(camera);
            // A budget adjust now and then changes the cut behind the sweep's back.
            if step % 10 == 9 {
                swept
                    .adjust(&viewpoint, &criteria, Goal::Budget(500 + 40 * step as u32))
                    .unwrap();
                swept.cut_mut().check().unwrap();
                continue;
            }
            let t = [1.0f32, 3.0][step % 2];
            let judge = Judge::new(&viewpoint, &criteria);
            let store = swept.cut().store();
            let [one, two] = waiting.each_mut().map(|sweep| sweep.run(store, &judge, t));
            assert_eq!(SweepStats { shared: 0, ..two }, one, "{name} step {step}");
            assert_eq!(
                waiting[1].active_nodes(store),
                waiting[0].active_nodes(store)
            );
            let mut deferred = waiting[0].deferred().to_vec();
            deferred.sort_unstable();
            assert_eq!(waiting[1].deferred(), deferred, "{name} step {step}");
            waited += deferred.len();
            let before = active_nodes(&swept);
            let frame = swept
                .adjust(&viewpoint, &criteria, Goal::Threshold(t))
                .unwrap();
            swept.cut_mut().check().unwrap();
            assert_eq!(frame.stats.deferred_unfolds, 0, "{name} step {step}");
            let expected = recursive_cut(reference.cut().store(), &judge, t, &before);
            assert!(
                active_nodes(&swept) == expected,
                "{name} step {step}: the adjust by sweeps differs from the recursion"
            );
            if criteria.frustum == FrustumMode::Fold {
                let facing = measure::facing_vertices(
                    reference.cut().store(),
                    &positions,
                    camera.view().eye,
                )
                .unwrap();
                let deviation = measure::screen_deviation(
                    swept.cut(),
                    &camera.view(),
                    &positions,
                    Some(&facing),
                );
                assert!(
                    deviation.max_px <= f64::from(t) + slack(t),
                    "{name} step {step}: a vertex moved {} px > {t} px",
                    deviation.max_px
                );
            }
        }
        assert!(waited > 0, "{name}: no sweep waited for a page");
    }
}

#[test]
fn adjusts_by_sweeps_with_background_loading_settle_on_the_recursive_cut() {
    let mut scene = load("as1_assembly.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let mut reference = runtime(&bytes, CornerTracking::Ranks);
    reference.load_every_page().unwrap();
    let mut swept = Runtime::with_loading(
        Box::new(vds_format::VdtFile::from_bytes(bytes.clone()).unwrap()),
        CornerTracking::Ranks,
        Loading::Background { threads: 2 },
    )
    .unwrap();
    swept.set_sweep(true);
    let mut rng = Rng(3);
    for view in 0..4 {
        let viewpoint = Viewpoint::Camera(random_camera(&mut rng, center, radius));
        let criteria = Criteria::default();
        let mut settled = false;
        for _ in 0..200 {
            let frame = swept
                .adjust(&viewpoint, &criteria, Goal::Threshold(1.0))
                .unwrap();
            swept.cut_mut().check().unwrap();
            if frame.stats.deferred_unfolds == 0 && swept.pending_pages() == 0 {
                settled = true;
                break;
            }
            swept.wait_for_pages();
        }
        assert!(settled, "view {view}: loading never settled");
        let judge = Judge::new(&viewpoint, &criteria);
        let expected = recursive_cut(reference.cut().store(), &judge, 1.0, &BTreeSet::new());
        assert!(
            active_nodes(&swept) == expected,
            "view {view}: the settled cut differs from the recursion"
        );
    }
}

#[test]
fn adjusts_by_sweeps_within_a_tiny_budget_keep_a_consistent_cut() {
    let (bytes, center, radius) = generated(60_000);
    let mut full = runtime(&bytes, CornerTracking::Ranks);
    full.set_memory_budget(u64::MAX);
    full.load_every_page().unwrap();
    let decoded = full.memory().resident_bytes;
    let mut swept = runtime(&bytes, CornerTracking::Ranks);
    swept.set_memory_budget(decoded / 8);
    swept.set_sweep(true);
    let path = CameraPath::fly_through(center, radius, 40, 640, 360);
    let budget = decoded / 8;
    for (i, camera) in path.cameras.iter().enumerate() {
        let frame = swept
            .adjust(
                &Viewpoint::Camera(*camera),
                &Criteria::default(),
                Goal::Threshold(1.0),
            )
            .unwrap();
        swept
            .cut_mut()
            .check()
            .unwrap_or_else(|e| panic!("frame {i}: {e}"));
        // As in `memory.rs`: over the budget only while the cut's own pages are.
        assert!(
            frame.memory.resident_bytes <= budget || swept.cut().store().over_budget_pinned(),
            "frame {i}: {} bytes held over a budget of {budget}",
            frame.memory.resident_bytes
        );
    }
    assert!(
        swept.memory().pages_evicted > 0,
        "a budget of an eighth of the model never evicted: the test tests nothing"
    );
}
