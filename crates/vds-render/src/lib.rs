//! The wgpu renderer of vds: a GPU mirror of the runtime's cut, updated by small per-frame
//! uploads, drawn by one pipeline into a window surface or an offscreen target.
//!
//! - [`gpu`]: device creation (headless or for a surface).
//! - [`update`]: the CPU-side batch of changes ([`CutUpdate`]) collected after an adjust by a
//!   [`VertexPool`], which gives GPU vertices only to the nodes the cut uses.
//! - [`ranks`]: the same for a rank-tracked cut ([`RankMirror`]): vertices for boundary
//!   nodes, a rank → vertex map edited by range fills, and slots of original corners.
//! - [`cut_renderer`]: buffers, uploads, the pipeline and `shaders/cut.wgsl`.
//! - [`target`]: offscreen targets, readback, PNG files.
//! - [`mod@pick`]: what a pixel shows (part id and world position), by an id buffer.
//!
//! Positions are never re-uploaded per frame: a node's vertex record goes up when the cut
//! starts to use it; per frame only those and the slots that changed are written. GPU memory
//! follows the cut, not the model.

#![deny(missing_docs)]

pub mod cut_renderer;
pub mod gpu;
pub mod pick;
pub mod ranks;
pub mod target;
pub mod update;

pub use cut_renderer::{
    Colouring, CutPipeline, GpuCut, MAX_SECTIONS, PartLook, SectionPlane, Shading, Style,
    world_to_clip,
};
pub use pick::{Hit, pick, pick_region};

/// The colour format offscreen targets use (sRGB, so PNGs look as the window does).
pub fn target_format() -> wgpu::TextureFormat {
    cut_renderer::COLOR_FORMAT
}
pub use gpu::Gpu;
pub use ranks::RankMirror;
pub use target::{Image, Offscreen};
pub use update::{CutUpdate, GpuNode, VertexPool};

/// What can go wrong while rendering.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// No adapter could be opened.
    #[error("no GPU or software adapter: {0}")]
    NoAdapter(String),
    /// The device failed.
    #[error("GPU device: {0}")]
    Device(String),
    /// A buffer would exceed the adapter's limits.
    #[error("too large for this adapter: {0}")]
    TooLarge(String),
    /// Reading or writing a file failed.
    #[error("{0}: {1}")]
    Io(std::path::PathBuf, std::io::Error),
    /// PNG encoding or decoding failed.
    #[error("PNG: {0}")]
    Png(String),
}
