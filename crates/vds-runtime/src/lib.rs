//! The view-dependent runtime of vds: the cut through a `.vdt` vertex tree, adjusted every
//! frame for a viewpoint (Luebke & Erikson, "View-Dependent Simplification of Arbitrary
//! Polygonal Environments", SIGGRAPH 1997).
//!
//! ```no_run
//! use vds_runtime::{Camera, Criteria, Goal, Runtime, Viewpoint};
//! let mut runtime = Runtime::open("model.vdt".as_ref(), Default::default())?;
//! let camera = Camera::framing([0.0; 3], 1.0, [0.0, 0.0, 1.0], 1280, 720);
//! let frame = runtime.adjust(&Viewpoint::Camera(camera), &Criteria::default(), Goal::Threshold(1.0))?;
//! for slot in &frame.changes.dirty_slots {
//!     let _triangle = runtime.cut_mut().slot(*slot); // upload this slot
//! }
//! # Ok::<(), vds_format::VdtError>(())
//! ```
//!
//! - [`store`]: nodes and triangles, fetched a page at a time through the format's reader.
//! - [`cut`]: node labels, the boundary, active triangles in slots, fold and unfold.
//! - [`criteria`]: the screen-space, silhouette, backface, frustum and gaze tests.
//! - [`adjust`]: the per-frame threshold traversal and the triangle-budget exchange.
//! - [`reuse`]: margins that let a threshold test stand while the camera moves little.
//! - [`sweep`]: the threshold cut evaluated from scratch, page by page, as bits per node.
//! - [`camera_path`]: camera paths (orbit, fly-through) and their JSON form.
//! - [`measure`]: exact screen-space deviation of the original vertices, for checks.
//! - [`nearest`]: the original vertex nearest a point (measurements snap to it).
//! - [`export`]: the cut as an OBJ or PLY mesh (`vds-cut`).
//! - [`size`]: byte sizes on command lines (`--memory-budget 512MiB`).

#![deny(missing_docs)]

pub mod adjust;
pub mod camera_path;
pub mod criteria;
pub mod cut;
pub mod export;
mod journal;
mod loader;
pub mod measure;
pub mod nearest;
mod prefetch;
mod repeats;
pub mod reuse;
pub mod size;
pub mod store;
pub mod sweep;
pub mod view;

use std::path::Path;

/// Uniform numbers in `[0, 1)` from a xorshift generator, for the unit tests' random cases.
#[cfg(test)]
pub(crate) fn unit_random(mut seed: u64) -> impl FnMut() -> f32 {
    move || {
        seed ^= seed << 13;
        seed ^= seed >> 7;
        seed ^= seed << 17;
        (seed >> 40) as f32 / (1u64 << 24) as f32
    }
}

pub use adjust::{AdjustStats, Adjuster};
pub use camera_path::{CameraPath, PathSource};
pub use criteria::{Bound, Criteria, Decision, Facing, FrustumMode, Gaze, Goal, Judge, Viewpoint};
pub use cut::{ActiveTriangle, Changes, CornerTracking, Cut, NIL, NodeState};
pub use loader::default_threads as default_loading_threads;
pub use store::{
    LoadError, Loading, MemoryStats, Node, NodeStore, PageSource, default_memory_budget,
};
pub use vds_format::VdtError;
pub use view::{Camera, View};

/// What one adjust did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Frame {
    /// The changes to the active triangle list.
    pub changes: Changes,
    /// The work done.
    pub stats: AdjustStats,
    /// The threshold the adjust used ([`Goal::Threshold`] only): the one asked for, or a
    /// larger one while the memory budget cannot hold the cut that one needs.
    pub effective_threshold: Option<f32>,
    /// Memory and paging after the adjust.
    pub memory: MemoryStats,
}

/// The share of the budget the effective threshold steers the pinned bytes towards.
const TARGET_SHARE: f64 = 0.8;
/// The share under which the threshold comes back down.
const RELIEF_SHARE: f64 = 0.6;
/// Bounds of one frame's step of the threshold, up and down.
const STEP_UP: (f64, f64) = (1.05, 1.5);
const STEP_DOWN: (f64, f64) = (1.02, 1.2);
/// Frames in a row with refusals after which the threshold rises whatever their kind.
const REFUSING_FRAMES: u32 = 8;
/// How much larger each step up is than the one before while the threshold rises frame
/// after frame.
const STEP_GROWTH: f64 = 1.1;
/// The largest factor the threshold is raised by.
const MAX_THRESHOLD_SCALE: f32 = 1e6;

/// A cut over one `.vdt` file and the scratch state to adjust it.
pub struct Runtime {
    cut: Cut,
    adjuster: Adjuster,
    /// Effective threshold over the requested one (1 while the budget holds the cut).
    threshold_scale: f32,
    /// Frames in a row in which the budget refused something, and the refusal count then.
    refusing_frames: u32,
    refusals_seen: u64,
    /// Frames in a row in which the threshold rose.
    rising_frames: u32,
    /// Threshold adjusts by sweeps from scratch instead of the incremental pass
    /// ([`Runtime::set_sweep`]).
    sweep: Option<sweep::Sweep>,
}

impl Runtime {
    /// Opens `path` (memory-mapped) with the root alone in the cut.
    pub fn open(path: &Path, tracking: CornerTracking) -> Result<Runtime, VdtError> {
        Runtime::new(Box::new(vds_format::VdtFile::open(path)?), tracking)
    }

    /// A runtime over any page source, loading pages synchronously.
    pub fn new(source: Box<dyn PageSource>, tracking: CornerTracking) -> Result<Runtime, VdtError> {
        Runtime::with_loading(source, tracking, Loading::Synchronous)
    }

    /// A runtime over any page source, loading pages as `loading` says.
    pub fn with_loading(
        source: Box<dyn PageSource>,
        tracking: CornerTracking,
        loading: Loading,
    ) -> Result<Runtime, VdtError> {
        Ok(Runtime {
            cut: Cut::new(NodeStore::with_loading(source, loading)?, tracking),
            adjuster: Adjuster::default(),
            threshold_scale: 1.0,
            refusing_frames: 0,
            refusals_seen: 0,
            rising_frames: 0,
            sweep: None,
        })
    }

    /// Tests the threshold pass's active entries on `threads` threads (1, the default: on the
    /// calling thread). The cut is the same whatever the number; folds and unfolds stay on
    /// the calling thread.
    pub fn set_adjust_threads(&mut self, threads: usize) {
        self.adjuster.set_threads(threads);
    }

    /// The number of threads the threshold pass tests entries on.
    pub fn adjust_threads(&self) -> usize {
        self.adjuster.threads()
    }

    /// The threshold pass one entry at a time ([`Adjuster::set_one_step_pass`]): the
    /// reference its two-step form is checked against.
    pub fn set_one_step_pass(&mut self, on: bool) {
        self.adjuster.set_one_step_pass(on);
    }

    /// Threshold adjusts by a sweep from scratch ([`sweep`]) with its changes applied through
    /// the cut's fold and unfold, instead of the incremental pass; budget adjusts are the
    /// same either way. The sweep's cut is the top-down one: it folds an active node that
    /// passes even while a child still fails, which the incremental pass leaves active until
    /// the child folds. Mesh-fold prevention does not apply to it, and it fetches no page
    /// ahead of need. Either way the next adjust starts from the cut as it is.
    pub fn set_sweep(&mut self, on: bool) {
        if on == self.sweep.is_some() {
            return;
        }
        // The incremental pass's records of reused tests and nodes to revisit did not see
        // what the sweeps changed.
        self.cut.clear_reuse();
        self.cut.forget_revisits();
        self.sweep = on.then(sweep::Sweep::new);
    }

    /// Sets the memory budget in bytes for the decoded tree and the cut
    /// ([`default_memory_budget`] until set; [`u64::MAX`] for none). The store never holds
    /// more: pages below the boundary are evicted, and when the cut itself does not fit, the
    /// effective threshold rises ([`Frame::effective_threshold`]).
    pub fn set_memory_budget(&mut self, bytes: u64) {
        self.cut.store.set_memory_budget(bytes);
    }

    /// Memory and paging figures now.
    pub fn memory(&self) -> MemoryStats {
        self.cut.store.memory()
    }

    /// The threshold an adjust for `t` uses now: `t`, or more while the budget cannot hold
    /// the cut.
    pub fn effective_threshold(&self, t: f32) -> f32 {
        t * self.threshold_scale
    }

    /// Pages asked of the background loader and not yet taken in (0 when loading is
    /// synchronous): while above zero, some node waits to unfold.
    pub fn pending_pages(&self) -> u32 {
        self.cut.store.pending_pages()
    }

    /// Waits until the background loader has delivered every page asked for, and takes them
    /// in; the next adjust can then unfold their nodes. Returns at once when loading is
    /// synchronous.
    pub fn wait_for_pages(&mut self) {
        self.cut.store.wait_for_pages();
    }

    /// Errors of pages the background loader could not read since the last call, each
    /// reported once, naming the page; the nodes that needed them stay folded.
    pub fn take_page_errors(&mut self) -> Vec<VdtError> {
        self.cut.store.take_page_errors()
    }

    /// The cut.
    pub fn cut(&self) -> &Cut {
        &self.cut
    }

    /// The cut, for local operations and reading slots.
    pub fn cut_mut(&mut self) -> &mut Cut {
        &mut self.cut
    }

    /// Adjusts the cut for `viewpoint` and returns what changed since the last adjust.
    pub fn adjust(
        &mut self,
        viewpoint: &Viewpoint,
        criteria: &Criteria,
        goal: Goal,
    ) -> Result<Frame, VdtError> {
        // Pages the background loader delivered since the last adjust: their nodes may
        // unfold in this one.
        self.cut.store.begin_frame();
        self.cut.store.poll();
        let judge = Judge::new(viewpoint, criteria);
        let prevent = criteria.prevent_mesh_folds;
        let (stats, effective_threshold) = match goal {
            Goal::Threshold(t) => {
                let effective = self.effective_threshold(t);
                self.cut.store.foresee(Some((&judge, effective)));
                let stats = match &mut self.sweep {
                    Some(sweep) => {
                        sweep::adjust_threshold(sweep, &mut self.cut, &judge, effective)?
                    }
                    None => {
                        self.adjuster
                            .adjust_threshold(&mut self.cut, &judge, effective, prevent)?
                    }
                };
                (stats, Some(effective))
            }
            Goal::Budget(n) => {
                self.cut.store.foresee(None);
                let stats = self
                    .adjuster
                    .adjust_budget(&mut self.cut, &judge, n, prevent)?;
                (stats, None)
            }
        };
        let changes = self.cut.take_changes();
        self.cut.store.cancel_unasked();
        self.cut.store.evict_to_budget();
        self.respond_to_pressure();
        Ok(Frame {
            changes,
            stats,
            effective_threshold,
            memory: self.cut.store.memory(),
        })
    }

    /// Raises the effective threshold while the cut does not fit (Cesium's memory-adjusted
    /// screen-space error): while the cut's demand ([`NodeStore::demanded_bytes`]: what it
    /// pins and the pages its waiting nodes asked for) is over what arrivals are held to, or
    /// the pinned bytes alone are over the budget, or a page or
    /// growth step the cut needed was refused that would not have fitted even with every
    /// unpinned page evicted, or refusals of any kind went on for [`REFUSING_FRAMES`] frames
    /// in a row. (A refusal that would have fitted is, at first, the budget waiting a frame
    /// for pages that just arrived to be used, not a cut too large; if it goes on, the pages
    /// the cut needs are evicting each other.) Below [`RELIEF_SHARE`] of the budget the
    /// threshold comes back down.
    ///
    /// Each step is proportional: a threshold `s` times larger asks for about `1/s²` the
    /// triangles, so the step is the square root of how far the demand is from
    /// [`TARGET_SHARE`] of the budget, within [`STEP_UP`] or [`STEP_DOWN`], and the
    /// threshold settles near the cut that fits instead of overshooting it. The demand
    /// cannot show how far a cut that does not fit is from fitting (the pinned bytes stop at
    /// the budget, and a page stays pinned until its last node leaves the cut), so while the threshold
    /// rises frame after frame because the cut does not fit, each step up is [`STEP_GROWTH`]
    /// times the one before: a threshold that must rise twentyfold gets there in about ten
    /// frames, not sixty, and overshoots by at most one step.
    fn respond_to_pressure(&mut self) {
        let store = &mut self.cut.store;
        let refused = store.take_refused();
        let refusals = store.memory().refusals;
        if refusals > std::mem::replace(&mut self.refusals_seen, refusals) {
            self.refusing_frames += 1;
        } else {
            self.refusing_frames = 0;
        }
        let budget = store.memory_budget() as f64;
        // What the cut holds and waits for: when that is past what arrivals are held to, the
        // cut cannot fit, and the threshold rises before the budget fills with pages of a
        // cut that will be coarsened anyway.
        let demanded = store.demanded_bytes();
        let off_target = (demanded as f64 / (TARGET_SHARE * budget)).sqrt();
        let outgrown =
            store.over_budget_pinned() || refused > 0 || demanded > store.arrival_limit();
        if outgrown || self.refusing_frames >= REFUSING_FRAMES {
            let least = STEP_UP.0 * STEP_GROWTH.powi(self.rising_frames.min(64) as i32);
            let step = off_target.max(least).clamp(STEP_UP.0, STEP_UP.1) as f32;
            self.threshold_scale = (self.threshold_scale * step).min(MAX_THRESHOLD_SCALE);
            // Pages evicting each other near the budget is not a cut far too large: the
            // steps grow only while the cut itself does not fit.
            self.rising_frames = if outgrown { self.rising_frames + 1 } else { 0 };
            return;
        }
        self.rising_frames = 0;
        if self.threshold_scale > 1.0 && (demanded as f64) < RELIEF_SHARE * budget {
            let step = (1.0 / off_target.max(1e-9)).clamp(STEP_DOWN.0, STEP_DOWN.1) as f32;
            self.threshold_scale = (self.threshold_scale / step).max(1.0);
        }
    }

    /// Makes every page resident ([`NodeStore::load_every_page`]): set a budget that holds
    /// the model first, or the next adjust evicts what does not fit.
    pub fn load_every_page(&mut self) -> Result<(), VdtError> {
        self.cut.store.load_every_page()
    }

    /// The original vertex positions by leaf rank (reads every page, keeps none).
    pub fn leaf_positions(&mut self) -> Result<Vec<[f32; 3]>, VdtError> {
        measure::leaf_positions(&self.cut.store)
    }

    /// The budget-mode priority of node `id` under `judge` (for checking §3.3's stopping
    /// rule): call right after a budget adjust with the same judge.
    pub fn budget_priority(&mut self, judge: &Judge, id: u32) -> f32 {
        self.adjuster.priority(&self.cut, judge, id)
    }
}
