//! Picking by an id buffer: the cut is drawn once more, into a small [`PICK_FORMAT`] target
//! that shows only the pixels asked about, and each pixel reads back the part id and the
//! world position of the frontmost fragment there.
//!
//! An id buffer rather than a ray cast against the cut: it answers for exactly the
//! triangles on screen at their current level of detail, under the same hiding, sections and
//! frustum culling as the picture, with no CPU copy of the cut's geometry. The window
//! transform ([`GpuCut::set_frame_window`]) keeps the full view's rasterisation sample points,
//! so a pixel's answer is the one the picture shows.

use crate::cut_renderer::{CutPipeline, DEPTH_FORMAT, GpuCut, PICK_FORMAT, Style};
use crate::target::map_read;
use crate::{Gpu, RenderError};
use vds_runtime::Camera;

/// What a pixel shows: the part and where on its surface.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// The part id of the drawn triangle (the same at every level of detail).
    pub part: u32,
    /// The world position of the pixel's centre on that triangle.
    pub world: [f32; 3],
}

/// The parts and positions that `cut` shows at the pixels of `window` (x, y, width, height
/// in the camera's pixels, y down), row by row; `None` where the background shows. Leaves the
/// frame uniforms set for `camera` and `style` again, ready for the next ordinary draw.
pub fn pick_region(
    gpu: &Gpu,
    cut: &GpuCut,
    pipeline: &CutPipeline,
    camera: &Camera,
    style: &Style,
    window: [u32; 4],
) -> Result<Vec<Option<Hit>>, RenderError> {
    let [_, _, width, height] = window;
    if width == 0 || height == 0 {
        return Ok(Vec::new());
    }
    let extent = wgpu::Extent3d {
        width,
        height,
        depth_or_array_layers: 1,
    };
    let texture = |label, format, usage| {
        gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some(label),
            size: extent,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    let ids = texture(
        "pick ids",
        PICK_FORMAT,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
    );
    let depth = texture(
        "pick depth",
        DEPTH_FORMAT,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    let padded_row = (width * 16).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
        * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let readback = gpu.device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("pick readback"),
        size: u64::from(padded_row) * u64::from(height),
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });
    cut.set_frame_window(gpu, camera, style, Some(window));
    let mut encoder = gpu
        .device
        .create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("pick"),
        });
    {
        let ids_view = ids.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("pick pass"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &ids_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    // Part id 0 (stored as id + 1) is a real part: 0 means background.
                    load: wgpu::LoadOp::Clear(wgpu::Color::TRANSPARENT),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &depth_view,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(0.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        cut.draw_pick(&mut pass, pipeline);
    }
    encoder.copy_texture_to_buffer(
        ids.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &readback,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(padded_row),
                rows_per_image: Some(height),
            },
        },
        extent,
    );
    gpu.queue.submit([encoder.finish()]);
    let bytes = map_read(gpu, &readback)?;
    readback.unmap();
    cut.set_frame(gpu, camera, style);
    let mut hits = Vec::with_capacity((width * height) as usize);
    for y in 0..height as usize {
        let row = &bytes[y * padded_row as usize..][..width as usize * 16];
        for texel in row.chunks_exact(16) {
            let word = |k: usize| u32::from_le_bytes(texel[k * 4..k * 4 + 4].try_into().unwrap());
            hits.push((word(0) != 0).then(|| Hit {
                part: word(0) - 1,
                world: [
                    f32::from_bits(word(1)),
                    f32::from_bits(word(2)),
                    f32::from_bits(word(3)),
                ],
            }));
        }
    }
    Ok(hits)
}

/// What `cut` shows at pixel (`x`, `y`) of `camera`'s view (y down); `None` for the
/// background or a pixel outside the view.
pub fn pick(
    gpu: &Gpu,
    cut: &GpuCut,
    pipeline: &CutPipeline,
    camera: &Camera,
    style: &Style,
    x: u32,
    y: u32,
) -> Result<Option<Hit>, RenderError> {
    let view = camera.view();
    if x >= view.width || y >= view.height {
        return Ok(None);
    }
    Ok(
        pick_region(gpu, cut, pipeline, camera, style, [x, y, 1, 1])?
            .into_iter()
            .next()
            .flatten(),
    )
}
