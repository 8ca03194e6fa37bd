//! The threshold cut evaluated from scratch in one sweep over the resident pages: the first
//! step of a runtime whose unit of work is a page, not a node (`docs/architecture.md`,
//! "Sweeps").
//!
//! The cut a sweep finds is the paper's top-down one: a node is active exactly when the
//! criteria ask each of its ancestors and itself to unfold (a node outside the frustum in
//! [`crate::FrustumMode::Ignore`] keeps its state of the sweep before). Every boundary node
//! therefore passes the test for this view, which is the threshold guarantee.
//!
//! It needs no state but one bit per node of the pages holding active nodes, and it reads
//! memory in order: nodes are numbered in page order with parents before children, so taking
//! the pages in index order and each page's active nodes in id order visits every parent
//! before its children. An active node whose group bound passes ([`Judge::group_within`])
//! has no child to unfold and its children are not read; the others' children, which are
//! contiguous, are tested one by one. What changed since the sweep before comes out of the
//! two bit sets: nodes that unfolded (ascending, so parents first) and nodes that folded, and
//! with their families the report a rank-tracking renderer reads ([`Sweep::report`]).
//!
//! A node unfolds only if its children are resident and checked; one whose criteria ask for
//! it but whose children are not is left folded and listed ([`Sweep::deferred`]); once they
//! arrive, [`Sweep::resume`] continues below it without sweeping the rest again.
//!
//! [`crate::Runtime::set_sweep`] makes a runtime's threshold adjusts run a sweep and apply
//! its changes through the cut's own fold and unfold.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use vds_format::VdtError;

use crate::adjust::AdjustStats;
use crate::criteria::{Decision, FrustumMode, Judge};
use crate::cut::{Changes, Cut, NIL};
use crate::store::{Hot, NodeStore, TestedPage};

/// Work done and found by one [`Sweep::run`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SweepStats {
    /// Nodes whose criteria were evaluated (the root and the children of active nodes
    /// whose group bound failed).
    pub tests: u32,
    /// Active nodes whose group bound passed: their children were not read.
    pub groups_passed: u32,
    /// Pages holding an active node.
    pub pages: u32,
    /// Active nodes.
    pub active: u32,
    /// Nodes active now that were not at the sweep before.
    pub unfolded: u32,
    /// Nodes active at the sweep before that are not now.
    pub folded: u32,
    /// Nodes the criteria ask to unfold whose children are not resident and checked.
    pub deferred: u32,
}

/// The threshold cut as bits per page, evaluated from scratch by [`Sweep::run`].
#[derive(Default)]
pub struct Sweep {
    /// Per page index: one bit per node of the page, set for the active ones; empty for a
    /// page that has never held one. All zero for pages not in `pages`.
    active: Vec<Vec<u64>>,
    /// `active` as the sweep before left it.
    before: Vec<Vec<u64>>,
    /// Pages holding an active node now, ascending.
    pages: Vec<u32>,
    /// `pages` as the sweep before left it.
    pages_before: Vec<u32>,
    /// One bit per page: queued in this sweep.
    queued: Vec<u64>,
    queue: BinaryHeap<Reverse<u32>>,
    /// In [`Sweep::resume`]: the nodes it unfolded whose children are still to test.
    nodes_queued: BinaryHeap<Reverse<u32>>,
    unfolded: Vec<u32>,
    folded: Vec<u32>,
    /// Nodes the criteria asked to unfold whose children were not resident and checked.
    deferred: Vec<u32>,
    /// In [`Sweep::resume`]: nodes newly marked active are listed as unfolded.
    resuming: bool,
    /// [`Cut::operations`] of the cut [`adjust_threshold`] last left in step with these bits.
    operations: u64,
}

impl Sweep {
    /// A sweep whose cut before its first run is the root alone, folded.
    pub fn new() -> Sweep {
        Sweep::default()
    }

    /// Evaluates the cut for `judge`'s view at threshold `t` over `store`'s resident pages,
    /// and what changed since the run before.
    pub fn run(&mut self, store: &NodeStore, judge: &Judge, t: f32) -> SweepStats {
        self.fit(store);
        std::mem::swap(&mut self.active, &mut self.before);
        std::mem::swap(&mut self.pages, &mut self.pages_before);
        for &p in &self.pages {
            self.active[p as usize].fill(0);
        }
        self.pages.clear();
        self.deferred.clear();
        let mut stats = SweepStats::default();
        if let Some(root_page) = store.tested_page(0) {
            stats.tests = 1;
            let keep = bit(&self.before, 0, 0);
            if root_page.hot[0].child_count > 0 && unfolds(judge, root_page.tested(0), t, keep) {
                self.unfold_or_defer(store, 0, root_page, 0, 0, &mut None);
            }
        }
        self.sweep_queued(store, judge, t, &mut stats);
        stats.pages = self.pages.len() as u32;
        stats.deferred = self.deferred.len() as u32;
        self.diff(store, &mut stats);
        stats
    }

    /// Gives the per-page tables a row for every page of `store`'s file.
    fn fit(&mut self, store: &NodeStore) {
        let page_count = store.page_count() as usize;
        if self.active.len() < page_count {
            self.active.resize_with(page_count, Vec::new);
            self.before.resize_with(page_count, Vec::new);
            self.queued.resize(page_count.div_ceil(64), 0);
        }
    }

    /// Takes `active` (ascending node ids, every one resident with its children) as the
    /// last run's cut: what the next run's changes are counted from.
    pub fn adopt(&mut self, store: &NodeStore, active: &[u32]) {
        self.fit(store);
        for &p in &self.pages {
            self.active[p as usize].fill(0);
        }
        self.pages.clear();
        for &id in active {
            let p = store.page_of(id).expect("an active node exists");
            let page = store.tested_page(p).expect("an active node is resident");
            let local = (id - page.first) as usize;
            let bits = &mut self.active[p as usize];
            if bits.is_empty() {
                bits.resize(page.hot.len().div_ceil(64), 0);
            }
            bits[local / 64] |= 1 << (local % 64);
            if self.pages.last() != Some(&p) {
                self.pages.push(p);
            }
        }
        self.pages.sort_unstable();
        self.pages.dedup();
    }

    /// Continues the last run below `seeds`, nodes it left waiting ([`Sweep::deferred`]) whose
    /// children have arrived since, for the same view and threshold: each seed unfolds (the
    /// run found that the criteria ask for it) and what lies below it is swept as in a run.
    /// Only nodes unfold: afterwards [`Sweep::unfolded`] lists those that did in this call,
    /// ascending, and [`Sweep::deferred`] those left waiting.
    pub fn resume(
        &mut self,
        store: &NodeStore,
        judge: &Judge,
        t: f32,
        seeds: &[u32],
    ) -> SweepStats {
        self.unfolded.clear();
        self.folded.clear();
        self.deferred.clear();
        self.resuming = true;
        let mut stats = SweepStats::default();
        for &id in seeds {
            let Some((p, page)) = store
                .page_of(id)
                .and_then(|p| Some((p, store.tested_page(p)?)))
            else {
                continue;
            };
            let local = (id - page.first) as usize;
            if !bit(&self.active, p, local) {
                self.unfold_or_defer(store, p, page, local, id, &mut None);
            }
        }
        // Only the nodes this call unfolds are visited, parents first: the rest of the cut
        // was swept by the run.
        let tight = judge.tightest(t);
        while let Some(Reverse(id)) = self.nodes_queued.pop() {
            let p = store.page_of(id).expect("an unfolded node exists");
            let page = store.tested_page(p).expect("an unfolded node is resident");
            let mut cursor = Cursor {
                index: p,
                page,
                grandchildren: None,
            };
            let hot = &page.hot[(id - page.first) as usize];
            self.visit(store, judge, t, tight, hot, &mut cursor, &mut stats);
        }
        self.pages.sort_unstable();
        self.pages.dedup();
        self.resuming = false;
        self.unfolded.sort_unstable();
        stats.pages = self.pages.len() as u32;
        stats.deferred = self.deferred.len() as u32;
        stats.unfolded = self.unfolded.len() as u32;
        stats
    }

    /// Sweeps the queued pages in index order, and those their nodes queue.
    fn sweep_queued(&mut self, store: &NodeStore, judge: &Judge, t: f32, stats: &mut SweepStats) {
        let tight = judge.tightest(t);
        let first_new = self.pages.len();
        while let Some(Reverse(p)) = self.queue.pop() {
            self.pages.push(p);
            let page = store
                .tested_page(p)
                .expect("a page holding an active node is resident");
            self.sweep_page(store, judge, t, tight, p, page, stats);
        }
        for &p in &self.pages[first_new..] {
            self.queued[p as usize / 64] &= !(1 << (p % 64));
        }
    }

    /// Tests the children of page `p`'s active nodes, in id order: children in this page
    /// come later in it, so re-reading each word picks them up.
    #[allow(clippy::too_many_arguments)]
    fn sweep_page<'a>(
        &mut self,
        store: &'a NodeStore,
        judge: &Judge,
        t: f32,
        tight: f32,
        p: u32,
        page: TestedPage<'a>,
        stats: &mut SweepStats,
    ) {
        let words = self.active[p as usize].len();
        let mut cursor = Cursor {
            index: p,
            page,
            grandchildren: None,
        };
        for w in 0..words {
            let mut done = 0u64;
            loop {
                let pending = self.active[p as usize][w] & !done;
                if pending == 0 {
                    break;
                }
                let b = pending.trailing_zeros();
                done |= 1 << b;
                let hot = &page.hot[w * 64 + b as usize];
                self.visit(store, judge, t, tight, hot, &mut cursor, stats);
            }
        }
    }

    /// Tests the children of the active node of record `hot` (unless its group bound says
    /// none can unfold) and marks those that unfold.
    #[allow(clippy::too_many_arguments)]
    #[inline]
    fn visit<'a>(
        &mut self,
        store: &'a NodeStore,
        judge: &Judge,
        t: f32,
        tight: f32,
        hot: &Hot,
        cursor: &mut Cursor<'a>,
        stats: &mut SweepStats,
    ) {
        stats.active += 1;
        // A passing group bound folds every child, except that in `Ignore` mode a child
        // outside the frustum keeps its state: those active before are tested.
        let group_passed = judge.group_within(hot, tight);
        if group_passed {
            stats.groups_passed += 1;
            if judge.criteria().frustum != FrustumMode::Ignore {
                return;
            }
        }
        for c in hot.first_child..hot.first_child + hot.child_count {
            if !cursor.page.holds(c) {
                // Siblings share a page, so this is once a family at most.
                cursor.index = store.page_of(c).expect("children exist");
                cursor.page = store
                    .tested_page(cursor.index)
                    .expect("an active node's children are resident");
            }
            let local = (c - cursor.page.first) as usize;
            let keep = bit(&self.before, cursor.index, local);
            if group_passed && !keep {
                continue;
            }
            stats.tests += 1;
            let child = &cursor.page.hot[local];
            if child.child_count == 0 || !unfolds(judge, cursor.page.tested(local), t, keep) {
                continue;
            }
            let (index, page) = (cursor.index, cursor.page);
            self.unfold_or_defer(store, index, page, local, c, &mut cursor.grandchildren);
        }
    }

    /// Marks node `id`, entry `local` of page `p`, active when its children are resident and
    /// checked ([`children_resident`], with its cache `grandchildren`), and lists it as
    /// deferred when they are not.
    fn unfold_or_defer<'a>(
        &mut self,
        store: &'a NodeStore,
        p: u32,
        page: TestedPage<'a>,
        local: usize,
        id: u32,
        grandchildren: &mut Option<TestedPage<'a>>,
    ) {
        if page.is_checked(local) && children_resident(store, id, &page.hot[local], grandchildren) {
            self.set(p, local, page.hot.len(), id);
        } else {
            self.deferred.push(id);
        }
    }

    /// Marks entry `local` of page `p` (of `len` nodes), node `id`, active. In a run, queues
    /// the page; when resuming, lists and queues the node itself if it was not active.
    #[inline]
    fn set(&mut self, p: u32, local: usize, len: usize, id: u32) {
        let bits = &mut self.active[p as usize];
        if bits.is_empty() {
            bits.resize(len.div_ceil(64), 0);
        }
        let word = &mut bits[local / 64];
        let fresh = *word & (1 << (local % 64)) == 0;
        *word |= 1 << (local % 64);
        if self.resuming {
            if fresh {
                self.unfolded.push(id);
                self.nodes_queued.push(Reverse(id));
                self.pages.push(p);
            }
            return;
        }
        let queued = &mut self.queued[p as usize / 64];
        if *queued & (1 << (p % 64)) == 0 {
            *queued |= 1 << (p % 64);
            self.queue.push(Reverse(p));
        }
    }

    /// Lists the nodes whose bit differs from the sweep before.
    fn diff(&mut self, store: &NodeStore, stats: &mut SweepStats) {
        let (mut unfolded, mut folded) = (
            std::mem::take(&mut self.unfolded),
            std::mem::take(&mut self.folded),
        );
        unfolded.clear();
        folded.clear();
        self.bits_now_and_before()
            .for_each_change(store, |id, now| match now {
                true => unfolded.push(id),
                false => folded.push(id),
            });
        (self.unfolded, self.folded) = (unfolded, folded);
        stats.unfolded = self.unfolded.len() as u32;
        stats.folded = self.folded.len() as u32;
    }

    /// The cut now and as the run before found it.
    fn bits_now_and_before(&self) -> BitsNowAndBefore<'_> {
        BitsNowAndBefore {
            pages: &self.pages,
            pages_before: &self.pages_before,
            now: &self.active,
            before: &self.before,
        }
    }

    /// What changed from the cut the run before left to the cut now (after the last run and
    /// the resumes since), as a renderer tracking leaf ranks reads it: nodes unfolded and
    /// folded (ascending), nodes that joined and left the boundary, triangles added and
    /// removed. It is found from the two bit sets and the changed nodes' families alone, with
    /// no state per node: an unfolded node leaves the boundary if its parent was active, and
    /// its children that are not active now join it; a folded node joins the boundary if its
    /// parent is active, and its children that were not active leave it (the root's parent
    /// counts as active). Repeats are not looked for (`hidden` and `shown` stay empty, as do
    /// the slot fields). `None` when a changed node's page is no longer resident.
    pub fn report(&self, store: &NodeStore) -> Option<Changes> {
        let bits = self.bits_now_and_before();
        let mut changes = Changes::default();
        let mut complete = true;
        bits.for_each_change(store, |id, now| {
            let Some(family) = store.family(id) else {
                complete = false;
                return;
            };
            let children = family.first_child..family.first_child + family.child_count;
            if now {
                changes.added += family.subtri_count;
                changes.unfolded.push(id);
                if bits.is_set_before(store, family.parent) {
                    changes.left_boundary.push(id);
                }
                let joined = children_unset(bits.now, store, children);
                changes.joined_boundary.extend(joined);
            } else {
                changes.removed += family.subtri_count;
                changes.folded.push(id);
                if bits.is_set_now(store, family.parent) {
                    changes.joined_boundary.push(id);
                }
                let left = children_unset(bits.before, store, children);
                changes.left_boundary.extend(left);
            }
        });
        complete.then_some(changes)
    }

    /// Nodes active now that were not at the run before, ascending (parents first).
    pub fn unfolded(&self) -> &[u32] {
        &self.unfolded
    }

    /// Nodes active at the run before that are not now, ascending.
    pub fn folded(&self) -> &[u32] {
        &self.folded
    }

    /// Nodes the last run's criteria asked to unfold whose children were not resident and
    /// checked, so they stayed folded.
    pub fn deferred(&self) -> &[u32] {
        &self.deferred
    }

    /// Whether node `id` is active in the last run's cut.
    pub fn is_active(&self, store: &NodeStore, id: u32) -> bool {
        store
            .page_of(id)
            .is_some_and(|p| bit(&self.active, p, (id - store.page_first(p)) as usize))
    }

    /// The active nodes of the last run's cut, ascending.
    pub fn active_nodes(&self, store: &NodeStore) -> Vec<u32> {
        let mut nodes = Vec::new();
        for &p in &self.pages {
            let first = store.page_first(p);
            for (w, &word) in self.active[p as usize].iter().enumerate() {
                let mut bits = word;
                while bits != 0 {
                    nodes.push(first + (w * 64) as u32 + bits.trailing_zeros());
                    bits &= bits - 1;
                }
            }
        }
        nodes
    }
}

/// A threshold adjust of `cut` by sweeps ([`crate::Runtime::set_sweep`]): the sweep's
/// changes applied through the cut's own fold (deepest first) and unfold (parents first), so
/// that every other part of the runtime (labels, repeats, the change report, pinned pages)
/// sees an ordinary cut. The nodes a sweep leaves folded because their children are not
/// resident get them: with synchronous loading they are loaded and the sweep resumes below
/// them ([`Sweep::resume`]), once per level of pages reached, until no node waits or no page
/// could be loaded (the memory budget refused it); with background loading they are asked
/// for, by their screen-space error, and unfold in a later adjust.
///
/// `cut` must be what `sweep`'s last run left (or the root alone, before its first).
pub(crate) fn adjust_threshold(
    sweep: &mut Sweep,
    cut: &mut Cut,
    judge: &Judge,
    t: f32,
) -> Result<AdjustStats, VdtError> {
    if sweep.operations != cut.operations() {
        // Something else changed the cut since the last sweep (a budget adjust, or a caller's
        // own folds and unfolds): its active nodes become the sweep's starting point.
        let mut active: Vec<u32> = cut.active_entries().iter().map(|e| e.id).collect();
        active.sort_unstable();
        sweep.adopt(cut.store(), &active);
    }
    let mut in_step = true;
    let stats = sweep_and_apply(sweep, cut, judge, t, &mut in_step);
    // Out of step (an unfold the memory budget refused, or an error midway), the next
    // adjust adopts the cut as it is.
    sweep.operations = if in_step && stats.is_ok() {
        cut.operations()
    } else {
        u64::MAX
    };
    stats
}

/// [`adjust_threshold`] once `sweep` holds `cut`'s active nodes.
fn sweep_and_apply(
    sweep: &mut Sweep,
    cut: &mut Cut,
    judge: &Judge,
    t: f32,
    in_step: &mut bool,
) -> Result<AdjustStats, VdtError> {
    let mut stats = AdjustStats::default();
    // The still passes' list of nodes to revisit is the incremental pass's; it must not
    // grow with these changes.
    cut.forget_revisits();
    let mut found = sweep.run(cut.store(), judge, t);
    let mut seeds = Vec::new();
    loop {
        stats.visited += found.tests + found.active;
        stats.groups += found.active;
        stats.groups_failed += found.active - found.groups_passed;
        for &id in sweep.folded().iter().rev() {
            cut.fold_node(id, false);
        }
        for &id in sweep.unfolded() {
            // The cut's own arrays grow within the memory budget: a node it cannot make room
            // for stays folded, and so does everything the sweep unfolded below it.
            if unfoldable(cut, id) && cut.reserve_for_unfold(id) {
                cut.unfold_available(id);
                stats.unfolds += 1;
            } else {
                *in_step = false;
            }
        }
        stats.folds += found.folded;
        seeds.clear();
        for &id in sweep.deferred() {
            // Below a node the budget kept folded, a deferred node is not in the cut.
            if !unfoldable(cut, id) {
                *in_step = false;
            } else if cut.children_available(id)? {
                seeds.push(id);
            } else if cut.request_children(id, judge.screen_error(cut.store().tested(id))) {
                stats.deferred_unfolds += 1;
            }
        }
        if seeds.is_empty() {
            return Ok(stats);
        }
        found = sweep.resume(cut.store(), judge, t, &seeds);
        // Resumed rounds only unfold, so they end; one that unfolds nothing (a page loaded
        // for one seed was evicted for another's) ends them too.
        if found.unfolded == 0 {
            stats.visited += found.tests + found.active;
            return Ok(stats);
        }
    }
}

/// Two cuts as bits per page: now, and as the run before left it.
#[derive(Clone, Copy)]
struct BitsNowAndBefore<'a> {
    /// Pages holding an active node now, and before (ascending).
    pages: &'a [u32],
    pages_before: &'a [u32],
    now: &'a [Vec<u64>],
    before: &'a [Vec<u64>],
}

impl BitsNowAndBefore<'_> {
    /// Calls `each(id, now)` for every node active in one cut and not the other, in ascending
    /// id order (`now`: active now).
    fn for_each_change(&self, store: &NodeStore, mut each: impl FnMut(u32, bool)) {
        let (mut a, mut b) = (0, 0);
        // Both page lists are ascending: walk their union in order.
        while a < self.pages.len() || b < self.pages_before.len() {
            let p = match (self.pages.get(a), self.pages_before.get(b)) {
                (Some(&x), Some(&y)) => x.min(y),
                (Some(&x), None) => x,
                (None, Some(&y)) => y,
                (None, None) => unreachable!(),
            };
            a += usize::from(self.pages.get(a) == Some(&p));
            b += usize::from(self.pages_before.get(b) == Some(&p));
            let first = store.page_first(p);
            let (now, then) = (&self.now[p as usize], &self.before[p as usize]);
            for w in 0..now.len().max(then.len()) {
                let x = now.get(w).copied().unwrap_or(0);
                let mut changed = x ^ then.get(w).copied().unwrap_or(0);
                while changed != 0 {
                    let k = changed.trailing_zeros();
                    changed &= changed - 1;
                    each(first + (w * 64) as u32 + k, x & (1 << k) != 0);
                }
            }
        }
    }

    /// Whether node `id` is active now; [`NIL`] (the root's parent) is.
    fn is_set_now(&self, store: &NodeStore, id: u32) -> bool {
        is_set(self.now, store, id)
    }

    /// Whether node `id` was active before; [`NIL`] (the root's parent) was.
    fn is_set_before(&self, store: &NodeStore, id: u32) -> bool {
        is_set(self.before, store, id)
    }
}

/// The nodes of `ids` (a node's children) not set in `pages`, with one page look-up for those
/// in the first one's page.
#[inline]
fn children_unset<'a>(
    pages: &'a [Vec<u64>],
    store: &'a NodeStore,
    ids: std::ops::Range<u32>,
) -> impl Iterator<Item = u32> + 'a {
    let page = store.page_of(ids.start);
    let first = page.map_or(0, |p| store.page_first(p));
    let in_page = page.map_or(0, |p| store.page_end(p) - first);
    ids.filter(move |&c| {
        let set = match page {
            Some(p) if c - first < in_page => bit(pages, p, (c - first) as usize),
            _ => is_set(pages, store, c),
        };
        !set
    })
}

/// Whether node `id` is set in `pages`; [`NIL`] is.
#[inline]
fn is_set(pages: &[Vec<u64>], store: &NodeStore, id: u32) -> bool {
    id == NIL
        || store
            .page_of(id)
            .is_some_and(|p| bit(pages, p, (id - store.page_first(p)) as usize))
}

/// Whether the criteria leave a node active: unfold, or keep a node that was (`keep`).
#[inline]
fn unfolds(judge: &Judge, tested: crate::store::Tested<'_>, t: f32, keep: bool) -> bool {
    match judge.decide(tested, t) {
        Decision::Unfold => true,
        Decision::Fold => false,
        Decision::Keep => keep,
    }
}

/// Whether node `id` is on the boundary of `cut` with children, so it may unfold. Below a node
/// whose unfold the budget refused, the sweep's nodes are not in the cut, and their pages,
/// which nothing pins, may have been evicted to make room for another.
fn unfoldable(cut: &Cut, id: u32) -> bool {
    cut.store().is_resident(id) && cut.can_unfold(id)
}

/// Where the children of the nodes being visited were last found.
struct Cursor<'a> {
    /// The page holding the last children tested, and its index.
    page: TestedPage<'a>,
    index: u32,
    /// The page of the last grandchildren found resident: consecutive nodes' children are
    /// usually in one page, so most residency checks need no look-up.
    grandchildren: Option<TestedPage<'a>>,
}

/// Whether the children of node `id`, of record `hot`, are resident: in the page `last`
/// (then kept), or found so by the store (and that page kept if it holds them all).
#[inline]
fn children_resident<'a>(
    store: &'a NodeStore,
    id: u32,
    hot: &Hot,
    last: &mut Option<TestedPage<'a>>,
) -> bool {
    let (first, end) = (hot.first_child, hot.first_child + hot.child_count - 1);
    if last.is_some_and(|page| page.holds(first) && page.holds(end)) {
        return true;
    }
    let page = store
        .page_of(first)
        .and_then(|index| store.tested_page(index))
        .filter(|page| page.holds(end));
    if page.is_some() {
        *last = page;
        return true;
    }
    // Children over two pages, or not resident.
    store.children_resident(id)
}

/// Bit `local` of page `p` in `pages` (false for a page without bits).
#[inline]
fn bit(pages: &[Vec<u64>], p: u32, local: usize) -> bool {
    pages
        .get(p as usize)
        .and_then(|bits| bits.get(local / 64))
        .is_some_and(|word| word & (1 << (local % 64)) != 0)
}
