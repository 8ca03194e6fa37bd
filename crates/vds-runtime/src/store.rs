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
    fn from_record(r: &NodeRecord) -> Node {
        let f = |v: &[vds_format::layout::F32]| [v[0].get(), v[1].get(), v[2].get()];
        Node {
            proxy: f(&r.proxy),
            error_radius: r.error_radius.get(),
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
    /// (`max ‖child proxy − proxy‖ + child error radius`); zero until the children load.
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

/// The two records the criteria read of one node.
#[derive(Debug, Clone, Copy)]
pub struct Tested<'a> {
    /// Proxy, error radius and group bound.
    pub hot: &'a Hot,
    /// Sphere and cone.
    pub shape: &'a Shape,
}

/// The rest of a node: where it sits in the tree and which triangles it owns.
#[derive(Debug, Clone, Copy, PartialEq, Zeroable)]
struct Topology {
    parent: u32,
    leaf_end: u32,
    subtri_begin: u32,
    subtri_count: u32,
    cone_half_angle: f32,
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
    /// Not loaded, not asked for (or asked for and not arrived: see `awaited`).
    Absent,
    /// Decoded into the store's arrays.
    Resident,
    /// The background loader could not read it; its nodes stay folded.
    Failed,
}

/// Nodes and triangles of the pages loaded so far.
///
/// A node is kept as four records in four arrays, split by who reads them: [`Hot`] by the
/// per-frame traversal, [`Shape`] by the full criteria, its first leaf rank by the descent
/// along a vertex's path, and the rest by fold and unfold. [`NodeStore::node`] assembles
/// them into a [`Node`].
pub struct NodeStore {
    source: std::sync::Arc<dyn PageSource>,
    page_first_node: Vec<u32>,
    page_state: Vec<PageState>,
    resident_pages: u32,
    /// Background loading, when on.
    loader: Option<crate::loader::Loader>,
    /// Per page: the highest priority it was asked for with and not yet delivered, or
    /// negative when it is not awaited.
    awaited: Vec<f32>,
    /// Pages asked of the loader and not yet delivered.
    pending_pages: u32,
    /// Errors of pages the background loader could not read, not yet taken.
    page_errors: Vec<VdtError>,
    topology: Vec<Topology>,
    hot: Vec<Hot>,
    shape: Vec<Shape>,
    /// Per node: its first leaf rank, apart, so finding the child that holds a rank reads
    /// one small contiguous run instead of several node records.
    leaf_begin: Vec<u32>,
    /// One bit per node: its children are loaded and checked ([`NodeStore::load_children`]).
    children_ready: Vec<u64>,
    triangle_corners: Vec<[u32; 3]>,
    triangle_parts: Vec<u32>,
    /// Node id ranges of the pages loaded since the last [`NodeStore::take_loaded`].
    loaded: Vec<std::ops::Range<u32>>,
    scratch: Page,
}

impl NodeStore {
    /// A store over `source` with the root's page loaded, loading pages synchronously.
    pub fn new(source: Box<dyn PageSource>) -> Result<NodeStore, VdtError> {
        NodeStore::with_loading(source, Loading::Synchronous)
    }

    /// A store over `source` with the root's page loaded (on this thread, whatever the
    /// loading: nothing can be drawn before it), loading the others as `loading` says.
    pub fn with_loading(
        source: Box<dyn PageSource>,
        loading: Loading,
    ) -> Result<NodeStore, VdtError> {
        let source: std::sync::Arc<dyn PageSource> = source.into();
        let header = source.header();
        let node_count = header.node_count.get() as usize;
        let triangle_count = header.triangle_count.get() as usize;
        if node_count == 0 {
            return Err(VdtError::invalid("tree", "the file holds no nodes"));
        }
        let page_first_node = source
            .directory()
            .iter()
            .map(|p| p.first_node.get())
            .collect::<Vec<_>>();
        let page_count = page_first_node.len();
        let loader = match loading {
            Loading::Synchronous => None,
            Loading::Background { threads } => Some(crate::loader::Loader::start(
                std::sync::Arc::clone(&source),
                threads,
            )?),
        };
        let mut store = NodeStore {
            source,
            page_first_node,
            page_state: vec![PageState::Absent; page_count],
            resident_pages: 0,
            loader,
            awaited: vec![-1.0; page_count],
            pending_pages: 0,
            page_errors: Vec::new(),
            // Zeroed allocations: the operating system provides the pages lazily, so a
            // store over a huge file costs memory only for the pages actually loaded.
            topology: bytemuck::zeroed_vec(node_count),
            hot: bytemuck::zeroed_vec(node_count),
            shape: bytemuck::zeroed_vec(node_count),
            leaf_begin: bytemuck::zeroed_vec(node_count),
            children_ready: vec![0; node_count.div_ceil(64)],
            triangle_corners: bytemuck::zeroed_vec(triangle_count),
            triangle_parts: bytemuck::zeroed_vec(triangle_count),
            loaded: Vec::new(),
            scratch: Page {
                first_node: 0,
                first_triangle: 0,
                nodes: Vec::new(),
                triangles: Vec::new(),
            },
        };
        store.load_node(0)?;
        let root = store.node(0);
        if root.leaf_begin != 0
            || u64::from(root.leaf_end) != store.source.header().vertex_count.get()
        {
            return Err(VdtError::invalid(
                "node 0",
                "the root does not cover every vertex",
            ));
        }
        Ok(store)
    }

    /// Number of nodes in the tree.
    pub fn node_count(&self) -> u32 {
        self.hot.len() as u32
    }

    /// Number of original vertices (leaves).
    pub fn vertex_count(&self) -> u32 {
        self.source.header().vertex_count.get() as u32
    }

    /// Number of triangles in the tree.
    pub fn triangle_count(&self) -> u32 {
        self.triangle_corners.len() as u32
    }

    /// The node id ranges of the pages loaded since the last call: what a renderer must upload
    /// before it draws triangles whose corners lie there.
    pub fn take_loaded(&mut self) -> Vec<std::ops::Range<u32>> {
        std::mem::take(&mut self.loaded)
    }

    /// Pages loaded so far, and pages in the file.
    pub fn pages_resident(&self) -> (u32, u32) {
        (self.resident_pages, self.page_state.len() as u32)
    }

    /// Pages asked of the background loader and not yet delivered (0 when loading is
    /// synchronous).
    pub fn pending_pages(&self) -> u32 {
        self.pending_pages
    }

    /// Errors of pages the background loader could not read since the last call, each
    /// reported once (the error names the page); those pages' nodes stay folded.
    pub fn take_page_errors(&mut self) -> Vec<VdtError> {
        std::mem::take(&mut self.page_errors)
    }

    /// Whether `id`'s children are loaded and checked, so that it may unfold now. With
    /// synchronous loading this loads them (and is `false` only by an error); with
    /// background loading it never reads a page: `false` means ask with
    /// [`NodeStore::request_children`] and try again after they arrive.
    pub fn children_available(&mut self, id: u32) -> Result<bool, VdtError> {
        let (word, bit) = ((id / 64) as usize, 1u64 << (id % 64));
        if self.children_ready[word] & bit != 0 {
            return Ok(true);
        }
        if self.loader.is_some() {
            let hot = self.hot[id as usize];
            if hot.child_count == 0 {
                return Ok(true);
            }
            let last = hot.first_child + hot.child_count - 1;
            let resident = |store: &NodeStore, node: u32| {
                store
                    .page_of(node)
                    .is_some_and(|p| store.page_state[p as usize] == PageState::Resident)
            };
            if !(resident(self, hot.first_child) && resident(self, last)) {
                return Ok(false);
            }
        }
        self.load_children(id)?;
        Ok(true)
    }

    /// Whether `id`'s children's pages are resident, without reading any: always true with
    /// synchronous loading (an unfold reads them itself).
    pub fn children_resident(&self, id: u32) -> bool {
        let (word, bit) = ((id / 64) as usize, 1u64 << (id % 64));
        if self.loader.is_none() || self.children_ready[word] & bit != 0 {
            return true;
        }
        let hot = &self.hot[id as usize];
        if hot.child_count == 0 {
            return true;
        }
        let last = hot.first_child + hot.child_count - 1;
        [hot.first_child, last].into_iter().all(|node| {
            self.page_of(node)
                .is_some_and(|p| self.page_state[p as usize] == PageState::Resident)
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
        let Some(loader) = &self.loader else {
            return false;
        };
        let hot = self.hot[id as usize];
        if hot.child_count == 0 {
            return false;
        }
        let priority = priority.max(0.0);
        let last = hot.first_child + hot.child_count - 1;
        let pages = [self.page_of(hot.first_child), self.page_of(last)];
        let mut arriving = true;
        for page in pages.into_iter().flatten() {
            let p = page as usize;
            match self.page_state[p] {
                PageState::Resident => continue,
                PageState::Failed => {
                    arriving = false;
                    continue;
                }
                PageState::Absent => {}
            }
            let awaited = self.awaited[p];
            if awaited >= 0.0 && priority < 2.0 * awaited.max(f32::MIN_POSITIVE) {
                continue;
            }
            if awaited < 0.0 {
                self.pending_pages += 1;
            }
            self.awaited[p] = priority;
            loader.request(page, priority);
        }
        arriving
    }

    /// Takes in the pages the background loader has delivered since the last call, without
    /// waiting; returns how many. Their nodes can unfold from now on.
    pub fn poll(&mut self) -> u32 {
        let mut delivered = Vec::new();
        if let Some(loader) = &self.loader {
            delivered.extend(std::iter::from_fn(|| loader.try_next()));
        }
        let count = delivered.len() as u32;
        for (index, result) in delivered {
            self.deliver(index, result);
        }
        count
    }

    /// Waits until every page asked of the background loader has been delivered and takes
    /// them in (what a test or a batch replay does to let loading settle).
    pub fn wait_for_pages(&mut self) {
        while self.pending_pages > 0 {
            let Some((index, result)) = self.loader.as_ref().and_then(|l| l.wait_next()) else {
                return;
            };
            self.deliver(index, result);
        }
    }

    fn deliver(&mut self, index: u32, result: Result<Page, VdtError>) {
        let p = index as usize;
        if self.awaited[p] >= 0.0 {
            self.awaited[p] = -1.0;
            self.pending_pages -= 1;
        }
        if self.page_state[p] != PageState::Absent {
            return; // Loaded synchronously meanwhile.
        }
        match result {
            Ok(page) => self.install(index, &page),
            Err(error) => {
                self.page_state[p] = PageState::Failed;
                self.page_errors.push(error);
            }
        }
    }

    /// The page holding node `id`, if any.
    fn page_of(&self, id: u32) -> Option<u32> {
        let page = self.page_first_node.partition_point(|&first| first <= id);
        page.checked_sub(1).map(|p| p as u32)
    }

    /// Node `id`. Its page must have been loaded ([`NodeStore::load_node`]); nodes of pages
    /// not yet loaded read as zeros.
    #[inline]
    pub fn node(&self, id: u32) -> Node {
        let (i, hot, shape) = (
            id as usize,
            &self.hot[id as usize],
            &self.shape[id as usize],
        );
        let topology = &self.topology[i];
        Node {
            proxy: hot.proxy,
            error_radius: hot.error_radius,
            sphere_center: shape.center,
            sphere_radius: shape.radius,
            cone_axis: shape.cone_axis,
            cone_half_angle: topology.cone_half_angle,
            cone_two_sided: topology.cone_two_sided,
            parent: topology.parent,
            first_child: hot.first_child,
            leaf_begin: self.leaf_begin[i],
            leaf_end: topology.leaf_end,
            subtri_begin: topology.subtri_begin,
            subtri_count: topology.subtri_count,
            child_count: hot.child_count as u8,
            depth: topology.depth,
        }
    }

    /// Parent of node `id` ([`NO_NODE`] for the root).
    #[inline]
    pub fn parent(&self, id: u32) -> u32 {
        self.topology[id as usize].parent
    }

    /// True when node `id` supports the vertex of leaf rank `rank`.
    #[inline]
    pub fn supports_rank(&self, id: u32, rank: u32) -> bool {
        self.leaf_begin[id as usize] <= rank && rank < self.topology[id as usize].leaf_end
    }

    /// The subtris of node `id`, as a range of triangle indices.
    #[inline]
    pub fn subtris(&self, id: u32) -> std::ops::Range<u32> {
        let t = &self.topology[id as usize];
        t.subtri_begin..t.subtri_begin + t.subtri_count
    }

    /// Hints that the test data of nodes `first..first + count` will be read soon.
    #[inline]
    pub(crate) fn prefetch_tested(&self, first: u32, count: u32) {
        let range = first as usize..first as usize + count as usize;
        crate::prefetch::prefetch_range(&self.hot, range.clone());
        crate::prefetch::prefetch_range(&self.shape, range);
    }

    /// The per-frame test data of node `id` (loaded, as for [`NodeStore::node`]).
    #[inline]
    pub fn hot(&self, id: u32) -> &Hot {
        &self.hot[id as usize]
    }

    /// What the criteria read of node `id` (loaded, as for [`NodeStore::node`]).
    #[inline]
    pub fn tested(&self, id: u32) -> Tested<'_> {
        Tested {
            hot: &self.hot[id as usize],
            shape: &self.shape[id as usize],
        }
    }

    /// Corners (leaf ranks) of triangle `index`; its owner's page must be loaded.
    #[inline]
    pub fn triangle_corners(&self, index: u32) -> [u32; 3] {
        self.triangle_corners[index as usize]
    }

    /// Part id of triangle `index`; its owner's page must be loaded.
    #[inline]
    pub fn triangle_part(&self, index: u32) -> u32 {
        self.triangle_parts[index as usize]
    }

    /// Makes sure node `id` and its subtris are loaded.
    /// This reads the page on the calling thread if it is not resident, whatever the
    /// loading (for callers that need the data now: exports, measurements, unfold-all).
    pub fn load_node(&mut self, id: u32) -> Result<(), VdtError> {
        match self.page_of(id) {
            Some(index) if self.page_state[index as usize] == PageState::Resident => Ok(()),
            Some(index) => self.load_page(index),
            None => Err(VdtError::invalid("node id", format!("{id} has no page"))),
        }
    }

    /// Makes sure every child of `id` is loaded (children may straddle a page boundary) and
    /// that they partition `id`'s leaf range in order, as the traversal assumes, and that
    /// their bounds nest in `id`'s as far as quantisation allows ([`VdtError::Bounds`]
    /// otherwise, naming the child's page). The reader validates each page on its own; this
    /// is the part of the tree that spans pages, checked where it is first relied on.
    pub fn load_children(&mut self, id: u32) -> Result<(), VdtError> {
        // Pages never unload in this store, so a node checked once stays checked.
        let (word, bit) = ((id / 64) as usize, 1u64 << (id % 64));
        if self.children_ready[word] & bit != 0 {
            return Ok(());
        }
        let node = self.node(id);
        if node.is_leaf() {
            return Ok(());
        }
        self.load_node(node.first_child)?;
        self.load_node(node.first_child + u32::from(node.child_count) - 1)?;
        let mut next_rank = node.leaf_begin;
        for c in node.children() {
            let child = self.node(c);
            if child.parent != id || child.leaf_begin != next_rank || child.depth != node.depth + 1
            {
                return Err(VdtError::invalid(
                    format!("node {c}"),
                    format!("is not a well-formed child of node {id}"),
                ));
            }
            next_rank = child.leaf_end;
        }
        if next_rank != node.leaf_end {
            return Err(VdtError::invalid(
                format!("node {id}"),
                "its children do not cover its leaf range",
            ));
        }
        self.check_child_bounds(id)?;
        let center = glam::Vec3::from(node.proxy);
        let (mut radius, mut error) = (0.0f32, 0.0f32);
        for c in node.children() {
            let child = &self.hot[c as usize];
            radius =
                radius.max(center.distance(glam::Vec3::from(child.proxy)) + child.error_radius);
            error = error.max(child.error_radius);
        }
        // Widened by a few ulps so the ball holds the children's balls despite rounding.
        let hot = &mut self.hot[id as usize];
        hot.group_radius = radius * (1.0 + 4.0 * f32::EPSILON);
        hot.group_error = error;
        self.children_ready[word] |= bit;
        Ok(())
    }

    /// Holds the bounds of `id`'s children (loaded) to `id`'s where the file's quantisation
    /// lets an honest file be held to them: each child's sphere inside the parent's, and
    /// each leaf child within the parent's error radius of its proxy. A few multiplies per
    /// child, once per node (the caller marks it checked).
    ///
    /// A file can still lie about bounds this cannot see (a sphere or error radius too
    /// small for the leaves far below, a cone too narrow): `docs/format.md` says what such a
    /// file can do to a cut. Only `vds-info --verify` checks bounds against the geometry.
    fn check_child_bounds(&self, id: u32) -> Result<(), VdtError> {
        let step = self.source.header().grid_step.get();
        let (parent, parent_hot) = (&self.shape[id as usize], &self.hot[id as usize]);
        let parent_center = glam::Vec3::from(parent.center);
        let parent_proxy = glam::Vec3::from(parent_hot.proxy);
        // Room for f32 rounding: a few ulps of the coordinates and radii compared. A child
        // that passes lies within the parent's sphere (ball), so the parent's magnitudes
        // bound its own; one that fails by this little is far past any slack anyway.
        let sphere_rounding =
            32.0 * f32::EPSILON * (parent_center.abs().max_element() + parent.radius);
        let error_rounding =
            32.0 * f32::EPSILON * (parent_proxy.abs().max_element() + parent_hot.error_radius);
        let first = parent_hot.first_child as usize;
        let children = first..first + parent_hot.child_count as usize;
        let shapes = &self.shape[children.clone()];
        for (k, (shape, hot)) in shapes.iter().zip(&self.hot[children]).enumerate() {
            let c = (first + k) as u32;
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
        let page = self.page_first_node.partition_point(|&first| first <= id) as u32 - 1;
        VdtError::Bounds {
            page,
            node: id,
            violation,
        }
    }

    fn load_page(&mut self, index: u32) -> Result<(), VdtError> {
        let mut scratch = std::mem::replace(
            &mut self.scratch,
            Page {
                first_node: 0,
                first_triangle: 0,
                nodes: Vec::new(),
                triangles: Vec::new(),
            },
        );
        let result = self.source.read_page_into(index, &mut scratch);
        if result.is_ok() {
            self.install(index, &scratch);
        }
        self.scratch = scratch;
        result
    }

    /// Copies a decoded page into the arrays and marks it resident.
    fn install(&mut self, index: u32, page: &Page) {
        let first = page.first_node as usize;
        for (k, record) in page.nodes.iter().enumerate() {
            let node = Node::from_record(record);
            self.hot[first + k] = Hot {
                proxy: node.proxy,
                error_radius: node.error_radius,
                group_radius: 0.0,
                group_error: 0.0,
                first_child: node.first_child,
                child_count: u32::from(node.child_count),
            };
            self.shape[first + k] = Shape {
                center: node.sphere_center,
                radius: node.sphere_radius,
                cone_axis: node.cone_axis,
                cone_cos: Shape::cone_test(node.cone_half_angle, node.cone_two_sided),
            };
            self.leaf_begin[first + k] = node.leaf_begin;
            self.topology[first + k] = Topology {
                parent: node.parent,
                leaf_end: node.leaf_end,
                subtri_begin: node.subtri_begin,
                subtri_count: node.subtri_count,
                cone_half_angle: node.cone_half_angle,
                depth: node.depth,
                cone_two_sided: node.cone_two_sided,
            };
        }
        let first = page.first_triangle as usize;
        for (k, t) in page.triangles.iter().enumerate() {
            self.triangle_corners[first + k] = t.corners.map(|c| c.get());
            self.triangle_parts[first + k] = t.part.get();
        }
        self.page_state[index as usize] = PageState::Resident;
        self.resident_pages += 1;
        self.loaded
            .push(page.first_node..page.first_node + page.nodes.len() as u32);
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

    /// The child of inner node `id` that supports `rank` (which `id` must support).
    #[inline]
    pub fn child_supporting(&self, id: u32, rank: u32) -> u32 {
        let hot = &self.hot[id as usize];
        // Children cover consecutive leaf ranges in id order, so the last child starting at
        // or before `rank` is the one.
        let mut child = hot.first_child;
        for c in hot.first_child + 1..hot.first_child + hot.child_count {
            if self.leaf_begin[c as usize] <= rank {
                child = c;
            } else {
                break;
            }
        }
        child
    }

    /// The root id.
    pub const ROOT: u32 = 0;

    /// The parent id of the root.
    pub const NO_PARENT: u32 = NO_NODE;
}
