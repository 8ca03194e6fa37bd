//! Silhouettes, backfacing regions and mesh-fold prevention, on meshes where the answer is
//! known: a sphere seen from outside, a thin plate (a CAD-like shell), and the cow.

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
        parts: Vec::new(),
        stats: Default::default(),
        warnings: Vec::new(),
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

/// Checks every visible vertex with a front face against the cut: it is never folded away as
/// backfacing, it moves at most `t` pixels on screen, and at most `t · factor` when it is on
/// the silhouette (it has a front and a back face). Returns how many silhouette vertices
/// were checked.
fn assert_silhouettes_tight(
    cut: &vds_runtime::Cut,
    view: &vds_runtime::View,
    positions: &[[f32; 3]],
    facing: &[(bool, bool)],
    t: f32,
    factor: f32,
) -> usize {
    let mut silhouette_vertices = 0;
    for (rank, &p) in positions.iter().enumerate() {
        let v = Vec3::from(p);
        let (front, back) = facing[rank];
        if !view.contains(v) || !front {
            continue;
        }
        let proxy = Vec3::from(cut.node(cut.current_proxy_node(rank as u32)).proxy);
        let (a, b) = (view.project(v).unwrap(), view.project(proxy).unwrap());
        let moved = (a[0] - b[0]).hypot(a[1] - b[1]);
        let limit = if back {
            silhouette_vertices += 1;
            t * factor
        } else {
            t
        };
        assert!(
            moved <= f64::from(limit) * (1.0 + 1e-4) + 1e-4,
            "vertex {rank} moved {moved} px > {limit} px"
        );
    }
    silhouette_vertices
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
        let silhouette_vertices =
            assert_silhouettes_tight(runtime.cut(), &view, &positions, &facing, t, factor);
        assert!(
            silhouette_vertices > 100,
            "backface {backface}: the silhouette was not seen"
        );
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

/// A square plate of side 2 and thickness `2h` centred at the origin: an `n`×`n` grid on
/// the top face (facing +z), the same grid on the bottom face (facing −z) and the four rim
/// walls between their boundaries.
fn plate(n: u32, h: f32) -> Scene {
    let side = n + 1;
    let at = |i: u32, j: u32| {
        [
            2.0 * i as f32 / n as f32 - 1.0,
            2.0 * j as f32 / n as f32 - 1.0,
        ]
    };
    let mut positions = Vec::new();
    for z in [h, -h] {
        for j in 0..side {
            for i in 0..side {
                let [x, y] = at(i, j);
                positions.push([x, y, z]);
            }
        }
    }
    let top = |i: u32, j: u32| j * side + i;
    let bottom = |i: u32, j: u32| side * side + j * side + i;
    let mut triangles = Vec::new();
    for j in 0..n {
        for i in 0..n {
            let (a, b, c, d) = (top(i, j), top(i + 1, j), top(i + 1, j + 1), top(i, j + 1));
            triangles.push([a, b, c]);
            triangles.push([a, c, d]);
            let (a, b, c, d) = (
                bottom(i, j),
                bottom(i + 1, j),
                bottom(i + 1, j + 1),
                bottom(i, j + 1),
            );
            triangles.push([a, c, b]);
            triangles.push([a, d, c]);
        }
    }
    // The rim, walking the boundary counter-clockwise seen from +z (walls face outwards).
    let mut boundary: Vec<(u32, u32)> = (0..n).map(|i| (i, 0)).collect();
    boundary.extend((0..n).map(|j| (n, j)));
    boundary.extend((0..n).map(|i| (n - i, n)));
    boundary.extend((0..n).map(|j| (0, n - j)));
    for k in 0..boundary.len() {
        let (p, q) = (boundary[k], boundary[(k + 1) % boundary.len()]);
        let (tp, tq, bp, bq) = (
            top(p.0, p.1),
            top(q.0, q.1),
            bottom(p.0, p.1),
            bottom(q.0, q.1),
        );
        triangles.push([bp, bq, tq]);
        triangles.push([bp, tq, tp]);
    }
    let count = triangles.len();
    Scene {
        positions,
        triangles,
        triangle_parts: vec![0; count],
        part_names: vec!["plate".into()],
        parts: Vec::new(),
        stats: Default::default(),
        warnings: Vec::new(),
    }
}

/// CAD parts are thin shells. A cluster spanning both faces of a plate has normals on both
/// sides: its one-sided cone is wider than a hemisphere (a silhouette from every view), its
/// two-sided cone narrow. Seen across its faces, the plate must then keep the tight
/// threshold only at its rim: every vertex with a front and a back face (the rim, here)
/// within `t · factor`, every visible one within `t`, and far fewer triangles than the tight
/// threshold everywhere.
#[test]
fn on_a_thin_plate_only_the_rim_is_a_silhouette() {
    let mut scene = plate(96, 0.002);
    let bytes = vdt_bytes(&mut scene);
    let file = vds_format::VdtFile::from_bytes(bytes.clone()).unwrap();
    let two_sided = file
        .read_all_pages()
        .unwrap()
        .iter()
        .flat_map(|page| page.nodes.iter())
        .filter(|n| n.flags & vds_format::FLAG_TWO_SIDED_CONE != 0)
        .count();
    assert!(two_sided > 100, "nodes spanning both faces: {two_sided}");
    let camera = Camera::framing([0.0; 3], 1.5, [0.2, 0.3, 1.0], 600, 600);
    let view = camera.view();
    let (positions, facing) = vertex_facing(&bytes, view.eye);
    let (t, factor) = (8.0f32, 0.25f32);
    let count = |criteria: &Criteria, t: f32| {
        let mut runtime = runtime(&bytes, CornerTracking::Incidence);
        runtime
            .adjust(&Viewpoint::Camera(camera), criteria, Goal::Threshold(t))
            .unwrap();
        runtime.cut_mut().check().unwrap();
        runtime
    };
    let criteria = Criteria {
        silhouette_factor: Some(factor),
        ..Criteria::default()
    };
    let runtime = count(&criteria, t);
    let cut = runtime.cut();
    let rim_vertices = assert_silhouettes_tight(cut, &view, &positions, &facing, t, factor);
    assert!(rim_vertices > 100, "the rim was not seen: {rim_vertices}");
    let with_silhouettes = cut.active_triangle_count();
    let no_silhouettes = Criteria {
        silhouette_factor: None,
        ..Criteria::default()
    };
    let tight_everywhere = count(&no_silhouettes, t * factor)
        .cut()
        .active_triangle_count();
    assert!(
        with_silhouettes * 3 < tight_everywhere,
        "{with_silhouettes} triangles with silhouettes vs {tight_everywhere} at t·factor everywhere"
    );
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
