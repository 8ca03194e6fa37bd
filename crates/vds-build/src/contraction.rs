//! Quadric-ordered pair contraction: the topology of the `qem` builder's vertex tree.
//!
//! Garland & Heckbert, "Surface Simplification Using Quadric Error Metrics" (SIGGRAPH 1997),
//! run to the end: every vertex starts as a cluster, and the cheapest pair of clusters is
//! contracted into one until a single cluster is left. Each contraction becomes one inner node
//! whose two children are the contracted clusters, so the tree records the whole contraction
//! sequence, and a view-independent budget cut ranked by the same error replays it from the
//! coarse end. The octree builder ([`crate::octree`]) groups vertices by where they are; this
//! one by what merging them costs the surface, which is what a cut's fidelity per triangle
//! follows (Luebke & Erikson §5: the tree may come from any of a spectrum of algorithms).
//!
//! **Candidate pairs.** The mesh's edges, and *proximity pairs*: each vertex with the next one
//! in the tight octree's depth-first leaf order, which is spatially close. Proximity pairs join
//! vertices that share no edge: two parts of an assembly, the two faces of a thin plate, the
//! sides of a crack. So topology still simplifies and parts still merge, when the error says
//! it is cheaper than going on along the surface. When no candidate is left (each connected
//! group has become one cluster), the surviving clusters are paired the same way through an
//! octree over their proxies, which links them all, and contraction goes on to one root.
//!
//! **Cost** of a pair: the root-mean-square distance from the merged proxy to the merged
//! quadric's planes (the node's surface error, [`crate::NodeBounds::surface_error`]), plus a
//! 32nd of a bound on the merged error radius, the same ranking the runtime's budget cut uses
//! (`criteria::TIE_BREAK` in `vds-runtime`). The radius term decides among pairs of equal
//! surface error: flat regions then contract in compact clusters instead of one cluster
//! growing a vertex at a time, which would make the tree as deep as the region is wide.
//!
//! The proxy of a candidate is placed as the attribute pass places a node's
//! ([`Quadric::minimizer_near`] the mean, clamped to the vertices' box), so the cost that
//! ordered the contraction is the error the node is stored with, up to rounding. Ties are
//! broken by cluster ids, so the tree depends on the input alone. One thread: the heap's order
//! is sequential by nature.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use crate::bounds::Aabb;
use crate::octree::{Clustering, NO_PARENT, cluster};
use crate::quadric::{Quadric, dot, sub};
use crate::tree::Node;

/// The share of the error-radius bound added to a pair's cost (the runtime's tie break).
const RADIUS_SHARE: f64 = 1.0 / 32.0;

/// A cluster of vertices: what a contraction needs to price pairs with it.
#[derive(Clone, Copy)]
struct Cluster {
    quadric: Quadric,
    position_sum: [f64; 3],
    count: u32,
    vertex_box: Aabb,
    proxy: [f64; 3],
    /// An upper bound on the distance from the proxy to any vertex of the cluster.
    radius: f64,
}

impl Cluster {
    fn vertex(position: [f32; 3], quadric: Quadric) -> Cluster {
        let mut vertex_box = Aabb::EMPTY;
        vertex_box.add_point(position);
        let p = position.map(f64::from);
        Cluster {
            quadric,
            position_sum: p,
            count: 1,
            vertex_box,
            proxy: p,
            radius: 0.0,
        }
    }

    /// The cluster `a` and `b` contract into.
    fn merged(a: &Cluster, b: &Cluster) -> Cluster {
        let mut quadric = a.quadric;
        quadric.add(&b.quadric);
        let position_sum = [0, 1, 2].map(|k| a.position_sum[k] + b.position_sum[k]);
        let count = a.count + b.count;
        let mut vertex_box = a.vertex_box;
        vertex_box.add_box(&b.vertex_box);
        let mean = position_sum.map(|c| c / f64::from(count));
        // Rounded to `f32` as the stored proxy is, so the radius bound holds for it.
        let proxy = vertex_box
            .clamp(quadric.minimizer_near(mean))
            .map(|c| f64::from(c as f32));
        let radius = (distance(proxy, a.proxy) + a.radius).max(distance(proxy, b.proxy) + b.radius);
        Cluster {
            quadric,
            position_sum,
            count,
            vertex_box,
            proxy,
            radius,
        }
    }

    /// What contracting into this cluster costs: its surface error plus the radius share.
    fn cost(&self) -> f64 {
        let weight = self.quadric.a[0] + self.quadric.a[3] + self.quadric.a[5];
        let surface = if weight > 0.0 {
            (self.quadric.error(self.proxy).max(0.0) / weight).sqrt()
        } else {
            0.0
        };
        surface + RADIUS_SHARE * self.radius
    }
}

fn distance(a: [f64; 3], b: [f64; 3]) -> f64 {
    let d = sub(a, b);
    dot(d, d).sqrt()
}

/// A cluster id that is still alive has no entry in `merged_into`'s chain.
const ALIVE: u32 = u32::MAX;

/// The contraction in progress: clusters `0..n` are the vertices, later ones the contractions
/// in order, each with its two children.
struct Contraction {
    clusters: Vec<Cluster>,
    /// The two children of cluster `n + k`, at `k`.
    children: Vec<[u32; 2]>,
    /// The cluster each dead cluster was contracted into ([`ALIVE`] for a living one).
    merged_into: Vec<u32>,
    /// Clusters each cluster shares a candidate pair with; entries may name dead clusters,
    /// which [`Contraction::find`] resolves to the living cluster that holds them. The lists
    /// are symmetric up to that resolution: a contraction gives the new cluster the union of
    /// its two lists, and each neighbour's list already names one of the two.
    neighbours: Vec<Vec<u32>>,
    /// Candidate pairs by cost (as ordered bits: costs are never negative), cheapest first.
    /// A pair is current while both its clusters live: a cluster's cost inputs never change,
    /// it only dies.
    heap: BinaryHeap<Reverse<(u64, u32, u32)>>,
    alive: usize,
}

impl Contraction {
    fn find(&mut self, mut id: u32) -> u32 {
        let mut root = id;
        while self.merged_into[root as usize] != ALIVE {
            root = self.merged_into[root as usize];
        }
        // Path compression: later look-ups of the same stale ids take one step.
        while self.merged_into[id as usize] != ALIVE {
            let next = self.merged_into[id as usize];
            self.merged_into[id as usize] = root;
            id = next;
        }
        root
    }

    fn push_pair(&mut self, a: u32, b: u32) {
        let (a, b) = (a.min(b), a.max(b));
        let cost = Cluster::merged(&self.clusters[a as usize], &self.clusters[b as usize]).cost();
        let key = if cost.is_finite() {
            cost.to_bits()
        } else {
            f64::INFINITY.to_bits()
        };
        self.heap.push(Reverse((key, a, b)));
    }

    /// Makes `a` and `b` (living, distinct) candidates of each other.
    fn link(&mut self, a: u32, b: u32) {
        self.neighbours[a as usize].push(b);
        self.neighbours[b as usize].push(a);
        self.push_pair(a, b);
    }

    /// Resolves a neighbour list to living clusters, each once, without `own`.
    fn resolve(&mut self, mut list: Vec<u32>, own: u32) -> Vec<u32> {
        for entry in list.iter_mut() {
            *entry = self.find(*entry);
        }
        list.sort_unstable();
        list.dedup();
        list.retain(|&x| x != own);
        list
    }

    /// Contracts living clusters `a` and `b` into a new one and prices it against every
    /// neighbour of either.
    fn contract(&mut self, a: u32, b: u32) {
        let id = self.clusters.len() as u32;
        let merged = Cluster::merged(&self.clusters[a as usize], &self.clusters[b as usize]);
        self.clusters.push(merged);
        self.children.push([a, b]);
        self.merged_into.push(ALIVE);
        self.merged_into[a as usize] = id;
        self.merged_into[b as usize] = id;
        self.alive -= 1;
        let mut list = std::mem::take(&mut self.neighbours[a as usize]);
        list.append(&mut std::mem::take(&mut self.neighbours[b as usize]));
        let list = self.resolve(list, id);
        // Each neighbour's own list already names `a` or `b`, which `find` resolves to the new
        // cluster: nothing needs writing there.
        for &other in &list {
            self.push_pair(id, other);
        }
        self.neighbours.push(list);
    }

    /// Removes every pair of which a cluster is dead from the heap (a pop would skip them).
    fn drop_stale_pairs(&mut self) {
        let mut pairs = std::mem::take(&mut self.heap).into_vec();
        let live = |id: u32| self.merged_into[id as usize] == ALIVE;
        pairs.retain(|Reverse((_, a, b))| live(*a) && live(*b));
        self.heap = BinaryHeap::from(pairs);
    }

    /// Pairs the living clusters along the tight octree's leaf order of their proxies, which
    /// links them all: the candidates once each connected group has become one cluster.
    fn link_survivors(&mut self) {
        let living: Vec<u32> = (0..self.clusters.len() as u32)
            .filter(|&id| self.merged_into[id as usize] == ALIVE)
            .collect();
        let proxies: Vec<[f32; 3]> = living
            .iter()
            .map(|&id| self.clusters[id as usize].proxy.map(|c| c as f32))
            .collect();
        let order = cluster(&proxies).leaf_vertex;
        for pair in order.windows(2) {
            self.link(living[pair[0] as usize], living[pair[1] as usize]);
        }
    }
}

/// The quadric of each vertex: the area-weighted planes of its triangles.
fn vertex_quadrics(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<Quadric> {
    let mut quadrics = vec![Quadric::default(); positions.len()];
    for t in triangles {
        let [a, b, c] = t.map(|v| positions[v as usize].map(f64::from));
        let q = Quadric::from_triangle(a, b, c);
        for &v in t {
            quadrics[v as usize].add(&q);
        }
    }
    quadrics
}

/// The candidate pairs to start from: the mesh's edges and each vertex with its successor in
/// the octree's leaf order, each once.
fn initial_pairs(positions: &[[f32; 3]], triangles: &[[u32; 3]]) -> Vec<(u32, u32)> {
    let mut pairs: Vec<(u32, u32)> = Vec::with_capacity(3 * triangles.len() + positions.len());
    for t in triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if a != b {
                pairs.push((a.min(b), a.max(b)));
            }
        }
    }
    let order = cluster(positions).leaf_vertex;
    for w in order.windows(2) {
        pairs.push((w[0].min(w[1]), w[0].max(w[1])));
    }
    pairs.sort_unstable();
    pairs.dedup();
    pairs
}

/// The deepest contraction tree [`contract`] lays out. Real meshes give trees a few dozen
/// levels deep (the bunny 23, the dragon 32); a deeper one would come from a contrived input
/// whose clusters grow a vertex at a time, and the attribute pass recurses as deep as the
/// tree below its parallel frontier.
pub const MAX_DEPTH: usize = 1024;

/// Clusters the scene's vertices (at least one) by quadric-ordered pair contraction, or
/// `None` when the tree would be deeper than `max_depth` levels ([`MAX_DEPTH`] for the
/// builder, which then clusters by octree instead).
pub fn contract(
    positions: &[[f32; 3]],
    triangles: &[[u32; 3]],
    max_depth: usize,
) -> Option<Clustering> {
    let n = positions.len();
    assert!(n > 0, "contraction needs a vertex");
    let quadrics = vertex_quadrics(positions, triangles);
    let mut state = Contraction {
        clusters: positions
            .iter()
            .zip(&quadrics)
            .map(|(&p, &q)| Cluster::vertex(p, q))
            .collect(),
        children: Vec::with_capacity(n.saturating_sub(1)),
        merged_into: vec![ALIVE; n],
        neighbours: vec![Vec::new(); n],
        heap: BinaryHeap::new(),
        alive: n,
    };
    drop(quadrics);
    for (a, b) in initial_pairs(positions, triangles) {
        state.link(a, b);
    }
    let mut kept = state.heap.len();
    while state.alive > 1 {
        // Pairs go stale as their clusters are contracted, several per contraction, and a
        // stale pair popped costs a walk down the whole heap. So they are dropped in one pass
        // when the heap holds four pairs per living cluster (a mesh has about three per
        // vertex, so most are stale), but only once it has grown by a quarter since the last
        // pass: a pass over the heap then stands for at least a fifth as many pushes, which
        // keeps the passes linear however many neighbours the late, large clusters have.
        if state.heap.len() > 4 * state.alive + 4096 && state.heap.len() >= kept + kept / 4 {
            state.drop_stale_pairs();
            kept = state.heap.len();
        }
        match state.heap.pop() {
            Some(Reverse((_, a, b))) => {
                let live = |id: u32| state.merged_into[id as usize] == ALIVE;
                if live(a) && live(b) {
                    state.contract(a, b);
                }
            }
            None => state.link_survivors(),
        }
    }
    tree_of(&state.children, positions, max_depth)
}

/// Lays out the contraction tree (root: the last cluster) as a [`Clustering`]: nodes
/// breadth-first, leaves ranked depth-first, so each node covers a contiguous leaf range.
/// `None` when it is deeper than `max_depth`.
fn tree_of(children: &[[u32; 2]], positions: &[[f32; 3]], max_depth: usize) -> Option<Clustering> {
    let n = positions.len();
    let root = (n + children.len() - 1) as u32;
    // Leaves under each cluster: vertices count one, contractions the sum of their children
    // (children always precede the cluster they form).
    let mut leaves = vec![1u32; n + children.len()];
    for (k, &[a, b]) in children.iter().enumerate() {
        leaves[n + k] = leaves[a as usize] + leaves[b as usize];
    }
    let mut nodes = Vec::with_capacity(n + children.len());
    let mut cluster_of = Vec::with_capacity(n + children.len());
    nodes.push(Node::topology(0, n as u32, NO_PARENT, 0));
    cluster_of.push(root);
    let mut level_starts = vec![0u32];
    let mut inner = 0u32;
    let mut next = 0usize;
    while next < nodes.len() {
        let id = next;
        next += 1;
        let cluster = cluster_of[id] as usize;
        let node = nodes[id];
        // Breadth-first order visits the depths in turn: the first node of a new depth starts
        // its level.
        if usize::from(node.depth) == level_starts.len() {
            level_starts.push(id as u32);
        }
        if cluster < n {
            continue;
        }
        let pair = children[cluster - n];
        if usize::from(node.depth) >= max_depth.min(usize::from(u16::MAX)) {
            return None;
        }
        let depth = node.depth + 1;
        let first_child = nodes.len() as u32;
        let mut begin = node.leaf_begin;
        for &child in &pair {
            let end = begin + leaves[child as usize];
            nodes.push(Node::topology(begin, end, id as u32, depth));
            cluster_of.push(child);
            begin = end;
        }
        let node = &mut nodes[id];
        node.first_child = first_child;
        node.child_count = 2;
        node.bounds = inner;
        inner += 1;
    }
    level_starts.push(nodes.len() as u32);
    let mut leaf_vertex = vec![0u32; n];
    for (node, &cluster) in nodes.iter().zip(&cluster_of) {
        if (cluster as usize) < n {
            leaf_vertex[node.leaf_begin as usize] = cluster;
        }
    }
    let leaf_positions = leaf_vertex.iter().map(|&v| positions[v as usize]).collect();
    Some(Clustering {
        nodes,
        leaf_vertex,
        leaf_positions,
        level_starts,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A `side` × `side` grid of vertices, two triangles a cell, with a little bump at
    /// some vertices (none when `bumpy` is false).
    fn grid(side: u32, bumpy: bool) -> (Vec<[f32; 3]>, Vec<[u32; 3]>) {
        let mut positions = Vec::new();
        for y in 0..side {
            for x in 0..side {
                let bump = ((x * 7 + y * 3) % 5) as f32 * 0.01;
                positions.push([x as f32, y as f32, if bumpy { bump } else { 0.0 }]);
            }
        }
        let mut triangles = Vec::new();
        for y in 0..side - 1 {
            for x in 0..side - 1 {
                let v = y * side + x;
                triangles.push([v, v + 1, v + side]);
                triangles.push([v + 1, v + side + 1, v + side]);
            }
        }
        (positions, triangles)
    }

    #[test]
    fn one_root_binary_nodes_and_contiguous_leaf_ranges() {
        let (mut positions, mut triangles) = grid(20, true);
        // A second part apart from the first, sharing no edge with it.
        let base = positions.len() as u32;
        positions.extend([[50.0, 0.0, 0.0], [51.0, 0.0, 0.0], [50.0, 1.0, 0.0]]);
        triangles.push([base, base + 1, base + 2]);
        let clustering = contract(&positions, &triangles, MAX_DEPTH).unwrap();
        let nodes = &clustering.nodes;
        assert_eq!(
            nodes.iter().filter(|n| n.is_leaf()).count(),
            positions.len()
        );
        assert_eq!(nodes.len(), 2 * positions.len() - 1);
        let mut seen = vec![false; positions.len()];
        for &v in &clustering.leaf_vertex {
            assert!(!seen[v as usize], "vertex {v} ranked twice");
            seen[v as usize] = true;
        }
        for (id, node) in nodes.iter().enumerate() {
            if node.is_leaf() {
                assert_eq!(node.leaf_count(), 1);
                continue;
            }
            let [a, b] = [0, 1].map(|k| nodes[node.first_child as usize + k]);
            assert_eq!((a.parent, b.parent), (id as u32, id as u32));
            assert_eq!(a.leaf_begin, node.leaf_begin);
            assert_eq!(a.leaf_end, b.leaf_begin);
            assert_eq!(b.leaf_end, node.leaf_end);
            assert_eq!(a.depth, node.depth + 1);
        }
        let levels = &clustering.level_starts;
        for d in 0..levels.len() - 1 {
            for node in &nodes[levels[d] as usize..levels[d + 1] as usize] {
                assert_eq!(usize::from(node.depth), d);
            }
        }
    }

    #[test]
    fn a_tree_deeper_than_the_limit_is_refused() {
        let (positions, triangles) = grid(16, true);
        let depth = contract(&positions, &triangles, MAX_DEPTH)
            .unwrap()
            .level_starts
            .len()
            - 2;
        assert!(contract(&positions, &triangles, depth).is_some());
        assert!(contract(&positions, &triangles, depth - 1).is_none());
    }

    #[test]
    fn the_same_input_gives_the_same_tree() {
        let (positions, triangles) = grid(16, true);
        assert_eq!(
            contract(&positions, &triangles, MAX_DEPTH),
            contract(&positions, &triangles, MAX_DEPTH)
        );
    }

    #[test]
    fn flat_regions_stay_shallow() {
        // 1,600 vertices of a plane: a cluster growing one vertex at a time would make the
        // tree ~1,600 deep; compact contraction keeps it within a few times log2(n).
        let (positions, triangles) = grid(40, false);
        let clustering = contract(&positions, &triangles, MAX_DEPTH).unwrap();
        let depth = clustering.level_starts.len() - 2;
        assert!(depth <= 40, "depth {depth}");
    }
}
