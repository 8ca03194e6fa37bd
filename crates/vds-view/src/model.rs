//! Opening what the user gave: a `.vdt` file (memory-mapped, pages loaded as the cut reaches
//! them), any mesh file the importer reads (the tree is built in memory first), or nothing
//! (the bundled demo assembly, embedded in the binary).

use std::path::Path;

use anyhow::{Context, Result};
use vds_format::VdtFile;
use vds_runtime::{CornerTracking, Loading, Runtime};

use crate::parts::Parts;

/// An opened model.
pub struct Model {
    /// The runtime over its tree.
    pub runtime: Runtime,
    /// What to call it in messages.
    pub name: String,
    /// Triangles in the tree (the full-detail triangle count).
    pub triangles: u64,
    /// The original mesh, for brute-force comparison draws (kept only when asked for).
    pub mesh: Option<vds_import::Scene>,
    /// The assembly's parts, from the file's metadata.
    pub parts: Parts,
    /// The model's bounds along x, y and z: `[min, max]` each.
    pub bounds: [[f32; 2]; 3],
}

/// The bounds a file's metadata states, per axis.
fn bounds_of(metadata: &vds_format::Metadata) -> [[f32; 2]; 3] {
    std::array::from_fn(|k| [metadata.bounds_min[k], metadata.bounds_max[k]])
}

/// Opens `path` (or the demo when `None`). `keep_mesh` keeps the original triangles for
/// brute-force draws (only possible for mesh inputs: a `.vdt` file is decoded fully for it).
/// Pages are loaded as `loading` says, within `memory_budget` bytes (default:
/// [`vds_runtime::default_memory_budget`]). A mesh's tree is made by `builder`; the cut keeps
/// its corners as `tracking` says.
pub fn open(
    path: Option<&Path>,
    keep_mesh: bool,
    loading: Loading,
    memory_budget: Option<u64>,
    builder: vds_build::Builder,
    tracking: CornerTracking,
) -> Result<Model> {
    let budget = memory_budget.unwrap_or_else(vds_runtime::default_memory_budget);
    let (scene, name) = match path {
        Some(path)
            if path
                .extension()
                .is_some_and(|e| e.eq_ignore_ascii_case("vdt")) =>
        {
            let file = VdtFile::open(path).map_err(|error| match error {
                // The operating system's errors name the file already.
                error @ (vds_format::VdtError::Io { .. }
                | vds_format::VdtError::NotAFile { .. }) => anyhow::Error::new(error),
                error => anyhow::Error::new(error).context(path.display().to_string()),
            })?;
            let triangles = file.header().triangle_count.get();
            let parts = Parts::of(file.metadata());
            let bounds = bounds_of(file.metadata());
            let mut runtime = Runtime::with_loading(Box::new(file), tracking, loading)
                .with_context(|| path.display().to_string())?;
            runtime.set_memory_budget(budget);
            let mesh = keep_mesh
                .then(|| mesh_of(&mut runtime))
                .transpose()
                .with_context(|| path.display().to_string())?;
            return Ok(Model {
                runtime,
                name: path.display().to_string(),
                triangles,
                mesh,
                parts,
                bounds,
            });
        }
        Some(path) => (
            vds_import::load_file(path, &Default::default())?,
            path.display().to_string(),
        ),
        None => (crate::demo::scene()?, crate::demo::NAME.to_string()),
    };
    let mut scene = scene;
    for warning in &scene.warnings {
        eprintln!("vds-view: warning: {warning}");
    }
    let bytes = vds_build::encode_scene_by(
        &mut scene,
        concat!("vds-view ", env!("CARGO_PKG_VERSION")),
        &Default::default(),
        builder,
    )
    .with_context(|| format!("building the tree of {name}"))?;
    let file = VdtFile::from_bytes(bytes).with_context(|| format!("the tree of {name}"))?;
    let parts = Parts::of(file.metadata());
    let bounds = bounds_of(file.metadata());
    let mut runtime = Runtime::with_loading(Box::new(file), tracking, loading)
        .with_context(|| format!("the tree of {name}"))?;
    runtime.set_memory_budget(budget);
    Ok(Model {
        runtime,
        name,
        triangles: scene.triangles.len() as u64,
        mesh: keep_mesh.then_some(scene),
        parts,
        bounds,
    })
}

/// The original mesh of a `.vdt` file: leaves as vertices, every triangle by leaf rank.
fn mesh_of(runtime: &mut Runtime) -> Result<vds_import::Scene> {
    let positions = runtime.leaf_positions()?;
    let (mut triangles, mut triangle_parts) = (Vec::new(), Vec::new());
    runtime.cut().store().for_each_page(|page| {
        for t in &page.triangles {
            triangles.push(t.corners.map(|c| c.get()));
            triangle_parts.push(t.part.get());
        }
    })?;
    Ok(vds_import::Scene {
        positions,
        triangles,
        triangle_parts,
        part_names: Vec::new(),
        parts: Vec::new(),
        stats: Default::default(),
        warnings: Vec::new(),
    })
}
