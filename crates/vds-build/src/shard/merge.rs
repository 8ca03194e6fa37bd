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
use vds_format::{BuildInfo, InputInfo, Metadata, NodeRecord, TreeContent, TriangleRecord};
use zerocopy::FromZeros;
use zerocopy::little_endian::{U16, U32};

use super::part::{CrossCorner, ShardPart};
use super::{Plan, ShardError};
use crate::build::{Accumulator, Sphere, absorb_on, inner_attributes_on};
use crate::isa::Isa;
use crate::tree::Node;
use crate::vdt::{leading_smallest, node_record, part_records_of};

/// Joins the parts of every shard of `plan` (any order, each once) into the content of the
/// `.vdt` file the in-memory build of the same input writes. The parts must come from
/// [`super::build_shard`] or its siblings, or from [`super::read_part`], which checks a file's:
/// the merge trusts their links and ranges.
pub fn merge(plan: &Plan, parts: Vec<ShardPart>) -> Result<TreeContent, ShardError> {
    let mut by_index: Vec<Option<ShardPart>> = vec![None; plan.shard_count() as usize];
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
    merge_in_order(plan, |k| {
        Ok(by_index[k as usize]
            .take()
            .expect("every shard is present, once"))
    })
}

fn set(reason: String) -> ShardError {
    ShardError::PartSet(reason)
}

/// [`merge`], asking `part` for each shard in index order: one part's records are held at a
/// time, and freed once moved into the file's.
pub fn merge_in_order(
    plan: &Plan,
    mut part: impl FnMut(u32) -> Result<ShardPart, ShardError>,
) -> Result<TreeContent, ShardError> {
    let isa = Isa::detect();
    let top = &plan.top;
    // The top tree's nodes keep their ids (its leaves are the roots); each root's other nodes
    // follow, from `base[root]`.
    // Room for the most nodes a tree of this many leaves has (2V - 1): pages of it that are
    // never written are never touched, and the array is never copied as it grows.
    let mut records: Vec<NodeRecord> = Vec::new();
    // `try_`: the figures come from the plan, a file; one that states more than memory holds
    // gets the array grown part by part instead (and fails when the parts really are that
    // large).
    let _ = records.try_reserve_exact(2 * plan.vertices as usize);
    records.resize(top.len(), NodeRecord::new_zeroed());
    let mut base = vec![0u32; plan.roots.len()];
    let id_in = |base: &[u32], r: usize, local: u32| {
        if local == 0 {
            plan.roots[r]
        } else {
            base[r] + local - 1
        }
    };
    let mut up: Vec<(Accumulator, Sphere)> =
        vec![(Accumulator::EMPTY, Sphere::default()); top.len()];
    // Leaf positions by global rank, for the top nodes' error radii.
    let mut leaf_positions: Vec<[f32; 3]> = Vec::new();
    let mut owned: Vec<(u32, TriangleRecord)> = Vec::new();
    let _ = leaf_positions.try_reserve_exact(plan.vertices as usize);
    let _ = owned.try_reserve_exact(plan.triangles as usize);
    let mut cross: Vec<CrossCorner> = Vec::new();
    for k in 0..plan.shard_count() {
        let shard = part(k)?;
        let expected = plan.shard_roots(k);
        if shard.plan_id != plan.id
            || shard.index != k
            || shard.roots.len() != expected.len()
            || shard.roots.iter().zip(expected).any(|(p, r)| p.root != r)
        {
            return Err(set(format!("shard {k} does not hold the plan's roots")));
        }
        cross.extend_from_slice(&shard.cross);
        for root in shard.roots {
            let r = root.root as usize;
            let root_top = &top[plan.roots[r] as usize];
            let offset = root_top.leaf_begin;
            base[r] = records.len() as u32;
            if records.len() as u64 + root.nodes.len() as u64 > u64::from(u32::MAX) {
                return Err(set("more nodes than a file holds".into()));
            }
            up[plan.roots[r] as usize] = (root.sums, root.sphere);
            // Roots come in leaf order: this one's leaves extend the positions.
            leaf_positions.resize(root_top.leaf_end as usize, [0.0; 3]);
            for (local, n) in root.nodes.iter().enumerate() {
                if n.child_count == 0 {
                    leaf_positions[(offset + n.leaf_begin.get()) as usize] =
                        n.proxy.map(|c| c.get());
                }
                let mut moved = *n;
                moved.parent = U32::new(if local == 0 {
                    root_top.parent
                } else {
                    id_in(&base, r, n.parent.get())
                });
                if n.child_count > 0 {
                    moved.first_child = U32::new(id_in(&base, r, n.first_child.get()));
                }
                let depth = n.depth.get().checked_add(root_top.depth);
                moved.depth =
                    U16::new(depth.ok_or_else(|| set("a tree deeper than a file holds".into()))?);
                moved.leaf_begin = U32::new(n.leaf_begin.get() + offset);
                moved.leaf_end = U32::new(n.leaf_end.get() + offset);
                if local == 0 {
                    records[plan.roots[r] as usize] = moved;
                } else {
                    records.push(moved);
                }
                let begin = n.subtri_begin.get() as usize;
                for t in &root.triangles[begin..begin + n.subtri_count.get() as usize] {
                    let mut t = *t;
                    t.corners = t.corners.map(|c| U32::new(c.get() + offset));
                    owned.push((id_in(&base, r, local as u32), t));
                }
            }
        }
    }

    // The top nodes' attributes, children (later ids) first.
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
        records[id] = node_record(&node, Some(&bounds), [0.0; 3]);
    }
    drop(leaf_positions);
    let offset = |r: usize| plan.root_node(r as u32).leaf_begin;
    let global = |r: usize, local: u32| id_in(&base, r, local);

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
    let parts = part_records_of(
        m.part_names.len(),
        |i| {
            let (parent, color) = m.parts.get(i).copied().unwrap_or_default();
            (parent, color.map(|c| c.map(f32::from_bits)))
        },
        triangles.iter().map(|t| t.part.get()),
    );
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
