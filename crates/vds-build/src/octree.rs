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
//! Each node partitions its own slice of a vertex-order array into the other of two buffers
//! (a stable counting sort by octant; a node with more than 64 k vertices counts and scatters
//! in parallel chunks itself). Near the root the tree is split one level at a time; once every
//! node of a level holds at most 1/64 of the vertices, each of those subtrees is split depth
//! first as one task while its items are in cache, recording its splits per level, and the
//! levels are then linked from the records. Node ids are breadth-first either way (a node's
//! children are contiguous, parents precede children) and the final order array lists the
//! leaves in depth-first order, so every node owns a contiguous range of it. Nothing depends
//! on scheduling, so the result is identical on any thread count.
//!
//! Termination: an octant split of a cube with positive side always separates the vertices at
//! its lower and upper faces, except when rounding puts the split plane on a face; then (and
//! for clusters of coincident vertices) the node splits its range in balanced chunks instead.
//! Every inner node has at least two children and at most eight.

use rayon::prelude::*;

use crate::bounds::Aabb;
use crate::isa::{Isa, dispatched};
use crate::tree::Node;

/// No parent (the root).
pub const NO_PARENT: u32 = u32::MAX;

/// The clustering of a vertex set.
#[derive(Debug, Clone, PartialEq)]
pub struct Clustering {
    /// Nodes in breadth-first order; node 0 is the root. The topology fields (parent,
    /// children, depth, leaf range) and inner nodes' bounds indices are set.
    pub nodes: Vec<Node>,
    /// Vertex id of each leaf rank (depth-first leaf order).
    pub leaf_vertex: Vec<u32>,
    /// Position of each leaf rank (the positions in depth-first leaf order).
    pub leaf_positions: Vec<[f32; 3]>,
    /// Node ids where each depth starts, plus the total count at the end.
    pub level_starts: Vec<u32>,
}

/// A vertex being clustered: its position travels with its id, so partitioning streams
/// through memory instead of gathering positions through an index array.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Item {
    position: [f32; 3],
    vertex: u32,
}

/// The box of the items' positions.
fn bounds_of(items: &[Item]) -> Aabb {
    let mut b = Aabb::EMPTY;
    for item in items {
        b.add_point(item.position);
    }
    b
}

/// Clusters `positions` (at least one) into a tight octree.
pub fn cluster(positions: &[[f32; 3]]) -> Clustering {
    cluster_with(positions, Isa::detect())
}

/// [`cluster`] with the splits compiled for `isa`.
pub(crate) fn cluster_with(positions: &[[f32; 3]], isa: Isa) -> Clustering {
    let task_items = (positions.len() / TASK_SHARE).max(MIN_TASK_ITEMS);
    cluster_in_tasks(positions, task_items, isa)
}

/// [`cluster`], splitting level by level near the root until every node holds at most
/// `task_items` vertices, and each subtree below depth first. The tree is the same whatever
/// `task_items` is.
fn cluster_in_tasks(positions: &[[f32; 3]], task_items: usize, isa: Isa) -> Clustering {
    assert!(!positions.is_empty(), "cluster() needs at least one vertex");
    assert!(
        positions.len() < u32::MAX as usize,
        "vertex ids must fit in u32"
    );
    let mut items: Vec<Item> = positions
        .par_iter()
        .enumerate()
        .map(|(i, &position)| Item {
            position,
            vertex: i as u32,
        })
        .collect();
    // Levels alternate between two buffers: a level reads its nodes' items from one and
    // scatters them into the other, so nothing is copied back. A leaf's range is never
    // touched again once it is a leaf, so leaves found while reading the second buffer are
    // copied into the first, which ends up holding every leaf.
    // Copied in parallel: the copy is this buffer's first touch (88 MB at 10 M triangles),
    // whose page faults one thread would take alone.
    let mut second: Vec<Item> = items.par_iter().copied().collect();
    // An inner node has at least two children, so there are at most 2V - 1 nodes; reserving
    // that (untouched pages cost nothing) avoids copying the node array as it grows.
    let mut nodes = Vec::with_capacity(2 * positions.len() - 1);
    nodes.push(Node::topology(0, positions.len() as u32, NO_PARENT, 0));
    let mut level_starts = vec![0u32];
    let mut level = 0..1usize;
    let mut reading_first = true;
    // Bounds indices go to inner nodes in id order: levels are split in order, and a level's
    // nodes in id order.
    let mut inner_count = 0u32;
    let task_items = u32::try_from(task_items).unwrap_or(u32::MAX);
    // What a node slot holds until `link_children` writes the node.
    let placeholder = Node::topology(0, 0, NO_PARENT, 0);

    // Near the root, level by level: few nodes, each split by parallel chunks.
    while level.clone().any(|id| nodes[id].leaf_count() > task_items) {
        // Each node's own slices of both buffers; a leaf's item goes to the first buffer (see
        // `split_depth_first`).
        let mut work: Vec<(&mut [Item], &mut [Item])> = Vec::with_capacity(level.len());
        let slices = node_slices(
            &nodes[level.clone()],
            &mut items,
            &mut second,
            reading_first,
        );
        for (from, to) in slices {
            if from.len() > 1 {
                work.push((from, to));
            } else if !reading_first {
                to[0] = from[0];
            }
        }
        let splits: Vec<Children> = work
            .into_par_iter()
            .map(|(from, to)| split_on(isa, from, to))
            .collect();
        reading_first = !reading_first;
        let next_start = nodes.len();
        let added: usize = splits.iter().map(|children| children.count).sum();
        nodes.extend(std::iter::repeat_n(placeholder, added));
        let (upper, lower) = nodes.split_at_mut(next_start);
        let inner = splits.len() as u32;
        link_children(
            level.start,
            &mut upper[level.clone()],
            next_start,
            lower,
            inner_count,
            splits.into_iter(),
        );
        inner_count += inner;
        level = next_start..nodes.len();
        level_starts.push(next_start as u32);
    }

    // Below, each node of this level (the frontier) is one task that splits its subtree depth
    // first while its items are in cache, recording each split's child sizes per level; the
    // levels are then linked from those records. A level's nodes are in the same
    // left-to-right order whether a tree is walked depth or breadth first, so the records of
    // the tasks, concatenated in order, are the level's splits in id order, and a node reads
    // and writes the same buffer ranges either way: the tree is the same as level by level.
    let frontier = node_slices(
        &nodes[level.clone()],
        &mut items,
        &mut second,
        reading_first,
    );
    let records: Vec<Vec<LevelSplits>> = frontier
        .into_par_iter()
        .map(|(from, to)| {
            let mut records = Vec::new();
            split_depth_first(from, to, reading_first, 0, &mut records, isa);
            records
        })
        .collect();
    // Every node below the frontier is known now: have them all in place (the array's pages
    // faulted in parallel), then fill each level task by task in parallel. On each level a
    // task owns a contiguous run of nodes (the children of its splits one level up) and
    // appends one to the next level, at the sum of the earlier tasks' runs.
    let below: usize = records.iter().flatten().map(|splits| splits.children).sum();
    crate::prefault::populate(&mut nodes.spare_capacity_mut()[..below]);
    nodes.par_extend(rayon::iter::repeat_n(placeholder, below));
    let mut runs: Vec<usize> = vec![1; records.len()];
    for depth in 0.. {
        let level_end = level.end;
        let next_runs: Vec<usize> = records
            .iter()
            .map(|task| task.get(depth).map_or(0, |splits| splits.children))
            .collect();
        let added: usize = next_runs.iter().sum();
        let (upper, lower) = nodes.split_at_mut(level_end);
        let mut current = &mut upper[level.start..];
        let mut next = &mut lower[..added];
        let mut work = Vec::with_capacity(records.len());
        let (mut id, mut child, mut inner) = (level.start, level_end, inner_count);
        for (task, (&run, &next_run)) in records.iter().zip(runs.iter().zip(&next_runs)) {
            let (mine, tail) = std::mem::take(&mut current).split_at_mut(run);
            current = tail;
            let (children, tail) = std::mem::take(&mut next).split_at_mut(next_run);
            next = tail;
            let splits = task.get(depth);
            work.push((id, mine, child, children, inner, splits));
            id += run;
            child += next_run;
            inner += splits.map_or(0, |splits| splits.counts.len() as u32);
        }
        work.into_par_iter()
            .for_each(|(id, mine, child, children, inner, splits)| {
                let splits = splits.into_iter().flat_map(LevelSplits::iter);
                link_children(id, mine, child, children, inner, splits);
            });
        inner_count = inner;
        level_starts.push(level_end as u32);
        if added == 0 {
            break;
        }
        level = level_end..level_end + added;
        runs = next_runs;
    }
    drop(records);
    drop(second);
    Clustering {
        nodes,
        leaf_vertex: items.par_iter().map(|item| item.vertex).collect(),
        leaf_positions: items.par_iter().map(|item| item.position).collect(),
        level_starts,
    }
}

/// Subtrees split depth first as one task hold at most this share of all vertices (or
/// [`MIN_TASK_ITEMS`]): enough tasks for rayon to balance, each small enough for the cache.
const TASK_SHARE: usize = 64;

/// The least item count a depth-first task may be given however small the input.
const MIN_TASK_ITEMS: usize = 4096;

/// Each node's ranges of the two item buffers as (the one its items are read from, the one
/// its children's are written to). The nodes are consecutive in leaf order.
fn node_slices<'a>(
    nodes: &[Node],
    first: &'a mut [Item],
    second: &'a mut [Item],
    reading_first: bool,
) -> Vec<(&'a mut [Item], &'a mut [Item])> {
    let mut rest_first = first;
    let mut rest_second = second;
    let mut consumed = 0usize;
    let mut slices = Vec::with_capacity(nodes.len());
    for node in nodes {
        let (begin, end) = (node.leaf_begin as usize, node.leaf_end as usize);
        let (_, tail) = std::mem::take(&mut rest_first).split_at_mut(begin - consumed);
        let (mine_first, tail) = tail.split_at_mut(end - begin);
        rest_first = tail;
        let (_, tail) = std::mem::take(&mut rest_second).split_at_mut(begin - consumed);
        let (mine_second, tail) = tail.split_at_mut(end - begin);
        rest_second = tail;
        consumed = end;
        slices.push(if reading_first {
            (mine_first, mine_second)
        } else {
            (mine_second, mine_first)
        });
    }
    slices
}

/// Links the nodes `mine` (ids from `id`) to their children, which it writes to `children`
/// (ids from `child`): each node with more than one leaf takes the next of `splits` (its
/// children's sizes) and the next bounds index from `inner`.
fn link_children(
    id: usize,
    mine: &mut [Node],
    child: usize,
    children: &mut [Node],
    inner: u32,
    mut splits: impl Iterator<Item = Children>,
) {
    let (mut next_child, mut next_inner, mut written) = (child as u32, inner, 0usize);
    for (k, node) in mine.iter_mut().enumerate() {
        if node.leaf_count() <= 1 {
            continue;
        }
        let split = splits
            .next()
            .expect("a split recorded for every inner node");
        let sizes = split.sizes();
        node.first_child = next_child;
        node.child_count = sizes.len() as u8;
        node.bounds = next_inner;
        next_inner += 1;
        let mut begin = node.leaf_begin;
        for &size in sizes {
            children[written] =
                Node::topology(begin, begin + size, (id + k) as u32, node.depth + 1);
            begin += size;
            written += 1;
        }
        next_child += sizes.len() as u32;
    }
    debug_assert!(splits.next().is_none(), "every recorded split linked");
    debug_assert_eq!(written, children.len(), "every child written");
}

/// The splits one depth-first task made on one level, in leaf order: each split's child
/// count, and all their child sizes one after another as LEB128 varints: most sizes are
/// below 128, so one byte a node instead of four, which matters because every task's records
/// stay alive until all levels are linked (at 10 M triangles: 20 MB of peak instead of 50).
#[derive(Default)]
struct LevelSplits {
    counts: Vec<u8>,
    sizes: Vec<u8>,
    children: usize,
}

impl LevelSplits {
    /// Records one split.
    fn push(&mut self, children: &Children) {
        self.counts.push(children.count as u8);
        self.children += children.count;
        for &size in children.sizes() {
            let mut rest = size;
            while rest >= 0x80 {
                self.sizes.push(rest as u8 | 0x80);
                rest >>= 7;
            }
            self.sizes.push(rest as u8);
        }
    }

    /// Each split's children, in order.
    fn iter(&self) -> impl Iterator<Item = Children> {
        let mut bytes = self.sizes.iter();
        self.counts.iter().map(move |&count| {
            let mut children = Children {
                sizes: [0; 8],
                count: usize::from(count),
            };
            for size in &mut children.sizes[..children.count] {
                let mut shift = 0;
                loop {
                    let byte = *bytes.next().expect("a size for every child");
                    *size |= u32::from(byte & 0x7f) << shift;
                    if byte < 0x80 {
                        break;
                    }
                    shift += 7;
                }
            }
            children
        })
    }
}

/// Splits the subtree whose items are `from` (with `to`, its range of the other buffer)
/// depth first, recording each split in `records[level]`. A one-item node is a leaf; its item
/// must end in the first buffer, so a leaf read from the second is copied across.
fn split_depth_first(
    from: &mut [Item],
    to: &mut [Item],
    from_is_first: bool,
    level: usize,
    records: &mut Vec<LevelSplits>,
    isa: Isa,
) {
    if from.len() == 1 {
        if !from_is_first {
            to[0] = from[0];
        }
        return;
    }
    let children = split_on(isa, from, to);
    if records.len() == level {
        records.push(LevelSplits::default());
    }
    let splits = &mut records[level];
    splits.push(&children);
    // The children's items are now in `to`, grouped in order; they read from there.
    let (mut rest_from, mut rest_to) = (from, to);
    for &size in children.sizes() {
        let (child_to, tail) = std::mem::take(&mut rest_to).split_at_mut(size as usize);
        rest_to = tail;
        let (child_from, tail) = std::mem::take(&mut rest_from).split_at_mut(size as usize);
        rest_from = tail;
        split_depth_first(
            child_to,
            child_from,
            !from_is_first,
            level + 1,
            records,
            isa,
        );
    }
}

/// A node's children, in order: their sizes (at most eight; no heap allocation). Small on
/// purpose: a level's splits are all alive at once, millions on the widest level. (Returning
/// the children's bounds too, 192 more bytes each, saved a pass over each node's items but
/// made the clustering the build's peak of memory, and fresh memory costs more here.)
struct Children {
    sizes: [u32; 8],
    count: usize,
}

impl Children {
    /// The children's sizes, in order.
    fn sizes(&self) -> &[u32] {
        &self.sizes[..self.count]
    }
}

/// The centre of the tight cube of a node whose vertices span `bounds`, where its octant
/// split cuts; `None` when the cube has no extent (coincident vertices). The cube is anchored
/// at the box's lower corner, its side the box's longest extent.
#[inline(always)]
pub(crate) fn split_point(bounds: &Aabb) -> Option<[f32; 3]> {
    let Aabb { min, max } = *bounds;
    let side = (0..3).map(|k| max[k] - min[k]).fold(0.0f32, f32::max);
    (side > 0.0).then(|| [0, 1, 2].map(|k| min[k] + 0.5 * side))
}

/// The octant of `p` about a split point: bit `k` set when `p` is at or above it on axis `k`.
#[inline(always)]
pub(crate) fn octant_of(p: [f32; 3], mid: [f32; 3]) -> usize {
    usize::from(p[0] >= mid[0])
        | usize::from(p[1] >= mid[1]) << 1
        | usize::from(p[2] >= mid[2]) << 2
}

/// Items per parallel task when one node's split is itself split up: the levels near the root
/// hold a few nodes with most of the vertices, which one thread each would partition alone.
const ITEMS_PER_TASK: usize = 1 << 16;

dispatched! {
    /// [`split`] compiled for `isa`.
    fn split_on(from: &[Item], to: &mut [Item]) -> Children = split;
}

/// Writes `from` (≥ 2 items) into `to`, grouped by child in order, and returns the children.
/// (Inlined into both compilations of [`split_on`].)
#[inline(always)]
fn split(from: &[Item], to: &mut [Item]) -> Children {
    split_in_tasks(from, to, ITEMS_PER_TASK)
}

/// [`split`], cutting `from` into parallel tasks of `items_per_task` when it is longer.
#[inline(always)]
fn split_in_tasks(from: &[Item], to: &mut [Item], items_per_task: usize) -> Children {
    let large = from.len() > items_per_task;
    let Aabb { min, max } = if large {
        from.par_chunks(items_per_task).map(bounds_of).reduce(
            || Aabb::EMPTY,
            |mut a, b| {
                a.add_box(&b);
                a
            },
        )
    } else {
        bounds_of(from)
    };
    if let Some(mid) = split_point(&Aabb { min, max }) {
        let octant = |p: [f32; 3]| octant_of(p, mid);
        let count = |items: &[Item]| {
            let mut counts = [0u32; 8];
            for item in items {
                counts[octant(item.position)] += 1;
            }
            counts
        };
        // Stable scatter by octant of `items` into one slice per octant.
        let scatter = |items: &[Item], outputs: [&mut [Item]; 8]| {
            let mut filled = [0usize; 8];
            for item in items {
                let o = octant(item.position);
                outputs[o][filled[o]] = *item;
                filled[o] += 1;
            }
        };
        let chunk_counts: Vec<[u32; 8]> = if large {
            from.par_chunks(items_per_task).map(count).collect()
        } else {
            Vec::new()
        };
        let counts = if large {
            chunk_counts.iter().fold([0u32; 8], |mut sum, chunk| {
                for k in 0..8 {
                    sum[k] += chunk[k];
                }
                sum
            })
        } else {
            count(from)
        };
        if counts.iter().filter(|&&c| c > 0).count() >= 2 {
            if large {
                // Each octant's range of `to`, cut into one piece per chunk of `from` in
                // chunk order: the chunks scatter in parallel into disjoint pieces, in the
                // same stable order as one sequential scatter.
                let mut pieces: Vec<[&mut [Item]; 8]> = chunk_counts
                    .iter()
                    .map(|_| std::array::from_fn(|_| <&mut [Item]>::default()))
                    .collect();
                let mut rest: &mut [Item] = to;
                for k in 0..8 {
                    for (chunk, piece) in chunk_counts.iter().zip(&mut pieces) {
                        let (head, tail) =
                            std::mem::take(&mut rest).split_at_mut(chunk[k] as usize);
                        piece[k] = head;
                        rest = tail;
                    }
                }
                from.par_chunks(items_per_task)
                    .zip(pieces)
                    .for_each(|(items, outputs)| scatter(items, outputs));
            } else {
                let mut offsets = [0u32; 8];
                let mut total = 0;
                for k in 0..8 {
                    offsets[k] = total;
                    total += counts[k];
                }
                // Stable scatter by octant (as `scatter`, with offsets into one slice: fewer
                // instructions for the millions of small splits).
                for item in from {
                    let o = octant(item.position);
                    to[offsets[o] as usize] = *item;
                    offsets[o] += 1;
                }
            }
            let mut children = Children {
                sizes: [0; 8],
                count: 0,
            };
            for k in 0..8 {
                if counts[k] > 0 {
                    children.sizes[children.count] = counts[k];
                    children.count += 1;
                }
            }
            return children;
        }
    }
    // Coincident vertices, or a split plane that rounding put on a face: balanced chunks.
    to.copy_from_slice(from);
    let n = from.len() as u32;
    let parts = n.min(8);
    let mut children = Children {
        sizes: [0; 8],
        count: parts as usize,
    };
    for k in 0..parts as usize {
        children.sizes[k] = n / parts + u32::from((k as u32) < n % parts);
    }
    children
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

    /// Deterministic values in `[0, 1)` (xorshift), for test scenes.
    fn randoms(mut seed: u64) -> impl FnMut() -> f32 {
        move || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 40) as f32 / (1u64 << 24) as f32
        }
    }

    #[test]
    fn splits_in_parallel_tasks_match_one_sequential_split() {
        // Clustered and repeated positions, so octants are uneven and some chunks miss some.
        let mut random = randoms(7);
        let from: Vec<Item> = (0..5000u32)
            .map(|vertex| {
                let p = [random(), random() * random(), 0.25 * random()];
                let position = if vertex % 7 == 0 { [0.5; 3] } else { p };
                Item { position, vertex }
            })
            .collect();
        let mut sequential = from.clone();
        let expected = split_in_tasks(&from, &mut sequential, usize::MAX);
        for items_per_task in [1, 64, 999, 4096] {
            let mut chunked = from.clone();
            let children = split_in_tasks(&from, &mut chunked, items_per_task);
            assert_eq!(chunked, sequential);
            assert_eq!(children.count, expected.count);
            assert_eq!(children.sizes, expected.sizes);
        }
    }

    #[test]
    fn depth_first_tasks_build_the_same_tree_as_levels() {
        // Clusters at several scales, coincident runs and a thin plate, so that levels mix
        // leaves, balanced-chunk splits and octant splits.
        let mut random = randoms(11);
        let positions: Vec<[f32; 3]> = (0..20_000u32)
            .map(|i| match i % 5 {
                0 => [0.25; 3],
                1 => [random(), random(), 0.0],
                2 => [random() * 1e-3, random() * 1e-3, random() * 1e-3],
                _ => [random(), random() * random(), 0.25 * random()],
            })
            .collect();
        let level_by_level = cluster_in_tasks(&positions, 1, Isa::detect());
        for task_items in [2, 100, 4096, usize::MAX] {
            let clustering = cluster_in_tasks(&positions, task_items, Isa::detect());
            assert!(clustering == level_by_level, "task size {task_items}");
        }
        assert_eq!(cluster(&positions), level_by_level);
    }

    #[test]
    fn single_vertex_is_a_leaf_root() {
        let c = cluster(&[[0.0, 0.0, 0.0]]);
        assert_eq!(c.nodes.len(), 1);
        assert_eq!(c.leaf_vertex, vec![0]);
    }
}
