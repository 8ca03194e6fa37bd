//! `vds-view`: the vds viewer.
//!
//! `vds-view [FILE]` opens a window on a `.vdt` file, a mesh file (its tree is built in memory
//! first) or, with no file, the bundled demo assembly. `--headless` renders a camera path
//! offscreen instead: PNGs and a CSV of per-frame figures. Exit codes: 0 success, 1 failure
//! (named, with the file it is about), 2 bad command line (every number is checked for its
//! range, and NaN or infinity for none, before anything is opened).

mod controls;
mod headless;
mod hud;
mod model;
mod simplify;
mod window;

use std::path::PathBuf;

use anyhow::{Result, bail};
use clap::{Parser, ValueEnum};
use vds_render::{Colouring, Shading, Style};
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
    /// Simplify on a separate thread (frames never wait for simplification).
    #[arg(long = "async")]
    asynchronous: bool,
    /// Draw the original mesh instead of the cut (for comparison).
    #[arg(long)]
    brute_force: bool,
    /// Triangle colouring.
    #[arg(long, value_enum, default_value_t = ColouringArg::Parts)]
    colouring: ColouringArg,
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

impl Args {
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
            },
        }
    }

    fn style(&self) -> Style {
        Style {
            colouring: match self.colouring {
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
        }
    }
}

fn main() {
    let args = Args::parse();
    if let Err(error) = run(&args) {
        eprintln!("vds-view: {error:#}");
        std::process::exit(1);
    }
}

fn run(args: &Args) -> Result<()> {
    if !args.headless {
        if std::env::var_os("DISPLAY").is_none() && std::env::var_os("WAYLAND_DISPLAY").is_none() {
            bail!(
                "no display: neither DISPLAY nor WAYLAND_DISPLAY is set. To render without a \
                 window, use --headless (for example: vds-view {}--headless --orbit --frames \
                 60 --out frames --stats stats.csv)",
                args.file
                    .as_ref()
                    .map_or(String::new(), |f| format!("{} ", f.display()))
            );
        }
        let loading = args.loading.unwrap_or(LoadingArg::Background).loading();
        let model = model::open(args.file.as_deref(), false, loading, args.memory_budget)?;
        return window::run(
            model,
            args.settings(),
            args.style(),
            args.size,
            args.asynchronous,
        );
    }
    let loading = args.loading.unwrap_or(LoadingArg::Synchronous).loading();
    let model = model::open(
        args.file.as_deref(),
        args.brute_force,
        loading,
        args.memory_budget,
    )?;
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
    };
    if !args.compare {
        let summary = Summary::run(model, &headless)?;
        println!("{summary}");
        return Ok(());
    }
    // Same cameras, same process: first the cut, then the whole model.
    let vds = Summary::run(model, &headless)?;
    println!("{vds}");
    let model = model::open(args.file.as_deref(), true, loading, args.memory_budget)?;
    let brute_force = Headless {
        brute_force: true,
        out: None,
        stats: None,
        ..headless
    };
    let brute = Summary::run(model, &brute_force)?;
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
    fn run(model: model::Model, headless: &Headless) -> Result<Summary> {
        let (name, triangles) = (model.name.clone(), model.triangles);
        let rows = headless::run_model(model, headless)?;
        Ok(Summary::of(name, triangles, headless, rows))
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
