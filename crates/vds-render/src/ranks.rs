//! The CPU side of drawing a rank-tracked cut ([`vds_runtime::CornerTracking::Ranks`]), which
//! reports its changes per node and keeps no per-triangle state.
//!
//! The GPU holds three things, each edited by what the cut reports:
//! - **Vertices**: one record per boundary node (a node joining the boundary gets a vertex, one
//!   leaving gives it back).
//! - **A rank → vertex map**: the current vertex of every original vertex (leaf rank), in
//!   blocks of [`RANK_BLOCK`] ranks. A block covered by one boundary node is one word (the
//!   vertex, marked [`UNIFORM`]); a block the boundary divides points to [`RANK_BLOCK`] words
//!   of its own. A node joining the boundary fills its rank range: whole blocks become
//!   uniform (their words freed), partial ones are written. Words are held where the cut is
//!   finer than a block, not for the whole model.
//! - **Slots**: each active node's subtris as one run of slots holding their *original*
//!   corners as leaf ranks and their part, written once when the node unfolds and cleared
//!   when it folds; the shader maps each rank to its current vertex. A repeat the cut hides
//!   has its slot cleared, and written again when shown. A folded node's run goes to a free
//!   list by its length, for the next unfold of a node with as many subtris; when fewer
//!   than half the slots are in runs (and there are more than 4096), the runs are packed to
//!   the front and the array cut short (every live slot is written again then: the cost of
//!   that is at most the slots freed since the last packing, so it stays proportional to the
//!   changes).
//!
//! Work per frame follows the nodes that change: a vertex, a range fill and a run of slots per
//! node, never a pass over the active triangles.

use rustc_hash::FxHashMap;
use vds_runtime::{Changes, Cut};

use crate::update::{CutUpdate, EMPTY_SLOT, GpuNode, runs};

/// Ranks per block of the rank map (a power of two).
pub const RANK_BLOCK: u32 = 256;
const RANK_BLOCK_SHIFT: u32 = RANK_BLOCK.trailing_zeros();
/// Marks a block word that is a vertex for the whole block rather than the index of its own
/// words.
pub const UNIFORM: u32 = 1 << 31;

/// No vertex.
const NO_VERTEX: u32 = u32::MAX;

/// Where an active node's subtris lie in the slot array.
#[derive(Debug, Clone, Copy)]
struct Run {
    start: u32,
    count: u32,
    subtri_begin: u32,
}

/// Slot arrays shorter than this are never packed.
const SMALLEST_PACKED: usize = 4096;

/// The CPU side of a GPU mirror of a rank-tracked cut (see the module documentation). Each
/// [`RankMirror::collect`] turns one frame's [`Changes`] into a [`CutUpdate`].
#[derive(Debug, Default)]
pub struct RankMirror {
    vertex_of: FxHashMap<u32, u32>,
    /// Per vertex: its node, or [`NO_VERTEX`] when free.
    node_of: Vec<u32>,
    free_vertices: Vec<u32>,
    /// Vertices whose records must be written.
    fresh: Vec<u32>,
    /// Per block of ranks: `UNIFORM | vertex`, or the index of its own words in `words`.
    blocks: Vec<u32>,
    /// The words of blocks the boundary divides, [`RANK_BLOCK`] per block.
    words: Vec<u32>,
    free_words: Vec<u32>,
    dirty_blocks: Vec<u32>,
    dirty_words: Vec<u32>,
    runs: FxHashMap<u32, Run>,
    /// Free runs' starts by length.
    free_runs: FxHashMap<u32, Vec<u32>>,
    /// Slots in runs.
    live_slots: usize,
    /// What each slot holds (ranks and part, or [`EMPTY_SLOT`]).
    slots: Vec<[u32; 4]>,
    dirty_slots: Vec<u32>,
    max_depth: u32,
    /// Leaf ranks of the model: the last block may be shorter than [`RANK_BLOCK`].
    vertex_count: u32,
}

impl RankMirror {
    /// An empty mirror: the cut of a new runtime is its root alone, on the boundary; call
    /// [`RankMirror::collect`] with [`RankMirror::first_changes`] first.
    pub fn new() -> RankMirror {
        RankMirror::default()
    }

    /// The changes that bring an empty mirror to a new runtime's cut (the root on the
    /// boundary): a runtime reports changes from there on.
    pub fn first_changes() -> Changes {
        Changes {
            joined_boundary: vec![0],
            ..Changes::default()
        }
    }

    /// Starts this mirror over with the whole of `cut` as it is: the cut's pending changes are
    /// taken (and dropped: the update holds everything), so that the next
    /// [`RankMirror::collect`] continues from here.
    pub fn everything(&mut self, cut: &mut Cut) -> CutUpdate {
        *self = RankMirror::new();
        cut.take_changes();
        let mut unfolded: Vec<u32> = cut.active_entries().iter().map(|e| e.id).collect();
        unfolded.sort_unstable();
        let changes = Changes {
            joined_boundary: cut.boundary(),
            unfolded,
            hidden: cut.hidden_repeats(),
            ..Changes::default()
        };
        self.collect(cut, &changes)
    }

    /// Vertices in use.
    pub fn vertices_in_use(&self) -> usize {
        self.node_of.len() - self.free_vertices.len()
    }

    /// The update that brings the GPU up to date with `changes`, the changes of `cut` since
    /// the last call.
    ///
    /// # Panics
    /// If `cut` does not track corners by ranks.
    pub fn collect(&mut self, cut: &mut Cut, changes: &Changes) -> CutUpdate {
        assert_eq!(
            cut.tracking(),
            vds_runtime::CornerTracking::Ranks,
            "a rank mirror draws rank-tracked cuts"
        );
        cut.store_mut().take_loaded();
        let store = cut.store();
        if self.blocks.is_empty() {
            let blocks = store.vertex_count().div_ceil(RANK_BLOCK).max(1);
            self.blocks = vec![UNIFORM | NO_VERTEX; blocks as usize];
            self.vertex_count = store.vertex_count();
        }
        for &id in &changes.folded {
            let Some(run) = self.runs.remove(&id) else {
                continue;
            };
            for slot in run.start..run.start + run.count {
                self.slots[slot as usize] = EMPTY_SLOT;
                self.dirty_slots.push(slot);
            }
            self.free_runs.entry(run.count).or_default().push(run.start);
            self.live_slots -= run.count as usize;
        }
        for &id in &changes.left_boundary {
            if let Some(v) = self.vertex_of.remove(&id) {
                self.node_of[v as usize] = NO_VERTEX;
                self.free_vertices.push(v);
            }
        }
        for &id in &changes.joined_boundary {
            let v = match self.free_vertices.pop() {
                Some(v) => v,
                None => {
                    self.node_of.push(NO_VERTEX);
                    self.node_of.len() as u32 - 1
                }
            };
            self.node_of[v as usize] = id;
            self.vertex_of.insert(id, v);
            self.fresh.push(v);
            let node = store.node(id);
            self.fill(node.leaf_begin, node.leaf_end, v);
        }
        for &id in &changes.unfolded {
            let node = store.node(id);
            if node.subtri_count == 0 {
                continue;
            }
            let count = node.subtri_count;
            let reused = match self.free_runs.entry(count) {
                std::collections::hash_map::Entry::Occupied(mut free) => {
                    let start = free.get_mut().pop();
                    if free.get().is_empty() {
                        // No key stays behind for a length no longer free.
                        free.remove();
                    }
                    start
                }
                std::collections::hash_map::Entry::Vacant(_) => None,
            };
            let start = match reused {
                Some(start) => start,
                None => {
                    let start = self.slots.len() as u32;
                    self.slots
                        .resize(self.slots.len() + count as usize, EMPTY_SLOT);
                    start
                }
            };
            self.live_slots += count as usize;
            for (k, t) in (node.subtri_begin..node.subtri_begin + node.subtri_count).enumerate() {
                let [a, b, c] = store.triangle_corners(t);
                let slot = start + k as u32;
                self.slots[slot as usize] = [a, b, c, store.triangle_part(t)];
                self.dirty_slots.push(slot);
            }
            self.runs.insert(
                id,
                Run {
                    start,
                    count,
                    subtri_begin: node.subtri_begin,
                },
            );
        }
        for &(t, owner) in &changes.hidden {
            let slot = self.slot_of(t, owner);
            self.slots[slot as usize] = EMPTY_SLOT;
            self.dirty_slots.push(slot);
        }
        for &(t, owner) in &changes.shown {
            let slot = self.slot_of(t, owner);
            let [a, b, c] = store.triangle_corners(t);
            self.slots[slot as usize] = [a, b, c, store.triangle_part(t)];
            self.dirty_slots.push(slot);
        }
        if self.slots.len() > SMALLEST_PACKED && 2 * self.live_slots < self.slots.len() {
            self.pack();
        }
        self.take_update(cut)
    }

    /// Moves every run to the front of the slot array, in the order they lie, and cuts the
    /// array short: every live slot is written again.
    fn pack(&mut self) {
        let mut order: Vec<(u32, u32)> = self.runs.iter().map(|(&n, r)| (r.start, n)).collect();
        order.sort_unstable();
        let mut packed = Vec::with_capacity(self.live_slots);
        for (_, node) in order {
            let run = self.runs.get_mut(&node).expect("listed above");
            let from = run.start as usize..(run.start + run.count) as usize;
            run.start = packed.len() as u32;
            packed.extend_from_slice(&self.slots[from]);
        }
        self.slots = packed;
        self.free_runs.clear();
        self.dirty_slots.clear();
        self.dirty_slots.extend(0..self.slots.len() as u32);
    }

    /// The slot of active triangle `t`, a subtri of `owner`.
    fn slot_of(&self, t: u32, owner: u32) -> u32 {
        let run = self.runs[&owner];
        run.start + (t - run.subtri_begin)
    }

    /// Maps every rank in `begin..end` to vertex `v`.
    fn fill(&mut self, begin: u32, end: u32, v: u32) {
        let mut rank = begin;
        while rank < end {
            let block = rank >> RANK_BLOCK_SHIFT;
            let block_start = block << RANK_BLOCK_SHIFT;
            // The last block ends with the model's ranks.
            let block_end = (block_start + RANK_BLOCK).min(self.vertex_count);
            let word = self.blocks[block as usize];
            if rank == block_start && end >= block_end {
                if word & UNIFORM == 0 {
                    self.free_words.push(word);
                }
                self.blocks[block as usize] = UNIFORM | v;
                self.dirty_blocks.push(block);
                rank = block_end;
                continue;
            }
            let own = if word & UNIFORM != 0 {
                // The block is divided from now on: it gets words of its own, holding the
                // vertex it had until the fill below.
                let own = match self.free_words.pop() {
                    Some(own) => own,
                    None => {
                        let own = (self.words.len() as u32) >> RANK_BLOCK_SHIFT;
                        self.words.resize(self.words.len() + RANK_BLOCK as usize, 0);
                        own
                    }
                };
                let first = (own << RANK_BLOCK_SHIFT) as usize;
                self.words[first..first + RANK_BLOCK as usize].fill(word & !UNIFORM);
                self.dirty_words
                    .extend(first as u32..first as u32 + RANK_BLOCK);
                self.blocks[block as usize] = own;
                self.dirty_blocks.push(block);
                own
            } else {
                word
            };
            let stop = end.min(block_end);
            let first = (own << RANK_BLOCK_SHIFT) + (rank - block_start);
            let last = first + (stop - rank);
            self.words[first as usize..last as usize].fill(v);
            self.dirty_words.extend(first..last);
            rank = stop;
        }
    }

    /// Gathers the dirty records into runs.
    fn take_update(&mut self, cut: &Cut) -> CutUpdate {
        let store = cut.store();
        let mut update = CutUpdate {
            slot_count: self.slots.len() as u32,
            vertex_count: self.node_of.len() as u32,
            rank_block_count: self.blocks.len() as u32,
            rank_word_count: self.words.len() as u32,
            ..CutUpdate::default()
        };
        let mut fresh = std::mem::take(&mut self.fresh);
        fresh.retain(|&v| self.node_of[v as usize] != NO_VERTEX);
        fresh.sort_unstable();
        fresh.dedup();
        for run in runs(&fresh) {
            let nodes: Vec<u32> = run.clone().map(|v| self.node_of[v as usize]).collect();
            let records = nodes
                .iter()
                .map(|&node| match node {
                    NO_VERTEX => bytemuck::Zeroable::zeroed(),
                    node => {
                        let record = GpuNode::of(&store.node(node));
                        self.max_depth = self.max_depth.max(record.attrs[0]);
                        record
                    }
                })
                .collect();
            update.nodes.push((run.start, records));
            update.vertex_nodes.push(nodes);
        }
        fresh.clear();
        self.fresh = fresh;
        update.max_depth = self.max_depth;
        for (dirty, from, out) in [
            (
                &mut self.dirty_blocks,
                &self.blocks,
                &mut update.rank_blocks,
            ),
            (&mut self.dirty_words, &self.words, &mut update.rank_words),
        ] {
            dirty.sort_unstable();
            dirty.dedup();
            for run in runs(dirty) {
                out.push((
                    run.start,
                    from[run.start as usize..run.end as usize].to_vec(),
                ));
            }
            dirty.clear();
        }
        self.dirty_slots.sort_unstable();
        self.dirty_slots.dedup();
        for run in runs(&self.dirty_slots) {
            update.slots.push((
                run.start,
                self.slots[run.start as usize..run.end as usize].to_vec(),
            ));
        }
        self.dirty_slots.clear();
        update
    }
}

/// The vertex a rank-tracked mirror's GPU reads for leaf rank `rank` (what `cut.wgsl` does).
pub fn vertex_of_rank(blocks: &[u32], words: &[u32], rank: u32) -> u32 {
    let word = blocks[(rank >> RANK_BLOCK_SHIFT) as usize];
    if word & UNIFORM != 0 {
        word & !UNIFORM
    } else {
        words[((word << RANK_BLOCK_SHIFT) + (rank & (RANK_BLOCK - 1))) as usize]
    }
}
