//! One shard's build: the subtrees of its run of roots, from the triangles that touch them.
//!
//! The shard keeps every triangle with a corner among its vertices, in input order, and
//! numbers the vertices those triangles use (its own and the *ghost* corners that lie
//! elsewhere) in input order. Each root's vertices, in that order, are clustered by the
//! octree exactly as the in-memory build clusters that node's range, and the attribute pass
//! runs over the root's subtree with the shard's triangles as the adjacency: a vertex's
//! incident triangles are all there, in triangle order, so every sum is taken in the same
//! order as in the in-memory build. What a root passes to its parent (its accumulated sums
//! and sphere) goes into the part for the merge.

use rayon::prelude::*;
use vds_format::{EncodedPage, NodeRecord, TriangleRecord};
use vds_import::Scene;
use zerocopy::little_endian::{F32, U32, U64};
use zerocopy::{FromBytes, FromZeros, Immutable, IntoBytes, KnownLayout, Unaligned};

use super::numbering::Mismatch;
use super::{Plan, PlanScene, ShardError};
use crate::build::{Accumulator, Adjacency, Inputs, Sphere, compute_attributes, leaf_tables};
use crate::isa::Isa;
use crate::octree::cluster_with;
use crate::tree::{Node, subtri_node_of_ranks};
use crate::vdt::{leading_smallest, node_record};

/// One root's subtree, as the shard hands it to the merge: the nodes of the file's top that
/// lie under the root as records, and below them the regions (`vds_format::region_leaves`),
/// each encoded into the file's pages by the shard where it can be. Records hold the file's
/// depths and leaf ranks; their links are node ids of the subtree (node 0 is the root,
/// children after their parent).
#[derive(Debug, Clone, PartialEq)]
pub struct RootPart {
    /// The root's index in the plan.
    pub root: u32,
    /// Subtree ids of the nodes in the file's top (the root, each node with more than a
    /// region's leaves, and their children), ascending.
    pub top_ids: Vec<u32>,
    /// Their records, in the same order; `subtri_begin` indexes `top_triangles`.
    pub top_nodes: Vec<NodeRecord>,
    /// The top nodes' subtris whose corners all lie under the root, grouped by node.
    pub top_triangles: Vec<TriangleRecord>,
    /// The regions below the top nodes, in leaf order.
    pub regions: Vec<RegionPart>,
    /// Every leaf's position: the merge measures the error radii of the nodes above the root.
    pub leaves: Vec<[f32; 3]>,
    /// What the root passes to its parent.
    pub(crate) sums: Accumulator,
    /// The root's bounding sphere as passed up (a leaf's is not in its record).
    pub(crate) sphere: Sphere,
}

/// The subtree below one region root: its pages, each encoded by the shard unless it holds
/// a node that owns a triangle across shards (whose other corners' ranks only the merge
/// knows), and what the file's metadata counts of it.
#[derive(Debug, Clone, PartialEq)]
pub struct RegionPart {
    /// The region root's id in the subtree (a top node).
    pub root: u32,
    /// Its pages, in order, laid out with the triangles across shards counted.
    pub pages: Vec<RegionPage>,
    /// Its nodes by child count (8 for eight or more), as the metadata's histogram.
    pub degree_histogram: [u64; 9],
    /// Its deepest node's depth.
    pub max_depth: u32,
    /// Its triangles per part, (part, count) by part, without those across shards.
    pub part_triangles: Vec<(u32, u64)>,
}

/// One page of a region.
#[derive(Debug, Clone, PartialEq)]
pub enum RegionPage {
    /// The page compressed, from `vds_format::encode_detached_region`: the merge copies it
    /// (the region's first page rebased by `vds_format::attach_region`).
    Sealed(EncodedPage),
    /// A page with triangles across shards: its records, for the merge to encode.
    Open(OpenPage),
}

/// The records of a page the merge encodes.
#[derive(Debug, Clone, PartialEq)]
pub struct OpenPage {
    /// The region-relative id of its first node (`vds_format::detached_id`).
    pub first: u32,
    /// Subtree ids of its nodes, in page order (to find the triangles across shards they own).
    pub ids: Vec<u32>,
    /// Their records, links as region-relative ids (0: the region root), subtri counts
    /// without the triangles across shards.
    pub nodes: Vec<NodeRecord>,
    /// The nodes' own subtris, in node order.
    pub triangles: Vec<TriangleRecord>,
}

impl RegionPage {
    /// Nodes in the page.
    pub fn node_count(&self) -> u64 {
        match self {
            RegionPage::Sealed(page) => u64::from(page.node_count),
            RegionPage::Open(page) => page.ids.len() as u64,
        }
    }

    /// Triangles the part holds of the page (an open page's without those across shards).
    pub fn triangle_count(&self) -> u64 {
        match self {
            RegionPage::Sealed(page) => u64::from(page.triangle_count),
            RegionPage::Open(page) => page.triangles.len() as u64,
        }
    }
}

/// One corner of a triangle whose corners lie under two or three roots: the corner's root and
/// leaf rank under it, reported by the shard that holds the corner.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct CrossCorner {
    /// The triangle's index in the welded scene.
    pub triangle: u64,
    /// Which corner (0..3).
    pub corner: u8,
    /// The root holding the corner.
    pub root: u32,
    /// The corner's leaf rank under its root.
    pub rank: u32,
    /// The triangle's part.
    pub part: u32,
    /// When two of the triangle's corners lie under this corner's root, the subtree node the
    /// triangle is a subtri of; else `u32::MAX`.
    pub owner: u32,
}

/// A shard's output: its roots' subtrees and its corners of triangles across roots.
#[derive(Debug, Clone, PartialEq)]
pub struct ShardPart {
    /// The plan it was built for ([`Plan::id`]).
    pub plan_id: u64,
    /// The shard's index.
    pub index: u32,
    /// Its roots, in plan order.
    pub roots: Vec<RootPart>,
    /// Its corners of triangles whose corners lie under two or more roots, by triangle.
    pub cross: Vec<CrossCorner>,
}

/// No root: a vertex outside the shard.
const ELSEWHERE: u32 = u32::MAX;

/// One triangle as a shard reads it: its index in the welded scene, its part, and its
/// corners' welded vertex ids.
#[derive(
    Debug, Clone, Copy, PartialEq, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned,
)]
#[repr(C)]
pub struct InputTriangle {
    /// Index in the welded scene.
    pub triangle: U64,
    /// Part id.
    pub part: U32,
    /// The corners' welded vertex ids.
    pub vertices: [U32; 3],
}

/// One vertex as a shard reads it: its welded id and its position (snapped to the plan's
/// grid).
#[derive(
    Debug, Clone, Copy, PartialEq, FromBytes, IntoBytes, KnownLayout, Immutable, Unaligned,
)]
#[repr(C)]
pub struct InputVertex {
    /// Welded vertex id.
    pub vertex: U32,
    /// Position.
    pub position: [F32; 3],
}

/// What a shard reads: every triangle with a corner under one of its roots, in scene order,
/// and every vertex those triangles use, in id order (its own and the corners that lie under
/// other shards' roots), each once. What `vds-build plan` writes to each shard's input file.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct ShardInput {
    /// The triangles, in scene order.
    pub triangles: Vec<InputTriangle>,
    /// The vertices they use, in id order.
    pub vertices: Vec<InputVertex>,
}

/// The root of every vertex of `scene` (welded, snapped: the scene the plan was made from),
/// checked against the plan's counts.
pub fn roots_of_vertices(scene: &impl PlanScene, plan: &Plan) -> Result<Vec<u32>, ShardError> {
    let positions = scene.positions();
    if positions.len() != plan.vertices as usize || scene.triangle_count() != plan.triangles {
        return Err(ShardError::InputChanged(format!(
            "{} vertices and {} triangles, the plan has {} and {}",
            positions.len(),
            scene.triangle_count(),
            plan.vertices,
            plan.triangles
        )));
    }
    let root_of: Vec<u32> = positions
        .par_iter()
        .map(|&p| plan.locate(p).unwrap_or(ELSEWHERE))
        .collect();
    let mut counts = vec![0u32; plan.roots.len()];
    for &root in &root_of {
        match counts.get_mut(root as usize) {
            Some(count) => *count += 1,
            None => {
                return Err(ShardError::InputChanged(
                    "a vertex lies where the plan found none".into(),
                ));
            }
        }
    }
    check_counts(plan, 0..plan.roots.len() as u32, &counts)?;
    Ok(root_of)
}

/// Each root's vertex count, from `counts` (indexed from `roots.start`), against the plan's.
fn check_counts(
    plan: &Plan,
    roots: std::ops::Range<u32>,
    counts: &[u32],
) -> Result<(), ShardError> {
    for (root, &count) in roots.zip(counts) {
        let node = plan.root_node(root);
        if count != node.leaf_end - node.leaf_begin {
            return Err(ShardError::InputChanged(format!(
                "root {root} holds {count} vertices, the plan counted {}",
                node.leaf_end - node.leaf_begin
            )));
        }
    }
    Ok(())
}

/// Shard `index`'s input from `scene` (`root_of` from [`roots_of_vertices`]).
pub fn shard_input_of(scene: &Scene, plan: &Plan, root_of: &[u32], index: u32) -> ShardInput {
    let mine = plan.shard_roots(index);
    let triangles: Vec<InputTriangle> = (0..scene.triangles.len())
        .into_par_iter()
        .filter_map(|t| {
            let corners = scene.triangles[t];
            corners
                .iter()
                .any(|&v| mine.contains(&root_of[v as usize]))
                .then(|| input_triangle(t as u64, scene.triangle_parts[t], corners))
        })
        .collect();
    let mut used: Vec<u32> = triangles
        .iter()
        .flat_map(|t| t.vertices.map(|v| v.get()))
        .collect();
    used.par_sort_unstable();
    used.dedup();
    let vertices = used
        .into_iter()
        .map(|v| input_vertex(v, &scene.positions))
        .collect();
    ShardInput {
        triangles,
        vertices,
    }
}

/// Triangle `t` of a scene (in `part`, with `corners`) as a shard reads it.
pub fn input_triangle(t: u64, part: u32, corners: [u32; 3]) -> InputTriangle {
    InputTriangle {
        triangle: U64::new(t),
        part: U32::new(part),
        vertices: corners.map(U32::new),
    }
}

/// Vertex `v` of a scene's `positions` as a shard reads it.
pub fn input_vertex(v: u32, positions: &[[f32; 3]]) -> InputVertex {
    InputVertex {
        vertex: U32::new(v),
        position: positions[v as usize].map(F32::new),
    }
}

/// Builds shard `index` of `plan` from `scene` (welded, snapped to the plan's grid: the scene
/// the plan was made from).
pub fn build_shard(scene: &Scene, plan: &Plan, index: u32) -> Result<ShardPart, ShardError> {
    plan.check_index(index)?;
    let root_of = roots_of_vertices(scene, plan)?;
    build_shard_from(plan, index, shard_input_of(scene, plan, &root_of, index))
}

/// Builds shard `index` of `plan` from its input, which it frees as soon as it has read it.
pub fn build_shard_from(
    plan: &Plan,
    index: u32,
    input: ShardInput,
) -> Result<ShardPart, ShardError> {
    let mut roots = Vec::new();
    let cross = build_shard_into(plan, index, input, |root| {
        roots.push(root);
        Ok(())
    })?;
    Ok(ShardPart {
        plan_id: plan.id,
        index,
        roots,
        cross,
    })
}

/// [`build_shard_from`], handing each root's part to `each_root` as soon as it is made (in
/// plan order), so that a caller writing them out never holds them all; returns the shard's
/// cross-root corners.
pub fn build_shard_into(
    plan: &Plan,
    index: u32,
    input: ShardInput,
    each_root: impl FnMut(RootPart) -> Result<(), ShardError>,
) -> Result<Vec<CrossCorner>, ShardError> {
    build_shard_with(plan, index, input, Isa::detect(), each_root)
}

fn build_shard_with(
    plan: &Plan,
    index: u32,
    input: ShardInput,
    isa: Isa,
    mut each_root: impl FnMut(RootPart) -> Result<(), ShardError>,
) -> Result<Vec<CrossCorner>, ShardError> {
    plan.check_index(index)?;
    let mine = plan.shard_roots(index);
    let local = LocalScene::new(plan, mine.clone(), input)?;
    let adjacency = Adjacency::new(local.scene.positions.len(), &local.scene.triangles);
    let (subtrees, rank_of) = local.subtrees(&adjacency, mine.start, isa);
    drop(adjacency);
    let (pure, completed, cross) = local.assign_triangles(plan, &subtrees, &rank_of, mine.start);
    drop((local, rank_of));
    // The nodes that own triangles across shards, by root, with how many they own (two
    // corners of each are reported here): their pages wait for the merge.
    let mut owned: Vec<(u32, u32, u64)> = cross
        .iter()
        .filter(|c| c.owner != u32::MAX)
        .map(|c| (c.root - mine.start, c.owner, c.triangle))
        .collect();
    owned.sort_unstable();
    owned.dedup();
    let mut owners: Vec<Vec<(u32, u32)>> = vec![Vec::new(); subtrees.len()];
    for run in owned.chunk_by(|a, b| (a.0, a.1) == (b.0, b.1)) {
        owners[run[0].0 as usize].push((run[0].1, run.len() as u32));
    }
    drop(owned);
    // Roots are sealed a window at a time side by side (a root's regions are few pages each,
    // too little to fill the threads alone), and handed on in plan order. A window holds at
    // most as many roots as there are threads and, past its first root, twice the shard's
    // triangles over the threads: any two roots with two threads, an eighth of the shard
    // with sixteen, so the records a window holds stay a small share of a job's memory.
    let threads = rayon::current_num_threads().max(1);
    let window_triangles = (2 * pure.iter().map(Vec::len).sum::<usize>()).div_ceil(threads);
    let mut roots = subtrees
        .into_iter()
        .zip(pure)
        .zip(completed)
        .zip(owners)
        .peekable();
    loop {
        let mut batch = Vec::new();
        let mut held = 0;
        while batch.len() < threads {
            let Some(size) = roots.peek().map(|(((_, triangles), _), _)| triangles.len()) else {
                break;
            };
            if !batch.is_empty() && held + size > window_triangles {
                break;
            }
            held += size;
            batch.extend(roots.next());
        }
        if batch.is_empty() {
            break;
        }
        let sealed: Vec<Result<RootPart, ShardError>> = batch
            .into_par_iter()
            .map(|((((root, subtree), triangles), completed), owners)| {
                let records = subtree.into_records(triangles);
                super::seal::seal_root(plan, root, records, completed, &owners)
            })
            .collect();
        for part in sealed {
            each_root(part?)?;
        }
    }
    Ok(cross)
}

/// A shard's triangles over its own numbering of the vertices they use.
struct LocalScene {
    /// Positions of the vertices, in welded order, and triangles over them, in scene order.
    scene: Scene,
    /// Each triangle's index in the welded scene and its part.
    ids: Vec<(u64, u32)>,
    /// Each vertex's root, or [`ELSEWHERE`] for a corner in another shard.
    root: Vec<u32>,
    /// The shard's roots.
    mine: std::ops::Range<u32>,
}

impl LocalScene {
    /// Numbers the vertices of the shard's input and checks it against the plan: triangles in
    /// scene order, vertices in id order, the vertices listed the ones the corners use, a
    /// corner in the shard for every triangle, and each root's vertex count.
    fn new(
        plan: &Plan,
        mine: std::ops::Range<u32>,
        input: ShardInput,
    ) -> Result<LocalScene, ShardError> {
        let changed = |what: &str| Err(ShardError::InputChanged(what.to_string()));
        let ShardInput {
            triangles: input,
            vertices,
        } = input;
        if input
            .windows(2)
            .any(|w| w[0].triangle.get() >= w[1].triangle.get())
            || input
                .last()
                .is_some_and(|t| t.triangle.get() >= plan.triangles)
        {
            return changed("triangles out of order or past the plan's count");
        }
        if vertices
            .windows(2)
            .any(|w| w[0].vertex.get() >= w[1].vertex.get())
            || vertices
                .last()
                .is_some_and(|v| v.vertex.get() >= plan.vertices)
        {
            return changed("vertices out of order or past the plan's count");
        }
        let mut triangles: Vec<[u32; 3]> =
            input.iter().map(|t| t.vertices.map(|v| v.get())).collect();
        let ids: Vec<(u64, u32)> = input
            .iter()
            .map(|t| (t.triangle.get(), t.part.get()))
            .collect();
        drop(input);
        let listed: Vec<u32> = vertices.iter().map(|v| v.vertex.get()).collect();
        match super::numbering::number_corners(&mut triangles, &listed, plan.vertices) {
            Ok(()) => {}
            Err(Mismatch::PastTheCount) => return changed("a vertex past the plan's count"),
            Err(Mismatch::Unlisted) => return changed("a corner whose vertex is not listed"),
            Err(Mismatch::Unused) => return changed("a listed vertex that no triangle uses"),
        }
        drop(listed);
        let scene = Scene {
            positions: vertices
                .iter()
                .map(|v| v.position.map(|c| c.get()))
                .collect(),
            triangles,
            ..Scene::default()
        };
        drop(vertices);
        let root: Vec<u32> = scene
            .positions
            .par_iter()
            .map(|&p| {
                plan.locate(p)
                    .filter(|r| mine.contains(r))
                    .unwrap_or(ELSEWHERE)
            })
            .collect();
        if scene
            .triangles
            .iter()
            .any(|c| c.iter().all(|&v| root[v as usize] == ELSEWHERE))
        {
            return changed("a triangle with no corner in the shard");
        }
        let mut counts = vec![0u32; mine.len()];
        for &r in root.iter().filter(|&&r| r != ELSEWHERE) {
            counts[(r - mine.start) as usize] += 1;
        }
        check_counts(plan, mine.clone(), &counts)?;
        Ok(LocalScene {
            scene,
            ids,
            root,
            mine,
        })
    }

    /// Each root's subtree (with the root's index), clustered from its vertices in input
    /// order, and every vertex's leaf rank under its root (`u32::MAX` for one elsewhere).
    fn subtrees(
        &self,
        adjacency: &Adjacency,
        first: u32,
        isa: Isa,
    ) -> (Vec<(u32, Subtree)>, Vec<u32>) {
        let mut members: Vec<Vec<u32>> = vec![Vec::new(); self.mine.len()];
        for (v, &root) in self.root.iter().enumerate() {
            if root != ELSEWHERE {
                members[(root - first) as usize].push(v as u32);
            }
        }
        // Side by side: each build is parallel within, but a root's is too small to keep
        // every thread busy through its clustering and top levels.
        let subtrees: Vec<(u32, Subtree)> = members
            .par_iter()
            .enumerate()
            .map(|(k, vertices)| {
                let subtree = Subtree::build(&self.scene, adjacency, vertices, isa);
                (first + k as u32, subtree)
            })
            .collect();
        let mut rank_of = vec![u32::MAX; self.scene.positions.len()];
        for (_, subtree) in &subtrees {
            for (rank, &v) in subtree.leaf_vertex.iter().enumerate() {
                rank_of[v as usize] = rank as u32;
            }
        }
        (subtrees, rank_of)
    }

    /// A triangle within one root is a subtri of its subtree, listed with its owner per root
    /// (corners as the subtree's ranks). One with two corners under one root and the third
    /// under another of this shard's is a subtri of that subtree too, listed apart with its
    /// owner and its corners as the file's ranks. Of any other triangle across roots, this
    /// shard's corners are reported, with the owner where two of them lie under one root.
    #[allow(clippy::type_complexity)]
    fn assign_triangles(
        &self,
        plan: &Plan,
        subtrees: &[(u32, Subtree)],
        rank_of: &[u32],
        first: u32,
    ) -> (
        Vec<Vec<(u32, TriangleRecord)>>,
        Vec<Vec<(u32, TriangleRecord)>>,
        Vec<CrossCorner>,
    ) {
        let mut pure: Vec<Vec<(u32, TriangleRecord)>> = vec![Vec::new(); subtrees.len()];
        let mut completed: Vec<Vec<(u32, TriangleRecord)>> = vec![Vec::new(); subtrees.len()];
        let mut cross = Vec::new();
        for (&(t, part), &corners) in self.ids.iter().zip(&self.scene.triangles) {
            let roots = corners.map(|v| self.root[v as usize]);
            if roots[0] == roots[1] && roots[1] == roots[2] {
                // Every triangle has a corner here, so the one root is one of this shard's.
                let k = (roots[0] - first) as usize;
                let ranks = corners.map(|v| rank_of[v as usize]);
                let owner = subtrees[k].1.owner(ranks);
                pure[k].push((owner, record(leading_smallest(ranks), part)));
                continue;
            }
            let shared = |k: usize| roots.iter().filter(|&&r| r == roots[k]).count();
            // The node of corner `k`'s subtree that the triangle is a subtri of, with two of
            // its corners there: the corner under another root sorts last and stops no walk.
            let owner_under = |k: usize| {
                let ranks = [0, 1, 2].map(|j| {
                    if roots[j] == roots[k] {
                        rank_of[corners[j] as usize]
                    } else {
                        u32::MAX
                    }
                });
                subtrees[(roots[k] - first) as usize].1.owner(ranks)
            };
            if !roots.contains(&ELSEWHERE)
                && let Some(k) = (0..3).find(|&k| shared(k) == 2)
            {
                // All three corners are this shard's: the third corner's rank is known here.
                let owner = owner_under(k);
                let file_ranks = [0, 1, 2]
                    .map(|j| plan.root_node(roots[j]).leaf_begin + rank_of[corners[j] as usize]);
                completed[(roots[k] - first) as usize]
                    .push((owner, record(leading_smallest(file_ranks), part)));
                continue;
            }
            for k in 0..3 {
                if roots[k] == ELSEWHERE {
                    continue;
                }
                let owner = if shared(k) == 2 {
                    owner_under(k)
                } else {
                    u32::MAX
                };
                cross.push(CrossCorner {
                    triangle: t,
                    corner: k as u8,
                    root: roots[k],
                    rank: rank_of[corners[k] as usize],
                    part,
                    owner,
                });
            }
        }
        (pure, completed, cross)
    }
}

fn record(corners: [u32; 3], part: u32) -> TriangleRecord {
    TriangleRecord {
        corners: corners.map(U32::new),
        part: U32::new(part),
    }
}

/// A root's subtree while the shard builds it.
struct Subtree {
    nodes: Vec<Node>,
    bounds: Vec<crate::NodeBounds>,
    leaf_positions: Vec<[f32; 3]>,
    /// Local vertex of each leaf rank.
    leaf_vertex: Vec<u32>,
    leaf_node: Vec<u32>,
    sums: Accumulator,
    sphere: Sphere,
}

impl Subtree {
    /// Clusters `vertices` (local ids, in input order) and fills their attributes.
    fn build(scene: &Scene, adjacency: &Adjacency, vertices: &[u32], isa: Isa) -> Subtree {
        let positions: Vec<[f32; 3]> = vertices
            .iter()
            .map(|&v| scene.positions[v as usize])
            .collect();
        let clustering = cluster_with(&positions, isa);
        let (_, leaf_node) = leaf_tables(&clustering.leaf_vertex, &clustering.nodes);
        let leaf_vertex: Vec<u32> = clustering
            .leaf_vertex
            .iter()
            .map(|&i| vertices[i as usize])
            .collect();
        let (bounds, (sums, sphere)) = compute_attributes(
            &clustering.nodes,
            &clustering.level_starts,
            &Inputs {
                scene,
                leaf_vertex: &leaf_vertex,
                adjacency,
                leaf_positions: &clustering.leaf_positions,
                isa,
            },
        );
        Subtree {
            nodes: clustering.nodes,
            bounds,
            leaf_positions: clustering.leaf_positions,
            leaf_vertex,
            leaf_node,
            sums,
            sphere,
        }
    }

    /// The node a triangle with corners of these leaf ranks is a subtri of (two or three
    /// under this subtree; `u32::MAX` for one elsewhere), as [`crate::VertexTree::subtri_node`].
    fn owner(&self, ranks: [u32; 3]) -> u32 {
        subtri_node_of_ranks(&self.nodes, &self.leaf_node, ranks)
    }

    /// The subtree's records, with subtri ranges over its triangles, grouped by node and
    /// sorted within a node as the file stores them.
    fn into_records(mut self, owned: Vec<(u32, TriangleRecord)>) -> SubtreeRecords {
        // Grouped by node with a counting sort, then each node's run sorted alone: one
        // comparison sort of every triangle by (node, corners, part) was 6 % of a shard.
        // `ends[id]` starts as where node `id`'s run starts and is advanced past each of its
        // triangles placed: at the end it is where the run ends.
        let mut ends = vec![0u32; self.nodes.len() + 1];
        for &(node, _) in &owned {
            ends[node as usize + 1] += 1;
        }
        for i in 0..self.nodes.len() {
            ends[i + 1] += ends[i];
        }
        let mut triangles = vec![TriangleRecord::new_zeroed(); owned.len()];
        for (node, t) in owned {
            triangles[ends[node as usize] as usize] = t;
            ends[node as usize] += 1;
        }
        let mut begin = 0usize;
        for (node, &end) in self.nodes.iter_mut().zip(&ends) {
            let run = &mut triangles[begin..end as usize];
            if run.len() > 1 {
                run.sort_unstable_by_key(|t| (t.corners.map(|c| c.get()), t.part.get()));
            }
            node.subtri_begin = begin as u32;
            node.subtri_end = end;
            begin = end as usize;
        }
        let nodes = self
            .nodes
            .iter()
            .map(|node| {
                let bounds = (!node.is_leaf()).then(|| &self.bounds[node.bounds as usize]);
                let position = self.leaf_positions[node.leaf_begin as usize];
                node_record(node, bounds, position)
            })
            .collect();
        SubtreeRecords {
            nodes,
            triangles,
            sums: self.sums,
            sphere: self.sphere,
        }
    }
}

/// A root's whole subtree as records: node ids, leaf ranks and subtri ranges are the
/// subtree's own (node 0 is the root, nodes breadth-first, ranks from 0).
pub(crate) struct SubtreeRecords {
    pub(crate) nodes: Vec<NodeRecord>,
    pub(crate) triangles: Vec<TriangleRecord>,
    pub(crate) sums: Accumulator,
    pub(crate) sphere: Sphere,
}
