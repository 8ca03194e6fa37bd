//! `vds-bench refine`: what a user of background loading feels — how soon the first frame
//! shows after opening a `.vdt` file, how long until the view is fully refined, how long a
//! 180° turn takes to refine, how fast the loader delivers pages, and what the adjusts cost
//! along a fly-through with pages loading, against the same path fully resident.
//!
//! Frames are paced like a display (`--pace-ms`, 60 Hz by default): the loader works between
//! frames as it would in the viewer. "Fully refined" is the first frame that puts off no
//! unfold and leaves no page pending: the cut a synchronous adjust would give. On Linux the
//! file is evicted from the page cache first, so pages come from the disk.

use std::path::Path;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use vds_runtime::{
    Camera, CameraPath, CornerTracking, Criteria, Goal, Loading, Runtime, Viewpoint,
};

/// What one refinement took.
struct Settling {
    /// From the start of the first adjust for the camera to the end of the frame that
    /// settled (frames paced in between).
    elapsed: Duration,
    /// Adjusts, the first and the settling one included.
    frames: u32,
    pages: u32,
    /// The first adjust alone.
    first_adjust: Duration,
    /// The threshold the settled cut meets (raised when the budget cannot hold the cut).
    effective_threshold: f32,
}

/// Adjusts for `camera` at `pace` until a frame defers nothing and nothing is pending. With
/// `trace`, prints a line per frame: what the cut waited for and what the budget held.
fn settle(
    runtime: &mut Runtime,
    camera: &Camera,
    goal: Goal,
    pace: Duration,
    trace: bool,
) -> Result<Settling> {
    let criteria = Criteria::default();
    let pages_before = runtime.memory().pages_loaded;
    let start = Instant::now();
    let mut first_adjust = Duration::ZERO;
    for frame in 1..=100_000u32 {
        let adjust_start = Instant::now();
        let adjusted = runtime.adjust(&Viewpoint::Camera(*camera), &criteria, goal)?;
        let stats = adjusted.stats;
        if frame == 1 {
            first_adjust = adjust_start.elapsed();
        }
        if let Some(error) = runtime.take_page_errors().into_iter().next() {
            return Err(error.into());
        }
        if trace {
            let m = &adjusted.memory;
            println!(
                "    frame {frame:4} at {:7.1} ms: adjust {:6.2} ms, t {:7.2} px, {:5} unfolds, \
                 {:5} put off, {:5} pending, {:6} resident ({} of which pinned), {} loaded, \
                 {} evicted, {} refusals",
                start.elapsed().as_secs_f64() * 1e3,
                adjust_start.elapsed().as_secs_f64() * 1e3,
                adjusted.effective_threshold.unwrap_or(f32::NAN),
                stats.unfolds,
                stats.deferred_unfolds,
                m.pages_pending,
                m.pages_resident,
                vds_runtime::size::format_size(m.pinned_bytes),
                m.pages_loaded,
                m.pages_evicted,
                m.refusals,
            );
        }
        if stats.deferred_unfolds == 0 && runtime.pending_pages() == 0 {
            return Ok(Settling {
                elapsed: start.elapsed(),
                frames: frame,
                pages: (runtime.memory().pages_loaded - pages_before) as u32,
                first_adjust,
                effective_threshold: adjusted.effective_threshold.unwrap_or(f32::NAN),
            });
        }
        if let Some(wait) = (pace * frame).checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
    }
    anyhow::bail!("the view did not settle in 100,000 frames")
}

/// Adjust times along `path`, paced.
/// What a fly-through did: adjust times, the most bytes held, the highest effective
/// threshold, pages evicted.
struct Played {
    times: Vec<f64>,
    /// The effective threshold of each frame.
    thresholds: Vec<f64>,
    most_bytes: u64,
    highest_threshold: f32,
    evicted: u64,
    loaded: u64,
    /// Unfolds put off for pages not yet resident, over all frames.
    deferred: u64,
    /// Frames that put off at least one unfold.
    lagging_frames: u32,
}

fn play(runtime: &mut Runtime, path: &CameraPath, goal: Goal, pace: Duration) -> Result<Played> {
    let criteria = Criteria::default();
    let mut times = Vec::with_capacity(path.cameras.len());
    let mut thresholds = Vec::with_capacity(path.cameras.len());
    let (mut most_bytes, mut highest_threshold) = (0u64, 0.0f32);
    let (mut deferred, mut lagging_frames) = (0u64, 0u32);
    let evicted_before = runtime.memory().pages_evicted;
    let loaded_before = runtime.memory().pages_loaded;
    let start = Instant::now();
    for (i, camera) in path.cameras.iter().enumerate() {
        if let Some(wait) = (pace * i as u32).checked_sub(start.elapsed()) {
            std::thread::sleep(wait);
        }
        let t = Instant::now();
        let frame = runtime.adjust(&Viewpoint::Camera(*camera), &criteria, goal)?;
        times.push(t.elapsed().as_secs_f64() * 1e3);
        most_bytes = most_bytes.max(frame.memory.resident_bytes);
        highest_threshold = highest_threshold.max(frame.effective_threshold.unwrap_or(0.0));
        thresholds.push(f64::from(frame.effective_threshold.unwrap_or(f32::NAN)));
        deferred += u64::from(frame.stats.deferred_unfolds);
        lagging_frames += u32::from(frame.stats.deferred_unfolds > 0);
    }
    Ok(Played {
        times,
        thresholds,
        most_bytes,
        highest_threshold,
        evicted: runtime.memory().pages_evicted - evicted_before,
        loaded: runtime.memory().pages_loaded - loaded_before,
        deferred,
        lagging_frames,
    })
}

fn percentile(values: &[f64], p: f64) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// Drops `file`'s pages from the page cache where the system allows (Linux).
fn evict(file: &Path) -> bool {
    #[cfg(target_os = "linux")]
    {
        std::fs::File::open(file)
            .is_ok_and(|f| rustix::fs::fadvise(&f, 0, None, rustix::fs::Advice::DontNeed).is_ok())
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = file;
        false
    }
}

/// How `vds-bench refine` measures.
pub struct Options {
    /// The screen-space error threshold in pixels.
    pub t: f32,
    /// Background loading threads.
    pub threads: usize,
    /// The time between frames, in milliseconds.
    pub pace_ms: f64,
    /// Frames of the fly-through.
    pub frames: u32,
    /// The runtime's memory budget in bytes.
    pub budget: u64,
    /// How the runtime tracks triangle corners.
    pub tracking: CornerTracking,
    /// Print one line per frame while a cut settles.
    pub trace: bool,
    /// Skip the fly-through with every page resident.
    pub loading_only: bool,
}

/// Runs the measurements on `file` as `options` say.
pub fn run(file: &Path, options: &Options) -> Result<()> {
    let &Options {
        t,
        threads,
        pace_ms,
        frames,
        budget,
        tracking,
        trace,
        loading_only,
    } = options;
    let pace = Duration::from_secs_f64(pace_ms / 1e3);
    let goal = Goal::Threshold(t);
    let cold = evict(file);
    let open_start = Instant::now();
    let vdt = vds_format::VdtFile::open(file).with_context(|| file.display().to_string())?;
    let pages = vdt.directory().len();
    let mut runtime =
        Runtime::with_loading(Box::new(vdt), tracking, Loading::Background { threads })
            .with_context(|| file.display().to_string())?;
    runtime.set_memory_budget(budget);
    let root = runtime.cut().node(0);
    let (center, radius) = (root.sphere_center, root.sphere_radius);
    let path = CameraPath::fly_through(center, radius, frames, 1920, 1080);
    let start_camera = path.cameras[0];
    let opened = open_start.elapsed();
    let refined = settle(&mut runtime, &start_camera, goal, pace, trace)?;
    let first_frame_ms = (opened + refined.first_adjust).as_secs_f64() * 1e3;
    let first_adjust_ms = refined.first_adjust.as_secs_f64() * 1e3;
    // The same eye, looking the other way.
    let mut turned = start_camera;
    turned.target = [0, 1, 2].map(|k| 2.0 * start_camera.eye[k] - start_camera.target[k]);
    let turn = settle(&mut runtime, &turned, goal, pace, trace)?;

    println!(
        "{}: {pages} pages, t = {t} px, {threads} loading thread(s), frames every {pace_ms:.1} ms, \
         memory budget {}, page cache {}, {tracking:?} corners",
        file.display(),
        vds_runtime::size::format_size(budget),
        if cold { "evicted first" } else { "as it was" }
    );
    println!("  open to first frame {first_frame_ms:.1} ms (first adjust {first_adjust_ms:.2} ms)");
    for (what, s) in [
        ("at the start position", &refined),
        ("after a 180° turn", &turn),
    ] {
        let seconds = s.elapsed.as_secs_f64();
        println!(
            "  fully refined {what}: {:.0} ms, {} frames, {} pages ({:.0} pages/s while \
             refining at this pace, {:.0} per loading thread), at {:.1} px",
            seconds * 1e3,
            s.frames,
            s.pages,
            f64::from(s.pages) / seconds.max(1e-9),
            f64::from(s.pages) / seconds.max(1e-9) / threads as f64,
            s.effective_threshold,
        );
    }

    // The fly-through with pages loading in the background, from a fresh runtime (the first
    // one's map dropped, or the eviction would keep the pages it maps)...
    drop(runtime);
    evict(file);
    let vdt = vds_format::VdtFile::open(file)?;
    let mut loading =
        Runtime::with_loading(Box::new(vdt), tracking, Loading::Background { threads })?;
    loading.set_memory_budget(budget);
    let background = play(&mut loading, &path, goal, pace)?;
    let mut runs = vec![("background loading within the budget", background)];
    // ...and the same path with every page decoded first.
    if !loading_only {
        let vdt = vds_format::VdtFile::open(file)?;
        let mut resident = Runtime::new(Box::new(vdt), tracking)?;
        resident.set_memory_budget(u64::MAX);
        resident.load_every_page()?;
        runs.push((
            "every page resident",
            play(&mut resident, &path, goal, pace)?,
        ));
    }
    for (what, played) in &runs {
        let times = &played.times;
        println!(
            "  fly-through, {} frames, {what}: adjust median {:.3} ms, p99 {:.3} ms, max {:.3} ms; \
             at most {} held, effective threshold median {:.1} px, at most {:.1} px, {} pages loaded, {} evicted; \
             {} frames coarser than asked for, waiting on pages ({} unfolds put off in all)",
            times.len(),
            percentile(times, 0.5),
            percentile(times, 0.99),
            percentile(times, 1.0),
            vds_runtime::size::format_size(played.most_bytes),
            percentile(&played.thresholds, 0.5),
            played.highest_threshold,
            played.loaded,
            played.evicted,
            played.lagging_frames,
            played.deferred,
        );
    }
    Ok(())
}
