//! `vds-cut`: exports the cut the viewer would draw from a camera (or a view-independent cut)
//! as an OBJ or PLY mesh, and measures it.
//!
//! Without `--eye`, the camera frames the whole model the way `vds-view` does on open.
//! With `--camera-path`, `--orbit` or `--fly` it replays a camera path instead, with no GPU
//! (the runtime alone), writing one CSV row per frame to `--stats`; `-o` then writes the
//! last frame's cut.
//! Exit codes: 0 success, 1 the file could not be read or written, 2 bad command line (every
//! number is checked for its range, and NaN or infinity for none, before anything is read).

use std::path::{Path, PathBuf};
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::{Parser, ValueEnum};
use serde::Serialize;
use vds_runtime::export::{Mesh, MeshFormat, write_mesh};
use vds_runtime::{
    Bound, Camera, CameraPath, CornerTracking, Criteria, FrustumMode, Gaze, Goal, Loading,
    PathSource, Runtime, Viewpoint, measure,
};

#[derive(Parser)]
#[command(
    version,
    about = "Export the view-dependent cut of a .vdt file as a mesh, or replay a camera path",
    group(clap::ArgGroup::new("goal").required(true).args(["threshold", "budget"])),
    group(clap::ArgGroup::new("replay").multiple(false).args(["camera_path", "orbit", "fly"])),
)]
struct Args {
    /// The .vdt file.
    file: PathBuf,
    /// Output mesh: .obj or .ply (a regular file or a new one, never the input). Required
    /// for a single camera; optional for a path replay (the last frame's cut).
    #[arg(short, long, required_unless_present_any = ["camera_path", "orbit", "fly"])]
    output: Option<PathBuf>,
    /// Replay the cameras of this path file (JSON, as `vds-view --camera-path` reads).
    #[arg(long, value_name = "PATH.json", conflicts_with_all = ["orbit", "fly", "eye", "target", "view_independent"])]
    camera_path: Option<PathBuf>,
    /// Replay an orbit around the model (the same path as `vds-view --orbit`).
    #[arg(long, conflicts_with_all = ["fly", "eye", "target", "view_independent"])]
    orbit: bool,
    /// Replay a fly-through of the model (the same path as `vds-view --fly`).
    #[arg(long, conflicts_with_all = ["eye", "target", "view_independent"])]
    fly: bool,
    /// Frames of a generated orbit or fly-through, or the first frames of a path file, 1 to
    /// 1000000 (default: 120 for generated paths, the whole file otherwise).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
    frames: Option<u32>,
    /// With a path replay: one CSV row per frame (frame, adjust_ms, active_triangles,
    /// added, removed, changed, nodes_visited, unfolds, folds, deferred_unfolds,
    /// resident_bytes, pages_resident, pages_loaded and pages_evicted since the start,
    /// pages_pending, effective_threshold, rss_anon_bytes: the process's anonymous
    /// resident memory from /proc/self/status, empty where there is none; pinned_bytes: of
    /// resident_bytes, the pages the cut holds; refusals: pages and growth steps the budget
    /// refused since the start).
    #[arg(long, value_name = "OUT.csv", requires = "replay")]
    stats: Option<PathBuf>,
    /// With a path replay: start frames at most this often, in milliseconds (a display's
    /// pace, e.g. 16.7 for 60 Hz), so that background loading has the time between frames it
    /// would have in the viewer; 0 (the default) replays as fast as the adjusts run.
    #[arg(long, default_value_t = 0.0, value_parser = pace, requires = "replay")]
    pace_ms: f32,
    /// How pages are loaded: on the adjusting thread when first needed, or by background
    /// threads (an unfold then waits for its page and happens in a later frame; a single
    /// camera's cut is adjusted again as pages arrive until it settles, a replay's frames
    /// are not).
    #[arg(long, value_enum, default_value_t = LoadingMode::Synchronous)]
    loading: LoadingMode,
    /// Memory budget for the decoded tree and the cut, e.g. 512MiB or 2GiB (default: 1 GiB,
    /// or a quarter of physical memory if that is less). Pages below the boundary are
    /// evicted to stay within it; when the cut itself does not fit, the threshold is raised
    /// until it does (the effective threshold is reported).
    #[arg(long, value_name = "SIZE", value_parser = vds_runtime::size::parse_size)]
    memory_budget: Option<u64>,
    /// Background loading threads, 1 to 64 (default: the cores but one, at most 4).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=64))]
    loading_threads: Option<u32>,
    /// Threads the threshold pass tests active entries on, 1 to 256 (folds and unfolds stay
    /// on one; the cut is the same whatever the number).
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=256))]
    adjust_threads: u32,
    /// Threshold adjusts by a sweep from scratch each frame (the top-down cut, page by page)
    /// instead of the incremental pass; fetches no page ahead of need.
    #[arg(long, conflicts_with_all = ["prevent_folds", "adjust_threads"])]
    sweep: bool,
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
    /// What a --budget cut spends its triangles against: how far the surface moves (the
    /// builder's quadric estimate), or how far any vertex moves (the error radius, the
    /// paper's measure). Default: surface. A --threshold cut always holds the vertex bound.
    #[arg(long, value_enum)]
    bound: Option<BoundArg>,
    /// How active triangles' corners are kept: incidence lists, lazy evaluation when the cut
    /// is read, or no per-triangle state at all (corners from leaf ranks when read; changes
    /// per node). --prevent-folds needs incidence lists.
    #[arg(long, value_enum, default_value_t = CornersArg::Incidence)]
    corners: CornersArg,
    /// Check the cut against a recomputation from scratch.
    #[arg(long)]
    verify: bool,
    /// Print figures as JSON.
    #[arg(long)]
    json: bool,
}

#[derive(Clone, Copy, PartialEq, ValueEnum)]
enum LoadingMode {
    Synchronous,
    Background,
}

#[derive(Clone, Copy, ValueEnum)]
enum CornersArg {
    Incidence,
    Lazy,
    Ranks,
}

#[derive(Clone, Copy, ValueEnum)]
enum BoundArg {
    Surface,
    Vertex,
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

/// A frame pace in milliseconds, from 0 to 10,000.
fn pace(text: &str) -> Result<f32, String> {
    match finite(text)? {
        v if (0.0..=10_000.0).contains(&v) => Ok(v),
        v => Err(format!("expected milliseconds from 0 to 10000, got {v}")),
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
    /// Pages resident when the cut settled.
    pages_loaded: u32,
    pages: u32,
    /// Bytes the runtime held then, and the budget.
    resident_bytes: u64,
    memory_budget: u64,
    /// The threshold the cut meets: the one asked for, or a larger one when the memory
    /// budget could not hold that cut (threshold mode only).
    effective_threshold: Option<f32>,
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
    if args.bound.is_some() && args.budget.is_none() {
        // (clap's `requires` does not see through the goal's argument group here.)
        <Args as clap::CommandFactory>::command()
            .error(
                clap::error::ErrorKind::MissingRequiredArgument,
                "--bound needs --budget: a threshold always holds the vertex bound",
            )
            .exit();
    }
    if let Err(error) = run(&args) {
        eprintln!("vds-cut: {error:#}");
        std::process::exit(1);
    }
}

/// Refuses, before anything is read, an output that is not a regular file or that is the
/// input itself (by device and inode, however either is spelt).
fn check_output(output: &Path, input: &Path) -> Result<()> {
    vds_format::resolve_output(output)?;
    if vds_format::same_file(input, output).unwrap_or(false) {
        bail!(
            "{}: is the input {}; refusing to overwrite it",
            output.display(),
            input.display()
        );
    }
    Ok(())
}

fn run(args: &Args) -> Result<()> {
    let format = match &args.output {
        Some(output) => {
            let Some(format) = MeshFormat::of(output) else {
                bail!("{}: the output must end in .obj or .ply", output.display());
            };
            check_output(output, &args.file)?;
            Some((output.as_path(), format))
        }
        None => None,
    };
    if let Some(stats) = &args.stats {
        check_output(stats, &args.file)?;
    }
    let start = Instant::now();
    let file = vds_format::VdtFile::open(&args.file).map_err(naming(&args.file))?;
    let part_names = file.metadata().part_names.clone();
    let tracking = match args.corners {
        CornersArg::Incidence => CornerTracking::Incidence,
        CornersArg::Lazy => CornerTracking::Lazy,
        CornersArg::Ranks => CornerTracking::Ranks,
    };
    if args.prevent_folds && tracking != CornerTracking::Incidence {
        bail!(
            "--prevent-folds needs --corners incidence: only incidence lists see the triangles a fold moves"
        );
    }
    let loading = match args.loading {
        LoadingMode::Synchronous => Loading::Synchronous,
        LoadingMode::Background => Loading::Background {
            threads: args
                .loading_threads
                .map_or_else(vds_runtime::default_loading_threads, |n| n as usize),
        },
    };
    let mut runtime = Runtime::with_loading(Box::new(file), tracking, loading)
        .with_context(|| format!("{}", args.file.display()))?;
    runtime.set_adjust_threads(args.adjust_threads as usize);
    runtime.set_sweep(args.sweep);
    runtime.set_memory_budget(
        args.memory_budget
            .unwrap_or_else(vds_runtime::default_memory_budget),
    );
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
        bound: match args.bound {
            Some(BoundArg::Surface) | None => Bound::Surface,
            Some(BoundArg::Vertex) => Bound::Vertex,
        },
    };
    let goal = match (args.threshold, args.budget) {
        (Some(t), _) => Goal::Threshold(t),
        (None, Some(n)) => Goal::Budget(n),
        (None, None) => bail!("give --threshold or --budget"),
    };
    if args.camera_path.is_some() || args.orbit || args.fly {
        return replay(args, runtime, &criteria, goal, format, &part_names);
    }
    let (output, format) = format.expect("clap requires -o without a path replay");

    let start = Instant::now();
    let mut frame = runtime
        .adjust(&viewpoint, &criteria, goal)
        .with_context(|| format!("{}", args.file.display()))?;
    // With background loading one adjust leaves unfolds waiting for pages: the exported cut
    // is the settled one, so adjust again as pages arrive until nothing waits (a page that
    // cannot be read fails the export).
    // Under a memory budget that cannot hold the cut, pages are refused (or the pinned pages
    // are over it) and the effective threshold rises each adjust until the cut fits: adjust
    // again until it fits with nothing refused, so that the exported cut meets the threshold
    // it reports (each round raises the threshold by a quarter, so this ends).
    let mut refused = 0;
    let mut rounds = 0;
    while rounds < 1000
        && (frame.stats.deferred_unfolds > 0
            || runtime.pending_pages() > 0
            || frame.memory.refusals > std::mem::replace(&mut refused, frame.memory.refusals)
            || frame.memory.resident_bytes > frame.memory.budget_bytes)
    {
        rounds += 1;
        runtime.wait_for_pages();
        if let Some(error) = runtime.take_page_errors().into_iter().next() {
            return Err(anyhow::Error::new(error).context(args.file.display().to_string()));
        }
        frame = runtime
            .adjust(&viewpoint, &criteria, goal)
            .with_context(|| format!("{}", args.file.display()))?;
    }
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
        Some(c) if criteria.backface => Some(
            measure::facing_vertices(runtime.cut().store(), &positions, c.view().eye)
                .with_context(|| format!("{}", args.file.display()))?,
        ),
        _ => None,
    };
    let deviation = camera.map(|c| {
        measure::screen_deviation(runtime.cut(), &c.view(), &positions, facing.as_deref())
    });
    let max_object_error = measure::object_deviation(runtime.cut(), &positions);
    let measure_ms = start.elapsed().as_secs_f64() * 1e3;

    let start = Instant::now();
    let mesh = Mesh::from_cut(runtime.cut_mut());
    write_mesh(output, &mesh, format, &part_names).context("cannot write the cut")?;
    let write_ms = start.elapsed().as_secs_f64() * 1e3;

    let cut = runtime.cut();
    let report = Report {
        file: args.file.display().to_string(),
        output: output.display().to_string(),
        triangles: cut.active_triangle_count(),
        vertices: mesh.positions.len(),
        active_nodes: cut.active_node_count(),
        boundary_nodes: cut.boundary().len(),
        nodes_visited: frame.stats.visited,
        pages_loaded: pages.0,
        pages: pages.1,
        resident_bytes: frame.memory.resident_bytes,
        memory_budget: frame.memory.budget_bytes,
        effective_threshold: frame.effective_threshold,
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
        if let (Some(effective), Goal::Threshold(asked)) = (frame.effective_threshold, goal)
            && effective > asked
        {
            println!(
                "threshold raised from {asked} to {effective} px: the cut at {asked} px does not \
                 fit in the {} memory budget",
                vds_runtime::size::format_size(frame.memory.budget_bytes)
            );
        }
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

/// `--camera-path`, `--orbit`, `--fly`: adjusts the cut for each camera in turn, as the
/// viewer would, timing each adjust; writes the per-frame CSV and, with `-o`, the last cut.
fn replay(
    args: &Args,
    mut runtime: Runtime,
    criteria: &Criteria,
    goal: Goal,
    output: Option<(&Path, MeshFormat)>,
    part_names: &[String],
) -> Result<()> {
    let root = runtime.cut().node(0);
    let source = PathSource::from_flags(args.camera_path.as_deref(), args.fly);
    let mut path = CameraPath::from_source(
        source,
        root.sphere_center,
        root.sphere_radius,
        args.frames.unwrap_or(120),
        args.size,
    )
    .map_err(anyhow::Error::msg)?;
    if let Some(frames) = args.frames {
        path.cameras.truncate(frames as usize);
    }
    let mut rows = String::from(
        "frame,adjust_ms,active_triangles,added,removed,changed,nodes_visited,unfolds,folds,\
         deferred_unfolds,resident_bytes,pages_resident,pages_loaded,pages_evicted,pages_pending,\
         effective_threshold,rss_anon_bytes,pinned_bytes,refusals\n",
    );
    let mut adjust_ms = Vec::with_capacity(path.cameras.len());
    let mut errors = 0usize;
    let pace = std::time::Duration::from_secs_f64(f64::from(args.pace_ms) / 1e3);
    let replay_start = Instant::now();
    for (i, camera) in path.cameras.iter().enumerate() {
        if let Some(wait) = (pace * i as u32).checked_sub(replay_start.elapsed()) {
            std::thread::sleep(wait);
        }
        let start = Instant::now();
        let frame = runtime
            .adjust(&Viewpoint::Camera(*camera), criteria, goal)
            .with_context(|| format!("{}: frame {i}", args.file.display()))?;
        let ms = start.elapsed().as_secs_f64() * 1e3;
        adjust_ms.push(ms);
        for error in runtime.take_page_errors() {
            errors += 1;
            eprintln!("vds-cut: {}: {error}", args.file.display());
        }
        let memory = &frame.memory;
        let (loaded, evicted) = (memory.pages_loaded, memory.pages_evicted);
        let (stats, changes) = (&frame.stats, &frame.changes);
        rows += &format!(
            "{i},{ms:.4},{},{},{},{},{},{},{},{},{},{},{loaded},{evicted},{},{},{},{},{}\n",
            runtime.cut().active_triangle_count(),
            changes.added,
            changes.removed,
            changes.changed,
            stats.visited,
            stats.unfolds,
            stats.folds,
            stats.deferred_unfolds,
            memory.resident_bytes,
            memory.pages_resident,
            memory.pages_pending,
            frame
                .effective_threshold
                .map_or_else(String::new, |t| format!("{t}")),
            rss_anon_bytes().map_or_else(String::new, |b| b.to_string()),
            memory.pinned_bytes,
            memory.refusals,
        );
    }
    if let Some(stats) = &args.stats {
        vds_format::write_atomically(stats, |w| w.write_all(rows.as_bytes()))
            .context("cannot write the statistics")?;
    }
    if let Some((output, format)) = output {
        let mesh = Mesh::from_cut(runtime.cut_mut());
        write_mesh(output, &mesh, format, part_names).context("cannot write the cut")?;
    }
    adjust_ms.sort_by(f64::total_cmp);
    let at = |q: f64| adjust_ms[((adjust_ms.len() - 1) as f64 * q).round() as usize];
    let (pages, total) = runtime.cut().store().pages_resident();
    println!(
        "{} frames: adjust median {:.3} ms, p99 {:.3} ms, max {:.3} ms; {} triangles at the end; \
         pages {pages}/{total}, {} pending{}",
        adjust_ms.len(),
        at(0.5),
        at(0.99),
        at(1.0),
        runtime.cut().active_triangle_count(),
        runtime.pending_pages(),
        if errors > 0 {
            format!(", {errors} unreadable")
        } else {
            String::new()
        }
    );
    Ok(())
}

/// The process's anonymous resident memory (`RssAnon` of `/proc/self/status`), where the
/// system reports it.
fn rss_anon_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("RssAnon:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}
