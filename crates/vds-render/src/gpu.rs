//! The device: one wgpu instance, adapter, device and queue, created headless (for tests, CI
//! and `vds-view --headless`) or compatible with a window surface.

use crate::RenderError;

/// An open GPU (or software adapter such as llvmpipe).
pub struct Gpu {
    /// The wgpu instance.
    pub instance: wgpu::Instance,
    /// The adapter in use.
    pub adapter: wgpu::Adapter,
    /// The logical device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Whether timestamp queries work (for GPU frame times).
    pub timestamps: bool,
}

impl Gpu {
    /// Opens the preferred adapter without a window (`WGPU_BACKEND` and friends are honoured).
    pub fn headless() -> Result<Gpu, RenderError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        Gpu::with_instance(instance, None)
    }

    /// Opens an adapter that can present to `surface` (created from `instance`).
    pub fn with_instance(
        instance: wgpu::Instance,
        surface: Option<&wgpu::Surface<'_>>,
    ) -> Result<Gpu, RenderError> {
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            compatible_surface: surface,
            ..Default::default()
        }))
        .map_err(|e| RenderError::NoAdapter(e.to_string()))?;
        let wanted = wgpu::Features::TIMESTAMP_QUERY;
        let features = adapter.features() & wanted;
        // The cut's vertex and slot arrays are storage buffers as large as the cut: ask for
        // everything the adapter offers.
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("vds device"),
            required_features: features,
            required_limits: limits,
            ..Default::default()
        }))
        .map_err(|e| RenderError::Device(e.to_string()))?;
        Ok(Gpu {
            instance,
            adapter,
            device,
            queue,
            timestamps: features.contains(wgpu::Features::TIMESTAMP_QUERY),
        })
    }

    /// A one-line description of the adapter ("llvmpipe (LLVM 15.0.6, 256 bits), Gl").
    pub fn describe(&self) -> String {
        let info = self.adapter.get_info();
        format!("{}, {:?}", info.name, info.backend)
    }
}
