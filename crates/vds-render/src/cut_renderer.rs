//! The GPU mirror of a cut and the pipeline that draws it.
//!
//! Eight bindings (see `shaders/cut.wgsl`): per-frame uniforms, vertex records (`vec4` proxy
//! and error radius, `vec2<u32>` depth and normal, `vec4` sphere) indexed by the vertex
//! indices a [`crate::update::VertexPool`] or [`crate::RankMirror`] hands out, the slot
//! array, the per-part looks ([`PartLook`]: colour, hidden, picked), and for a rank-tracked
//! cut the rank → vertex map's blocks (after a header word holding their count, 0 when
//! slots hold vertices) and divided blocks' words. Updates write only
//! the runs a [`CutUpdate`] carries; the vertex buffers and the slot array grow by
//! reallocation (the old contents copied on the GPU), and the slot array is split into chunks
//! no larger than the adapter can bind.

use bytemuck::{Pod, Zeroable};
use glam::{Mat4, Vec3, Vec4};
use vds_runtime::Camera;

use crate::update::{CutUpdate, GpuNode};
use crate::{Gpu, RenderError};

/// How triangles are coloured.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Colouring {
    /// One pastel colour per part.
    Parts,
    /// Blue (root) to red (deepest) by the depth of the triangle's deepest corner node.
    Depth,
    /// Blue to red by screen-space error, red at twice the threshold.
    Error,
    /// The colour the file gives each part ([`PartLook::colour`]), the part palette for parts
    /// without one.
    #[default]
    File,
}

/// The most section planes a frame clips by.
pub const MAX_SECTIONS: usize = 3;

/// A section (clipping) plane: everything where `normal · x + offset > 0` is cut away, the
/// side the normal points to.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct SectionPlane {
    /// The plane's normal (any length; the test only needs its sign).
    pub normal: [f32; 3],
    /// The plane's offset: the plane is `normal · x + offset = 0`.
    pub offset: f32,
}

/// How one part is drawn, beyond the frame's [`Style`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct PartLook {
    /// Linear RGB in `0.0..=1.0`, shown by [`Colouring::File`]; none: the palette colour.
    pub colour: Option<[f32; 3]>,
    /// Not drawn at any level of detail.
    pub hidden: bool,
    /// Highlighted (the picked part).
    pub picked: bool,
}

impl PartLook {
    /// The shader's record (`parts` in `cut.wgsl`): linear RGBA8 with alpha 255 when the
    /// colour is given, and the flags (1 hidden, 2 picked).
    fn packed(&self) -> [u32; 2] {
        let colour = self.colour.map_or(0, |c| {
            let byte = |v: f32| (v.clamp(0.0, 1.0) * 255.0).round() as u32;
            byte(c[0]) | byte(c[1]) << 8 | byte(c[2]) << 16 | 0xFF << 24
        });
        [colour, u32::from(self.hidden) | u32::from(self.picked) << 1]
    }
}

/// How triangles are shaded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Shading {
    /// One normal per triangle.
    #[default]
    Faceted,
    /// Normals interpolated from the nodes' normal-cone axes.
    Smooth,
}

/// Everything about a frame's look.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Style {
    /// Colouring mode.
    pub colouring: Colouring,
    /// Shading mode.
    pub shading: Shading,
    /// Draw triangle edges on top.
    pub wireframe: bool,
    /// The pixel threshold (for the error colouring).
    pub threshold_px: f32,
    /// Skip triangles with a corner node entirely outside the view frustum: at full detail
    /// such a triangle is invisible, and its coarse stand-in (stretched to the proxy of a
    /// region folded for being off-screen) would only draw a sliver across the view.
    pub cull_outside: bool,
    /// Section planes (at most [`MAX_SECTIONS`] apply): what lies on their positive side is
    /// not drawn, and the inside of a cut solid shows as a flat cap colour.
    pub sections: [Option<SectionPlane>; MAX_SECTIONS],
}

/// Mirrors `Frame` in `cut.wgsl` (256 bytes).
#[derive(Debug, Clone, Copy, Pod, Zeroable)]
#[repr(C)]
struct FrameUniforms {
    world_to_clip: [[f32; 4]; 4],
    eye: [f32; 4],
    light: [f32; 4],
    threshold_px: f32,
    colouring: u32,
    shading: u32,
    wireframe: u32,
    max_depth: f32,
    cull_outside: u32,
    part_count: u32,
    section_count: u32,
    /// Outward frustum planes (near, right, left, top, bottom): `dot(n, x) + d` is the
    /// signed distance of `x` outside.
    planes: [[f32; 4]; 5],
    /// Section planes in use, first `section_count`: `dot(n, x) + d > 0` is cut away.
    sections: [[f32; 4]; MAX_SECTIONS],
}

const _: () = assert!(size_of::<FrameUniforms>() == 256);

/// The format of the picking target: part id plus one, and the world position's bits.
pub const PICK_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba32Uint;

/// The colour format of every target the pipeline draws to.
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// The depth format (reversed Z: near is 1, far is 0).
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;

/// The camera as a matrix to wgpu clip space, exactly matching the runtime's projection
/// (`vds_runtime::View::project`): same focal length in pixels, and reversed depth with an
/// infinite far plane (`z_ndc = near / depth`).
pub fn world_to_clip(camera: &Camera) -> Mat4 {
    let view = camera.view();
    let (w, h) = (view.width as f32, view.height as f32);
    let sx = 2.0 * view.focal_px / w;
    let sy = 2.0 * view.focal_px / h;
    let row =
        |axis: Vec3, scale: f32| Vec4::new(axis.x, axis.y, axis.z, -axis.dot(view.eye)) * scale;
    let rows = [
        row(view.right, sx),
        row(view.up, sy),
        Vec4::new(0.0, 0.0, 0.0, view.near.max(1e-12)),
        row(view.forward, 1.0),
    ];
    Mat4::from_cols_array_2d(&[
        rows[0].into(),
        rows[1].into(),
        rows[2].into(),
        rows[3].into(),
    ])
    .transpose()
}

/// The frustum's outward planes in world space, as `View::sphere_outside` tests them.
fn frustum_planes(camera: &Camera) -> [[f32; 4]; 5] {
    let view = camera.view();
    let plane = |n: Vec3| {
        let n = n.normalize();
        [n.x, n.y, n.z, -n.dot(view.eye)]
    };
    let near = -view.forward;
    [
        [
            near.x,
            near.y,
            near.z,
            view.forward.dot(view.eye) + view.near,
        ],
        plane(view.right - view.forward * view.tan_x),
        plane(-view.right - view.forward * view.tan_x),
        plane(view.up - view.forward * view.tan_y),
        plane(-view.up - view.forward * view.tan_y),
    ]
}

/// The render pipelines (the picture, and the picking pass into [`PICK_FORMAT`]) and their
/// bind group layout (created once).
pub struct CutPipeline {
    pipeline: wgpu::RenderPipeline,
    pick: wgpu::RenderPipeline,
    layout: wgpu::BindGroupLayout,
}

impl CutPipeline {
    /// Compiles `cut.wgsl` and builds the pipeline for [`COLOR_FORMAT`] or `format`.
    pub fn new(gpu: &Gpu, format: wgpu::TextureFormat) -> CutPipeline {
        let device = &gpu.device;
        let shader = device.create_shader_module(wgpu::include_wgsl!("shaders/cut.wgsl"));
        let storage = |binding| wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::VERTEX,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: true },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        };
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("cut bind group layout"),
            entries: &[
                wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Uniform,
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                },
                storage(1),
                storage(2),
                storage(3),
                storage(4),
                storage(5),
                storage(6),
                storage(7),
            ],
        });
        let pipeline_layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("cut pipeline layout"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let pipeline = |label, fragment, format| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&pipeline_layout),
                vertex: wgpu::VertexState {
                    module: &shader,
                    entry_point: Some("vs_main"),
                    compilation_options: Default::default(),
                    buffers: &[],
                },
                primitive: wgpu::PrimitiveState {
                    topology: wgpu::PrimitiveTopology::TriangleList,
                    // CAD soup has no consistent winding: draw both sides.
                    cull_mode: None,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(true),
                    depth_compare: Some(wgpu::CompareFunction::Greater),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: Default::default(),
                fragment: Some(wgpu::FragmentState {
                    module: &shader,
                    entry_point: Some(fragment),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format,
                        blend: None,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        CutPipeline {
            pipeline: pipeline("cut pipeline", "fs_main", format),
            pick: pipeline("pick pipeline", "fs_pick", PICK_FORMAT),
            layout,
        }
    }
}

/// One chunk of the slot array: adapters bind at most `max_storage_buffer_binding_size`
/// bytes per buffer (128 MiB on llvmpipe: 8 M slots), so large cuts span several chunks, each
/// with its own buffer, bind group and draw call.
struct SlotChunk {
    buffer: wgpu::Buffer,
    capacity: u32,
    bind_group: wgpu::BindGroup,
}

/// Vertices a new mirror holds before its first growth.
const INITIAL_VERTICES: u32 = 1 << 12;

/// The three vertex buffers, in binding order: label and bytes per vertex (positions and
/// error radii, depth and normal, spheres).
const VERTEX_BUFFERS: [(&str, u64); 3] = [("nodes", 16), ("node attrs", 8), ("node spheres", 16)];

/// The three vertex buffers ([`VERTEX_BUFFERS`]) for `capacity` vertices.
fn vertex_buffers(gpu: &Gpu, capacity: u32) -> [wgpu::Buffer; 3] {
    let usage =
        wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::COPY_SRC;
    VERTEX_BUFFERS.map(|(label, bytes)| {
        gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some(label),
            size: u64::from(capacity.max(1)) * bytes,
            usage,
            mapped_at_creation: false,
        })
    })
}

/// A cut (or a brute-force mesh) on the GPU.
pub struct GpuCut {
    uniforms: wgpu::Buffer,
    /// Vertex records (`nodes`, `node_attrs`, `node_spheres` in the shader), grown by
    /// reallocation like the slots.
    nodes: wgpu::Buffer,
    node_attrs: wgpu::Buffer,
    node_spheres: wgpu::Buffer,
    vertex_capacity: u32,
    /// The most vertices one binding can hold on this adapter.
    vertex_limit: u32,
    /// Slots per full chunk.
    chunk_slots: u32,
    chunks: Vec<SlotChunk>,
    slot_count: u32,
    max_depth: u32,
    /// Per-part looks ([`PartLook::packed`]), at least one entry's room.
    parts: wgpu::Buffer,
    /// Entries of `parts` in use.
    part_count: u32,
    /// The rank → vertex map of a rank-tracked cut: a header word (the block count; 0 while
    /// slots hold vertices), then the block words; and the divided blocks' words. Each holds
    /// one word at least: bindings cannot be empty.
    rank_blocks: wgpu::Buffer,
    rank_words: wgpu::Buffer,
    rank_block_count: u32,
}

/// A buffer of `words` 32-bit words (one at least; wgpu zero-initialises it), kept on growth
/// (copied on the GPU).
fn word_buffer(gpu: &Gpu, label: &str, words: u64) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: words.max(1) * 4,
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    })
}

/// A buffer for `count` packed part looks (room for one at least: bindings cannot be empty).
fn part_buffer(gpu: &Gpu, count: u32) -> wgpu::Buffer {
    gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("part looks"),
        size: u64::from(count.max(1)) * 8,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

impl GpuCut {
    /// An empty mirror; its buffers grow as updates need.
    pub fn new(gpu: &Gpu) -> GpuCut {
        GpuCut::with_chunk_slots(gpu, u32::MAX)
    }

    /// [`GpuCut::new`] with slot chunks of at most `chunk_slots` slots (the adapter's limit
    /// applies too); small chunks exercise the chunked path in tests.
    pub fn with_chunk_slots(gpu: &Gpu, chunk_slots: u32) -> GpuCut {
        let limit = gpu.device.limits().max_storage_buffer_binding_size;
        let [nodes, node_attrs, node_spheres] = vertex_buffers(gpu, INITIAL_VERTICES);
        GpuCut {
            uniforms: gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("frame uniforms"),
                size: size_of::<FrameUniforms>() as u64,
                usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            nodes,
            node_attrs,
            node_spheres,
            vertex_capacity: INITIAL_VERTICES,
            vertex_limit: (limit / 16).min(u64::from(u32::MAX)) as u32,
            chunk_slots: (limit / 16)
                .min(u64::from(u32::MAX / 3))
                .min(u64::from(chunk_slots.max(1))) as u32,
            chunks: Vec::new(),
            slot_count: 0,
            max_depth: 0,
            parts: part_buffer(gpu, 1),
            part_count: 0,
            rank_blocks: word_buffer(gpu, "rank blocks", 1),
            rank_words: word_buffer(gpu, "rank words", 1),
            rank_block_count: 0,
        }
    }

    /// Grows a word buffer of the rank map to hold `words` (by 1.5× when the adapter binds
    /// that much, contents copied on the GPU); true when it was reallocated. `limit`: the most
    /// words one binding holds (at least `words`).
    fn reserve_words(
        gpu: &Gpu,
        buffer: &mut wgpu::Buffer,
        label: &str,
        words: u64,
        limit: u64,
    ) -> bool {
        let have = buffer.size() / 4;
        if words <= have {
            return false;
        }
        let grown = word_buffer(gpu, label, words.max(have * 3 / 2).min(limit));
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("grow rank map"),
            });
        encoder.copy_buffer_to_buffer(buffer, 0, &grown, 0, buffer.size());
        gpu.queue.submit([encoder.finish()]);
        *buffer = grown;
        true
    }

    /// Sets how each part is drawn, by part id (ids past `looks` take the default look:
    /// palette colour, shown). A larger table than the last one reallocates its buffer.
    pub fn set_parts(&mut self, gpu: &Gpu, pipeline: &CutPipeline, looks: &[PartLook]) {
        let count = u32::try_from(looks.len()).unwrap_or(u32::MAX);
        let packed: Vec<[u32; 2]> = looks.iter().map(PartLook::packed).collect();
        if u64::from(count.max(1)) * 8 > self.parts.size() {
            self.parts = part_buffer(gpu, count);
            self.rebind(gpu, pipeline);
        }
        if !packed.is_empty() {
            gpu.queue
                .write_buffer(&self.parts, 0, bytemuck::cast_slice(&packed));
        }
        self.part_count = count;
    }

    /// Remakes every slot chunk's bind group over the current buffers.
    fn rebind(&mut self, gpu: &Gpu, pipeline: &CutPipeline) {
        for k in 0..self.chunks.len() {
            let bind_group = self.bind_group(gpu, pipeline, &self.chunks[k].buffer);
            self.chunks[k].bind_group = bind_group;
        }
    }

    /// Vertices the buffers hold now.
    pub fn vertex_capacity(&self) -> u32 {
        self.vertex_capacity
    }

    /// Makes room for `needed` vertices: the three vertex buffers grow by at least 1.5×, their
    /// contents copied on the GPU, and every slot chunk's bind group is remade over them.
    fn reserve_vertices(
        &mut self,
        gpu: &Gpu,
        pipeline: &CutPipeline,
        needed: u32,
    ) -> Result<(), RenderError> {
        if needed <= self.vertex_capacity {
            return Ok(());
        }
        if needed > self.vertex_limit {
            return Err(RenderError::TooLarge(format!(
                "{needed} vertices need {} bytes of storage; the adapter binds at most {}",
                u64::from(needed) * 16,
                u64::from(self.vertex_limit) * 16
            )));
        }
        let capacity = needed
            .max(self.vertex_capacity.saturating_mul(3) / 2)
            .min(self.vertex_limit);
        let grown = vertex_buffers(gpu, capacity);
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("grow vertices"),
            });
        let old = [&self.nodes, &self.node_attrs, &self.node_spheres];
        for ((from, to), (_, bytes)) in old.into_iter().zip(&grown).zip(VERTEX_BUFFERS) {
            encoder.copy_buffer_to_buffer(from, 0, to, 0, u64::from(self.vertex_capacity) * bytes);
        }
        gpu.queue.submit([encoder.finish()]);
        [self.nodes, self.node_attrs, self.node_spheres] = grown;
        self.vertex_capacity = capacity;
        self.rebind(gpu, pipeline);
        Ok(())
    }

    fn chunk(&self, gpu: &Gpu, pipeline: &CutPipeline, capacity: u32) -> SlotChunk {
        let buffer = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("slots"),
            size: u64::from(capacity.max(1)) * 16,
            usage: wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
            mapped_at_creation: false,
        });
        let bind_group = self.bind_group(gpu, pipeline, &buffer);
        SlotChunk {
            buffer,
            capacity,
            bind_group,
        }
    }

    /// The bind group of one slot chunk over the current vertex buffers.
    fn bind_group(
        &self,
        gpu: &Gpu,
        pipeline: &CutPipeline,
        slots: &wgpu::Buffer,
    ) -> wgpu::BindGroup {
        let buffers = [
            &self.uniforms,
            &self.nodes,
            &self.node_attrs,
            slots,
            &self.node_spheres,
            &self.parts,
            &self.rank_blocks,
            &self.rank_words,
        ];
        let entries: Vec<wgpu::BindGroupEntry<'_>> = buffers
            .iter()
            .enumerate()
            .map(|(binding, buffer)| wgpu::BindGroupEntry {
                binding: binding as u32,
                resource: buffer.as_entire_binding(),
            })
            .collect();
        gpu.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("cut bind group"),
            layout: &pipeline.layout,
            entries: &entries,
        })
    }

    /// Number of slots drawn (free ones included, as empty triangles).
    pub fn slot_count(&self) -> u32 {
        self.slot_count
    }

    /// Writes `update` to the buffers and returns the bytes written (a slot-buffer
    /// reallocation copies on the GPU and is not counted).
    pub fn apply(
        &mut self,
        gpu: &Gpu,
        pipeline: &CutPipeline,
        update: &CutUpdate,
    ) -> Result<u64, RenderError> {
        self.reserve_vertices(gpu, pipeline, update.vertex_count)?;
        self.reserve(gpu, pipeline, update.slot_count);
        let mut bytes = self.apply_rank_map(gpu, pipeline, update)?;
        for (first, records) in &update.nodes {
            if u64::from(*first) + records.len() as u64 > u64::from(self.vertex_capacity) {
                return Err(RenderError::TooLarge(format!(
                    "vertex {} is beyond the update's vertex count {}",
                    u64::from(*first) + records.len() as u64 - 1,
                    update.vertex_count
                )));
            }
            let positions: Vec<[f32; 4]> = records.iter().map(|n| n.position_error).collect();
            let attrs: Vec<[u32; 2]> = records.iter().map(|n| n.attrs).collect();
            let spheres: Vec<[f32; 4]> = records.iter().map(|n| n.sphere).collect();
            gpu.queue.write_buffer(
                &self.node_spheres,
                u64::from(*first) * 16,
                bytemuck::cast_slice(&spheres),
            );
            gpu.queue.write_buffer(
                &self.nodes,
                u64::from(*first) * 16,
                bytemuck::cast_slice(&positions),
            );
            gpu.queue.write_buffer(
                &self.node_attrs,
                u64::from(*first) * 8,
                bytemuck::cast_slice(&attrs),
            );
            bytes += (records.len() * size_of::<GpuNode>()) as u64;
        }
        for (first, contents) in &update.slots {
            // A run may cross chunk boundaries: write it piece by piece.
            let mut slot = *first;
            let mut rest = &contents[..];
            while !rest.is_empty() {
                let (chunk, offset) = (slot / self.chunk_slots, slot % self.chunk_slots);
                let Some(target) = self.chunks.get(chunk as usize) else {
                    return Err(RenderError::TooLarge(format!(
                        "slot {slot} is beyond the slots of this mirror"
                    )));
                };
                let take = rest
                    .len()
                    .min((target.capacity - offset.min(target.capacity)) as usize);
                if take == 0 {
                    return Err(RenderError::TooLarge(format!(
                        "slot {slot} is beyond the slots of this mirror"
                    )));
                }
                gpu.queue.write_buffer(
                    &target.buffer,
                    u64::from(offset) * 16,
                    bytemuck::cast_slice(&rest[..take]),
                );
                bytes += (take * 16) as u64;
                slot += take as u32;
                rest = &rest[take..];
            }
        }
        self.slot_count = update.slot_count;
        self.max_depth = self.max_depth.max(update.max_depth);
        Ok(bytes)
    }

    /// Writes the rank map's runs of `update` (header word first when the block count
    /// changes); returns the bytes written.
    fn apply_rank_map(
        &mut self,
        gpu: &Gpu,
        pipeline: &CutPipeline,
        update: &CutUpdate,
    ) -> Result<u64, RenderError> {
        let limits = gpu.device.limits();
        let limit = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size)
            / 4;
        let blocks = 1 + u64::from(update.rank_block_count);
        let words = u64::from(update.rank_word_count);
        if blocks > limit || words > limit {
            return Err(RenderError::TooLarge(format!(
                "a rank map of {blocks} blocks and {words} words; the adapter binds at most \
                 {limit} words"
            )));
        }
        let grew = Self::reserve_words(gpu, &mut self.rank_blocks, "rank blocks", blocks, limit)
            | Self::reserve_words(gpu, &mut self.rank_words, "rank words", words, limit);
        if grew {
            self.rebind(gpu, pipeline);
        }
        let mut bytes = 0;
        if update.rank_block_count != self.rank_block_count {
            self.rank_block_count = update.rank_block_count;
            gpu.queue.write_buffer(
                &self.rank_blocks,
                0,
                bytemuck::bytes_of(&self.rank_block_count),
            );
            bytes += 4;
        }
        for (buffer, offset, count, runs) in [
            (&self.rank_blocks, 1, blocks, &update.rank_blocks),
            (&self.rank_words, 0, words, &update.rank_words),
        ] {
            for (first, values) in runs {
                let end = u64::from(*first) + offset + values.len() as u64;
                if end > count {
                    return Err(RenderError::TooLarge(format!(
                        "rank map word {end} is beyond the update's counts"
                    )));
                }
                gpu.queue.write_buffer(
                    buffer,
                    (u64::from(*first) + offset) * 4,
                    bytemuck::cast_slice(values),
                );
                bytes += values.len() as u64 * 4;
            }
        }
        Ok(bytes)
    }

    /// Makes room for `needed` slots: full chunks first, the last one grown by 1.5× with its
    /// contents copied on the GPU.
    fn reserve(&mut self, gpu: &Gpu, pipeline: &CutPipeline, needed: u32) {
        let have: u64 = self.chunks.iter().map(|c| u64::from(c.capacity)).sum();
        if u64::from(needed) <= have {
            return;
        }
        // Fill the last chunk up to a full one.
        if let Some(last) = self.chunks.last()
            && last.capacity < self.chunk_slots
        {
            let before: u32 = self.chunks.len() as u32 - 1;
            let wanted = needed - before * self.chunk_slots;
            let capacity = wanted
                .max(last.capacity.saturating_mul(3) / 2)
                .min(self.chunk_slots);
            let grown = self.chunk(gpu, pipeline, capacity);
            let mut encoder = gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("grow slots"),
                });
            encoder.copy_buffer_to_buffer(
                &last.buffer,
                0,
                &grown.buffer,
                0,
                u64::from(last.capacity) * 16,
            );
            gpu.queue.submit([encoder.finish()]);
            *self.chunks.last_mut().expect("checked above") = grown;
        }
        while self
            .chunks
            .iter()
            .map(|c| u64::from(c.capacity))
            .sum::<u64>()
            < u64::from(needed)
        {
            let before = self.chunks.len() as u32 * self.chunk_slots;
            let capacity = (needed - before)
                .max(1024.min(self.chunk_slots))
                .min(self.chunk_slots);
            let chunk = self.chunk(gpu, pipeline, capacity);
            self.chunks.push(chunk);
        }
    }

    /// Sets the camera and style for the next draw.
    pub fn set_frame(&self, gpu: &Gpu, camera: &Camera, style: &Style) {
        self.set_frame_window(gpu, camera, style, None);
    }

    /// [`GpuCut::set_frame`] for a target that shows only `window` (x, y, width, height in
    /// the camera's pixels, y down) of the camera's view, stretched over the whole target:
    /// the picking pass draws the pixels it reads this way, with the same rasterisation
    /// sample points as the full view.
    pub fn set_frame_window(
        &self,
        gpu: &Gpu,
        camera: &Camera,
        style: &Style,
        window: Option<[u32; 4]>,
    ) {
        let view = camera.view();
        let mut world_to_clip = world_to_clip(camera);
        if let Some([x, y, w, h]) = window {
            // Clip-space scale and shift taking the window's NDC rectangle to [-1, 1]²:
            // x' = (x − c_x·w_c)·W/w and likewise for y (NDC y points up, pixels down).
            let (full_w, full_h) = (view.width as f32, view.height as f32);
            let (w, h) = (w.max(1) as f32, h.max(1) as f32);
            let centre_x = (2.0 * x as f32 + w) / full_w - 1.0;
            let centre_y = 1.0 - (2.0 * y as f32 + h) / full_h;
            let (scale_x, scale_y) = (full_w / w, full_h / h);
            let window = Mat4::from_cols_array_2d(&[
                [scale_x, 0.0, 0.0, 0.0],
                [0.0, scale_y, 0.0, 0.0],
                [0.0, 0.0, 1.0, 0.0],
                [-centre_x * scale_x, -centre_y * scale_y, 0.0, 1.0],
            ]);
            world_to_clip = window * world_to_clip;
        }
        let mut sections = [[0.0; 4]; MAX_SECTIONS];
        let mut section_count = 0;
        for plane in style.sections.iter().flatten() {
            let [x, y, z] = plane.normal;
            sections[section_count] = [x, y, z, plane.offset];
            section_count += 1;
        }
        // Headlight from above the eye, so faces square to the view are not all equally lit.
        let light = (-view.forward + view.up * 0.35 + view.right * 0.2).normalize();
        let uniforms = FrameUniforms {
            world_to_clip: world_to_clip.to_cols_array_2d(),
            eye: [view.eye.x, view.eye.y, view.eye.z, view.focal_px],
            light: [light.x, light.y, light.z, 0.25],
            threshold_px: style.threshold_px,
            colouring: style.colouring as u32,
            shading: style.shading as u32,
            wireframe: u32::from(style.wireframe),
            max_depth: self.max_depth as f32,
            cull_outside: u32::from(style.cull_outside),
            part_count: self.part_count,
            section_count: section_count as u32,
            planes: frustum_planes(camera),
            sections,
        };
        gpu.queue
            .write_buffer(&self.uniforms, 0, bytemuck::bytes_of(&uniforms));
    }

    /// Records the draw into `pass`: one draw call per slot chunk.
    pub fn draw(&self, pass: &mut wgpu::RenderPass<'_>, pipeline: &CutPipeline) {
        self.draw_with(pass, pipeline, &pipeline.pipeline);
    }

    /// Records the picking draw (into a [`PICK_FORMAT`] target) into `pass`.
    pub fn draw_pick(&self, pass: &mut wgpu::RenderPass<'_>, pipeline: &CutPipeline) {
        self.draw_with(pass, pipeline, &pipeline.pick);
    }

    fn draw_with(
        &self,
        pass: &mut wgpu::RenderPass<'_>,
        _pipeline: &CutPipeline,
        render: &wgpu::RenderPipeline,
    ) {
        pass.set_pipeline(render);
        let mut left = self.slot_count;
        for chunk in &self.chunks {
            let count = left.min(chunk.capacity);
            if count == 0 {
                break;
            }
            pass.set_bind_group(0, &chunk.bind_group, &[]);
            pass.draw(0..count * 3, 0..1);
            left -= count;
        }
    }
}
