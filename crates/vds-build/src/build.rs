//! The build pipeline: scene → clustering → per-node attributes → subtris.
//!
//! Attributes are computed bottom-up: a leaf's quadric, triangle bounds and normal cone come
//! from its incident triangles; an inner node combines its children's. Subtrees below a
//! frontier level are filled depth first, one parallel task each, so a node's accumulator
//! lives only until its parent absorbs it; the few levels above are filled one at a time.

use std::time::{Duration, Instant};

use rayon::prelude::*;
use vds_import::Scene;

use crate::bounds::{Aabb, NormalCone, round_up_f32};
use crate::contraction::{MAX_DEPTH, contract};
use crate::isa::{Isa, dispatched};
use crate::octree::cluster_with;
use crate::prefault::filled;
use crate::quadric::{Quadric, cross, dot, sub};
use crate::tree::{Node, NodeBounds, VertexTree};

/// Wall-clock time of each build phase.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BuildTimings {
    /// Tight-octree clustering.
    pub cluster: Duration,
    /// Vertex → triangle adjacency.
    pub adjacency: Duration,
    /// Quadrics, proxies, error radii, spheres and cones, and, beside them on the same
    /// threads, sorting the triangles into each node's subtris.
    pub attributes: Duration,
    /// Storing each node's subtri range once both are done.
    pub subtris: Duration,
}

impl BuildTimings {
    /// The sum of all phases.
    pub fn total(&self) -> Duration {
        self.cluster + self.adjacency + self.attributes + self.subtris
    }
}

/// The algorithm that groups vertices into the tree's nodes; everything else about the tree
/// (proxies, bounds, subtris) is computed the same way for each.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Hash)]
pub enum Builder {
    /// Tight-octree clustering ([`crate::octree`]): fast, parallel, the default.
    #[default]
    Octree,
    /// Quadric-ordered pair contraction over mesh edges and proximity pairs
    /// ([`crate::contraction`]): a binary tree whose budget cuts follow the quadric error,
    /// more faithful per triangle, slower to build (one thread). A contraction tree deeper
    /// than [`crate::contraction::MAX_DEPTH`] levels (no real mesh makes one) is replaced by
    /// the octree's.
    Qem,
}

impl Builder {
    /// Every builder.
    pub const ALL: [Builder; 2] = [Builder::Octree, Builder::Qem];

    /// The name `--builder` takes.
    pub fn name(self) -> &'static str {
        match self {
            Builder::Octree => "octree",
            Builder::Qem => "qem",
        }
    }
}

impl std::str::FromStr for Builder {
    type Err = String;

    /// A builder by [`Builder::name`].
    fn from_str(name: &str) -> Result<Builder, String> {
        Builder::ALL
            .into_iter()
            .find(|b| b.name() == name)
            .ok_or_else(|| format!("'{name}' is not a builder (octree or qem)"))
    }
}

/// Builds the vertex tree of a scene with the default builder.
pub fn build_tree(scene: &Scene) -> VertexTree {
    build_tree_timed(scene).0
}

/// Builds the vertex tree of a scene with the default builder and reports how long each
/// phase took.
pub fn build_tree_timed(scene: &Scene) -> (VertexTree, BuildTimings) {
    build_tree_by(scene, Builder::default())
}

/// Builds the vertex tree of a scene with `builder` and reports how long each phase took
/// (the grouping is the `cluster` phase, whichever builder makes it).
pub fn build_tree_by(scene: &Scene, builder: Builder) -> (VertexTree, BuildTimings) {
    build_tree_with(scene, builder, Isa::detect())
}

/// [`build_tree_by`] with the kernels compiled for `isa`.
fn build_tree_with(scene: &Scene, builder: Builder, isa: Isa) -> (VertexTree, BuildTimings) {
    let mut timings = BuildTimings::default();
    if scene.positions.is_empty() {
        return (VertexTree::default(), timings);
    }
    let start = Instant::now();
    let clustering = match builder {
        Builder::Octree => cluster_with(&scene.positions, isa),
        // A contraction tree too deep for the attribute pass (no real mesh makes one) falls
        // back to the octree.
        Builder::Qem => contract(&scene.positions, &scene.triangles, MAX_DEPTH)
            .unwrap_or_else(|| cluster_with(&scene.positions, isa)),
    };
    timings.cluster = start.elapsed();

    // The adjacency and the leaf-rank tables are each one thread's scatter: built side by
    // side. (The adjacency's phase time includes the tables.)
    let start = Instant::now();
    let (adjacency, (vertex_rank, leaf_node)) = rayon::join(
        || Adjacency::new(scene.positions.len(), &scene.triangles),
        || leaf_tables(&clustering.leaf_vertex, &clustering.nodes),
    );
    timings.adjacency = start.elapsed();

    let mut tree = VertexTree {
        nodes: clustering.nodes,
        bounds: Vec::new(),
        leaf_positions: clustering.leaf_positions,
        leaf_vertex: clustering.leaf_vertex,
        vertex_rank,
        leaf_node,
        subtris: Vec::new(),
        level_starts: clustering.level_starts,
    };
    // Sorting triangles into subtris needs the topology and the leaf tables, not the
    // attributes, so it runs beside them: its counting sort is one thread's scattered writes,
    // which wait on memory, while the attributes are arithmetic that fills both cores; side
    // by side the sort's thread no longer leaves the other core idle.
    let start = Instant::now();
    let ((bounds, _), (subtri_ends, subtris)) = rayon::join(
        || {
            compute_attributes(
                &tree.nodes,
                &tree.level_starts,
                &Inputs {
                    scene,
                    leaf_vertex: &tree.leaf_vertex,
                    adjacency: &adjacency,
                    leaf_positions: &tree.leaf_positions,
                    isa,
                },
            )
        },
        || sort_subtris(&tree, &scene.triangles),
    );
    timings.attributes = start.elapsed();
    drop(adjacency);

    let start = Instant::now();
    tree.bounds = bounds;
    set_subtri_ranges(&mut tree.nodes, &subtri_ends);
    tree.subtris = subtris;
    timings.subtris = start.elapsed();
    (tree, timings)
}

/// The leaf rank of each vertex (the inverse of `leaf_vertex`) and the node id of each leaf
/// rank.
pub(crate) fn leaf_tables(leaf_vertex: &[u32], nodes: &[Node]) -> (Vec<u32>, Vec<u32>) {
    let mut vertex_rank = filled(leaf_vertex.len(), 0u32);
    for (rank, &v) in leaf_vertex.iter().enumerate() {
        vertex_rank[v as usize] = rank as u32;
    }
    let mut leaf_node = filled(leaf_vertex.len(), 0u32);
    for (id, n) in nodes.iter().enumerate() {
        if n.is_leaf() {
            leaf_node[n.leaf_begin as usize] = id as u32;
        }
    }
    (vertex_rank, leaf_node)
}

/// Incident triangles of each vertex, in increasing triangle id (compressed rows).
pub(crate) struct Adjacency {
    offsets: Vec<u32>,
    triangles: Vec<u32>,
}

impl Adjacency {
    pub(crate) fn new(vertex_count: usize, triangles: &[[u32; 3]]) -> Adjacency {
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
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Accumulator {
    pub(crate) quadric: Quadric,
    pub(crate) position_sum: [f64; 3],
    pub(crate) vertex_box: Aabb,
    pub(crate) triangle_box: Aabb,
    pub(crate) cone: NormalCone,
    /// A two-sided cone of the same normals, or `None` where the one-sided cone is narrower
    /// than a hemisphere and stands in for it (a one-sided cone bounds its normals up to sign
    /// too). Fitting and merging two-sided cones only where one-sided ones fail keeps their
    /// cost to thin-shell regions.
    pub(crate) two_sided: Option<NormalCone>,
}

fn widen(p: [f32; 3]) -> [f64; 3] {
    p.map(f64::from)
}

/// What every node's attributes are computed from.
pub(crate) struct Inputs<'a> {
    pub(crate) scene: &'a Scene,
    pub(crate) leaf_vertex: &'a [u32],
    pub(crate) adjacency: &'a Adjacency,
    pub(crate) leaf_positions: &'a [[f32; 3]],
    pub(crate) isa: Isa,
}

/// Subtrees filled as one task hold at most this share of all leaves (or
/// [`MIN_TASK_LEAVES`]): enough tasks for rayon to balance, few enough that each is long.
const TASK_SHARE: u32 = 64;

/// The least leaf count a task may be given however small the tree.
const MIN_TASK_LEAVES: u32 = 4096;

/// A bounding sphere a node passes to its parent, which bounds its children's spheres. A
/// leaf's is not kept in the tree (leaves have no bounds there), only passed up.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct Sphere {
    pub(crate) center: [f32; 3],
    pub(crate) radius: f32,
}

/// Computes every inner node's proxy and bounds (indexed as [`Node::bounds`]), children
/// before parents.
///
/// The tree is cut at a *frontier* level: the shallowest level whose every node holds at most
/// a 64th of the leaves. Each frontier node's subtree is filled by one task, depth first, so a
/// node's accumulator lives only until its parent has absorbed it (one running sum per level
/// of the recursion). The few levels above the frontier are then filled level by level from
/// the frontier's accumulators. Filling the whole tree level by level instead kept every
/// accumulator of a level alive at once, 224 bytes each: 385 MB of fresh memory at the widest
/// levels of the 10 M scene, whose first touch the dev VMs charge heavily for. Sums are taken
/// in child order either way, so the attributes do not depend on how the work is split.
///
/// In breadth-first order a subtree's nodes form one contiguous run per level (children of
/// consecutive nodes are consecutive), found from the leaf ranges; bounds indices follow
/// node ids, so its inner nodes' bounds form one contiguous run per level too, and each task
/// gets its own `&mut` slice of the bounds of every level below the frontier.
pub(crate) fn compute_attributes(
    nodes: &[Node],
    levels: &[u32],
    inputs: &Inputs,
) -> (Vec<NodeBounds>, (Accumulator, Sphere)) {
    let level_count = levels.len() - 1;
    let level = |k: usize| &nodes[levels[k] as usize..levels[k + 1] as usize];
    let inner_count = |nodes: &[Node]| nodes.iter().filter(|n| !n.is_leaf()).count();
    let task_leaves = (nodes[0].leaf_count() / TASK_SHARE).max(MIN_TASK_LEAVES);
    let frontier = (0..level_count)
        .find(|&k| level(k).iter().all(|n| n.leaf_count() <= task_leaves))
        .unwrap_or(level_count - 1);
    let roots = level(frontier);

    // Where each task's nodes start on each level from the frontier down (leaf ranges
    // increase along a level), and how many of them are inner nodes.
    let starts: Vec<Vec<usize>> = (frontier..level_count)
        .map(|k| {
            let nodes = level(k);
            let mut starts = Vec::with_capacity(roots.len() + 1);
            starts.push(0);
            for root in roots {
                let at = starts[starts.len() - 1];
                starts.push(at + nodes[at..].partition_point(|n| n.leaf_begin < root.leaf_end));
            }
            starts
        })
        .collect();
    let inner_counts: Vec<Vec<usize>> = starts
        .par_iter()
        .enumerate()
        .map(|(j, starts)| {
            let nodes = level(frontier + j);
            starts
                .windows(2)
                .map(|w| inner_count(&nodes[w[0]..w[1]]))
                .collect()
        })
        .collect();

    let above = inner_count(&nodes[..levels[frontier] as usize]);
    let below_frontier: usize = inner_counts.iter().flatten().sum();
    let mut bounds = filled(above + below_frontier, NodeBounds::EMPTY);
    let (upper_bounds, lower_bounds) = bounds.split_at_mut(above);
    // Each task's bounds on each level from the frontier down, with the index of the first.
    let mut tasks: Vec<Vec<(u32, &mut [NodeBounds])>> = roots.iter().map(|_| Vec::new()).collect();
    let mut rest = lower_bounds;
    let mut index = above as u32;
    for counts in &inner_counts {
        for (task, &count) in tasks.iter_mut().zip(counts) {
            let (mine, tail) = std::mem::take(&mut rest).split_at_mut(count);
            rest = tail;
            task.push((index, mine));
            index += count as u32;
        }
    }
    let frontier_start = levels[frontier] as usize;
    let mut below: Vec<(Accumulator, Sphere)> = tasks
        .into_par_iter()
        .enumerate()
        .map_init(LeafScratch::default, |scratch, (root, mut task)| {
            let mut sum = Accumulator::EMPTY;
            let sphere =
                inputs.fill_subtree(nodes, &mut task, frontier_start + root, scratch, &mut sum);
            (sum, sphere)
        })
        .collect();

    // Above the frontier, level by level: `below` holds the accumulator and sphere of every
    // node of the level underneath, in id order.
    for k in (0..frontier).rev() {
        let next_start = levels[k + 1];
        let below_ref = &below;
        let results: Vec<((Accumulator, Sphere), Option<NodeBounds>)> = level(k)
            .par_iter()
            .map_init(LeafScratch::default, |scratch, node| {
                if node.is_leaf() {
                    let mut sum = Accumulator::EMPTY;
                    let sphere = inputs.leaf(node, scratch, &mut sum);
                    return ((sum, sphere), None);
                }
                let first = (node.first_child - next_start) as usize;
                let family = &below_ref[first..first + usize::from(node.child_count)];
                let mut sum = family[0].0;
                for (child, _) in &family[1..] {
                    absorb_on(inputs.isa, &mut sum, child);
                }
                let spheres = family.iter().map(|&(_, sphere)| sphere);
                let (node_bounds, sphere) =
                    inner_attributes_on(inputs.isa, node, spheres, &sum, inputs.leaf_positions);
                ((sum, sphere), Some(node_bounds))
            })
            .collect();
        for (node, (_, node_bounds)) in level(k).iter().zip(&results) {
            if let Some(node_bounds) = node_bounds {
                upper_bounds[node.bounds as usize] = *node_bounds;
            }
        }
        below = results.into_iter().map(|(up, _)| up).collect();
    }
    // The root's level is the last one filled: what it would pass to a parent.
    (bounds, below[0])
}

impl Inputs<'_> {
    /// A leaf's accumulator and sphere.
    fn leaf(&self, node: &Node, scratch: &mut LeafScratch, out: &mut Accumulator) -> Sphere {
        let vertex = self.leaf_vertex[node.leaf_begin as usize];
        let incident = self.adjacency.of(vertex);
        leaf_attributes_on(self.isa, vertex, self.scene, incident, scratch, out)
    }

    /// Fills the bounds of node `id`'s subtree, writes its accumulator to `sum` and returns
    /// its sphere. `levels` holds the subtree's bounds on each level from `id`'s down, each
    /// slice with the bounds index of its first entry. (Accumulators are written in place,
    /// not returned: returning 224 bytes through each level of the recursion cost a copy each
    /// time, 2 % of a build.)
    fn fill_subtree(
        &self,
        nodes: &[Node],
        levels: &mut [(u32, &mut [NodeBounds])],
        id: usize,
        scratch: &mut LeafScratch,
        sum: &mut Accumulator,
    ) -> Sphere {
        let node = &nodes[id];
        if node.is_leaf() {
            return self.leaf(node, scratch, sum);
        }
        let ((first_index, this_level), deeper) =
            levels.split_first_mut().expect("the node's level");
        let first = node.first_child as usize;
        let mut spheres = [Sphere {
            center: [0.0; 3],
            radius: 0.0,
        }; 8];
        spheres[0] = self.fill_subtree(nodes, deeper, first, scratch, sum);
        let mut child = Accumulator::EMPTY;
        for k in 1..usize::from(node.child_count) {
            spheres[k] = self.fill_subtree(nodes, deeper, first + k, scratch, &mut child);
            absorb_on(self.isa, sum, &child);
        }
        let spheres = spheres[..usize::from(node.child_count)].iter().copied();
        let (node_bounds, sphere) =
            inner_attributes_on(self.isa, node, spheres, sum, self.leaf_positions);
        this_level[(node.bounds - *first_index) as usize] = node_bounds;
        sphere
    }
}

/// A leaf's incident triangles, gathered once and used by every leaf attribute: each one's
/// two corners besides the leaf's vertex (as stored, in `f32`: half the bytes of widened
/// ones, and widening again later gives the same values), and the unit normals of those with
/// a non-zero area (apart, so the cone fits run over a plain slice).
#[derive(Default)]
struct LeafScratch {
    corners: Vec<[[f32; 3]; 2]>,
    normals: Vec<[f64; 3]>,
}

dispatched! {
    /// [`leaf_attributes`] compiled for `isa`.
    fn leaf_attributes_on(
        vertex: u32,
        scene: &Scene,
        incident: &[u32],
        scratch: &mut LeafScratch,
        out: &mut Accumulator,
    ) -> Sphere = leaf_attributes;
}

/// A leaf's accumulator (written to `out`) and sphere, from its incident triangles.
/// (Inlined into both compilations of [`leaf_attributes_on`], as the other kernels are into
/// theirs.)
#[inline(always)]
fn leaf_attributes(
    vertex: u32,
    scene: &Scene,
    incident: &[u32],
    scratch: &mut LeafScratch,
    out: &mut Accumulator,
) -> Sphere {
    let position = scene.positions[vertex as usize];
    let p = widen(position);
    // Σ area·n·nᵀ of the incident planes; they all pass through this vertex, which gives
    // the rest of the quadric (`Quadric::through_point`).
    let mut moments = [0.0f64; 6];
    let mut triangle_box = Aabb::EMPTY;
    triangle_box.add_point(position);
    scratch.corners.clear();
    scratch.normals.clear();
    for &t in incident {
        // The vertex is a corner of each of its triangles, already in the box and at the
        // start of the farthest-corner scan below; only the other two, taken in the
        // triangle's cyclic order (which keeps its winding), are new. (A triangle that repeats
        // the vertex, which welding drops but a scene built by hand may hold, gives the same
        // box and distances this way, and no normal either way: its area is zero.)
        let [i0, i1, i2] = scene.triangles[t as usize];
        let (j, k) = if i0 == vertex {
            (i1, i2)
        } else if i1 == vertex {
            (i2, i0)
        } else {
            (i0, i1)
        };
        let others = [scene.positions[j as usize], scene.positions[k as usize]];
        triangle_box.add_point(others[0]);
        triangle_box.add_point(others[1]);
        let [b, c] = others.map(widen);
        // One cross product gives both the plane for the quadric and the normal for the cone.
        let n = cross(sub(b, p), sub(c, p));
        let twice_area = dot(n, n).sqrt();
        if twice_area > 0.0 && twice_area.is_finite() {
            let inverse = 1.0 / twice_area;
            let normal = n.map(|x| x * inverse);
            // area·n̂·n̂ᵀ = n·nᵀ / (2·|n|) for the unnormalised cross product `n`.
            let w = 0.5 * inverse;
            let wn = n.map(|x| x * w);
            moments[0] += wn[0] * n[0];
            moments[1] += wn[0] * n[1];
            moments[2] += wn[0] * n[2];
            moments[3] += wn[1] * n[1];
            moments[4] += wn[1] * n[2];
            moments[5] += wn[2] * n[2];
            scratch.normals.push(normal);
        }
        scratch.corners.push(others);
    }
    let center = widen(triangle_box.center().map(|c| c as f32));
    // Plain loops and a comparison: a flattened iterator and `f64::max`'s NaN rule (distances
    // between finite points are never NaN) cost more instructions than the distances.
    let mut farthest = distance_squared(center, p);
    for others in &scratch.corners {
        for &q in others {
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
    let sphere = Sphere {
        center: center.map(|c| c as f32),
        radius: round_up_f32(radius),
    };
    let mut vertex_box = Aabb::EMPTY;
    vertex_box.add_point(position);
    *out = Accumulator {
        quadric: Quadric::through_point(moments, p),
        position_sum: p,
        vertex_box,
        triangle_box,
        cone,
        two_sided,
    };
    sphere
}

dispatched! {
    /// [`Accumulator::absorb`] compiled for `isa`.
    pub(crate) fn absorb_on(sum: &mut Accumulator, other: &Accumulator) = Accumulator::absorb;
}

impl Accumulator {
    /// A placeholder to be overwritten (the sum of nothing).
    pub(crate) const EMPTY: Accumulator = Accumulator {
        quadric: Quadric {
            a: [0.0; 6],
            b: [0.0; 3],
            c: 0.0,
        },
        position_sum: [0.0; 3],
        vertex_box: Aabb::EMPTY,
        triangle_box: Aabb::EMPTY,
        cone: NormalCone::EMPTY,
        two_sided: None,
    };

    /// Adds `other` in place (a 224-byte accumulator moved in and out per child cost
    /// copies; the sums and their order are the same).
    #[inline(always)]
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

dispatched! {
    /// [`inner_attributes`] compiled for `isa`.
    pub(crate) fn inner_attributes_on(
        node: &Node,
        child_spheres: impl Iterator<Item = Sphere>,
        sum: &Accumulator,
        leaf_positions: &[[f32; 3]],
    ) -> (NodeBounds, Sphere) = inner_attributes;
}

/// An inner node's proxy and bounds from its children's accumulated sum and their spheres,
/// and the sphere it passes up.
#[inline(always)]
fn inner_attributes(
    node: &Node,
    child_spheres: impl Iterator<Item = Sphere>,
    sum: &Accumulator,
    leaf_positions: &[[f32; 3]],
) -> (NodeBounds, Sphere) {
    let proxy = inner_proxy(node, sum);
    let leaves = &leaf_positions[node.leaf_begin as usize..node.leaf_end as usize];
    inner_bounds(
        proxy,
        farthest_squared(widen(proxy), leaves),
        child_spheres,
        sum,
    )
}

/// An inner node's proxy: the quadric's minimiser near the mean of its vertices.
#[inline(always)]
pub(crate) fn inner_proxy(node: &Node, sum: &Accumulator) -> [f32; 3] {
    let count = f64::from(node.leaf_count());
    let mean = sum.position_sum.map(|c| c / count);
    // The proxy stays inside the cluster's vertex box, so inside the node's octree cell.
    sum.vertex_box
        .clamp(sum.quadric.minimizer_near(mean))
        .map(|c| c as f32)
}

/// An inner node's bounds around `proxy`, given the squared distance to its farthest leaf
/// (the maximum of [`leaf_distance_squared`] over its leaves, in any order), and the sphere it
/// passes up.
#[inline(always)]
pub(crate) fn inner_bounds(
    proxy: [f32; 3],
    farthest_squared: f64,
    child_spheres: impl Iterator<Item = Sphere>,
    sum: &Accumulator,
) -> (NodeBounds, Sphere) {
    let error_radius = round_up_f32(farthest_squared.sqrt());
    let surface_error = surface_error(&sum.quadric, widen(proxy)).min(error_radius);
    let center = sum.triangle_box.center().map(|c| c as f32);
    let sphere_radius = child_spheres
        .map(|c| distance(widen(center), widen(c.center)) + f64::from(c.radius))
        .fold(0.0, f64::max);
    let sphere = Sphere {
        center,
        radius: round_up_f32(sphere_radius),
    };
    let (cone_axis, cone_half_angle, cone_two_sided) =
        stored_cone(&sum.cone, sum.two_sided.as_ref());
    let bounds = NodeBounds {
        proxy,
        error_radius,
        surface_error,
        sphere_center: sphere.center,
        sphere_radius: sphere.radius,
        cone_axis,
        cone_half_angle,
        cone_two_sided,
    };
    (bounds, sphere)
}

/// The squared distance from a proxy to a leaf position, as the error radius measures it.
pub(crate) fn leaf_distance_squared(proxy: [f32; 3], leaf: [f32; 3]) -> f64 {
    distance_squared(widen(proxy), widen(leaf))
}

/// The root-mean-square plane distance of `proxy` under `quadric` ([`NodeBounds::surface_error`]),
/// rounded up. The quadric's planes have unit normals and area weights, so the trace of its
/// matrix is the total weight.
#[inline(always)]
fn surface_error(quadric: &Quadric, proxy: [f64; 3]) -> f32 {
    let weight = quadric.a[0] + quadric.a[3] + quadric.a[5];
    if weight > 0.0 {
        round_up_f32((quadric.error(proxy).max(0.0) / weight).sqrt())
    } else {
        0.0
    }
}

/// The cone to store, as axis, half-angle and two-sidedness: the one-sided cone, or the
/// two-sided one where the one-sided cone is wider than a hemisphere (no view then sees only
/// backs, and every view sees a possible silhouette: the cone tells nothing) and the
/// two-sided cone is narrower than a hemisphere.
fn stored_cone(cone: &NormalCone, two_sided: Option<&NormalCone>) -> ([f32; 3], f32, bool) {
    let half_pi = std::f64::consts::FRAC_PI_2;
    let two_sided = two_sided
        .filter(|c| !cone.is_empty() && cone.half_angle >= half_pi && c.half_angle < half_pi);
    let use_two_sided = two_sided.is_some();
    let chosen = two_sided.unwrap_or(cone);
    let half_angle = if chosen.is_empty() {
        -1.0
    } else {
        round_up_f32(chosen.half_angle)
    };
    (chosen.axis.map(|c| c as f32), half_angle, use_two_sided)
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

/// The triangles sorted by the node they are a subtri of (a counting sort, stable), and the
/// end of each node's run in that order.
fn sort_subtris(tree: &VertexTree, triangles: &[[u32; 3]]) -> (Vec<u32>, Vec<u32>) {
    let owner: Vec<u32> = triangles.par_iter().map(|&t| tree.subtri_node(t)).collect();
    // `ends[id]` starts as the number of subtris of the nodes before `id`, where its run
    // starts, and is advanced past each subtri written: at the end it is where the run ends.
    let mut ends = filled(tree.nodes.len() + 1, 0u32);
    for &node in &owner {
        ends[node as usize + 1] += 1;
    }
    for i in 0..tree.nodes.len() {
        ends[i + 1] += ends[i];
    }
    let mut subtris = filled(triangles.len(), 0u32);
    for (t, &node) in owner.iter().enumerate() {
        subtris[ends[node as usize] as usize] = t as u32;
        ends[node as usize] += 1;
    }
    ends.pop();
    (ends, subtris)
}

/// Sets each node's subtri range from the ends of the runs ([`sort_subtris`]): a node's run
/// starts where the previous node's ends.
fn set_subtri_ranges(nodes: &mut [Node], ends: &[u32]) {
    // In parallel: a pass over every node, the whole node array.
    nodes.par_iter_mut().enumerate().for_each(|(id, node)| {
        node.subtri_begin = if id == 0 { 0 } else { ends[id - 1] };
        node.subtri_end = ends[id];
    });
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The wide kernels (`crate::isa`) must build the tree the baseline ones build, bit for
    /// bit, or `.vdt` files would depend on the CPU that built them.
    #[test]
    fn wide_kernels_build_the_same_tree_as_baseline_ones() {
        let path = concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/../../testdata/as1_assembly.obj"
        );
        let mut scene = vds_import::load_file(path, &Default::default()).expect("test mesh");
        // Besides the CAD parts, a row of coplanar triangles of alternating winding (normals
        // exactly ±z), so two-sided cones and exactly parallel cone axes both occur.
        let base = scene.positions.len() as u32;
        for k in 0..64u32 {
            let x = k as f32 * 0.37;
            scene
                .positions
                .extend([[x, 0.0, 5.0], [x + 0.3, 0.0, 5.0], [x, 0.3, 5.0]]);
            let v = base + 3 * k;
            let triangle = if k % 2 == 0 {
                [v, v + 1, v + 2]
            } else {
                [v, v + 2, v + 1]
            };
            scene.triangles.push(triangle);
            scene.triangle_parts.push(0);
        }
        let isa = Isa::detect();
        #[cfg(target_arch = "x86_64")]
        assert!(
            isa.is_wide(),
            "comparing the two compilations needs an x86-64 CPU with AVX2, BMI1/2 and LZCNT"
        );
        let (wide, _) = build_tree_with(&scene, Builder::Octree, isa);
        let (baseline, _) = build_tree_with(&scene, Builder::Octree, Isa::BASELINE);
        assert!(wide.nodes.len() > 5_000, "{} nodes", wide.nodes.len());
        assert!(wide.bounds.iter().any(|b| b.cone_two_sided));
        assert_eq!(wide, baseline);
        // Compared as bits: equal values with different bits (−0.0, NaN payloads) would
        // still change a file.
        let bits = |tree: &VertexTree| -> Vec<u32> {
            tree.bounds
                .iter()
                .flat_map(|b| {
                    let mut words = vec![b.error_radius, b.sphere_radius, b.cone_half_angle];
                    words.extend(b.proxy.iter().chain(&b.sphere_center).chain(&b.cone_axis));
                    words
                        .into_iter()
                        .map(f32::to_bits)
                        .chain([u32::from(b.cone_two_sided)])
                })
                .collect()
        };
        assert_eq!(bits(&wide), bits(&baseline));
    }
}
