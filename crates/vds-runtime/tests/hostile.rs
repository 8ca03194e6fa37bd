//! The runtime over hostile pages: a page source that returns records the format reader
//! would accept (every per-record range check holds) but whose tree is inconsistent across
//! records and pages. Every operation must return or fail with an error, never panic or hang.

mod common;

use common::{Rng, bounds, load, random_camera, vdt_bytes};
use proptest::prelude::*;
use vds_format::layout::{F32, U16, U32};
use vds_format::{BoundViolation, Header, NO_NODE, Page, PageEntry, VdtError, VdtFile};
use vds_runtime::{CornerTracking, Criteria, Goal, PageSource, Runtime, Viewpoint};

struct Mutating {
    file: VdtFile<Vec<u8>>,
    seed: u64,
    edits: u32,
}

impl PageSource for Mutating {
    fn header(&self) -> &Header {
        self.file.header()
    }

    fn directory(&self) -> &[PageEntry] {
        self.file.directory()
    }

    fn read_page_into(&self, index: u32, page: &mut Page) -> Result<(), VdtError> {
        self.file.read_page_into(index, page)?;
        let header = self.file.header();
        let node_count = header.node_count.get() as u32;
        let vertex_count = header.vertex_count.get() as u32;
        let max_depth = header.max_depth.get() as u16;
        let mut rng = Rng(self.seed ^ u64::from(index).wrapping_mul(0x9E37_79B9));
        let below = |rng: &mut Rng, n: u32| (rng.next_u64() % u64::from(n.max(1))) as u32;
        let triangle_end = page.first_triangle + page.triangles.len() as u32;
        for _ in 0..self.edits {
            if page.nodes.is_empty() {
                break;
            }
            let k = below(&mut rng, page.nodes.len() as u32) as usize;
            let id = page.first_node + k as u32;
            let n = &mut page.nodes[k];
            match rng.next_u64() % 7 {
                0 => {
                    let begin = below(&mut rng, vertex_count - 1);
                    let end = begin + 1 + below(&mut rng, vertex_count - begin);
                    n.leaf_begin = U32::new(begin);
                    n.leaf_end = U32::new(end.min(vertex_count));
                }
                1 => {
                    let count = below(&mut rng, 9).min(node_count - 1 - id);
                    if count > 0 {
                        let first = id + 1 + below(&mut rng, node_count - id - count);
                        n.child_count = count as u8;
                        n.first_child = U32::new(first);
                    } else {
                        n.child_count = 0;
                        n.first_child = U32::new(NO_NODE);
                    }
                }
                2 if id > 0 => n.parent = U32::new(below(&mut rng, id)),
                3 => {
                    let begin = page.first_triangle
                        + below(&mut rng, triangle_end - page.first_triangle + 1);
                    n.subtri_begin = U32::new(begin);
                    n.subtri_count = U32::new(below(&mut rng, triangle_end - begin + 1));
                }
                4 => {
                    let f = f32::from_bits(rng.next_u64() as u32);
                    let f = if f.is_finite() { f.abs() } else { 1.0 };
                    n.error_radius = F32::new(f);
                    n.proxy[0] = F32::new(-f);
                }
                5 => n.depth = U16::new(below(&mut rng, u32::from(max_depth) + 1) as u16),
                _ if !page.triangles.is_empty() => {
                    let t = below(&mut rng, page.triangles.len() as u32) as usize;
                    page.triangles[t].corners[below(&mut rng, 3) as usize] =
                        U32::new(below(&mut rng, vertex_count));
                }
                _ => {}
            }
        }
        Ok(())
    }
}

fn exercise(runtime: &mut Runtime, seed: u64, center: [f32; 3], radius: f32) {
    let mut rng = Rng(seed);
    for step in 0..6 {
        let camera = random_camera(&mut rng, center, radius);
        let goal = if step % 2 == 0 {
            Goal::Threshold(0.5)
        } else {
            Goal::Budget(3000)
        };
        if runtime
            .adjust(&Viewpoint::Camera(camera), &Criteria::default(), goal)
            .is_err()
        {
            return;
        }
        let _ = runtime.cut_mut().check();
    }
    if runtime.cut_mut().unfold_all().is_ok() {
        let _ = runtime.cut_mut().check();
    }
    runtime.cut_mut().fold_all();
    let _ = runtime.leaf_positions();
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, ..ProptestConfig::default() })]

    #[test]
    fn inconsistent_pages_give_errors_not_panics(seed in any::<u64>(), edits in 1u32..6, tracking in 0usize..3) {
        let mut scene = load("cow.obj");
        let bytes = vdt_bytes(&mut scene);
        let (center, radius) = bounds(&scene.positions);
        let source = Mutating { file: VdtFile::from_bytes(bytes).unwrap(), seed, edits };
        let tracking = [CornerTracking::Lazy, CornerTracking::Incidence, CornerTracking::Ranks][tracking];
        if let Ok(mut runtime) = Runtime::new(Box::new(source), tracking) {
            exercise(&mut runtime, seed, center, radius);
        }
    }
}

/// `scene`'s `.vdt` bytes (small pages) after `lie` has edited the built tree: the writer
/// encodes what it is given, so the file is a valid one, checksums and all, whose only fault
/// is the lie.
fn lying_file(
    scene: &mut vds_import::Scene,
    lie: impl FnOnce(&mut vds_build::VertexTree),
) -> Vec<u8> {
    let grid = vds_build::snap_to_grid(scene);
    let mut tree = vds_build::build_tree(scene);
    lie(&mut tree);
    let metadata = vds_format::Metadata {
        part_names: scene.part_names.clone(),
        ..Default::default()
    };
    let options = vds_format::WriteOptions {
        zstd_level: 1,
        page_bytes: 4096,
    };
    vds_format::encode(
        &vds_build::tree_content(&tree, scene, metadata, grid),
        &options,
    )
    .unwrap()
    .0
}

/// The cow with its root's bounding sphere shrunk to a quarter: the root's children reach
/// outside it.
fn cow_with_a_shrunk_root_sphere() -> Vec<u8> {
    lying_file(&mut load("cow.obj"), |tree| {
        assert!(!tree.nodes[0].is_leaf());
        tree.bounds[tree.nodes[0].bounds as usize].sphere_radius *= 0.25;
    })
}

#[test]
fn a_child_sphere_outside_its_parent_fails_the_load_naming_the_page() {
    let bytes = cow_with_a_shrunk_root_sphere();
    let file = VdtFile::from_bytes(bytes.clone()).unwrap();
    // What --verify says of the same file: the root's sphere misses triangles.
    let (tree, scene) = vds_build::tree_from_file(&file).unwrap();
    assert!(vds_build::verify_tree(&tree, &scene).is_err());
    let mut runtime = Runtime::new(Box::new(file), CornerTracking::Incidence).unwrap();
    match runtime.cut_mut().unfold_all() {
        Err(
            ref e @ VdtError::Bounds {
                page,
                node,
                violation: BoundViolation::SphereOutsideParent { parent: 0, by },
            },
        ) => {
            let file = VdtFile::from_bytes(bytes).unwrap();
            assert_eq!(page, file.page_of_node(node).unwrap());
            assert!(by > 0.0);
            assert!(e.to_string().contains(&format!("page {page}")), "{e}");
        }
        other => panic!("expected a sphere outside its parent, got {other:?}"),
    }
}

#[test]
fn a_leaf_outside_its_parent_error_radius_fails_the_load() {
    // One triangle: the root's children are its three leaves.
    let mut scene = vds_import::Scene {
        positions: vec![[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]],
        triangles: vec![[0, 1, 2]],
        triangle_parts: vec![0],
        part_names: vec!["triangle".into()],
        parts: Vec::new(),
        stats: Default::default(),
        warnings: Vec::new(),
    };
    let bytes = lying_file(&mut scene, |tree| {
        assert!(tree.nodes[1..].iter().all(|n| n.is_leaf()));
        tree.bounds[tree.nodes[0].bounds as usize].error_radius = 0.0;
    });
    let file = VdtFile::from_bytes(bytes).unwrap();
    let mut runtime = Runtime::new(Box::new(file), CornerTracking::Incidence).unwrap();
    let error = runtime.cut_mut().unfold_all().unwrap_err();
    assert!(
        matches!(
            error,
            VdtError::Bounds {
                page: 0,
                violation: BoundViolation::LeafOutsideErrorRadius { parent: 0, .. },
                ..
            }
        ),
        "{error:?}"
    );
}

#[test]
fn honest_files_pass_the_bound_checks_everywhere() {
    for name in ["cow.obj", "bunny.obj", "as1_assembly.obj", "bone.ply"] {
        let mut scene = load(name);
        let bytes = vdt_bytes(&mut scene);
        let mut runtime = Runtime::new(
            Box::new(VdtFile::from_bytes(bytes).unwrap()),
            CornerTracking::Incidence,
        )
        .unwrap();
        runtime
            .cut_mut()
            .unfold_all()
            .unwrap_or_else(|e| panic!("{name}: {e}"));
    }
}

#[test]
fn vds_cut_refuses_a_file_with_a_child_sphere_outside_its_parent() {
    let dir = std::env::temp_dir().join(format!("vds-hostile-cut-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let input = dir.join("lying-cow.vdt");
    std::fs::write(&input, cow_with_a_shrunk_root_sphere()).unwrap();
    let output = dir.join("cut.obj");
    let run = std::process::Command::new(env!("CARGO_BIN_EXE_vds-cut"))
        .arg(&input)
        .arg("-o")
        .arg(&output)
        .args(["--threshold", "1"])
        .output()
        .unwrap();
    assert_eq!(run.status.code(), Some(1));
    let message = String::from_utf8_lossy(&run.stderr);
    assert!(
        message.contains("lying-cow.vdt") && message.contains("page") && message.contains("sphere"),
        "{message}"
    );
    let left: Vec<_> = std::fs::read_dir(&dir)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(left.len(), 1, "no output, no partial file: {left:?}");
    std::fs::remove_dir_all(&dir).unwrap();
}
