//! `vds-bench cut`: the runtime along camera paths (and, unless told not to, the fidelity
//! table of the bunny, `fidelity.rs`).
//!
//! Per frame: the adjust time (one thread), nodes visited, and triangles added, removed and
//! changed as fractions of the active set. The first frame starts from the root and loads
//! pages; it is reported apart, and the medians and 99th percentiles cover the frames after.
//! Runs marked `resident` decode every page before the first frame (the adjust alone);
//! `cold` runs load pages inside the adjusts that first need them.

use std::path::Path;
use std::time::Instant;

use anyhow::{Context, Result};
use vds_build::Builder;
use vds_format::{VdtFile, WriteOptions, encode};
use vds_runtime::sweep::Sweep;
use vds_runtime::{CameraPath, CornerTracking, Criteria, Goal, Judge, Runtime, Viewpoint};

/// The `.vdt` bytes of a mesh file, built in memory, and the scene as imported and snapped.
pub fn vdt_bytes(file: &Path, builder: Builder) -> Result<(Vec<u8>, vds_import::Scene)> {
    let mut scene = vds_import::load_file(file, &Default::default())
        .with_context(|| format!("reading {}", file.display()))?;
    let grid = vds_build::snap_to_grid(&mut scene);
    let tree = vds_build::build_tree_by(&scene, builder).0;
    let metadata = vds_format::Metadata {
        part_names: scene.part_names.clone(),
        ..Default::default()
    };
    let content = vds_build::tree_content(&tree, &scene, metadata, grid);
    Ok((encode(&content, &WriteOptions::default())?.0, scene))
}

fn percentile(values: &[f64], p: f64) -> f64 {
    let mut sorted = values.to_vec();
    sorted.sort_by(f64::total_cmp);
    sorted[((sorted.len() - 1) as f64 * p).round() as usize]
}

/// What [`play`] times.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Timed {
    /// Each frame's adjust.
    Adjusts,
    /// A second adjust of each frame for the same camera: what confirming a cut that needs
    /// no change costs. A run of its own, so that the extra adjusts do not warm the cache
    /// for the frames timed by [`Timed::Adjusts`].
    SettledChecks,
    /// A third adjust of each frame for the same camera: what each further adjust of a still
    /// camera costs (a viewer adjusting again while pages arrive), visiting only what the
    /// settled check left unsettled (`vds_runtime`'s still passes).
    Readjusts,
}

impl Timed {
    /// Untimed adjusts for the same camera before the timed one.
    fn before(self) -> usize {
        match self {
            Timed::Adjusts => 0,
            Timed::SettledChecks => 1,
            Timed::Readjusts => 2,
        }
    }
}

/// Plays `path` through a fresh runtime and prints one line of figures. `resident`: every
/// page is decoded before the first frame, so frames time the cut alone; otherwise pages load
/// as the cut first reaches them, inside the adjust that needs them.
fn play(
    bytes: &[u8],
    path: &CameraPath,
    goal: Goal,
    tracking: CornerTracking,
    resident: bool,
    timed: Timed,
    threads: usize,
) -> Result<()> {
    let settled = timed != Timed::Adjusts;
    let file = VdtFile::from_bytes(bytes.to_vec())?;
    // Each page's first node, to count the pages a frame's changes touch.
    let page_firsts: Vec<u32> = file
        .directory()
        .iter()
        .map(|e| e.first_node.get())
        .collect();
    let mut runtime = Runtime::new(Box::new(file), tracking)?;
    runtime.set_adjust_threads(threads);
    if resident {
        runtime.set_memory_budget(u64::MAX);
        runtime.load_every_page()?;
    }
    let criteria = Criteria::default();
    let (mut ms, mut visited, mut added, mut removed, mut changed, mut active) =
        (vec![], vec![], vec![], vec![], vec![], vec![]);
    let (mut groups, mut failed, mut reused) = (vec![], vec![], vec![]);
    let mut active_nodes = vec![];
    // What a frame costs per active triangle, and per node folded or unfolded (frames with
    // changes only): the two costs the per-frame-work issue sets out to separate.
    let (mut ns_per_active, mut ns_per_change) = (vec![], vec![]);
    // Rank tracking's changed nodes a frame, and the pages they lie in: how many units of
    // change a cut that changed a page's nodes together would make.
    let (mut changed_nodes, mut changed_pages) = (vec![], vec![]);
    let mut pages = Vec::new();
    let mut first_ms = 0.0;
    // Folds and unfolds of the timed adjusts: none when each first adjust settled its cut.
    let mut settled_changes = 0u64;
    // The sweep from scratch beside the adjust, on the same resident store (rank tracking).
    let mut sweep = (resident && tracking == CornerTracking::Ranks && timed == Timed::Adjusts)
        .then(|| SweepFigures::on_threads(threads));
    for (i, camera) in path.cameras.iter().enumerate() {
        for _ in 0..timed.before() {
            runtime.adjust(&Viewpoint::Camera(*camera), &criteria, goal)?;
        }
        let start = Instant::now();
        let frame = runtime.adjust(&Viewpoint::Camera(*camera), &criteria, goal)?;
        let elapsed = start.elapsed().as_secs_f64() * 1e3;
        let n = f64::from(runtime.cut().active_triangle_count().max(1));
        if i == 0 {
            first_ms = elapsed;
            continue;
        }
        ms.push(elapsed);
        if let (Some(figures), Goal::Threshold(t)) = (&mut sweep, goal) {
            figures.frame(&runtime, &Viewpoint::Camera(*camera), &criteria, t);
        }
        let nodes = frame.changes.unfolded.iter().chain(&frame.changes.folded);
        pages.clear();
        pages.extend(nodes.map(|&id| page_firsts.partition_point(|&f| f <= id)));
        changed_nodes.push(pages.len() as f64);
        pages.sort_unstable();
        pages.dedup();
        changed_pages.push(pages.len() as f64);
        let changes = frame.stats.folds + frame.stats.unfolds;
        settled_changes += u64::from(changes);
        ns_per_active.push(elapsed * 1e6 / n);
        if changes > 0 {
            ns_per_change.push(elapsed * 1e6 / f64::from(changes));
        }
        visited.push(f64::from(frame.stats.visited));
        groups.push(f64::from(frame.stats.groups));
        failed.push(f64::from(frame.stats.groups_failed));
        reused.push(f64::from(frame.stats.groups_reused));
        added.push(f64::from(frame.changes.added) / n * 100.0);
        removed.push(f64::from(frame.changes.removed) / n * 100.0);
        changed.push(f64::from(frame.changes.changed) / n * 100.0);
        active.push(n);
        active_nodes.push(f64::from(runtime.cut().active_node_count()));
    }
    let median = |v: &[f64]| percentile(v, 0.5);
    let t = match goal {
        Goal::Threshold(t) => format!("t={t} px"),
        Goal::Budget(n) => format!("n={n}"),
    };
    if settled {
        // The first adjusts of each frame above were not timed; `frame` counts the last.
        println!(
            "  {t:<8} {:<9} {:<8} {} median {:6.3} ms  p99 {:6.3} ms | visited {:>7.0} \
             | folds and unfolds in the checks {} (0: the cut was settled)",
            format!("{tracking:?}"),
            if resident { "resident" } else { "cold" },
            match timed {
                Timed::Readjusts => "re-adjust",
                _ => "settled check",
            },
            median(&ms),
            percentile(&ms, 0.99),
            median(&visited),
            settled_changes,
        );
        return Ok(());
    }
    println!(
        "  {t:<8} {:<9} {:<8} adjust median {:6.3} ms  p99 {:6.3} ms  (first {:7.1} ms) | \
         visited {:>7.0} (groups {:.0}, failed {:.0}, reused {:.0}) | active {:>8.0} (nodes {:.0}) | added {:5.2}% removed {:5.2}% changed {:5.2}% (medians; p99 sum {:5.2}%)",
        format!("{tracking:?}"),
        if resident { "resident" } else { "cold" },
        median(&ms),
        percentile(&ms, 0.99),
        first_ms,
        median(&visited),
        median(&groups),
        median(&failed),
        median(&reused),
        median(&active),
        median(&active_nodes),
        median(&added),
        median(&removed),
        median(&changed),
        percentile(
            &added
                .iter()
                .zip(&removed)
                .zip(&changed)
                .map(|((a, r), c)| a + r + c)
                .collect::<Vec<_>>(),
            0.99
        ),
    );
    println!(
        "  {:<28} per frame: {:6.1} ns per active triangle, {:7.0} ns per node folded or \
         unfolded (medians; {} of {} frames changed); {:.0} nodes changed in {:.0} pages \
         (medians, rank tracking)",
        "",
        median(&ns_per_active),
        if ns_per_change.is_empty() {
            0.0
        } else {
            median(&ns_per_change)
        },
        ns_per_change.len(),
        ms.len(),
        median(&changed_nodes),
        median(&changed_pages),
    );
    if let Some(figures) = sweep {
        figures.print();
    }
    Ok(())
}

/// The sweep from scratch (`vds_runtime::sweep`) along the same path as an adjust, after
/// each adjust, on its store and as many threads: time, work, and how far its cut is from
/// the adjust's.
#[derive(Default)]
struct SweepFigures {
    sweep: Sweep,
    ms: Vec<f64>,
    tests: Vec<f64>,
    groups_passed: Vec<f64>,
    pages: Vec<f64>,
    changed: Vec<f64>,
    /// Nodes active in one cut and not the other.
    differing: Vec<f64>,
    /// The change report from the sweep's bits (`Sweep::report`): time, and nodes that
    /// joined or left the boundary.
    report_ms: Vec<f64>,
    boundary_changes: Vec<f64>,
    ids: Vec<u32>,
}

impl SweepFigures {
    /// Figures of a sweep on `threads` threads (`Sweep::set_threads`).
    fn on_threads(threads: usize) -> SweepFigures {
        let mut figures = SweepFigures::default();
        figures.sweep.set_threads(threads);
        figures
    }

    fn frame(&mut self, runtime: &Runtime, viewpoint: &Viewpoint, criteria: &Criteria, t: f32) {
        let store = runtime.cut().store();
        let start = Instant::now();
        let judge = Judge::new(viewpoint, criteria);
        let stats = self.sweep.run(store, &judge, t);
        self.ms.push(start.elapsed().as_secs_f64() * 1e3);
        let start = Instant::now();
        let report = self.sweep.report(store);
        self.report_ms.push(start.elapsed().as_secs_f64() * 1e3);
        let report = report.expect("every page is resident");
        self.boundary_changes
            .push((report.joined_boundary.len() + report.left_boundary.len()) as f64);
        self.tests.push(f64::from(stats.tests));
        self.groups_passed.push(f64::from(stats.groups_passed));
        self.pages.push(f64::from(stats.pages));
        self.changed.push(f64::from(stats.unfolded + stats.folded));
        self.ids.clear();
        self.ids
            .extend(runtime.cut().active_entries().iter().map(|e| e.id));
        let only_adjust = self
            .ids
            .iter()
            .filter(|&&id| !self.sweep.is_active(store, id))
            .count();
        let both = self.ids.len() - only_adjust;
        self.differing
            .push((only_adjust + stats.active as usize - both) as f64);
    }

    fn print(&self) {
        let median = |v: &[f64]| percentile(v, 0.5);
        println!(
            "  {:<28} sweep from scratch: median {:6.3} ms  p99 {:6.3} ms | tests {:.0}, groups \
             passed {:.0} | {:.0} pages with active nodes | {:.0} nodes changed | cut differs \
             from the adjust's in {:.0} nodes (median; max {:.0})",
            "",
            median(&self.ms),
            percentile(&self.ms, 0.99),
            median(&self.tests),
            median(&self.groups_passed),
            median(&self.pages),
            median(&self.changed),
            median(&self.differing),
            percentile(&self.differing, 1.0),
        );
        println!(
            "  {:<28} report from the sweep's bits: median {:6.3} ms  p99 {:6.3} ms | {:.0} \
             nodes joined or left the boundary (median)",
            "",
            median(&self.report_ms),
            percentile(&self.report_ms, 0.99),
            median(&self.boundary_changes),
        );
    }
}

/// A rank-tracked runtime over `bytes` with every page resident and no memory budget.
pub fn resident_ranks(bytes: &[u8]) -> Result<Runtime> {
    let mut runtime = Runtime::new(
        Box::new(VdtFile::from_bytes(bytes.to_vec())?),
        CornerTracking::Ranks,
    )?;
    runtime.set_memory_budget(u64::MAX);
    runtime.load_every_page()?;
    Ok(runtime)
}

/// Plays `path` at threshold `t` through a fresh rank-tracked runtime with every page resident
/// that adjusts by sweeps ([`Runtime::set_sweep`]): each frame's sweep from scratch, its
/// changes applied through the cut's fold and unfold, and the report a renderer reads.
fn play_sweep(bytes: &[u8], path: &CameraPath, t: f32) -> Result<()> {
    let mut runtime = resident_ranks(bytes)?;
    runtime.set_sweep(true);
    let criteria = Criteria::default();
    let (mut ms, mut changed) = (vec![], vec![]);
    let mut first_ms = 0.0;
    for (i, camera) in path.cameras.iter().enumerate() {
        let start = Instant::now();
        let frame = runtime.adjust(&Viewpoint::Camera(*camera), &criteria, Goal::Threshold(t))?;
        let elapsed = start.elapsed().as_secs_f64() * 1e3;
        if i == 0 {
            first_ms = elapsed;
            continue;
        }
        ms.push(elapsed);
        changed.push(f64::from(frame.stats.unfolds + frame.stats.folds));
    }
    println!(
        "  {:<28} adjust by sweeps: median {:6.3} ms  p99 {:6.3} ms  (first {:7.1} ms) | \
         {:.0} nodes changed (median)",
        "",
        percentile(&ms, 0.5),
        percentile(&ms, 0.99),
        first_ms,
        percentile(&changed, 0.5),
    );
    Ok(())
}

/// Which runs [`paths`] makes.
#[derive(Debug, Clone, Copy, Default)]
pub struct Runs {
    /// Only resident pages (no cold run, no lazy corners): quicker A/B runs.
    pub resident_only: bool,
    /// Only rank tracking, resident (implies `resident_only`).
    pub ranks_only: bool,
    /// Also time settled checks (a second adjust for each frame's camera) and re-adjusts (a
    /// third) of the resident runs; full runs time settled checks for incidence lists only.
    pub settled: bool,
    /// Threads the threshold pass tests entries on ([`Runtime::set_adjust_threads`]), and the
    /// sweep from scratch beside it runs on (`Sweep::set_threads`).
    pub threads: usize,
    /// Also run the sweep in place of the adjust ([`play_sweep`]).
    pub sweep: bool,
    /// Instead of timing, estimate the tests a per-node slack could skip
    /// ([`crate::slack`]).
    pub slack_estimate: bool,
}

/// Runtime figures for one mesh along `path`, at t = 1 and 5 px: every corner strategy with
/// resident pages and incidence lists with cold pages, or fewer as `runs` says.
pub fn paths(name: &str, file: &Path, frames: u32, fly: bool, runs: Runs) -> Result<()> {
    let (bytes, _) = vdt_bytes(file, Builder::default())?;
    paths_of_vdt(name, &bytes, frames, fly, runs)
}

/// [`paths`] for the `.vdt` file `bytes`, built elsewhere.
pub fn paths_of_vdt(name: &str, bytes: &[u8], frames: u32, fly: bool, runs: Runs) -> Result<()> {
    let resident_only = runs.resident_only || runs.ranks_only;
    let probe = Runtime::new(
        Box::new(VdtFile::from_bytes(bytes.to_vec())?),
        CornerTracking::Incidence,
    )?;
    let root = probe.cut().node(0);
    let (width, height) = (1920, 1080);
    let path = if fly {
        CameraPath::fly_through(
            root.sphere_center,
            root.sphere_radius,
            frames,
            width,
            height,
        )
    } else {
        CameraPath::orbit(
            root.sphere_center,
            root.sphere_radius,
            frames,
            width,
            height,
        )
    };
    if runs.slack_estimate {
        println!(
            "{name}: per-node slack along {frames} frames {} at {width}x{height} (an estimate)",
            if fly { "flying through" } else { "orbiting" }
        );
        for t in [1.0, 5.0] {
            crate::slack::run(bytes, &path, t)?;
        }
        return Ok(());
    }
    println!(
        "{name} ({} triangles), {} frames {} at {width}x{height}, {}",
        probe.cut().store().triangle_count(),
        frames,
        if fly { "flying through" } else { "orbiting" },
        match runs.threads {
            0 | 1 => "one thread".to_string(),
            n => format!("entries tested and sweeps from scratch run on {n} threads"),
        },
    );
    let resident_trackings: &[CornerTracking] = if runs.ranks_only {
        &[CornerTracking::Ranks]
    } else if resident_only {
        &[CornerTracking::Incidence, CornerTracking::Ranks]
    } else {
        &[
            CornerTracking::Incidence,
            CornerTracking::Lazy,
            CornerTracking::Ranks,
        ]
    };
    for t in [1.0, 5.0] {
        for &tracking in resident_trackings {
            play(
                bytes,
                &path,
                Goal::Threshold(t),
                tracking,
                true,
                Timed::Adjusts,
                runs.threads,
            )?;
            if runs.sweep && tracking == CornerTracking::Ranks {
                play_sweep(bytes, &path, t)?;
            }
            if runs.settled {
                for timed in [Timed::SettledChecks, Timed::Readjusts] {
                    let goal = Goal::Threshold(t);
                    play(bytes, &path, goal, tracking, true, timed, runs.threads)?;
                }
            }
        }
        if resident_only {
            continue;
        }
        play(
            bytes,
            &path,
            Goal::Threshold(t),
            CornerTracking::Incidence,
            true,
            Timed::SettledChecks,
            runs.threads,
        )?;
        play(
            bytes,
            &path,
            Goal::Threshold(t),
            CornerTracking::Incidence,
            false,
            Timed::Adjusts,
            runs.threads,
        )?;
    }
    println!();
    Ok(())
}
