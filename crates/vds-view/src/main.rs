//! `vds-view`: the vds viewer.
//!
//! `vds-view [FILE]` opens a window on a `.vdt` file, a mesh file (its tree is built in memory
//! first) or, with no file, the bundled demo assembly. `--headless` renders a camera path
//! offscreen instead: PNGs and a CSV of per-frame figures. Exit codes: 0 success, 1 failure
//! (named, with the file it is about), 2 bad command line (every number is checked for its
//! range, and NaN or infinity for none, before anything is opened).
//!
//! A design review's state starts from the command line in both modes: `--hide` and
//! `--isolate` (part names or assembly paths, shell globs), `--section` planes and the
//! colouring; headless, `--pick` and `--measure` print what the first frame shows at given
//! pixels as JSON.

mod controls;
mod demo;
mod headless;
mod hud;
mod model;
mod parts;
mod probe;
mod review;
mod simplify;
mod window;

use std::num::NonZero;
use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Parser, ValueEnum};
use vds_render::{Colouring, MAX_SECTIONS, SectionPlane, Shading, Style};
use vds_runtime::{CameraPath, Criteria, FrustumMode, Gaze, Goal, PathSource};

use crate::headless::Headless;
use crate::simplify::Settings;

#[derive(Parser)]
#[command(version, about = "View a model with view-dependent simplification")]
struct Args {
    /// A .vdt file or a mesh (.obj, .gltf, .glb, .ply, .stl); the bundled demo when absent.
    file: Option<PathBuf>,
    /// Render offscreen along a camera path instead of opening a window.
    #[arg(long)]
    headless: bool,
    /// Camera path JSON: `{"cameras": [camera, ...]}`, each camera with `eye`, `target`,
    /// `up` (three numbers each), `fov_y_degrees`, `width`, `height` and `near`.
    #[arg(long, conflicts_with = "orbit")]
    camera_path: Option<PathBuf>,
    /// Generate an orbit around the model as the camera path.
    #[arg(long)]
    orbit: bool,
    /// Generate a loop flown through the model (at 60% of its radius) as the camera path.
    #[arg(long, conflicts_with_all = ["orbit", "camera_path"])]
    fly: bool,
    /// Frames to render: the first N of the camera path (1 to 1000000).
    #[arg(long, value_parser = frame_count())]
    frames: Option<usize>,
    /// Length of a generated orbit or fly-through loop in frames, 1 to 1000000 (default:
    /// --frames, or 120); with a longer loop, `--frames` renders its first steps at that
    /// smaller pace.
    #[arg(long, value_parser = frame_count())]
    path_frames: Option<usize>,
    /// Image or window size WIDTHxHEIGHT, each from 1 to 16384.
    #[arg(long, value_parser = parse_size, default_value = "1280x720")]
    size: (u32, u32),
    /// Directory for the PNGs of a headless run.
    #[arg(long)]
    out: Option<PathBuf>,
    /// CSV file for per-frame figures of a headless run.
    #[arg(long)]
    stats: Option<PathBuf>,
    /// Screen-space error threshold in pixels; a finite number, at least 0.
    #[arg(long, default_value_t = 1.0, conflicts_with = "budget", value_parser = non_negative)]
    threshold: f32,
    /// Triangle budget instead of a threshold (at least 1).
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..))]
    budget: Option<u32>,
    /// What a --budget cut spends its triangles against: how far the surface moves (the
    /// builder's quadric estimate; the default), or how far any vertex moves (the error
    /// radius). A threshold always holds the vertex bound.
    #[arg(long, value_enum)]
    bound: Option<BoundArg>,
    /// Simplify on a separate thread (frames never wait for simplification).
    #[arg(long = "async")]
    asynchronous: bool,
    /// Draw the original mesh instead of the cut (for comparison).
    #[arg(long)]
    brute_force: bool,
    /// Triangle colouring: the file's part colours (palette colours for parts without
    /// one), a palette colour per part, node depth, or screen-space error.
    #[arg(long, value_enum, default_value_t = ColouringArg::File)]
    colouring: ColouringArg,
    /// Hide the parts whose name or assembly path matches this shell glob (`*` also
    /// crosses `/`), with everything below them; repeatable.
    #[arg(long, value_name = "NAME_GLOB")]
    hide: Vec<String>,
    /// Show only the parts matching this glob and what lies below them; repeatable (the
    /// union is shown). Applied before --hide.
    #[arg(long, value_name = "NAME_GLOB")]
    isolate: Vec<String>,
    /// A section plane "nx,ny,nz,d": everything where nx·x + ny·y + nz·z + d > 0 (the side
    /// the normal points to) is cut away; up to three.
    #[arg(long, value_name = "NX,NY,NZ,D", value_parser = parse_section)]
    section: Vec<SectionPlane>,
    /// Headless: print, as JSON, the part drawn at pixel X,Y of the first frame (x from the
    /// left, y from the top) and the picked world position.
    #[arg(long, value_name = "X,Y", value_parser = parse_pixel, requires = "headless")]
    pick: Option<(u32, u32)>,
    /// Headless: pick two pixels of the first frame and print, as JSON, the distance between
    /// the original vertices nearest the picked points.
    #[arg(long, value_name = "X1,Y1,X2,Y2", value_parser = parse_pixel_pair, requires = "headless")]
    measure: Option<[(u32, u32); 2]>,
    /// Shading.
    #[arg(long, value_enum, default_value_t = ShadingArg::Faceted)]
    shading: ShadingArg,
    /// Draw triangle edges.
    #[arg(long)]
    wireframe: bool,
    /// Do not hold silhouettes to a tighter threshold.
    #[arg(long)]
    no_silhouette: bool,
    /// Do not fold backfacing regions.
    #[arg(long)]
    no_backface: bool,
    /// What nodes outside the view frustum do.
    #[arg(long, value_enum, default_value_t = FrustumArg::Fold)]
    frustum: FrustumArg,
    /// Gaze falloff per radian away from the view direction (0: off); a finite number, at
    /// least 0.
    #[arg(long, default_value_t = 0.0, value_parser = non_negative)]
    gaze_falloff: f32,
    /// Check every cut and every rendered frame's consistency (slow).
    #[arg(long)]
    verify: bool,
    /// Headless: stop adjusting after frame N and draw the frozen cut along the rest of the
    /// path.
    #[arg(long)]
    freeze_after: Option<usize>,
    /// Headless: run the path twice in one process, with VDS and drawing the full model
    /// brute force, and print both and their ratio.
    #[arg(long, conflicts_with = "brute_force")]
    compare: bool,
    /// How pages are loaded: by background threads (no frame waits for a page; a region
    /// refines a frame or so after its page arrives) or on the simplifying thread when first
    /// needed (every adjust settles the cut). Default: background in a window, synchronous
    /// headless (so runs are repeatable).
    #[arg(long, value_enum)]
    loading: Option<LoadingArg>,
    /// Memory budget for the decoded tree and the cut, e.g. 512MiB or 2GiB (default: 1 GiB,
    /// or a quarter of physical memory if that is less). Pages below the boundary are
    /// evicted to stay within it; when the cut itself does not fit, the threshold is raised
    /// until it does (the panel and --stats show the effective threshold).
    #[arg(long, value_name = "SIZE", value_parser = vds_runtime::size::parse_size)]
    memory_budget: Option<u64>,
    /// How a mesh file's tree is built when it is opened directly (`vds-build --builder`):
    /// octree (fast) or qem (closer to the original per triangle, slower to open). A .vdt
    /// file keeps the tree it was built with.
    #[arg(long, value_name = "octree|qem", default_value = "octree")]
    builder: vds_build::Builder,
    /// How the cut keeps its triangles' corners, and so what the GPU is sent: ranks (no
    /// per-triangle state; per node changed, a vertex, a range of the rank map and a run of
    /// slots of original corners) or incidence (slots of current corners kept by incidence
    /// lists, rewritten per triangle changed).
    #[arg(long, value_enum, default_value_t = CornersArg::Ranks)]
    corners: CornersArg,
    /// Threads the threshold pass tests active entries on, 1 to 256 (default: every core).
    /// Folds and unfolds stay on one; the cut is the same whatever the number.
    #[arg(long, value_parser = clap::value_parser!(u32).range(1..=256))]
    adjust_threads: Option<u32>,
    /// Threshold adjusts by a sweep from scratch each frame (the top-down cut, page by page)
    /// instead of the incremental pass: faster on large scenes; fetches no page ahead of need.
    #[arg(long, conflicts_with = "adjust_threads")]
    sweep: bool,
}

/// `--corners`.
#[derive(Clone, Copy, ValueEnum)]
enum CornersArg {
    Ranks,
    Incidence,
}

#[derive(Clone, Copy, ValueEnum)]
enum LoadingArg {
    Synchronous,
    Background,
}

impl LoadingArg {
    fn loading(self) -> vds_runtime::Loading {
        match self {
            LoadingArg::Synchronous => vds_runtime::Loading::Synchronous,
            LoadingArg::Background => vds_runtime::Loading::Background {
                threads: vds_runtime::default_loading_threads(),
            },
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum ColouringArg {
    File,
    Parts,
    Depth,
    Error,
}

#[derive(Clone, Copy, ValueEnum)]
enum ShadingArg {
    Faceted,
    Smooth,
}

#[derive(Clone, Copy, ValueEnum)]
enum BoundArg {
    Surface,
    Vertex,
}

impl From<BoundArg> for vds_runtime::Bound {
    fn from(bound: BoundArg) -> Self {
        match bound {
            BoundArg::Surface => vds_runtime::Bound::Surface,
            BoundArg::Vertex => vds_runtime::Bound::Vertex,
        }
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum FrustumArg {
    Fold,
    Ignore,
    Off,
}

/// The most frames `--frames` and `--path-frames` accept: a generated path holds a camera per
/// frame, and a million (over four hours at 60 fps) is more than any run needs.
const MAX_FRAMES: u64 = 1_000_000;

fn frame_count() -> clap::builder::RangedU64ValueParser<usize> {
    clap::builder::RangedU64ValueParser::<usize>::new().range(1..=MAX_FRAMES)
}

/// A finite number, at least 0 (NaN and infinities are refused: they would poison every
/// comparison of the simplifier).
fn non_negative(text: &str) -> Result<f32, String> {
    match text.trim().parse::<f32>() {
        Ok(v) if v.is_finite() && v >= 0.0 => Ok(v),
        Ok(v) => Err(format!("expected a finite number of at least 0, got {v}")),
        Err(e) => Err(format!("expected a number, got {text:?}: {e}")),
    }
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let (w, h) = text
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {text:?}"))?;
    match (w.trim().parse::<u32>(), h.trim().parse::<u32>()) {
        (Ok(w), Ok(h)) if (1..=16384).contains(&w) && (1..=16384).contains(&h) => Ok((w, h)),
        _ => Err(format!(
            "expected WIDTHxHEIGHT between 1 and 16384, got {text:?}"
        )),
    }
}

/// `X,Y`: a pixel, each coordinate at most 16383.
fn parse_pixel(text: &str) -> Result<(u32, u32), String> {
    let numbers = numbers::<u32>(text, 2)?;
    if numbers.iter().any(|&v| v > 16383) {
        return Err(format!(
            "expected pixel coordinates below 16384, got {text:?}"
        ));
    }
    Ok((numbers[0], numbers[1]))
}

/// `X1,Y1,X2,Y2`: two pixels.
fn parse_pixel_pair(text: &str) -> Result<[(u32, u32); 2], String> {
    let numbers = numbers::<u32>(text, 4)?;
    if numbers.iter().any(|&v| v > 16383) {
        return Err(format!(
            "expected pixel coordinates below 16384, got {text:?}"
        ));
    }
    Ok([(numbers[0], numbers[1]), (numbers[2], numbers[3])])
}

/// `nx,ny,nz,d`: finite numbers, the normal not zero.
fn parse_section(text: &str) -> Result<SectionPlane, String> {
    let v = numbers::<f32>(text, 4)?;
    if v.iter().any(|x| !x.is_finite()) {
        return Err(format!("expected finite numbers, got {text:?}"));
    }
    let length = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if !(length > 0.0 && length.is_finite()) {
        return Err(format!("the plane's normal must not be zero, got {text:?}"));
    }
    // Normalised, so that the panel's offset slider moves in world units.
    Ok(SectionPlane {
        normal: [v[0] / length, v[1] / length, v[2] / length],
        offset: v[3] / length,
    })
}

/// Exactly `count` comma-separated numbers.
fn numbers<T: std::str::FromStr>(text: &str, count: usize) -> Result<Vec<T>, String>
where
    T::Err: std::fmt::Display,
{
    let parts: Vec<&str> = text.split(',').map(str::trim).collect();
    if parts.len() != count {
        return Err(format!(
            "expected {count} comma-separated numbers, got {text:?}"
        ));
    }
    parts
        .iter()
        .map(|p| {
            p.parse::<T>()
                .map_err(|e| format!("{p:?} in {text:?}: {e}"))
        })
        .collect()
}

impl Args {
    /// Opens the model the arguments name (`model::open`), keeping the original mesh when
    /// `keep_mesh` is set.
    fn open_model(&self, keep_mesh: bool, loading: vds_runtime::Loading) -> Result<model::Model> {
        let mut model = model::open(
            self.file.as_deref(),
            keep_mesh,
            loading,
            self.memory_budget,
            self.builder,
            match self.corners {
                CornersArg::Ranks => vds_runtime::CornerTracking::Ranks,
                CornersArg::Incidence => vds_runtime::CornerTracking::Incidence,
            },
        )?;
        let every_core = || std::thread::available_parallelism().map_or(1, NonZero::get);
        let threads = self.adjust_threads.map_or_else(every_core, |n| n as usize);
        model.runtime.set_adjust_threads(threads);
        model.runtime.set_sweep(self.sweep);
        Ok(model)
    }

    fn settings(&self) -> Settings {
        Settings {
            goal: match self.budget {
                Some(n) => Goal::Budget(n),
                None => Goal::Threshold(self.threshold),
            },
            criteria: Criteria {
                silhouette_factor: (!self.no_silhouette).then_some(0.25),
                backface: !self.no_backface,
                frustum: match self.frustum {
                    FrustumArg::Fold => FrustumMode::Fold,
                    FrustumArg::Ignore => FrustumMode::Ignore,
                    FrustumArg::Off => FrustumMode::Off,
                },
                // The focus follows the view direction; the runtime takes it per frame.
                gaze: (self.gaze_falloff > 0.0).then_some(Gaze {
                    direction: [0.0, 0.0, -1.0],
                    falloff: self.gaze_falloff,
                }),
                prevent_mesh_folds: false,
                bound: self.bound.map_or(vds_runtime::Bound::Surface, Into::into),
            },
        }
    }

    fn style(&self) -> Style {
        Style {
            colouring: match self.colouring {
                ColouringArg::File => Colouring::File,
                ColouringArg::Parts => Colouring::Parts,
                ColouringArg::Depth => Colouring::Depth,
                ColouringArg::Error => Colouring::Error,
            },
            shading: match self.shading {
                ShadingArg::Faceted => Shading::Faceted,
                ShadingArg::Smooth => Shading::Smooth,
            },
            wireframe: self.wireframe,
            threshold_px: self.threshold,
            cull_outside: !matches!(self.frustum, FrustumArg::Off) && !self.brute_force,
            sections: std::array::from_fn(|k| self.section.get(k).copied()),
        }
    }

    /// Applies `--isolate` and `--hide` to `parts`.
    fn review(&self, parts: &mut parts::Parts) -> Result<()> {
        let matching = |parts: &parts::Parts, glob: &str| -> Result<Vec<u32>> {
            let ids = parts.matching(glob)?;
            if ids.is_empty() {
                bail!(
                    "no part's name or path matches {glob:?} (the model has {} parts; \
                     `vds-info --parts FILE` lists them)",
                    parts.len()
                );
            }
            Ok(ids)
        };
        if !self.isolate.is_empty() {
            let mut shown = Vec::new();
            for glob in &self.isolate {
                shown.extend(matching(parts, glob)?);
            }
            parts.isolate(&shown);
        }
        for glob in &self.hide {
            for id in matching(parts, glob)? {
                parts.set_hidden(id, true);
            }
        }
        Ok(())
    }
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
        eprintln!("vds-view: {error:#}");
        std::process::exit(1);
    }
}

fn run(args: &Args) -> Result<()> {
    if args.section.len() > MAX_SECTIONS {
        eprintln!("vds-view: at most {MAX_SECTIONS} --section planes");
        std::process::exit(2);
    }
    if !args.headless {
        if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
            return picture_without_display(args);
        }
        let loading = args.loading.unwrap_or(LoadingArg::Background).loading();
        let mut model = args.open_model(false, loading)?;
        args.review(&mut model.parts)?;
        return window::run(
            model,
            args.settings(),
            args.style(),
            args.size,
            args.asynchronous,
        );
    }
    let loading = args.loading.unwrap_or(LoadingArg::Synchronous).loading();
    let mut model = args.open_model(args.brute_force, loading)?;
    args.review(&mut model.parts)?;
    let review = model.parts.clone();
    let pages = model.runtime.cut().store().source();
    let root = model.runtime.cut().node(0);
    let loop_frames = args.path_frames.or(args.frames).unwrap_or(120) as u32;
    let source = PathSource::from_flags(args.camera_path.as_deref(), args.fly);
    let mut path = CameraPath::from_source(
        source,
        root.sphere_center,
        root.sphere_radius,
        loop_frames,
        args.size,
    )
    .map_err(anyhow::Error::msg)?;
    if let Some(frames) = args.frames {
        path.cameras.truncate(frames);
    }
    if path.cameras.is_empty() {
        bail!("the camera path has no cameras");
    }
    let first = path.cameras[0];
    if path
        .cameras
        .iter()
        .any(|c| (c.width, c.height) != (first.width, first.height))
    {
        bail!("every camera of a path must have the same size");
    }
    let headless = Headless {
        path,
        out: args.out.clone(),
        stats: args.stats.clone(),
        settings: args.settings(),
        style: args.style(),
        asynchronous: args.asynchronous,
        brute_force: args.brute_force,
        verify: args.verify,
        freeze_after: args.freeze_after,
        part_looks: model.parts.looks(),
        first_image: None,
        probes: args
            .pick
            .into_iter()
            .chain(args.measure.into_iter().flatten())
            .collect(),
    };
    if !args.compare {
        let (summary, hits) = Summary::run(model, &headless)?;
        if let Some(pixel) = args.pick {
            let pick = probe::pick_json(&review, pixel, hits[0]);
            println!("{}", serde_json::json!({ "pick": pick }));
        }
        if let Some(pixels) = args.measure {
            let hits = &hits[usize::from(args.pick.is_some())..];
            let measure = probe::measure_json(&review, &*pages, pixels, [hits[0], hits[1]])?;
            println!("{}", serde_json::json!({ "measure": measure }));
        }
        println!("{summary}");
        return Ok(());
    }
    // Same cameras, same process: first the cut, then the whole model.
    let (vds, _) = Summary::run(model, &headless)?;
    println!("{vds}");
    let model = args.open_model(true, loading)?;
    let brute_force = Headless {
        brute_force: true,
        out: None,
        stats: None,
        ..headless
    };
    let (brute, _) = Summary::run(model, &brute_force)?;
    println!("{brute}");
    println!(
        "brute force / vds: CPU frame {:.2}×{}",
        brute.cpu_frame_ms / vds.cpu_frame_ms,
        match (brute.gpu_ms, vds.gpu_ms) {
            (Some(b), Some(v)) => format!(", GPU {:.2}×", b / v),
            _ => String::new(),
        }
    );
    Ok(())
}

/// Without a display: one picture of the model (the bundled demo when no file is given),
/// seen from above at three quarters, written to the current directory.
fn picture_without_display(args: &Args) -> Result<()> {
    let loading = args.loading.unwrap_or(LoadingArg::Synchronous).loading();
    let mut model = args.open_model(false, loading)?;
    args.review(&mut model.parts)?;
    let root = model.runtime.cut().node(0);
    // The bounding sphere of a CAD assembly is loose around it: frame three quarters of it.
    let mut camera = vds_runtime::Camera::framing(
        root.sphere_center,
        root.sphere_radius * 0.75,
        [0.7, -1.0, 0.8],
        args.size.0,
        args.size.1,
    );
    if args.file.is_none() {
        // The demo assembly stands on its plate in the xy plane.
        camera.up = [0.0, 0.0, 1.0];
    }
    let png = PathBuf::from(match &args.file {
        None => "vds-view-demo.png".to_string(),
        Some(file) => format!(
            "{}.png",
            file.file_stem()
                .map_or("vds-view".into(), |s| s.to_string_lossy())
        ),
    });
    let name = model.name.clone();
    let headless = Headless {
        path: CameraPath {
            cameras: vec![camera],
        },
        out: None,
        stats: None,
        settings: args.settings(),
        style: args.style(),
        asynchronous: false,
        brute_force: false,
        verify: false,
        freeze_after: None,
        part_looks: model.parts.looks(),
        probes: Vec::new(),
        first_image: Some(png.clone()),
    };
    let (summary, _) = Summary::run(model, &headless)?;
    let shown = std::path::absolute(&png).unwrap_or(png);
    println!(
        "no display (neither DISPLAY nor WAYLAND_DISPLAY is set): rendered {name} to {}",
        shown.display()
    );
    println!("{summary}");
    println!(
        "for more frames: vds-view {}--headless --orbit --frames 60 --out frames --stats stats.csv",
        args.file
            .as_ref()
            .map_or(String::new(), |f| format!("{} ", f.display()))
    );
    Ok(())
}

/// Medians of a headless run: of the frames after the first (which starts the cut from the
/// root and uploads everything), or of the only frame of a one-frame run.
struct Summary {
    name: String,
    frames: usize,
    /// Whether the medians cover the frames after the first (false: the only frame).
    after_first: bool,
    size: (u32, u32),
    triangles: u64,
    brute_force: bool,
    adjust_ms: f64,
    cpu_frame_ms: f64,
    gpu_ms: Option<f64>,
    active_triangles: f64,
    upload_bytes: f64,
}

impl Summary {
    fn run(
        model: model::Model,
        headless: &Headless,
    ) -> Result<(Summary, Vec<Option<vds_render::Hit>>)> {
        let (name, triangles) = (model.name.clone(), model.triangles);
        let run = headless::run_model(model, headless)?;
        Ok((Summary::of(name, triangles, headless, run.rows), run.hits))
    }

    fn of(
        name: String,
        triangles: u64,
        headless: &Headless,
        rows: Vec<headless::FrameRow>,
    ) -> Summary {
        let median = |mut v: Vec<f64>| {
            v.sort_by(f64::total_cmp);
            v.get(v.len() / 2).copied().unwrap_or(0.0)
        };
        let after_first = rows.len() > 1;
        let after: Vec<_> = rows.iter().skip(usize::from(after_first)).collect();
        let gpu: Vec<f64> = after.iter().filter_map(|r| r.gpu_ms).collect();
        let first = headless.path.cameras[0];
        Summary {
            name,
            frames: rows.len(),
            after_first,
            size: (first.width, first.height),
            triangles,
            brute_force: headless.brute_force,
            adjust_ms: median(after.iter().map(|r| r.adjust.adjust_ms).collect()),
            cpu_frame_ms: median(after.iter().map(|r| r.cpu_frame_ms).collect()),
            gpu_ms: (!gpu.is_empty()).then(|| median(gpu)),
            active_triangles: median(
                after
                    .iter()
                    .map(|r| f64::from(r.adjust.active_triangles))
                    .collect(),
            ),
            upload_bytes: median(after.iter().map(|r| r.upload_bytes as f64).collect()),
        }
    }
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}: {} frames at {}x{} of {} triangles{}; {}: adjust \
             {:.3} ms, CPU frame {:.2} ms{}, {:.0} triangles drawn, {:.0} upload bytes",
            self.name,
            self.frames,
            self.size.0,
            self.size.1,
            self.triangles,
            if self.brute_force {
                " (brute force)"
            } else {
                " (vds)"
            },
            if self.after_first {
                "medians after the first frame"
            } else {
                "the only frame"
            },
            self.adjust_ms,
            self.cpu_frame_ms,
            self.gpu_ms
                .map_or(String::new(), |g| format!(", GPU {g:.2} ms")),
            self.active_triangles,
            self.upload_bytes,
        )
    }
}
