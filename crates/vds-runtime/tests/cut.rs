//! The method's invariants for the cut: the threshold guarantee, the budget's stopping rule,
//! unfold-all/fold-all, coherence of incremental adjusts with a recomputation from scratch,
//! the change journal a renderer applies, the two corner-tracking strategies agreeing, and one
//! adjust leaving a settled cut.

mod common;

use common::*;
use vds_build::Builder;
use vds_runtime::{
    ActiveTriangle, Camera, CornerTracking, Criteria, FrustumMode, Goal, Judge, Runtime, Viewpoint,
    measure,
};

const MESHES: [&str; 3] = ["bunny.obj", "cow.obj", "as1_assembly.obj"];

/// Screen-space checks compare a bound computed in `f32` with a projection computed in `f64`
/// from `f32` positions; relative rounding of both is below 1e-5, so this slack covers it
/// with room to spare while being far below anything a wrong bound would produce.
fn slack(t: f32) -> f64 {
    f64::from(t) * 1e-4 + 1e-4
}

fn no_backface() -> Criteria {
    Criteria {
        backface: false,
        ..Criteria::default()
    }
}

/// A canonical form of a triangle by corner positions: rotated so the smallest corner leads,
/// keeping orientation.
fn canonical(corners: [[f32; 3]; 3]) -> [[u32; 3]; 3] {
    let bits = corners.map(|p| p.map(f32::to_bits));
    let lead = (0..3).min_by_key(|&k| bits[k]).unwrap();
    [bits[lead], bits[(lead + 1) % 3], bits[(lead + 2) % 3]]
}

#[test]
fn unfolding_everything_gives_the_original_mesh_and_folding_everything_the_root() {
    for (name, scene, bytes) in built_by_each(&MESHES) {
        for tracking in [
            CornerTracking::Incidence,
            CornerTracking::Lazy,
            CornerTracking::Ranks,
        ] {
            let mut runtime = runtime(&bytes, tracking);
            runtime.cut_mut().unfold_all().unwrap();
            runtime.cut_mut().check().unwrap();
            let cut = runtime.cut_mut();
            let active = cut.active_triangles();
            let mut drawn: Vec<_> = active
                .iter()
                .map(|t| {
                    let corners = t.corners.map(|n| {
                        assert!(cut.node(n).is_leaf(), "{name}: a corner is not a leaf");
                        cut.node(n).proxy
                    });
                    canonical(corners)
                })
                .collect();
            let mut original: Vec<_> = scene
                .triangles
                .iter()
                .map(|t| canonical(t.map(|v| scene.positions[v as usize])))
                .collect();
            drawn.sort_unstable();
            original.sort_unstable();
            assert_eq!(drawn.len(), original.len(), "{name}: triangle count");
            assert!(drawn == original, "{name}: the unfolded mesh differs");
            assert_eq!(cut.boundary().len(), scene.positions.len());

            cut.fold_all();
            cut.check().unwrap();
            assert_eq!(cut.active_triangle_count(), 0);
            assert_eq!(cut.active_node_count(), 0);
            assert_eq!(cut.boundary(), vec![0]);
        }
    }
}

#[test]
fn threshold_bounds_every_visible_vertex_on_random_cameras() {
    for name in MESHES {
        for builder in BUILDERS {
            assert_threshold_on_random_cameras(name, load(name), builder);
        }
    }
}

/// The largest coordinates import accepts keep the whole pipeline exact: a model scaled out
/// to `MAX_COORDINATE`, centred or far from the origin, meets the screen-space bound from
/// random cameras, from the framing camera `vds-cut` uses, and zoomed far out. (The tests'
/// fourth powers of distances overflowed in `f32` beyond about 10⁹ and folded everything.)
#[test]
fn threshold_holds_for_models_at_the_largest_accepted_coordinates() {
    let limit = vds_import::MAX_COORDINATE as f32;
    for (label, offset) in [("centred", 0.0), ("at the far corner", 0.5)] {
        let mut scene = load("cow.obj");
        let (center, radius) = bounds(&scene.positions);
        let extent = radius * 3f32.sqrt();
        // Centred: spans [-limit, limit]; far: spans [0, limit] on every axis.
        let scale = limit * (1.0 - offset) / extent;
        for p in &mut scene.positions {
            *p = [0, 1, 2].map(|k| (p[k] - center[k]) * scale + offset * limit);
        }
        assert!(scene.positions.iter().flatten().all(|c| c.abs() <= limit));
        let (center, radius) = bounds(&scene.positions);
        let bytes = vdt_bytes(&mut scene.clone());
        let mut runtime = runtime(&bytes, CornerTracking::Incidence);
        let positions = runtime.leaf_positions().unwrap();
        for zoom in [1.0f32, 30.0, 1000.0] {
            for t in [1.0f32, 5.0] {
                let mut camera = Camera::framing(center, radius, [1.0, 0.6, 1.4], 1920, 1080);
                camera.eye = [0, 1, 2].map(|k| center[k] + (camera.eye[k] - center[k]) * zoom);
                camera.near *= zoom;
                let what = format!("{label}, zoom {zoom}");
                adjust_within(&mut runtime, &camera, &no_backface(), t, &positions, &what);
            }
        }
        assert_threshold_on_random_cameras(label, scene, Builder::default());
    }
}

fn assert_threshold_on_random_cameras(name: &str, mut scene: vds_import::Scene, builder: Builder) {
    let name = &format!("{name} ({} builder)", builder.name());
    let bytes = vdt_bytes_by(&mut scene, builder);
    let (center, radius) = bounds(&scene.positions);
    let mut runtime = runtime(&bytes, CornerTracking::Incidence);
    let positions = runtime.leaf_positions().unwrap();
    let mut rng = Rng(name.len() as u64);
    let mut checked = 0;
    for step in 0..24 {
        let camera = random_camera(&mut rng, center, radius);
        let t = [0.5f32, 1.0, 3.0][step % 3];
        let criteria = Criteria {
            frustum: [FrustumMode::Fold, FrustumMode::Off][step / 3 % 2],
            silhouette_factor: [Some(0.25), None][step / 6 % 2],
            backface: step / 12 == 1,
            ..Criteria::default()
        };
        runtime
            .adjust(&Viewpoint::Camera(camera), &criteria, Goal::Threshold(t))
            .unwrap();
        runtime.cut_mut().check().unwrap();
        // With backface folding, vertices whose every triangle faces away may move further.
        let facing = criteria.backface.then(|| {
            measure::facing_vertices(runtime.cut().store(), &positions, camera.view().eye).unwrap()
        });
        let deviation =
            measure::screen_deviation(runtime.cut(), &camera.view(), &positions, facing.as_deref());
        assert!(
            deviation.max_px <= f64::from(t) + slack(t),
            "{name} step {step}: a vertex moved {} px > {t} px (camera {camera:?})",
            deviation.max_px
        );
        if deviation.visible_vertices > 0 {
            checked += 1;
        }
    }
    assert!(checked >= 12, "{name}: too few cameras saw the model");
}

#[test]
fn threshold_zero_unfolds_every_visible_region_fully() {
    let mut scene = load("cow.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let camera = Camera::framing(center, radius, [1.0, 0.5, 2.0], 400, 300);
    let mut runtime = runtime(&bytes, CornerTracking::Incidence);
    runtime
        .adjust(
            &Viewpoint::Camera(camera),
            &no_backface(),
            Goal::Threshold(0.0),
        )
        .unwrap();
    // The whole cow is in view, so every node unfolds.
    assert_eq!(
        runtime.cut().active_triangle_count() as usize,
        scene.triangles.len()
    );
}

/// Applies a frame's changes to a mirror of the slot array, as a renderer would.
fn apply(mirror: &mut Vec<Option<ActiveTriangle>>, runtime: &mut Runtime, dirty: &[u32]) {
    let cut = runtime.cut_mut();
    mirror.resize(cut.slot_count() as usize, None);
    for &slot in dirty {
        mirror[slot as usize] = cut.slot(slot);
    }
}

#[test]
fn incremental_adjusts_match_a_recomputation_and_the_journal_replays_them() {
    for (name, scene, bytes) in built_by_each(&["bunny.obj", "as1_assembly.obj"]) {
        let (center, radius) = bounds(&scene.positions);
        let mut eager = runtime(&bytes, CornerTracking::Incidence);
        let mut lazy = runtime(&bytes, CornerTracking::Lazy);
        let mut mirror = Vec::new();
        let mut rng = Rng(7);
        let mut camera = random_camera(&mut rng, center, radius);
        for step in 0..60 {
            // Mostly small moves, with a jump every 15 frames and goal switches.
            next_camera(&mut rng, &mut camera, (step, 15), (center, radius), 0.05);
            let goal = match step / 20 {
                0 => Goal::Threshold(1.0),
                1 => Goal::Budget(2000 + 300 * step),
                _ => Goal::Threshold(4.0),
            };
            let criteria = Criteria {
                frustum: [FrustumMode::Fold, FrustumMode::Ignore][step as usize % 2],
                ..Criteria::default()
            };
            let view = Viewpoint::Camera(camera);
            let frame = eager.adjust(&view, &criteria, goal).unwrap();
            lazy.adjust(&view, &criteria, goal).unwrap();
            eager.cut_mut().check().unwrap();
            lazy.cut_mut().check().unwrap();
            assert!(
                frame.changes.dirty_slots.windows(2).all(|w| w[0] < w[1]),
                "{name} step {step}: dirty slots are not ascending and distinct"
            );
            apply(&mut mirror, &mut eager, &frame.changes.dirty_slots);
            let cut = eager.cut_mut();
            let slots: Vec<_> = (0..cut.slot_count()).map(|s| cut.slot(s)).collect();
            assert!(
                mirror == slots,
                "{name} step {step}: the journal missed a change"
            );
            // Under a budget the two may differ: incidence tracking counts each class of
            // repeats once, lazy tracking (which sorts repeats only when the cut is read)
            // counts every active triangle.
            if let Goal::Threshold(_) = goal {
                let mut a = eager.cut_mut().active_triangles();
                let mut b = lazy.cut_mut().active_triangles();
                a.sort_unstable();
                b.sort_unstable();
                assert!(
                    a == b,
                    "{name} step {step}: incidence and lazy tracking disagree"
                );
            }
        }
    }
}

#[test]
fn budget_is_never_exceeded_and_the_next_unfold_would_exceed_it() {
    for builder in BUILDERS {
        budget_is_never_exceeded_with(builder);
    }
}

fn budget_is_never_exceeded_with(builder: Builder) {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes_by(&mut scene, builder);
    let (center, radius) = bounds(&scene.positions);
    let mut runtime = runtime(&bytes, CornerTracking::Incidence);
    let mut rng = Rng(3);
    let mut camera = random_camera(&mut rng, center, radius);
    for (step, budget) in [100u32, 1000, 5000, 20000, 3000, 500, 12000, 0, 8000]
        .into_iter()
        .cycle()
        .take(27)
        .enumerate()
    {
        if step % 3 == 0 {
            camera = random_camera(&mut rng, center, radius);
        }
        let views = [Viewpoint::Camera(camera), Viewpoint::Independent];
        let viewpoint = views[step % 4 / 3];
        let criteria = Criteria::default();
        runtime
            .adjust(&viewpoint, &criteria, Goal::Budget(budget))
            .unwrap();
        runtime.cut_mut().check().unwrap();
        let active = runtime.cut().active_triangle_count();
        assert!(active <= budget, "step {step}: {active} > {budget}");
        // §3.3's stopping rule: the highest-priority boundary node does not fit.
        let judge = Judge::new(&viewpoint, &criteria);
        let unfoldable: Vec<u32> = runtime
            .cut()
            .boundary()
            .iter()
            .copied()
            .filter(|&b| runtime.cut().can_unfold(b))
            .collect();
        let next = unfoldable
            .into_iter()
            .map(|b| (runtime.budget_priority(&judge, b), b))
            .filter(|&(p, _)| p > 0.0)
            .max_by(|a, b| a.0.total_cmp(&b.0).then(b.1.cmp(&a.1)));
        if let Some((_, node)) = next {
            let cost = runtime.cut().node(node).subtri_count;
            // Its subtris do not fit, or, if they seem to, unfolding it splits classes of
            // repeats past the budget.
            if active + cost <= budget {
                let cut = runtime.cut_mut();
                cut.unfold_node(node).unwrap();
                let after = cut.active_triangle_count();
                assert!(
                    after > budget,
                    "step {step}: node {node} ({cost} triangles) still fits in {budget} - {active}"
                );
                cut.fold_node(node, false);
                cut.check().unwrap();
                assert_eq!(cut.active_triangle_count(), active);
            }
        }
    }
}

#[test]
fn view_independent_budget_orders_by_object_space_error() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let mut runtime = runtime(&bytes, CornerTracking::Incidence);
    let mut previous_error = f32::INFINITY;
    for budget in [500u32, 2000, 8000, 30000] {
        runtime
            .adjust(
                &Viewpoint::Independent,
                &Criteria::default(),
                Goal::Budget(budget),
            )
            .unwrap();
        // The largest error radius left on the boundary shrinks as the budget grows.
        let cut = runtime.cut();
        let worst = cut
            .boundary()
            .iter()
            .map(|&b| cut.node(b).error_radius)
            .fold(0.0f32, f32::max);
        assert!(
            worst <= previous_error,
            "budget {budget}: {worst} > {previous_error}"
        );
        previous_error = worst;
        assert!(
            cut.active_triangle_count() > budget / 2,
            "budget {budget} is badly used"
        );
    }
}

#[test]
fn frustum_fold_collapses_an_unseen_model_and_ignore_leaves_it() {
    let mut scene = load("cow.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let front = Camera::framing(center, radius, [0.0, 0.0, 1.0], 320, 240);
    // Same eye, looking straight away from the model.
    let mut away = front;
    away.target = [0, 1, 2].map(|k| 2.0 * front.eye[k] - center[k]);
    for (mode, keeps) in [(FrustumMode::Fold, false), (FrustumMode::Ignore, true)] {
        let mut runtime = runtime(&bytes, CornerTracking::Incidence);
        let criteria = Criteria {
            frustum: mode,
            ..Criteria::default()
        };
        runtime
            .adjust(&Viewpoint::Camera(front), &criteria, Goal::Threshold(1.0))
            .unwrap();
        let seen = runtime.cut().active_triangle_count();
        assert!(seen > 1000);
        let frame = runtime
            .adjust(&Viewpoint::Camera(away), &criteria, Goal::Threshold(1.0))
            .unwrap();
        runtime.cut_mut().check().unwrap();
        if keeps {
            assert_eq!(runtime.cut().active_triangle_count(), seen);
            assert!(frame.changes.dirty_slots.is_empty());
        } else {
            assert_eq!(runtime.cut().active_triangle_count(), 0);
            assert_eq!(frame.changes.removed, seen);
        }
    }
}

#[test]
fn gaze_loosens_the_threshold_away_from_the_focus_and_keeps_its_bound() {
    let mut scene = load("bunny.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let camera = Camera::framing(center, radius * 0.6, [0.3, 0.2, 1.0], 640, 480);
    let view = camera.view();
    let gaze_direction = (view.forward + view.right * 0.3).normalize();
    let falloff = 8.0;
    let mut plain = runtime(&bytes, CornerTracking::Incidence);
    let mut gazing = runtime(&bytes, CornerTracking::Incidence);
    let t = 1.0;
    plain
        .adjust(
            &Viewpoint::Camera(camera),
            &no_backface(),
            Goal::Threshold(t),
        )
        .unwrap();
    let criteria = Criteria {
        gaze: Some(vds_runtime::Gaze {
            direction: gaze_direction.into(),
            falloff,
        }),
        ..no_backface()
    };
    gazing
        .adjust(&Viewpoint::Camera(camera), &criteria, Goal::Threshold(t))
        .unwrap();
    assert!(
        gazing.cut().active_triangle_count() * 5 < plain.cut().active_triangle_count() * 4,
        "gaze should cost at least a fifth fewer triangles: {} vs {}",
        gazing.cut().active_triangle_count(),
        plain.cut().active_triangle_count()
    );
    // Each visible vertex is within t·(1 + falloff·θ) of its image, θ its angle from the gaze.
    let positions = gazing.leaf_positions().unwrap();
    let cut = gazing.cut();
    for (rank, &p) in positions.iter().enumerate() {
        let v = glam::Vec3::from(p);
        if !view.contains(v) {
            continue;
        }
        let proxy = glam::Vec3::from(cut.node(cut.current_proxy_node(rank as u32)).proxy);
        let a = view.project(v).unwrap();
        let b = view.project(proxy).unwrap();
        let theta = gaze_direction.angle_between(v - view.eye);
        let limit = t * (1.0 + falloff * theta);
        let moved = (a[0] - b[0]).hypot(a[1] - b[1]);
        assert!(
            moved <= f64::from(limit) + slack(limit),
            "vertex {rank}: {moved} > {limit}"
        );
    }
}

/// Adjusts to threshold `t` for `camera` and checks that every visible vertex is within `t`
/// of its image.
fn adjust_within(
    runtime: &mut Runtime,
    camera: &Camera,
    criteria: &Criteria,
    t: f32,
    positions: &[[f32; 3]],
    what: &str,
) -> vds_runtime::AdjustStats {
    let frame = runtime
        .adjust(&Viewpoint::Camera(*camera), criteria, Goal::Threshold(t))
        .unwrap();
    let deviation = measure::screen_deviation(runtime.cut(), &camera.view(), positions, None);
    assert!(
        deviation.max_px <= f64::from(t) + slack(t),
        "{what}: {} px > {t} px",
        deviation.max_px
    );
    frame.stats
}

#[test]
fn threshold_holds_on_every_frame_of_a_smooth_path() {
    for (name, scene, bytes) in built_by_each(&["bunny.obj", "as1_assembly.obj"]) {
        let (center, radius) = bounds(&scene.positions);
        let mut runtime = runtime(&bytes, CornerTracking::Incidence);
        let positions = runtime.leaf_positions().unwrap();
        let path = vds_runtime::CameraPath::fly_through(center, radius * 1.5, 40, 480, 320);
        for (frame, camera) in path.cameras.iter().enumerate() {
            let what = format!("{name} frame {frame}");
            adjust_within(&mut runtime, camera, &no_backface(), 1.0, &positions, &what);
        }
        runtime.cut_mut().check().unwrap();
    }
}

/// Groups whose last test still holds are skipped (`crate::reuse`): along smooth paths most
/// are, and the threshold must hold on every frame all the same, also right after the
/// threshold tightens (which must start over, not reuse tests made at the looser threshold).
/// Silhouettes and backfaces off: the threshold then bounds every visible vertex with no
/// factor to spare, which a wrong margin would show.
#[test]
fn reused_tests_keep_the_threshold_on_smooth_paths() {
    for name in ["bunny.obj", "as1_assembly.obj"] {
        let mut scene = load(name);
        let bytes = vdt_bytes(&mut scene);
        let (center, radius) = bounds(&scene.positions);
        let mut runtime = runtime(&bytes, CornerTracking::Incidence);
        let positions = runtime.leaf_positions().unwrap();
        let frames = 160;
        let paths = [
            vds_runtime::CameraPath::orbit(center, radius * 2.0, frames, 480, 320),
            vds_runtime::CameraPath::fly_through(center, radius * 1.5, frames, 480, 320),
        ];
        let (mut tested, mut reused) = (0u64, 0u64);
        for path in &paths {
            for (frame, camera) in path.cameras.iter().enumerate() {
                let t = if frame < frames as usize / 2 {
                    1.0
                } else {
                    0.5
                };
                let criteria = Criteria {
                    silhouette_factor: None,
                    ..no_backface()
                };
                let what = format!("{name} frame {frame}");
                let stats = adjust_within(&mut runtime, camera, &criteria, t, &positions, &what);
                tested += u64::from(stats.groups);
                reused += u64::from(stats.groups_reused);
            }
        }
        runtime.cut_mut().check().unwrap();
        assert!(
            reused > tested,
            "{name}: {reused} groups reused, {tested} tested: the paths should reuse most"
        );
    }
}

/// One adjust settles the cut: adjusting again for the same camera and goal changes nothing,
/// so a still camera shows a still mesh. After a threshold adjust every boundary node has
/// passed its test and every fold candidate has failed its own (or was just unfolded because
/// it failed it); after a budget adjust no exchange is left. With mesh-fold prevention this
/// holds because refused folds are tried again within the adjust.
#[test]
fn a_second_adjust_for_the_same_camera_and_goal_changes_nothing() {
    let gaze = vds_runtime::Gaze {
        direction: [0.3, -0.2, -1.0],
        falloff: 2.0,
    };
    let settings = [
        Criteria::default(),
        Criteria {
            frustum: FrustumMode::Ignore,
            ..Criteria::default()
        },
        Criteria {
            prevent_mesh_folds: true,
            ..Criteria::default()
        },
        Criteria {
            gaze: Some(gaze),
            silhouette_factor: None,
            ..no_backface()
        },
    ];
    for (name, scene, bytes) in built_by_each(&["bunny.obj", "as1_assembly.obj"]) {
        let (center, radius) = bounds(&scene.positions);
        let path = vds_runtime::CameraPath::fly_through(center, radius * 1.5, 30, 480, 320);
        for (setting, criteria) in settings.iter().enumerate() {
            let mut runtime = runtime(&bytes, CornerTracking::Incidence);
            let mut changed = 0;
            for (frame, camera) in path.cameras.iter().enumerate() {
                let view = Viewpoint::Camera(*camera);
                let goal = [
                    Goal::Threshold(1.0),
                    Goal::Budget(2000),
                    Goal::Threshold(3.0),
                    Goal::Budget(5000),
                ][frame % 4];
                let first = runtime.adjust(&view, criteria, goal).unwrap();
                changed += first.stats.folds + first.stats.unfolds;
                let second = runtime.adjust(&view, criteria, goal).unwrap();
                let what = format!("{name}, criteria {setting}, frame {frame}, {goal:?}");
                assert_eq!(
                    second.stats.folds, 0,
                    "{what}: folded again ({:?})",
                    second.stats
                );
                assert_eq!(second.stats.unfolds, 0, "{what}: unfolded again");
                assert!(
                    second.changes.dirty_slots.is_empty(),
                    "{what}: slots changed"
                );
            }
            runtime.cut_mut().check().unwrap();
            assert!(changed > 1000, "{name}: the path should change the cut");
        }
    }
}

/// Still passes ([`vds_runtime`]'s threshold adjusts for a camera where it was at the last
/// adjust) visit only what did not settle and what changed: a runtime that adjusts four
/// times at each camera of a path (the second adjust a full pass that lists what did not
/// settle, the third and fourth visiting that list) keeps the same cut as one that adjusts
/// once, frame after frame, under each kind of criteria; the threshold holds on every adjust
/// (measured where backfaces stay, which the measure counts as visible); and the later
/// adjusts make far fewer tests than the second.
#[test]
fn still_passes_keep_the_cut_of_single_adjusts() {
    let settings = [
        Criteria::default(),
        Criteria {
            frustum: FrustumMode::Ignore,
            ..Criteria::default()
        },
        Criteria {
            silhouette_factor: None,
            ..no_backface()
        },
    ];
    for name in ["bunny.obj", "as1_assembly.obj"] {
        let mut scene = load(name);
        let bytes = vdt_bytes(&mut scene);
        let (center, radius) = bounds(&scene.positions);
        let path = vds_runtime::CameraPath::fly_through(center, radius * 1.5, 60, 480, 320);
        for (setting, criteria) in settings.iter().enumerate() {
            let mut once = runtime(&bytes, CornerTracking::Ranks);
            let mut paused = runtime(&bytes, CornerTracking::Ranks);
            let positions = paused.leaf_positions().unwrap();
            // Tests made by each of the four adjusts at a camera, summed over the path.
            let mut tests = [0u64; 4];
            for (frame, camera) in path.cameras.iter().enumerate() {
                let t = [1.0, 2.0][frame / 40];
                once.adjust(&Viewpoint::Camera(*camera), criteria, Goal::Threshold(t))
                    .unwrap();
                for made in &mut tests {
                    let stats = if criteria.backface {
                        let view = Viewpoint::Camera(*camera);
                        paused
                            .adjust(&view, criteria, Goal::Threshold(t))
                            .unwrap()
                            .stats
                    } else {
                        let what = format!("{name}, criteria {setting}, frame {frame}");
                        adjust_within(&mut paused, camera, criteria, t, &positions, &what)
                    };
                    *made += u64::from(stats.visited);
                }
                assert_eq!(
                    once.cut().boundary(),
                    paused.cut().boundary(),
                    "{name}, criteria {setting}, frame {frame}: the cuts differ"
                );
            }
            paused.cut_mut().check().unwrap();
            assert!(
                tests[3] * 2 < tests[1],
                "{name}, criteria {setting}: tests made by the four adjusts {tests:?}"
            );
        }
    }
}

/// A still pass visits only what the last one listed and what changed since
/// ([`vds_runtime`]'s re-adjusts): a budget adjust between threshold adjusts for the same
/// camera changes the cut under the records (coarser: nodes to unfold again; finer: new
/// active nodes to fold), and the threshold adjust after it must end where a runtime without
/// the still passes before it ends.
#[test]
fn a_still_pass_visits_what_changed_since_the_last() {
    for name in ["bunny.obj", "as1_assembly.obj"] {
        let mut scene = load(name);
        let bytes = vdt_bytes(&mut scene);
        let (center, radius) = bounds(&scene.positions);
        let mut rng = Rng(11);
        let criteria = Criteria::default();
        for step in 0..8 {
            let view = Viewpoint::Camera(random_camera(&mut rng, center, radius));
            let t = Goal::Threshold([1.0, 2.0][step % 2]);
            let (mut plain, mut still) = (
                runtime(&bytes, CornerTracking::Ranks),
                runtime(&bytes, CornerTracking::Ranks),
            );
            plain.adjust(&view, &criteria, t).unwrap();
            for _ in 0..3 {
                still.adjust(&view, &criteria, t).unwrap();
            }
            let threshold_count = plain.cut().active_triangle_count();
            let finer = step % 2 == 1;
            let budget = Goal::Budget(if finer {
                threshold_count * 3
            } else {
                threshold_count / 3
            });
            plain.adjust(&view, &criteria, budget).unwrap();
            still.adjust(&view, &criteria, budget).unwrap();
            let again = plain.adjust(&view, &criteria, t).unwrap();
            let listed = still.adjust(&view, &criteria, t).unwrap();
            let back = if finer {
                again.stats.folds
            } else {
                again.stats.unfolds
            };
            assert!(back > 0, "{name} step {step}: the budget changed nothing");
            assert_eq!(
                plain.cut().boundary(),
                still.cut().boundary(),
                "{name} step {step}: the still pass missed a change ({:?})",
                listed.stats
            );
        }
    }
}
