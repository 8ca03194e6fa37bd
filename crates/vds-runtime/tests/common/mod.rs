//! Shared helpers: building `.vdt` bytes from meshes, runtimes over them, and cameras.

#![allow(dead_code)]

use std::path::PathBuf;

use vds_build::{Builder, build_tree_by, snap_to_grid, tree_content};
use vds_format::{VdtFile, WriteOptions, encode};
use vds_import::Scene;
use vds_runtime::{Camera, CornerTracking, Runtime};

pub fn shared(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../../shared/data")
        .join(name)
}

/// A mesh from `../shared/data`.
pub fn load(name: &str) -> Scene {
    vds_import::load_file(shared(name), &Default::default()).unwrap()
}

/// Every builder, for the invariants that must hold whichever made the tree.
pub const BUILDERS: [Builder; 2] = [Builder::Octree, Builder::Qem];

/// The `.vdt` bytes of `scene` (snapped to the file's grid in place), with small pages so
/// that even small meshes exercise page loading.
pub fn vdt_bytes(scene: &mut Scene) -> Vec<u8> {
    vdt_bytes_by(scene, Builder::default())
}

/// [`vdt_bytes`] with the tree made by `builder`.
pub fn vdt_bytes_by(scene: &mut Scene, builder: Builder) -> Vec<u8> {
    let grid = snap_to_grid(scene);
    let (tree, _) = build_tree_by(scene, builder);
    let metadata = vds_format::Metadata {
        part_names: scene.part_names.clone(),
        ..Default::default()
    };
    let options = WriteOptions {
        zstd_level: 1,
        page_bytes: 4096,
    };
    encode(&tree_content(&tree, scene, metadata, grid), &options)
        .unwrap()
        .0
}

/// Meshes from `../shared/data`, each built by every builder: a label naming mesh and
/// builder, the scene (snapped to the file's grid) and the `.vdt` bytes.
pub fn built_by_each(files: &[&str]) -> Vec<(String, Scene, Vec<u8>)> {
    let mut built = Vec::new();
    for &file in files {
        for builder in BUILDERS {
            let mut scene = load(file);
            let bytes = vdt_bytes_by(&mut scene, builder);
            built.push((format!("{file} ({} builder)", builder.name()), scene, bytes));
        }
    }
    built
}

pub fn runtime(bytes: &[u8], tracking: CornerTracking) -> Runtime {
    Runtime::new(
        Box::new(VdtFile::from_bytes(bytes.to_vec()).unwrap()),
        tracking,
    )
    .unwrap()
}

/// Bounding sphere (centre, radius) of a point set.
pub fn bounds(positions: &[[f32; 3]]) -> ([f32; 3], f32) {
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for p in positions {
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    let center = [0, 1, 2].map(|k| (min[k] + max[k]) / 2.0);
    let radius = (0..3)
        .map(|k| (max[k] - min[k]) / 2.0)
        .map(|h| h * h)
        .sum::<f32>()
        .sqrt();
    (center, radius)
}

/// A small deterministic generator (SplitMix64) for cameras.
pub struct Rng(pub u64);

impl Rng {
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [lo, hi).
    pub fn range(&mut self, lo: f32, hi: f32) -> f32 {
        lo + (hi - lo) * (self.next_u64() >> 40) as f32 / (1u64 << 24) as f32
    }

    pub fn unit_vector(&mut self) -> [f32; 3] {
        loop {
            let v = [0; 3].map(|_| self.range(-1.0, 1.0));
            let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if l > 0.1 && l <= 1.0 {
                return v.map(|x| x / l);
            }
        }
    }
}

/// A random camera around a model: from far outside to inside its bounds, looking roughly at
/// its centre, with varied fields of view and aspect ratios.
pub fn random_camera(rng: &mut Rng, center: [f32; 3], radius: f32) -> Camera {
    let distance = radius * rng.range(0.3, 4.0);
    let dir = rng.unit_vector();
    let eye = [0, 1, 2].map(|k| center[k] + dir[k] * distance);
    let jitter = rng.unit_vector();
    let target = [0, 1, 2].map(|k| center[k] + jitter[k] * radius * 0.3);
    let width = 160 + (rng.next_u64() % 400) as u32;
    let height = 120 + (rng.next_u64() % 300) as u32;
    Camera {
        eye,
        target,
        up: rng.unit_vector(),
        fov_y_degrees: rng.range(20.0, 100.0),
        width,
        height,
        near: radius * 1e-3,
    }
}

/// Moves a test path's camera to its next frame: at every `jump_every`-th step (`step %
/// jump_every == jump_every - 1`) a new random camera, otherwise the eye moved by `share` of
/// `radius` in a random direction.
pub fn next_camera(
    rng: &mut Rng,
    camera: &mut Camera,
    (step, jump_every): (u32, u32),
    (center, radius): ([f32; 3], f32),
    share: f32,
) {
    if step % jump_every == jump_every - 1 {
        *camera = random_camera(rng, center, radius);
    } else {
        let d = rng.unit_vector();
        for k in 0..3 {
            camera.eye[k] += d[k] * radius * share;
        }
    }
}

/// A generated CAD-like scene of about `triangles` triangles, built into `.vdt` bytes.
pub fn generated(triangles: u64) -> (Vec<u8>, [f32; 3], f32) {
    let g = vds_gen::generate(triangles);
    let mut scene = vds_import::Scene {
        positions: g.positions,
        triangles: g.triangles,
        triangle_parts: g.triangle_parts,
        part_names: (0..g.part_count).map(|p| format!("part{p}")).collect(),
        parts: Vec::new(),
        stats: Default::default(),
        warnings: Vec::new(),
    };
    let (center, radius) = bounds(&scene.positions);
    (vdt_bytes(&mut scene), center, radius)
}
