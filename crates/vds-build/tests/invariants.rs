//! The vertex tree's invariants (the builder issue's spec) on random soups, non-manifold and
//! coincident geometry, and real meshes; determinism across thread counts; and proof that the
//! invariant checker itself rejects broken trees.

use std::path::PathBuf;

use proptest::prelude::*;
use vds_build::{Builder, VertexTree, build_tree, build_tree_by, verify_tree};
use vds_import::{MeshSoup, Scene, Weld, weld};

fn scene_from(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Scene {
    let mut soup = MeshSoup::default();
    let part = soup.begin_part("test");
    soup.positions = positions;
    for t in triangles {
        soup.push_polygon(part, &t);
    }
    weld(soup, Weld::Exact)
}

/// A scene whose coincident vertices are kept distinct (no welding), as the builder must
/// handle scenes from embedders that do not weld.
fn unwelded_scene(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Scene {
    let triangles: Vec<[u32; 3]> = triangles
        .into_iter()
        .filter(|[a, b, c]| a != b && b != c && a != c)
        .collect();
    let mut used = vec![false; positions.len()];
    for t in &triangles {
        for &v in t {
            used[v as usize] = true;
        }
    }
    assert!(used.iter().all(|&u| u), "test scenes use every vertex");
    Scene {
        triangle_parts: vec![0; triangles.len()],
        part_names: vec!["test".into()],
        parts: Vec::new(),
        positions,
        triangles,
        stats: Default::default(),
        warnings: Vec::new(),
    }
}

fn build_and_verify_by(scene: &Scene, builder: Builder) -> VertexTree {
    let (tree, _) = build_tree_by(scene, builder);
    if let Err(error) = verify_tree(&tree, scene) {
        panic!("invariant broken ({} builder): {error}", builder.name());
    }
    tree
}

/// Builds the scene's tree with every builder and checks each; returns the default one's.
fn build_and_verify(scene: &Scene) -> VertexTree {
    build_and_verify_by(scene, Builder::Qem);
    build_and_verify_by(scene, Builder::Octree)
}

fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name)
}

fn coordinate() -> impl Strategy<Value = f32> {
    prop_oneof![
        // A coarse grid makes coincident positions and axis-aligned planes common.
        (-4i32..4).prop_map(|i| i as f32 * 0.5),
        -100.0f32..100.0,
        // Tiny offsets around 1.0 exercise the float-precision edge of octree splitting.
        (0u32..4).prop_map(|k| f32::from_bits(1.0f32.to_bits() + k)),
    ]
}

fn soup_strategy() -> impl Strategy<Value = (Vec<[f32; 3]>, Vec<[u32; 3]>)> {
    (3usize..120).prop_flat_map(|n| {
        let position = [coordinate(), coordinate(), coordinate()];
        let index = 0..n as u32;
        (
            prop::collection::vec(position, n),
            prop::collection::vec([index.clone(), index.clone(), index], 1..200),
        )
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(200))]

    /// Random welded soups (degenerate triangles dropped by the weld) satisfy every invariant.
    #[test]
    fn random_soups_satisfy_all_invariants((positions, triangles) in soup_strategy()) {
        let scene = scene_from(positions, triangles);
        build_and_verify(&scene);
    }

    /// Unwelded soups: distinct vertices at the same position must terminate cleanly.
    #[test]
    fn unwelded_coincident_vertices_satisfy_all_invariants(
        base in prop::collection::vec([coordinate(), coordinate(), coordinate()], 3..30),
        copies in 1usize..12,
    ) {
        let mut positions = Vec::new();
        let mut triangles = Vec::new();
        for _ in 0..copies {
            let offset = positions.len() as u32;
            positions.extend(base.iter().copied());
            for i in 0..base.len() as u32 - 2 {
                triangles.push([offset + i, offset + i + 1, offset + i + 2]);
            }
        }
        let scene = unwelded_scene(positions, triangles);
        prop_assume!(!scene.triangles.is_empty());
        build_and_verify(&scene);
    }
}

/// Proptest's minimal case from a CI run: two unwelded copies of one triangle whose far corner
/// sits ~113 units from the origin. Each node of coincident copies has error radius 0 and stores
/// surface error 0, while the checker's own plane distances round to ~10⁻¹⁵ there.
#[test]
fn coincident_copies_of_a_long_triangle() {
    let base = [
        [-63.261585, 94.98771, -0.5],
        [0.0, 0.0, 0.0],
        [0.0, 0.5, 0.5],
    ];
    let positions = [base, base].concat();
    let scene = unwelded_scene(positions, vec![[0, 1, 2], [3, 4, 5]]);
    build_and_verify(&scene);
}

#[test]
fn non_manifold_fan_of_triangles_on_one_edge() {
    // Twelve fins share the edge (0,0,0)-(0,0,1): every edge is non-manifold.
    let mut positions = vec![[0.0, 0.0, 0.0], [0.0, 0.0, 1.0]];
    let mut triangles = Vec::new();
    for k in 0..12 {
        let angle = k as f32 * std::f32::consts::TAU / 12.0;
        positions.push([angle.cos(), angle.sin(), 0.5]);
        triangles.push([0, 1, positions.len() as u32 - 1]);
    }
    let scene = scene_from(positions, triangles);
    let tree = build_and_verify(&scene);
    assert!(tree.nodes.iter().all(|n| n.child_count <= 8));
}

#[test]
fn a_hundred_coincident_distinct_vertices() {
    let positions = vec![[3.0, 3.0, 3.0]; 100];
    let triangles = (0..98).map(|i| [i, i + 1, i + 2]).collect();
    let scene = unwelded_scene(positions, triangles);
    let tree = build_and_verify(&scene);
    assert_eq!(tree.leaf_vertex.len(), 100);
}

#[test]
fn degenerate_triangles_are_not_subtris() {
    let scene = scene_from(
        vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
        ],
        vec![[0, 1, 2], [0, 1, 3], [2, 2, 1]],
    );
    assert_eq!(scene.triangles.len(), 1);
    let tree = build_and_verify(&scene);
    assert_eq!(tree.subtris, vec![0]);
}

#[test]
fn real_meshes_satisfy_all_invariants() {
    for name in [
        "bunny.obj",
        "cow.obj",
        "airplane.obj",
        "bone.ply",
        "as1_assembly.obj",
    ] {
        let scene = vds_import::load_file(shared(name), &Default::default()).unwrap();
        let tree = build_and_verify(&scene);
        assert_eq!(tree.leaf_vertex.len(), scene.positions.len(), "{name}");
        assert_eq!(tree.subtris.len(), scene.triangles.len(), "{name}");
    }
}

#[test]
fn small_parts_merge_across_objects_under_one_root() {
    // The CAD assembly's 18 solids share one tree: some node mixes triangles of several parts.
    let scene = vds_import::load_file(shared("as1_assembly.obj"), &Default::default()).unwrap();
    for builder in [Builder::Octree, Builder::Qem] {
        let tree = build_and_verify_by(&scene, builder);
        let mixed = tree.nodes.iter().enumerate().any(|(id, _)| {
            let parts: std::collections::BTreeSet<u32> = tree
                .subtris_of(id as u32)
                .iter()
                .map(|&t| scene.triangle_parts[t as usize])
                .collect();
            parts.len() > 1
        });
        assert!(
            mixed,
            "{}: no node's subtris span two parts",
            builder.name()
        );
    }
}

#[test]
fn identical_trees_on_one_two_and_three_threads() {
    let scene = vds_import::load_file(shared("bunny.obj"), &Default::default()).unwrap();
    for builder in [Builder::Octree, Builder::Qem] {
        let on = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| build_tree_by(&scene, builder).0)
        };
        let one = on(1);
        assert!(one == on(2), "{}: 1 and 2 threads differ", builder.name());
        assert!(one == on(3), "{}: 1 and 3 threads differ", builder.name());
    }
}

#[test]
fn the_checker_rejects_broken_trees() {
    let scene = vds_import::load_file(shared("cow.obj"), &Default::default()).unwrap();
    let tree = build_and_verify(&scene);
    let inner = tree
        .bounds
        .iter()
        .position(|b| b.error_radius > 0.0)
        .unwrap();

    let mut shrunk = tree.clone();
    shrunk.bounds[inner].error_radius *= 0.5;
    assert!(
        verify_tree(&shrunk, &scene).is_err(),
        "shrunk error radius accepted"
    );

    let mut small_sphere = tree.clone();
    small_sphere.bounds[inner].sphere_radius *= 0.5;
    assert!(
        verify_tree(&small_sphere, &scene).is_err(),
        "shrunk sphere accepted"
    );

    let mut narrow_cone = tree.clone();
    narrow_cone.bounds[0].cone_half_angle = 0.0;
    assert!(
        verify_tree(&narrow_cone, &scene).is_err(),
        "narrowed cone accepted"
    );

    // Moving a subtri to its node's parent breaks the "deepest node" rule.
    let mut moved = tree.clone();
    let owner = moved
        .nodes
        .iter()
        .position(|n| n.subtri_end > n.subtri_begin && n.parent != u32::MAX)
        .unwrap();
    let parent = moved.nodes[owner].parent as usize;
    moved.nodes[owner].subtri_end -= 1;
    moved.nodes[parent].subtri_begin = moved.nodes[owner].subtri_end;
    assert!(
        verify_tree(&moved, &scene).is_err(),
        "misplaced subtri accepted"
    );

    let mut duplicated = tree.clone();
    duplicated.leaf_vertex[1] = duplicated.leaf_vertex[0];
    assert!(
        verify_tree(&duplicated, &scene).is_err(),
        "vertex as two leaves accepted"
    );
}

#[test]
fn empty_scene_gives_empty_tree() {
    let tree = build_tree(&Scene::default());
    assert!(tree.nodes.is_empty());
    verify_tree(&tree, &Scene::default()).unwrap();
}
