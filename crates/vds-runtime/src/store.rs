//! Node and triangle records, fetched a page at a time through the `.vdt` reader's page API.
//!
//! The cut never reads a file directly: it asks the store for the page holding a node before
//! it first touches that node (the root at start, a node's children when it unfolds). Pages
//! are decoded on first use into flat arrays indexed by node id and triangle index, so the
//! per-frame traversal reads a node with one indexed load. A paging layer with a memory
//! budget replaces this module's residency rule without touching the cut.

use bytemuck::Zeroable;
use vds_format::BoundViolation::{self, LeafOutsideErrorRadius, SphereOutsideParent};
use vds_format::{Header, NO_NODE, NodeRecord, Page, PageEntry, VdtError, VdtFile};

/// Where pages come from: a `.vdt` file, or anything else that speaks its page API. Shared
/// with the background loader's threads ([`Loading::Background`]), hence `Sync`.
pub trait PageSource: Send + Sync {
    /// The file's header (counts and grid).
    fn header(&self) -> &Header;
    /// The page directory.
    fn directory(&self) -> &[PageEntry];
    /// Decodes and validates page `index` into `page`, reusing its buffers.
    fn read_page_into(&self, index: u32, page: &mut Page) -> Result<(), VdtError>;
}

impl<B: AsRef<[u8]> + Send + Sync> PageSource for VdtFile<B> {
    fn header(&self) -> &Header {
        VdtFile::header(self)
    }

    fn directory(&self) -> &[PageEntry] {
        VdtFile::directory(self)
    }

    fn read_page_into(&self, index: u32, page: &mut Page) -> Result<(), VdtError> {
        VdtFile::read_page_into(self, index, page)
    }
}

/// One node of the vertex tree as the runtime reads it (native floats and integers).
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
pub struct Node {
    /// The proxy vertex (a leaf's original position).
    pub proxy: [f32; 3],
    /// Largest distance from the proxy to any original vertex under the node.
    pub error_radius: f32,
    /// How far the surface moves when the node folds, as the builder's quadric measures it
    /// (an estimate at most the error radius; `docs/format.md`, Bounds). 0 for a leaf.
    pub surface_error: f32,
    /// Centre of a sphere holding every triangle with a corner under the node.
    pub sphere_center: [f32; 3],
    /// Radius of that sphere.
    pub sphere_radius: f32,
    /// Unit axis of the cone of those triangles' normals.
    pub cone_axis: [f32; 3],
    /// Half-angle of that cone in radians; negative when it bounds no normal.
    pub cone_half_angle: f32,
    /// The cone is two-sided: every normal `n` has `n` or `−n` inside it (thin shells:
    /// both faces of a plate), so it bounds where silhouettes can be but not backfacing.
    pub cone_two_sided: bool,
    /// Parent id, or [`NO_NODE`] for the root.
    pub parent: u32,
    /// First child id; children are `first_child .. first_child + child_count`.
    pub first_child: u32,
    /// First leaf rank under the node.
    pub leaf_begin: u32,
    /// One past the last leaf rank under the node.
    pub leaf_end: u32,
    /// Global index of the node's first subtri.
    pub subtri_begin: u32,
    /// Number of subtris.
    pub subtri_count: u32,
    /// Number of children (0 for a leaf).
    pub child_count: u8,
    /// Depth below the root.
    pub depth: u16,
}

impl Node {
    pub(crate) fn from_record(r: &NodeRecord) -> Node {
        let f = |v: &[vds_format::layout::F32]| [v[0].get(), v[1].get(), v[2].get()];
        Node {
            proxy: f(&r.proxy),
            error_radius: r.error_radius.get(),
            surface_error: r.surface_error.get(),
            sphere_center: f(&r.sphere[..3]),
            sphere_radius: r.sphere[3].get(),
            cone_axis: f(&r.cone[..3]),
            cone_half_angle: r.cone[3].get(),
            cone_two_sided: r.flags & vds_format::FLAG_TWO_SIDED_CONE != 0,
            parent: r.parent.get(),
            first_child: r.first_child.get(),
            leaf_begin: r.leaf_begin.get(),
            leaf_end: r.leaf_end.get(),
            subtri_begin: r.subtri_begin.get(),
            subtri_count: r.subtri_count.get(),
            child_count: r.child_count,
            depth: r.depth.get(),
        }
    }

    /// True for a leaf (an original vertex).
    pub fn is_leaf(&self) -> bool {
        self.child_count == 0
    }

    /// The children's ids.
    pub fn children(&self) -> std::ops::Range<u32> {
        self.first_child..self.first_child + u32::from(self.child_count)
    }

    /// True when the original vertex of leaf rank `rank` lies under this node.
    pub fn supports_rank(&self, rank: u32) -> bool {
        self.leaf_begin <= rank && rank < self.leaf_end
    }

    /// True when triangle `index` is one of this node's subtris.
    pub fn owns_subtri(&self, index: u32) -> bool {
        index.wrapping_sub(self.subtri_begin) < self.subtri_count
    }
}

/// How far past its parent's sphere an honest child's decoded sphere can reach, for a child
/// of decoded error radius `error_radius` on a grid of `step`.
///
/// The writer quantises each sphere on its own (`docs/format.md`, Bounds): a centre moves
/// by at most √3 *centre units* `u = max(1, e / 32)` steps (`e`: the error radius in steps)
/// and the radius grows by that move and by under `u + 1` steps of rounding up. The parent's
/// radius grows by its own centre's move, so the child's sphere, nested before quantising,
/// can end up to `(2√3 + 2)·u` steps past the parent's: about 5.5 units, 6 here. On the
/// bundled meshes the largest is 2.2 units.
fn nesting_slack(error_radius: f32, step: f32) -> f32 {
    6.0 * (error_radius / 32.0).max(step)
}

/// What the per-frame traversal reads of every active node, packed apart from the rest
/// (32 bytes: two nodes per cache line instead of one node over two).
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
pub struct Hot {
    /// The proxy vertex.
    pub proxy: [f32; 3],
    /// The node's error radius.
    pub error_radius: f32,
    /// Radius of a ball around this node's proxy holding every child's error ball
    /// (`max ‖child proxy − proxy‖ + child error radius`); zero until the node is checked
    /// (`NodeStore::check_and_bound`).
    pub group_radius: f32,
    /// The largest error radius among the children.
    pub group_error: f32,
    /// First child id (as in [`Node`]).
    pub first_child: u32,
    /// Number of children.
    pub child_count: u32,
}

/// What the full criteria read besides [`Hot`]: the bounding sphere and the normal cone
/// (32 bytes, in their own array, read in the same id order as [`Hot`]).
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
pub struct Shape {
    /// Bounding sphere centre.
    pub center: [f32; 3],
    /// Bounding sphere radius.
    pub radius: f32,
    /// Unit cone axis.
    pub cone_axis: [f32; 3],
    /// The cone's test value ([`Shape::cone_test`]): the cosine of the half-angle of a
    /// one-sided cone, minus that cosine for a two-sided one, above 1 for an empty cone.
    pub cone_cos: f32,
}

impl Shape {
    /// The value [`Shape::cone_cos`] holds for a cone of `half_angle` radians (negative:
    /// empty), one- or two-sided.
    ///
    /// One number carries the kind so the record stays 32 bytes. It is unambiguous because a
    /// cone at least a hemisphere wide, of either kind, is stored as a hemisphere (cosine 0):
    /// from every view such a cone may hold a silhouette and never only backs, which is all
    /// the criteria ask of it. The narrower cones then have positive cosines (one-sided) or
    /// negative ones (two-sided).
    pub fn cone_test(half_angle: f32, two_sided: bool) -> f32 {
        if half_angle < 0.0 {
            return 2.0;
        }
        let cos = half_angle.cos().max(0.0);
        if two_sided && cos > 0.0 { -cos } else { cos }
    }
}

/// The page holding node `id`, given each page's first node (`first_nodes[0]` is 0,
/// checked at open, or at most `id` for a part of the directory, so some page starts at or
/// before any id).
#[inline]
pub(crate) fn page_holding(first_nodes: &[u32], id: u32) -> usize {
    first_nodes
        .partition_point(|&first| first <= id)
        .saturating_sub(1)
}

/// The two records the criteria read of `node`, as a resident page keeps them (the group
/// bound is zero: it is set when the children load).
pub(crate) fn tested_parts(node: &Node) -> (Hot, Shape) {
    let hot = Hot {
        proxy: node.proxy,
        error_radius: node.error_radius,
        group_radius: 0.0,
        group_error: 0.0,
        first_child: node.first_child,
        child_count: u32::from(node.child_count),
    };
    let shape = Shape {
        center: node.sphere_center,
        radius: node.sphere_radius,
        cone_axis: node.cone_axis,
        cone_cos: Shape::cone_test(node.cone_half_angle, node.cone_two_sided),
    };
    (hot, shape)
}

/// The two records the criteria read of one node.
#[derive(Debug, Clone, Copy)]
pub struct Tested<'a> {
    /// Proxy, error radius and group bound.
    pub hot: &'a Hot,
    /// Sphere and cone.
    pub shape: &'a Shape,
}

/// The records the criteria read of one resident page's nodes ([`NodeStore::tested_page`]).
#[derive(Clone, Copy)]
pub(crate) struct TestedPage<'a> {
    /// The page's first node id: node `first + i` is entry `i`.
    pub first: u32,
    /// Proxies, error radii and group bounds.
    pub hot: &'a [Hot],
    /// Spheres and cones.
    pub shape: &'a [Shape],
    /// One bit per node: its children were loaded and checked against it.
    pub checked: &'a [u64],
}

impl<'a> TestedPage<'a> {
    /// What the criteria read of entry `i`.
    #[inline]
    pub fn tested(&self, i: usize) -> Tested<'a> {
        Tested {
            hot: &self.hot[i],
            shape: &self.shape[i],
        }
    }

    /// Whether entry `i`'s children were loaded and checked.
    #[inline]
    pub fn is_checked(&self, i: usize) -> bool {
        self.checked[i / 64] & (1 << (i % 64)) != 0
    }

    /// Whether node `id` lies in this page.
    #[inline]
    pub fn holds(&self, id: u32) -> bool {
        id.wrapping_sub(self.first) < self.hot.len() as u32
    }
}

/// Where a node sits in the tree and how many triangles it owns: what a change report needs
/// of a node that folded or unfolded ([`crate::sweep::Sweep::report`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Family {
    /// The parent's id, or [`crate::NIL`] for the root.
    pub parent: u32,
    /// The first child's id; the children are consecutive.
    pub first_child: u32,
    /// Number of children.
    pub child_count: u32,
    /// Number of subtris.
    pub subtri_count: u32,
}

/// The rest of a node: where it sits in the tree and which triangles it owns.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
struct Topology {
    parent: u32,
    leaf_end: u32,
    subtri_begin: u32,
    subtri_count: u32,
    cone_half_angle: f32,
    surface_error: f32,
    depth: u16,
    cone_two_sided: bool,
}

/// How a store gets the pages the cut reaches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Loading {
    /// On the adjusting thread, when first needed: an unfold waits for its children's page.
    /// What tests, `vds-cut` and batch exports want: every adjust settles the cut fully.
    #[default]
    Synchronous,
    /// On `threads` background threads (the `loader` module): an adjust never reads a page. A
    /// node whose children are not resident stays folded and asks for their page, most
    /// urgent first; it unfolds in an adjust after the page arrives (the scene is briefly
    /// coarser, the frame time does not move).
    Background {
        /// Loading threads (at least one; [`crate::default_loading_threads`] suggests how many).
        threads: usize,
    },
}

/// Where one page of the file stands.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum PageState {
    /// Not resident, not asked for (or asked for and not arrived: see `awaited`).
    Absent,
    /// Decoded into a [`ResidentPage`].
    Resident,
    /// The background loader could not read it; its nodes stay folded.
    Failed,
}

/// What the cut keeps of one node while the node's page is resident: its label, its count of
/// active children, its place in the cut's active list, and the head of its incidence list or
/// its entry in the cut's journal of changes. Nodes of pages that are not resident read as
/// inactive.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct NodeLabel {
    /// Inactive, boundary or active. Changed only through [`NodeStore::set_state`], which
    /// keeps the page's pin count.
    pub(crate) state: crate::cut::NodeState,
    /// How many of its children are active.
    pub(crate) active_children: u8,
    /// Its index in the cut's active list, or [`NIL`].
    pub(crate) active_index: u32,
    /// Incidence tracking: the first incidence-list entry it heads, or [`NIL`]. Rank
    /// tracking: its entry in the cut's journal of changed nodes (`crate::journal::Journal`),
    /// which is its entry only while that entry names it: the journal empties at each change
    /// report, so a stale index points past the end or at another node, and no label need be
    /// cleared.
    pub(crate) head: u32,
}

const _: () = assert!(size_of::<NodeLabel>() == 12);

impl NodeLabel {
    /// The label of a node below the boundary.
    pub(crate) const INACTIVE: NodeLabel = NodeLabel {
        state: crate::cut::NodeState::Inactive,
        active_children: 0,
        active_index: NIL,
        head: NIL,
    };
}

/// "None" for slots, list links and page slots.
const NIL: u32 = u32::MAX;

/// Pages asked for ahead of need at most at once.
const MAX_AHEAD: u32 = 16;

/// Decoded pages that may wait for the store to take them in, in bytes (besides the budget;
/// at least [`crate::loader::WAITING`] pages per loading thread): a frame's worth of pages
/// at the rate a worker decodes them.
const WAITING_BYTES: u64 = 16 << 20;

/// Frames an unpinned page must go unused before a page fetched ahead of need may take its
/// place (one second at 60 Hz).
const STALE_FRAMES: usize = 60;

/// An empty page range, for "keep no page".
#[allow(clippy::reversed_empty_ranges)]
const NO_PAGES: std::ops::RangeInclusive<u32> = 1..=0;

/// The `awaited` priority of a page nobody asked for.
const NOT_AWAITED: f32 = f32::NEG_INFINITY;

/// One decoded page: its nodes' records split by who reads them, its triangles, and the cut's
/// per-node and per-triangle state, all freed together when the page is evicted.
// `repr(C)` and the alignment keep the four arrays read on nearly every look-up (boxed
// slices, 16 bytes each) in the record's first cache line.
#[repr(C, align(64))]
struct ResidentPage {
    hot: Box<[Hot]>,
    shape: Box<[Shape]>,
    labels: Box<[NodeLabel]>,
    /// Per node: its first leaf rank, apart, so finding the child that holds a rank reads one
    /// small contiguous run.
    leaf_begin: Box<[u32]>,
    topology: Box<[Topology]>,
    /// The page's index in the file.
    index: u32,
    first_triangle: u32,
    /// One bit per node: its children were checked against it ([`NodeStore::check_and_bound`]).
    checked: Vec<u64>,
    /// One bit per node: no two of its subtris can ever repeat (found on the arrival of a
    /// page, [`NodeStore::establish_on_arrival`], or when it last unfolded under rank
    /// tracking; a fact of the tree, kept while the page is resident).
    unrepeated: Vec<u64>,
    corners: Vec<[u32; 3]>,
    parts: Vec<u32>,
    /// Per triangle: the cut's slot holding it while it is active, or [`NIL`]; empty when
    /// the cut keeps no slots ([`crate::CornerTracking::Ranks`]).
    triangle_slot: Vec<u32>,
    /// Nodes of this page on or above the boundary: while any is, the page stays.
    pins: u32,
    /// When the page last arrived or was last unpinned ([`NodeStore::tick`]): the eviction
    /// order among unpinned pages.
    stamp: u64,
    /// Every byte this page holds: the record above and its arrays' capacities.
    bytes: u64,
}

impl ResidentPage {
    fn from_page(index: u32, page: &Page, triangle_slots: bool) -> ResidentPage {
        let n = page.nodes.len();
        let t = page.triangles.len();
        let mut hot = Vec::with_capacity(n);
        let mut shape = Vec::with_capacity(n);
        let mut leaf_begin = Vec::with_capacity(n);
        let mut topology = Vec::with_capacity(n);
        for record in &page.nodes {
            let node = Node::from_record(record);
            let (node_hot, node_shape) = tested_parts(&node);
            hot.push(node_hot);
            shape.push(node_shape);
            leaf_begin.push(node.leaf_begin);
            topology.push(Topology {
                parent: node.parent,
                leaf_end: node.leaf_end,
                subtri_begin: node.subtri_begin,
                subtri_count: node.subtri_count,
                cone_half_angle: node.cone_half_angle,
                surface_error: node.surface_error,
                depth: node.depth,
                cone_two_sided: node.cone_two_sided,
            });
        }
        let mut resident = ResidentPage {
            index,
            first_triangle: page.first_triangle,
            hot: hot.into_boxed_slice(),
            shape: shape.into_boxed_slice(),
            leaf_begin: leaf_begin.into_boxed_slice(),
            topology: topology.into_boxed_slice(),
            labels: vec![NodeLabel::INACTIVE; n].into_boxed_slice(),
            checked: vec![0; n.div_ceil(64)],
            unrepeated: vec![0; n.div_ceil(64)],
            corners: Vec::with_capacity(t),
            parts: Vec::with_capacity(t),
            triangle_slot: if triangle_slots {
                vec![NIL; t]
            } else {
                Vec::new()
            },
            pins: 0,
            stamp: 0,
            bytes: 0,
        };
        for triangle in &page.triangles {
            resident.corners.push(triangle.corners.map(|c| c.get()));
            resident.parts.push(triangle.part.get());
        }
        resident.bytes = resident.counted_bytes();
        resident
    }

    /// Counts a node of this page going from `was` to `state` in its pins: the page is
    /// pinned while any of its nodes is on or above the boundary, and joins the eviction order
    /// (`evictable`, stamped `tick`) when the last one leaves.
    fn repin(
        &mut self,
        was: crate::cut::NodeState,
        state: crate::cut::NodeState,
        evictable: &mut std::collections::BTreeSet<(u64, u32)>,
        evictable_bytes: &mut u64,
        tick: &mut u64,
    ) {
        use crate::cut::NodeState::Inactive;
        match (was == Inactive, state == Inactive) {
            (true, false) => {
                self.pins += 1;
                if self.pins == 1 {
                    evictable.remove(&(self.stamp, self.index));
                    *evictable_bytes -= self.bytes;
                }
            }
            (false, true) => {
                self.pins -= 1;
                if self.pins == 0 {
                    self.stamp = *tick;
                    *tick += 1;
                    evictable.insert((self.stamp, self.index));
                    *evictable_bytes += self.bytes;
                }
            }
            _ => {}
        }
    }

    /// The bytes of the record and of every array it owns, by capacity.
    fn counted_bytes(&self) -> u64 {
        fn held<T>(v: &Vec<T>) -> usize {
            v.capacity() * size_of::<T>()
        }
        fn boxed<T>(v: &[T]) -> usize {
            std::mem::size_of_val(v)
        }
        (size_of::<ResidentPage>()
            + boxed(&self.hot)
            + boxed(&self.shape)
            + boxed(&self.leaf_begin)
            + boxed(&self.topology)
            + boxed(&self.labels)
            + held(&self.checked)
            + held(&self.unrepeated)
            + held(&self.corners)
            + held(&self.parts)
            + held(&self.triangle_slot)) as u64
    }

    /// The bytes a page of `nodes` nodes and `triangles` triangles takes once resident, with
    /// or without a slot per triangle.
    fn bytes_for(nodes: usize, triangles: usize, triangle_slots: bool) -> u64 {
        let per_triangle =
            size_of::<[u32; 3]>() + size_of::<u32>() * (1 + usize::from(triangle_slots));
        (size_of::<ResidentPage>()
            + nodes
                * (size_of::<Hot>()
                    + size_of::<Shape>()
                    + size_of::<u32>()
                    + size_of::<Topology>()
                    + size_of::<NodeLabel>())
            + 2 * nodes.div_ceil(64) * size_of::<u64>()
            + triangles * per_triangle) as u64
    }
}

/// Where a resident node lives: its page's slot in the store and its index in the page.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
struct Place {
    slot: u32,
    local: u32,
}

/// The node → page table's blocks: `2^shift` node ids each, the largest power of two at most
/// a page's average node count (1 to 65536 ids), so that one or two blocks start in a page
/// of average size and the table costs 4 to 8 B a page of the file.
fn block_shift(node_count: u32, page_count: usize) -> u32 {
    let per_block = (u64::from(node_count) / page_count.max(1) as u64).max(1);
    (63 - per_block.leading_zeros()).min(16)
}

/// Steps of the look-up's walk along the page directory before it searches instead: a block
/// is no longer than an average page, so a walk of one step or none finds nearly every node.
const WALK_STEPS: usize = 4;

/// The page holding node `id` (what [`page_holding`] finds), from the page its block starts
/// in (`block_page`, made by [`block_pages`]): a short walk along the directory, or a search
/// past [`WALK_STEPS`] pages, since a hostile file's pages may be of any size.
#[inline]
fn page_from_block(first_nodes: &[u32], block_page: &[u32], shift: u32, id: u32) -> usize {
    let block = (id >> shift) as usize;
    let mut page = block_page[block] as usize;
    for _ in 0..WALK_STEPS {
        match first_nodes.get(page + 1) {
            Some(&next) if next <= id => page += 1,
            _ => return page,
        }
    }
    // The page holding the next block's first node is the last that can hold `id`.
    let end = block_page
        .get(block + 1)
        .map_or(first_nodes.len(), |&p| p as usize + 1)
        .clamp(page + 1, first_nodes.len());
    page + page_holding(&first_nodes[page..end], id)
}

/// Per block of `2^shift` node ids, the page holding the block's first node (the directory is
/// `first_nodes`, ascending from 0).
fn block_pages(first_nodes: &[u32], node_count: u32, shift: u32) -> Vec<u32> {
    let blocks = (node_count >> shift) as usize + 1;
    let mut page = 0usize;
    (0..blocks)
        .map(|block| {
            let id = (block as u32) << shift;
            while first_nodes.get(page + 1).is_some_and(|&next| next <= id) {
                page += 1;
            }
            page as u32
        })
        .collect()
}

/// Memory figures of a store ([`NodeStore::memory`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MemoryStats {
    /// Bytes held now: resident pages, the per-page tables, and what the cut reports it
    /// holds ([`NodeStore::set_cut_bytes`]).
    pub resident_bytes: u64,
    /// Of those, the bytes of pages that hold boundary or active nodes (never evicted).
    pub pinned_bytes: u64,
    /// The budget ([`u64::MAX`] when unlimited).
    pub budget_bytes: u64,
    /// Pages resident now.
    pub pages_resident: u32,
    /// Pages in the file.
    pub pages_total: u32,
    /// Pages decoded into the store since it opened.
    pub pages_loaded: u64,
    /// Pages evicted since it opened.
    pub pages_evicted: u64,
    /// Pages asked of the background loader for waiting nodes and not yet delivered.
    pub pages_pending: u32,
    /// Pages, and growth steps of the cut's arrays, that were needed and did not fit in the
    /// budget, since the store opened.
    pub refusals: u64,
}

/// The default memory budget: 1 GiB, or a quarter of physical memory if that is less.
pub fn default_memory_budget() -> u64 {
    const GIB: u64 = 1 << 30;
    physical_memory().map_or(GIB, |bytes| GIB.min(bytes / 4))
}

/// Physical memory in bytes (`MemTotal` of `/proc/meminfo`), where the system reports it.
fn physical_memory() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = meminfo.lines().find(|l| l.starts_with("MemTotal:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

/// Nodes and triangles of the resident pages, and the cut's labels of them.
///
/// Nothing here is sized by the model but a few tables with an entry per page of the file
/// (where a page starts, its slot, its state) and the node → page table of one entry per
/// block of node ids (`block_shift`, `block_pages`). Every per-node and per-triangle record
/// lives in the resident page that holds it (`ResidentPage`), found through those tables.
///
/// ## Memory budget and eviction
/// The store holds at most its budget in bytes ([`NodeStore::set_memory_budget`]): resident
/// pages (every byte of their records and arrays), the per-page tables, and what the cut
/// reports of its own arrays. A page holding a boundary or active node is *pinned*: the cut
/// reads it every frame, so it stays. Every other page is evictable, oldest first by its
/// stamp: the moment it arrived or its last node left the cut. Pages below the boundary are
/// reached only through it, so the ones touched last are those nearest the boundary, the
/// next to be needed; a page deep below has not been touched since the cut left it.
///
/// A page that arrived or was unpinned since the start of the previous frame is not evicted
/// to make room: it has not yet had a frame to be used, and evicting it for another page that
/// the same cut needs is how a cache thrashes. When a needed page does not fit, it is
/// refused (its node stays folded, [`MemoryStats::refusals`] counts it), and the runtime
/// raises its effective threshold until the cut fits ([`crate::Runtime`]). Arrivals and the
/// cut's growth are held to fifteen sixteenths of the budget; the rest is room for the
/// journal of a frame's changes.
pub struct NodeStore {
    source: std::sync::Arc<dyn PageSource>,
    node_count: u32,
    triangle_count: u32,
    vertex_count: u32,
    /// Per page, its first node id (shared with the background loader).
    page_first_node: std::sync::Arc<[u32]>,
    page_first_triangle: Vec<u32>,
    /// Node ids per block of `block_page`, as a shift.
    block_shift: u32,
    /// Per block of node ids: the page holding its first node, where the look-up of any node
    /// of the block starts its walk along the page directory.
    block_page: Vec<u32>,
    page_state: Vec<PageState>,
    /// Per page: its slot in `pages`, or [`NIL`].
    page_slot: Vec<u32>,
    pages: Vec<Option<ResidentPage>>,
    free_page_slots: Vec<u32>,
    /// Unpinned resident pages by (stamp, page index): the eviction order.
    evictable: std::collections::BTreeSet<(u64, u32)>,
    evictable_bytes: u64,
    page_bytes: u64,
    table_bytes: u64,
    cut_bytes: u64,
    budget: u64,
    /// A counter that orders arrivals and unpinnings.
    tick: u64,
    /// `tick` at the start of each of the last [`STALE_FRAMES`] frames.
    recent_frames: std::collections::VecDeque<u64>,
    /// Pages stamped before this tick have not been used for [`STALE_FRAMES`] frames.
    stale_before: u64,
    /// The decoded size of an average page of the file, for fetching ahead of need.
    typical_page_bytes: u64,
    /// Whether resident pages keep a cut slot per triangle (every corner tracking but ranks).
    triangle_slots: bool,
    /// Pages stamped at or after this tick are not evicted to make room (see the type's
    /// documentation).
    protect_from: u64,
    frame_start: u64,
    pages_loaded: u64,
    pages_evicted: u64,
    refusals: u64,
    /// Pages refused since the last [`NodeStore::take_refused`].
    refused_recently: u32,
    /// Background loading, when on.
    loader: Option<crate::loader::Loader>,
    /// Per page: the highest priority it was asked for with and not yet delivered, or
    /// [`NOT_AWAITED`] when it is not awaited. Pages asked for ahead of need
    /// ([`NodeStore::prefetch_children`]) have priorities below zero, needed ones zero or more.
    awaited: Vec<f32>,
    /// Pages asked of the loader for waiting nodes and not yet delivered.
    pending_pages: u32,
    /// The pages counted in `pending_pages`, in the order asked (a page delivered or
    /// cancelled since may still be listed, and is skipped).
    pending_list: Vec<u32>,
    /// Per page: the frame ([`NodeStore::frames`]) in which a node last asked for it.
    asked_in: Vec<u32>,
    /// Frames begun ([`NodeStore::begin_frame`]).
    frames: u32,
    /// Pages asked of the loader ahead of need and not yet delivered.
    pending_ahead: u32,
    /// Errors of pages the background loader could not read, not yet taken.
    page_errors: Vec<VdtError>,
    /// Node id ranges of the pages loaded since the last [`NodeStore::take_loaded`].
    loaded: Vec<std::ops::Range<u32>>,
    scratch: Page,
    /// Scratch of [`NodeStore::check_and_bound`]: the children's records.
    children_scratch: Vec<ChildRecords>,
    /// Scratch of [`NodeStore::subtris_cannot_repeat`]: the children's first leaf ranks,
    starts_scratch: Vec<u32>,
    /// the siblings' first leaf ranks,
    siblings_scratch: Vec<u32>,
    /// each subtri's signature with its place among the node's subtris,
    signatures_scratch: Vec<([u32; 3], u32)>,
    /// and the corners of those that share a signature.
    candidates_scratch: Vec<([u32; 3], u32)>,
}

/// The records of one child that [`NodeStore::check_and_bound`] checks.
struct ChildRecords {
    hot: Hot,
    shape: Shape,
    leaf_begin: u32,
    topology: Topology,
}

pub(crate) fn empty_page() -> Page {
    Page {
        first_node: 0,
        first_triangle: 0,
        nodes: Vec::new(),
        triangles: Vec::new(),
    }
}

impl NodeStore {
    /// A store over `source` with the root's page loaded, loading pages synchronously.
    pub fn new(source: Box<dyn PageSource>) -> Result<NodeStore, VdtError> {
        NodeStore::with_loading(source, Loading::Synchronous)
    }

    /// A store over `source` with the root's page loaded (on this thread, whatever the
    /// loading: nothing can be drawn before it), loading the others as `loading` says, with
    /// the [`default_memory_budget`].
    pub fn with_loading(
        source: Box<dyn PageSource>,
        loading: Loading,
    ) -> Result<NodeStore, VdtError> {
        let source: std::sync::Arc<dyn PageSource> = source.into();
        let header = source.header();
        let node_count = u32::try_from(header.node_count.get())
            .map_err(|_| VdtError::invalid("header", "more than 2^32 nodes"))?;
        let triangle_count = u32::try_from(header.triangle_count.get())
            .map_err(|_| VdtError::invalid("header", "more than 2^32 triangles"))?;
        let vertex_count = u32::try_from(header.vertex_count.get())
            .map_err(|_| VdtError::invalid("header", "more than 2^32 vertices"))?;
        if node_count == 0 {
            return Err(VdtError::invalid("tree", "the file holds no nodes"));
        }
        let directory = source.directory();
        let page_first_node: std::sync::Arc<[u32]> =
            directory.iter().map(|p| p.first_node.get()).collect();
        let page_first_triangle: Vec<u32> =
            directory.iter().map(|p| p.first_triangle.get()).collect();
        if page_first_node.first() != Some(&0) {
            return Err(VdtError::invalid(
                "page directory",
                "page 0 does not start at node 0",
            ));
        }
        let page_count = page_first_node.len();
        // The reader checked that pages start in ascending order; the block table's walk
        // and `partition_point` take that as given, and stay in bounds whatever the order.
        let shift = block_shift(node_count, page_count);
        let block_page = block_pages(&page_first_node, node_count, shift);
        let typical_page_bytes = ResidentPage::bytes_for(
            (node_count as usize).div_ceil(page_count),
            (triangle_count as usize).div_ceil(page_count),
            true,
        );
        let loader = match loading {
            Loading::Synchronous => None,
            Loading::Background { threads } => Some(crate::loader::Loader::start(
                std::sync::Arc::clone(&source),
                std::sync::Arc::clone(&page_first_node),
                threads,
                // Decoded pages waiting for the store are held outside its budget: as many
                // as fit in WAITING_BYTES.
                (WAITING_BYTES / typical_page_bytes.max(1)) as usize,
            )?),
        };
        let background = loader.is_some();
        let table_bytes = (page_count
            * (2 * size_of::<u32>()
                + size_of::<PageState>()
                + size_of::<u32>()
                + size_of::<f32>()
                + if loader.is_some() {
                    crate::loader::PER_PAGE_BYTES + size_of::<u32>()
                } else {
                    0
                })
            + block_page.len() * size_of::<u32>()) as u64;
        let mut store = NodeStore {
            source,
            node_count,
            triangle_count,
            vertex_count,
            page_first_node,
            page_first_triangle,
            block_page,
            block_shift: shift,
            page_state: vec![PageState::Absent; page_count],
            page_slot: vec![NIL; page_count],
            pages: Vec::new(),
            free_page_slots: Vec::new(),
            evictable: Default::default(),
            evictable_bytes: 0,
            page_bytes: 0,
            table_bytes,
            cut_bytes: 0,
            budget: default_memory_budget(),
            tick: 1,
            recent_frames: Default::default(),
            stale_before: 0,
            typical_page_bytes,
            triangle_slots: true,
            protect_from: 0,
            frame_start: 0,
            pages_loaded: 0,
            pages_evicted: 0,
            refusals: 0,
            refused_recently: 0,
            loader,
            awaited: vec![NOT_AWAITED; page_count],
            pending_pages: 0,
            pending_list: Vec::new(),
            asked_in: vec![0; if background { page_count } else { 0 }],
            frames: 0,
            pending_ahead: 0,
            page_errors: Vec::new(),
            loaded: Vec::new(),
            scratch: empty_page(),
            children_scratch: Vec::new(),
            starts_scratch: Vec::new(),
            siblings_scratch: Vec::new(),
            signatures_scratch: Vec::new(),
            candidates_scratch: Vec::new(),
        };
        store.load_node(0)?;
        let root = store.node(0);
        if root.leaf_begin != 0 || root.leaf_end != store.vertex_count {
            return Err(VdtError::invalid(
                "node 0",
                "the root does not cover every vertex",
            ));
        }
        // The root is always on or above the boundary.
        store.set_state(0, crate::cut::NodeState::Boundary);
        Ok(store)
    }

    /// Stops keeping a cut slot per resident triangle (for a cut that keeps no slots,
    /// [`crate::CornerTracking::Ranks`]): pages already resident give theirs back, and pages
    /// are counted without them from now on.
    pub(crate) fn drop_triangle_slots(&mut self) {
        self.triangle_slots = false;
        let pages = self.page_first_node.len().max(1);
        self.typical_page_bytes = ResidentPage::bytes_for(
            (self.node_count as usize).div_ceil(pages),
            (self.triangle_count as usize).div_ceil(pages),
            false,
        );
        for page in self.pages.iter_mut().flatten() {
            page.triangle_slot = Vec::new();
            let freed = page.bytes - page.counted_bytes();
            page.bytes -= freed;
            self.page_bytes -= freed;
            if page.pins == 0 {
                self.evictable_bytes -= freed;
            }
        }
    }

    /// Sets the memory budget in bytes ([`u64::MAX`]: none). Takes effect as pages arrive and
    /// at the next [`NodeStore::evict_to_budget`].
    pub fn set_memory_budget(&mut self, bytes: u64) {
        self.budget = bytes;
    }

    /// The memory budget in bytes.
    pub fn memory_budget(&self) -> u64 {
        self.budget
    }

    /// Tells the store how many bytes the cut's own arrays hold, so that the budget covers
    /// them too.
    pub fn set_cut_bytes(&mut self, bytes: u64) {
        self.cut_bytes = bytes;
    }

    /// Bytes held now (pages, tables and the cut's arrays).
    pub fn resident_bytes(&self) -> u64 {
        self.page_bytes + self.table_bytes + self.cut_bytes
    }

    /// Memory and paging figures.
    pub fn memory(&self) -> MemoryStats {
        MemoryStats {
            resident_bytes: self.resident_bytes(),
            pinned_bytes: self.page_bytes - self.evictable_bytes,
            budget_bytes: self.budget,
            pages_resident: self.pages.len() as u32 - self.free_page_slots.len() as u32,
            pages_total: self.page_state.len() as u32,
            pages_loaded: self.pages_loaded,
            pages_evicted: self.pages_evicted,
            pages_pending: self.pending_pages,
            refusals: self.refusals,
        }
    }

    /// Bytes that eviction cannot give back: pinned pages, the tables and the cut's arrays.
    pub fn pinned_total(&self) -> u64 {
        self.resident_bytes() - self.evictable_bytes
    }

    /// Whether [`NodeStore::pinned_total`] is over the budget.
    pub fn over_budget_pinned(&self) -> bool {
        self.pinned_total() > self.budget
    }

    /// Pages (and growth steps of the cut) refused since the last call that would not have
    /// fitted even with every unpinned page evicted: the cut outgrowing the budget.
    pub fn take_refused(&mut self) -> u32 {
        std::mem::take(&mut self.refused_recently)
    }

    /// Marks the start of a frame: pages that arrived or were unpinned since the start of
    /// the previous one are kept from eviction through this frame.
    pub fn begin_frame(&mut self) {
        // Whoever wanted the last frame's arrivals has taken them by now.
        self.loaded.clear();
        self.frames = self.frames.wrapping_add(1);
        self.protect_from = self.frame_start;
        self.frame_start = self.tick;
        if self.recent_frames.len() == STALE_FRAMES {
            self.stale_before = self.recent_frames.pop_front().unwrap_or(0);
        }
        self.recent_frames.push_back(self.tick);
    }

    /// Whether a page fetched ahead of need could be taken in now: there is room, or an
    /// unpinned page the cut has not used for [`STALE_FRAMES`] frames to give it. Pages
    /// fetched ahead and not yet used never make room for others fetched ahead, so that
    /// fetching ahead cannot churn the cache; when it is full of pages the cut used lately,
    /// fetching ahead waits.
    fn room_ahead_of_need(&self, bytes: u64) -> bool {
        self.resident_bytes() + bytes <= self.limit()
            || self
                .evictable
                .range((1, 0)..)
                .next()
                .is_some_and(|&(stamp, _)| stamp < self.stale_before)
    }

    /// Makes room for a page fetched ahead of need by evicting stale pages only (see
    /// [`NodeStore::room_ahead_of_need`]).
    fn make_room_ahead_of_need(&mut self, bytes: u64) -> bool {
        while self.resident_bytes() + bytes > self.limit() {
            match self.evictable.range((1, 0)..).next() {
                Some(&(stamp, page)) if stamp < self.stale_before => self.evict(page),
                _ => return false,
            }
        }
        true
    }

    /// What arrivals and the cut's growth are held to: a sixteenth of the budget stays free
    /// for what a frame's changes add to the cut's journal and change sets before the frame
    /// ends (they are counted, but grow by push, not by asking): the budget then holds at
    /// every frame's end.
    fn limit(&self) -> u64 {
        self.budget - self.budget / 16
    }

    /// Evicts unpinned pages, oldest first, until the store is within its budget or only
    /// pinned pages are left. Returns how many it evicted. (Pages kept from eviction to make
    /// room for others, see the type's documentation, are evicted here too: over the budget,
    /// nothing else can give.)
    pub fn evict_to_budget(&mut self) -> u32 {
        let mut evicted = 0;
        while self.resident_bytes() > self.budget {
            let Some(&(_, page)) = self.evictable.iter().next() else {
                break;
            };
            self.evict(page);
            evicted += 1;
        }
        evicted
    }

    /// Makes room for `bytes` more by evicting unpinned pages stamped before
    /// `protect_from`, oldest first, never the pages in `keep`. False if it cannot.
    fn make_room(&mut self, bytes: u64, keep: &std::ops::RangeInclusive<u32>) -> bool {
        let limit = self.limit();
        while self.resident_bytes() + bytes > limit {
            let candidate = self
                .evictable
                .range(..(self.protect_from, 0))
                .find(|(_, page)| !keep.contains(page))
                .map(|&(_, page)| page);
            match candidate {
                Some(page) => self.evict(page),
                None => return false,
            }
        }
        true
    }

    /// Makes room for `bytes` more of the cut's own arrays, as for a page: by evicting
    /// unpinned pages that have had their frame. False (and counted as a refusal, so the
    /// effective threshold rises) when it cannot.
    /// The pages of `unfolding`'s children are kept: the unfold that asked needs them.
    pub(crate) fn make_room_for_cut(&mut self, bytes: u64, unfolding: u32) -> bool {
        let keep = self.children_pages(unfolding).unwrap_or(NO_PAGES);
        let room = self.make_room(bytes, &keep);
        if !room {
            self.refuse(bytes);
        }
        room
    }

    fn evict(&mut self, index: u32) {
        let slot = std::mem::replace(&mut self.page_slot[index as usize], NIL);
        let page = self.pages[slot as usize]
            .take()
            .expect("an evictable page is resident");
        debug_assert_eq!(page.pins, 0, "page {index} is pinned");
        self.evictable.remove(&(page.stamp, index));
        self.evictable_bytes -= page.bytes;
        self.page_bytes -= page.bytes;
        self.free_page_slots.push(slot);
        self.page_state[index as usize] = PageState::Absent;
        self.pages_evicted += 1;
    }

    /// Number of nodes in the tree.
    pub fn node_count(&self) -> u32 {
        self.node_count
    }

    /// Number of original vertices (leaves).
    pub fn vertex_count(&self) -> u32 {
        self.vertex_count
    }

    /// Number of triangles in the tree.
    pub fn triangle_count(&self) -> u32 {
        self.triangle_count
    }

    /// The node id ranges of the pages loaded since the last call: what a renderer must upload
    /// before it draws triangles whose corners lie there.
    pub fn take_loaded(&mut self) -> Vec<std::ops::Range<u32>> {
        std::mem::take(&mut self.loaded)
    }

    /// Pages resident now, and pages in the file.
    pub fn pages_resident(&self) -> (u32, u32) {
        let memory = self.memory();
        (memory.pages_resident, memory.pages_total)
    }

    /// Pages asked of the background loader for nodes that wait to unfold, not yet
    /// delivered (0 when loading is synchronous). Pages fetched ahead of need are not counted:
    /// no node waits for them.
    pub fn pending_pages(&self) -> u32 {
        self.pending_pages
    }

    /// Errors of pages the background loader could not read since the last call, each
    /// reported once (the error names the page); those pages' nodes stay folded.
    pub fn take_page_errors(&mut self) -> Vec<VdtError> {
        std::mem::take(&mut self.page_errors)
    }

    /// The page holding node `id` (resident or not), if any ([`page_from_block`]).
    #[inline]
    pub(crate) fn page_of(&self, id: u32) -> Option<u32> {
        if id >= self.node_count {
            return None;
        }
        Some(page_from_block(
            &self.page_first_node,
            &self.block_page,
            self.block_shift,
            id,
        ) as u32)
    }

    /// The page holding triangle `index`, if any.
    fn page_of_triangle(&self, index: u32) -> Option<u32> {
        if index >= self.triangle_count {
            return None;
        }
        // Pages without triangles share their successor's first triangle: the last page
        // starting at or before `index` is the one that holds it.
        let page = self.page_first_triangle.partition_point(|&f| f <= index);
        page.checked_sub(1).map(|p| p as u32)
    }

    /// Where resident node `id` lives, or `None` if its page is not resident.
    #[inline]
    fn place(&self, id: u32) -> Option<Place> {
        let page = self.page_of(id)?;
        let slot = self.page_slot[page as usize];
        (slot != NIL).then(|| Place {
            slot,
            local: id - self.page_first_node[page as usize],
        })
    }

    #[inline]
    fn resident(&self, slot: u32) -> &ResidentPage {
        // Slots handed out by `place` hold a page until it is evicted, which needs `&mut`.
        self.pages[slot as usize]
            .as_ref()
            .expect("a placed slot is resident")
    }

    #[inline]
    fn resident_mut(&mut self, slot: u32) -> &mut ResidentPage {
        self.pages[slot as usize]
            .as_mut()
            .expect("a placed slot is resident")
    }

    /// The place of node `id`, which must be resident.
    #[inline]
    #[track_caller]
    fn expect_place(&self, id: u32) -> Place {
        match self.place(id) {
            Some(place) => place,
            None => panic!("node {id} was read while its page is not resident"),
        }
    }

    /// Whether node `id`'s page is resident.
    pub fn is_resident(&self, id: u32) -> bool {
        self.place(id).is_some()
    }

    /// The cut's label of node `id` ([`NodeLabel::INACTIVE`] if its page is not resident).
    #[inline]
    pub(crate) fn label(&self, id: u32) -> NodeLabel {
        match self.place(id) {
            Some(p) => self.resident(p.slot).labels[p.local as usize],
            None => NodeLabel::INACTIVE,
        }
    }

    /// The state of node `id` (inactive if its page is not resident).
    #[inline]
    pub fn state(&self, id: u32) -> crate::cut::NodeState {
        self.label(id).state
    }

    /// The cut's label of node `id` if its page is resident (a page is evicted only once
    /// every node in it is inactive).
    #[inline]
    pub(crate) fn label_if_resident_mut(&mut self, id: u32) -> Option<&mut NodeLabel> {
        let p = self.place(id)?;
        Some(&mut self.resident_mut(p.slot).labels[p.local as usize])
    }

    /// The cut's label of resident node `id`, to change anything but its state.
    #[inline]
    #[track_caller]
    pub(crate) fn label_mut(&mut self, id: u32) -> &mut NodeLabel {
        let p = self.expect_place(id);
        &mut self.resident_mut(p.slot).labels[p.local as usize]
    }

    /// Sets resident node `id`'s state, pinning its page while any of its nodes is on or
    /// above the boundary. Returns the state it had.
    #[track_caller]
    pub(crate) fn set_state(
        &mut self,
        id: u32,
        state: crate::cut::NodeState,
    ) -> crate::cut::NodeState {
        let mut before = state;
        self.set_run_state(id, 1, state, |_, was, _| before = was);
        before
    }

    /// [`NodeStore::set_state`] for the `count` resident nodes from `first` (a node's
    /// children, say), with one page look-up per page they span instead of one per node. `changed` sees each node's id, its state before and its label
    /// after.
    #[track_caller]
    pub(crate) fn set_run_state(
        &mut self,
        first: u32,
        count: u32,
        state: crate::cut::NodeState,
        mut changed: impl FnMut(u32, crate::cut::NodeState, &mut NodeLabel),
    ) {
        let end = first + count;
        let mut id = first;
        while id < end {
            let p = self.expect_place(id);
            let Self {
                pages,
                evictable,
                evictable_bytes,
                tick,
                ..
            } = self;
            let page = pages[p.slot as usize]
                .as_mut()
                .expect("a placed slot is resident");
            let local = p.local as usize;
            let in_page = ((end - id) as usize).min(page.labels.len() - local);
            for k in 0..in_page {
                let label = &mut page.labels[local + k];
                let was = std::mem::replace(&mut label.state, state);
                changed(id + k as u32, was, label);
                page.repin(was, state, evictable, evictable_bytes, tick);
            }
            id += in_page as u32;
        }
    }

    /// Numbers of boundary and active nodes over the resident pages (for [`crate::Cut::check`]).
    pub(crate) fn label_counts(&self) -> [usize; 2] {
        use crate::cut::NodeState::{Active, Boundary};
        let mut counts = [0, 0];
        for label in self.pages.iter().flatten().flat_map(|p| &p.labels) {
            match label.state {
                Boundary => counts[0] += 1,
                Active => counts[1] += 1,
                _ => {}
            }
        }
        counts
    }

    /// Checks the paging invariants: every page's pin count is its nodes on or above the
    /// boundary, exactly the unpinned pages are evictable, and the byte counts add up.
    pub(crate) fn check_pins(&self) -> Result<(), String> {
        let (mut bytes, mut evictable_bytes, mut evictable) = (0, 0, 0);
        for (slot, page) in self.pages.iter().enumerate() {
            let Some(page) = page else { continue };
            let pinned = page
                .labels
                .iter()
                .filter(|l| l.state != crate::cut::NodeState::Inactive)
                .count() as u32;
            if pinned != page.pins {
                return Err(format!(
                    "page {} counts {} pins but holds {pinned} nodes of the cut",
                    page.index, page.pins
                ));
            }
            if self.page_slot[page.index as usize] != slot as u32
                || self.page_state[page.index as usize] != PageState::Resident
            {
                return Err(format!("page {} is resident out of its slot", page.index));
            }
            let listed = self.evictable.contains(&(page.stamp, page.index));
            if listed != (page.pins == 0) {
                return Err(format!(
                    "page {} is {}evictable with {} pins",
                    page.index,
                    if listed { "" } else { "not " },
                    page.pins
                ));
            }
            bytes += page.bytes;
            if listed {
                evictable_bytes += page.bytes;
                evictable += 1;
            }
        }
        if bytes != self.page_bytes
            || evictable_bytes != self.evictable_bytes
            || evictable != self.evictable.len()
        {
            return Err("the store's byte counts are off".into());
        }
        Ok(())
    }

    /// The cut's slot of active triangle `index` of node `owner` (whose page is resident),
    /// or [`NIL`].
    #[inline]
    pub(crate) fn triangle_slot(&self, owner: u32, index: u32) -> u32 {
        let p = self.expect_place(owner);
        let page = self.resident(p.slot);
        page.triangle_slot[(index - page.first_triangle) as usize]
    }

    /// Records the cut's slot of triangle `index` of node `owner` ([`NIL`]: not active).
    #[inline]
    pub(crate) fn set_triangle_slot(&mut self, owner: u32, index: u32, slot: u32) {
        let p = self.expect_place(owner);
        let page = self.resident_mut(p.slot);
        let local = (index - page.first_triangle) as usize;
        page.triangle_slot[local] = slot;
    }

    /// Whether `id`'s children are loaded and checked, so that it may unfold now. With
    /// synchronous loading this loads them (and is `false` when they do not fit in the
    /// budget); with background loading it never reads a page: `false` means ask with
    /// [`NodeStore::request_children`] and try again after they arrive.
    pub fn children_available(&mut self, id: u32) -> Result<bool, VdtError> {
        if self.children_resident(id) && self.is_checked(id) {
            return Ok(true);
        }
        if self.loader.is_some() && !self.children_resident(id) {
            return Ok(false);
        }
        match self.load_children(id) {
            Ok(()) => Ok(true),
            Err(LoadError::OverBudget) => Ok(false),
            Err(LoadError::File(e)) => Err(e),
        }
    }

    /// Whether resident node `id` is known to have no subtris that can repeat
    /// ([`NodeStore::mark_unrepeated`]).
    #[inline]
    pub(crate) fn is_unrepeated(&self, id: u32) -> bool {
        let p = self.expect_place(id);
        self.resident(p.slot).unrepeated[(p.local / 64) as usize] & (1 << (p.local % 64)) != 0
    }

    /// Records that no two subtris of resident node `id` can repeat, so that its next unfold
    /// need not group them again.
    #[inline]
    pub(crate) fn mark_unrepeated(&mut self, id: u32) {
        let p = self.expect_place(id);
        self.resident_mut(p.slot).unrepeated[(p.local / 64) as usize] |= 1 << (p.local % 64);
    }

    /// Number of pages in the file.
    pub(crate) fn page_count(&self) -> u32 {
        self.page_first_node.len() as u32
    }

    /// The first node id of page `index`.
    #[inline]
    pub(crate) fn page_first(&self, index: u32) -> u32 {
        self.page_first_node[index as usize]
    }

    /// The id after page `index`'s last node.
    pub(crate) fn page_end(&self, index: u32) -> u32 {
        self.page_first_node
            .get(index as usize + 1)
            .copied()
            .unwrap_or(self.node_count)
    }

    /// What the criteria read of resident page `index`'s nodes, side by side, or `None` when
    /// the page is not resident.
    #[inline]
    pub(crate) fn tested_page(&self, index: u32) -> Option<TestedPage<'_>> {
        let slot = *self.page_slot.get(index as usize)?;
        if slot == NIL {
            return None;
        }
        let page = self.resident(slot);
        Some(TestedPage {
            first: self.page_first_node[index as usize],
            hot: &page.hot,
            shape: &page.shape,
            checked: &page.checked,
        })
    }

    fn is_checked(&self, id: u32) -> bool {
        let p = self.expect_place(id);
        self.resident(p.slot).checked[(p.local / 64) as usize] & (1 << (p.local % 64)) != 0
    }

    /// The pages holding `id`'s children (one page, usually), for a node with children.
    ///
    /// Every page from the first child's to the last child's: a hostile file can put a page
    /// of a few nodes between two siblings, so the range, not its two ends, is what the
    /// children need.
    fn children_pages(&self, id: u32) -> Option<std::ops::RangeInclusive<u32>> {
        let hot = self.hot(id);
        if hot.child_count == 0 {
            return None;
        }
        let last = hot.first_child + hot.child_count - 1;
        Some(self.page_of(hot.first_child)?..=self.page_of(last)?)
    }

    /// Whether `id`'s children's pages are resident, without reading any. With synchronous
    /// loading an unfold reads them itself, so this is about residency alone.
    pub fn children_resident(&self, id: u32) -> bool {
        // Usually every child is in one page: two look-ups by block say so, without the
        // searches of the page directory below.
        if let Some(p) = self.place(id) {
            let hot = &self.resident(p.slot).hot[p.local as usize];
            if hot.child_count == 0 {
                return true;
            }
            let last = hot.first_child + hot.child_count - 1;
            if let (Some(a), Some(b)) = (self.place(hot.first_child), self.place(last))
                && a.slot == b.slot
            {
                return true;
            }
        }
        self.children_pages(id).is_none_or(|mut pages| {
            pages.all(|p| self.page_state[p as usize] == PageState::Resident)
        })
    }

    /// Asks the background loader for the pages of `id`'s children that are not resident,
    /// with `priority` (higher is more urgent: the node's error in pixels past its
    /// threshold, say). Pages already asked for keep the higher of their priorities; pages
    /// that failed are not asked for again. Returns whether the children can still arrive:
    /// false when a page they need failed (the node stays folded for good) or when loading
    /// is synchronous.
    ///
    /// A page already asked for is queued again only when its priority at least doubles, so
    /// a node waiting many frames does not grow the loader's queue by a request each frame.
    pub fn request_children(&mut self, id: u32, priority: f32) -> bool {
        if self.loader.is_none() {
            return false;
        }
        let Some(pages) = self.children_pages(id) else {
            return false;
        };
        let priority = priority.max(0.0);
        let mut arriving = true;
        for page in pages {
            let p = page as usize;
            match self.page_state[p] {
                PageState::Resident => continue,
                PageState::Failed => {
                    arriving = false;
                    continue;
                }
                PageState::Absent => {}
            }
            self.asked_in[p] = self.frames;
            let awaited = self.awaited[p];
            if awaited >= 0.0 && priority < 2.0 * awaited.max(f32::MIN_POSITIVE) {
                continue;
            }
            let fresh = awaited == NOT_AWAITED;
            if fresh || awaited < 0.0 {
                // Asked for afresh, or fetched ahead and needed now.
                self.pending_pages += 1;
                self.pending_ahead -= u32::from(!fresh);
                self.pending_list.push(page);
            }
            self.awaited[p] = priority;
            if let Some(loader) = &self.loader {
                loader.request(page, priority, fresh);
            }
        }
        arriving
    }

    /// Asks the background loader, ahead of need, for the pages of `id`'s children that are
    /// neither resident nor asked for, with `priority` below zero (closer to zero: sooner;
    /// below every page a node is waiting for). Nothing with synchronous loading.
    pub fn prefetch_children(&mut self, id: u32, priority: f32) {
        if self.loader.is_none() {
            return;
        }
        let Some(pages) = self.children_pages(id) else {
            return;
        };
        let priority = if priority.is_nan() {
            -1.0
        } else {
            priority.clamp(-1.0, -f32::MIN_POSITIVE)
        };
        // Room for what is already on its way too, and never more than a few pages at once:
        // a frame's worth of near-threshold nodes must not queue hundreds of pages that
        // will not fit.
        let in_flight = u64::from(self.pending_ahead + 1) * self.typical_page_bytes;
        if self.pending_ahead >= MAX_AHEAD || !self.room_ahead_of_need(in_flight) {
            return;
        }
        for page in pages {
            let p = page as usize;
            if self.page_state[p] == PageState::Absent && self.awaited[p] == NOT_AWAITED {
                self.awaited[p] = priority;
                self.pending_ahead += 1;
                if let Some(loader) = &self.loader {
                    loader.request(page, priority, true);
                }
            }
        }
    }

    /// Whether pages are loaded by background threads.
    pub fn loads_in_background(&self) -> bool {
        self.loader.is_some()
    }

    /// Takes in the pages the background loader has delivered since the last call, without
    /// waiting; returns how many. Their nodes can unfold from now on.
    pub fn poll(&mut self) -> u32 {
        let mut delivered = Vec::new();
        if let Some(loader) = &self.loader {
            delivered.extend(std::iter::from_fn(|| loader.try_next()));
        }
        let count = delivered.len() as u32;
        let mut received = Vec::with_capacity(delivered.len());
        for (index, result) in delivered {
            self.deliver(index, result);
            received.push(index);
        }
        if let Some(loader) = &self.loader {
            loader.received(&received);
        }
        count
    }

    /// Cancels the pages asked for by waiting nodes that no node asked for again in this
    /// frame: the nodes that wanted them unfolded, folded away or stopped needing them (the
    /// camera moved, the effective threshold rose), and loading them would only delay the
    /// pages the cut needs now. A node still waiting asks again every frame, so its page
    /// stays asked for.
    pub(crate) fn cancel_unasked(&mut self) {
        let Some(loader) = &self.loader else {
            return;
        };
        let mut cancelled = Vec::new();
        let frame = self.frames;
        let (awaited, asked_in) = (&mut self.awaited, &self.asked_in);
        let mut pending = self.pending_pages;
        self.pending_list.retain(|&page| {
            let p = page as usize;
            if awaited[p] < 0.0 {
                return false; // Delivered, or listed twice and cancelled already.
            }
            if asked_in[p] == frame {
                return true;
            }
            awaited[p] = NOT_AWAITED;
            pending -= 1;
            cancelled.push(page);
            false
        });
        self.pending_pages = pending;
        loader.cancel(&cancelled);
    }

    /// The bytes the cut would hold with every page it waits for: the pinned pages and
    /// the pages asked for by waiting nodes, at the file's average page size (a lower bound
    /// of what it needs: the waiting nodes' children may need further pages below).
    pub fn demanded_bytes(&self) -> u64 {
        self.pinned_total() + u64::from(self.pending_pages) * self.typical_page_bytes
    }

    /// What arrivals and the cut's growth are held to: the budget less a sixteenth kept free
    /// for what a frame's changes add to the cut's journal before the frame ends.
    pub fn arrival_limit(&self) -> u64 {
        self.limit()
    }

    /// Hands the background loader the view and threshold of this frame's adjust (`None`:
    /// none, as for a triangle budget) so that it asks for the pages below each page it
    /// decodes that the cut will reach, within the room the budget has for pages nobody
    /// awaits (the `loader` module's "Looking ahead").
    pub(crate) fn foresee(&self, sight: Option<(&crate::criteria::Judge, f32)>) {
        let Some(loader) = &self.loader else {
            return;
        };
        let awaited = u64::from(self.pending_pages + self.pending_ahead);
        let free = self.limit().saturating_sub(self.resident_bytes());
        let room = (free / self.typical_page_bytes.max(1)).saturating_sub(awaited);
        loader.foresee(sight.map(|(judge, t)| crate::loader::Foresight {
            judge: *judge,
            t,
            room: u32::try_from(room).unwrap_or(u32::MAX),
        }));
    }

    /// Waits until every page asked of the background loader (ahead of need, and by the
    /// loader looking ahead, too) has been delivered and takes them in (what a test or a
    /// batch replay does to let loading settle).
    pub fn wait_for_pages(&mut self) {
        loop {
            let Some(loader) = &self.loader else {
                return;
            };
            if self.pending_pages + self.pending_ahead == 0 && !loader.busy() {
                return;
            }
            let Some((index, result)) = loader.wait_next() else {
                return;
            };
            self.deliver(index, result);
            if let Some(loader) = &self.loader {
                loader.received(&[index]);
            }
        }
    }

    fn deliver(&mut self, index: u32, result: Result<Page, VdtError>) {
        let p = index as usize;
        let awaited = std::mem::replace(&mut self.awaited[p], NOT_AWAITED);
        let needed = awaited >= 0.0;
        if needed {
            self.pending_pages -= 1;
        } else if awaited != NOT_AWAITED {
            self.pending_ahead -= 1;
        }
        if self.page_state[p] != PageState::Absent {
            return; // Loaded synchronously meanwhile.
        }
        match result {
            Ok(page) => {
                let bytes = ResidentPage::bytes_for(
                    page.nodes.len(),
                    page.triangles.len(),
                    self.triangle_slots,
                );
                if needed && self.make_room(bytes, &NO_PAGES) {
                    self.install(index, &page, false);
                } else if needed {
                    self.refuse(bytes);
                } else if self.make_room_ahead_of_need(bytes) {
                    self.install(index, &page, true);
                }
                // A page fetched ahead of need that does not fit is dropped: no node waits
                // for it, so the threshold need not rise.
            }
            Err(error) => {
                self.page_state[p] = PageState::Failed;
                self.page_errors.push(error);
            }
        }
    }

    /// Whether room for `bytes` could be made by evicting every unpinned page, protected or
    /// not: a refusal that could not is the cut outgrowing the budget; one that could is
    /// the budget waiting for pages that arrived lately to be used.
    fn could_fit(&self, bytes: u64) -> bool {
        self.pinned_total() + bytes <= self.limit()
    }

    fn refuse(&mut self, bytes: u64) {
        self.refusals += 1;
        if !self.could_fit(bytes) {
            self.refused_recently += 1;
        }
    }

    /// Node `id`, which must be resident ([`NodeStore::load_node`]).
    ///
    /// # Panics
    /// If `id`'s page is not resident.
    #[inline]
    #[track_caller]
    pub fn node(&self, id: u32) -> Node {
        let p = self.expect_place(id);
        let page = self.resident(p.slot);
        let i = p.local as usize;
        let (hot, shape, topology) = (&page.hot[i], &page.shape[i], &page.topology[i]);
        Node {
            proxy: hot.proxy,
            error_radius: hot.error_radius,
            surface_error: topology.surface_error,
            sphere_center: shape.center,
            sphere_radius: shape.radius,
            cone_axis: shape.cone_axis,
            cone_half_angle: topology.cone_half_angle,
            cone_two_sided: topology.cone_two_sided,
            parent: topology.parent,
            first_child: hot.first_child,
            leaf_begin: page.leaf_begin[i],
            leaf_end: topology.leaf_end,
            subtri_begin: topology.subtri_begin,
            subtri_count: topology.subtri_count,
            child_count: hot.child_count as u8,
            depth: topology.depth,
        }
    }

    /// Surface error of resident node `id` ([`Node::surface_error`]).
    #[inline]
    #[track_caller]
    pub fn surface_error(&self, id: u32) -> f32 {
        let p = self.expect_place(id);
        self.resident(p.slot).topology[p.local as usize].surface_error
    }

    /// Parent of resident node `id` ([`NO_NODE`] for the root).
    #[inline]
    #[track_caller]
    pub fn parent(&self, id: u32) -> u32 {
        let p = self.expect_place(id);
        self.resident(p.slot).topology[p.local as usize].parent
    }

    /// The first leaf rank of resident node `id`.
    #[inline]
    pub fn leaf_begin(&self, id: u32) -> u32 {
        let p = self.expect_place(id);
        self.resident(p.slot).leaf_begin[p.local as usize]
    }

    /// True when resident node `id` supports the vertex of leaf rank `rank`.
    #[inline]
    #[track_caller]
    pub fn supports_rank(&self, id: u32, rank: u32) -> bool {
        let p = self.expect_place(id);
        let page = self.resident(p.slot);
        let i = p.local as usize;
        page.leaf_begin[i] <= rank && rank < page.topology[i].leaf_end
    }

    /// The subtris of resident node `id`, as a range of triangle indices.
    #[inline]
    #[track_caller]
    pub fn subtris(&self, id: u32) -> std::ops::Range<u32> {
        let p = self.expect_place(id);
        let t = &self.resident(p.slot).topology[p.local as usize];
        t.subtri_begin..t.subtri_begin + t.subtri_count
    }

    /// Hints that the test data of nodes `first..first + count` will be read soon.
    #[inline]
    pub(crate) fn prefetch_tested(&self, first: u32, count: u32) {
        if let Some((page, range)) = self.page_run(first, count) {
            crate::prefetch::prefetch_range(&page.hot, range.clone());
            crate::prefetch::prefetch_range(&page.shape, range.clone());
            crate::prefetch::prefetch_range(&page.labels, range);
        }
    }

    /// The resident page holding node `first` and the local range of `first..first + count`
    /// within it (cut at the page's end), or `None` when `first` is not resident.
    #[inline]
    fn page_run(&self, first: u32, count: u32) -> Option<(&ResidentPage, std::ops::Range<usize>)> {
        let p = self.place(first)?;
        let page = self.resident(p.slot);
        let begin = p.local as usize;
        Some((page, begin..(begin + count as usize).min(page.labels.len())))
    }

    /// The per-frame test data of resident node `id`.
    #[inline]
    #[track_caller]
    pub fn hot(&self, id: u32) -> &Hot {
        let p = self.expect_place(id);
        &self.resident(p.slot).hot[p.local as usize]
    }

    /// Node `id`'s parent, children and subtri count, or `None` if its page is not resident
    /// (one page look-up, two records).
    #[inline]
    pub(crate) fn family(&self, id: u32) -> Option<Family> {
        let p = self.place(id)?;
        let page = self.resident(p.slot);
        let i = p.local as usize;
        let (hot, topology) = (&page.hot[i], &page.topology[i]);
        Some(Family {
            parent: topology.parent,
            first_child: hot.first_child,
            child_count: hot.child_count,
            subtri_count: topology.subtri_count,
        })
    }

    /// What the criteria read of resident node `id`.
    #[inline]
    #[track_caller]
    pub fn tested(&self, id: u32) -> Tested<'_> {
        let p = self.expect_place(id);
        let page = self.resident(p.slot);
        Tested {
            hot: &page.hot[p.local as usize],
            shape: &page.shape[p.local as usize],
        }
    }

    /// Resident node `id`'s label and test data together (one look-up).
    #[inline]
    #[track_caller]
    pub(crate) fn labelled(&self, id: u32) -> (NodeLabel, Tested<'_>) {
        let p = self.expect_place(id);
        let page = self.resident(p.slot);
        let i = p.local as usize;
        (
            page.labels[i],
            Tested {
                hot: &page.hot[i],
                shape: &page.shape[i],
            },
        )
    }

    /// The resident page holding triangle `index`, and the triangle's index in it.
    #[track_caller]
    fn triangle_place(&self, index: u32) -> (&ResidentPage, usize) {
        let page = self
            .page_of_triangle(index)
            .map(|p| self.page_slot[p as usize])
            .filter(|&slot| slot != NIL);
        match page {
            Some(slot) => {
                let page = self.resident(slot);
                (page, (index - page.first_triangle) as usize)
            }
            None => panic!("triangle {index} was read while its page is not resident"),
        }
    }

    /// Corners (leaf ranks) of triangle `index`; its owner's page must be resident (it is
    /// while the triangle is active).
    #[inline]
    #[track_caller]
    pub fn triangle_corners(&self, index: u32) -> [u32; 3] {
        let (page, local) = self.triangle_place(index);
        page.corners[local]
    }

    /// Part id of triangle `index`; its owner's page must be resident.
    #[inline]
    #[track_caller]
    pub fn triangle_part(&self, index: u32) -> u32 {
        let (page, local) = self.triangle_place(index);
        page.parts[local]
    }

    /// Hints that the labels of nodes `first..first + count` (resident or not; one page's
    /// run) will be read soon.
    #[inline]
    pub(crate) fn prefetch_labels(&self, first: u32, count: u32) {
        if let Some((page, range)) = self.page_run(first, count) {
            crate::prefetch::prefetch_range(&page.labels, range);
        }
    }

    /// Hints that the corners of resident node `id`'s subtris will be read soon.
    #[inline]
    pub(crate) fn prefetch_subtri_corners(&self, id: u32) {
        let corners = self.subtri_corners(id);
        crate::prefetch::prefetch_range(corners, 0..corners.len());
    }

    /// Corners of the subtris of resident node `id`, in triangle order.
    pub(crate) fn subtri_corners(&self, id: u32) -> &[[u32; 3]] {
        let p = self.expect_place(id);
        let page = self.resident(p.slot);
        let t = &page.topology[p.local as usize];
        let begin = (t.subtri_begin - page.first_triangle) as usize;
        &page.corners[begin..begin + t.subtri_count as usize]
    }

    /// Makes sure node `id` and its subtris are resident, reading its page on the calling
    /// thread if need be, whatever the loading (for callers that need the data now: exports,
    /// measurements, unfold-all). A page that does not fit in the budget is read anyway when
    /// nothing else can give: the caller needs it now. It is evicted again as soon as it is
    /// not pinned and the budget asks.
    pub fn load_node(&mut self, id: u32) -> Result<(), VdtError> {
        match self.page_of(id) {
            Some(index) if self.page_state[index as usize] == PageState::Resident => Ok(()),
            Some(index) => match self.load_page(index, &NO_PAGES, false) {
                Err(LoadError::File(e)) => Err(e),
                _ => Ok(()),
            },
            None => Err(VdtError::invalid("node id", format!("{id} has no page"))),
        }
    }

    /// Makes sure every child of `id` is resident (children may straddle a page boundary)
    /// and that they partition `id`'s leaf range in order, as the traversal assumes, and
    /// that their bounds nest in `id`'s as far as quantisation allows ([`VdtError::Bounds`]
    /// otherwise, naming the child's page). The reader validates each page on its own; this
    /// is the part of the tree that spans pages, checked where it is first relied on unless the
    /// arrival of a page checked it before (`NodeStore::establish_on_arrival`).
    ///
    /// Fails with [`LoadError::OverBudget`] when the children's pages do not fit in the
    /// memory budget.
    pub fn load_children(&mut self, id: u32) -> Result<(), LoadError> {
        let Some(pages) = self.children_pages(id) else {
            return Ok(());
        };
        for page in pages.clone() {
            if self.page_state[page as usize] != PageState::Resident {
                self.load_page(page, &pages, true)?;
            }
        }
        if self.is_checked(id) {
            return Ok(());
        }
        self.check_and_bound(id)?;
        Ok(())
    }

    /// [`NodeStore::load_children`]'s checks of resident node `id`'s resident children, and
    /// then its group bound ([`Hot::group_radius`], [`Hot::group_error`]); marks the node
    /// checked when they pass.
    fn check_and_bound(&mut self, id: u32) -> Result<(), VdtError> {
        // The children's records, read a page's run at a time rather than a look-up each.
        let mut children = std::mem::take(&mut self.children_scratch);
        self.gather_children(id, &mut children);
        let checked = self.check_children(id, &children);
        let node = self.node(id);
        let center = glam::Vec3::from(node.proxy);
        let (mut radius, mut error) = (0.0f32, 0.0f32);
        for child in &children {
            let child = &child.hot;
            radius =
                radius.max(center.distance(glam::Vec3::from(child.proxy)) + child.error_radius);
            error = error.max(child.error_radius);
        }
        self.children_scratch = children;
        checked?;
        // Widened by a few ulps so the ball holds the children's balls despite rounding.
        let p = self.expect_place(id);
        let page = self.resident_mut(p.slot);
        let hot = &mut page.hot[p.local as usize];
        hot.group_radius = radius * (1.0 + 4.0 * f32::EPSILON);
        hot.group_error = error;
        page.checked[(p.local / 64) as usize] |= 1 << (p.local % 64);
        Ok(())
    }

    /// What a node's first unfold needs to know of the tree, established when a page
    /// arrives instead, for the parents of the page's sibling groups and for the page's own
    /// inner nodes, wherever every page it takes is resident: the checks of its children and
    /// its group bound ([`NodeStore::load_children`]), and whether two of its subtris can
    /// repeat ([`NodeStore::mark_unrepeated`]). The arriving page's records are in cache here,
    /// where a fly-through's unfolds, nearly all first ones, found them cold. A node left out
    /// (a page it takes is not resident, or its children fail the checks) is left to its
    /// first unfold, which reports any failure.
    fn establish_on_arrival(&mut self, index: u32) {
        let slot = self.page_slot[index as usize];
        let first = self.page_first_node[index as usize];
        let count = self.resident(slot).hot.len() as u32;
        let mut previous = NIL;
        for local in 0..count as usize {
            let parent = self.resident(slot).topology[local].parent;
            if parent != previous {
                previous = parent;
                self.establish(parent);
            }
        }
        for id in first..first + count {
            self.establish(id);
        }
    }

    /// [`NodeStore::establish_on_arrival`] for node `id` (any id: one not resident, or with
    /// pages it takes not resident, is left alone).
    fn establish(&mut self, id: u32) {
        let Some(p) = self.place(id) else {
            return;
        };
        let page = self.resident(p.slot);
        let (children, subtris) = (
            page.hot[p.local as usize].child_count,
            page.topology[p.local as usize].subtri_count,
        );
        if children == 0 || !self.children_resident(id) {
            return;
        }
        if !self.is_checked(id) && self.check_and_bound(id).is_err() {
            return;
        }
        // Only rank tracking reads the mark (a store keeping triangle slots serves the
        // others).
        if !self.triangle_slots
            && subtris > 1
            && !self.is_unrepeated(id)
            && self.subtris_cannot_repeat(id)
        {
            self.mark_unrepeated(id);
        }
    }

    /// True when no two subtris of resident node `id` (checked, its children resident) can
    /// repeat: none share their [`crate::repeats::OwnCut::signature`], or those that do have
    /// different corners in `id`'s own cut ([`crate::repeats::groups_of`] finds no group);
    /// false also when a page that takes is not resident, or a node on the way is not checked
    /// (its structure is then not known to hold).
    fn subtris_cannot_repeat(&mut self, id: u32) -> bool {
        let node = self.node(id);
        let mut starts = std::mem::take(&mut self.starts_scratch);
        let mut siblings = std::mem::take(&mut self.siblings_scratch);
        let mut signatures = std::mem::take(&mut self.signatures_scratch);
        let mut candidates = std::mem::take(&mut self.candidates_scratch);
        starts.clear();
        siblings.clear();
        let mut known = true;
        let (mut parent_ranks, mut parent_first) = (0..0, 0);
        if node.parent != NO_NODE {
            if self.place(node.parent).is_some()
                && self.is_checked(node.parent)
                && self.children_resident(node.parent)
            {
                let parent = self.node(node.parent);
                parent_ranks = parent.leaf_begin..parent.leaf_end;
                parent_first = parent.first_child;
                self.children_leaf_begins(
                    parent.first_child,
                    u32::from(parent.child_count),
                    &mut siblings,
                );
            } else {
                known = false;
            }
        }
        let mut cannot = false;
        if known {
            self.children_leaf_begins(node.first_child, u32::from(node.child_count), &mut starts);
            let own_cut = crate::repeats::OwnCut {
                node: &node,
                children: &starts,
                parent_ranks,
                parent_first,
                siblings: &siblings,
            };
            cannot = own_cut
                .groups(
                    0,
                    self.subtri_corners(id),
                    |r| self.own_cut_corner(r, id),
                    &mut signatures,
                    &mut candidates,
                )
                .is_some_and(|groups| groups.is_empty());
        }
        self.starts_scratch = starts;
        self.siblings_scratch = siblings;
        self.signatures_scratch = signatures;
        self.candidates_scratch = candidates;
        cannot
    }

    /// Where leaf rank `rank`, outside resident node `near`, stands in `near`'s own cut: the
    /// child holding it of the first ancestor that supports it. `None` when an ancestor on
    /// the way is not resident or not checked, or its children are not resident. (Parents
    /// precede their children, which the reader checks, so the walk ends.)
    fn own_cut_corner(&self, rank: u32, near: u32) -> Option<u32> {
        let mut node = near;
        loop {
            let parent = self.parent(node);
            if parent == NO_NODE
                || self.place(parent).is_none()
                || !self.is_checked(parent)
                || !self.children_resident(parent)
            {
                return None;
            }
            if self.supports_rank(parent, rank) {
                return Some(self.child_supporting(parent, rank));
            }
            node = parent;
        }
    }

    /// The records of resident node `id`'s resident children, in order, into `out`: one
    /// look-up per page they span.
    fn gather_children(&self, id: u32, out: &mut Vec<ChildRecords>) {
        out.clear();
        let hot = self.hot(id);
        let (mut child, end) = (hot.first_child, hot.first_child + hot.child_count);
        while child < end {
            let p = self.expect_place(child);
            let page = self.resident(p.slot);
            let local = p.local as usize;
            let in_page = ((end - child) as usize).min(page.hot.len() - local);
            out.extend((local..local + in_page).map(|i| ChildRecords {
                hot: page.hot[i],
                shape: page.shape[i],
                leaf_begin: page.leaf_begin[i],
                topology: page.topology[i],
            }));
            child += in_page as u32;
        }
    }

    /// The structural checks of [`NodeStore::load_children`], on the records of `id`'s
    /// children ([`NodeStore::gather_children`]), then the bounds.
    fn check_children(&self, id: u32, children: &[ChildRecords]) -> Result<(), VdtError> {
        let node = self.node(id);
        let mut next_rank = node.leaf_begin;
        for (c, child) in node.children().zip(children) {
            let (leaf_begin, topology) = (child.leaf_begin, &child.topology);
            // In u32: a hostile node at the deepest u16 depth must fail, not overflow.
            if topology.parent != id
                || leaf_begin != next_rank
                || u32::from(topology.depth) != u32::from(node.depth) + 1
            {
                return Err(VdtError::invalid(
                    format!("node {c}"),
                    format!("is not a well-formed child of node {id}"),
                ));
            }
            next_rank = topology.leaf_end;
        }
        if next_rank != node.leaf_end {
            return Err(VdtError::invalid(
                format!("node {id}"),
                "its children do not cover its leaf range",
            ));
        }
        self.check_child_bounds(id, children)
    }

    /// Holds the bounds of `id`'s children (resident) to `id`'s where the file's quantisation
    /// lets an honest file be held to them: each child's sphere inside the parent's, and
    /// each leaf child within the parent's error radius of its proxy. A few multiplies per
    /// child, once per node (the caller marks it checked).
    ///
    /// A file can still lie about bounds this cannot see (a sphere or error radius too
    /// small for the leaves far below, a cone too narrow): `docs/format.md` says what such a
    /// file can do to a cut. Only `vds-info --verify` checks bounds against the geometry.
    fn check_child_bounds(&self, id: u32, children: &[ChildRecords]) -> Result<(), VdtError> {
        let step = self.source.header().grid_step.get();
        let Tested {
            hot: parent_hot,
            shape: parent,
        } = self.tested(id);
        let parent_center = glam::Vec3::from(parent.center);
        let parent_proxy = glam::Vec3::from(parent_hot.proxy);
        // Room for f32 rounding: a few ulps of the coordinates and radii compared. A child
        // that passes lies within the parent's sphere (ball), so the parent's magnitudes
        // bound its own; one that fails by this little is far past any slack anyway.
        let sphere_rounding =
            32.0 * f32::EPSILON * (parent_center.abs().max_element() + parent.radius);
        let error_rounding =
            32.0 * f32::EPSILON * (parent_proxy.abs().max_element() + parent_hot.error_radius);
        for (c, child) in (parent_hot.first_child..).zip(children) {
            let (hot, shape) = (&child.hot, &child.shape);
            let center = glam::Vec3::from(shape.center);
            let by = center.distance(parent_center) + shape.radius - parent.radius;
            if by > nesting_slack(hot.error_radius, step) + sphere_rounding {
                return Err(self.bound_error(c, SphereOutsideParent { parent: id, by }));
            }
            if hot.child_count == 0 {
                let by =
                    glam::Vec3::from(hot.proxy).distance(parent_proxy) - parent_hot.error_radius;
                if by > error_rounding {
                    return Err(self.bound_error(c, LeafOutsideErrorRadius { parent: id, by }));
                }
            }
        }
        Ok(())
    }

    /// A [`VdtError::Bounds`] for node `id`, naming its page.
    fn bound_error(&self, id: u32, violation: BoundViolation) -> VdtError {
        VdtError::Bounds {
            page: self.page_of(id).unwrap_or(0),
            node: id,
            violation,
        }
    }

    /// Reads page `index` on this thread and installs it, evicting unpinned pages (never
    /// those in `keep`) to make room. When room cannot be made: refused if `refusable`,
    /// installed over the budget otherwise.
    fn load_page(
        &mut self,
        index: u32,
        keep: &std::ops::RangeInclusive<u32>,
        refusable: bool,
    ) -> Result<(), LoadError> {
        let mut scratch = std::mem::replace(&mut self.scratch, empty_page());
        let result = self.source.read_page_into(index, &mut scratch);
        let outcome = match result {
            Ok(()) => {
                let bytes = ResidentPage::bytes_for(
                    scratch.nodes.len(),
                    scratch.triangles.len(),
                    self.triangle_slots,
                );
                if self.make_room(bytes, keep) || !refusable {
                    self.install(index, &scratch, false);
                    Ok(())
                } else {
                    self.refuse(bytes);
                    Err(LoadError::OverBudget)
                }
            }
            Err(e) => Err(LoadError::File(e)),
        };
        self.scratch = scratch;
        outcome
    }

    /// Makes a decoded page resident, unpinned. A page fetched ahead of need goes to the
    /// front of the eviction order (stamp 0) until a node of it joins the cut: it must not
    /// push out pages the cut has used, nor be kept from eviction as a page that just
    /// arrived for a waiting node is.
    fn install(&mut self, index: u32, page: &Page, ahead_of_need: bool) {
        let mut resident = ResidentPage::from_page(index, page, self.triangle_slots);
        resident.stamp = if ahead_of_need { 0 } else { self.tick };
        self.tick += 1;
        let bytes = resident.bytes;
        self.evictable.insert((resident.stamp, index));
        self.evictable_bytes += bytes;
        self.page_bytes += bytes;
        let slot = match self.free_page_slots.pop() {
            Some(slot) => {
                self.pages[slot as usize] = Some(resident);
                slot
            }
            None => {
                self.pages.push(Some(resident));
                self.pages.len() as u32 - 1
            }
        };
        self.page_slot[index as usize] = slot;
        self.page_state[index as usize] = PageState::Resident;
        self.pages_loaded += 1;
        self.loaded
            .push(page.first_node..page.first_node + page.nodes.len() as u32);
        self.establish_on_arrival(index);
    }

    /// Reads every page of the file that is not resident and makes it resident, over the
    /// budget if need be (for benchmarks of the fully resident case, with the budget set to
    /// hold the model; otherwise the next adjust evicts what does not fit).
    pub fn load_every_page(&mut self) -> Result<(), VdtError> {
        for index in 0..self.page_state.len() as u32 {
            if self.page_state[index as usize] != PageState::Resident
                && let Err(LoadError::File(e)) = self.load_page(index, &NO_PAGES, false)
            {
                return Err(e);
            }
        }
        Ok(())
    }

    /// The file the store reads (shared with its loader threads), for searches of their
    /// own such as [`crate::nearest::nearest_leaf`].
    pub fn source(&self) -> std::sync::Arc<dyn PageSource> {
        std::sync::Arc::clone(&self.source)
    }

    /// Calls `visit` with every page of the file in order, decoded and checked by the
    /// reader but not made resident (for whole-model measurements and exports, which must
    /// not hold the model in the store).
    pub fn for_each_page(&self, mut visit: impl FnMut(&Page)) -> Result<(), VdtError> {
        let mut page = empty_page();
        for index in 0..self.page_state.len() as u32 {
            self.source.read_page_into(index, &mut page)?;
            visit(&page);
        }
        Ok(())
    }

    /// The boundary-node test needs the leaf a rank belongs to only through ranges, so no
    /// rank → node table exists; this walks down from `from` (which must support `rank`)
    /// through nodes for which `descend` says yes, and returns where it stops.
    #[inline]
    pub fn descend(&self, mut from: u32, rank: u32, mut descend: impl FnMut(u32) -> bool) -> u32 {
        while descend(from) {
            from = self.child_supporting(from, rank);
        }
        from
    }

    /// Appends the first leaf ranks of the `count` resident nodes from `first` (a node's
    /// children) to `out`, reading the page's run of them at once.
    pub(crate) fn children_leaf_begins(&self, first: u32, count: u32, out: &mut Vec<u32>) {
        let p = self.expect_place(first);
        let page = self.resident(p.slot);
        let local = p.local as usize;
        let in_page = (count as usize).min(page.leaf_begin.len() - local);
        out.extend_from_slice(&page.leaf_begin[local..local + in_page]);
        // Children that straddle into the next page, looked up one by one.
        out.extend((first + in_page as u32..first + count).map(|c| self.leaf_begin(c)));
    }

    /// The child of resident inner node `id` that supports `rank` (which `id` must support);
    /// its children must be resident.
    #[inline]
    pub fn child_supporting(&self, id: u32, rank: u32) -> u32 {
        let hot = self.hot(id);
        let (first, count) = (hot.first_child, hot.child_count);
        let p = self.expect_place(first);
        let page = self.resident(p.slot);
        let local = p.local as usize;
        let in_page = (count as usize).min(page.leaf_begin.len() - local);
        // Children cover consecutive leaf ranges in id order, so the last child starting at
        // or before `rank` is the one.
        let mut child = first;
        for (k, &begin) in page.leaf_begin[local..local + in_page]
            .iter()
            .enumerate()
            .skip(1)
        {
            if begin > rank {
                return child;
            }
            child = first + k as u32;
        }
        // Children that straddle into the next page, looked up one by one.
        for c in first + in_page as u32..first + count {
            let q = self.expect_place(c);
            if self.resident(q.slot).leaf_begin[q.local as usize] > rank {
                break;
            }
            child = c;
        }
        child
    }

    /// The root id.
    pub const ROOT: u32 = 0;

    /// The parent id of the root.
    pub const NO_PARENT: u32 = NO_NODE;
}

/// Why [`NodeStore::load_children`] did not load.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// A page could not be read or the children are not well formed.
    #[error(transparent)]
    File(#[from] VdtError),
    /// The pages do not fit in the memory budget with what the cut pins.
    #[error("the children's pages do not fit in the memory budget")]
    OverBudget,
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    proptest! {
        /// The block table's walk finds the page the directory search finds, for pages of any
        /// size (one node, or far more than the average).
        #[test]
        fn block_walk_finds_the_page_the_search_finds(
            sizes in proptest::collection::vec(
                prop_oneof![1u32..4, 1u32..200, 1000u32..5000], 1..60),
        ) {
            let mut first_nodes = Vec::with_capacity(sizes.len());
            let mut next = 0u32;
            for size in &sizes {
                first_nodes.push(next);
                next += size;
            }
            let node_count = next;
            let shift = block_shift(node_count, first_nodes.len());
            let block_page = block_pages(&first_nodes, node_count, shift);
            for id in 0..node_count {
                prop_assert_eq!(
                    page_from_block(&first_nodes, &block_page, shift, id),
                    page_holding(&first_nodes, id)
                );
            }
        }
    }
}
