//! The build pipeline: scene → clustering → per-node attributes → subtris.
//!
//! Attributes are computed bottom-up one depth level at a time, in parallel within a level:
//! a leaf's quadric, triangle bounds and normal cone come from its incident triangles; an
//! inner node combines its children's. Only the accumulators of the level below are kept, so
//! transient memory is bounded by the widest level, not by the whole tree.

use std::time::{Duration, Instant};

use rayon::prelude::*;
use vds_import::Scene;

use crate::bounds::{Aabb, NormalCone, round_up_f32};
use crate::octree::cluster;
use crate::prefault::filled;
use crate::quadric::{Quadric, cross, dot, sub};
use crate::tree::{Node, VertexTree};

/// Wall-clock time of each build phase.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BuildTimings {
    /// Tight-octree clustering.
    pub cluster: Duration,
    /// Vertex → triangle adjacency.
    pub adjacency: Duration,
    /// Quadrics, proxies, error radii, spheres and cones.
    pub attributes: Duration,
    /// Assigning triangles to nodes as subtris.
    pub subtris: Duration,
}

impl BuildTimings {
    /// The sum of all phases.
    pub fn total(&self) -> Duration {
        self.cluster + self.adjacency + self.attributes + self.subtris
    }
}

/// Builds the vertex tree of a scene.
pub fn build_tree(scene: &Scene) -> VertexTree {
    build_tree_timed(scene).0
}

/// Builds the vertex tree of a scene and reports how long each phase took.
pub fn build_tree_timed(scene: &Scene) -> (VertexTree, BuildTimings) {
    let mut timings = BuildTimings::default();
    if scene.positions.is_empty() {
        return (VertexTree::default(), timings);
    }
    let start = Instant::now();
    let clustering = cluster(&scene.positions);
    timings.cluster = start.elapsed();

    let start = Instant::now();
    let adjacency = Adjacency::new(scene.positions.len(), &scene.triangles);
    timings.adjacency = start.elapsed();

    let start = Instant::now();
    let leaf_count = clustering.leaf_vertex.len();
    let mut vertex_rank = filled(leaf_count, 0u32);
    for (rank, &v) in clustering.leaf_vertex.iter().enumerate() {
        vertex_rank[v as usize] = rank as u32;
    }
    let mut leaf_node = filled(leaf_count, 0u32);
    for (id, n) in clustering.nodes.iter().enumerate() {
        if n.child_count == 0 {
            leaf_node[n.leaf_begin as usize] = id as u32;
        }
    }
    let leaf_positions = clustering.leaf_positions;
    let mut nodes = clustering.nodes;
    compute_attributes(
        scene,
        &mut nodes,
        &clustering.level_starts,
        &clustering.leaf_vertex,
        &adjacency,
        &leaf_positions,
    );
    timings.attributes = start.elapsed();
    drop(adjacency);

    let mut tree = VertexTree {
        nodes,
        leaf_vertex: clustering.leaf_vertex,
        vertex_rank,
        leaf_node,
        subtris: Vec::new(),
        level_starts: clustering.level_starts,
    };
    let start = Instant::now();
    assign_subtris(&mut tree, &scene.triangles);
    timings.subtris = start.elapsed();
    (tree, timings)
}

/// Incident triangles of each vertex, in increasing triangle id (compressed rows).
struct Adjacency {
    offsets: Vec<u32>,
    triangles: Vec<u32>,
}

impl Adjacency {
    fn new(vertex_count: usize, triangles: &[[u32; 3]]) -> Adjacency {
        // Counts, then running ends: `offsets[v]` is where row `v` ends.
        let mut offsets = filled(vertex_count + 1, 0u32);
        for t in triangles {
            for &v in t {
                offsets[v as usize] += 1;
            }
        }
        for i in 1..=vertex_count {
            offsets[i] += offsets[i - 1];
        }
        // Rows filled from their ends, triangles taken last to first: each row comes out in
        // increasing triangle id and each `offsets[v]` moves down to where row `v` starts, so
        // no second array of fill positions is needed.
        let mut list = filled(offsets[vertex_count] as usize, 0u32);
        for (id, t) in triangles.iter().enumerate().rev() {
            for &v in t {
                offsets[v as usize] -= 1;
                list[offsets[v as usize] as usize] = id as u32;
            }
        }
        Adjacency {
            offsets,
            triangles: list,
        }
    }

    fn of(&self, vertex: u32) -> &[u32] {
        let v = vertex as usize;
        &self.triangles[self.offsets[v] as usize..self.offsets[v + 1] as usize]
    }
}

/// What a node passes to its parent.
#[derive(Clone, Copy)]
struct Accumulator {
    quadric: Quadric,
    position_sum: [f64; 3],
    vertex_box: Aabb,
    triangle_box: Aabb,
    cone: NormalCone,
    /// A two-sided cone of the same normals, or `None` where the one-sided cone is narrower
    /// than a hemisphere and stands in for it (a one-sided cone bounds its normals up to sign
    /// too). Fitting and merging two-sided cones only where one-sided ones fail keeps their
    /// cost to thin-shell regions.
    two_sided: Option<NormalCone>,
}

fn widen(p: [f32; 3]) -> [f64; 3] {
    p.map(f64::from)
}

/// Fills every node's attributes, deepest level first. A parent computes its leaf children's
/// accumulators itself, so only inner nodes' accumulators are kept between levels, indexed
/// compactly: leaves, the bulk of the tree, never occupy an accumulator slot.
fn compute_attributes(
    scene: &Scene,
    nodes: &mut [Node],
    levels: &[u32],
    leaf_vertex: &[u32],
    adjacency: &Adjacency,
    leaf_positions: &[[f32; 3]],
) {
    let level_count = levels.len() - 1;
    // Each inner node's place among its level's inner nodes (its accumulator's index), set
    // while its level's families are listed, before its parent's level reads it.
    let mut inner_index = filled(nodes.len(), u32::MAX);
    // Two buffers reused level after level: fresh multi-megabyte allocations per level would
    // spend more time in page faults than in the geometry. (Reserving both at the widest
    // level's size up front raised peak memory by 280 MB: the growing buffers reuse memory
    // the clustering freed.)
    let mut below: Vec<Accumulator> = Vec::new();
    let mut current: Vec<Accumulator> = Vec::new();
    for level in (0..level_count).rev() {
        let (start, end) = (levels[level] as usize, levels[level + 1] as usize);
        let next_end = levels.get(level + 2).map_or(end, |&e| e as usize);
        let (this_level, rest) = nodes[start..next_end].split_at_mut(end - start);
        // The next level is exactly this level's children, in parent order.
        let mut children_left: &mut [Node] = rest;
        let mut families: Vec<(&mut Node, &mut [Node])> = Vec::new();
        for (k, node) in this_level.iter_mut().enumerate() {
            if !node.is_leaf() {
                let (children, tail) =
                    std::mem::take(&mut children_left).split_at_mut(usize::from(node.child_count));
                children_left = tail;
                inner_index[start + k] = families.len() as u32;
                families.push((node, children));
            }
        }
        // This level's accumulators (the widest levels take hundreds of megabytes) are
        // written in parallel below; map their fresh pages in one go first.
        current.clear();
        current.reserve(families.len());
        crate::prefault::populate(&mut current.spare_capacity_mut()[..families.len()]);
        let below_ref = &below;
        let inner_index = &inner_index[..];
        families
            .into_par_iter()
            .map_init(LeafScratch::default, |scratch, (node, children)| {
                let mut sum: Option<Accumulator> = None;
                for (k, child) in children.iter_mut().enumerate() {
                    let leaf;
                    let accumulator = if child.is_leaf() {
                        let vertex = leaf_vertex[child.leaf_begin as usize];
                        leaf = leaf_attributes(child, vertex, scene, adjacency.of(vertex), scratch);
                        &leaf
                    } else {
                        &below_ref[inner_index[node.first_child as usize + k] as usize]
                    };
                    match &mut sum {
                        None => sum = Some(*accumulator),
                        Some(sum) => sum.absorb(accumulator),
                    }
                }
                let sum = sum.expect("inner nodes have children");
                inner_attributes(node, children, &sum, leaf_positions);
                sum
            })
            .collect_into_vec(&mut current);
        std::mem::swap(&mut below, &mut current);
    }
    if nodes.len() == 1 {
        let vertex = leaf_vertex[0];
        leaf_attributes(
            &mut nodes[0],
            vertex,
            scene,
            adjacency.of(vertex),
            &mut LeafScratch::default(),
        );
    }
}

/// A leaf's incident triangles, gathered once and used by every leaf attribute: each one's
/// corners (as stored, in `f32`: half the bytes of widened ones, and widening again later
/// gives the same values), and the unit normals of those with a non-zero area (apart, so the
/// cone fits run over a plain slice).
#[derive(Default)]
struct LeafScratch {
    corners: Vec<[[f32; 3]; 3]>,
    normals: Vec<[f64; 3]>,
}

fn leaf_attributes(
    node: &mut Node,
    vertex: u32,
    scene: &Scene,
    incident: &[u32],
    scratch: &mut LeafScratch,
) -> Accumulator {
    let position = scene.positions[vertex as usize];
    let p = widen(position);
    let mut quadric = Quadric::default();
    let mut triangle_box = Aabb::EMPTY;
    triangle_box.add_point(position);
    scratch.corners.clear();
    scratch.normals.clear();
    for &t in incident {
        let corners = scene.triangles[t as usize].map(|v| scene.positions[v as usize]);
        for q in corners {
            triangle_box.add_point(q);
        }
        let [a, b, c] = corners.map(widen);
        // One cross product gives both the plane for the quadric and the normal for the cone.
        let n = cross(sub(b, a), sub(c, a));
        let twice_area = dot(n, n).sqrt();
        if twice_area > 0.0 && twice_area.is_finite() {
            let inverse = 1.0 / twice_area;
            let normal = n.map(|x| x * inverse);
            quadric.add(&Quadric::from_plane(normal, a, 0.5 * twice_area));
            scratch.normals.push(normal);
        }
        scratch.corners.push(corners);
    }
    let center = widen(triangle_box.center().map(|c| c as f32));
    // Plain loops and a comparison: a flattened iterator and `f64::max`'s NaN rule (distances
    // between finite points are never NaN) cost more instructions than the distances.
    let mut farthest = distance_squared(center, p);
    for corners in &scratch.corners {
        for &q in corners {
            let d = distance_squared(center, widen(q));
            if d > farthest {
                farthest = d;
            }
        }
    }
    let radius = farthest.sqrt();
    let cone = NormalCone::fit(&scratch.normals);
    let two_sided = (cone.half_angle >= std::f64::consts::FRAC_PI_2)
        .then(|| NormalCone::fit_two_sided(&scratch.normals));
    node.proxy = position;
    node.error_radius = 0.0;
    node.sphere_center = center.map(|c| c as f32);
    node.sphere_radius = round_up_f32(radius);
    store_cone(node, &cone, two_sided.as_ref());
    let mut vertex_box = Aabb::EMPTY;
    vertex_box.add_point(position);
    Accumulator {
        quadric,
        position_sum: p,
        vertex_box,
        triangle_box,
        cone,
        two_sided,
    }
}

impl Accumulator {
    /// Adds `other` in place (a 224-byte accumulator moved in and out per child cost
    /// copies; the sums and their order are the same).
    fn absorb(&mut self, other: &Accumulator) {
        let before = self.cone;
        self.quadric.add(&other.quadric);
        for k in 0..3 {
            self.position_sum[k] += other.position_sum[k];
        }
        self.vertex_box.add_box(&other.vertex_box);
        self.triangle_box.add_box(&other.triangle_box);
        self.cone = self.cone.merge(&other.cone);
        let narrow = self.cone.half_angle < std::f64::consts::FRAC_PI_2;
        self.two_sided = match (self.two_sided, other.two_sided) {
            (None, None) if narrow => None,
            (mine, theirs) => Some(
                mine.unwrap_or(before)
                    .merge_two_sided(&theirs.unwrap_or(other.cone)),
            ),
        };
    }
}

fn inner_attributes(
    node: &mut Node,
    children: &[Node],
    sum: &Accumulator,
    leaf_positions: &[[f32; 3]],
) {
    let count = f64::from(node.leaf_count());
    let mean = sum.position_sum.map(|c| c / count);
    // The proxy stays inside the cluster's vertex box, so inside the node's octree cell.
    let proxy = sum.vertex_box.clamp(sum.quadric.minimizer_near(mean));
    node.proxy = proxy.map(|c| c as f32);
    let proxy = widen(node.proxy);
    let leaves = &leaf_positions[node.leaf_begin as usize..node.leaf_end as usize];
    node.error_radius = round_up_f32(farthest_squared(proxy, leaves).sqrt());
    let center = sum.triangle_box.center().map(|c| c as f32);
    let sphere_radius = children
        .iter()
        .map(|c| distance(widen(center), widen(c.sphere_center)) + f64::from(c.sphere_radius))
        .fold(0.0, f64::max);
    node.sphere_center = center;
    node.sphere_radius = round_up_f32(sphere_radius);
    store_cone(node, &sum.cone, sum.two_sided.as_ref());
}

/// Stores the one-sided cone, or the two-sided one where the one-sided cone is wider than a
/// hemisphere (no view then sees only backs, and every view sees a possible silhouette: the
/// cone tells nothing) and the two-sided cone is narrower than a hemisphere.
fn store_cone(node: &mut Node, cone: &NormalCone, two_sided: Option<&NormalCone>) {
    let half_pi = std::f64::consts::FRAC_PI_2;
    let two_sided = two_sided
        .filter(|c| !cone.is_empty() && cone.half_angle >= half_pi && c.half_angle < half_pi);
    let use_two_sided = two_sided.is_some();
    let chosen = two_sided.unwrap_or(cone);
    node.cone_axis = chosen.axis.map(|c| c as f32);
    node.cone_half_angle = if chosen.is_empty() {
        -1.0
    } else {
        round_up_f32(chosen.half_angle)
    };
    node.cone_two_sided = use_two_sided;
}

/// The largest squared distance from `from` to any of `points`. The error radius is exact,
/// so every node scans its whole leaf range (O(n · depth) over the tree); squared distances
/// keep that scan to multiply-adds, and ranges near the root, too few nodes to keep both
/// cores busy, are split across threads.
fn farthest_squared(from: [f64; 3], points: &[[f32; 3]]) -> f64 {
    const PARALLEL_ABOVE: usize = 1 << 16;
    let scan = |points: &[[f32; 3]]| {
        points
            .iter()
            .map(|&q| distance_squared(from, widen(q)))
            .fold(0.0, f64::max)
    };
    if points.len() > PARALLEL_ABOVE {
        points
            .par_chunks(PARALLEL_ABOVE)
            .map(scan)
            .reduce(|| 0.0, f64::max)
    } else {
        scan(points)
    }
}

fn distance_squared(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    dot(d, d)
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    dot(d, d).sqrt()
}

/// Fills `tree.subtris` and each node's subtri range.
fn assign_subtris(tree: &mut VertexTree, triangles: &[[u32; 3]]) {
    let owner: Vec<u32> = triangles.par_iter().map(|&t| tree.subtri_node(t)).collect();
    let mut counts = filled(tree.nodes.len() + 1, 0u32);
    for &node in &owner {
        counts[node as usize + 1] += 1;
    }
    for i in 0..tree.nodes.len() {
        counts[i + 1] += counts[i];
    }
    // In parallel: a pass over every node's 76 bytes, the whole node array.
    tree.nodes
        .par_iter_mut()
        .enumerate()
        .for_each(|(id, node)| {
            node.subtri_begin = counts[id];
            node.subtri_end = counts[id + 1];
        });
    let mut subtris = filled(triangles.len(), 0u32);
    for (t, &node) in owner.iter().enumerate() {
        subtris[counts[node as usize] as usize] = t as u32;
        counts[node as usize] += 1;
    }
    tree.subtris = subtris;
}
