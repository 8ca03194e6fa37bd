//! Offscreen render targets: a colour and a depth texture, one render pass drawing a
//! [`GpuCut`] into them, and reading the pixels back (for PNGs, tests and benchmarks).
//! Window surfaces use the same pass through [`draw_pass`].

use std::path::Path;

use crate::cut_renderer::{COLOR_FORMAT, CutPipeline, DEPTH_FORMAT, GpuCut};
use crate::{Gpu, RenderError};

/// The background colour (linear).
pub const BACKGROUND: wgpu::Color = wgpu::Color {
    r: 0.02,
    g: 0.025,
    b: 0.035,
    a: 1.0,
};

/// Records one pass that clears `color` and `depth` and draws `cut`.
pub fn draw_pass(
    encoder: &mut wgpu::CommandEncoder,
    color: &wgpu::TextureView,
    depth: &wgpu::TextureView,
    cut: &GpuCut,
    pipeline: &CutPipeline,
    timestamps: Option<wgpu::RenderPassTimestampWrites<'_>>,
) {
    let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
        label: Some("cut pass"),
        color_attachments: &[Some(wgpu::RenderPassColorAttachment {
            view: color,
            depth_slice: None,
            resolve_target: None,
            ops: wgpu::Operations {
                load: wgpu::LoadOp::Clear(BACKGROUND),
                store: wgpu::StoreOp::Store,
            },
        })],
        depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
            view: depth,
            // Reversed Z: far is 0.
            depth_ops: Some(wgpu::Operations {
                load: wgpu::LoadOp::Clear(0.0),
                store: wgpu::StoreOp::Discard,
            }),
            stencil_ops: None,
        }),
        timestamp_writes: timestamps,
        occlusion_query_set: None,
        multiview_mask: None,
    });
    cut.draw(&mut pass, pipeline);
}

/// A depth texture of the given size.
pub fn depth_texture(gpu: &Gpu, width: u32, height: u32) -> wgpu::TextureView {
    gpu.device
        .create_texture(&wgpu::TextureDescriptor {
            label: Some("depth"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: DEPTH_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            view_formats: &[],
        })
        .create_view(&Default::default())
}

/// An offscreen colour + depth target with a readback buffer.
pub struct Offscreen {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    color: wgpu::Texture,
    color_view: wgpu::TextureView,
    depth_view: wgpu::TextureView,
    readback: wgpu::Buffer,
    padded_row: u32,
    queries: Option<(wgpu::QuerySet, wgpu::Buffer, wgpu::Buffer)>,
}

/// An RGBA8 image (sRGB), rows top to bottom.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Image {
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
    /// `width * height * 4` bytes.
    pub rgba: Vec<u8>,
}

impl Image {
    /// Writes the image as PNG (atomically: a temporary file renamed into place).
    pub fn write_png(&self, path: &Path) -> Result<(), RenderError> {
        let io = |e: std::io::Error| RenderError::Io(path.to_path_buf(), e);
        let temporary = path.with_extension("png.partial");
        let result = (|| {
            let file = std::io::BufWriter::new(std::fs::File::create(&temporary).map_err(io)?);
            let mut encoder = png::Encoder::new(file, self.width, self.height);
            encoder.set_color(png::ColorType::Rgba);
            encoder.set_depth(png::BitDepth::Eight);
            let mut writer = encoder
                .write_header()
                .map_err(|e| RenderError::Png(e.to_string()))?;
            writer
                .write_image_data(&self.rgba)
                .map_err(|e| RenderError::Png(e.to_string()))?;
            writer
                .finish()
                .map_err(|e| RenderError::Png(e.to_string()))?;
            std::fs::rename(&temporary, path).map_err(io)
        })();
        if result.is_err() {
            let _ = std::fs::remove_file(&temporary);
        }
        result
    }

    /// Reads a PNG written by [`Image::write_png`] (RGBA8 only).
    pub fn read_png(path: &Path) -> Result<Image, RenderError> {
        let file = std::fs::File::open(path).map_err(|e| RenderError::Io(path.to_path_buf(), e))?;
        let decoder = png::Decoder::new(std::io::BufReader::new(file));
        let mut reader = decoder
            .read_info()
            .map_err(|e| RenderError::Png(e.to_string()))?;
        let mut rgba = vec![0; reader.output_buffer_size().unwrap_or(0)];
        let info = reader
            .next_frame(&mut rgba)
            .map_err(|e| RenderError::Png(e.to_string()))?;
        if info.color_type != png::ColorType::Rgba || info.bit_depth != png::BitDepth::Eight {
            return Err(RenderError::Png(format!(
                "{}: expected 8-bit RGBA",
                path.display()
            )));
        }
        rgba.truncate(info.buffer_size());
        Ok(Image {
            width: info.width,
            height: info.height,
            rgba,
        })
    }
}

impl Offscreen {
    /// A target of `width` × `height` pixels.
    pub fn new(gpu: &Gpu, width: u32, height: u32) -> Offscreen {
        let color = gpu.device.create_texture(&wgpu::TextureDescriptor {
            label: Some("offscreen colour"),
            size: wgpu::Extent3d {
                width,
                height,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: COLOR_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
        let color_view = color.create_view(&Default::default());
        let padded_row = (width * 4).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let readback = gpu.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("readback"),
            size: u64::from(padded_row) * u64::from(height),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let queries = gpu.timestamps.then(|| {
            let set = gpu.device.create_query_set(&wgpu::QuerySetDescriptor {
                label: Some("pass timestamps"),
                ty: wgpu::QueryType::Timestamp,
                count: 2,
            });
            let resolve = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp resolve"),
                size: 16,
                usage: wgpu::BufferUsages::QUERY_RESOLVE | wgpu::BufferUsages::COPY_SRC,
                mapped_at_creation: false,
            });
            let read = gpu.device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("timestamp read"),
                size: 16,
                usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
                mapped_at_creation: false,
            });
            (set, resolve, read)
        });
        Offscreen {
            width,
            height,
            color,
            color_view,
            depth_view: depth_texture(gpu, width, height),
            readback,
            padded_row,
            queries,
        }
    }

    /// Draws `cut` and waits for the GPU. Returns the GPU time of the pass in milliseconds
    /// where the adapter has timestamp queries.
    pub fn render(
        &self,
        gpu: &Gpu,
        cut: &GpuCut,
        pipeline: &CutPipeline,
    ) -> Result<Option<f64>, RenderError> {
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("offscreen frame"),
            });
        let timestamps = self
            .queries
            .as_ref()
            .map(|(set, _, _)| wgpu::RenderPassTimestampWrites {
                query_set: set,
                beginning_of_pass_write_index: Some(0),
                end_of_pass_write_index: Some(1),
            });
        draw_pass(
            &mut encoder,
            &self.color_view,
            &self.depth_view,
            cut,
            pipeline,
            timestamps,
        );
        if let Some((set, resolve, read)) = &self.queries {
            encoder.resolve_query_set(set, 0..2, resolve, 0);
            encoder.copy_buffer_to_buffer(resolve, 0, read, 0, 16);
        }
        gpu.queue.submit([encoder.finish()]);
        let Some((_, _, read)) = &self.queries else {
            wait(gpu)?;
            return Ok(None);
        };
        let ticks: [u64; 2] = {
            let bytes = map_read(gpu, read)?;
            let ticks = bytemuck::pod_read_unaligned(&bytes[..16]);
            read.unmap();
            ticks
        };
        let period = f64::from(gpu.queue.get_timestamp_period());
        Ok(Some(
            ticks[1].saturating_sub(ticks[0]) as f64 * period / 1e6,
        ))
    }

    /// Copies the last frame back to the CPU.
    pub fn read(&self, gpu: &Gpu) -> Result<Image, RenderError> {
        let mut encoder = gpu
            .device
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("readback"),
            });
        encoder.copy_texture_to_buffer(
            self.color.as_image_copy(),
            wgpu::TexelCopyBufferInfo {
                buffer: &self.readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(self.padded_row),
                    rows_per_image: Some(self.height),
                },
            },
            wgpu::Extent3d {
                width: self.width,
                height: self.height,
                depth_or_array_layers: 1,
            },
        );
        gpu.queue.submit([encoder.finish()]);
        let bytes = map_read(gpu, &self.readback)?;
        let row = (self.width * 4) as usize;
        let mut rgba = Vec::with_capacity(row * self.height as usize);
        for y in 0..self.height as usize {
            let start = y * self.padded_row as usize;
            rgba.extend_from_slice(&bytes[start..start + row]);
        }
        drop(bytes);
        self.readback.unmap();
        Ok(Image {
            width: self.width,
            height: self.height,
            rgba,
        })
    }
}

fn wait(gpu: &Gpu) -> Result<(), RenderError> {
    gpu.device
        .poll(wgpu::PollType::wait_indefinitely())
        .map(|_| ())
        .map_err(|e| RenderError::Device(e.to_string()))
}

/// Maps `buffer` for reading, waits, and returns its bytes (the caller unmaps).
pub(crate) fn map_read(gpu: &Gpu, buffer: &wgpu::Buffer) -> Result<Vec<u8>, RenderError> {
    let (sender, receiver) = std::sync::mpsc::channel();
    buffer.map_async(wgpu::MapMode::Read, .., move |result| {
        let _ = sender.send(result);
    });
    wait(gpu)?;
    receiver
        .recv()
        .map_err(|e| RenderError::Device(e.to_string()))?
        .map_err(|e| RenderError::Device(e.to_string()))?;
    let bytes = buffer
        .get_mapped_range(..)
        .map_err(|e| RenderError::Device(e.to_string()))?
        .to_vec();
    Ok(bytes)
}
