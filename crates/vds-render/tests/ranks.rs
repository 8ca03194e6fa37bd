//! A rank-tracked cut's GPU mirror, read on the CPU as the shader reads it: after every frame
//! of random camera paths (jumps, threshold and budget goals), the slots, mapped through the
//! rank map to vertices and through those to nodes, draw exactly the cut's active triangles
//! with their parts, and the vertices in use are the boundary nodes; a mirror started over
//! from the cut as it is draws the same and goes on from there.

use std::path::PathBuf;

use vds_format::VdtFile;
use vds_render::ranks::vertex_of_rank;
use vds_render::{CutUpdate, RankMirror};
use vds_runtime::{Camera, CornerTracking, Criteria, FrustumMode, Goal, Runtime, Viewpoint};

fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name)
}

fn vdt_bytes(name: &str) -> Vec<u8> {
    let mut scene = vds_import::load_file(shared(name), &Default::default()).unwrap();
    let grid = vds_build::snap_to_grid(&mut scene);
    let tree = vds_build::build_tree(&scene);
    let metadata = vds_format::Metadata {
        part_names: scene.part_names.clone(),
        ..Default::default()
    };
    vds_format::encode(
        &vds_build::tree_content(&tree, &scene, metadata, grid),
        &vds_format::WriteOptions::default(),
    )
    .unwrap()
    .0
}

/// What the GPU holds, written as `GpuCut::apply` writes it.
#[derive(Default)]
struct FakeGpu {
    vertex_nodes: Vec<u32>,
    slots: Vec<[u32; 4]>,
    blocks: Vec<u32>,
    words: Vec<u32>,
}

impl FakeGpu {
    fn apply(&mut self, update: &CutUpdate) {
        fn write<T: Copy + Default>(into: &mut Vec<T>, len: u32, runs: &[(u32, Vec<T>)]) {
            into.resize(into.len().max(len as usize), T::default());
            for (first, values) in runs {
                let first = *first as usize;
                into[first..first + values.len()].copy_from_slice(values);
            }
        }
        let vertex_runs: Vec<(u32, Vec<u32>)> = (update.nodes.iter())
            .zip(&update.vertex_nodes)
            .map(|((first, _), nodes)| (*first, nodes.clone()))
            .collect();
        write(&mut self.vertex_nodes, update.vertex_count, &vertex_runs);
        self.slots.truncate(update.slot_count as usize);
        write(&mut self.slots, update.slot_count, &update.slots);
        write(
            &mut self.blocks,
            update.rank_block_count,
            &update.rank_blocks,
        );
        write(&mut self.words, update.rank_word_count, &update.rank_words);
    }

    /// Corner nodes and part of every drawn slot, sorted.
    fn drawn(&self) -> Vec<([u32; 3], u32)> {
        let mut drawn: Vec<_> = (self.slots.iter())
            .filter(|s| s[0] != u32::MAX)
            .map(|s| {
                let corners = [s[0], s[1], s[2]].map(|rank| {
                    self.vertex_nodes[vertex_of_rank(&self.blocks, &self.words, rank) as usize]
                });
                (corners, s[3])
            })
            .collect();
        drawn.sort_unstable();
        drawn
    }
}

#[test]
fn the_mirror_of_node_changes_draws_the_cut() {
    for name in ["bunny.obj", "as1_assembly.obj"] {
        let bytes = vdt_bytes(name);
        let mut runtime = Runtime::new(
            Box::new(VdtFile::from_bytes(bytes).unwrap()),
            CornerTracking::Ranks,
        )
        .unwrap();
        let mut mirror = RankMirror::new();
        let mut gpu = FakeGpu::default();
        gpu.apply(&mirror.collect(runtime.cut_mut(), &RankMirror::first_changes()));
        let root = runtime.cut().node(0);
        let (center, radius) = (root.sphere_center, root.sphere_radius);
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut random = move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        };
        let mut most_slots = 0;
        let mut shrank = false;
        for step in 0..50u32 {
            let distance = radius * (0.4 + 3.0 * random());
            let direction = [random() - 0.5, random() - 0.5, random() - 0.5];
            let length = direction
                .iter()
                .map(|d| d * d)
                .sum::<f32>()
                .sqrt()
                .max(1e-3);
            let eye = [0, 1, 2].map(|k| center[k] + direction[k] / length * distance);
            let camera = Camera {
                eye,
                target: center,
                up: [0.0, 1.0, 0.0],
                fov_y_degrees: 50.0,
                width: 800,
                height: 600,
                near: radius * 1e-3,
            };
            let goal = match step % 3 {
                0 => Goal::Threshold(1.0),
                1 => Goal::Threshold(6.0),
                _ => Goal::Budget(1500 + 200 * step),
            };
            let criteria = Criteria {
                frustum: [FrustumMode::Fold, FrustumMode::Ignore][step as usize % 2],
                ..Criteria::default()
            };
            let frame = runtime
                .adjust(&Viewpoint::Camera(camera), &criteria, goal)
                .unwrap();
            let before = gpu.slots.len();
            gpu.apply(&mirror.collect(runtime.cut_mut(), &frame.changes));
            shrank |= gpu.slots.len() < before;
            if step % 10 == 9 {
                // A fresh GPU mirror of the cut as it is, continued incrementally from here.
                gpu = FakeGpu::default();
                gpu.apply(&mirror.everything(runtime.cut_mut()));
            }
            let active = runtime.cut_mut().active_triangles();
            let cut = runtime.cut();
            let mut expected: Vec<_> = active
                .into_iter()
                .map(|t| (t.corners, cut.store().triangle_part(t.triangle)))
                .collect();
            expected.sort_unstable();
            assert!(
                gpu.drawn() == expected,
                "{name} step {step}: the mirror draws {} triangles, the cut {}",
                gpu.drawn().len(),
                expected.len()
            );
            assert_eq!(
                mirror.vertices_in_use(),
                cut.boundary().len(),
                "{name} step {step}: a vertex per boundary node"
            );
            most_slots = most_slots.max(gpu.slots.len());
        }
        assert!(most_slots > 1000, "{name}: the path never refined");
        assert!(shrank, "{name}: the slot array was never packed");
    }
}
