//! A root's subtree cut as the merge takes it: the nodes of the file's top that lie under the
//! root stay records, and each region below them (`vds_format::region_leaves`) is encoded
//! into the file's own pages by the shard, so that the merge copies them; only a region with
//! a node that owns a triangle across roots stays records (its subtris' order and corners
//! wait for the other shards' ranks).
//!
//! A region's pages do not depend on where the region lands in the file but for its first
//! page's first parent (`vds_format::encode_detached_region`), so the shard needs to know
//! only what the plan fixes: the root's depth and first leaf rank, the grid, the page size and
//! the zstd level.

use vds_format::{
    NodeRecord, PageLayout, TriangleRecord, encode_detached_region, in_top_with_children,
};
use zerocopy::little_endian::{U16, U32};

use super::part::{RegionBody, RegionPart, RootPart, SealedRegion, SubtreeRecords};
use super::{Plan, ShardError};

/// No region: a node of the top, or not looked at yet.
const NO_REGION: u32 = u32::MAX;

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
/// corners as the file's ranks) added to their owners' subtris, its top nodes as records, its
/// regions sealed or, where a node in `owners` owns a triangle across shards, open.
pub(crate) fn seal_root(
    plan: &Plan,
    root: u32,
    records: SubtreeRecords,
    mut completed: Vec<(u32, TriangleRecord)>,
    owners: &[u32],
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

    // Which region each node lies in, and which regions own triangles across roots.
    let mut region_of = vec![NO_REGION; nodes.len()];
    for (k, &r) in region_roots.iter().enumerate() {
        let mut stack: Vec<u32> = children(&nodes[r as usize]).collect();
        while let Some(id) = stack.pop() {
            region_of[id as usize] = k as u32;
            stack.extend(children(&nodes[id as usize]));
        }
    }
    let mut open = vec![false; region_roots.len()];
    for &owner in owners {
        if let Some(&k) = region_of.get(owner as usize)
            && k != NO_REGION
        {
            open[k as usize] = true;
        }
    }
    let mut open_ids: Vec<Vec<u32>> = vec![Vec::new(); region_roots.len()];
    for (id, &k) in region_of.iter().enumerate() {
        if k != NO_REGION && open[k as usize] {
            open_ids[k as usize].push(id as u32);
        }
    }

    let grid = plan.grid();
    let mut regions = Vec::with_capacity(region_roots.len());
    for (k, &r) in region_roots.iter().enumerate() {
        let body = if open[k] {
            let ids = std::mem::take(&mut open_ids[k]);
            let (nodes, triangles) = records_of(&nodes, &triangles, &ids);
            RegionBody::Open {
                ids,
                nodes,
                triangles,
            }
        } else {
            let n = &nodes[r as usize];
            let layout = PageLayout::region(&nodes, n.first_child.get(), n.child_count, page_bytes);
            let pages = encode_detached_region(
                &nodes,
                &triangles,
                &layout,
                r,
                &grid,
                plan.metadata.zstd_level,
            )?;
            RegionBody::Sealed(sealed(&nodes, &triangles, &layout, pages))
        };
        regions.push(RegionPart { root: r, body });
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

/// A sealed region: its pages and what the metadata counts of its nodes and triangles.
fn sealed(
    nodes: &[NodeRecord],
    triangles: &[TriangleRecord],
    layout: &PageLayout,
    pages: Vec<vds_format::EncodedPage>,
) -> SealedRegion {
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
    SealedRegion {
        pages,
        degree_histogram,
        max_depth,
        part_triangles,
    }
}
