//! A root's subtree cut as the merge takes it: the nodes of the file's top that lie under the
//! root stay records, and each region below them (`vds_format::region_leaves`) is laid out
//! and encoded into the file's own pages by the shard, so that the merge copies them. Only a
//! page holding a node that owns a triangle across shards stays records: that triangle's
//! corner in another shard has a rank only the merge knows, and with it the order of the
//! node's subtris. The layout counts those triangles, as the merge will place them.
//!
//! A region's pages do not depend on where the region lands in the file but for its first
//! page's first parent (`vds_format::encode_detached_region`), so the shard needs to know
//! only what the plan fixes: the root's depth and first leaf rank, the grid, the page size and
//! the zstd level.

use vds_format::{
    DETACHED_ROOT, NO_NODE, NodeRecord, NodeSource, PageLayout, TriangleRecord, detached_id,
    encode_detached_region, in_top_with_children,
};
use zerocopy::little_endian::{U16, U32};

use super::part::{OpenPage, RegionPage, RegionPart, RootPart, SubtreeRecords};
use super::{Plan, ShardError};

/// A record's leaf count.
pub(super) fn leaf_count(n: &NodeRecord) -> u32 {
    n.leaf_end.get().saturating_sub(n.leaf_begin.get())
}

/// A record's subtri range.
pub(super) fn subtris(n: &NodeRecord) -> std::ops::Range<usize> {
    let begin = n.subtri_begin.get() as usize;
    begin..begin + n.subtri_count.get() as usize
}

/// A record's children's ids.
pub(super) fn children(n: &NodeRecord) -> std::ops::Range<u32> {
    if n.child_count == 0 {
        return 0..0;
    }
    let first = n.first_child.get();
    first..first + u32::from(n.child_count)
}

/// Root `root`'s subtree (`records`, the shard's numbering) as its part: placed in the file
/// (depths and leaf ranks moved by the root's), with the triangles `completed` (owner, and
/// corners as the file's ranks) added to their owners' subtris, its top nodes as records, and
/// its regions' pages, sealed but where a node of `owners` (owner, triangles across shards it
/// owns; by owner) lies.
pub(crate) fn seal_root(
    plan: &Plan,
    root: u32,
    records: SubtreeRecords,
    mut completed: Vec<(u32, TriangleRecord)>,
    owners: &[(u32, u32)],
) -> Result<RootPart, ShardError> {
    let SubtreeRecords {
        mut nodes,
        mut triangles,
        sums,
        sphere,
    } = records;
    let placement = plan.root_node(root);
    for n in &mut nodes {
        let depth =
            n.depth.get().checked_add(placement.depth).ok_or_else(|| {
                ShardError::InputChanged("a tree deeper than a file holds".into())
            })?;
        n.depth = U16::new(depth);
        n.leaf_begin = U32::new(n.leaf_begin.get() + placement.leaf_begin);
        n.leaf_end = U32::new(n.leaf_end.get() + placement.leaf_begin);
    }
    for t in &mut triangles {
        t.corners = t.corners.map(|c| U32::new(c.get() + placement.leaf_begin));
    }
    if !completed.is_empty() {
        triangles = with_completed(&mut nodes, triangles, &mut completed);
    }
    let page_bytes = plan.metadata.page_bytes;
    let expands = |n: &NodeRecord| in_top_with_children(leaf_count(n), plan.vertices, page_bytes);

    // The top under the root, breadth-first as the merge walks it, and the region roots.
    let mut top_ids = vec![0u32];
    let mut region_roots = Vec::new();
    let mut at = 0;
    while let Some(&id) = top_ids.get(at) {
        at += 1;
        let n = &nodes[id as usize];
        if n.child_count == 0 {
            continue;
        }
        if expands(n) {
            top_ids.extend(children(n));
        } else {
            region_roots.push(id);
        }
    }
    top_ids.sort_unstable();
    region_roots.sort_unstable_by_key(|&id| nodes[id as usize].leaf_begin.get());

    let counted = WithOwned {
        nodes: &nodes,
        owners,
    };
    let mut detached = vec![DETACHED_ROOT; nodes.len()];
    let mut regions = Vec::with_capacity(region_roots.len());
    for &r in &region_roots {
        let n = &nodes[r as usize];
        let layout = PageLayout::region(&counted, n.first_child.get(), n.child_count, page_bytes);
        let open: Vec<bool> = (0..layout.page_count())
            .map(|k| layout.page_nodes(k).any(|id| counted.owns(id) > 0))
            .collect();
        let sealed = encode_detached_region(
            &nodes,
            &triangles,
            &layout,
            r,
            |k| !open[k],
            &plan.grid(),
            plan.metadata.zstd_level,
        )?;
        // The detached ids of the region's nodes, for the links of its open pages (a region
        // root lies in no region: its entry stays `DETACHED_ROOT`).
        if open.contains(&true) {
            for (k, id) in layout.nodes().enumerate() {
                detached[id as usize] = detached_id(k);
            }
        }
        let mut pages = Vec::with_capacity(sealed.len());
        for (k, page) in sealed.into_iter().enumerate() {
            pages.push(match page {
                Some(page) => RegionPage::Sealed(page),
                None => RegionPage::Open(open_page(&nodes, &triangles, &layout, k, &detached)),
            });
        }
        regions.push(region_part(r, pages, &nodes, &triangles, &layout));
    }

    let (top_nodes, top_triangles) = records_of(&nodes, &triangles, &top_ids);
    let leaves = nodes
        .iter()
        .filter(|n| n.child_count == 0)
        .map(|n| n.proxy.map(|c| c.get()))
        .collect();
    Ok(RootPart {
        root,
        top_ids,
        top_nodes,
        top_triangles,
        regions,
        leaves,
        sums,
        sphere,
    })
}

/// The subtree's records with the triangles across shards their nodes will own counted in,
/// for the layout.
struct WithOwned<'a> {
    nodes: &'a [NodeRecord],
    owners: &'a [(u32, u32)],
}

impl WithOwned<'_> {
    /// How many triangles across shards node `id` owns.
    fn owns(&self, id: u32) -> u32 {
        self.owners
            .binary_search_by_key(&id, |&(owner, _)| owner)
            .map_or(0, |k| self.owners[k].1)
    }
}

impl NodeSource for WithOwned<'_> {
    fn node_count(&self) -> usize {
        self.nodes.len()
    }

    fn node_record(&self, id: u32) -> NodeRecord {
        let mut n = self.nodes[id as usize];
        n.subtri_count = U32::new(n.subtri_count.get() + self.owns(id));
        n
    }
}

/// Page `k` of a region's `layout` as records, links as `detached` ids.
fn open_page(
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
    layout: &PageLayout,
    k: usize,
    detached: &[u32],
) -> OpenPage {
    let ids: Vec<u32> = layout.page_nodes(k).collect();
    let (mut records, triangles) = records_of(nodes, triangles, &ids);
    for n in &mut records {
        n.parent = U32::new(detached[n.parent.get() as usize]);
        if n.first_child.get() != NO_NODE {
            n.first_child = U32::new(detached[n.first_child.get() as usize]);
        }
    }
    OpenPage {
        first: detached[ids[0] as usize],
        ids,
        nodes: records,
        triangles,
    }
}

/// A region's part: its pages, and what the metadata counts of its nodes and own triangles.
fn region_part(
    root: u32,
    pages: Vec<RegionPage>,
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
    layout: &PageLayout,
) -> RegionPart {
    let mut degree_histogram = [0u64; 9];
    let mut max_depth = 0u32;
    let mut parts = Vec::new();
    for id in layout.nodes() {
        let n = &nodes[id as usize];
        degree_histogram[usize::from(n.child_count).min(8)] += 1;
        max_depth = max_depth.max(u32::from(n.depth.get()));
        parts.extend(triangles[subtris(n)].iter().map(|t| t.part.get()));
    }
    parts.sort_unstable();
    let part_triangles = parts
        .chunk_by(|a, b| a == b)
        .map(|run| (run[0], run.len() as u64))
        .collect();
    RegionPart {
        root,
        pages,
        degree_histogram,
        max_depth,
        part_triangles,
    }
}

/// The subtris of `nodes` with `completed` (by owner) added, each node's sorted as the file
/// stores them; the nodes' subtri ranges are moved to the result.
fn with_completed(
    nodes: &mut [NodeRecord],
    triangles: Vec<TriangleRecord>,
    completed: &mut [(u32, TriangleRecord)],
) -> Vec<TriangleRecord> {
    completed.sort_unstable_by_key(|&(owner, _)| owner);
    let mut all = Vec::with_capacity(triangles.len() + completed.len());
    let mut extra = completed.iter().peekable();
    for (id, n) in nodes.iter_mut().enumerate() {
        let begin = all.len();
        all.extend_from_slice(&triangles[subtris(n)]);
        let own = all.len();
        while let Some((_, t)) = extra.next_if(|(owner, _)| *owner == id as u32) {
            all.push(*t);
        }
        if all.len() > own {
            all[begin..].sort_unstable_by_key(|t| (t.corners.map(|c| c.get()), t.part.get()));
        }
        n.subtri_begin = U32::new(begin as u32);
        n.subtri_count = U32::new((all.len() - begin) as u32);
    }
    all
}

/// The records of nodes `ids` and their subtris, with subtri ranges into the latter.
fn records_of(
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
    ids: &[u32],
) -> (Vec<NodeRecord>, Vec<TriangleRecord>) {
    let mut records = Vec::with_capacity(ids.len());
    let mut owned = Vec::new();
    for &id in ids {
        let mut n = nodes[id as usize];
        let range = subtris(&n);
        n.subtri_begin = U32::new(owned.len() as u32);
        owned.extend_from_slice(&triangles[range]);
        records.push(n);
    }
    (records, owned)
}
