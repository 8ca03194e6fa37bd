//! Silhouettes, backfacing regions and mesh-fold prevention, on meshes where the answer is
//! known: a sphere seen from outside, and the cow.

mod common;

use common::*;
use glam::Vec3;
use vds_import::Scene;
use vds_runtime::{Camera, CornerTracking, Criteria, Goal, Viewpoint};

/// A UV sphere of radius 1 with outward (counter-clockwise) triangles.
fn sphere(segments: u32, rings: u32) -> Scene {
    let mut positions = vec![[0.0, 1.0, 0.0]];
    for r in 1..rings {
        let polar = std::f32::consts::PI * r as f32 / rings as f32;
        for s in 0..segments {
            let azimuth = std::f32::consts::TAU * s as f32 / segments as f32;
            positions.push([
                polar.sin() * azimuth.cos(),
                polar.cos(),
                -polar.sin() * azimuth.sin(),
            ]);
        }
    }
    positions.push([0.0, -1.0, 0.0]);
    let south = positions.len() as u32 - 1;
    let ring = |r: u32, s: u32| 1 + (r - 1) * segments + s % segments;
    let mut triangles = Vec::new();
    for s in 0..segments {
        triangles.push([0, ring(1, s), ring(1, s + 1)]);
        for r in 1..rings - 1 {
            let (a, b, c, d) = (
                ring(r, s),
                ring(r + 1, s),
                ring(r + 1, s + 1),
                ring(r, s + 1),
            );
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
        }
        triangles.push([ring(rings - 1, s), south, ring(rings - 1, s + 1)]);
    }
    let count = triangles.len();
    Scene {
        positions,
        triangles,
        triangle_parts: vec![0; count],
        part_names: vec!["sphere".into()],
        stats: Default::default(),
    }
}

/// Per leaf rank: does the vertex have a front-facing and a back-facing incident triangle
/// (seen from `eye`)? Read from the fully unfolded cut, so ranks match the file.
fn vertex_facing(bytes: &[u8], eye: Vec3) -> (Vec<[f32; 3]>, Vec<(bool, bool)>) {
    let mut full = runtime(bytes, CornerTracking::Incidence);
    let positions = full.leaf_positions().unwrap();
    full.cut_mut().unfold_all().unwrap();
    let mut facing = vec![(false, false); positions.len()];
    let cut = full.cut_mut();
    for t in cut.active_triangles() {
        let ranks = t.corners.map(|n| cut.node(n).leaf_begin);
        let p = ranks.map(|r| Vec3::from(positions[r as usize]));
        let normal = (p[1] - p[0]).cross(p[2] - p[0]);
        let front = normal.dot(eye - (p[0] + p[1] + p[2]) / 3.0) > 0.0;
        for r in ranks {
            let f = &mut facing[r as usize];
            if front {
                f.0 = true;
            } else {
                f.1 = true;
            }
        }
    }
    (positions, facing)
}

#[test]
fn on_a_sphere_backfaces_fold_and_the_silhouette_keeps_the_tight_threshold() {
    let mut scene = sphere(128, 64);
    let bytes = vdt_bytes(&mut scene);
    let camera = Camera::framing([0.0; 3], 1.0, [0.3, 0.4, 1.0], 500, 500);
    let view = camera.view();
    let (positions, facing) = vertex_facing(&bytes, view.eye);
    let (t, factor) = (2.0f32, 0.25f32);
    let mut back_triangles = [0usize; 2];
    for (k, backface) in [false, true].into_iter().enumerate() {
        let criteria = Criteria {
            backface,
            silhouette_factor: Some(factor),
            ..Criteria::default()
        };
        let mut runtime = runtime(&bytes, CornerTracking::Incidence);
        runtime
            .adjust(&Viewpoint::Camera(camera), &criteria, Goal::Threshold(t))
            .unwrap();
        runtime.cut_mut().check().unwrap();
        let cut = runtime.cut();
        let mut silhouette_vertices = 0;
        for (rank, &p) in positions.iter().enumerate() {
            let v = Vec3::from(p);
            let (front, back) = facing[rank];
            if !view.contains(v) || !front {
                continue;
            }
            let proxy = Vec3::from(cut.node(cut.current_proxy_node(rank as u32)).proxy);
            let a = view.project(v).unwrap();
            let b = view.project(proxy).unwrap();
            let moved = (a[0] - b[0]).hypot(a[1] - b[1]);
            // A vertex with a front face is never folded away as backfacing, and one on the
            // silhouette (front and back faces) gets the tight threshold.
            let limit = if back {
                silhouette_vertices += 1;
                t * factor
            } else {
                t
            };
            assert!(
                moved <= f64::from(limit) * (1.0 + 1e-4) + 1e-4,
                "backface {backface}: vertex {rank} moved {moved} px > {limit} px"
            );
        }
        assert!(silhouette_vertices > 100, "the silhouette was not seen");
        // Count active triangles lying entirely on the far side (original corners backfacing).
        let runtime_cut = runtime.cut_mut();
        back_triangles[k] = runtime_cut
            .active_triangles()
            .iter()
            .filter(|tri| {
                let leaves = runtime_cut.store().triangle_corners(tri.triangle);
                leaves.iter().all(|&r| !facing[r as usize].0)
            })
            .count();
    }
    assert!(
        back_triangles[0] > 1000,
        "without backface folding the far side stays detailed"
    );
    assert!(
        back_triangles[1] * 5 < back_triangles[0],
        "backfacing regions should fold: {back_triangles:?}"
    );
}

#[test]
fn silhouette_preservation_costs_triangles_only_near_the_silhouette() {
    let mut scene = sphere(256, 128);
    let bytes = vdt_bytes(&mut scene);
    let camera = Camera::framing([0.0; 3], 1.0, [0.0, 0.0, 1.0], 300, 300);
    let mut counts = Vec::new();
    for silhouette_factor in [None, Some(0.25)] {
        let criteria = Criteria {
            silhouette_factor,
            ..Criteria::default()
        };
        let mut runtime = runtime(&bytes, CornerTracking::Incidence);
        runtime
            .adjust(&Viewpoint::Camera(camera), &criteria, Goal::Threshold(4.0))
            .unwrap();
        counts.push(runtime.cut().active_triangle_count());
    }
    // A tighter silhouette adds triangles, but far fewer than a 4× tighter threshold overall.
    let mut everywhere = runtime(&bytes, CornerTracking::Incidence);
    everywhere
        .adjust(
            &Viewpoint::Camera(camera),
            &Criteria {
                silhouette_factor: None,
                ..Criteria::default()
            },
            Goal::Threshold(1.0),
        )
        .unwrap();
    let tight = everywhere.cut().active_triangle_count();
    assert!(counts[1] > counts[0], "{counts:?}");
    assert!(counts[1] < tight, "{counts:?} vs {tight}");
}

#[test]
fn mesh_fold_prevention_refuses_exactly_the_folds_that_flip_a_triangle() {
    let mut scene = load("cow.obj");
    let bytes = vdt_bytes(&mut scene);
    let (center, radius) = bounds(&scene.positions);
    let camera = Camera::framing(center, radius, [1.0, 0.2, 0.5], 800, 600);
    let mut runtime = runtime(&bytes, CornerTracking::Incidence);
    runtime
        .adjust(
            &Viewpoint::Camera(camera),
            &Criteria::default(),
            Goal::Threshold(0.3),
        )
        .unwrap();
    let normals = |runtime: &mut vds_runtime::Runtime| {
        let cut = runtime.cut_mut();
        let mut by_triangle = std::collections::HashMap::new();
        for t in cut.active_triangles() {
            let p = t.corners.map(|n| Vec3::from(cut.node(n).proxy));
            by_triangle.insert(t.triangle, (p[1] - p[0]).cross(p[2] - p[0]));
        }
        by_triangle
    };
    let (mut folded, mut refused) = (0, 0);
    for _pass in 0..6 {
        let candidates: Vec<u32> = {
            let cut = runtime.cut();
            let mut c: Vec<u32> = cut
                .boundary()
                .iter()
                .map(|&b| cut.node(b).parent)
                .filter(|&p| p != vds_runtime::NIL && cut.can_fold(p))
                .collect();
            c.sort_unstable();
            c.dedup();
            c
        };
        for id in candidates.into_iter().step_by(7) {
            let before = normals(&mut runtime);
            let changed = runtime.cut_mut().fold_node(id, true);
            let after = normals(&mut runtime);
            if changed {
                folded += 1;
                for (t, n) in &after {
                    assert!(n.dot(before[t]) >= 0.0, "fold of {id} flipped triangle {t}");
                }
            } else {
                refused += 1;
                assert_eq!(before, after, "a refused fold changed the cut");
            }
        }
        runtime.cut_mut().check().unwrap();
    }
    assert!(folded > 50, "too few folds tried ({folded})");
    assert!(
        refused > 0,
        "no fold was refused, so the test proves nothing"
    );
}
