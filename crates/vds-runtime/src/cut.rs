//! The cut through the vertex tree and its two local operations, fold and unfold
//! (Luebke & Erikson 1997 §2.3).
//!
//! Every node is *active* (unfolded: its children are in the cut), *boundary* (folded with an
//! active parent, or the folded root: its proxy is a vertex of the current mesh) or
//! *inactive* (below the boundary). A triangle is active exactly when the node it is a subtri
//! of is active, and its current corners are the boundary nodes above its three original
//! vertices.
//!
//! ## The active triangle list
//! Active triangles live in *slots* of one array with a free list: a fold frees its subtris'
//! slots, an unfold fills free slots first, and a triangle keeps its slot while it is active.
//! A renderer mirrors the array on the GPU and rewrites only the slots a frame touched (the
//! paper's own suggested improvement over its linked list).
//!
//! ## Keeping corners current
//! Two strategies, chosen at construction ([`CornerTracking`]):
//! - **Incidence lists** (the paper's reltris, maintained at run time instead of stored per
//!   node): every boundary node heads an intrusive doubly-linked list of the active triangle
//!   corners it is the proxy of. Folding a node removes its subtris and relinks its
//!   children's lists to itself, rewriting those corners; unfolding splits its list among its
//!   children by the leaf-range test. Work is proportional to the triangles that change.
//! - **Lazy evaluation** (§4.5): no lists; after the cut changes, every active corner is
//!   checked and, if its node is no longer on the boundary, re-resolved by walking up (it was
//!   folded away) or down (it was unfolded) along its original vertex's path. Work is
//!   proportional to the active triangles, every frame.
//!
//! - **Ranks** (no per-triangle state): an active triangle is a subtri of an active node, and
//!   a corner's current node is the boundary node whose leaf-rank interval holds the corner's
//!   original leaf rank. Fold and unfold change labels alone, the cut reports its changes per
//!   node (the nodes that unfolded, folded and joined the boundary: what a renderer needs to
//!   edit a draw list of subtri ranges and a rank → vertex map with range fills), and corners
//!   are resolved only when the cut is read. Work per frame is proportional to the nodes that
//!   change, whatever their triangles. There are no slots; `vds_render::RankMirror` draws
//!   the cut from its node changes.
//!
//! `vds-bench cut` measures them along the same camera paths.
//!
//! ## Repeats
//! Active triangles with the same three current corners in the same winding are drawn and
//! counted once (`repeats.rs`): the others stay in their slots, marked hidden, and read
//! as free slots. Only subtris of one node can repeat, and only those its unfold finds in one
//! group; a fold or unfold that moves a grouped triangle's corner has its group compared
//! again. With incidence lists that happens at once, and a triangle budget counts what is
//! drawn (an unfold that would split repeats past the budget is undone). Lazy tracking sees
//! corners only when the cut is read, so it compares groups then, and its budget counts every
//! active triangle (never fewer than are drawn). Rank tracking finds groups cheaply (only
//! subtris sharing their corners inside the node need their outside corners), watches the
//! ranks of their corners, and compares a group again when a node joins the boundary over
//! one, once a frame; its budget too counts every active triangle.

use vds_format::VdtError;

use crate::journal::{Journal, JournalEntry};
use crate::repeats::{Repeats, groups_of, hidden_members, key};
use crate::reuse::Reuse;
use crate::store::{Hot, Node, NodeStore, Shape};

/// "None" for slot, list and node links.
pub const NIL: u32 = u32::MAX;

/// A node's label in the cut.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum NodeState {
    /// Below the boundary.
    Inactive = 0,
    /// On the boundary: folded, with an active parent (or the folded root).
    Boundary = 1,
    /// Above the boundary: unfolded.
    Active = 2,
}

/// How active triangles' corners are kept up to date (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum CornerTracking {
    /// Per-boundary-node lists of the corners it holds, updated by fold and unfold.
    #[default]
    Incidence,
    /// No lists; every active corner is re-checked when the cut is read.
    Lazy,
    /// No per-triangle state at all: corners are found from leaf ranks when the cut is read,
    /// and changes are reported per node.
    Ranks,
}

/// One active triangle.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct ActiveTriangle {
    /// The triangle's index in the file.
    pub triangle: u32,
    /// Its current corners: boundary node ids, whose proxies are the positions to draw.
    pub corners: [u32; 3],
}

/// One slot of the active triangle array, with its three incidence-list links: everything
/// fold and unfold touch for one triangle lies in one cache line.
#[derive(Debug, Clone, Copy)]
#[repr(C, align(64))]
struct Slot {
    /// The triangle held, or [`NIL`] for a free slot.
    triangle: u32,
    /// The node it is a subtri of.
    owner: u32,
    /// Leaf ranks of its original corners.
    leaves: [u32; 3],
    /// Current corners (boundary node ids).
    corners: [u32; 3],
    /// Next entry of each corner's incidence list (entries are `slot * 3 + corner`).
    next: [u32; 3],
    /// Previous entry of each corner's incidence list.
    prev: [u32; 3],
    /// The journal epoch in which this slot was last recorded.
    touched: u32,
    /// Hidden as a repeat of a triangle with a smaller index ([`crate::repeats`]).
    hidden: bool,
    /// In a group of its node's subtris that can repeat ([`crate::repeats`]).
    grouped: bool,
}

const FREE_SLOT: Slot = Slot {
    triangle: NIL,
    owner: NIL,
    leaves: [NIL; 3],
    corners: [NIL; 3],
    next: [NIL; 3],
    prev: [NIL; 3],
    touched: 0,
    hidden: false,
    grouped: false,
};

const _: () = assert!(size_of::<Slot>() == 64);

impl Slot {
    /// What a renderer draws from this slot: the triangle and its corners, or nothing
    /// ([`NIL`]) for a free slot or a hidden repeat.
    #[inline]
    fn drawn(&self) -> (u32, [u32; 3]) {
        if self.hidden {
            (NIL, [NIL; 3])
        } else {
            (self.triangle, self.corners)
        }
    }
}

/// What changed in the active triangle list since the last [`Cut::take_changes`].
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Changes {
    /// Slots whose contents differ from what they held before (ascending): a renderer
    /// rewrites exactly these, with the triangle they now hold or a degenerate one if free.
    pub dirty_slots: Vec<u32>,
    /// Triangles that became active.
    pub added: u32,
    /// Triangles that stopped being active.
    pub removed: u32,
    /// Triangles active before and after whose corners changed (not counted with
    /// [`CornerTracking::Ranks`], which keeps no per-triangle state).
    pub changed: u32,
    /// With [`CornerTracking::Ranks`]: the nodes active now that were not (their subtris
    /// became active). The node lists are in the order the nodes first changed (after an
    /// eviction, in no particular order).
    pub unfolded: Vec<u32>,
    /// With [`CornerTracking::Ranks`]: the nodes active before that are not now (their subtris
    /// stopped being active).
    pub folded: Vec<u32>,
    /// With [`CornerTracking::Ranks`]: active triangles hidden now as repeats that were drawn
    /// (or not active) at the last report, each with the node it is a subtri of.
    pub hidden: Vec<(u32, u32)>,
    /// With [`CornerTracking::Ranks`]: active triangles drawn now that were hidden as repeats,
    /// each with the node it is a subtri of.
    pub shown: Vec<(u32, u32)>,
    /// With [`CornerTracking::Ranks`]: the nodes on the boundary now that were not.
    /// Boundary nodes' leaf ranges are disjoint, and every leaf rank whose current node
    /// changed lies in one of theirs: a rank → node map is kept current by filling each of
    /// their ranges with the node.
    pub joined_boundary: Vec<u32>,
    /// With [`CornerTracking::Ranks`]: the nodes on the boundary before that are not now
    /// (their vertex is no longer in the mesh).
    pub left_boundary: Vec<u32>,
}

/// One active node as the per-frame traversal reads it: a copy of its [`Hot`] record and its
/// count of active children, kept in a dense array so the traversal streams through memory.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ActiveEntry {
    /// The node's proxy, error radius and group bound.
    pub hot: Hot,
    /// The node id.
    pub id: u32,
    /// How many of its children are active (it may fold when none is).
    pub active_children: u16,
    /// What the threshold pass's tests found for it and its unfolds and folds have yet to
    /// act on ([`crate::adjust`]); zero outside a pass.
    pub(crate) pending: u16,
    /// Its boundary children's last threshold test, while the camera has moved too little to
    /// change it ([`crate::reuse`]); cleared whenever a child folds or unfolds.
    pub(crate) reuse: Reuse,
}

const _: () = assert!(size_of::<ActiveEntry>() == 56);

/// The cut: node labels, the boundary path and the active triangles.
pub struct Cut {
    pub(crate) store: NodeStore,
    tracking: CornerTracking,
    /// The active nodes, densely: the per-frame traversal streams through this array (and
    /// `active_shapes` beside it) instead of chasing node ids across the store.
    active_list: Vec<ActiveEntry>,
    active_shapes: Vec<Shape>,
    active_node_count: u32,
    boundary_count: u32,
    slots: Vec<Slot>,
    free_slots: Vec<u32>,
    active_triangle_count: u32,
    /// Journal of slots touched since the last `take_changes`: their contents before.
    journal: Vec<(u32, u32, [u32; 3])>,
    /// One bit per slot, set for the dirty ones while changes are collected, so they come out
    /// in ascending order without a sort; all clear between calls.
    dirty_bits: Vec<u64>,
    epoch: u32,
    lazy_dirty: bool,
    /// Scratch of `take_changes`: triangles in touched slots now, by slot, and before.
    now_in_slot: rustc_hash::FxHashMap<u32, u32>,
    before: rustc_hash::FxHashSet<u32>,
    /// Scratch of `unfold_node`: the children's first leaf ranks, and the subtris' corners.
    child_starts: Vec<u32>,
    subtri_scratch: Vec<[u32; 3]>,
    /// The slot array's length at the last `take_changes`.
    drawn_len: u32,
    /// The groups of subtris that can repeat, and how many triangles are hidden.
    repeats: Repeats,
    /// Scratch of `unfold_node`: its subtris' corners in its own cut, for grouping.
    own_corners: Vec<([u32; 3], u32)>,
    /// Scratch of rank tracking's grouping: the subtris that share their inside corners.
    candidates: Vec<([u32; 3], u32)>,
    /// Scratch of rank tracking's grouping: the first leaf ranks of the node's siblings.
    sibling_starts: Vec<u32>,
    /// Rank tracking: the nodes whose state changed since the last `take_changes`, with
    /// their states then and now.
    node_journal: Journal,
    /// Rank tracking: every leaf rank that is a corner of a grouped subtri, with the node
    /// owning the group: a node joining the boundary over such a rank may change what the
    /// group hides.
    watched: std::collections::BTreeSet<(u32, u32)>,
    /// Rank tracking: the active triangles hidden as repeats.
    hidden_set: rustc_hash::FxHashSet<u32>,
    /// Rank tracking: the triangles hidden or shown since the last report, with whether each
    /// was hidden then and the node owning it.
    hidden_was: rustc_hash::FxHashMap<u32, (bool, u32)>,
    /// Still passes of the threshold traversal ([`crate::adjust`]: the camera where it was at
    /// the last adjust): the active nodes the next still pass must visit, those that did not
    /// settle at the last one and those the cut created or cleared the record of since
    /// (duplicates allowed). `None` while no still pass has run since the camera last moved or
    /// the records were cleared: the next still pass then visits every entry.
    revisit: Option<Vec<u32>>,
    /// The threshold pass ([`crate::adjust`]): indices to which a fold moved an entry with
    /// something still pending.
    moved_pending: Vec<u32>,
    /// Folds and unfolds made so far ([`Cut::operations`]).
    operations: u64,
}

impl Cut {
    /// The coarsest cut over `store`: the root alone, folded.
    pub fn new(mut store: NodeStore, tracking: CornerTracking) -> Cut {
        if tracking == CornerTracking::Ranks {
            store.drop_triangle_slots();
        }
        Cut {
            store,
            tracking,
            active_list: Vec::new(),
            active_shapes: Vec::new(),
            active_node_count: 0,
            boundary_count: 1,
            slots: Vec::new(),
            free_slots: Vec::new(),
            active_triangle_count: 0,
            journal: Vec::new(),
            dirty_bits: Vec::new(),
            epoch: 1,
            lazy_dirty: false,
            now_in_slot: Default::default(),
            before: Default::default(),
            child_starts: Vec::new(),
            subtri_scratch: Vec::new(),
            drawn_len: 0,
            repeats: Repeats::default(),
            own_corners: Vec::new(),
            candidates: Vec::new(),
            sibling_starts: Vec::new(),
            node_journal: Journal::default(),
            watched: Default::default(),
            hidden_set: Default::default(),
            hidden_was: Default::default(),
            revisit: None,
            moved_pending: Vec::new(),
            operations: 0,
        }
    }

    /// How many folds and unfolds this cut has made: whoever keeps a copy of the cut (the
    /// sweep's bits) can tell whether anything else changed it since.
    pub fn operations(&self) -> u64 {
        self.operations
    }

    /// The node store, for taking the log of loaded pages ([`NodeStore::take_loaded`]).
    pub fn store_mut(&mut self) -> &mut NodeStore {
        &mut self.store
    }

    /// How corners are tracked.
    pub fn tracking(&self) -> CornerTracking {
        self.tracking
    }

    /// The node store (node attributes, triangle records, residency).
    pub fn store(&self) -> &NodeStore {
        &self.store
    }

    /// Node `id`'s attributes; the node must be on or above the boundary, or a child of a
    /// boundary node's... in short, loaded: every node the cut has reached is.
    #[inline]
    pub fn node(&self, id: u32) -> Node {
        self.store.node(id)
    }

    /// Node `id`'s label.
    #[inline]
    pub fn state(&self, id: u32) -> NodeState {
        self.store.state(id)
    }

    /// The boundary nodes (the current vertices), in ascending id order. Computed from the
    /// active nodes' children.
    pub fn boundary(&self) -> Vec<u32> {
        let mut boundary = Vec::with_capacity(self.boundary_count as usize);
        if self.store.state(0) == NodeState::Boundary {
            boundary.push(0);
        }
        for entry in &self.active_list {
            let h = &entry.hot;
            boundary.extend(
                (h.first_child..h.first_child + h.child_count)
                    .filter(|&c| self.store.state(c) == NodeState::Boundary),
            );
        }
        boundary.sort_unstable();
        boundary
    }

    /// Number of boundary nodes (vertices of the current mesh).
    pub fn boundary_count(&self) -> u32 {
        self.boundary_count
    }

    /// The active nodes, densely, in no particular order. Folds remove entries by moving the
    /// last one into their place; unfolds append.
    #[inline]
    pub fn active_entries(&self) -> &[ActiveEntry] {
        &self.active_list
    }

    /// Hints that the boundary children of the active node at `index` of
    /// [`Cut::active_entries`] will be tested soon: their labels and test data.
    #[inline]
    pub(crate) fn prefetch_children(&self, index: usize) {
        if let Some(entry) = self.active_list.get(index) {
            let (first, count) = (entry.hot.first_child, entry.hot.child_count);
            self.store.prefetch_tested(first, count);
        }
    }

    /// Hints that the active entry at `index` and its shape will be read soon.
    #[inline]
    pub(crate) fn prefetch_entry(&self, index: usize) {
        crate::prefetch::prefetch_range(&self.active_list, index..index + 1);
        crate::prefetch::prefetch_range(&self.active_shapes, index..index + 1);
    }

    /// Records that the boundary children of the active node at `index` of
    /// [`Cut::active_entries`] passed the threshold test as `reuse` says.
    #[inline]
    pub(crate) fn set_reuse(&mut self, index: usize, reuse: Reuse) {
        if let Some(entry) = self.active_list.get_mut(index) {
            entry.reuse = reuse;
        }
    }

    /// Forgets every recorded test (a new generation of [`crate::reuse`]).
    pub(crate) fn clear_reuse(&mut self) {
        for entry in &mut self.active_list {
            entry.reuse = Reuse::NONE;
        }
        self.revisit = None;
    }

    /// Starts a still pass: the nodes it must visit (`None`: every entry), and from now on
    /// the list for the next one, which [`Cut::revisit`] and the cut's own changes fill.
    pub(crate) fn begin_still_pass(&mut self) -> Option<Vec<u32>> {
        self.revisit.replace(Vec::new())
    }

    /// Ends the lists of still passes: the camera moved, so the next still pass visits every
    /// entry.
    pub(crate) fn forget_revisits(&mut self) {
        self.revisit = None;
    }

    /// Marks active node `id` for a visit by the next still pass (while one is listing).
    #[inline]
    pub(crate) fn revisit(&mut self, id: u32) {
        if let Some(list) = &mut self.revisit {
            list.push(id);
        }
    }

    /// The index in [`Cut::active_entries`] of node `id`, if it is active.
    pub(crate) fn active_index(&self, id: u32) -> Option<usize> {
        let label = self.store.label(id);
        (label.state == NodeState::Active).then_some(label.active_index as usize)
    }

    /// The active entries to change in place, their shapes beside them and the store, for the
    /// threshold pass's tests (which set each entry's record and what is pending for it).
    #[inline]
    pub(crate) fn active_entries_mut(&mut self) -> (&mut [ActiveEntry], &[Shape], &NodeStore) {
        (&mut self.active_list, &self.active_shapes, &self.store)
    }

    /// The indices to which folds moved entries with something pending, since the last call.
    #[inline]
    pub(crate) fn take_moved_pending(&mut self, into: &mut Vec<u32>) {
        into.append(&mut self.moved_pending);
    }

    /// What is pending for the active entry at `index` ([`ActiveEntry`]), cleared.
    #[inline]
    pub(crate) fn take_pending(&mut self, index: usize) -> u16 {
        self.active_list
            .get_mut(index)
            .map_or(0, |entry| std::mem::take(&mut entry.pending))
    }

    /// Number of active children of node `id`.
    #[inline]
    pub fn active_children(&self, id: u32) -> u8 {
        self.store.label(id).active_children
    }

    /// Number of active (unfolded) nodes.
    pub fn active_node_count(&self) -> u32 {
        self.active_node_count
    }

    /// Number of active triangles drawn: each class of same-winding repeats once (with
    /// lazy tracking, as compared when the cut was last read).
    pub fn active_triangle_count(&self) -> u32 {
        self.active_triangle_count - self.repeats.hidden
    }

    /// The triangle count a budget holds to: what is drawn, or, with lazy tracking (which
    /// compares repeats only when the cut is read), every active triangle.
    pub(crate) fn counted_triangles(&self) -> u32 {
        match self.tracking {
            CornerTracking::Incidence => self.active_triangle_count(),
            CornerTracking::Lazy | CornerTracking::Ranks => self.active_triangle_count,
        }
    }

    /// Number of active triangles, hidden repeats included.
    pub fn active_triangle_count_with_repeats(&self) -> u32 {
        self.active_triangle_count
    }

    /// Number of slots, free ones included: the length of a renderer's triangle buffer.
    pub fn slot_count(&self) -> u32 {
        self.slots.len() as u32
    }

    /// The triangle in slot `index`, or `None` for a free slot.
    pub fn slot(&mut self, index: u32) -> Option<ActiveTriangle> {
        self.refresh_lazy_corners();
        self.peek_slot(index)
    }

    fn peek_slot(&self, index: u32) -> Option<ActiveTriangle> {
        let (triangle, corners) = self.slots.get(index as usize)?.drawn();
        (triangle != NIL).then_some(ActiveTriangle { triangle, corners })
    }

    /// Every active triangle drawn (each class of repeats once), by slot (with rank
    /// tracking, which has no slots, by triangle index).
    pub fn active_triangles(&mut self) -> Vec<ActiveTriangle> {
        if self.tracking == CornerTracking::Ranks {
            return self.triangles_from_ranks();
        }
        self.refresh_lazy_corners();
        (0..self.slot_count())
            .filter_map(|s| self.peek_slot(s))
            .collect()
    }

    /// With rank tracking: the active triangles hidden as repeats, each with the node it is a
    /// subtri of (for a renderer that starts from the current cut). Exact right after
    /// [`Cut::take_changes`], which compares the groups whose corners moved; a fold since has
    /// dropped its own. Empty with the other trackings.
    pub fn hidden_repeats(&self) -> Vec<(u32, u32)> {
        let mut hidden = Vec::with_capacity(self.hidden_set.len());
        for (&owner, groups) in &self.repeats.groups {
            hidden.extend(
                groups
                    .iter()
                    .flatten()
                    .filter(|t| self.hidden_set.contains(t))
                    .map(|&t| (t, owner)),
            );
        }
        hidden.sort_unstable();
        hidden
    }

    /// The boundary node above original vertex `rank`: the node whose proxy stands in for it.
    pub fn current_proxy_node(&self, rank: u32) -> u32 {
        self.store
            .descend(0, rank, |id| self.store.state(id) == NodeState::Active)
    }

    /// True when `id` may be unfolded: on the boundary and not a leaf.
    pub fn can_unfold(&self, id: u32) -> bool {
        let label = self.store.label(id);
        label.state == NodeState::Boundary && self.store.hot(id).child_count > 0
    }

    /// True when `id` may be folded: active with every child on the boundary.
    pub fn can_fold(&self, id: u32) -> bool {
        let label = self.store.label(id);
        label.state == NodeState::Active && label.active_children == 0
    }

    /// Unfolds boundary node `id`: its children join the boundary, its subtris become
    /// active and its corners move to the children. Loads the children's page first; on a
    /// load error, or when the page does not fit in the memory budget, nothing changes.
    ///
    /// # Panics
    /// If `id` cannot unfold ([`Cut::can_unfold`]).
    pub fn unfold_node(&mut self, id: u32) -> Result<(), VdtError> {
        assert!(self.can_unfold(id), "node {id} cannot unfold");
        self.store.load_children(id).map_err(|e| match e {
            crate::store::LoadError::File(e) => e,
            crate::store::LoadError::OverBudget => VdtError::invalid(
                format!("node {id}"),
                "its children's pages do not fit in the memory budget",
            ),
        })?;
        self.unfold_available(id);
        Ok(())
    }

    /// [`Cut::unfold_node`] for a node that can unfold and whose children
    /// [`Cut::children_available`] has just found loaded and checked: the adjuster's unfold,
    /// without asking the store again.
    pub(crate) fn unfold_available(&mut self, id: u32) {
        debug_assert!(self.can_unfold(id), "node {id} cannot unfold");
        debug_assert!(self.store.children_resident(id));
        let node = self.store.node(id);
        // The children's and the parent's labels are written below, and grouping the subtris
        // reads their corners: misses at random, started together so that they overlap.
        self.store
            .prefetch_labels(node.first_child, u32::from(node.child_count));
        self.store.prefetch_labels(node.parent, 1);
        if self.tracking == CornerTracking::Ranks && node.subtri_count > 1 {
            self.store.prefetch_subtri_corners(id);
        }
        self.operations += 1;
        self.set_state(id, NodeState::Active, node.subtri_count);
        self.set_children_state(&node, NodeState::Boundary);
        self.boundary_count += u32::from(node.child_count) - 1;
        self.count_active_child(node.parent, 1);
        self.active_node_count += 1;
        if self.tracking == CornerTracking::Ranks {
            self.active_triangle_count += node.subtri_count;
            self.note_ranks_moved(node.leaf_begin, node.leaf_end);
            if node.subtri_count > 1
                && !self.store.is_unrepeated(id)
                && !self.group_by_ranks(id, &node)
            {
                self.store.mark_unrepeated(id);
            }
            return;
        }
        // The children's first leaf ranks, once: every corner that moves down, and every
        // subtri corner under `id`, picks its child from them without a look-up per corner.
        let mut starts = std::mem::take(&mut self.child_starts);
        starts.clear();
        starts.extend(node.children().map(|c| self.store.node(c).leaf_begin));
        let child_of =
            |rank: u32| node.first_child + starts.partition_point(|&b| b <= rank) as u32 - 1;
        if self.tracking == CornerTracking::Incidence {
            let mut entry = std::mem::replace(&mut self.store.label_mut(id).head, NIL);
            while entry != NIL {
                let following = self.next_of(entry);
                let (slot, k) = (entry / 3, (entry % 3) as usize);
                let child = child_of(self.slots[slot as usize].leaves[k]);
                self.touch(slot);
                self.note_moved(slot);
                self.slots[slot as usize].corners[k] = child;
                self.link(child, entry);
                entry = following;
            }
        } else {
            self.lazy_dirty = true;
        }
        let mut subtris = std::mem::take(&mut self.subtri_scratch);
        subtris.clear();
        subtris.extend_from_slice(self.store.subtri_corners(id));
        // Subtris that can repeat are those with equal corners in `id`'s own cut
        // ([`crate::repeats`]): with only one, there is nothing to group.
        let grouping = subtris.len() > 1;
        let mut own = std::mem::take(&mut self.own_corners);
        own.clear();
        for (t, &leaves) in (node.subtri_begin..).zip(&subtris) {
            // A corner under `id` is on one of its children, which are all on the boundary
            // now; the others are found from `id` upwards. In `id`'s own cut, a corner outside
            // it is on the child, holding it, of the deepest ancestor that supports it: the
            // first step of the way down.
            let (mut corners, mut own_corners) = ([NIL; 3], [NIL; 3]);
            for k in 0..3 {
                let rank = leaves[k];
                (own_corners[k], corners[k]) = if node.supports_rank(rank) {
                    let child = child_of(rank);
                    (child, child)
                } else {
                    self.boundary_node_of(rank, id)
                };
            }
            self.insert_triangle(id, t, leaves, corners);
            if grouping {
                own.push((own_corners, t));
            }
        }
        if grouping {
            let groups = groups_of(&mut own);
            if !groups.is_empty() {
                for &t in groups.iter().flatten() {
                    let slot = self.store.triangle_slot(id, t);
                    self.slots[slot as usize].grouped = true;
                }
                self.repeats.groups.insert(id, groups);
                self.repeats.dirty.push(id);
            }
        }
        self.own_corners = own;
        self.child_starts = starts;
        self.subtri_scratch = subtris;
        self.settle_repeats();
    }

    /// Folds active node `id`: its subtris are removed and every corner held by a child moves
    /// to `id`'s proxy. Returns `false` without changing anything when `prevent_flips` is set
    /// and the fold would turn a surviving triangle's normal around (incidence tracking only:
    /// lazy tracking cannot see the surviving triangles).
    ///
    /// # Panics
    /// If `id` cannot fold ([`Cut::can_fold`]).
    pub fn fold_node(&mut self, id: u32, prevent_flips: bool) -> bool {
        assert!(self.can_fold(id), "node {id} cannot fold");
        if prevent_flips && self.fold_would_flip(id) {
            return false;
        }
        self.operations += 1;
        let node = self.store.node(id);
        // The children's and the parent's labels are written below: their misses overlap.
        self.store
            .prefetch_labels(node.first_child, u32::from(node.child_count));
        self.store.prefetch_labels(node.parent, 1);
        if self.tracking == CornerTracking::Ranks {
            self.active_triangle_count -= node.subtri_count;
            self.ungroup_by_ranks(id);
            self.note_ranks_moved(node.leaf_begin, node.leaf_end);
        } else {
            for t in node.subtri_begin..node.subtri_begin + node.subtri_count {
                let slot = self.store.triangle_slot(id, t);
                if slot != NIL {
                    self.remove_slot(slot);
                }
            }
        }
        if self.tracking == CornerTracking::Incidence {
            for c in node.children() {
                let mut entry = std::mem::replace(&mut self.store.label_mut(c).head, NIL);
                while entry != NIL {
                    let following = self.next_of(entry);
                    let (slot, k) = (entry / 3, (entry % 3) as usize);
                    self.touch(slot);
                    self.note_moved(slot);
                    self.slots[slot as usize].corners[k] = id;
                    self.link(id, entry);
                    entry = following;
                }
            }
        }
        self.set_children_state(&node, NodeState::Inactive);
        self.boundary_count -= u32::from(node.child_count) - 1;
        if self.tracking == CornerTracking::Lazy {
            self.lazy_dirty = true;
        }
        self.set_state(id, NodeState::Boundary, node.subtri_count);
        self.count_active_child(node.parent, -1);
        self.active_node_count -= 1;
        self.repeats.groups.remove(&id);
        self.settle_repeats();
        true
    }

    /// Whether boundary node `id`'s children are loaded, so it can unfold without reading a
    /// page ([`NodeStore::children_available`]: with synchronous loading this loads them),
    /// and whether the cut's own arrays have room for its unfold within the memory budget
    /// (they grow in steps, each asked of the store first; a step that does not fit leaves
    /// the node folded, as a page that does not fit does).
    pub fn children_available(&mut self, id: u32) -> Result<bool, VdtError> {
        Ok(self.store.children_available(id)? && self.reserve_for_unfold(id))
    }

    /// Makes room in the slot array and the active list for unfolding `id`, within the
    /// memory budget; false when the budget cannot give it. (The part of
    /// [`Cut::children_available`] a caller needs whose children are known to be resident
    /// and checked.)
    pub(crate) fn reserve_for_unfold(&mut self, id: u32) -> bool {
        let subtris = match self.tracking {
            CornerTracking::Ranks => 0,
            _ => self.store.subtris(id).len(),
        };
        let needed_slots = self.slots.len() + subtris.saturating_sub(self.free_slots.len());
        let slot_growth = grown_capacity(self.slots.capacity(), needed_slots);
        let entry_growth = grown_capacity(self.active_list.capacity(), self.active_list.len() + 1);
        let bytes = slot_growth * size_of::<Slot>()
            + entry_growth * (size_of::<ActiveEntry>() + size_of::<Shape>());
        if bytes == 0 {
            return true;
        }
        if !self.store.make_room_for_cut(bytes as u64, id) {
            return false;
        }
        // `reserve_exact` counts from the length, the growth from the capacity.
        let (slots_to, entries_to) = (
            self.slots.capacity() + slot_growth,
            self.active_list.capacity() + entry_growth,
        );
        self.slots.reserve_exact(slots_to - self.slots.len());
        self.active_list
            .reserve_exact(entries_to - self.active_list.len());
        self.active_shapes
            .reserve_exact(entries_to - self.active_shapes.len());
        self.store.set_cut_bytes(self.own_bytes());
        true
    }

    /// Whether `id`'s children's pages are resident ([`NodeStore::children_resident`]; always
    /// with synchronous loading). Reads nothing.
    pub fn children_resident(&self, id: u32) -> bool {
        self.store.children_resident(id)
    }

    /// Asks for `id`'s children's pages ([`NodeStore::request_children`]); false when they
    /// cannot arrive.
    pub fn request_children(&mut self, id: u32, priority: f32) -> bool {
        self.store.request_children(id, priority)
    }

    /// Unfolds every node: the cut becomes the original mesh.
    pub fn unfold_all(&mut self) -> Result<(), VdtError> {
        let mut stack = self.boundary();
        while let Some(id) = stack.pop() {
            if self.can_unfold(id) {
                self.unfold_node(id)?;
                stack.extend(self.store.node(id).children());
            }
        }
        Ok(())
    }

    /// Folds every node: the cut becomes the root alone.
    pub fn fold_all(&mut self) {
        let mut stack: Vec<u32> = self
            .boundary()
            .iter()
            .map(|&b| self.store.node(b).parent)
            .filter(|&p| p != NIL)
            .collect();
        while let Some(id) = stack.pop() {
            if self.can_fold(id) {
                self.fold_node(id, false);
                let parent = self.store.node(id).parent;
                if parent != NIL {
                    stack.push(parent);
                }
            }
        }
    }

    /// The changes to the active triangle list since the last call, and a fresh journal.
    pub fn take_changes(&mut self) -> Changes {
        if self.tracking == CornerTracking::Ranks {
            return self.take_node_changes();
        }
        self.settle_repeats();
        // Compaction first: with lazy tracking, the groups of moved triangles are compared by
        // the refresh.
        self.compact_slots();
        self.refresh_lazy_corners();
        let mut changes = Changes::default();
        self.dirty_bits.resize(self.slots.len().div_ceil(64), 0);
        // A triangle active before the frame and after it sits in a touched slot now if it
        // sat in one before (leaving a slot or changing corners touches it, and so does
        // entering one), so the touched slots alone say what was added, removed and changed.
        self.now_in_slot.clear();
        self.before.clear();
        for &(slot, triangle, _) in &self.journal {
            let now = self.slots.get(slot as usize).map_or(NIL, |s| s.drawn().0);
            if now != NIL {
                self.now_in_slot.insert(now, slot);
            }
            if triangle != NIL {
                self.before.insert(triangle);
            }
        }
        for &(slot, triangle, corners) in &self.journal {
            if triangle != NIL {
                match self.now_in_slot.get(&triangle) {
                    None => changes.removed += 1,
                    Some(&now) if self.slots[now as usize].corners != corners => {
                        changes.changed += 1
                    }
                    _ => {}
                }
            }
            // A slot past the end was cut off by compaction: it is no longer drawn at all.
            let Some(now) = self.slots.get(slot as usize) else {
                continue;
            };
            let (now_triangle, now_corners) = now.drawn();
            if now_triangle != triangle || now_corners != corners {
                self.dirty_bits[slot as usize / 64] |= 1 << (slot % 64);
            }
            if now_triangle != NIL && !self.before.contains(&now_triangle) {
                changes.added += 1;
            }
        }
        // Slots past the array's length at the last call hold, in a renderer's mirror,
        // whatever was there before compaction cut the array short: each is rewritten.
        for slot in self.drawn_len.min(self.slots.len() as u32)..self.slots.len() as u32 {
            self.dirty_bits[slot as usize / 64] |= 1 << (slot % 64);
        }
        self.drawn_len = self.slots.len() as u32;
        for (word_index, word) in self.dirty_bits.iter_mut().enumerate() {
            let mut bits = std::mem::take(word);
            while bits != 0 {
                changes
                    .dirty_slots
                    .push(word_index as u32 * 64 + bits.trailing_zeros());
                bits &= bits - 1;
            }
        }
        let touched = self.journal.len();
        self.journal.clear();
        shrink_if_sparse(&mut self.journal, 2 * touched);
        shrink_if_sparse(&mut self.active_list, self.active_node_count as usize);
        shrink_if_sparse(&mut self.active_shapes, self.active_node_count as usize);
        shrink_if_sparse(&mut self.free_slots, 0);
        if self.now_in_slot.capacity() > 4 * touched.max(1024) {
            self.now_in_slot.shrink_to(2 * touched);
            self.before.shrink_to(2 * touched);
        }
        self.dirty_bits.shrink_to(self.slots.len().div_ceil(64));
        self.store.set_cut_bytes(self.own_bytes());
        self.epoch = self.epoch.wrapping_add(1);
        if self.epoch == 0 {
            for s in &mut self.slots {
                s.touched = 0;
            }
            self.epoch = 1;
        }
        changes
    }

    /// Bytes held by the cut's own arrays (by capacity; the hash sets by their entries and
    /// control bytes): what the memory budget counts beside the store's pages.
    pub fn own_bytes(&self) -> u64 {
        fn held<T>(v: &Vec<T>) -> usize {
            v.capacity() * size_of::<T>()
        }
        let hashed = self.repeats.bytes() as usize
            + self.now_in_slot.capacity() * (size_of::<(u32, u32)>() + 1)
            + self.before.capacity() * (size_of::<u32>() + 1)
            + self.hidden_set.capacity() * (size_of::<u32>() + 1)
            + self.hidden_was.capacity() * (size_of::<(u32, (bool, u32))>() + 1)
            // A B-tree's nodes hold 11 entries and are two thirds full on average, with
            // child links in the inner ones: 16 bytes an 8-byte entry covers it.
            + self.watched.len() * 16;
        (size_of::<Cut>()
            + held(&self.active_list)
            + held(&self.active_shapes)
            + held(&self.slots)
            + held(&self.free_slots)
            + held(&self.journal)
            + held(&self.dirty_bits)
            + self.node_journal.held_bytes()
            + self.revisit.as_ref().map_or(0, held)
            + hashed) as u64
    }

    /// Rank tracking's [`Cut::take_changes`]: the nodes whose label changed, by what they
    /// became, from the node journal.
    fn take_node_changes(&mut self) -> Changes {
        let mut changes = Changes::default();
        let evictions = self.store.memory().pages_evicted;
        let mut journal = self.node_journal.take(evictions);
        for &JournalEntry {
            id,
            before,
            now,
            subtris,
        } in &journal
        {
            if before == now {
                continue;
            }
            // Triangles added and removed, net: subtris of nodes active now and not at the
            // last report, and the reverse.
            if now == NodeState::Active {
                changes.added += subtris;
            } else if before == NodeState::Active {
                changes.removed += subtris;
            }
            match now {
                NodeState::Active => changes.unfolded.push(id),
                NodeState::Boundary => changes.joined_boundary.push(id),
                NodeState::Inactive => {}
            }
            match before {
                NodeState::Active => changes.folded.push(id),
                NodeState::Boundary => changes.left_boundary.push(id),
                NodeState::Inactive => {}
            }
        }
        self.settle_rank_repeats();
        for (t, (was, owner)) in std::mem::take(&mut self.hidden_was) {
            let now = self.hidden_set.contains(&t);
            let owner_active = self
                .store
                .label_if_resident_mut(owner)
                .is_some_and(|l| l.state == NodeState::Active);
            if now && !was {
                changes.hidden.push((t, owner));
            } else if !now && was && owner_active {
                changes.shown.push((t, owner));
            }
        }
        changes.hidden.sort_unstable();
        changes.shown.sort_unstable();
        let touched = journal.len();
        journal.clear();
        shrink_if_sparse(&mut journal, 2 * touched);
        self.node_journal.recycle(journal);
        shrink_if_sparse(&mut self.active_list, self.active_node_count as usize);
        shrink_if_sparse(&mut self.active_shapes, self.active_node_count as usize);
        self.store.set_cut_bytes(self.own_bytes());
        changes
    }

    /// Rank tracking: the current node of leaf rank `rank`, a corner of a subtri of active
    /// node `owner`: under the owner, down from its child holding the rank; outside it, down
    /// from the first ancestor holding the rank.
    fn current_corner(&self, rank: u32, owner: u32, owner_node: &Node) -> u32 {
        let is_active = |n: u32| self.store.state(n) == NodeState::Active;
        if owner_node.supports_rank(rank) {
            let child = self.store.child_supporting(owner, rank);
            self.store.descend(child, rank, is_active)
        } else {
            self.boundary_node_of(rank, owner).1
        }
    }

    /// Rank tracking: every active triangle drawn (the hidden repeats left out) with its
    /// current corners, in triangle order.
    fn triangles_from_ranks(&mut self) -> Vec<ActiveTriangle> {
        self.settle_rank_repeats();
        let mut drawn = Vec::with_capacity(self.active_triangle_count() as usize);
        for entry in &self.active_list {
            let id = entry.id;
            let node = self.store.node(id);
            for (t, leaves) in (node.subtri_begin..).zip(self.store.subtri_corners(id)) {
                if self.hidden_set.contains(&t) {
                    continue;
                }
                let corners = leaves.map(|rank| self.current_corner(rank, id, &node));
                drawn.push(ActiveTriangle {
                    triangle: t,
                    corners,
                });
            }
        }
        drawn.sort_unstable_by_key(|t| t.triangle);
        drawn
    }

    /// Rank tracking: the groups of `id`'s subtris that can repeat (those with equal corners
    /// in `id`'s own cut, [`crate::repeats`]), registered and watched. Their corners inside
    /// `id` are its children, so subtris whose inside corners differ cannot repeat: corners
    /// outside `id` (an ancestor walk each) are found only for subtris that share their
    /// inside corners with another. Returns whether any group was found.
    fn group_by_ranks(&mut self, id: u32, node: &Node) -> bool {
        let mut starts = std::mem::take(&mut self.child_starts);
        starts.clear();
        self.store
            .children_leaf_begins(node.first_child, u32::from(node.child_count), &mut starts);
        // A corner outside `id` but inside its parent is, in `id`'s own cut, the sibling
        // holding it: found from the parent's children's ranks, read once.
        let mut siblings = std::mem::take(&mut self.sibling_starts);
        siblings.clear();
        let (mut parent_ranks, mut parent_first) = (0..0, 0);
        if node.parent != NIL {
            let parent = self.store.node(node.parent);
            parent_ranks = parent.leaf_begin..parent.leaf_end;
            parent_first = parent.first_child;
            self.store.children_leaf_begins(
                parent.first_child,
                u32::from(parent.child_count),
                &mut siblings,
            );
        }
        let own_cut = crate::repeats::OwnCut {
            node,
            children: &starts,
            parent_ranks,
            parent_first,
            siblings: &siblings,
        };
        let mut own = std::mem::take(&mut self.own_corners);
        let mut candidates = std::mem::take(&mut self.candidates);
        let groups = own_cut
            .groups(
                node.subtri_begin,
                self.store.subtri_corners(id),
                |r| Some(self.outside_child(r, id)),
                &mut own,
                &mut candidates,
            )
            .expect("every corner outside an unfolding node is found");
        self.own_corners = own;
        self.candidates = candidates;
        self.child_starts = starts;
        self.sibling_starts = siblings;
        if groups.is_empty() {
            return false;
        }
        for &t in groups.iter().flatten() {
            for rank in self.store.triangle_corners(t) {
                self.watched.insert((rank, id));
            }
        }
        // No corners are kept for it (they come and go with its groups, and it had none
        // while folded): the next comparison works them out afresh.
        self.repeats.groups.insert(id, groups);
        self.repeats.dirty.push(id);
        true
    }

    /// Rank tracking: forgets folded node `id`'s groups; their hidden members leave with it.
    fn ungroup_by_ranks(&mut self, id: u32) {
        let Some(groups) = self.repeats.groups.remove(&id) else {
            return;
        };
        self.repeats.corners.remove(&id);
        for &t in groups.iter().flatten() {
            for rank in self.store.triangle_corners(t) {
                self.watched.remove(&(rank, id));
            }
            self.set_hidden_by_rank(t, id, false);
        }
    }

    /// Rank tracking: hides or shows active triangle `t` of node `owner`, noting its state at
    /// the last report the first time it moves.
    fn set_hidden_by_rank(&mut self, t: u32, owner: u32, hidden: bool) {
        let was = self.hidden_set.contains(&t);
        if was == hidden {
            return;
        }
        self.hidden_was.entry(t).or_insert((was, owner));
        if hidden {
            self.hidden_set.insert(t);
            self.repeats.hidden += 1;
        } else {
            self.hidden_set.remove(&t);
            self.repeats.hidden -= 1;
        }
    }

    /// Rank tracking: the current node of every leaf rank in `begin..end` has changed (a node
    /// holding them folded or unfolded): groups with a corner there are compared again.
    #[inline]
    fn note_ranks_moved(&mut self, begin: u32, end: u32) {
        if !self.watched.is_empty() {
            // Open-ended and cut short by hand: a bounded range searches the tree for both
            // ends, and nearly every fold or unfold finds nothing past the first.
            self.repeats.moved.extend(
                self.watched
                    .range((begin, 0)..)
                    .take_while(|&&(rank, _)| rank < end)
                    .map(|&(rank, owner)| (owner, rank)),
            );
        }
    }

    /// Rank tracking: compares again the groups whose corners moved, and every group made
    /// since the last comparison. A member's corners are kept from the last comparison with
    /// the ranks they stand for; only those whose rank moved are brought up to date, from
    /// where they were ([`Cut::refreshed_corner`]): one that moved is a few levels from where
    /// it was, while working it out from the group's node descends through every active
    /// level between them.
    fn settle_rank_repeats(&mut self) {
        if self.repeats.dirty.is_empty() && self.repeats.moved.is_empty() {
            return;
        }
        let mut moved = std::mem::take(&mut self.repeats.moved);
        let noted = moved.len();
        moved.sort_unstable();
        moved.dedup();
        let mut dirty = std::mem::take(&mut self.repeats.dirty);
        dirty.extend(moved.iter().map(|&(owner, _)| owner));
        dirty.sort_unstable();
        dirty.dedup();
        let mut verdicts: Vec<bool> = Vec::new();
        let mut group_corners: Vec<[u32; 3]> = Vec::new();
        for &owner in &dirty {
            let Some(groups) = self.repeats.groups.remove(&owner) else {
                continue;
            };
            let owner_node = self.store.node(owner);
            let mut members = self.repeats.corners.remove(&owner).unwrap_or_default();
            if members.is_empty() {
                // Groups made since the last comparison: every corner from the node.
                for &t in groups.iter().flatten() {
                    let leaves = self.store.triangle_corners(t);
                    let nodes = leaves.map(|r| self.current_corner(r, owner, &owner_node));
                    members.push(crate::repeats::MemberCorners { leaves, nodes });
                }
            } else {
                let first = moved.partition_point(|&(o, _)| o < owner);
                let end = first + moved[first..].partition_point(|&(o, _)| o == owner);
                let ranks = &moved[first..end];
                for member in &mut members {
                    for (node, &rank) in member.nodes.iter_mut().zip(&member.leaves) {
                        if ranks.binary_search(&(owner, rank)).is_ok() {
                            *node = self.refreshed_corner(*node, rank, owner, &owner_node);
                        }
                    }
                }
            }
            let mut start = 0;
            for group in &groups {
                group_corners.clear();
                group_corners.extend(members[start..start + group.len()].iter().map(|m| m.nodes));
                start += group.len();
                verdicts.clear();
                verdicts.extend(hidden_members(&group_corners));
                for (&t, &hidden) in group.iter().zip(&verdicts) {
                    self.set_hidden_by_rank(t, owner, hidden);
                }
            }
            self.repeats.groups.insert(owner, groups);
            self.repeats.corners.insert(owner, members);
        }
        dirty.clear();
        self.repeats.dirty = dirty;
        moved.clear();
        // A frame that moved many watched ranks (a jump) does not keep its list's size.
        shrink_if_sparse(&mut moved, noted);
        self.repeats.moved = moved;
    }

    /// Rank tracking, right after a comparison of repeats: the corners kept for each group
    /// member are its triangle's, and are those worked out afresh from its node.
    fn check_kept_corners(&self) -> Result<(), String> {
        for (&owner, members) in &self.repeats.corners {
            let Some(groups) = self.repeats.groups.get(&owner) else {
                return Err(format!(
                    "corners are kept for node {owner}, which has no groups"
                ));
            };
            if members.len() != groups.iter().map(Vec::len).sum::<usize>() {
                return Err(format!("node {owner}'s kept corners are not its members'"));
            }
            let owner_node = self.store.node(owner);
            for (&t, member) in groups.iter().flatten().zip(members) {
                let leaves = self.store.triangle_corners(t);
                let nodes = leaves.map(|r| self.current_corner(r, owner, &owner_node));
                if member.leaves != leaves || member.nodes != nodes {
                    return Err(format!(
                        "triangle {t}'s kept corners {:?} are not its corners {nodes:?}",
                        member.nodes
                    ));
                }
            }
        }
        Ok(())
    }

    /// Rank tracking: the current corner of leaf `rank` of a subtri of active node `owner`,
    /// from `kept`, its corner at the last comparison of `owner`'s groups (a boundary node
    /// then, on `rank`'s path from the root). Still on the boundary: unchanged. Active: it
    /// unfolded, and the corner is below it. Inactive: a node above it folded, and the corner
    /// is the first boundary node above it, if the walk up stays in resident pages (a page
    /// whose nodes left the cut is kept for the frame after, but that is the store's policy,
    /// not this function's to rely on); otherwise worked out from `owner`.
    fn refreshed_corner(&self, kept: u32, rank: u32, owner: u32, owner_node: &Node) -> u32 {
        let is_active = |n: u32| self.store.state(n) == NodeState::Active;
        match self.store.state(kept) {
            NodeState::Boundary => kept,
            NodeState::Active => self.store.descend(kept, rank, is_active),
            NodeState::Inactive => {
                let mut up = kept;
                while self.store.is_resident(up) {
                    up = self.store.parent(up);
                    if self.store.state(up) == NodeState::Boundary {
                        return up;
                    }
                }
                self.current_corner(rank, owner, owner_node)
            }
        }
    }

    /// Moves active triangles out of the tail of the slot array into free slots below, and
    /// cuts the array short, when more than half of it is free: the array (and a renderer's
    /// mirror of it) follows the cut as it shrinks instead of keeping its largest size, which
    /// the memory budget would go on paying for. Moved slots are journalled like any change,
    /// so the renderer rewrites them; slots past the new end are simply no longer drawn.
    fn compact_slots(&mut self) {
        const SMALLEST: usize = 1024;
        let len = self.slots.len();
        if len <= SMALLEST || self.free_slots.len() * 2 <= len {
            return;
        }
        let active = self.active_triangle_count as usize;
        let target = (active + active / 8).max(SMALLEST);
        if target >= len {
            return;
        }
        let mut holes: Vec<u32> = self
            .free_slots
            .iter()
            .copied()
            .filter(|&s| (s as usize) < target)
            .collect();
        // Lowest holes last, so `pop` fills from the bottom up.
        holes.sort_unstable_by(|a, b| b.cmp(a));
        for from in (target..len).rev() {
            let moved = self.slots[from];
            if moved.triangle == NIL {
                continue;
            }
            // Holes below `target` number `target − active below`, at least the tail's
            // `active − active below`.
            let to = holes.pop().expect("enough free slots below the target");
            self.remove_slot(from as u32);
            self.free_slots.pop(); // `remove_slot` freed `from`, which is cut off below.
            let slot =
                self.place_triangle(to, moved.owner, moved.triangle, moved.leaves, moved.corners);
            debug_assert_eq!(slot, to);
            if moved.grouped {
                self.slots[slot as usize].grouped = true;
                self.note_moved(slot);
            }
        }
        self.slots.truncate(target);
        self.slots.shrink_to(target);
        self.free_slots = holes;
        self.settle_repeats();
        if self.tracking == CornerTracking::Lazy {
            // Moved members of groups are compared when the corners are refreshed.
            self.lazy_dirty = true;
        }
    }

    /// Lazy tracking: re-resolves every active corner whose node left the boundary.
    pub(crate) fn refresh_lazy_corners(&mut self) {
        if !self.lazy_dirty {
            return;
        }
        self.lazy_dirty = false;
        for slot in 0..self.slots.len() as u32 {
            let s = self.slots[slot as usize];
            if s.triangle == NIL {
                continue;
            }
            for k in 0..3 {
                let node = s.corners[k];
                let resolved = match self.store.state(node) {
                    NodeState::Boundary => continue,
                    NodeState::Active => self.store.descend(node, s.leaves[k], |id| {
                        self.store.state(id) == NodeState::Active
                    }),
                    NodeState::Inactive => {
                        let mut up = node;
                        while self.store.state(up) != NodeState::Boundary {
                            up = self.store.parent(up);
                        }
                        up
                    }
                };
                self.touch(slot);
                self.slots[slot as usize].corners[k] = resolved;
            }
        }
        // Every group's corners may have moved.
        let owners: Vec<u32> = self.repeats.groups.keys().copied().collect();
        self.repeats.dirty.extend(owners);
        self.compare_groups();
    }

    /// Notes that a corner of the triangle in `slot` is about to move: its group, if it has
    /// one, is compared again ([`Cut::settle_repeats`]).
    #[inline]
    fn note_moved(&mut self, slot: u32) {
        let s = &self.slots[slot as usize];
        if s.grouped {
            self.repeats.dirty.push(s.owner);
        }
    }

    /// Ends a fold, unfold or compaction: compares again the groups whose members moved
    /// (with lazy tracking, corners are current only when the cut is read, which compares
    /// them then).
    fn settle_repeats(&mut self) {
        if self.tracking == CornerTracking::Incidence {
            self.compare_groups();
        }
    }

    /// Hides, in each group of the nodes marked dirty, every member whose current corners a
    /// member with a smaller triangle index has, and shows the rest.
    fn compare_groups(&mut self) {
        if self.repeats.dirty.is_empty() {
            return;
        }
        let mut dirty = std::mem::take(&mut self.repeats.dirty);
        dirty.sort_unstable();
        dirty.dedup();
        let mut members: Vec<(u32, [u32; 3])> = Vec::new();
        let mut corners: Vec<[u32; 3]> = Vec::new();
        for &owner in &dirty {
            // A node folded since its members moved has no groups any more.
            let Some(groups) = self.repeats.groups.get(&owner) else {
                continue;
            };
            members.clear();
            for group in groups {
                for &t in group {
                    let slot = self.store.triangle_slot(owner, t);
                    members.push((slot, self.slots[slot as usize].corners));
                }
                // Group boundaries travel as a marker between groups.
                members.push((NIL, [NIL; 3]));
            }
            for group in members.split(|&(slot, _)| slot == NIL) {
                corners.clear();
                corners.extend(group.iter().map(|&(_, c)| c));
                let verdicts: Vec<bool> = hidden_members(&corners).collect();
                for (&(slot, _), hidden) in group.iter().zip(verdicts) {
                    self.set_hidden(slot, hidden);
                }
            }
        }
        dirty.clear();
        self.repeats.dirty = dirty;
    }

    /// Marks an active slot hidden or drawn, keeping the hidden count.
    fn set_hidden(&mut self, slot: u32, hidden: bool) {
        if self.slots[slot as usize].hidden == hidden {
            return;
        }
        self.touch(slot);
        self.slots[slot as usize].hidden = hidden;
        if hidden {
            self.repeats.hidden += 1;
        } else {
            self.repeats.hidden -= 1;
        }
    }

    /// The boundary node above `rank`, found from `near` (an active node not supporting
    /// `rank`, the node being unfolded): up to the first ancestor supporting `rank`, then
    /// down through active nodes. Also returns the first node of the way down: the child of
    /// that ancestor which holds `rank`.
    fn boundary_node_of(&self, rank: u32, near: u32) -> (u32, u32) {
        let first = self.outside_child(rank, near);
        let boundary = self
            .store
            .descend(first, rank, |id| self.store.state(id) == NodeState::Active);
        (first, boundary)
    }

    /// The child, holding `rank`, of the first ancestor of `near` that supports `rank` (an
    /// active node: `near` is active and does not support `rank`).
    fn outside_child(&self, rank: u32, near: u32) -> u32 {
        let mut node = self.store.parent(near);
        while !self.store.supports_rank(node, rank) {
            node = self.store.parent(node);
        }
        self.store.child_supporting(node, rank)
    }

    fn fold_would_flip(&self, id: u32) -> bool {
        if self.tracking != CornerTracking::Incidence {
            return false;
        }
        let node = self.store.node(id);
        let position = |n: u32| glam::Vec3::from(self.store.node(n).proxy);
        for c in node.children() {
            let mut entry = self.store.label(c).head;
            while entry != NIL {
                let (slot, k) = (entry / 3, (entry % 3) as usize);
                let s = &self.slots[slot as usize];
                if !node.owns_subtri(s.triangle) {
                    let p = s.corners.map(position);
                    let before = (p[1] - p[0]).cross(p[2] - p[0]);
                    let mut q = p;
                    q[k] = glam::Vec3::from(node.proxy);
                    let after = (q[1] - q[0]).cross(q[2] - q[0]);
                    if before.dot(after) < 0.0 {
                        return true;
                    }
                }
                entry = self.next_of(entry);
            }
        }
        false
    }

    fn insert_triangle(&mut self, owner: u32, triangle: u32, leaves: [u32; 3], corners: [u32; 3]) {
        let slot = match self.free_slots.pop() {
            Some(slot) => slot,
            None => {
                self.slots.push(FREE_SLOT);
                self.slots.len() as u32 - 1
            }
        };
        self.place_triangle(slot, owner, triangle, leaves, corners);
    }

    /// Puts a triangle into free slot `slot` (taken off the free list by the caller).
    fn place_triangle(
        &mut self,
        slot: u32,
        owner: u32,
        triangle: u32,
        leaves: [u32; 3],
        corners: [u32; 3],
    ) -> u32 {
        self.touch(slot);
        let s = &mut self.slots[slot as usize];
        s.triangle = triangle;
        s.owner = owner;
        s.leaves = leaves;
        s.corners = corners;
        self.store.set_triangle_slot(owner, triangle, slot);
        if self.tracking == CornerTracking::Incidence {
            for k in 0..3 {
                self.link(corners[k], slot * 3 + k as u32);
            }
        }
        self.active_triangle_count += 1;
        slot
    }

    fn remove_slot(&mut self, slot: u32) {
        self.touch(slot);
        let s = self.slots[slot as usize];
        if s.hidden {
            self.repeats.hidden -= 1;
        }
        if self.tracking == CornerTracking::Incidence {
            for k in 0..3 {
                self.unlink(s.corners[k], slot * 3 + k as u32);
            }
        }
        self.store.set_triangle_slot(s.owner, s.triangle, NIL);
        self.slots[slot as usize] = Slot {
            touched: s.touched,
            ..FREE_SLOT
        };
        self.free_slots.push(slot);
        self.active_triangle_count -= 1;
    }

    /// Records a slot's contents before its first change since the last `take_changes`.
    #[inline]
    fn touch(&mut self, slot: u32) {
        let s = &mut self.slots[slot as usize];
        if s.touched != self.epoch {
            s.touched = self.epoch;
            let (triangle, corners) = s.drawn();
            self.journal.push((slot, triangle, corners));
        }
    }

    #[inline]
    fn next_of(&self, entry: u32) -> u32 {
        self.slots[(entry / 3) as usize].next[(entry % 3) as usize]
    }

    #[inline]
    fn prev_of(&self, entry: u32) -> u32 {
        self.slots[(entry / 3) as usize].prev[(entry % 3) as usize]
    }

    #[inline]
    fn set_next(&mut self, entry: u32, to: u32) {
        self.slots[(entry / 3) as usize].next[(entry % 3) as usize] = to;
    }

    #[inline]
    fn set_prev(&mut self, entry: u32, to: u32) {
        self.slots[(entry / 3) as usize].prev[(entry % 3) as usize] = to;
    }

    #[inline]
    fn link(&mut self, node: u32, entry: u32) {
        let first = std::mem::replace(&mut self.store.label_mut(node).head, entry);
        self.set_next(entry, first);
        self.set_prev(entry, NIL);
        if first != NIL {
            self.set_prev(first, entry);
        }
    }

    #[inline]
    fn unlink(&mut self, node: u32, entry: u32) {
        let (before, after) = (self.prev_of(entry), self.next_of(entry));
        if before != NIL {
            self.set_next(before, after);
        } else {
            self.store.label_mut(node).head = after;
        }
        if after != NIL {
            self.set_prev(after, before);
        }
    }

    fn count_active_child(&mut self, parent: u32, change: i32) {
        if parent != NIL {
            let label = self.store.label_mut(parent);
            label.active_children = (i32::from(label.active_children) + change) as u8;
            let (count, index) = (label.active_children, label.active_index);
            let entry = &mut self.active_list[index as usize];
            entry.active_children = u16::from(count);
            entry.reuse = Reuse::NONE;
            self.revisit(parent);
        }
    }

    /// Rank tracking: checks that every journal entry says what its node is now. An entry its
    /// node's label names holds the label's state; any other entry is of a node whose page
    /// was evicted since (inactive then) and which is inactive or listed again later.
    fn check_journal(&self) -> Result<(), String> {
        for (k, entry) in self.node_journal.entries().iter().enumerate() {
            let label = self.store.label(entry.id);
            let now = if label.head == k as u32 {
                label.state
            } else {
                NodeState::Inactive
            };
            if entry.now != now {
                return Err(format!(
                    "the change journal says node {} is {:?}, but it is {now:?}",
                    entry.id, entry.now
                ));
            }
        }
        Ok(())
    }

    /// [`Cut::set_state`] for the children of `node`, which are not active and do not become
    /// active (a fold or unfold of `node`): their labels are reached with a page look-up per
    /// page, not per child.
    fn set_children_state(&mut self, node: &Node, state: NodeState) {
        debug_assert!(state != NodeState::Active);
        let ranks = self.tracking == CornerTracking::Ranks;
        let journal = &mut self.node_journal;
        let (first, count) = (node.first_child, u32::from(node.child_count));
        self.store
            .set_run_state(first, count, state, |id, was, label| {
                debug_assert!(was != NodeState::Active, "node {id} was active");
                if ranks {
                    journal.note(id, label, was, state, 0);
                }
            });
    }

    /// Sets node `id`'s label to `state`, keeping the active list and, under rank tracking,
    /// the change journal (`subtris`: the node's subtri count, which the report counts when
    /// it goes to or from active).
    fn set_state(&mut self, id: u32, state: NodeState, subtris: u32) {
        let ranks = self.tracking == CornerTracking::Ranks;
        let journal = &mut self.node_journal;
        let next_index = self.active_list.len() as u32;
        let (mut was, mut active_children, mut left_index) = (state, 0, NIL);
        // One page look-up for the label's state, journal entry and place in the active list.
        self.store.set_run_state(id, 1, state, |_, before, label| {
            was = before;
            if ranks {
                journal.note(id, label, before, state, subtris);
            }
            if state == NodeState::Active && before != NodeState::Active {
                label.active_index = next_index;
                active_children = u16::from(label.active_children);
            } else if before == NodeState::Active && state != NodeState::Active {
                left_index = std::mem::replace(&mut label.active_index, NIL);
            }
        });
        if state == NodeState::Active && was != NodeState::Active {
            let tested = self.store.tested(id);
            self.active_list.push(ActiveEntry {
                hot: *tested.hot,
                id,
                active_children,
                pending: 0,
                reuse: Reuse::NONE,
            });
            self.active_shapes.push(*tested.shape);
            self.revisit(id);
        } else if was == NodeState::Active && state != NodeState::Active {
            let index = left_index as usize;
            self.active_list.swap_remove(index);
            self.active_shapes.swap_remove(index);
            if let Some(moved) = self.active_list.get(index) {
                self.store.label_mut(moved.id).active_index = index as u32;
                if moved.pending != 0 {
                    self.moved_pending.push(index as u32);
                }
            }
        }
    }

    /// Checks which triangles are hidden against a recomputation from all active triangles:
    /// of each set with the same corners and winding, all but the smallest triangle index.
    fn check_repeats(&self) -> Result<(), String> {
        let mut smallest: rustc_hash::FxHashMap<[u32; 3], u32> = Default::default();
        for s in self.slots.iter().filter(|s| s.triangle != NIL) {
            let t = smallest.entry(key(s.corners)).or_insert(s.triangle);
            *t = (*t).min(s.triangle);
        }
        let mut hidden = 0;
        for s in &self.slots {
            if s.triangle == NIL {
                if s.hidden || s.grouped {
                    return Err("a free slot is marked hidden or grouped".into());
                }
                continue;
            }
            let should = smallest[&key(s.corners)] != s.triangle;
            if s.hidden != should {
                return Err(format!(
                    "triangle {} (corners {:?}) is {} but should be {}",
                    s.triangle,
                    s.corners,
                    if s.hidden { "hidden" } else { "drawn" },
                    if should { "hidden" } else { "drawn" }
                ));
            }
            hidden += u32::from(should);
        }
        if hidden != self.repeats.hidden {
            return Err("the hidden repeat count is wrong".into());
        }
        Ok(())
    }

    /// Checks every structural invariant of the cut against a recomputation from scratch:
    /// labels, the boundary list, child counts, and the active triangle set (each active
    /// node's subtris, with corners found by walking down from the root), plus the incidence
    /// lists. For tests and `vds-cut --verify`; costs a walk over the whole tree.
    pub fn check(&mut self) -> Result<(), String> {
        self.refresh_lazy_corners();
        let mut expected = Vec::new();
        let mut reached = 0usize;
        let mut stack = vec![0u32];
        let root_state = self.store.state(0);
        if root_state == NodeState::Inactive {
            return Err("the root is inactive".into());
        }
        while let Some(id) = stack.pop() {
            reached += 1;
            let node = self.store.node(id);
            let label = self.store.label(id);
            match label.state {
                NodeState::Inactive => {
                    return Err(format!("node {id} is inactive under an active parent"));
                }
                NodeState::Boundary => {}
                NodeState::Active => {
                    let index = label.active_index as usize;
                    match self.active_list.get(index) {
                        Some(e)
                            if e.id == id
                                && e.active_children == u16::from(label.active_children) =>
                        {
                            if e.pending != 0 {
                                return Err(format!(
                                    "active node {id} has a test outcome left from a pass"
                                ));
                            }
                        }
                        _ => {
                            return Err(format!(
                                "active node {id} is missing from the active list"
                            ));
                        }
                    }
                    let active = node
                        .children()
                        .filter(|&c| self.store.state(c) == NodeState::Active)
                        .count();
                    if active != usize::from(label.active_children) {
                        return Err(format!("node {id} counts its active children wrong"));
                    }
                    for t in node.subtri_begin..node.subtri_begin + node.subtri_count {
                        let leaves = self.store.triangle_corners(t);
                        expected.push(ActiveTriangle {
                            triangle: t,
                            corners: leaves.map(|r| self.current_proxy_node(r)),
                        });
                    }
                    stack.extend(node.children());
                }
            }
        }
        self.store.check_pins()?;
        let [boundary_count, active_count] = self.store.label_counts();
        let labelled = boundary_count + active_count;
        if labelled != reached {
            return Err(format!(
                "{labelled} nodes are labelled active or boundary but {reached} are reachable"
            ));
        }
        if boundary_count != self.boundary_count as usize {
            return Err("the boundary count is wrong".into());
        }
        if self.active_list.len() != self.active_node_count as usize {
            return Err("the active set holds nodes that are not active".into());
        }
        if active_count != self.active_node_count as usize {
            return Err("the active node count is wrong".into());
        }
        if self.tracking == CornerTracking::Ranks {
            let subtris: u32 = self
                .active_list
                .iter()
                .map(|e| self.store.node(e.id).subtri_count)
                .sum();
            if subtris != self.active_triangle_count {
                return Err("the active triangle count is wrong".into());
            }
            self.check_journal()?;
            expected.sort_unstable_by_key(|t| (key(t.corners), t.triangle));
            expected.dedup_by_key(|t| key(t.corners));
            expected.sort_unstable();
            let actual = self.triangles_from_ranks();
            self.check_kept_corners()?;
            if self.repeats.hidden as usize != self.hidden_set.len()
                || actual.len() != self.active_triangle_count() as usize
            {
                return Err("the hidden repeat count is wrong".into());
            }
            return if actual == expected {
                Ok(())
            } else {
                Err(format!(
                    "active triangles differ from the recomputed set ({} expected, {} found)",
                    expected.len(),
                    actual.len()
                ))
            };
        }
        let held = self.slots.iter().filter(|s| s.triangle != NIL).count();
        if held != self.active_triangle_count as usize {
            return Err("the active triangle count is wrong".into());
        }
        self.check_repeats()?;
        // Of each class of repeats, the member with the smallest triangle index is drawn.
        expected.sort_unstable_by_key(|t| (key(t.corners), t.triangle));
        expected.dedup_by_key(|t| key(t.corners));
        let mut actual: Vec<ActiveTriangle> = (0..self.slot_count())
            .filter_map(|s| self.peek_slot(s))
            .collect();
        if actual.len() != self.active_triangle_count() as usize {
            return Err("the drawn triangle count is wrong".into());
        }
        expected.sort_unstable();
        actual.sort_unstable();
        if let Some(k) =
            (0..expected.len().max(actual.len())).find(|&k| expected.get(k) != actual.get(k))
        {
            return Err(format!(
                "active triangles differ from the recomputed set: expected {:?}, found {:?} \
                 ({} expected, {} found)",
                expected.get(k),
                actual.get(k),
                expected.len(),
                actual.len()
            ));
        }
        for (slot, s) in self.slots.iter().enumerate() {
            if s.triangle != NIL && self.store.triangle_slot(s.owner, s.triangle) != slot as u32 {
                return Err(format!("triangle {} does not map to its slot", s.triangle));
            }
        }
        if self.tracking == CornerTracking::Incidence {
            let mut listed = 0usize;
            for b in self.boundary() {
                let mut entry = self.store.label(b).head;
                let mut previous = NIL;
                while entry != NIL {
                    let s = &self.slots[(entry / 3) as usize];
                    if s.triangle == NIL || s.corners[(entry % 3) as usize] != b {
                        return Err(format!("node {b}'s incidence list holds a stray entry"));
                    }
                    if self.prev_of(entry) != previous {
                        return Err(format!("node {b}'s incidence list is mislinked"));
                    }
                    listed += 1;
                    previous = entry;
                    entry = self.next_of(entry);
                }
            }
            if listed != 3 * held {
                return Err("incidence lists miss active corners".into());
            }
        }
        Ok(())
    }
}

/// How many more entries a vector of `capacity` must reserve to hold `needed`: none if it
/// holds them, else a quarter more than it has (at least 1024), so growth is in steps the
/// memory budget can be asked for, and amortised.
fn grown_capacity(capacity: usize, needed: usize) -> usize {
    if needed <= capacity {
        return 0;
    }
    needed.max(capacity + (capacity / 4).max(1024)) - capacity
}

/// Gives back most of `v`'s spare capacity once it holds under a quarter of it (with room
/// for `expected` entries and a floor of 1024), so a cut that shrinks stops paying for its
/// largest size.
fn shrink_if_sparse<T>(v: &mut Vec<T>, expected: usize) {
    let keep = expected.max(v.len()).max(1024);
    if v.capacity() > 4 * keep {
        v.shrink_to(keep);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use vds_format::{VdtFile, WriteOptions};

    /// `name` from `../shared/data` built by `builder` into a `.vdt` file of small pages.
    fn file_of(name: &str, builder: vds_build::Builder) -> VdtFile<Vec<u8>> {
        let path = std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
            .join("../../../shared/data")
            .join(name);
        let mut scene = vds_import::load_file(path, &Default::default()).unwrap();
        let grid = vds_build::snap_to_grid(&mut scene);
        let (tree, _) = vds_build::build_tree_by(&scene, builder);
        let metadata = vds_format::Metadata {
            part_names: scene.part_names.clone(),
            ..Default::default()
        };
        let content = vds_build::tree_content(&tree, &scene, metadata, grid);
        let options = WriteOptions {
            zstd_level: 1,
            page_bytes: 4096,
        };
        VdtFile::from_bytes(vds_format::encode(&content, &options).unwrap().0).unwrap()
    }

    /// The store marks a node's subtris as unable to repeat when their pages arrive
    /// (`NodeStore::establish_on_arrival`) only where grouping them at an unfold, the slow
    /// way, finds no group; and it decides most nodes, the others left to the unfold.
    #[test]
    fn subtris_marked_unrepeatable_on_arrival_form_no_group_when_unfolded() {
        for builder in [vds_build::Builder::Octree, vds_build::Builder::Qem] {
            for name in ["bunny.obj", "as1_assembly.obj"] {
                let store = NodeStore::new(Box::new(file_of(name, builder))).unwrap();
                let mut cut = Cut::new(store, CornerTracking::Ranks);
                cut.store_mut().load_every_page().unwrap();
                let (mut marked, mut grouped, mut several) = (0, 0, 0);
                for id in 0..cut.store().node_count() {
                    let node = cut.store().node(id);
                    if node.subtri_count < 2 {
                        continue;
                    }
                    several += 1;
                    let unrepeatable = cut.store().is_unrepeated(id);
                    let groups = cut.group_by_ranks(id, &node);
                    assert!(
                        !(unrepeatable && groups),
                        "{name}: node {id} was marked on arrival but its subtris group"
                    );
                    marked += usize::from(unrepeatable);
                    grouped += usize::from(groups);
                }
                let what = format!("{name}, {} builder", builder.name());
                assert!(
                    marked * 10 > several * 9,
                    "{what}: {marked} of {several} marked"
                );
                if builder == vds_build::Builder::Octree {
                    assert!(grouped > 0, "{what}: no node's subtris group");
                }
            }
        }
    }
}
