//! What the GPU needs to learn after an adjust, gathered on the CPU: the vertex records of
//! nodes the cut starts to use and the contents of the slots that changed, coalesced into
//! runs so that each run is one `write_buffer`. Built where the runtime lives (the
//! simplification thread, in asynchronous mode) and applied where the device lives
//! ([`crate::GpuCut::apply`]).
//!
//! GPU memory follows the cut, not the model: a [`VertexPool`] gives a GPU vertex only to the
//! nodes that are corners of active triangles (reference-counted, freed vertices reused), and
//! slots hold vertex indices. A model of a hundred million triangles then needs vertex buffers
//! the size of its cut, within the storage-binding limits of ordinary adapters (llvmpipe binds
//! 128 MiB: 8 M vertices), where buffers indexed by node id would need gigabytes.

use std::ops::Range;

use vds_runtime::{Changes, Cut};

/// One vertex as the shaders read it (a node's proxy and what the shading needs of the
/// node): `vec4(proxy, error radius)`,
/// `vec2<u32>(depth, octahedral normal)` and `vec4(sphere centre, radius)` (mirrors `nodes`,
/// `node_attrs` and `node_spheres` in `cut.wgsl`).
#[derive(Debug, Clone, Copy, PartialEq, bytemuck::Pod, bytemuck::Zeroable)]
#[repr(C)]
pub struct GpuNode {
    /// Proxy position and error radius.
    pub position_error: [f32; 4],
    /// Depth below the root, and the node's normal (its cone axis) as two snorm16.
    pub attrs: [u32; 2],
    /// The sphere holding every triangle that touches the node (for culling).
    pub sphere: [f32; 4],
}

const _: () = assert!(size_of::<GpuNode>() == 40);

impl GpuNode {
    /// The vertex record of a node.
    pub fn of(node: &vds_runtime::Node) -> GpuNode {
        GpuNode {
            position_error: [
                node.proxy[0],
                node.proxy[1],
                node.proxy[2],
                node.error_radius,
            ],
            attrs: [u32::from(node.depth), octahedral(node.cone_axis)],
            // Files store no bounds for leaves (they never unfold), so a leaf is never culled.
            sphere: if node.is_leaf() {
                [node.proxy[0], node.proxy[1], node.proxy[2], f32::MAX]
            } else {
                [
                    node.sphere_center[0],
                    node.sphere_center[1],
                    node.sphere_center[2],
                    node.sphere_radius,
                ]
            },
        }
    }
}

/// A free slot: the shader turns it into a zero-area triangle.
pub const EMPTY_SLOT: [u32; 4] = [u32::MAX; 4];

/// One batch of GPU updates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CutUpdate {
    /// Runs of vertex records: first vertex index, records.
    pub nodes: Vec<(u32, Vec<GpuNode>)>,
    /// The node each record of `nodes` holds (`u32::MAX` for a free vertex), run for run:
    /// not uploaded; it lets a checker map slot contents back to the cut's nodes.
    pub vertex_nodes: Vec<Vec<u32>>,
    /// Runs of slot contents (`[vertex, vertex, vertex, part]`): first slot, contents.
    pub slots: Vec<(u32, Vec<[u32; 4]>)>,
    /// The number of slots to draw after this update.
    pub slot_count: u32,
    /// Vertex indices in use are below this after the update (the GPU's vertex buffers must
    /// hold this many).
    pub vertex_count: u32,
    /// The deepest node depth seen (for the depth colouring).
    pub max_depth: u32,
    /// For a rank-tracked cut ([`crate::RankMirror`]): runs of the rank map's block words,
    /// first block and words; slots then hold leaf ranks, not vertices.
    pub rank_blocks: Vec<(u32, Vec<u32>)>,
    /// Runs of the rank map's divided blocks' words: first word, words.
    pub rank_words: Vec<(u32, Vec<u32>)>,
    /// Blocks of the rank map (0: slots hold vertices).
    pub rank_block_count: u32,
    /// Words of divided blocks the rank map holds after this update.
    pub rank_word_count: u32,
}

impl CutUpdate {
    /// Bytes this update writes to the GPU.
    pub fn bytes(&self) -> u64 {
        let nodes: usize = self.nodes.iter().map(|(_, n)| n.len()).sum();
        let slots: usize = self.slots.iter().map(|(_, s)| s.len()).sum();
        let words: usize = (self.rank_blocks.iter())
            .chain(&self.rank_words)
            .map(|(_, w)| w.len())
            .sum();
        (nodes * size_of::<GpuNode>() + slots * 16 + words * 4) as u64
    }

    /// Merges `later` into this update (for a queue of batches applied together): later node
    /// records and slot contents win.
    pub fn merge(&mut self, later: CutUpdate) {
        self.nodes.extend(later.nodes);
        self.vertex_nodes.extend(later.vertex_nodes);
        self.slots.extend(later.slots);
        self.rank_blocks.extend(later.rank_blocks);
        self.rank_words.extend(later.rank_words);
        self.rank_block_count = later.rank_block_count;
        self.rank_word_count = self.rank_word_count.max(later.rank_word_count);
        self.slot_count = later.slot_count;
        self.vertex_count = self.vertex_count.max(later.vertex_count);
        self.max_depth = self.max_depth.max(later.max_depth);
    }

    /// The update that draws an ordinary indexed mesh through the same shaders: vertices as
    /// nodes (depth 0, no error), triangles as slots. This is the brute-force reference.
    pub fn whole_mesh(positions: &[[f32; 3]], triangles: &[[u32; 3]], parts: &[u32]) -> CutUpdate {
        let nodes = positions
            .iter()
            .map(|p| GpuNode {
                position_error: [p[0], p[1], p[2], 0.0],
                attrs: [0, 0],
                // Never culled: a plain mesh draws everything.
                sphere: [p[0], p[1], p[2], f32::MAX],
            })
            .collect();
        let slots = triangles
            .iter()
            .zip(parts)
            .map(|(t, &part)| [t[0], t[1], t[2], part])
            .collect();
        CutUpdate {
            nodes: vec![(0, nodes)],
            vertex_nodes: vec![(0..positions.len() as u32).collect()],
            slots: vec![(0, slots)],
            slot_count: triangles.len() as u32,
            vertex_count: positions.len() as u32,
            ..CutUpdate::default()
        }
    }
}

/// No vertex (a node without one, or a corner of an empty slot).
const NO_VERTEX: u32 = u32::MAX;

/// Runs are joined across gaps of up to this many entries: one larger write is cheaper than
/// several tiny ones.
const JOIN_GAP: u32 = 8;

/// The CPU side of a GPU mirror: which nodes have a GPU vertex, how many slot corners use
/// each, and which vertices each slot uses. Owned next to the runtime; each
/// [`VertexPool::collect`] turns the runtime's changes into one [`CutUpdate`].
#[derive(Debug, Clone, Default)]
pub struct VertexPool {
    /// The vertex of each node that has one (the current mesh's vertices, not the model's).
    vertex_of: rustc_hash::FxHashMap<u32, u32>,
    /// Per vertex: the node it holds.
    node_of: Vec<u32>,
    /// Per vertex: slot corners using it (0: free).
    uses: Vec<u32>,
    /// Free vertices, reused last-freed first.
    free: Vec<u32>,
    /// Per slot: the vertices its contents use.
    slot_vertices: Vec<[u32; 3]>,
    /// Vertices given out or refilled during the current collect.
    fresh: Vec<u32>,
}

impl VertexPool {
    /// An empty pool (for a new GPU mirror).
    pub fn new() -> VertexPool {
        VertexPool::default()
    }

    /// Vertices in use.
    pub fn vertices_in_use(&self) -> usize {
        self.node_of.len() - self.free.len()
    }

    /// The update that brings a GPU mirror up to date after an adjust: records of the nodes
    /// that became corners of active triangles, and the dirty slots of `changes`.
    ///
    /// # Panics
    /// If `cut` tracks corners by ranks ([`vds_runtime::CornerTracking::Ranks`]): it has no
    /// slots to mirror.
    pub fn collect(&mut self, cut: &mut Cut, changes: &Changes) -> CutUpdate {
        assert_mirrors_slots(cut);
        // Pages loaded are of no concern here: vertices go up when a slot first uses them.
        cut.store_mut().take_loaded();
        self.update(cut, &changes.dirty_slots)
    }

    /// The update that uploads the whole current cut to a new GPU mirror: this pool starts
    /// over, and every slot is written.
    ///
    /// # Panics
    /// As [`VertexPool::collect`].
    pub fn everything(&mut self, cut: &mut Cut) -> CutUpdate {
        assert_mirrors_slots(cut);
        *self = VertexPool::new();
        cut.store_mut().take_loaded();
        let all: Vec<u32> = (0..cut.slot_count()).collect();
        self.update(cut, &all)
    }

    fn update(&mut self, cut: &mut Cut, dirty: &[u32]) -> CutUpdate {
        let slot_count = cut.slot_count() as usize;
        if self.slot_vertices.len() < slot_count {
            self.slot_vertices.resize(slot_count, [NO_VERTEX; 3]);
        }
        self.fresh.clear();
        // New contents take their vertices before the old contents let theirs go, so a
        // corner that stays keeps its vertex.
        for &slot in dirty {
            let now = match cut.slot(slot) {
                Some(t) => t.corners.map(|node| self.acquire(node)),
                None => [NO_VERTEX; 3],
            };
            let before = std::mem::replace(&mut self.slot_vertices[slot as usize], now);
            for v in before {
                self.release(v);
            }
        }
        // Slots past the end, where the cut compacted its slot array, are no longer drawn:
        // their vertices go.
        for before in self
            .slot_vertices
            .split_off(slot_count.min(self.slot_vertices.len()))
        {
            for v in before {
                self.release(v);
            }
        }
        let mut update = CutUpdate {
            slot_count: cut.slot_count(),
            ..Default::default()
        };
        self.push_vertices(cut, &mut update);
        self.push_slots(cut, dirty, &mut update);
        update.vertex_count = self.node_of.len() as u32;
        update
    }

    fn acquire(&mut self, node: u32) -> u32 {
        if let Some(&existing) = self.vertex_of.get(&node) {
            self.uses[existing as usize] += 1;
            return existing;
        }
        let v = match self.free.pop() {
            Some(v) => v,
            None => {
                self.node_of.push(NO_VERTEX);
                self.uses.push(0);
                self.node_of.len() as u32 - 1
            }
        };
        self.vertex_of.insert(node, v);
        self.node_of[v as usize] = node;
        self.uses[v as usize] = 1;
        self.fresh.push(v);
        v
    }

    fn release(&mut self, v: u32) {
        if v == NO_VERTEX {
            return;
        }
        let uses = &mut self.uses[v as usize];
        *uses -= 1;
        if *uses == 0 {
            self.vertex_of.remove(&self.node_of[v as usize]);
            self.node_of[v as usize] = NO_VERTEX;
            self.free.push(v);
        }
    }

    /// Records of the vertices given out this time and still in use, in joined runs.
    fn push_vertices(&mut self, cut: &Cut, update: &mut CutUpdate) {
        let mut fresh = std::mem::take(&mut self.fresh);
        fresh.retain(|&v| self.uses[v as usize] > 0);
        fresh.sort_unstable();
        fresh.dedup();
        let store = cut.store();
        for run in runs(&fresh) {
            let (start, len) = (run.start, run.end - run.start);
            let records = run
                .map(|v| match self.node_of[v as usize] {
                    NO_VERTEX => bytemuck::Zeroable::zeroed(),
                    node => {
                        let record = GpuNode::of(&store.node(node));
                        update.max_depth = update.max_depth.max(record.attrs[0]);
                        record
                    }
                })
                .collect::<Vec<_>>();
            update.nodes.push((start, records));
            update.vertex_nodes.push(
                (start..start + len)
                    .map(|v| self.node_of[v as usize])
                    .collect(),
            );
        }
        self.fresh = fresh;
    }

    /// Slot runs: the dirty slots, sorted, joined across small gaps.
    fn push_slots(&self, cut: &mut Cut, dirty: &[u32], update: &mut CutUpdate) {
        let mut sorted = dirty.to_vec();
        sorted.sort_unstable();
        sorted.dedup();
        for run in runs(&sorted) {
            let start = run.start;
            let contents = run
                .map(|slot| match cut.slot(slot) {
                    Some(t) => {
                        let [a, b, c] = self.slot_vertices[slot as usize];
                        [a, b, c, cut.store().triangle_part(t.triangle)]
                    }
                    None => EMPTY_SLOT,
                })
                .collect();
            update.slots.push((start, contents));
        }
    }
}

/// Sorted, distinct indices as ranges, joined where the gap between them is at most
/// [`JOIN_GAP`].
pub(crate) fn runs(sorted: &[u32]) -> impl Iterator<Item = Range<u32>> + '_ {
    let mut k = 0;
    std::iter::from_fn(move || {
        let &start = sorted.get(k)?;
        let mut end = start + 1;
        k += 1;
        while k < sorted.len() && sorted[k] <= end + JOIN_GAP {
            end = sorted[k] + 1;
            k += 1;
        }
        Some(start..end)
    })
}

/// A unit vector as two snorm16 in one `u32` (octahedral mapping; Cigolle et al. 2014).
fn octahedral(n: [f32; 3]) -> u32 {
    let l1 = n[0].abs() + n[1].abs() + n[2].abs();
    if l1 == 0.0 || !l1.is_finite() {
        return 0;
    }
    let (mut x, mut y) = (n[0] / l1, n[1] / l1);
    if n[2] < 0.0 {
        (x, y) = ((1.0 - y.abs()) * x.signum(), (1.0 - x.abs()) * y.signum());
    }
    let pack = |v: f32| ((v.clamp(-1.0, 1.0) * 32767.0).round() as i16) as u16 as u32;
    pack(x) | pack(y) << 16
}

/// The pool mirrors slots; a rank-tracked cut has none (its changes come per node).
fn assert_mirrors_slots(cut: &Cut) {
    assert!(
        cut.tracking() != vds_runtime::CornerTracking::Ranks,
        "the renderer mirrors slots: a cut with rank tracking has none to draw"
    );
}
