//! What the GPU needs to learn after an adjust, gathered on the CPU: the node records of newly
//! loaded pages and the contents of the slots that changed, coalesced into runs so that each
//! run is one `write_buffer`. Built where the runtime lives (the simplification thread, in
//! asynchronous mode) and applied where the device lives ([`crate::GpuCut::apply`]).

use std::ops::Range;

use vds_runtime::{Changes, Cut};

/// One node as the shaders read it: `vec4(proxy, error radius)`,
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

/// A free slot: the shader turns it into a zero-area triangle.
pub const EMPTY_SLOT: [u32; 4] = [u32::MAX; 4];

/// One batch of GPU updates.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CutUpdate {
    /// Runs of node records: first node id, records.
    pub nodes: Vec<(u32, Vec<GpuNode>)>,
    /// Runs of slot contents (`[corner, corner, corner, part]`): first slot, contents.
    pub slots: Vec<(u32, Vec<[u32; 4]>)>,
    /// The number of slots to draw after this update.
    pub slot_count: u32,
    /// The deepest node depth seen (for the depth colouring).
    pub max_depth: u32,
}

impl CutUpdate {
    /// Bytes this update writes to the GPU.
    pub fn bytes(&self) -> u64 {
        let nodes: usize = self.nodes.iter().map(|(_, n)| n.len()).sum();
        let slots: usize = self.slots.iter().map(|(_, s)| s.len()).sum();
        (nodes * size_of::<GpuNode>() + slots * 16) as u64
    }

    /// Merges `later` into this update (for a queue of batches applied together): later node
    /// records and slot contents win.
    pub fn merge(&mut self, later: CutUpdate) {
        self.nodes.extend(later.nodes);
        self.slots.extend(later.slots);
        self.slot_count = later.slot_count;
        self.max_depth = self.max_depth.max(later.max_depth);
    }

    /// The update that brings a GPU mirror up to date after an adjust: records of the pages
    /// loaded since the last call, and the dirty slots of `changes`.
    pub fn collect(cut: &mut Cut, changes: &Changes) -> CutUpdate {
        let mut update = CutUpdate {
            slot_count: cut.slot_count(),
            ..Default::default()
        };
        for range in cut.store_mut().take_loaded() {
            update.push_nodes(cut, range);
        }
        update.push_slots(cut, &changes.dirty_slots);
        update
    }

    /// The update that uploads the whole current cut (a new GPU mirror of an existing cut):
    /// every loaded node and every slot.
    pub fn everything(cut: &mut Cut) -> CutUpdate {
        let mut update = CutUpdate {
            slot_count: cut.slot_count(),
            ..Default::default()
        };
        cut.store_mut().take_loaded();
        update.push_nodes(cut, 0..cut.store().node_count());
        let all: Vec<u32> = (0..cut.slot_count()).collect();
        update.push_slots(cut, &all);
        update
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
            slots: vec![(0, slots)],
            slot_count: triangles.len() as u32,
            max_depth: 0,
        }
    }

    fn push_nodes(&mut self, cut: &Cut, range: Range<u32>) {
        let store = cut.store();
        let records = range
            .clone()
            .map(|id| {
                let node = store.node(id);
                self.max_depth = self.max_depth.max(u32::from(node.depth));
                GpuNode {
                    position_error: [
                        node.proxy[0],
                        node.proxy[1],
                        node.proxy[2],
                        node.error_radius,
                    ],
                    attrs: [u32::from(node.depth), octahedral(node.cone_axis)],
                    // Files store no bounds for leaves (they never unfold), so a leaf is
                    // never culled.
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
            })
            .collect();
        self.nodes.push((range.start, records));
    }

    /// Slot runs: sorted dirty slots joined when the gap between them is small, since one
    /// larger write is cheaper than several tiny ones.
    fn push_slots(&mut self, cut: &mut Cut, dirty: &[u32]) {
        const JOIN_GAP: u32 = 8;
        let mut k = 0;
        while k < dirty.len() {
            let start = dirty[k];
            let mut end = start + 1;
            k += 1;
            while k < dirty.len() && dirty[k] <= end + JOIN_GAP {
                end = dirty[k] + 1;
                k += 1;
            }
            let contents = (start..end)
                .map(|slot| match cut.slot(slot) {
                    Some(t) => {
                        let part = cut.store().triangle_part(t.triangle);
                        [t.corners[0], t.corners[1], t.corners[2], part]
                    }
                    None => EMPTY_SLOT,
                })
                .collect();
            self.slots.push((start, contents));
        }
    }
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
