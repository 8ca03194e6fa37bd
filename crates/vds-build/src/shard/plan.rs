//! The plan of a sharded build: the file's grid, the top levels of the tight octree, which
//! shard builds which roots, and what the merge writes into the file's metadata.
//!
//! The top tree is found in passes over the vertices, one per level: a pass walks each vertex
//! down the levels already split and, at the node being split, adds it to its octant's count
//! and bounds, which are the children's sizes and the bounds that decide the children's own
//! splits. The split itself is the octree's ([`crate::octree`]): the same split point and
//! octant test, children in octant order. A node stops being split, and becomes a *shard
//! root*, when it holds at most an eighth of a shard's share of the vertices or at most a
//! region of the file's pages (`vds_format::region_leaves`: the merge lays out each region
//! from one part, so no node a region could hold is split), when its
//! vertices coincide, when rounding would leave them in one octant (the octree then cuts
//! balanced chunks, which depend on the vertex order the shard sees anyway), or at depth
//! [`MAX_TOP_DEPTH`] (which bounds the passes; such a root may hold more than a shard's share,
//! and its shard is then larger than the others). Roots are handed to shards in leaf order, a
//! contiguous run each, balanced by vertex count.

use std::path::Path;

use rayon::prelude::*;
use serde::{Deserialize, Serialize};
use vds_format::Grid;
use xxhash_rust::xxh3::xxh3_64;

use super::ShardError;
use crate::bounds::Aabb;
use crate::octree::{octant_of, split_point};

/// The plan format this crate writes and reads.
pub const PLAN_FORMAT: u32 = 2;

/// Top levels deeper than this are not split further: a shard's subtree is as good a place
/// for them, and it bounds the plan's passes over the input.
pub const MAX_TOP_DEPTH: u16 = 12;

/// One node of the top tree. Its children are `first_child .. first_child + child_count`,
/// one per non-empty octant (`octants`, bit `k` for octant `k`) in octant order.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TopNode {
    /// Parent, or `u32::MAX` for the root.
    pub parent: u32,
    /// First child (top nodes); 0 for a shard root.
    pub first_child: u32,
    /// Number of children: 0 for a shard root.
    pub child_count: u8,
    /// Depth below the root.
    pub depth: u16,
    /// First leaf rank under the node.
    pub leaf_begin: u32,
    /// One past the last.
    pub leaf_end: u32,
    /// The split point's bits (`f32::to_bits`), for a split node.
    pub split: Option<[u32; 3]>,
    /// Which octants hold children (a split node).
    pub octants: u8,
    /// The node's index among the shard roots, for a root.
    pub root: Option<u32>,
}

/// What the merge writes into the file's metadata besides what the tree gives: the same as
/// `vds-build` writes for an in-memory build. Colours are `f32` bits.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct PlanMetadata {
    /// The writing tool.
    pub tool: String,
    /// zstd level of the pages.
    pub zstd_level: i32,
    /// Target raw bytes per page.
    pub page_bytes: u32,
    /// Input files: name, size and XXH3-64 of the contents.
    pub inputs: Vec<(String, u64, u64)>,
    /// Part names.
    pub part_names: Vec<String>,
    /// Each part's parent and colour (bits), as imported; empty for a scene made by hand.
    pub parts: Vec<(Option<u32>, Option<[u32; 4]>)>,
    /// Vertices as read, before welding.
    pub input_vertices: u64,
    /// Triangles as read, before dropping degenerate ones.
    pub input_triangles: u64,
}

impl PlanMetadata {
    /// What a build of `scene` records: its parts and import counts, with the tool, page
    /// options and input files given.
    pub fn of_scene(
        scene: &vds_import::Scene,
        tool: String,
        options: &vds_format::WriteOptions,
        inputs: Vec<(String, u64, u64)>,
    ) -> PlanMetadata {
        PlanMetadata::of_parts(
            &scene.part_names,
            &scene.parts,
            &scene.stats,
            tool,
            options,
            inputs,
        )
    }

    /// [`PlanMetadata::of_scene`] from a scene's parts and import counts (a scene whose
    /// triangles are elsewhere).
    pub fn of_parts(
        part_names: &[String],
        parts: &[vds_import::PartInfo],
        stats: &vds_import::ImportStats,
        tool: String,
        options: &vds_format::WriteOptions,
        inputs: Vec<(String, u64, u64)>,
    ) -> PlanMetadata {
        PlanMetadata {
            tool,
            zstd_level: options.zstd_level,
            page_bytes: options.page_bytes,
            inputs,
            part_names: part_names.to_vec(),
            parts: parts
                .iter()
                .map(|p| (p.parent, p.color.map(|c| c.map(f32::to_bits))))
                .collect(),
            input_vertices: stats.input_vertices,
            input_triangles: stats.input_triangles,
        }
    }
}

/// A sharded build's plan: written once, read by every shard and by the merge.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Plan {
    /// [`PLAN_FORMAT`].
    pub format: u32,
    /// XXH3-64 of the plan's compact JSON (`serde_json::to_vec`) with this field 0: every
    /// part names the plan it was built for, and a plan edited by hand no longer matches its
    /// id. (The file itself is written pretty-printed.)
    pub id: u64,
    /// Each shard's input file (written by `vds-build plan`), named relative to the plan's
    /// folder; empty when the plan's maker passes shards their input another way.
    pub input_files: Vec<String>,
    /// How many triangles each shard's input holds (those with a corner in the shard).
    pub shard_triangles: Vec<u64>,
    /// The grid's origin and step, as `f32` bits.
    pub grid: ([u32; 3], u32),
    /// Welded vertices (leaves).
    pub vertices: u32,
    /// Triangles after welding.
    pub triangles: u64,
    /// The top tree; node 0 is the octree's root.
    pub top: Vec<TopNode>,
    /// The top node of each shard root, in leaf order.
    pub roots: Vec<u32>,
    /// Where each shard's run of roots starts, and the end: shard `k` builds roots
    /// `shard_starts[k] .. shard_starts[k + 1]`.
    pub shard_starts: Vec<u32>,
    /// For the file's metadata.
    pub metadata: PlanMetadata,
}

impl Plan {
    /// Number of shards.
    pub fn shard_count(&self) -> u32 {
        self.shard_starts.len().saturating_sub(1) as u32
    }

    /// The roots shard `index` builds.
    pub fn shard_roots(&self, index: u32) -> std::ops::Range<u32> {
        let k = index as usize;
        self.shard_starts[k]..self.shard_starts[k + 1]
    }

    /// The top node of root `root`.
    pub fn root_node(&self, root: u32) -> &TopNode {
        &self.top[self.roots[root as usize] as usize]
    }

    /// The file's grid.
    pub fn grid(&self) -> Grid {
        Grid {
            origin: self.grid.0.map(f32::from_bits),
            step: f32::from_bits(self.grid.1),
        }
    }

    /// The root whose cell holds `p` (a snapped position), or `None` when `p` falls in an
    /// octant the plan found empty (the input is not the plan's).
    pub fn locate(&self, p: [f32; 3]) -> Option<u32> {
        let mut node = &self.top[0];
        loop {
            if let Some(root) = node.root {
                return Some(root);
            }
            let mid = node.split?.map(f32::from_bits);
            let octant = octant_of(p, mid);
            if node.octants & (1 << octant) == 0 {
                return None;
            }
            let before = (node.octants & ((1u8 << octant) - 1)).count_ones();
            node = self.top.get((node.first_child + before) as usize)?;
        }
    }

    /// Sets the id from the contents: call after changing any field.
    pub fn seal(&mut self) {
        self.id = self.digest();
    }

    /// The most triangles shard `index`'s input holds: its count when the plan records one,
    /// else every triangle.
    pub fn triangles_of_shard(&self, index: u32) -> u64 {
        self.shard_triangles
            .get(index as usize)
            .copied()
            .unwrap_or(self.triangles)
    }

    /// Refuses a shard index the plan does not have.
    pub fn check_index(&self, index: u32) -> Result<(), ShardError> {
        if index >= self.shard_count() {
            return Err(ShardError::NoSuchShard {
                index,
                shards: self.shard_count(),
            });
        }
        Ok(())
    }

    /// The plan's id: XXH3-64 of its JSON with `id` 0.
    fn digest(&self) -> u64 {
        let mut unnamed = self.clone();
        unnamed.id = 0;
        xxh3_64(&serde_json::to_vec(&unnamed).expect("a plan serialises"))
    }

    /// Writes the plan as JSON (a temporary file, then renamed).
    pub fn save(&self, path: &Path) -> Result<(), ShardError> {
        let json = serde_json::to_vec_pretty(self).expect("a plan serialises");
        Ok(vds_format::write_atomically(path, |out| {
            out.write_all(&json)
        })?)
    }

    /// Reads a plan and checks it: its id, and that its top tree and shards are consistent
    /// (so a shard or merge can index by them without further checks).
    pub fn load(path: &Path) -> Result<Plan, ShardError> {
        let bad = |reason: String| ShardError::BadPlan {
            path: path.to_path_buf(),
            reason,
        };
        // A plan is a few hundred bytes per shard root; a gigabyte is not a plan.
        const MAX_PLAN_BYTES: u64 = 1 << 30;
        let size = super::container::file_size(path)?;
        if size > MAX_PLAN_BYTES {
            return Err(bad(format!("{size} bytes, more than a plan holds")));
        }
        let text = std::fs::read(path).map_err(|source| ShardError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Plan::from_json(&text).map_err(bad)
    }

    /// A plan from its JSON, checked as [`Plan::load`] checks a file.
    pub fn from_json(text: &[u8]) -> Result<Plan, String> {
        let plan: Plan = serde_json::from_slice(text).map_err(|e| e.to_string())?;
        if plan.format != PLAN_FORMAT {
            return Err(format!(
                "format {}, this build reads {PLAN_FORMAT}",
                plan.format
            ));
        }
        if plan.digest() != plan.id {
            return Err("its id does not match its contents (edited?)".into());
        }
        plan.check()?;
        Ok(plan)
    }

    /// The structural checks of [`Plan::from_json`].
    fn check(&self) -> Result<(), String> {
        let top = &self.top;
        if top.is_empty() || self.vertices == 0 {
            return Err("an empty top tree".into());
        }
        if top[0].leaf_begin != 0
            || top[0].leaf_end != self.vertices
            || top[0].depth != 0
            || top[0].parent != u32::MAX
        {
            return Err("the root does not span every vertex".into());
        }
        // Triangle ids are `u32` in the builder, as in the in-memory build.
        if self.triangles > u64::from(u32::MAX) {
            return Err(format!(
                "{} triangles, more than a build holds",
                self.triangles
            ));
        }
        let mut roots_seen = 0u32;
        for (id, node) in top.iter().enumerate() {
            if node.leaf_begin >= node.leaf_end {
                return Err(format!("top node {id} has no vertices"));
            }
            match node.root {
                Some(root) => {
                    if node.child_count != 0 || self.roots.get(root as usize) != Some(&(id as u32))
                    {
                        return Err(format!("top node {id}: root {root} is not listed"));
                    }
                    roots_seen += 1;
                }
                None => {
                    // The merge lays out each region of the file from one part: a region
                    // must not span roots.
                    if node.leaf_end - node.leaf_begin
                        <= vds_format::region_leaves(self.metadata.page_bytes)
                    {
                        return Err(format!(
                            "top node {id} is split but holds no more than a region of pages"
                        ));
                    }
                    let count = u32::from(node.child_count);
                    let first = node.first_child as usize;
                    if node.split.is_none()
                        || !(2..=8).contains(&count)
                        || node.octants.count_ones() != count
                        || first <= id
                        || first + count as usize > top.len()
                    {
                        return Err(format!("top node {id} is not a valid split"));
                    }
                    let mut at = node.leaf_begin;
                    for child in &top[first..first + count as usize] {
                        if child.parent != id as u32
                            || Some(child.depth) != node.depth.checked_add(1)
                            || child.leaf_begin != at
                        {
                            return Err(format!("top node {id}: children do not partition it"));
                        }
                        at = child.leaf_end;
                    }
                    if at != node.leaf_end {
                        return Err(format!("top node {id}: children do not partition it"));
                    }
                }
            }
        }
        if !self.input_files.is_empty() && self.input_files.len() != self.shard_count() as usize
            || self.input_files.iter().any(|name| {
                let path = Path::new(name);
                path.components().count() != 1 || path.file_name().is_none()
            })
        {
            return Err("shard input files must be one plain file name per shard".into());
        }
        if roots_seen as usize != self.roots.len() {
            return Err("a listed root is not a top node's".into());
        }
        let mut at = 0;
        for &node in &self.roots {
            let node = &top[node as usize];
            if node.leaf_begin != at {
                return Err("roots are not in leaf order".into());
            }
            at = node.leaf_end;
        }
        if at != self.vertices {
            return Err("the roots do not cover every vertex".into());
        }
        let starts = &self.shard_starts;
        if starts.len() < 2
            || starts[0] != 0
            || starts[starts.len() - 1] as usize != self.roots.len()
            || starts.windows(2).any(|w| w[0] > w[1])
        {
            return Err("shards do not cover the roots in order".into());
        }
        if !self.shard_triangles.is_empty()
            && (self.shard_triangles.len() != self.shard_count() as usize
                || self.shard_triangles.iter().any(|&n| n > self.triangles))
        {
            return Err("a shard's triangle count that does not fit the plan".into());
        }
        Ok(())
    }
}

/// Plans a sharded build of `positions` (welded and snapped to `grid`, in input order, every
/// one used by a triangle, as an imported scene's are) into `shards` shards. `triangles` and `metadata` are recorded for the shards and the merge.
pub fn plan(
    positions: &[[f32; 3]],
    triangles: u64,
    grid: Grid,
    shards: u32,
    metadata: PlanMetadata,
) -> Result<Plan, ShardError> {
    if positions.is_empty() {
        return Err(ShardError::Empty);
    }
    let vertices = positions.len() as u32;
    let shards = shards.max(1);
    // Roots of at most an eighth of a shard's share: runs of them balance shards well. And no
    // node that a region of the file's pages could hold is split, so that every region lies
    // under one root and the merge lays out each shard's regions from that shard's part alone.
    let root_target = vertices
        .div_ceil(shards.saturating_mul(8))
        .max(vds_format::region_leaves(metadata.page_bytes));

    let mut whole = Aabb::EMPTY;
    for &p in positions {
        whole.add_point(p);
    }
    let mut top = vec![TopNode {
        parent: u32::MAX,
        first_child: 0,
        child_count: 0,
        depth: 0,
        leaf_begin: 0,
        leaf_end: vertices,
        split: None,
        octants: 0,
        root: None,
    }];
    // Nodes to split on the next pass, with their vertices' bounds.
    let mut pending: Vec<(u32, Aabb)> = vec![(0, whole)];
    let mut finished: Vec<u32> = Vec::new();
    while !pending.is_empty() {
        let mut splitting = Vec::new();
        for (id, bounds) in pending.drain(..) {
            let node = &mut top[id as usize];
            let count = node.leaf_end - node.leaf_begin;
            match split_point(&bounds) {
                Some(mid) if count > root_target && node.depth < MAX_TOP_DEPTH => {
                    node.split = Some(mid.map(f32::to_bits));
                    splitting.push(id);
                }
                _ => finished.push(id),
            }
        }
        if splitting.is_empty() {
            break;
        }
        // One pass: each vertex's octant in the node being split that holds it.
        let mut slot_of = vec![u32::MAX; top.len()];
        for (slot, &id) in splitting.iter().enumerate() {
            slot_of[id as usize] = slot as u32;
        }
        let (counts, boxes) = octant_tallies(positions, &top, &slot_of, splitting.len());
        for (slot, &id) in splitting.iter().enumerate() {
            let octants = (0..8)
                .filter(|&k| counts[slot][k] > 0)
                .fold(0u8, |m, k| m | 1 << k);
            if octants.count_ones() < 2 {
                // Rounding put every vertex in one octant: the octree cuts balanced chunks.
                top[id as usize].split = None;
                finished.push(id);
                continue;
            }
            let first = top.len() as u32;
            let (depth, mut at) = (top[id as usize].depth + 1, top[id as usize].leaf_begin);
            for k in 0..8 {
                if counts[slot][k] == 0 {
                    continue;
                }
                pending.push((top.len() as u32, boxes[slot][k]));
                top.push(TopNode {
                    parent: id,
                    first_child: 0,
                    child_count: 0,
                    depth,
                    leaf_begin: at,
                    leaf_end: at + counts[slot][k],
                    split: None,
                    octants: 0,
                    root: None,
                });
                at += counts[slot][k];
            }
            let node = &mut top[id as usize];
            node.first_child = first;
            node.child_count = octants.count_ones() as u8;
            node.octants = octants;
        }
    }

    finished.sort_by_key(|&id| top[id as usize].leaf_begin);
    for (root, &id) in finished.iter().enumerate() {
        top[id as usize].root = Some(root as u32);
        top[id as usize].split = None;
    }
    let shard_starts = balanced_runs(&top, &finished, shards);
    let mut plan = Plan {
        format: PLAN_FORMAT,
        id: 0,
        input_files: Vec::new(),
        shard_triangles: Vec::new(),
        grid: (grid.origin.map(f32::to_bits), grid.step.to_bits()),
        vertices,
        triangles,
        top,
        roots: finished,
        shard_starts,
        metadata,
    };
    plan.seal();
    Ok(plan)
}

/// One pass of [`plan()`]: for each node being split (`slot_of` gives its slot, `u32::MAX`
/// for the others), how many of `positions` fall in each of its octants and their bounds.
/// Runs of chunks of the positions are tallied side by side and the tallies summed in order:
/// counts are integers and bounds minima and maxima that keep the first of equal values, so
/// the result is the serial pass's.
fn octant_tallies(
    positions: &[[f32; 3]],
    top: &[TopNode],
    slot_of: &[u32],
    slots: usize,
) -> (Vec<[u32; 8]>, Vec<[Aabb; 8]>) {
    // Large enough that summing tallies (28 bytes an octant) costs little beside making them.
    const CHUNK: usize = 1 << 16;
    let empty = || (vec![[0u32; 8]; slots], vec![[Aabb::EMPTY; 8]; slots]);
    positions
        .par_chunks(CHUNK)
        .fold(empty, |(mut counts, mut boxes), chunk| {
            for &p in chunk {
                let mut id = 0u32;
                loop {
                    let node = &top[id as usize];
                    let Some(mid) = node.split else {
                        break; // a finished node: a root
                    };
                    let octant = octant_of(p, mid.map(f32::from_bits));
                    let slot = slot_of[id as usize];
                    if slot != u32::MAX {
                        counts[slot as usize][octant] += 1;
                        boxes[slot as usize][octant].add_point(p);
                        break;
                    }
                    let before = (node.octants & ((1u8 << octant) - 1)).count_ones();
                    id = node.first_child + before;
                }
            }
            (counts, boxes)
        })
        .reduce_with(|(mut counts, mut boxes), (more_counts, more_boxes)| {
            for (c, m) in counts.iter_mut().zip(&more_counts) {
                for (a, b) in c.iter_mut().zip(m) {
                    *a += b;
                }
            }
            for (c, m) in boxes.iter_mut().zip(&more_boxes) {
                for (a, b) in c.iter_mut().zip(m) {
                    a.add_box(b);
                }
            }
            (counts, boxes)
        })
        .unwrap_or_else(empty)
}

/// Cuts the roots (in leaf order) into `shards` contiguous runs of about equal vertex counts:
/// run `k` ends at the first root that starts at or past `(k + 1) / shards` of the vertices.
fn balanced_runs(top: &[TopNode], roots: &[u32], shards: u32) -> Vec<u32> {
    let total = u64::from(top[0].leaf_end);
    let mut starts = vec![0u32];
    let mut root = 0usize;
    for k in 1..u64::from(shards) {
        let goal = total * k / u64::from(shards);
        while root < roots.len() && u64::from(top[roots[root] as usize].leaf_begin) < goal {
            root += 1;
        }
        starts.push(root as u32);
    }
    starts.push(roots.len() as u32);
    starts
}
