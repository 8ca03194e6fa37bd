//! Tight-octree vertex clustering: the topology of the vertex tree.
//!
//! Luebke & Erikson, "View-Dependent Simplification of Arbitrary Polygonal Environments"
//! (SIGGRAPH 1997), §5.1: each node's cube is shrunk to the smallest axis-aligned cube that
//! encloses its vertices before it is split into octants, so the tree adapts to the model
//! instead of to the scene's bounding cube. The cube is anchored at the vertices' lower
//! bounding-box corner; a thin axis (extent below half the cube's side) is therefore not split
//! until the cells are as small as it is thin, which lets the two faces of a thin plate merge
//! early.
//!
//! The tree is built one level at a time: all nodes of a level partition their own slice of
//! one vertex-order array in parallel (a stable counting sort by octant), and their children,
//! appended in order, form the next level. Node ids are therefore breadth-first (a node's
//! children are contiguous, parents precede children) and the final order array lists the
//! leaves in depth-first order, so every node owns a contiguous range of it. Nothing depends
//! on scheduling, so the result is identical on any thread count.
//!
//! Termination: an octant split of a cube with positive side always separates the vertices at
//! its lower and upper faces, except when rounding puts the split plane on a face; then (and
//! for clusters of coincident vertices) the node splits its range in balanced chunks instead.
//! Every inner node has at least two children and at most eight.

use rayon::prelude::*;

use crate::tree::Node;

/// No parent (the root).
pub const NO_PARENT: u32 = u32::MAX;

/// The clustering of a vertex set.
#[derive(Debug, Clone, PartialEq)]
pub struct Clustering {
    /// Nodes in breadth-first order; node 0 is the root.
    /// Only the topology fields (parent, children, depth, leaf range) are set.
    pub nodes: Vec<Node>,
    /// Vertex id of each leaf rank (depth-first leaf order).
    pub leaf_vertex: Vec<u32>,
    /// Node ids where each depth starts, plus the total count at the end.
    pub level_starts: Vec<u32>,
}

/// Clusters `positions` (at least one) into a tight octree.
pub fn cluster(positions: &[[f32; 3]]) -> Clustering {
    assert!(!positions.is_empty(), "cluster() needs at least one vertex");
    assert!(
        positions.len() < u32::MAX as usize,
        "vertex ids must fit in u32"
    );
    let mut order: Vec<u32> = (0..positions.len() as u32).collect();
    // An inner node has at least two children, so there are at most 2V - 1 nodes; reserving
    // that (untouched pages cost nothing) avoids copying the node array as it grows.
    let mut nodes = Vec::with_capacity(2 * positions.len() - 1);
    nodes.push(Node::topology(0, positions.len() as u32, NO_PARENT, 0));
    let mut level_starts = vec![0u32];
    let mut level = 0..1usize;
    while !level.is_empty() {
        // Hand each splittable node of this level its own slice of the order array.
        let mut work: Vec<(usize, &mut [u32])> = Vec::new();
        let mut rest: &mut [u32] = &mut order;
        let mut consumed = 0usize;
        for id in level.clone() {
            let node = nodes[id];
            let (begin, end) = (node.leaf_begin as usize, node.leaf_end as usize);
            let tail = std::mem::take(&mut rest);
            let (_, tail) = tail.split_at_mut(begin - consumed);
            let (slice, tail) = tail.split_at_mut(end - begin);
            rest = tail;
            consumed = end;
            if end - begin > 1 {
                work.push((id, slice));
            }
        }
        let splits: Vec<(usize, ChildSizes)> = work
            .into_par_iter()
            .map_init(Vec::new, |scratch, (id, slice)| {
                (id, split(slice, positions, scratch))
            })
            .collect();
        let next_start = nodes.len();
        for (id, child_sizes) in splits {
            let parent = nodes[id];
            nodes[id].first_child = nodes.len() as u32;
            nodes[id].child_count = child_sizes.len() as u8;
            let mut begin = parent.leaf_begin;
            for &size in child_sizes.as_slice() {
                nodes.push(Node::topology(
                    begin,
                    begin + size,
                    id as u32,
                    parent.depth + 1,
                ));
                begin += size;
            }
        }
        level = next_start..nodes.len();
        level_starts.push(next_start as u32);
    }
    Clustering {
        nodes,
        leaf_vertex: order,
        level_starts,
    }
}

/// Sizes of a node's children, in order (at most eight; no heap allocation per node).
struct ChildSizes {
    sizes: [u32; 8],
    count: usize,
}

impl ChildSizes {
    fn from_iter(sizes: impl Iterator<Item = u32>) -> ChildSizes {
        let mut out = ChildSizes {
            sizes: [0; 8],
            count: 0,
        };
        for size in sizes {
            out.sizes[out.count] = size;
            out.count += 1;
        }
        out
    }

    fn len(&self) -> usize {
        self.count
    }

    fn as_slice(&self) -> &[u32] {
        &self.sizes[..self.count]
    }
}

/// Reorders `slice` (≥ 2 vertex ids) into its children and returns their sizes, in order.
fn split(slice: &mut [u32], positions: &[[f32; 3]], scratch: &mut Vec<u32>) -> ChildSizes {
    let mut min = [f32::INFINITY; 3];
    let mut max = [f32::NEG_INFINITY; 3];
    for &v in slice.iter() {
        let p = positions[v as usize];
        for k in 0..3 {
            min[k] = min[k].min(p[k]);
            max[k] = max[k].max(p[k]);
        }
    }
    let side = (0..3).map(|k| max[k] - min[k]).fold(0.0f32, f32::max);
    if side > 0.0 {
        let mid = [0, 1, 2].map(|k| min[k] + 0.5 * side);
        let octant = |v: u32| {
            let p = positions[v as usize];
            usize::from(p[0] >= mid[0])
                | usize::from(p[1] >= mid[1]) << 1
                | usize::from(p[2] >= mid[2]) << 2
        };
        let mut counts = [0u32; 8];
        for &v in slice.iter() {
            counts[octant(v)] += 1;
        }
        if counts.iter().filter(|&&c| c > 0).count() >= 2 {
            let mut offsets = [0u32; 8];
            let mut total = 0;
            for k in 0..8 {
                offsets[k] = total;
                total += counts[k];
            }
            scratch.clear();
            scratch.resize(slice.len(), 0);
            for &v in slice.iter() {
                let o = octant(v);
                scratch[offsets[o] as usize] = v;
                offsets[o] += 1;
            }
            slice.copy_from_slice(scratch);
            return ChildSizes::from_iter(counts.into_iter().filter(|&c| c > 0));
        }
    }
    // Coincident vertices, or a split plane that rounding put on a face: balanced chunks.
    balanced_chunks(slice.len() as u32)
}

/// Sizes of at most eight nearly equal chunks of `n ≥ 2` items.
fn balanced_chunks(n: u32) -> ChildSizes {
    let parts = n.min(8);
    ChildSizes::from_iter((0..parts).map(|i| n / parts + u32::from(i < n % parts)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn coincident_vertices_terminate_in_leaves() {
        let positions = vec![[1.0, 2.0, 3.0]; 100];
        let c = cluster(&positions);
        let leaves = c.nodes.iter().filter(|n| n.child_count == 0).count();
        assert_eq!(leaves, 100);
        assert!(
            c.nodes
                .iter()
                .all(|n| n.child_count <= 8 && n.child_count != 1)
        );
    }

    #[test]
    fn adjacent_floats_split_cleanly() {
        let x = 1.0f32;
        let positions = vec![
            [x, 0.0, 0.0],
            [x.next_up(), 0.0, 0.0],
            [x.next_up().next_up(), 0.0, 0.0],
        ];
        let c = cluster(&positions);
        assert_eq!(c.nodes.iter().filter(|n| n.child_count == 0).count(), 3);
    }

    #[test]
    fn single_vertex_is_a_leaf_root() {
        let c = cluster(&[[0.0, 0.0, 0.0]]);
        assert_eq!(c.nodes.len(), 1);
        assert_eq!(c.leaf_vertex, vec![0]);
    }
}
