//! The merge: the shards' subtrees joined under the top tree into the file's content.
//!
//! Node ids: the top tree keeps its own (its leaves are the shard roots), and each root's
//! other nodes follow in root order, each subtree in its own breadth-first order. Any order
//! with contiguous children and the root first will do: the writer lays pages out from the
//! tree's shape and renumbers every node in page order. Leaf ranks move by the root's first
//! rank. The top nodes' attributes come from the roots' sums exactly as the in-memory build's
//! levels above its parallel frontier come from theirs, and their error radii scan the
//! leaves, as every node's does.

use rayon::prelude::*;
use vds_format::{
    BuildInfo, InputInfo, Metadata, NO_PART, NodeRecord, PartInfo, TreeContent, TriangleRecord,
};
use zerocopy::little_endian::{U16, U32};

use super::part::{CrossCorner, RootPart, ShardPart};
use super::{Plan, ShardError};
use crate::build::{Accumulator, Sphere, absorb_on, inner_attributes_on};
use crate::isa::Isa;
use crate::tree::Node;
use crate::vdt::{leading_smallest, node_record};

/// Joins the parts of every shard of `plan` (any order, each once) into the content of the
/// `.vdt` file the in-memory build of the same input writes.
pub fn merge(plan: &Plan, parts: &[ShardPart]) -> Result<TreeContent, ShardError> {
    let isa = Isa::detect();
    let set = |reason: String| ShardError::PartSet(reason);
    let mut by_index: Vec<Option<&ShardPart>> = vec![None; plan.shard_count() as usize];
    for part in parts {
        if part.plan_id != plan.id {
            return Err(set(format!(
                "shard {} was built for another plan",
                part.index
            )));
        }
        match by_index.get_mut(part.index as usize) {
            Some(slot @ None) => *slot = Some(part),
            Some(Some(_)) => return Err(set(format!("shard {} is given twice", part.index))),
            None => return Err(set(format!("shard {} is not in the plan", part.index))),
        }
    }
    if let Some(missing) = by_index.iter().position(Option::is_none) {
        return Err(set(format!(
            "shard {missing} of {} is missing",
            plan.shard_count()
        )));
    }
    let roots: Vec<&RootPart> = by_index.iter().flatten().flat_map(|p| &p.roots).collect();
    if roots.len() != plan.roots.len() || roots.iter().enumerate().any(|(r, p)| p.root != r as u32)
    {
        return Err(set("the parts do not hold the plan's roots".into()));
    }

    let top = &plan.top;
    let offset = |r: usize| plan.root_node(r as u32).leaf_begin;
    // Each root's first id for its nodes below the root.
    let mut base = Vec::with_capacity(roots.len());
    let mut next = top.len() as u64;
    for part in &roots {
        base.push(next as u32);
        next += part.nodes.len() as u64 - 1;
    }
    if next > u64::from(u32::MAX) {
        return Err(set(format!("{next} nodes, more than a file holds")));
    }
    let global = |r: usize, local: u32| {
        if local == 0 {
            plan.roots[r]
        } else {
            base[r] + local - 1
        }
    };

    // Leaf positions by global rank, for the top nodes' error radii.
    let mut leaf_positions = vec![[0.0f32; 3]; plan.vertices as usize];
    for (r, part) in roots.iter().enumerate() {
        for n in part.nodes.iter().filter(|n| n.child_count == 0) {
            leaf_positions[(offset(r) + n.leaf_begin.get()) as usize] = n.proxy.map(|c| c.get());
        }
    }

    // The top nodes' attributes, children (later ids) first.
    let mut up: Vec<(Accumulator, Sphere)> =
        vec![(Accumulator::EMPTY, Sphere::default()); top.len()];
    let mut top_records = vec![None; top.len()];
    for (r, part) in roots.iter().enumerate() {
        up[plan.roots[r] as usize] = (part.sums, part.sphere);
    }
    for id in (0..top.len()).rev() {
        let t = &top[id];
        if t.root.is_some() {
            continue;
        }
        let family =
            &up[t.first_child as usize..t.first_child as usize + usize::from(t.child_count)];
        let mut sum = family[0].0;
        for (child, _) in &family[1..] {
            absorb_on(isa, &mut sum, child);
        }
        let node = Node {
            first_child: t.first_child,
            child_count: t.child_count,
            ..Node::topology(t.leaf_begin, t.leaf_end, t.parent, t.depth)
        };
        let spheres: Vec<Sphere> = family.iter().map(|&(_, s)| s).collect();
        let (bounds, sphere) =
            inner_attributes_on(isa, &node, spheres.into_iter(), &sum, &leaf_positions);
        up[id] = (sum, sphere);
        top_records[id] = Some(node_record(&node, Some(&bounds), [0.0; 3]));
    }
    drop(leaf_positions);

    // Every record, with global ids, depths and ranks; subtri ranges are set below.
    let mut records: Vec<NodeRecord> = Vec::with_capacity(next as usize);
    let moved = |r: usize, local: u32, n: &NodeRecord| -> Result<NodeRecord, ShardError> {
        let root_top = &top[plan.roots[r] as usize];
        let mut n = *n;
        n.parent = U32::new(if local == 0 {
            root_top.parent
        } else {
            global(r, n.parent.get())
        });
        if n.child_count > 0 {
            n.first_child = U32::new(global(r, n.first_child.get()));
        }
        let depth = n.depth.get().checked_add(root_top.depth);
        n.depth = U16::new(depth.ok_or_else(|| set("a tree deeper than a file holds".into()))?);
        n.leaf_begin = U32::new(n.leaf_begin.get() + root_top.leaf_begin);
        n.leaf_end = U32::new(n.leaf_end.get() + root_top.leaf_begin);
        Ok(n)
    };
    for (id, t) in top.iter().enumerate() {
        records.push(match t.root {
            Some(r) => moved(r as usize, 0, &roots[r as usize].nodes[0])?,
            None => top_records[id].expect("filled above"),
        });
    }
    for (r, part) in roots.iter().enumerate() {
        for (local, n) in part.nodes.iter().enumerate().skip(1) {
            records.push(moved(r, local as u32, n)?);
        }
    }

    // Triangles with their owners' global ids: each root's own, then those across roots.
    let mut owned: Vec<(u32, TriangleRecord)> = Vec::with_capacity(plan.triangles as usize);
    for (r, part) in roots.iter().enumerate() {
        for (local, n) in part.nodes.iter().enumerate() {
            let begin = n.subtri_begin.get() as usize;
            for t in &part.triangles[begin..begin + n.subtri_count.get() as usize] {
                let mut t = *t;
                t.corners = t.corners.map(|c| U32::new(c.get() + offset(r)));
                owned.push((global(r, local as u32), t));
            }
        }
    }
    let mut cross: Vec<CrossCorner> = by_index
        .iter()
        .flatten()
        .flat_map(|p| p.cross.iter().copied())
        .collect();
    cross.par_sort_unstable();
    for corners in cross.chunk_by(|a, b| a.triangle == b.triangle) {
        let t = corners[0].triangle;
        let complete = corners.len() == 3
            && corners
                .iter()
                .enumerate()
                .all(|(k, c)| usize::from(c.corner) == k);
        if !complete || corners.iter().any(|c| c.part != corners[0].part) {
            return Err(set(format!(
                "triangle {t}: its corners' shards disagree (a part from another build?)"
            )));
        }
        let ranks: [u32; 3] =
            std::array::from_fn(|k| offset(corners[k].root as usize) + corners[k].rank);
        let owner = match corners.iter().find(|c| c.owner != u32::MAX) {
            Some(c) => global(c.root as usize, c.owner),
            None => top_owner(plan, ranks),
        };
        owned.push((
            owner,
            TriangleRecord {
                corners: leading_smallest(ranks).map(U32::new),
                part: U32::new(corners[0].part),
            },
        ));
    }
    drop(cross);
    if owned.len() as u64 != plan.triangles {
        return Err(set(format!(
            "{} triangles, the plan has {}",
            owned.len(),
            plan.triangles
        )));
    }
    // Grouped by node, and within a node in the order the file stores them.
    owned.par_sort_unstable_by_key(|(node, t)| (*node, t.corners.map(|c| c.get()), t.part.get()));
    let mut at = 0usize;
    for (id, n) in records.iter_mut().enumerate() {
        let begin = at;
        while at < owned.len() && owned[at].0 == id as u32 {
            at += 1;
        }
        n.subtri_begin = U32::new(begin as u32);
        n.subtri_count = U32::new((at - begin) as u32);
    }
    let triangles: Vec<TriangleRecord> = owned.into_iter().map(|(_, t)| t).collect();

    let metadata = metadata(plan, &records, &triangles);
    let max_depth = records
        .iter()
        .map(|n| u32::from(n.depth.get()))
        .max()
        .unwrap_or(0);
    Ok(TreeContent {
        nodes: records,
        triangles,
        vertex_count: u64::from(plan.vertices),
        max_depth,
        grid: plan.grid(),
        metadata,
    })
}

/// The top node a triangle with corners under three roots is a subtri of: the deepest one
/// supporting two of its corners (leaf ranks), found as [`crate::VertexTree::subtri_node`]
/// does, from the middle corner's root.
fn top_owner(plan: &Plan, mut ranks: [u32; 3]) -> u32 {
    ranks.sort_unstable();
    let top = &plan.top;
    let mut node = 0usize;
    while top[node].root.is_none() {
        let t = &top[node];
        let children = t.first_child as usize..t.first_child as usize + usize::from(t.child_count);
        node = children
            .into_iter()
            .find(|&c| top[c].leaf_begin <= ranks[1] && ranks[1] < top[c].leaf_end)
            .expect("children partition their parent's ranks");
    }
    loop {
        let t = &top[node];
        if t.leaf_begin <= ranks[0] || t.leaf_end > ranks[2] {
            return node as u32;
        }
        node = t.parent as usize;
    }
}

/// The metadata `vds-build` writes for an in-memory build of the plan's input.
fn metadata(plan: &Plan, records: &[NodeRecord], triangles: &[TriangleRecord]) -> Metadata {
    let m = &plan.metadata;
    let mut degree_histogram = [0u64; 9];
    for n in records {
        degree_histogram[usize::from(n.child_count).min(8)] += 1;
    }
    let mut counts = vec![0u64; m.part_names.len()];
    let mut named = true;
    for t in triangles {
        match counts.get_mut(t.part.get() as usize) {
            Some(count) => *count += 1,
            None => named = false,
        }
    }
    let parts = if named {
        counts
            .iter()
            .enumerate()
            .map(|(i, &triangles)| {
                let (parent, color) = m.parts.get(i).copied().unwrap_or_default();
                PartInfo {
                    parent: parent.filter(|&p| (p as usize) < i).unwrap_or(NO_PART),
                    color: color.map(|c| c.map(f32::from_bits)),
                    triangles,
                }
            })
            .collect()
    } else {
        Vec::new()
    };
    let root = &records[0];
    let (center, radius) = if root.child_count == 0 {
        (root.proxy.map(|c| c.get()), 0.0)
    } else {
        let s = root.sphere.map(|c| c.get());
        ([s[0], s[1], s[2]], s[3])
    };
    Metadata {
        tool: m.tool.clone(),
        build: BuildInfo {
            weld: None,
            zstd_level: m.zstd_level,
            page_bytes: m.page_bytes,
        },
        inputs: m
            .inputs
            .iter()
            .map(|(name, bytes, content_hash)| InputInfo {
                name: name.clone(),
                bytes: *bytes,
                content_hash: *content_hash,
            })
            .collect(),
        part_names: m.part_names.clone(),
        parts,
        bounds_min: [0, 1, 2].map(|k| center[k] - radius),
        bounds_max: [0, 1, 2].map(|k| center[k] + radius),
        input_vertices: m.input_vertices,
        input_triangles: m.input_triangles,
        degree_histogram,
    }
}
