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
//! Subtrees are independent, so a run can share them among threads ([`Sweep::set_threads`]),
//! each sweeping its share page by page with bits of its own for the pages it reaches (kept
//! between runs, as the sweep's own are), joined at the end.
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
    /// Subtrees shared among the threads ([`Sweep::set_threads`]); zero on one thread.
    pub shared: u32,
}

impl SweepStats {
    /// Adds `other`'s counts to these.
    fn add(&mut self, other: &SweepStats) {
        self.tests += other.tests;
        self.groups_passed += other.groups_passed;
        self.pages += other.pages;
        self.active += other.active;
        self.unfolded += other.unfolded;
        self.folded += other.folded;
        self.deferred += other.deferred;
        self.shared += other.shared;
    }
}

/// The threshold cut as bits per page, evaluated from scratch by [`Sweep::run`].
#[derive(Default)]
pub struct Sweep {
    /// The cut now: its bits (`walker.marks`), the pages holding them (`walker.pages`,
    /// ascending after a run), and the lists of the last run or resume.
    walker: Walker,
    /// `walker.marks` as the sweep before left it.
    before: Vec<Vec<u64>>,
    /// `walker.pages` as the sweep before left it.
    pages_before: Vec<u32>,
    folded: Vec<u32>,
    /// [`Cut::operations`] of the cut [`adjust_threshold`] last left in step with these bits.
    operations: u64,
    /// Threads a run sweeps on ([`Sweep::set_threads`]).
    threads: usize,
    /// One per thread of a parallel run.
    helpers: Vec<Helper>,
}

/// The state of one walk down the cut: what it marked active, what it has still to visit,
/// and what it found. A sweep's own walker holds the cut; each thread of a parallel run walks
/// its share of subtrees with one of its own.
#[derive(Default)]
struct Walker {
    /// Per page index: one bit per node of the page, set for the nodes marked active; empty
    /// for a page that has never held one. All zero for pages not in `pages`.
    marks: Vec<Vec<u64>>,
    /// Pages holding marks: in a run, in the order swept (ascending); otherwise in the order
    /// first marked, with repeats.
    pages: Vec<u32>,
    /// One bit per page: queued in this walk.
    queued: Vec<u64>,
    queue: BinaryHeap<Reverse<u32>>,
    /// Walks by node ([`Order::Nodes`]): the nodes marked whose children are still to test.
    nodes_queued: BinaryHeap<Reverse<u32>>,
    /// Nodes newly marked ([`Order::Nodes`] listing them), or after a run the nodes active
    /// now that were not before.
    unfolded: Vec<u32>,
    /// Nodes the criteria asked to unfold whose children were not resident and checked.
    deferred: Vec<u32>,
    order: Order,
}

/// How a walker reaches the nodes it marks.
#[derive(Default, Clone, Copy, PartialEq, Eq)]
enum Order {
    /// Page by page in index order: a page is swept once every node that can mark it has
    /// been visited (a run).
    #[default]
    Pages,
    /// Node by node: each node marked is queued itself (a resume, which lists the nodes it
    /// marks, and the first levels of a parallel run, which hands them to the threads).
    Nodes { list: bool },
}

/// A thread's share of a parallel run: the walker it sweeps each chunk of subtrees with, and
/// the marks of the chunks it has finished. Aligned to two cache lines so that no two
/// threads' helpers share one: each thread writes its own counts and queues for every node it
/// visits, and a line written by both would pass between their cores at each write.
#[derive(Default)]
#[repr(align(128))]
struct Helper {
    walker: Walker,
    done: Vec<Vec<u64>>,
    done_pages: Vec<u32>,
    stats: SweepStats,
}

/// How many chunks of subtrees a parallel run makes per thread: threads take them in turn,
/// so that they finish together however unequal the subtrees.
const CHUNKS_PER_THREAD: usize = 32;
/// Subtrees per chunk: a parallel run walks node by node until this many per chunk wait (a
/// cut that never has that many is walked node by node on the calling thread).
const SEEDS_PER_CHUNK: usize = 4;

impl Sweep {
    /// A sweep whose cut before its first run is the root alone, folded.
    pub fn new() -> Sweep {
        Sweep::default()
    }

    /// Runs on `threads` threads (0 or 1: on the calling thread alone; each run starts the
    /// others afresh, so more than the cores only costs). The cut found, its lists of changes
    /// and the work counted are the same; only the order of [`Sweep::deferred`] differs (it
    /// is ascending on several threads). [`Sweep::resume`] runs on the calling thread.
    pub fn set_threads(&mut self, threads: usize) {
        self.threads = threads.max(1);
    }

    /// Evaluates the cut for `judge`'s view at threshold `t` over `store`'s resident pages,
    /// and what changed since the run before.
    pub fn run(&mut self, store: &NodeStore, judge: &Judge, t: f32) -> SweepStats {
        self.fit(store);
        let walker = &mut self.walker;
        std::mem::swap(&mut walker.marks, &mut self.before);
        std::mem::swap(&mut walker.pages, &mut self.pages_before);
        walker.clear_marks();
        walker.deferred.clear();
        let mut stats = SweepStats::default();
        let threads = self.threads.max(1);
        walker.order = match threads {
            1 => Order::Pages,
            _ => Order::Nodes { list: false },
        };
        if let Some(root_page) = store.tested_page(0) {
            stats.tests = 1;
            let keep = bit(&self.before, 0, 0);
            if root_page.hot[0].child_count > 0 && unfolds(judge, root_page.tested(0), t, keep) {
                walker.unfold_or_defer(store, 0, root_page, 0, 0, &mut None);
            }
        }
        if threads == 1 {
            walker.sweep_queued(&Pass::new(store, &self.before, judge, t), &mut stats);
        } else {
            self.sweep_in_parallel(store, judge, t, threads, &mut stats);
        }
        stats.pages = self.walker.pages.len() as u32;
        stats.deferred = self.walker.deferred.len() as u32;
        self.diff(store, &mut stats);
        stats
    }

    /// The rest of a run on `threads` threads, once the root is marked: the first levels node
    /// by node on the calling thread until there are subtrees enough to share, then those
    /// subtrees in chunks, each thread taking the next chunk when done with one and sweeping
    /// it page by page with its own bits (subtrees are disjoint, so no node is visited twice),
    /// and the threads' bits joined into the cut's.
    fn sweep_in_parallel(
        &mut self,
        store: &NodeStore,
        judge: &Judge,
        t: f32,
        threads: usize,
        stats: &mut SweepStats,
    ) {
        let pass = Pass::new(store, &self.before, judge, t);
        let enough = threads * CHUNKS_PER_THREAD * SEEDS_PER_CHUNK;
        let walker = &mut self.walker;
        while walker.nodes_queued.len() < enough {
            let Some(Reverse(id)) = walker.nodes_queued.pop() else {
                break;
            };
            walker.visit_node(&pass, id, stats);
        }
        let mut seeds: Vec<u32> = walker.nodes_queued.drain().map(|Reverse(id)| id).collect();
        seeds.sort_unstable();
        walker.order = Order::Pages;
        if !seeds.is_empty() {
            stats.shared = seeds.len() as u32;
            self.share(store, judge, t, threads, &seeds, stats);
        }
        let walker = &mut self.walker;
        walker.pages.sort_unstable();
        walker.pages.dedup();
        walker.deferred.sort_unstable();
    }

    /// Sweeps the subtrees under `seeds` (marked, not visited) on `threads` threads, and
    /// joins their bits into the cut's.
    fn share(
        &mut self,
        store: &NodeStore,
        judge: &Judge,
        t: f32,
        threads: usize,
        seeds: &[u32],
        stats: &mut SweepStats,
    ) {
        let chunk = seeds.len().div_ceil(threads * CHUNKS_PER_THREAD).max(1);
        let chunks: Vec<&[u32]> = seeds.chunks(chunk).collect();
        let next = std::sync::atomic::AtomicUsize::new(0);
        let page_count = store.page_count() as usize;
        self.helpers.resize_with(threads, Helper::default);
        let pass = Pass::new(store, &self.before, judge, t);
        let work = |helper: &mut Helper| {
            helper.walker.fit(page_count);
            if helper.done.len() < page_count {
                helper.done.resize_with(page_count, Vec::new);
            }
            helper.stats = SweepStats::default();
            helper.walker.deferred.clear();
            loop {
                let k = next.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
                let Some(chunk) = chunks.get(k) else {
                    break;
                };
                helper.sweep_chunk(&pass, chunk);
            }
        };
        let (first, others) = self.helpers.split_first_mut().expect("a helper per thread");
        std::thread::scope(|scope| {
            for helper in others {
                scope.spawn(|| work(helper));
            }
            work(first);
        });
        // The threads' bits into the cut's: every page one marked is listed in its
        // `done_pages`.
        let walker = &mut self.walker;
        for helper in &mut self.helpers {
            for &p in &helper.done_pages {
                move_bits(&mut helper.done[p as usize], &mut walker.marks[p as usize]);
                walker.pages.push(p);
            }
            helper.done_pages.clear();
            walker.deferred.append(&mut helper.walker.deferred);
            stats.add(&helper.stats);
        }
    }

    /// Gives the per-page tables a row for every page of `store`'s file.
    fn fit(&mut self, store: &NodeStore) {
        let page_count = store.page_count() as usize;
        self.walker.fit(page_count);
        if self.before.len() < page_count {
            self.before.resize_with(page_count, Vec::new);
        }
    }

    /// Takes `active` (ascending node ids, every one resident with its children) as the
    /// last run's cut: what the next run's changes are counted from.
    pub fn adopt(&mut self, store: &NodeStore, active: &[u32]) {
        self.fit(store);
        let walker = &mut self.walker;
        walker.clear_marks();
        for &id in active {
            let p = store.page_of(id).expect("an active node exists");
            let page = store.tested_page(p).expect("an active node is resident");
            let local = (id - page.first) as usize;
            let bits = &mut walker.marks[p as usize];
            if bits.is_empty() {
                bits.resize(page.hot.len().div_ceil(64), 0);
            }
            bits[local / 64] |= 1 << (local % 64);
            if walker.pages.last() != Some(&p) {
                walker.pages.push(p);
            }
        }
        walker.pages.sort_unstable();
        walker.pages.dedup();
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
        let walker = &mut self.walker;
        walker.unfolded.clear();
        self.folded.clear();
        walker.deferred.clear();
        walker.order = Order::Nodes { list: true };
        let mut stats = SweepStats::default();
        for &id in seeds {
            let Some((p, page)) = store
                .page_of(id)
                .and_then(|p| Some((p, store.tested_page(p)?)))
            else {
                continue;
            };
            let local = (id - page.first) as usize;
            if !bit(&walker.marks, p, local) {
                walker.unfold_or_defer(store, p, page, local, id, &mut None);
            }
        }
        // Only the nodes this call unfolds are visited, parents first: the rest of the cut
        // was swept by the run.
        let pass = Pass::new(store, &self.before, judge, t);
        while let Some(Reverse(id)) = walker.nodes_queued.pop() {
            walker.visit_node(&pass, id, &mut stats);
        }
        walker.pages.sort_unstable();
        walker.pages.dedup();
        walker.order = Order::Pages;
        walker.unfolded.sort_unstable();
        stats.pages = walker.pages.len() as u32;
        stats.deferred = walker.deferred.len() as u32;
        stats.unfolded = walker.unfolded.len() as u32;
        stats
    }

    /// Lists the nodes whose bit differs from the sweep before.
    fn diff(&mut self, store: &NodeStore, stats: &mut SweepStats) {
        let (mut unfolded, mut folded) = (
            std::mem::take(&mut self.walker.unfolded),
            std::mem::take(&mut self.folded),
        );
        unfolded.clear();
        folded.clear();
        self.bits_now_and_before()
            .for_each_change(store, |id, now| match now {
                true => unfolded.push(id),
                false => folded.push(id),
            });
        (self.walker.unfolded, self.folded) = (unfolded, folded);
        stats.unfolded = self.walker.unfolded.len() as u32;
        stats.folded = self.folded.len() as u32;
    }

    /// The cut now and as the run before found it.
    fn bits_now_and_before(&self) -> BitsNowAndBefore<'_> {
        BitsNowAndBefore {
            pages: &self.walker.pages,
            pages_before: &self.pages_before,
            now: &self.walker.marks,
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
            // In the cut where the node is not active it is on the boundary if its parent is
            // active; in the cut where it is, its children that are not active are.
            let (triangles, nodes, boundary_without, boundary_with, (without, with)) = if now {
                (
                    &mut changes.added,
                    &mut changes.unfolded,
                    &mut changes.left_boundary,
                    &mut changes.joined_boundary,
                    (bits.before, bits.now),
                )
            } else {
                (
                    &mut changes.removed,
                    &mut changes.folded,
                    &mut changes.joined_boundary,
                    &mut changes.left_boundary,
                    (bits.now, bits.before),
                )
            };
            *triangles += family.subtri_count;
            nodes.push(id);
            if is_set(without, store, family.parent) {
                boundary_without.push(id);
            }
            let children = family.first_child..family.first_child + family.child_count;
            boundary_with.extend(children_unset(with, store, children));
        });
        complete.then_some(changes)
    }

    /// Nodes active now that were not at the run before, ascending (parents first).
    pub fn unfolded(&self) -> &[u32] {
        &self.walker.unfolded
    }

    /// Nodes active at the run before that are not now, ascending.
    pub fn folded(&self) -> &[u32] {
        &self.folded
    }

    /// Nodes the last run's criteria asked to unfold whose children were not resident and
    /// checked, so they stayed folded.
    pub fn deferred(&self) -> &[u32] {
        &self.walker.deferred
    }

    /// Whether node `id` is active in the last run's cut.
    pub fn is_active(&self, store: &NodeStore, id: u32) -> bool {
        store
            .page_of(id)
            .is_some_and(|p| bit(&self.walker.marks, p, (id - store.page_first(p)) as usize))
    }

    /// The active nodes of the last run's cut, ascending.
    pub fn active_nodes(&self, store: &NodeStore) -> Vec<u32> {
        let mut nodes = Vec::new();
        for &p in &self.walker.pages {
            let first = store.page_first(p);
            for (w, &word) in self.walker.marks[p as usize].iter().enumerate() {
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

impl Helper {
    /// Sweeps the subtrees under `seeds` (nodes marked active whose children are still to
    /// test) page by page, then moves their marks to `done`.
    fn sweep_chunk(&mut self, pass: &Pass<'_>, seeds: &[u32]) {
        let walker = &mut self.walker;
        for &id in seeds {
            let p = pass.store.page_of(id).expect("a marked node exists");
            let page = pass
                .store
                .tested_page(p)
                .expect("a marked node is resident");
            walker.set(p, (id - page.first) as usize, page.hot.len(), id);
        }
        walker.sweep_queued(pass, &mut self.stats);
        // The chunk's pages are swept: its marks move out of the way of the next chunk's
        // (a page may hold nodes of both, and a sweep visits every mark of a page).
        for &p in &walker.pages {
            move_bits(&mut walker.marks[p as usize], &mut self.done[p as usize]);
            self.done_pages.push(p);
        }
        walker.pages.clear();
    }
}

impl Walker {
    /// Gives the per-page tables a row for every one of `page_count` pages.
    fn fit(&mut self, page_count: usize) {
        if self.marks.len() < page_count {
            self.marks.resize_with(page_count, Vec::new);
            self.queued.resize(page_count.div_ceil(64), 0);
        }
    }

    /// Clears every mark.
    fn clear_marks(&mut self) {
        for &p in &self.pages {
            self.marks[p as usize].fill(0);
        }
        self.pages.clear();
    }

    /// Sweeps the queued pages in index order, and those their nodes queue.
    fn sweep_queued(&mut self, pass: &Pass<'_>, stats: &mut SweepStats) {
        let first_new = self.pages.len();
        while let Some(Reverse(p)) = self.queue.pop() {
            self.pages.push(p);
            let page = pass
                .store
                .tested_page(p)
                .expect("a page holding an active node is resident");
            self.sweep_page(pass, p, page, stats);
        }
        for &p in &self.pages[first_new..] {
            self.queued[p as usize / 64] &= !(1 << (p % 64));
        }
    }

    /// Tests the children of page `p`'s marked nodes, in id order: children in this page
    /// come later in it, so re-reading each word picks them up.
    fn sweep_page<'a>(
        &mut self,
        pass: &Pass<'a>,
        p: u32,
        page: TestedPage<'a>,
        stats: &mut SweepStats,
    ) {
        let words = self.marks[p as usize].len();
        let mut cursor = Cursor::at(p, page);
        for w in 0..words {
            let mut done = 0u64;
            loop {
                let pending = self.marks[p as usize][w] & !done;
                if pending == 0 {
                    break;
                }
                let b = pending.trailing_zeros();
                done |= 1 << b;
                let hot = &page.hot[w * 64 + b as usize];
                self.visit(pass, hot, &mut cursor, stats);
            }
        }
    }

    /// [`Walker::visit`] for marked node `id`, looked up by id (walks by node).
    fn visit_node(&mut self, pass: &Pass<'_>, id: u32, stats: &mut SweepStats) {
        let p = pass.store.page_of(id).expect("a marked node exists");
        let page = pass
            .store
            .tested_page(p)
            .expect("a marked node is resident");
        let hot = &page.hot[(id - page.first) as usize];
        self.visit(pass, hot, &mut Cursor::at(p, page), stats);
    }

    /// Tests the children of the marked node of record `hot` (unless its group bound says
    /// none can unfold) and marks those that unfold.
    #[inline]
    fn visit<'a>(
        &mut self,
        pass: &Pass<'a>,
        hot: &Hot,
        cursor: &mut Cursor<'a>,
        stats: &mut SweepStats,
    ) {
        let Pass {
            store,
            before,
            judge,
            t,
            tight,
        } = *pass;
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
            let keep = bit(before, cursor.index, local);
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

    /// Marks entry `local` of page `p` (of `len` nodes), node `id`, active, and queues what
    /// visits it: its page, or walking by node the node itself.
    #[inline]
    fn set(&mut self, p: u32, local: usize, len: usize, id: u32) {
        let bits = &mut self.marks[p as usize];
        if bits.is_empty() {
            bits.resize(len.div_ceil(64), 0);
        }
        let word = &mut bits[local / 64];
        let fresh = *word & (1 << (local % 64)) == 0;
        *word |= 1 << (local % 64);
        match self.order {
            Order::Nodes { list } => {
                if fresh {
                    if list {
                        self.unfolded.push(id);
                    }
                    self.nodes_queued.push(Reverse(id));
                    self.pages.push(p);
                }
            }
            Order::Pages => {
                let queued = &mut self.queued[p as usize / 64];
                if *queued & (1 << (p % 64)) == 0 {
                    *queued |= 1 << (p % 64);
                    self.queue.push(Reverse(p));
                }
            }
        }
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

/// What every step of a run or a resume reads: the store, the cut the run before found, the
/// view's criteria and the threshold.
#[derive(Clone, Copy)]
struct Pass<'a> {
    store: &'a NodeStore,
    before: &'a [Vec<u64>],
    judge: &'a Judge,
    t: f32,
    /// `judge.tightest(t)`, the group bounds' threshold.
    tight: f32,
}

impl<'a> Pass<'a> {
    fn new(store: &'a NodeStore, before: &'a [Vec<u64>], judge: &'a Judge, t: f32) -> Pass<'a> {
        Pass {
            store,
            before,
            judge,
            t,
            tight: judge.tightest(t),
        }
    }
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

impl<'a> Cursor<'a> {
    /// A cursor at page `index`, `page`.
    fn at(index: u32, page: TestedPage<'a>) -> Cursor<'a> {
        Cursor {
            page,
            index,
            grandchildren: None,
        }
    }
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

/// Sets in `into` every bit set in `from`, and clears `from` (keeping its length).
fn move_bits(from: &mut [u64], into: &mut Vec<u64>) {
    if into.len() < from.len() {
        into.resize(from.len(), 0);
    }
    for (word, bits) in into.iter_mut().zip(from.iter_mut()) {
        *word |= std::mem::take(bits);
    }
}

/// Bit `local` of page `p` in `pages` (false for a page without bits).
#[inline]
fn bit(pages: &[Vec<u64>], p: u32, local: usize) -> bool {
    pages
        .get(p as usize)
        .and_then(|bits| bits.get(local / 64))
        .is_some_and(|word| word & (1 << (local % 64)) != 0)
}
