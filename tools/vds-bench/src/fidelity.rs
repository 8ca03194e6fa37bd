//! `vds-bench fidelity`: view-independent budget cuts against meshoptimizer's `simplify`
//! (edge collapse) and `simplify_sloppy` (clustering) at equal triangle counts.
//!
//! Each peer runs first on the imported, exactly welded, grid-snapped scene that the tree is
//! built from; the cut then takes at most the triangles the peer produced, so every row
//! compares equal budgets. The error is the two-sided sampled surface distance (200,000
//! points spread over each surface by area, each measured to the nearest point of the other
//! surface): the mean of the two directions' means, and the larger of their maxima (a sampled
//! Hausdorff distance), both as % of the bounding-box diagonal. This is what Metro and
//! MeshLab's Hausdorff filter measure.

use std::path::Path;
use std::time::Instant;

use anyhow::Result;
use glam::DVec3;
use vds_build::Builder;
use vds_format::VdtFile;
use vds_runtime::{Bound, CornerTracking, Criteria, Goal, Runtime, Viewpoint};

use crate::distance::{NearestTriangle, distances, surface_samples};

/// Samples per surface and direction.
const SAMPLES: usize = 200_000;

/// Two-sided surface distance of a simplified mesh from the original.
#[derive(Debug, Clone, Copy)]
pub struct Error {
    /// Mean of the two directions' mean distances, fraction of the diagonal.
    pub mean: f64,
    /// Largest sampled distance either way, fraction of the diagonal.
    pub max: f64,
}

/// The original surface, prepared once for measuring many simplifications of it.
struct Reference {
    samples: Vec<DVec3>,
    nearest: NearestTriangle,
    min: DVec3,
    max: DVec3,
    diagonal: f64,
}

fn corners(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<[DVec3; 3]> {
    triangles
        .iter()
        .map(|t| t.map(|v| glam::Vec3::from(positions[v as usize]).as_dvec3()))
        .collect()
}

impl Reference {
    fn new(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Reference {
        let original = corners(positions, triangles);
        let (mut min, mut max) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in original.iter().flatten() {
            min = min.min(*p);
            max = max.max(*p);
        }
        Reference {
            samples: surface_samples(&original, SAMPLES),
            nearest: NearestTriangle::new(original, min, max),
            min,
            max,
            diagonal: (max - min).length(),
        }
    }

    /// The error of `mesh` (whose vertices lie within the original's box: every proxy does).
    fn error(&self, positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Error {
        let simplified = corners(positions, triangles);
        let (mut min, mut max) = (self.min, self.max);
        for p in simplified.iter().flatten() {
            min = min.min(*p);
            max = max.max(*p);
        }
        let samples = surface_samples(&simplified, SAMPLES);
        let nearest = NearestTriangle::new(simplified, min, max);
        let forward = distances(&self.samples, &nearest);
        let back = distances(&samples, &self.nearest);
        Error {
            mean: (forward.0 + back.0) / 2.0 / self.diagonal,
            max: forward.1.max(back.1) / self.diagonal,
        }
    }
}

fn triangles_of(indices: &[u32]) -> Vec<[u32; 3]> {
    indices
        .chunks_exact(3)
        .map(|t| [t[0], t[1], t[2]])
        .collect()
}

/// Triangles that repeat another's three corners with the same winding (each repeat counted
/// once per extra copy).
fn repeats(triangles: &[[u32; 3]]) -> usize {
    let mut canonical: Vec<[u32; 3]> = triangles
        .iter()
        .map(|&t| {
            let k = (0..3).min_by_key(|&k| t[k]).unwrap_or(0);
            [t[k], t[(k + 1) % 3], t[(k + 2) % 3]]
        })
        .collect();
    canonical.sort_unstable();
    canonical.windows(2).filter(|w| w[0] == w[1]).count()
}

fn cell(count: usize, error: Error) -> String {
    format!(
        "{count:>7} {:>8.4} {:>8.4}",
        error.mean * 100.0,
        error.max * 100.0
    )
}

/// Prints the fidelity table of one mesh file at the given triangle counts: the cut of each
/// builder's tree ranked by surface error (the default) and the octree's by vertex error,
/// and both peers.
pub fn run(file: &Path, targets: &[usize]) -> Result<()> {
    let builders = [Builder::Octree, Builder::Qem];
    let mut built = Vec::new();
    for builder in builders {
        let started = Instant::now();
        let (bytes, scene) = crate::cut::vdt_bytes(file, builder)?;
        built.push((bytes, scene, started.elapsed()));
    }
    let scene = &built[0].1;
    let reference = Reference::new(&scene.positions, &scene.triangles);
    let indices: Vec<u32> = scene.triangles.iter().flatten().copied().collect();
    let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&scene.positions), 12, 0)?;
    let times: Vec<String> = builders
        .iter()
        .zip(&built)
        .map(|(b, (_, _, time))| format!("{} {:.2} s", b.name(), time.as_secs_f64()))
        .collect();
    println!(
        "{} ({} triangles; import + tree + encode: {}): triangles, mean % and max % of the diagonal",
        file.display(),
        scene.triangles.len(),
        times.join(", ")
    );
    println!(
        "  {:>7}  {:>24}  {:>24}  {:>24}  {:>24}  {:>24}  {:>9} {:>9}  {:>7} {:>7}",
        "target",
        "octree, surface",
        "octree, vertex",
        "qem, surface",
        "simplify",
        "simplify_sloppy",
        "qem/simp",
        "qem/slop",
        "oct rep",
        "qem rep"
    );
    for &target in targets {
        let simplify = triangles_of(&meshopt::simplify(
            &indices,
            &adapter,
            target * 3,
            1.0,
            meshopt::SimplifyOptions::empty(),
            None,
        ));
        let sloppy = triangles_of(&meshopt::simplify_sloppy(
            &indices,
            &adapter,
            target * 3,
            1.0,
            None,
        ));
        // The cut gets the smaller of the peers' counts, so neither peer is compared with more
        // triangles than the cut had.
        let budget = simplify.len().min(sloppy.len()).max(1) as u32;
        let cut = |bytes: &[u8], bound: Bound| -> Result<(usize, Error, usize)> {
            let mut runtime = Runtime::new(
                Box::new(VdtFile::from_bytes(bytes.to_vec())?),
                CornerTracking::Incidence,
            )?;
            let criteria = Criteria {
                bound,
                ..Criteria::default()
            };
            runtime.adjust(&Viewpoint::Independent, &criteria, Goal::Budget(budget))?;
            let mesh = vds_runtime::export::Mesh::from_cut(runtime.cut_mut());
            Ok((
                mesh.triangles.len(),
                reference.error(&mesh.positions, &mesh.triangles),
                repeats(&mesh.triangles),
            ))
        };
        let (octree_count, octree, octree_repeats) = cut(&built[0].0, Bound::Surface)?;
        let (vertex_count, vertex, _) = cut(&built[0].0, Bound::Vertex)?;
        let (qem_count, qem, qem_repeats) = cut(&built[1].0, Bound::Surface)?;
        let peer = reference.error(&scene.positions, &simplify);
        let clustered = reference.error(&scene.positions, &sloppy);
        println!(
            "  {target:>7}  {}  {}  {}  {}  {}  {:>9.2} {:>9.2}  {:>7} {:>7}",
            cell(octree_count, octree),
            cell(vertex_count, vertex),
            cell(qem_count, qem),
            cell(simplify.len(), peer),
            cell(sloppy.len(), clustered),
            qem.mean / peer.mean,
            qem.mean / clustered.mean,
            octree_repeats,
            qem_repeats
        );
    }
    println!();
    Ok(())
}
