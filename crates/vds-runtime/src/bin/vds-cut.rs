//! `vds-cut`: exports the cut the viewer would draw from a camera (or a view-independent cut)
//! as an OBJ or PLY mesh, and measures it.
//!
//! Without `--eye`, the camera frames the whole model the way `vds-view` does on open.
//! Exit codes: 0 success, 1 the file could not be read or written, 2 bad command line (every
//! number is checked for its range, and NaN or infinity for none, before anything is read).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, ValueEnum};
use serde::Serialize;
use vds_runtime::export::{Mesh, MeshFormat, write_mesh};
use vds_runtime::{
    Camera, CornerTracking, Criteria, FrustumMode, Gaze, Goal, Runtime, Viewpoint, measure,
};

#[derive(Parser)]
#[command(
    version,
    about = "Export the view-dependent cut of a .vdt file as a mesh",
    group(clap::ArgGroup::new("goal").required(true).args(["threshold", "budget"])),
)]
struct Args {
    /// The .vdt file.
    file: PathBuf,
    /// Output mesh: .obj or .ply (a regular file or a new one, never the input).
    #[arg(short, long)]
    output: PathBuf,
    /// Screen-space error threshold in pixels (scene units with --view-independent); a finite
    /// number, at least 0.
    #[arg(long, value_parser = non_negative)]
    threshold: Option<f32>,
    /// Triangle budget: the best cut of at most this many triangles (at least 1).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    budget: Option<u32>,
    /// Eye position X,Y,Z (default: framing the whole model).
    #[arg(long, value_parser = parse_vec3, conflicts_with = "view_independent")]
    eye: Option<[f32; 3]>,
    /// Point looked at X,Y,Z (default: the model's centre).
    #[arg(long, value_parser = parse_vec3, conflicts_with = "view_independent")]
    target: Option<[f32; 3]>,
    /// Up direction X,Y,Z (not zero).
    #[arg(long, value_parser = parse_direction, default_value = "0,1,0")]
    up: [f32; 3],
    /// Vertical field of view in degrees, above 0 and below 180.
    #[arg(long, default_value_t = 45.0, value_parser = parse_fov)]
    fov: f32,
    /// Viewport size WIDTHxHEIGHT in pixels, each from 1 to 16384.
    #[arg(long, value_parser = parse_size, default_value = "1920x1080")]
    size: (u32, u32),
    /// Object-space error instead of a camera: no culling, no cones.
    #[arg(long)]
    view_independent: bool,
    /// Do not hold silhouettes to a tighter threshold.
    #[arg(long)]
    no_silhouette: bool,
    /// Silhouette threshold as a fraction of the threshold, from 0 to 1.
    #[arg(long, default_value_t = 0.25, value_parser = fraction)]
    silhouette_factor: f32,
    /// Do not fold entirely backfacing regions.
    #[arg(long)]
    no_backface: bool,
    /// What nodes outside the view frustum do.
    #[arg(long, value_enum, default_value_t = Frustum::Fold)]
    frustum: Frustum,
    /// Gaze falloff: the threshold grows by this factor per radian away from the view
    /// direction (0: off); a finite number, at least 0.
    #[arg(long, default_value_t = 0.0, value_parser = non_negative)]
    gaze_falloff: f32,
    /// Refuse folds that would flip a triangle.
    #[arg(long)]
    prevent_folds: bool,
    /// Keep corners by lazy evaluation instead of incidence lists.
    #[arg(long)]
    lazy: bool,
    /// Check the cut against a recomputation from scratch.
    #[arg(long)]
    verify: bool,
    /// Print figures as JSON.
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, ValueEnum)]
enum Frustum {
    Fold,
    Ignore,
    Off,
}

fn parse_vec3(text: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = text.split(',').collect();
    let values: Result<Vec<f32>, _> = parts.iter().map(|p| p.trim().parse::<f32>()).collect();
    match values {
        Ok(v) if v.len() == 3 && v.iter().all(|x| x.is_finite()) => Ok([v[0], v[1], v[2]]),
        _ => Err(format!(
            "expected X,Y,Z with three finite numbers, got {text:?}"
        )),
    }
}

/// A direction: three finite numbers, not all zero.
fn parse_direction(text: &str) -> Result<[f32; 3], String> {
    let v = parse_vec3(text)?;
    if v == [0.0; 3] {
        return Err(format!("expected a direction, not zero, got {text:?}"));
    }
    Ok(v)
}

/// The largest viewport side: wgpu's limit on a texture side on most adapters, and what the
/// viewer accepts.
const MAX_SIZE: u32 = 16384;

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {text:?}"))?;
    let side = 1..=MAX_SIZE;
    match (w.trim().parse::<u32>(), h.trim().parse::<u32>()) {
        (Ok(w), Ok(h)) if side.contains(&w) && side.contains(&h) => Ok((w, h)),
        _ => Err(format!(
            "expected WIDTHxHEIGHT, each from 1 to {MAX_SIZE}, got {text:?}"
        )),
    }
}

/// A finite number (NaN and infinities are refused: they would poison every comparison).
fn finite(text: &str) -> Result<f32, String> {
    match text.trim().parse::<f32>() {
        Ok(v) if v.is_finite() => Ok(v),
        Ok(_) => Err(format!("expected a finite number, got {text:?}")),
        Err(e) => Err(format!("expected a number, got {text:?}: {e}")),
    }
}

/// A finite number, at least 0.
fn non_negative(text: &str) -> Result<f32, String> {
    match finite(text)? {
        v if v >= 0.0 => Ok(v),
        v => Err(format!("expected a number of at least 0, got {v}")),
    }
}

/// A finite number from 0 to 1.
fn fraction(text: &str) -> Result<f32, String> {
    match finite(text)? {
        v if (0.0..=1.0).contains(&v) => Ok(v),
        v => Err(format!("expected a number from 0 to 1, got {v}")),
    }
}

/// A field of view in degrees, above 0 and below 180.
fn parse_fov(text: &str) -> Result<f32, String> {
    match finite(text)? {
        v if v > 0.0 && v < 180.0 => Ok(v),
        v => Err(format!("expected degrees above 0 and below 180, got {v}")),
    }
}

/// An error of reading the `.vdt` file `path`, named for it (the operating system's errors
/// already are).
fn naming(path: &Path) -> impl FnOnce(vds_format::VdtError) -> anyhow::Error + '_ {
    move |error| match error {
        error @ (vds_format::VdtError::Io { .. } | vds_format::VdtError::NotAFile { .. }) => {
            error.into()
        }
        error => anyhow::Error::new(error).context(path.display().to_string()),
    }
}

#[derive(Serialize)]
struct Report {
    file: String,
    output: String,
    triangles: u32,
    vertices: usize,
    active_nodes: u32,
    boundary_nodes: usize,
    nodes_visited: u32,
    pages_loaded: u32,
    pages: u32,
    /// The largest screen-space distance between a visible original vertex (in the frustum
    /// and, with backface simplification, on a triangle facing the eye) and its proxy, in
    /// pixels; absent when view-independent.
    max_deviation_px: Option<f64>,
    visible_vertices: Option<u64>,
    /// The largest object-space distance of any original vertex from its proxy.
    max_object_error: f32,
    camera: Option<Camera>,
    open_ms: f64,
    adjust_ms: f64,
    measure_ms: f64,
    write_ms: f64,
}

fn main() {
    let args = Args::parse();
    if let Err(error) = run(&args) {
        eprintln!("vds-cut: {error:#}");
        std::process::exit(1);
    }
}

fn run(args: &Args) -> Result<()> {
    let Some(format) = MeshFormat::of(&args.output) else {
        bail!(
            "{}: the output must end in .obj or .ply",
            args.output.display()
        );
    };
    // Refused before anything is read: an output that is not a regular file, or that is the
    // input itself (by device and inode, however either is spelt).
    vds_format::resolve_output(&args.output)?;
    if vds_format::same_file(&args.file, &args.output).unwrap_or(false) {
        bail!(
            "{}: is the input {}; refusing to overwrite it",
            args.output.display(),
            args.file.display()
        );
    }
    let start = Instant::now();
    let file = vds_format::VdtFile::open(&args.file).map_err(naming(&args.file))?;
    let part_names = file.metadata().part_names.clone();
    let tracking = if args.lazy {
        CornerTracking::Lazy
    } else {
        CornerTracking::Incidence
    };
    let mut runtime = Runtime::new(Box::new(file), tracking)
        .with_context(|| format!("{}", args.file.display()))?;
    let open_ms = start.elapsed().as_secs_f64() * 1e3;

    let root = runtime.cut().node(0);
    let camera = (!args.view_independent).then(|| {
        let (width, height) = args.size;
        let framing = Camera::framing(
            root.sphere_center,
            root.sphere_radius,
            [1.0, 0.6, 1.4],
            width,
            height,
        );
        Camera {
            eye: args.eye.unwrap_or(framing.eye),
            target: args.target.unwrap_or(root.sphere_center),
            up: args.up,
            fov_y_degrees: args.fov,
            width,
            height,
            near: framing.near,
        }
    });
    let viewpoint = camera.map_or(Viewpoint::Independent, Viewpoint::Camera);
    let criteria = Criteria {
        silhouette_factor: (!args.no_silhouette).then_some(args.silhouette_factor),
        backface: !args.no_backface,
        frustum: match args.frustum {
            Frustum::Fold => FrustumMode::Fold,
            Frustum::Ignore => FrustumMode::Ignore,
            Frustum::Off => FrustumMode::Off,
        },
        gaze: (args.gaze_falloff > 0.0).then(|| Gaze {
            direction: camera.map_or([0.0, 0.0, -1.0], |c| c.view().forward.into()),
            falloff: args.gaze_falloff,
        }),
        prevent_mesh_folds: args.prevent_folds,
    };
    let goal = match (args.threshold, args.budget) {
        (Some(t), _) => Goal::Threshold(t),
        (None, Some(n)) => Goal::Budget(n),
        (None, None) => bail!("give --threshold or --budget"),
    };

    let start = Instant::now();
    let frame = runtime
        .adjust(&viewpoint, &criteria, goal)
        .with_context(|| format!("{}", args.file.display()))?;
    let adjust_ms = start.elapsed().as_secs_f64() * 1e3;
    let pages = runtime.cut().store().pages_resident();

    let start = Instant::now();
    if args.verify {
        runtime
            .cut_mut()
            .check()
            .map_err(anyhow::Error::msg)
            .with_context(|| format!("{}: the cut is inconsistent", args.file.display()))?;
    }
    let positions = runtime
        .leaf_positions()
        .with_context(|| format!("{}", args.file.display()))?;
    // With backface simplification on, vertices whose every triangle faces away are hidden
    // and may move further; the deviation is measured over the others.
    let facing = match camera {
        Some(c) if criteria.backface => Some(measure::facing_vertices(
            runtime.cut().store(),
            &positions,
            c.view().eye,
        )),
        _ => None,
    };
    let deviation = camera.map(|c| {
        measure::screen_deviation(runtime.cut(), &c.view(), &positions, facing.as_deref())
    });
    let max_object_error = measure::object_deviation(runtime.cut(), &positions);
    let measure_ms = start.elapsed().as_secs_f64() * 1e3;

    let start = Instant::now();
    let mesh = Mesh::from_cut(runtime.cut_mut());
    write_mesh(&args.output, &mesh, format, &part_names).context("cannot write the cut")?;
    let write_ms = start.elapsed().as_secs_f64() * 1e3;

    let cut = runtime.cut();
    let report = Report {
        file: args.file.display().to_string(),
        output: args.output.display().to_string(),
        triangles: cut.active_triangle_count(),
        vertices: mesh.positions.len(),
        active_nodes: cut.active_node_count(),
        boundary_nodes: cut.boundary().len(),
        nodes_visited: frame.stats.visited,
        pages_loaded: pages.0,
        pages: pages.1,
        max_deviation_px: deviation.map(|d| d.max_px),
        visible_vertices: deviation.map(|d| d.visible_vertices),
        max_object_error,
        camera,
        open_ms,
        adjust_ms,
        measure_ms,
        write_ms,
    };
    if args.json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!(
            "{}: {} triangles, {} vertices ({} active nodes); pages {}/{}",
            report.output,
            report.triangles,
            report.vertices,
            report.active_nodes,
            report.pages_loaded,
            report.pages
        );
        if let Some(d) = deviation {
            println!(
                "largest screen-space deviation {:.3} px over {} visible vertices",
                d.max_px, d.visible_vertices
            );
        }
        println!(
            "adjust {:.2} ms (open {:.2} ms, measure {:.1} ms, write {:.1} ms)",
            adjust_ms, open_ms, measure_ms, write_ms
        );
    }
    Ok(())
}
