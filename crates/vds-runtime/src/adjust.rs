//! Adjusting the cut for a new viewpoint: the threshold traversal along the boundary path
//! (Luebke & Erikson 1997 §3.1, §4.1) and the triangle-budget exchange (§3.3, in `budget.rs`).
//!
//! ## Threshold
//! The paper's `adjust_tree` recurses through the active tree, and its §4.1 traversal follows
//! the boundary path. Every decision happens at the boundary: a boundary node that needs more
//! detail unfolds (and its new children are checked in turn); an active node whose children
//! are all on the boundary folds if it passes itself, and the fold goes on upwards.
//!
//! The traversal walks a dense array of the active nodes (so memory streams) and asks two
//! questions of each:
//! - *Do its boundary children need anything?* One bound for the whole group answers "no"
//!   for most of them ([`Judge::group_within`]: a ball around the node's proxy holding every
//!   child's error ball, checked against the tightest threshold); only groups near the limit
//!   test their children one by one.
//! - *Can it fold?* Only if all its children are on the boundary; then its own full test
//!   decides.
//!
//! A group's test is not repeated while the camera has moved less than the margin it passed
//! with ([`crate::reuse`]): along a smooth path most groups skip their bound.
//!
//! A pass asks both questions of every entry first (`findings.rs`: the tests read the
//! store and write only each entry's own record, so shares of the list can be tested on
//! several threads), then acts on the entries marked, from the last to the first, on the
//! calling thread. Acting on one entry changes what was tested of another only in ways the
//! acting step checks for; the one-step pass, which tests and acts on each entry in turn, is
//! kept as the reference ([`Adjuster::set_one_step_pass`]).
//!
//! Work per frame is the active nodes (one 56-byte record each, and a bound for those whose
//! last test no longer holds) plus the boundary nodes near the threshold plus what changes.
//!
//! After the traversal every boundary node has passed the test for this frame — its group
//! passed, or it was tested and stayed, or it folded because it passed — which is the
//! threshold guarantee: no visible vertex is further than `t` pixels from its image.

mod budget;
mod findings;

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use vds_format::VdtError;

use budget::Priority;
use findings::{Findings, GROUP_FAILED, GroupFindings, MAY_FOLD, test_children, test_entry};

use crate::criteria::{Decision, Judge};
use crate::cut::{Cut, NIL, NodeState};
use crate::reuse::{MotionLog, Reuse};
use crate::store::Hot;

/// Work done by one adjust.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct AdjustStats {
    /// Nodes whose criteria were evaluated (group bounds and single nodes).
    pub visited: u32,
    /// Group bounds evaluated (threshold mode).
    pub groups: u32,
    /// Groups whose bound failed, so their children were tested one by one.
    pub groups_failed: u32,
    /// Groups not tested because their last test still holds for this camera
    /// ([`crate::reuse`]).
    pub groups_reused: u32,
    /// Nodes unfolded.
    pub unfolds: u32,
    /// Nodes folded.
    pub folds: u32,
    /// Folds refused because they would flip a triangle (a fold tried again within the same
    /// adjust and refused again counts again).
    pub refused_folds: u32,
    /// Unfolds put off because the node's children were not resident yet (background
    /// loading only): their pages are asked for. Nodes whose pages failed to load are not
    /// counted: they stay folded for good.
    pub deferred_unfolds: u32,
}

impl AdjustStats {
    /// Adds the counts of `other`, work done on another thread for the same adjust.
    fn add(&mut self, other: &AdjustStats) {
        let AdjustStats {
            visited,
            groups,
            groups_failed,
            groups_reused,
            unfolds,
            folds,
            refused_folds,
            deferred_unfolds,
        } = *other;
        self.visited += visited;
        self.groups += groups;
        self.groups_failed += groups_failed;
        self.groups_reused += groups_reused;
        self.unfolds += unfolds;
        self.folds += folds;
        self.refused_folds += refused_folds;
        self.deferred_unfolds += deferred_unfolds;
    }
}

/// After a still pass (or the full pass that starts a run of them) visited node `id` at
/// index `i`: lists it for the next still pass unless it `settled`. A node that left index
/// `i` folded: its parent's record was cleared, which listed the parent.
fn list_unsettled(cut: &mut Cut, i: usize, id: u32, settled: bool) {
    if !settled
        && cut
            .active_entries()
            .get(i)
            .is_some_and(|entry| entry.id == id)
    {
        cut.revisit(id);
    }
}

/// A boundary node whose screen-space error is past this share of the threshold has its
/// children's pages fetched ahead of need (background loading): a camera closing in by less
/// than half the distance makes it unfold.
const PREFETCH_RATIO: f32 = 0.5;

/// How far ahead the camera's motion is extrapolated for fetching pages, in frames: about
/// what a page takes to arrive when a few are in flight (tens of milliseconds each).
const LEAD_FRAMES: f32 = 8.0;

/// How far ahead the threshold pass asks for what it reads: the children of the failed group
/// this many failed groups later, and the entry this many marked entries later.
const LOOKAHEAD: usize = 8;

/// How many levels below a folded node pages are fetched ahead of need when the node is
/// about to unfold: a camera closing in fast unfolds several levels in one frame, and each
/// level may be another page.
const PREFETCH_LEVELS: u32 = 3;

/// How many folded nodes a frame looks below for pages to fetch ([`PREFETCH_LEVELS`]), the
/// nearest to their threshold first: the look costs a few page look-ups per child, and a
/// node that needs it stays near its threshold for several frames. With pages a level or two
/// deep, nearly every level below is another page: on the 1 M fly-through within the budget,
/// 1,024 put off 1,381 unfolds in all where 256 put off 8,015, for 0.2 ms more a frame
/// (looking 4 levels down instead of 3 put off 311, for 1 ms more).
const DEEPER_PER_FRAME: usize = 1024;

/// The share of its threshold past which a folded node's resident children are looked at
/// for pages to fetch ([`PREFETCH_LEVELS`]).
const DEEPER_RATIO: f32 = 0.9;

/// Fetches the children's pages of folded node `id` ahead of need when its error (now, or
/// where the camera is heading) is past [`PREFETCH_RATIO`] of the threshold. When its
/// children are resident and it is past [`DEEPER_RATIO`]: on the top level it becomes a
/// candidate in `deeper` (the frame looks below the nearest of them,
/// [`Adjuster::prefetch_deeper`]); below, its children are looked at in turn, down to
/// [`PREFETCH_LEVELS`] levels.
fn prefetch_below(
    cut: &mut Cut,
    sight: &Sight,
    id: u32,
    hot: Hot,
    now: f32,
    level: u32,
    deeper: &mut Vec<(f32, u32)>,
) {
    if hot.child_count == 0 {
        return;
    }
    let ratio = sight
        .ahead
        .map_or(now, |ahead| now.max(ahead.screen_error_of(&hot) / sight.t));
    if ratio <= PREFETCH_RATIO {
        return;
    }
    if !cut.children_resident(id) {
        cut.store_mut()
            .prefetch_children(id, ratio - 1.0 - level as f32);
    } else if now > DEEPER_RATIO && level + 1 < PREFETCH_LEVELS {
        if level == 0 {
            deeper.push((now, id));
        } else {
            sight.below(cut, hot, level + 1, deeper);
        }
    }
}

/// What every entry of one threshold pass is tested and acted on with.
struct Pass<'a> {
    /// The judge and threshold (`sight.judge`, `sight.t`), and the view ahead.
    sight: &'a Sight<'a>,
    /// The tightest threshold any node gets ([`Judge::tightest`]).
    tight: f32,
    prevent_flips: bool,
    /// Pages load in the background: nodes near their threshold fetch their children's.
    prefetching: bool,
    /// The motion log at this frame (`None` without a camera).
    now: Option<crate::reuse::Now>,
}

/// What [`prefetch_below`] judges by: the view now, the view ahead, the threshold.
struct Sight<'a> {
    judge: &'a Judge,
    ahead: Option<&'a Judge>,
    t: f32,
}

impl Sight<'_> {
    /// `hot`'s error now, as a share of the threshold.
    fn now(&self, hot: &Hot) -> f32 {
        self.judge.screen_error_of(hot) / self.t
    }

    /// [`prefetch_below`] on each child of the node `hot` (children resident), at `level`.
    fn below(&self, cut: &mut Cut, hot: Hot, level: u32, deeper: &mut Vec<(f32, u32)>) {
        for c in hot.first_child..hot.first_child + hot.child_count {
            let child = *cut.store().tested(c).hot;
            prefetch_below(cut, self, c, child, self.now(&child), level, deeper);
        }
    }
}

/// Scratch state of the adjust traversals, reused from frame to frame.
#[derive(Default)]
pub struct Adjuster {
    /// Nodes whose priority this frame computed, and the priority (budget mode; cleared
    /// every frame, so it holds the nodes one exchange touched, not the model).
    priorities: rustc_hash::FxHashMap<u32, f32>,
    /// Nodes queued as fold candidates this frame.
    queued: rustc_hash::FxHashSet<u32>,
    work: Vec<u32>,
    stack: Vec<u32>,
    /// Nodes whose fold mesh-fold prevention refused this frame, to try again.
    refused: Vec<u32>,
    unfold_queue: BinaryHeap<(Priority, Reverse<u32>)>,
    fold_queue: BinaryHeap<Reverse<(Priority, u32)>>,
    motion: MotionLog,
    /// Folded nodes near their threshold whose children are resident, with their share of
    /// the threshold: this frame's candidates for [`Adjuster::prefetch_deeper`].
    deeper: Vec<(f32, u32)>,
    /// What the threshold pass's tests found ([`Adjuster::test_entries`]), kept for reuse.
    findings: Findings,
    /// Scratch of [`Adjuster::act_on`] for children tested on the spot.
    spot: Findings,
    /// Scratch of the threshold pass: entries moved with something pending.
    moved: Vec<u32>,
    /// The threshold pass tests and acts on one entry at a time
    /// ([`Adjuster::set_one_step_pass`]).
    one_step: bool,
    /// The threads the threshold pass tests entries on, when more than the calling one.
    threads: usize,
    stats: AdjustStats,
}

impl Adjuster {
    fn begin(&mut self) {
        self.priorities.clear();
        self.queued.clear();
        self.stats = AdjustStats::default();
        self.refused.clear();
        self.deeper.clear();
    }

    /// The threshold decision for `id`. Not cached: the traversal asks each node at most
    /// once per frame except along fold cascades, which are short and rare.
    #[inline]
    fn decision(&mut self, cut: &Cut, judge: &Judge, t: f32, id: u32) -> Decision {
        self.stats.visited += 1;
        judge.decide(cut.store().tested(id), t)
    }

    /// Adjusts `cut` so that every visible vertex is within `t` of its image.
    pub fn adjust_threshold(
        &mut self,
        cut: &mut Cut,
        judge: &Judge,
        t: f32,
        prevent_flips: bool,
    ) -> Result<AdjustStats, VdtError> {
        self.begin();
        if cut.state(0) == NodeState::Boundary {
            if self.decision(cut, judge, t, 0) == Decision::Unfold {
                self.refine(cut, judge, t, 0)?;
            } else {
                return Ok(self.stats);
            }
        }
        let prefetching = cut.store().loads_in_background() && t > 0.0;
        // Pages are fetched for where the camera is heading too, not only where it is.
        let ahead = prefetching
            .then(|| self.motion.ahead(judge, t, LEAD_FRAMES))
            .flatten();
        let sight = Sight {
            judge,
            ahead: ahead.as_ref(),
            t,
        };
        let now = self.motion.advance(judge, t);
        if now.is_some_and(|now| now.fresh) {
            cut.clear_reuse();
        }
        let pass = Pass {
            sight: &sight,
            tight: judge.tightest(t),
            prevent_flips,
            prefetching,
            now,
        };
        if now.is_some_and(|now| now.still) {
            self.still_pass(cut, &pass)?;
        } else {
            // A moving camera: the next still pass starts from a full pass again.
            cut.forget_revisits();
            self.full_pass(cut, &pass, false)?;
        }
        self.prefetch_deeper(cut, &sight);
        self.retry_refused_folds(cut, judge, t, prevent_flips);
        Ok(self.stats)
    }

    /// The threshold pass for a camera where it was at the previous adjust: every test gives
    /// what it gave then, so only entries that did not settle then, and those the cut changed
    /// since, are visited (the list the previous still pass left, [`Cut::begin_still_pass`]);
    /// a full pass that lists them when there is none.
    fn still_pass(&mut self, cut: &mut Cut, pass: &Pass) -> Result<(), VdtError> {
        let Some(mut listed) = cut.begin_still_pass() else {
            return self.full_pass(cut, pass, true);
        };
        listed.sort_unstable();
        listed.dedup();
        for id in listed {
            if let Some(i) = cut.active_index(id) {
                let settled = self.visit_entry(cut, pass, i)?;
                list_unsettled(cut, i, id, settled);
            }
        }
        Ok(())
    }

    /// The threshold pass over the whole active list; `listing`: each entry that does not
    /// settle is listed for the next still pass ([`Cut::revisit`]).
    ///
    /// Two steps. First every entry is tested as the cut stands ([`test_entry`]: its group,
    /// and whether it may fold), and the children of each group whose bound failed are read
    /// from the store and tested ([`test_children`]); what is pending is marked in the entry.
    /// Then the marked entries are acted on, from the last to the first, as the one-step pass
    /// visits them: an unfold appends entries whose children it has just tested.
    ///
    /// Acting on one entry changes what the first step saw of another in three ways, each
    /// handled in [`Adjuster::act_marked`]. A fold that leaves its parent with no active
    /// child tests the parent at once ([`Adjuster::coarsen`]). A fold that puts a child back
    /// on the boundary makes its parent's findings stale: they are made again. A fold moves
    /// the last entry into the folded one's place: an entry still pending is then acted on
    /// where it lands, with findings made for it.
    ///
    /// The cut is the one-step pass's (`tests/two_step.rs`) as long as no fold is refused for
    /// flipping a triangle: a refused fold may succeed later in the same pass, after the
    /// folds and unfolds between, and the one-step pass tries again the parents it reaches
    /// afterwards. With mesh-fold prevention the pass therefore runs one step at a time. (An
    /// unfold the memory budget refuses, or a page fetched ahead of need, can also come out
    /// differently: both depend on the order of what the pass does, and neither breaks the
    /// threshold guarantee.)
    fn full_pass(&mut self, cut: &mut Cut, pass: &Pass, listing: bool) -> Result<(), VdtError> {
        if self.one_step || pass.prevent_flips {
            return self.one_step_pass(cut, pass, listing);
        }
        self.test_entries(cut, pass);
        let mut findings = std::mem::take(&mut self.findings);
        let acted = self.act_marked(cut, pass, listing, &mut findings);
        if acted.is_err() {
            // An unfold's page failed to load: the entries not reached keep nothing pending.
            for &i in &findings.marked {
                cut.take_pending(i as usize);
            }
            cut.take_moved_pending(&mut self.moved);
            self.moved.clear();
        }
        debug_assert!(
            cut.active_entries().iter().all(|entry| entry.pending == 0),
            "an entry's pending test outcome was not acted on"
        );
        self.findings = findings;
        acted
    }

    /// The second step of [`Adjuster::full_pass`]: the entries `findings` marked acted on,
    /// from the last to the first.
    fn act_marked(
        &mut self,
        cut: &mut Cut,
        pass: &Pass,
        listing: bool,
        findings: &mut Findings,
    ) -> Result<(), VdtError> {
        while let (Some(i), Some(group)) = (findings.marked.pop(), findings.groups.pop()) {
            // An unfold reads the node's children again: a few misses, started here for an
            // entry a few ahead.
            if let Some(k) = findings.marked.len().checked_sub(LOOKAHEAD)
                && findings.groups[k].is_some_and(|g| g.unfold.0 < g.unfold.1)
            {
                let ahead = findings.marked[k] as usize;
                cut.prefetch_entry(ahead);
                cut.prefetch_children(ahead);
            }
            let i = i as usize;
            let pending = cut.take_pending(i);
            if pending == 0 {
                continue;
            }
            let id = cut.active_entries()[i].id;
            let settled = self.act_on(cut, pass, i, pending, group.map(|g| (g, &*findings)))?;
            if listing {
                list_unsettled(cut, i, id, settled);
            }
            // A fold moves the last entry into the folded one's place. That entry is pending
            // only when folds shortened the list past this one: it is acted on where it
            // landed, in turn, with its children tested then (findings already marked at
            // that index were made for the folded entry).
            cut.take_moved_pending(&mut self.moved);
            for j in self.moved.drain(..) {
                match findings.marked.binary_search(&j) {
                    Ok(at) => findings.groups[at] = None,
                    Err(at) => {
                        findings.marked.insert(at, j);
                        findings.groups.insert(at, None);
                    }
                }
            }
        }
        Ok(())
    }

    /// [`Adjuster::full_pass`] one entry at a time: each tested and acted on in turn, from the
    /// last to the first ([`Adjuster::set_one_step_pass`]).
    fn one_step_pass(&mut self, cut: &mut Cut, pass: &Pass, listing: bool) -> Result<(), VdtError> {
        let mut i = cut.active_entries().len();
        while i > 0 {
            i -= 1;
            let id = cut.active_entries().get(i).map_or(NIL, |entry| entry.id);
            let settled = self.visit_entry(cut, pass, i)?;
            if listing {
                list_unsettled(cut, i, id, settled);
            }
        }
        Ok(())
    }

    /// Makes the threshold pass test and act on each active entry in turn, on the calling
    /// thread, instead of testing them all first. Slower, and the same cut: the reference the
    /// two-step pass is checked against.
    pub fn set_one_step_pass(&mut self, on: bool) {
        self.one_step = on;
    }

    /// Tests the threshold pass's entries on `threads` threads (1: on the calling thread,
    /// the default). The cut is the same whatever the number.
    pub fn set_threads(&mut self, threads: usize) {
        self.threads = threads.max(1);
    }

    /// The number of threads the threshold pass tests entries on.
    pub fn threads(&self) -> usize {
        self.threads.max(1)
    }

    /// One entry tested ([`test_entry`]) and acted on at once, as still passes and the
    /// one-step pass visit them. Returns whether it settled: nothing in it unfolded or waits
    /// for a page, and it did not try to fold.
    fn visit_entry(&mut self, cut: &mut Cut, pass: &Pass, i: usize) -> Result<bool, VdtError> {
        let (entries, shapes, _) = cut.active_entries_mut();
        let (Some(entry), Some(shape)) = (entries.get_mut(i), shapes.get(i)) else {
            return Ok(true);
        };
        let pending = test_entry(entry, shape, pass, &mut self.stats);
        self.act_on(cut, pass, i, pending, None)
    }

    /// Acts on what [`test_entry`] found pending for the active entry at `i`: the children of
    /// a group whose bound failed that need it are unfolded (and those near their threshold
    /// have their children's pages fetched ahead of need), and an entry that may fold folds
    /// if it still can. `group`: its children's tests ([`test_children`]), made with the
    /// entry's; they are made again now when there are none, when they were made for another
    /// entry, or when a child folded since. Returns whether the entry settled: nothing in it
    /// unfolded or waits for a page, and it did not try to fold.
    fn act_on(
        &mut self,
        cut: &mut Cut,
        pass: &Pass,
        i: usize,
        pending: u16,
        group: Option<(GroupFindings, &Findings)>,
    ) -> Result<bool, VdtError> {
        let Pass {
            sight,
            prevent_flips,
            ref now,
            ..
        } = *pass;
        let (judge, t) = (sight.judge, sight.t);
        let Some(&entry) = cut.active_entries().get(i) else {
            return Ok(true);
        };
        let hot = entry.hot;
        let mut settled = true;
        if pending & GROUP_FAILED != 0 && u32::from(entry.active_children) < hot.child_count {
            self.stats.groups_failed += 1;
            let mut spot = std::mem::take(&mut self.spot);
            let (group, findings) = match group {
                Some((group, findings))
                    if (group.id, group.active_children) == (entry.id, entry.active_children) =>
                {
                    (group, findings)
                }
                _ => {
                    spot.clear();
                    let group = test_children(&entry, cut.store(), pass, &mut spot);
                    self.stats.add(&spot.stats);
                    (group, &spot)
                }
            };
            let (begin, end) = group.unfold;
            for &c in &findings.unfold[begin as usize..end as usize] {
                settled = false;
                self.refine(cut, judge, t, c)?;
            }
            let (begin, end) = group.near;
            for &(c, share) in &findings.near[begin as usize..end as usize] {
                let hot = *cut.store().tested(c).hot;
                prefetch_below(cut, sight, c, hot, share, 0, &mut self.deeper);
            }
            self.spot = spot;
            // Still at index `i`: refinement only appended entries (and an unfold cleared
            // this entry's record, which stays cleared with a zero margin).
            if let Some(now) = now
                && group.least > 0.0
            {
                cut.set_reuse(i, Reuse::new(now, judge.group_reach(&hot), group.least));
            }
        }
        // Still at index `i`, and an unfolded child shows in the count.
        let Some(&entry) = cut.active_entries().get(i) else {
            return Ok(settled);
        };
        if pending & MAY_FOLD != 0 && entry.active_children == 0 {
            settled = false;
            self.coarsen(cut, judge, t, entry.id, prevent_flips);
        }
        Ok(settled)
    }

    /// Looks below the [`DEEPER_PER_FRAME`] candidates nearest to their threshold for pages
    /// to fetch ([`prefetch_below`]); those the frame folded or unfolded since are skipped.
    fn prefetch_deeper(&mut self, cut: &mut Cut, sight: &Sight) {
        let mut deeper = std::mem::take(&mut self.deeper);
        if deeper.len() > DEEPER_PER_FRAME {
            deeper.select_nth_unstable_by(DEEPER_PER_FRAME, |a, b| b.0.total_cmp(&a.0));
            deeper.truncate(DEEPER_PER_FRAME);
        }
        // Below the top level nothing becomes a candidate: this stays empty.
        let mut none = Vec::new();
        for &(_, id) in &deeper {
            // Pages below the boundary may have been evicted since the candidate was taken.
            if !cut.store().is_resident(id)
                || cut.state(id) != NodeState::Boundary
                || !cut.children_resident(id)
            {
                continue;
            }
            let hot = *cut.store().tested(id).hot;
            sight.below(cut, hot, 1, &mut none);
        }
        deeper.clear();
        self.deeper = deeper;
    }

    /// Mesh-fold prevention refuses a fold for the triangles around the node as they are at
    /// that moment; later folds and unfolds of the same frame can remove the triangle that
    /// would have flipped. Refused folds are tried again, until a round folds nothing, so
    /// that the frame ends with a settled cut: adjusting again for the same camera changes
    /// nothing. Each round that goes on folds a node, so the rounds end.
    fn retry_refused_folds(&mut self, cut: &mut Cut, judge: &Judge, t: f32, prevent: bool) {
        while !self.refused.is_empty() {
            let folds = self.stats.folds;
            for id in std::mem::take(&mut self.refused) {
                if cut.can_fold(id) && self.decision(cut, judge, t, id) == Decision::Fold {
                    self.coarsen(cut, judge, t, id, prevent);
                }
            }
            if self.stats.folds == folds {
                return;
            }
        }
    }

    /// Unfolds `id` (which was decided to need it) and, recursively, each new boundary node
    /// that needs it.
    fn refine(&mut self, cut: &mut Cut, judge: &Judge, t: f32, id: u32) -> Result<(), VdtError> {
        if !cut.can_unfold(id) || !self.unfold_if_loaded(cut, judge, id)? {
            return Ok(());
        }
        self.stack.clear();
        self.stack.extend(cut.node(id).children());
        while let Some(n) = self.stack.pop() {
            // The label and the test data in one look-up: most new children stay folded.
            let (label, tested) = cut.store().labelled(n);
            let hot = *tested.hot;
            if label.state != NodeState::Boundary || hot.child_count == 0 {
                continue;
            }
            self.stats.visited += 1;
            if judge.decide(tested, t) == Decision::Unfold
                && self.unfold_if_loaded(cut, judge, n)?
            {
                self.stack
                    .extend(hot.first_child..hot.first_child + hot.child_count);
            }
        }
        Ok(())
    }

    /// Unfolds `id` if its children are resident; otherwise asks for their pages, most
    /// urgent for the nodes farthest past their threshold, and leaves it folded for now.
    fn unfold_if_loaded(
        &mut self,
        cut: &mut Cut,
        judge: &Judge,
        id: u32,
    ) -> Result<bool, VdtError> {
        if !cut.children_available(id)? {
            let urgency = judge.screen_error(cut.store().tested(id));
            if cut.request_children(id, urgency) {
                self.stats.deferred_unfolds += 1;
            }
            return Ok(false);
        }
        cut.unfold_available(id);
        self.stats.unfolds += 1;
        Ok(true)
    }

    /// Folds `id` (which may fold and was decided to) and then its ancestors while each may
    /// fold and passes the test.
    fn coarsen(&mut self, cut: &mut Cut, judge: &Judge, t: f32, mut id: u32, prevent: bool) {
        loop {
            if !cut.fold_node(id, prevent) {
                self.stats.refused_folds += 1;
                self.refused.push(id);
                return;
            }
            self.stats.folds += 1;
            id = cut.store().parent(id);
            if id == NIL || !cut.can_fold(id) || self.decision(cut, judge, t, id) != Decision::Fold
            {
                return;
            }
        }
    }
}
