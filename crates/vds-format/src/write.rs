//! Writing `.vdt` files: page layout, parallel compression, and an atomic, deterministic
//! write (a temporary file beside the target, renamed into place).
//!
//! Page layout: pages hold the tree *level by level*. Within what is laid out together (the
//! top, or one region below), sibling groups are taken breadth-first, each level in leaf order,
//! and cut into pages at the byte budget. Below a region's first few narrow levels, a page is
//! a slice of one or two levels over a spatially compact stretch of the tree, not a treelet
//! several levels deep: a boundary that passes through a page leaves few of its nodes far
//! below the cut, so a memory budget holds a finer cut (pages are the runtime's unit of
//! residency; `docs/benchmarks.md`, "Page shape under a budget"). A root-to-leaf path crosses
//! about one page per level below the region's first page.
//!
//! The tree is laid out in *regions* ([`region_leaves`]): first its top (the nodes with more
//! leaves than a region holds, and their children), then, in leaf order, the subtree below
//! each *region root* (a child of the top with at most that many leaves). No page mixes two
//! regions, so a region's pages depend on its subtree alone: the sharded build encodes them
//! one region at a time ([`PageLayout`], [`encode_pages`], [`file_head`]). The first page, the
//! top of the tree, has a quarter of the budget so opening a file decodes little. Nodes are
//! renumbered in page order: every page holds a contiguous node range, siblings stay
//! contiguous, and parents precede children.

use std::collections::VecDeque;
use std::path::Path;

use rayon::prelude::*;
use xxhash_rust::xxh3::xxh3_64;
use zerocopy::IntoBytes;
use zerocopy::little_endian::{U32, U64};

use crate::layout::*;
use crate::{Grid, Metadata, VdtError};

/// Default bytes of decoded records per page. Pages are the runtime's unit of residency, so
/// smaller pages let a memory budget hold a finer cut, and larger ones compress better and
/// cost fewer per-page tables. 32 KiB compresses to about 1.6 KiB on generated CAD scenes;
/// against 128 KiB pages the files are 12–24 % larger and a 256 MiB budget holds a cut of the
/// 50 M scene about five times finer in screen error (`docs/benchmarks.md`, "Page shape under
/// a budget").
pub const DEFAULT_PAGE_BYTES: u32 = 32 * 1024;
/// Default zstd level. On the pages of the generated 1 M scene level 3 compresses at 2.4× the
/// speed of level 6 for 4.7 % more bytes (zstd's own benchmark, one page per frame), and the
/// 10 M build, whose writing was half its time at level 6, takes 17 % less time end to end
/// (`docs/benchmarks.md`, "Measurements behind current defaults").
pub const DEFAULT_ZSTD_LEVEL: i32 = 3;

/// The nodes of a tree to write, by id: a slice of records, or a builder's own node array
/// that makes each record when the writer asks for it, so that a whole tree of records (76
/// bytes a node, 0.6 GB at 10 M triangles) never has to exist beside the tree.
pub trait NodeSource: Sync {
    /// Number of nodes; ids are `0 .. node_count()`.
    fn node_count(&self) -> usize;
    /// The record of node `id` (below [`NodeSource::node_count`]).
    fn node_record(&self, id: u32) -> NodeRecord;
}

impl NodeSource for Vec<NodeRecord> {
    fn node_count(&self) -> usize {
        self.len()
    }

    fn node_record(&self, id: u32) -> NodeRecord {
        self[id as usize]
    }
}

/// A tree to write, with nodes in any order where children are contiguous and node 0 is the
/// root. Each node's subtris are `triangles[subtri_begin .. subtri_begin + subtri_count]`.
#[derive(Debug, Clone)]
pub struct TreeContent<N: NodeSource = Vec<NodeRecord>> {
    /// Nodes; ids are indices. Written in page order (renumbered) by the writer.
    pub nodes: N,
    /// Triangles grouped by node.
    pub triangles: Vec<TriangleRecord>,
    /// Number of leaves (original vertices).
    pub vertex_count: u64,
    /// Depth of the deepest node.
    pub max_depth: u32,
    /// The grid positions are stored on; every leaf position must lie on it
    /// ([`Grid::snap`] the scene before building).
    pub grid: Grid,
    /// The metadata section.
    pub metadata: Metadata,
}

/// Options for [`write_file`].
#[derive(Debug, Clone, Copy)]
pub struct WriteOptions {
    /// zstd level (1..=22).
    pub zstd_level: i32,
    /// Target raw bytes per page.
    pub page_bytes: u32,
}

impl Default for WriteOptions {
    fn default() -> Self {
        WriteOptions {
            zstd_level: DEFAULT_ZSTD_LEVEL,
            page_bytes: DEFAULT_PAGE_BYTES,
        }
    }
}

/// What was written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct WriteReport {
    /// Total file size.
    pub file_bytes: u64,
    /// Size of all pages' encoded streams before zstd.
    pub raw_page_bytes: u64,
    /// Compressed size of all pages.
    pub compressed_page_bytes: u64,
    /// Number of pages.
    pub pages: u32,
}

/// The most leaves a *region* holds for pages of `page_bytes` decoded bytes (8,192 for the
/// default pages): about 50 pages' worth of the nodes and triangles above those leaves (a
/// leaf brings about two nodes and two triangles, some 200 decoded bytes), so that the partly
/// filled page a region ends with is one in 50 in the largest regions (most are smaller: a
/// region root is any child of a larger node that holds at most this many leaves). Measured
/// with treelet pages of 128 KiB, against one layout of the whole tree: files 1.9–2.5 %
/// smaller on the generated 1 M and 10 M scenes and 0.1 % on the dragon, 6–8 % more pages; a
/// quarter of this limit cost the dragon 1.3 % and the bunny 1.9 %.
///
/// A *region root* is a node with at most this many leaves whose parent has more. Pages never
/// mix the subtrees of two region roots, so each subtree's pages depend on that subtree alone
/// and can be encoded by whoever holds it: the sharded build's merge lays out and encodes one
/// region after another without ever holding the whole tree.
pub fn region_leaves(page_bytes: u32) -> u32 {
    (page_bytes / 4).max(1)
}

/// Whether a node with `leaves` leaves has its children in the top of a tree with
/// `tree_leaves` leaves (the rule [`PageLayout::top`] lays out by): it holds more than a
/// region, or the whole tree fits in one (then the top is the whole tree, laid out as a small
/// file's).
pub fn in_top_with_children(leaves: u32, tree_leaves: u32, page_bytes: u32) -> bool {
    let limit = region_leaves(page_bytes);
    tree_leaves <= limit || leaves > limit
}

/// A sibling group: `count` nodes from `first`.
#[derive(Debug, Clone, Copy)]
struct Group {
    first: u32,
    count: u32,
}

/// One planned page: its sibling groups, in order, and how many subtris they own.
#[derive(Debug, Clone, Default)]
struct PagePlan {
    groups: Vec<Group>,
    triangles: usize,
    nodes: usize,
}

/// The pages of a tree, or of part of one, as sibling groups in page order: the order the
/// writer numbers nodes and triangles in.
///
/// A file is laid out as its top ([`PageLayout::top`]: the nodes with more than
/// [`region_leaves`] leaves and their children, or the whole tree if the root has no more
/// than that) followed by each region root's subtree below it ([`PageLayout::region`]), in
/// leaf order. Layouts of parts of a tree [`append`](PageLayout::append) into the file's.
#[derive(Debug, Clone, Default)]
pub struct PageLayout {
    pages: Vec<PagePlan>,
}

impl PageLayout {
    /// The top of the tree in `nodes` (node 0 is the root): the whole tree when the root has at
    /// most [`region_leaves`] leaves, else every node with more than that and their children
    /// (region roots among them), without what lies below the region roots. The first page
    /// has a quarter of the budget, so opening a file decodes little.
    pub fn top(nodes: &impl NodeSource, page_bytes: u32) -> PageLayout {
        let tree_leaves = leaf_count(&nodes.node_record(0));
        let expand = |n: &NodeRecord| in_top_with_children(leaf_count(n), tree_leaves, page_bytes);
        PageLayout {
            pages: plan_pages(
                nodes,
                Group { first: 0, count: 1 },
                page_bytes,
                true,
                expand,
            ),
        }
    }

    /// The subtree of a region root below it: from its children `first_child ..+ count`
    /// (ids of `nodes`) down to the leaves, every page full-sized.
    pub fn region(
        nodes: &impl NodeSource,
        first_child: u32,
        count: u8,
        page_bytes: u32,
    ) -> PageLayout {
        let group = Group {
            first: first_child,
            count: u32::from(count),
        };
        PageLayout {
            pages: plan_pages(nodes, group, page_bytes, false, |_| true),
        }
    }

    /// Appends `later`'s pages after this layout's (the ids of both must be of one node
    /// source when they are encoded together).
    pub fn append(&mut self, later: PageLayout) {
        self.pages.extend(later.pages);
    }

    /// Number of pages.
    pub fn page_count(&self) -> usize {
        self.pages.len()
    }

    /// The nodes of page `k` (below [`PageLayout::page_count`]), in order.
    pub fn page_nodes(&self, k: usize) -> impl Iterator<Item = u32> + '_ {
        self.pages[k]
            .groups
            .iter()
            .flat_map(|g| g.first..g.first + g.count)
    }

    /// Number of nodes in the pages.
    pub fn node_count(&self) -> usize {
        self.pages.iter().map(|p| p.nodes).sum()
    }

    /// The nodes in page order (ids of the source it was laid out from): the `k`-th is
    /// numbered `first_node + k` when the pages are encoded from `first_node`.
    pub fn nodes(&self) -> impl Iterator<Item = u32> + '_ {
        self.pages
            .iter()
            .flat_map(|p| p.groups.iter())
            .flat_map(|g| g.first..g.first + g.count)
    }
}

fn leaf_count(n: &NodeRecord) -> u32 {
    n.leaf_end.get().saturating_sub(n.leaf_begin.get())
}

/// The region roots that have children, in leaf order: the nodes whose subtrees follow the
/// top in the file, each laid out by [`PageLayout::region`]. None when the root itself has
/// at most [`region_leaves`] leaves (the top is then the whole tree).
fn region_roots(nodes: &impl NodeSource, page_bytes: u32) -> Vec<u32> {
    let tree_leaves = leaf_count(&nodes.node_record(0));
    let mut roots = Vec::new();
    let mut stack = vec![0u32];
    while let Some(id) = stack.pop() {
        let n = nodes.node_record(id);
        if !in_top_with_children(leaf_count(&n), tree_leaves, page_bytes) {
            if n.child_count > 0 {
                roots.push(id);
            }
            continue;
        }
        let first = n.first_child.get();
        stack.extend((first..first + u32::from(n.child_count)).rev());
    }
    roots
}

/// Plans pages from `start`: the sibling groups of each page, its triangle and node counts
/// (read here once, where each group's size is measured anyway). Groups are taken
/// breadth-first, so each level follows the one above it in leaf order, and a page ends where
/// the next group would pass the budget. A node's children are laid out only where `expand`
/// says so. With `quarter_first`, the first page has a quarter of the budget.
fn plan_pages<N: NodeSource>(
    nodes: &N,
    start: Group,
    page_bytes: u32,
    quarter_first: bool,
    expand: impl Fn(&NodeRecord) -> bool,
) -> Vec<PagePlan> {
    let page_bytes = u64::from(page_bytes.max(NODE_BYTES as u32));
    let mut pages: Vec<PagePlan> = Vec::new();
    let mut page = PagePlan::default();
    let mut page_budget = if quarter_first {
        page_bytes / 4
    } else {
        page_bytes
    };
    let mut bytes = 0u64;
    let mut queue = VecDeque::from([start]);
    while let Some(group) = queue.pop_front() {
        // One record of each node: records are made on demand, and planning runs on one
        // thread.
        let mut triangles = 0u64;
        for id in group.first..group.first + group.count {
            let n = nodes.node_record(id);
            triangles += u64::from(n.subtri_count.get());
            if n.child_count > 0 && expand(&n) {
                queue.push_back(Group {
                    first: n.first_child.get(),
                    count: u32::from(n.child_count),
                });
            }
        }
        let size = NODE_BYTES as u64 * u64::from(group.count) + TRIANGLE_BYTES as u64 * triangles;
        if !page.groups.is_empty() && bytes + size > page_budget {
            pages.push(std::mem::take(&mut page));
            page_budget = page_bytes;
            bytes = 0;
        }
        page.groups.push(group);
        page.triangles += triangles as usize;
        page.nodes += group.count as usize;
        bytes += size;
    }
    if !page.groups.is_empty() {
        pages.push(page);
    }
    pages
}

/// One page encoded and compressed, and what the directory says of it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EncodedPage {
    /// The page's zstd frame.
    pub frame: Vec<u8>,
    /// Length of the decoded page.
    pub raw_length: u32,
    /// Nodes in the page.
    pub node_count: u32,
    /// Triangles in the page.
    pub triangle_count: u32,
}

/// Encodes and compresses the pages of `layout` (in parallel), numbering nodes from
/// `first_node` in page order. `new_id` maps an id of `nodes` (a parent or first child that
/// a page's records name) to its id in the file; it must agree with that numbering for the
/// layout's own nodes. Each node's subtris are `triangles[subtri_begin ..+ subtri_count]`
/// and its depth and leaf ranges are the file's.
pub fn encode_pages<N: NodeSource>(
    nodes: &N,
    triangles: &[TriangleRecord],
    layout: &PageLayout,
    new_id: &(impl Fn(u32) -> u32 + Sync),
    first_node: u32,
    grid: &Grid,
    zstd_level: i32,
) -> Result<Vec<EncodedPage>, VdtError> {
    let pages = encode_pages_where(
        nodes,
        triangles,
        layout,
        new_id,
        first_node,
        grid,
        zstd_level,
        |_| true,
    )?;
    Ok(pages.into_iter().flatten().collect())
}

/// [`encode_pages`] for the pages `k` of `layout` where `keep(k)`; `None` for the others.
#[allow(clippy::too_many_arguments)]
fn encode_pages_where<N: NodeSource>(
    nodes: &N,
    triangles: &[TriangleRecord],
    layout: &PageLayout,
    new_id: &(impl Fn(u32) -> u32 + Sync),
    first_node: u32,
    grid: &Grid,
    zstd_level: i32,
    keep: impl Fn(usize) -> bool + Sync,
) -> Result<Vec<Option<EncodedPage>>, VdtError> {
    let mut starts = Vec::with_capacity(layout.pages.len());
    let mut at = u64::from(first_node);
    for page in &layout.pages {
        starts.push(at);
        at += page.nodes as u64;
    }
    if at > u64::from(u32::MAX) {
        return Err(VdtError::invalid("tree", "more nodes than a file holds"));
    }
    let map = |id: U32| -> U32 {
        if id.get() == NO_NODE {
            id
        } else {
            U32::new(new_id(id.get()))
        }
    };
    // Each page gathers its own records in page order (renumbered) from the caller's tree:
    // no copy of the whole tree is made, which at 10 M triangles was 0.7 GB beside the tree.
    layout
        .pages
        .par_iter()
        .zip(starts)
        .enumerate()
        .map(|(k, (page, n0))| {
            if !keep(k) {
                return Ok(None);
            }
            PageWork::with(zstd_level, |work| {
                work.records.clear();
                work.triangles.clear();
                for group in &page.groups {
                    for old in group.first..group.first + group.count {
                        let mut n = nodes.node_record(old);
                        n.parent = map(n.parent);
                        n.first_child = map(n.first_child);
                        let begin = n.subtri_begin.get() as usize;
                        let count = n.subtri_count.get() as usize;
                        work.triangles
                            .extend_from_slice(&triangles[begin..begin + count]);
                        work.records.push(n);
                    }
                }
                encode_gathered(work, grid, n0 as u32).map(Some)
            })
        })
        .collect()
}

/// What a file says of its tree beside its pages: the figures of the header, and the
/// metadata.
#[derive(Debug, Clone)]
pub struct FileFigures<'a> {
    /// Number of leaves (original vertices).
    pub vertex_count: u64,
    /// Depth of the deepest node.
    pub max_depth: u32,
    /// The grid positions are stored on.
    pub grid: Grid,
    /// The metadata section.
    pub metadata: &'a Metadata,
}

/// The bytes of a file that precede its pages (header, metadata and directory) for pages of
/// these sizes, in this order, and the report of the whole file.
pub fn file_head(
    pages: &[EncodedPageSummary],
    figures: &FileFigures<'_>,
) -> Result<(Vec<u8>, WriteReport), VdtError> {
    let node_count: u64 = pages.iter().map(|p| u64::from(p.node_count)).sum();
    let triangle_count: u64 = pages.iter().map(|p| u64::from(p.triangle_count)).sum();
    if node_count == 0 {
        return Err(VdtError::invalid(
            "tree",
            "a .vdt file needs at least one node",
        ));
    }
    if node_count > u64::from(u32::MAX) || triangle_count > u64::from(u32::MAX) {
        return Err(VdtError::invalid(
            "tree",
            "more nodes or triangles than a file holds",
        ));
    }
    // A writer never produces a file its readers refuse.
    figures.metadata.check(triangle_count)?;
    let metadata = rkyv::to_bytes::<rkyv::rancor::Error>(figures.metadata)
        .map_err(|e| VdtError::invalid("metadata", e.to_string()))?;
    let metadata_offset = HEADER_BYTES as u64;
    let directory_offset = metadata_offset + metadata.len() as u64;
    let directory_length = (pages.len() * PAGE_ENTRY_BYTES) as u64;
    let mut offset = directory_offset + directory_length;
    let mut directory = Vec::with_capacity(pages.len());
    let (mut n0, mut t0) = (0u32, 0u32);
    let mut report = WriteReport {
        pages: pages.len() as u32,
        ..WriteReport::default()
    };
    for page in pages {
        directory.push(PageEntry {
            offset: U64::new(offset),
            compressed_length: U32::new(page.compressed_length),
            raw_length: U32::new(page.raw_length),
            first_node: U32::new(n0),
            node_count: U32::new(page.node_count),
            first_triangle: U32::new(t0),
            triangle_count: U32::new(page.triangle_count),
            checksum: U64::new(page.checksum),
        });
        n0 += page.node_count;
        t0 += page.triangle_count;
        offset += u64::from(page.compressed_length);
        report.raw_page_bytes += u64::from(page.raw_length);
        report.compressed_page_bytes += u64::from(page.compressed_length);
    }
    let grid = &figures.grid;
    let mut header = Header {
        magic: VDT_MAGIC,
        version: U32::new(VDT_VERSION),
        header_size: U32::new(HEADER_BYTES as u32),
        file_size: U64::new(offset),
        node_count: U64::new(node_count),
        triangle_count: U64::new(triangle_count),
        vertex_count: U64::new(figures.vertex_count),
        page_count: U32::new(pages.len() as u32),
        max_depth: U32::new(figures.max_depth),
        metadata: SectionRef {
            offset: U64::new(metadata_offset),
            length: U64::new(metadata.len() as u64),
            checksum: U64::new(xxh3_64(&metadata)),
        },
        directory: SectionRef {
            offset: U64::new(directory_offset),
            length: U64::new(directory_length),
            checksum: U64::new(xxh3_64(directory.as_bytes())),
        },
        grid_origin: grid.origin.map(zerocopy::little_endian::F32::new),
        grid_step: zerocopy::little_endian::F32::new(grid.step),
        header_checksum: U64::new(0),
    };
    header.header_checksum = U64::new(xxh3_64(&header.as_bytes()[..HEADER_BYTES - 8]));
    let mut head = Vec::with_capacity(directory_offset as usize + directory_length as usize);
    head.extend_from_slice(header.as_bytes());
    head.extend_from_slice(&metadata);
    head.extend_from_slice(directory.as_bytes());
    report.file_bytes = offset;
    Ok((head, report))
}

/// Node id of a detached region's root (see [`encode_detached_region`]).
pub const DETACHED_ROOT: u32 = 0;
/// Node id of a detached region's first node.
const DETACHED_FIRST: u32 = 1;

/// Encodes and compresses the pages `k` of one region where `keep(k)` (`layout`, from
/// [`PageLayout::region`] of `region_root`'s children in `nodes`; `None` for the others)
/// apart from where the region lies in the file: its nodes numbered from 1 in page order
/// ([`detached_id`]), and its root as node 0. Each link inside a region is
/// a difference of two of its ids, so every page but the first is the page the file holds
/// wherever the region lands; [`attach_region`] makes the first one the file's. (The sharded
/// build's shards encode their regions so, and the merge copies them.)
pub fn encode_detached_region<N: NodeSource>(
    nodes: &N,
    triangles: &[TriangleRecord],
    layout: &PageLayout,
    region_root: u32,
    keep: impl Fn(usize) -> bool + Sync,
    grid: &Grid,
    zstd_level: i32,
) -> Result<Vec<Option<EncodedPage>>, VdtError> {
    let mut detached: Vec<(u32, u32)> = layout
        .nodes()
        .enumerate()
        .map(|(k, id)| (id, DETACHED_FIRST + k as u32))
        .collect();
    detached.sort_unstable();
    let new_id = |id: u32| {
        if id == region_root {
            return DETACHED_ROOT;
        }
        match detached.binary_search_by_key(&id, |&(old, _)| old) {
            Ok(k) => detached[k].1,
            // A link out of the region other than to its root: no page of a region has one,
            // and this id, past every region id, would be refused by any reader.
            Err(_) => NO_NODE - 1,
        }
    };
    encode_pages_where(
        nodes,
        triangles,
        layout,
        &new_id,
        DETACHED_FIRST,
        grid,
        zstd_level,
        keep,
    )
}

/// The id [`encode_detached_region`] gives the `k`-th node of a region's layout.
pub fn detached_id(k: usize) -> u32 {
    DETACHED_FIRST + k as u32
}

/// The file's id of a node named by `detached` id in a region whose nodes are numbered from
/// `first_node` and whose root is `root`; `None` past the ids a file holds.
pub fn attached_id(detached: u32, first_node: u32, root: u32) -> Option<u32> {
    match detached {
        DETACHED_ROOT => Some(root),
        id => u32::try_from(u64::from(first_node) + u64::from(id - DETACHED_FIRST)).ok(),
    }
}

/// Encodes and compresses one page: `nodes` numbered from `first_node`, their links the
/// file's ids, and their subtris `triangles` (each node's `subtri_count` of them, in node
/// order). What [`encode_pages`] does for each page of a layout, for a caller that gathers a
/// page's records itself (the sharded build's merge, for a page with triangles across shards).
pub fn encode_page_frame(
    grid: &Grid,
    first_node: u32,
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
    zstd_level: i32,
) -> Result<EncodedPage, VdtError> {
    PageWork::with(zstd_level, |work| {
        work.records.clear();
        work.records.extend_from_slice(nodes);
        work.triangles.clear();
        work.triangles.extend_from_slice(triangles);
        encode_gathered(work, grid, first_node)
    })
}

/// Encodes and compresses the page gathered in `work` (its records and their subtris),
/// numbered from `first_node`.
fn encode_gathered(
    work: &mut PageWork,
    grid: &Grid,
    first_node: u32,
) -> Result<EncodedPage, VdtError> {
    let PageWork {
        compressor,
        scratch,
        records,
        triangles,
        raw,
        ..
    } = work;
    crate::codec::encode_page_into(scratch, grid, first_node, records, triangles, raw)?;
    let frame = compressor
        .compress(raw)
        .expect("zstd compression of an in-memory buffer cannot fail");
    if raw.len() as u64 > crate::read::MAX_COMPRESSION_RATIO * frame.len() as u64 {
        return Err(VdtError::invalid(
            format!("the page of node {first_node}"),
            "compresses beyond the ratio readers accept as a decompression bomb",
        ));
    }
    Ok(EncodedPage {
        frame,
        raw_length: raw.len() as u32,
        node_count: records.len() as u32,
        triangle_count: triangles.len() as u32,
    })
}

/// The first page of a region encoded by [`encode_detached_region`] as the file holds it when
/// the region's nodes are numbered from `first_node` and its root is node `root` (an id of the
/// file's top, below `first_node`): its first node's parent step rewritten, and the page
/// compressed again.
pub fn attach_region(
    first_page: &EncodedPage,
    first_node: u32,
    root: u32,
    zstd_level: i32,
) -> Result<EncodedPage, VdtError> {
    let bad =
        |reason: String| VdtError::invalid(format!("the region of node {first_node}"), reason);
    if root >= first_node {
        return Err(bad(format!("its root {root} does not precede it")));
    }
    if first_page.raw_length > crate::read::MAX_PAGE_RAW_BYTES
        || u64::from(first_page.raw_length)
            > crate::read::MAX_COMPRESSION_RATIO * first_page.frame.len() as u64
    {
        return Err(bad("a first page larger than a page can be".into()));
    }
    let (rebased, frame) = PageWork::with(zstd_level, |work| {
        let raw = work
            .decompressor
            .decompress(&first_page.frame, first_page.raw_length as usize)
            .map_err(|e| bad(format!("its first page does not decompress: {e}")))?;
        if raw.len() != first_page.raw_length as usize {
            return Err(bad("its first page decompresses to another length".into()));
        }
        let mut rebased = Vec::new();
        crate::codec::rebase_first_parent(
            &raw,
            u64::from(DETACHED_FIRST - DETACHED_ROOT),
            u64::from(first_node - root),
            &mut rebased,
        )
        .map_err(bad)?;
        let frame = work
            .compressor
            .compress(&rebased)
            .map_err(|e| bad(format!("zstd: {e}")))?;
        Ok((rebased, frame))
    })?;
    if rebased.len() as u64 > crate::read::MAX_COMPRESSION_RATIO * frame.len() as u64 {
        return Err(bad(
            "its first page compresses beyond the ratio readers accept".into(),
        ));
    }
    Ok(EncodedPage {
        frame,
        raw_length: rebased.len() as u32,
        node_count: first_page.node_count,
        triangle_count: first_page.triangle_count,
    })
}

/// What the directory needs of an [`EncodedPage`] once its frame has been written elsewhere.
#[derive(Debug, Clone, Copy)]
pub struct EncodedPageSummary {
    /// Length of the zstd frame.
    pub compressed_length: u32,
    /// XXH3-64 of the zstd frame.
    pub checksum: u64,
    /// Length of the decoded page.
    pub raw_length: u32,
    /// Nodes in the page.
    pub node_count: u32,
    /// Triangles in the page.
    pub triangle_count: u32,
}

impl EncodedPage {
    /// What [`file_head`] needs of the page.
    pub fn summary(&self) -> EncodedPageSummary {
        EncodedPageSummary {
            compressed_length: self.frame.len() as u32,
            checksum: xxh3_64(&self.frame),
            raw_length: self.raw_length,
            node_count: self.node_count,
            triangle_count: self.triangle_count,
        }
    }
}

/// The whole tree's layout: its top, then each region root's subtree in leaf order.
fn lay_out(nodes: &impl NodeSource, page_bytes: u32) -> PageLayout {
    let mut layout = PageLayout::top(nodes, page_bytes);
    for root in region_roots(nodes, page_bytes) {
        let n = nodes.node_record(root);
        layout.append(PageLayout::region(
            nodes,
            n.first_child.get(),
            n.child_count,
            page_bytes,
        ));
    }
    layout
}

/// Lays the tree out in pages (its top, then each region in leaf order) and encodes the
/// whole file in memory.
pub fn encode<N: NodeSource>(
    content: &TreeContent<N>,
    options: &WriteOptions,
) -> Result<(Vec<u8>, WriteReport), VdtError> {
    let nodes = &content.nodes;
    let node_count = nodes.node_count();
    if node_count == 0 {
        return Err(VdtError::invalid(
            "tree",
            "a .vdt file needs at least one node",
        ));
    }
    let layout = lay_out(nodes, options.page_bytes);

    // Renumber nodes in page order.
    let mut new_id = vec![NO_NODE; node_count];
    let mut placed = 0usize;
    for old in layout.nodes() {
        new_id[old as usize] = placed as u32;
        placed += 1;
    }
    if placed != node_count || new_id.contains(&NO_NODE) {
        return Err(VdtError::invalid(
            "tree",
            "some nodes are not reachable from the root",
        ));
    }
    let pages = encode_pages(
        nodes,
        &content.triangles,
        &layout,
        &|id| new_id[id as usize],
        0,
        &content.grid,
        options.zstd_level,
    )?;
    drop(new_id);
    let summaries: Vec<_> = pages.iter().map(EncodedPage::summary).collect();
    let figures = FileFigures {
        vertex_count: content.vertex_count,
        max_depth: content.max_depth,
        grid: content.grid,
        metadata: &content.metadata,
    };
    let (mut out, report) = file_head(&summaries, &figures)?;
    out.reserve_exact(report.compressed_page_bytes as usize);
    for page in pages {
        out.extend_from_slice(&page.frame);
    }
    Ok((out, report))
}

/// What a writing thread keeps from page to page: zstd contexts, the encoder's working
/// arrays, and the page's gathered records and encoding (see `PAGE_WORK`).
struct PageWork {
    level: i32,
    compressor: zstd::bulk::Compressor<'static>,
    /// For the pages [`attach_region`] rewrites (a context per call was 1 % of a merge).
    decompressor: zstd::bulk::Decompressor<'static>,
    scratch: crate::codec::EncodeScratch,
    records: Vec<NodeRecord>,
    triangles: Vec<TriangleRecord>,
    raw: Vec<u8>,
}

thread_local! {
    /// Each thread's working arrays and zstd context, kept across calls: a sharded build
    /// encodes its regions a few pages per call, and a zstd context at the default level
    /// allocates and clears megabytes of tables when it is made.
    static PAGE_WORK: std::cell::RefCell<Option<PageWork>> = const { std::cell::RefCell::new(None) };
}

impl PageWork {
    /// Runs `f` with this thread's working arrays, with a compressor at `zstd_level`.
    fn with<T>(zstd_level: i32, f: impl FnOnce(&mut PageWork) -> T) -> T {
        PAGE_WORK.with(|cell| {
            let mut slot = cell.borrow_mut();
            if slot.as_ref().is_none_or(|w| w.level != zstd_level) {
                *slot = Some(PageWork {
                    level: zstd_level,
                    compressor: zstd::bulk::Compressor::new(zstd_level)
                        .expect("a zstd context at a level zstd accepts"),
                    decompressor: zstd::bulk::Decompressor::new()
                        .expect("a zstd decompression context"),
                    scratch: Default::default(),
                    records: Vec::new(),
                    triangles: Vec::new(),
                    raw: Vec::new(),
                });
            }
            f(slot.as_mut().expect("made above"))
        })
    }
}

/// Encodes the tree and writes it to `path` atomically ([`crate::output::write_atomically`]):
/// the bytes go to a temporary file in the same directory, which is renamed over `path` only
/// once complete, so an interrupted or failed write never leaves a partial `.vdt`; stale
/// partials of killed writes are removed, and a `path` that names a device, a directory or
/// anything else that is not a regular file is refused before anything is encoded.
pub fn write_file<N: NodeSource>(
    path: &Path,
    content: &TreeContent<N>,
    options: &WriteOptions,
) -> Result<WriteReport, VdtError> {
    crate::output::resolve_output(path)?;
    let (bytes, report) = encode(content, options)?;
    crate::output::write_atomically(path, |out| out.write_all(&bytes))?;
    Ok(report)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn page(raw: &[u8]) -> EncodedPage {
        EncodedPage {
            frame: zstd::bulk::compress(raw, 1).unwrap(),
            raw_length: raw.len() as u32,
            node_count: 1,
            triangle_count: 0,
        }
    }

    /// A page of empty streams but a parent stream holding `steps`.
    fn raw_with_parents(steps: &[u8]) -> Vec<u8> {
        let mut raw = Vec::new();
        for k in 0..crate::codec::STREAMS {
            let length = if k == 1 { steps.len() } else { 0 };
            raw.extend_from_slice(&(length as u32).to_le_bytes());
        }
        raw.extend_from_slice(steps);
        raw
    }

    #[test]
    fn attaching_rewrites_the_first_parent_step_and_nothing_else() {
        let attached = attach_region(&page(&raw_with_parents(&[1, 0, 0])), 300, 5, 3).unwrap();
        let raw = zstd::bulk::decompress(&attached.frame, attached.raw_length as usize).unwrap();
        // 295 takes two varint bytes: the stream and its length grow by one.
        assert_eq!(raw, raw_with_parents(&[0xa7, 0x02, 0, 0]));
        assert_eq!(
            attached.summary().compressed_length as usize,
            attached.frame.len()
        );
    }

    #[test]
    fn attaching_a_page_that_is_not_a_detached_first_page_is_refused() {
        let cases = [
            (page(b"short"), 10, 2),
            (page(&raw_with_parents(&[])), 10, 2),
            (page(&raw_with_parents(&[7])), 10, 2),
            (page(&raw_with_parents(&[1])), 10, 10),
            (page(&raw_with_parents(&[0x80])), 10, 2),
        ];
        for (page, first, root) in cases {
            assert!(attach_region(&page, first, root, 3).is_err());
        }
        let mut lying = page(&raw_with_parents(&[1]));
        lying.raw_length = 1 << 30;
        assert!(attach_region(&lying, 10, 2, 3).is_err());
        lying.frame = b"not zstd".to_vec();
        lying.raw_length = 8;
        assert!(attach_region(&lying, 10, 2, 3).is_err());
    }
}
