//! Adjusting the cut for a new viewpoint: the threshold traversal along the boundary path
//! (Luebke & Erikson 1997 §3.1, §4.1) and the triangle-budget exchange (§3.3).
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
//! Work per frame is the active nodes (one 56-byte record each, and a bound for those whose
//! last test no longer holds) plus the boundary nodes near the threshold plus what changes.
//!
//! After the traversal every boundary node has passed the test for this frame — its group
//! passed, or it was tested and stayed, or it folded because it passed — which is the
//! threshold guarantee: no visible vertex is further than `t` pixels from its image.
//!
//! ## Budget
//! A max-queue of boundary nodes by priority (screen-space error over the criteria's
//! threshold scale) and a min-queue of *fold candidates* (active nodes whose children are all
//! on the boundary). Starting from the current cut (coherence), the worst boundary node is
//! unfolded while its subtris fit (counted as drawn: repeats once, see `repeats.rs`; an
//! unfold that splits repeats past the budget is undone, and the node does not fit after
//! all); when it does not fit and a fold candidate is cheaper, that
//! candidate is folded to make room. A node's priority is clamped to its parent's, so a fold
//! candidate is never the parent of the node it makes room for. Each exchange replaces lower
//! priorities by a higher one, so the loop terminates; it stops when the worst boundary node
//! does not fit and nothing cheaper can fold: unfolding the next node in the queue would
//! exceed the budget, which is §3.3's stopping rule.

use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;

use vds_format::VdtError;

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

/// How many entries ahead of the threshold traversal its children's data is prefetched.
const LOOKAHEAD: usize = 8;

/// How many entries ahead the traversal prefetches the active list itself.
const STREAM_AHEAD: usize = 32;

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

/// What every entry of one threshold pass is visited with ([`Adjuster::visit_entry`]).
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

/// A float with a total order, for the priority queues.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Priority(f32);

impl Eq for Priority {}

impl PartialOrd for Priority {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Priority {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0)
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
    fn full_pass(&mut self, cut: &mut Cut, pass: &Pass, listing: bool) -> Result<(), VdtError> {
        // Backwards through the dense active list: an unfold appends nodes whose children
        // it has just tested, so they need no visit now; a fold moves the last entry (already
        // visited) into the folded node's place, so nothing unvisited is skipped.
        let mut i = cut.active_entries().len();
        while i > 0 {
            i -= 1;
            // The list is read backwards, which the hardware prefetchers follow poorly.
            if let Some(far) = i.checked_sub(STREAM_AHEAD) {
                cut.prefetch_entry(far);
            }
            // A group whose test is not reused nearly always fails it (the margin keeps the
            // others), and then its children's labels and test data are read: a few misses
            // per group, started here for a group a few entries ahead so they overlap.
            if let Some(ahead) = i.checked_sub(LOOKAHEAD)
                && let Some(entry) = cut.active_entries().get(ahead)
                && entry.active_children < entry.hot.child_count
                && !pass.now.as_ref().is_some_and(|now| entry.reuse.holds(now))
            {
                cut.prefetch_children(ahead);
            }
            if listing {
                let id = cut.active_entries().get(i).map_or(NIL, |entry| entry.id);
                let settled = self.visit_entry(cut, pass, i)?;
                list_unsettled(cut, i, id, settled);
            } else {
                self.visit_entry(cut, pass, i)?;
            }
        }
        Ok(())
    }

    /// One entry of the threshold pass: its boundary children's group (skipped while its
    /// record holds, [`crate::reuse`]) and, for a fold candidate, its own test. Returns
    /// whether the entry settled: nothing in it unfolded or waits for a page, and it did not
    /// try to fold.
    #[inline(always)]
    fn visit_entry(&mut self, cut: &mut Cut, pass: &Pass, i: usize) -> Result<bool, VdtError> {
        let Pass {
            sight,
            tight,
            prevent_flips,
            prefetching,
            ref now,
        } = *pass;
        let (judge, t) = (sight.judge, sight.t);
        let Some(&entry) = cut.active_entries().get(i) else {
            return Ok(true);
        };
        let hot = entry.hot;
        let mut settled = true;
        if entry.active_children < hot.child_count {
            if now.as_ref().is_some_and(|now| entry.reuse.holds(now)) {
                self.stats.groups_reused += 1;
            } else {
                self.stats.visited += 1;
                self.stats.groups += 1;
                // The group's margin, or the least of its children's when each had to be
                // tested and none unfolded.
                let mut margin = judge.group_margin(&hot, tight);
                if margin.is_none() {
                    self.stats.groups_failed += 1;
                    let mut least = f32::INFINITY;
                    for c in hot.first_child..hot.first_child + hot.child_count {
                        let (label, tested) = cut.store().labelled(c);
                        if label.state != NodeState::Boundary {
                            continue;
                        }
                        self.stats.visited += 1;
                        let (decision, child_margin) = judge.decide_with_margin(tested, t);
                        if decision == Decision::Unfold {
                            least = 0.0;
                            settled = false;
                            self.refine(cut, judge, t, c)?;
                        } else {
                            least = least.min(child_margin);
                            // Near its threshold: its children's pages are fetched
                            // ahead of need, the nearest first.
                            if prefetching {
                                // Cheap test first: most nodes are far from it.
                                let hot = *tested.hot;
                                let now = sight.now(&hot);
                                if now > PREFETCH_RATIO * 0.5 {
                                    let deeper = &mut self.deeper;
                                    prefetch_below(cut, sight, c, hot, now, 0, deeper);
                                }
                            }
                        }
                    }
                    margin = Some(least);
                }
                // Still at index `i`: refinement only appended entries (and an unfold
                // cleared this entry's record, which stays cleared with a zero margin).
                if let (Some(now), Some(margin)) = (now, margin)
                    && margin > 0.0
                {
                    cut.set_reuse(i, Reuse::new(now, judge.group_reach(&hot), margin));
                }
            }
        }
        // Still at index `i` (refinement above only appended entries, and an unfolded child
        // shows in the count): the entry itself says whether `p` may fold, without a look-up
        // by node id, which would miss the cache on every entry.
        let Some(&entry) = cut.active_entries().get(i) else {
            return Ok(settled);
        };
        let p = entry.id;
        if entry.active_children == 0 {
            self.stats.visited += 1;
            if judge.decide(cut.active_tested(i), t) == Decision::Fold {
                settled = false;
                self.coarsen(cut, judge, t, p, prevent_flips);
            }
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

    /// The priority of unfolding `id` this frame: the judge's priority, clamped to its
    /// parent's (see the module documentation).
    pub fn priority(&mut self, cut: &Cut, judge: &Judge, id: u32) -> f32 {
        // Walk up to the first ancestor already priced this frame, then price down.
        self.stack.clear();
        let mut n = id;
        let mut above = f32::MAX;
        while n != NIL {
            if let Some(&value) = self.priorities.get(&n) {
                above = value;
                break;
            }
            self.stack.push(n);
            n = cut.node(n).parent;
        }
        while let Some(n) = self.stack.pop() {
            self.stats.visited += 1;
            let surface = cut.store().surface_error(n);
            above = judge.priority(cut.store().tested(n), surface).min(above);
            self.priorities.insert(n, above);
        }
        above
    }

    /// Adjusts `cut` to the best cut of at most `budget` triangles under `judge`.
    pub fn adjust_budget(
        &mut self,
        cut: &mut Cut,
        judge: &Judge,
        budget: u32,
        prevent_flips: bool,
    ) -> Result<AdjustStats, VdtError> {
        self.begin();
        self.unfold_queue.clear();
        self.fold_queue.clear();
        self.work.clear();
        self.work.extend(cut.boundary());
        for i in 0..self.work.len() {
            let b = self.work[i];
            self.queue_unfold(cut, judge, b);
            self.queue_fold(cut, judge, cut.node(b).parent);
        }
        // Over budget (the budget shrank): fold the cheapest candidates. The budget is a hard
        // limit, so mesh-fold prevention yields here.
        while cut.counted_triangles() > budget {
            let Some(f) = self.pop_fold(cut) else { break };
            cut.fold_node(f, false);
            self.stats.folds += 1;
            self.after_fold(cut, judge, f);
        }
        self.exchange(cut, judge, budget, prevent_flips)?;
        // Refused folds again (see `retry_refused_folds`): back in the queue after changes
        // that may have removed the triangle they would have flipped. A round that goes on
        // made an exchange, and a frame's exchanges are finite (module documentation), so
        // the rounds end.
        while !self.refused.is_empty() {
            let changes = self.stats.folds + self.stats.unfolds;
            for f in std::mem::take(&mut self.refused) {
                self.queue_fold(cut, judge, f);
            }
            self.exchange(cut, judge, budget, prevent_flips)?;
            if self.stats.folds + self.stats.unfolds == changes {
                break;
            }
        }
        Ok(self.stats)
    }

    /// The budget's exchanges (see the module documentation) until the worst boundary node
    /// does not fit and no cheaper candidate can fold.
    fn exchange(
        &mut self,
        cut: &mut Cut,
        judge: &Judge,
        budget: u32,
        prevent_flips: bool,
    ) -> Result<(), VdtError> {
        while let Some(&(Priority(worst), Reverse(u))) = self.peek_unfold(cut) {
            if worst <= 0.0 {
                break;
            }
            // A node whose children are not resident is passed over (its pages asked for)
            // before anything is folded to make room for it. (With synchronous loading they
            // are read here, and passed over only when they do not fit in the memory budget.)
            if !cut.children_available(u)? {
                self.unfold_queue.pop();
                if cut.request_children(u, worst) {
                    self.stats.deferred_unfolds += 1;
                }
                continue;
            }
            let cost = cut.node(u).subtri_count;
            if u64::from(cut.counted_triangles()) + u64::from(cost) <= u64::from(budget) {
                cut.unfold_node(u)?;
                // An unfold can split classes of repeats that were counted once, and so add
                // more than its subtris: one that goes past the budget is undone, and the node
                // does not fit after all.
                if cut.counted_triangles() > budget {
                    cut.fold_node(u, false);
                } else {
                    self.unfold_queue.pop();
                    self.stats.unfolds += 1;
                    for c in cut.node(u).children() {
                        self.queue_unfold(cut, judge, c);
                    }
                    self.queue_fold(cut, judge, u);
                    continue;
                }
            }
            match self.peek_fold(cut) {
                Some(&Reverse((Priority(cheapest), f))) if cheapest < worst => {
                    self.pop_fold(cut);
                    if cut.fold_node(f, prevent_flips) {
                        self.stats.folds += 1;
                        self.after_fold(cut, judge, f);
                    } else {
                        self.stats.refused_folds += 1;
                        self.refused.push(f);
                    }
                }
                _ => break,
            }
        }
        Ok(())
    }

    fn after_fold(&mut self, cut: &Cut, judge: &Judge, id: u32) {
        self.queue_unfold(cut, judge, id);
        self.queue_fold(cut, judge, cut.node(id).parent);
    }

    fn queue_unfold(&mut self, cut: &Cut, judge: &Judge, id: u32) {
        if cut.can_unfold(id) {
            let p = self.priority(cut, judge, id);
            self.unfold_queue.push((Priority(p), Reverse(id)));
        }
    }

    fn queue_fold(&mut self, cut: &Cut, judge: &Judge, id: u32) {
        if id != NIL && cut.can_fold(id) && self.queued.insert(id) {
            let p = self.priority(cut, judge, id);
            self.fold_queue.push(Reverse((Priority(p), id)));
        }
    }

    fn peek_unfold(&mut self, cut: &Cut) -> Option<&(Priority, Reverse<u32>)> {
        while let Some(&(_, Reverse(u))) = self.unfold_queue.peek() {
            if cut.can_unfold(u) {
                break;
            }
            self.unfold_queue.pop();
        }
        self.unfold_queue.peek()
    }

    fn peek_fold(&mut self, cut: &Cut) -> Option<&Reverse<(Priority, u32)>> {
        while let Some(&Reverse((_, f))) = self.fold_queue.peek() {
            if cut.can_fold(f) {
                break;
            }
            // A node that stops being a candidate may become one again this frame.
            self.queued.remove(&f);
            self.fold_queue.pop();
        }
        self.fold_queue.peek()
    }

    fn pop_fold(&mut self, cut: &Cut) -> Option<u32> {
        let f = self.peek_fold(cut)?.0.1;
        self.fold_queue.pop();
        self.queued.remove(&f);
        Some(f)
    }
}
