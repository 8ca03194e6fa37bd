//! The on-screen panel (egui): the figures of the last frames and the controls for the
//! threshold or budget, every criterion, the simplification mode and the look.
//!
//! The panel edits a [`PanelModel`]; the window copies its state in before the frame and
//! acts on what changed after, so the panel owns no viewer state.

use egui_wgpu::ScreenDescriptor;
use vds_render::{Colouring, Gpu, Shading, Style};
use vds_runtime::{FrustumMode, Gaze, Goal};
use winit::window::Window;

use crate::review::Review;
use crate::simplify::{AdjustFigures, Settings};

/// What the panel shows and edits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PanelModel {
    /// Cut settings.
    pub settings: Settings,
    /// Look.
    pub style: Style,
    /// The cut is frozen.
    pub frozen: bool,
    /// Simplification runs on its own thread.
    pub asynchronous: bool,
    /// Frames per second (over the last quarter second).
    pub fps: f64,
    /// Last frame's CPU time.
    pub frame_ms: f64,
    /// The last adjust.
    pub adjust: AdjustFigures,
    /// Bytes uploaded this frame.
    pub upload_bytes: u64,
    /// Pages in the file.
    pub pages: u32,
    /// Flying (else orbiting).
    pub flying: bool,
}

/// egui's context, its winit input state and its wgpu renderer.
pub struct Panel {
    context: egui::Context,
    input: egui_winit::State,
    renderer: egui_wgpu::Renderer,
}

impl Panel {
    /// A panel for `window`, drawing to targets of `format`.
    pub fn new(window: &Window, gpu: &Gpu, format: wgpu::TextureFormat) -> Panel {
        let context = egui::Context::default();
        let input = egui_winit::State::new(
            context.clone(),
            egui::ViewportId::ROOT,
            window,
            Some(window.scale_factor() as f32),
            None,
            Some(gpu.device.limits().max_texture_dimension_2d as usize),
        );
        let renderer = egui_wgpu::Renderer::new(&gpu.device, format, Default::default());
        Panel {
            context,
            input,
            renderer,
        }
    }

    /// True while a text field has the keyboard (keys are not shortcuts then).
    pub fn wants_keyboard(&self) -> bool {
        self.context.egui_wants_keyboard_input()
    }

    /// Feeds a window event to egui; true when egui used it (the camera should not).
    pub fn on_event(&mut self, window: &Window, event: &winit::event::WindowEvent) -> bool {
        self.input.on_window_event(window, event).consumed
    }

    /// True while the pointer is over the panel.
    pub fn wants_pointer(&self) -> bool {
        self.context.egui_wants_pointer_input()
    }

    /// Lays the panel and the review window out, edits `model` and `review`, and records
    /// their draw into `encoder` on top of `view` (which already holds the frame of `size`).
    pub fn draw(
        &mut self,
        window: &Window,
        gpu: &Gpu,
        (encoder, view, size): (&mut wgpu::CommandEncoder, &wgpu::TextureView, [u32; 2]),
        model: &mut PanelModel,
        review: &mut Review,
    ) {
        let raw = self.input.take_egui_input(window);
        let output = self.context.run_ui(raw, |ui| {
            egui::Window::new("vds")
                .default_pos([12.0, 12.0])
                .resizable(false)
                .show(ui.ctx(), |ui| contents(ui, model));
            review.show(ui.ctx());
        });
        self.input
            .handle_platform_output(window, output.platform_output);
        let jobs = self
            .context
            .tessellate(output.shapes, output.pixels_per_point);
        let screen = ScreenDescriptor {
            size_in_pixels: size,
            pixels_per_point: output.pixels_per_point,
        };
        for (id, deltas) in &output.textures_delta.set {
            for delta in deltas {
                self.renderer
                    .update_texture(&gpu.device, &gpu.queue, *id, delta);
            }
        }
        let extra = self
            .renderer
            .update_buffers(&gpu.device, &gpu.queue, encoder, &jobs, &screen);
        if !extra.is_empty() {
            gpu.queue.submit(extra);
        }
        {
            let pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("panel"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view,
                    depth_slice: None,
                    resolve_target: None,
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Load,
                        store: wgpu::StoreOp::Store,
                    },
                })],
                depth_stencil_attachment: None,
                timestamp_writes: None,
                occlusion_query_set: None,
                multiview_mask: None,
            });
            self.renderer
                .render(&mut pass.forget_lifetime(), &jobs, &screen);
        }
        for id in &output.textures_delta.free {
            self.renderer.free_texture(id);
        }
    }
}

fn contents(ui: &mut egui::Ui, model: &mut PanelModel) {
    let a = &model.adjust;
    egui::Grid::new("figures").num_columns(2).show(ui, |ui| {
        let mut row = |name: &str, value: String| {
            ui.label(name);
            ui.monospace(value);
            ui.end_row();
        };
        row("fps", format!("{:.0}", model.fps));
        row("frame", format!("{:.2} ms", model.frame_ms));
        row("simplify", format!("{:.3} ms", a.adjust_ms));
        row("triangles", format!("{}", a.active_triangles));
        row("nodes", format!("{}", a.active_nodes));
        row(
            "changes",
            format!("+{} −{} ~{}", a.added, a.removed, a.changed),
        );
        row("upload", format!("{} B", model.upload_bytes));
        row(
            "pages",
            if a.pages_pending > 0 {
                format!(
                    "{} / {} ({} loading)",
                    a.pages_resident, model.pages, a.pages_pending
                )
            } else {
                format!("{} / {}", a.pages_resident, model.pages)
            },
        );
        row(
            "memory",
            format!(
                "{} / {}",
                vds_runtime::size::format_size(a.resident_bytes),
                vds_runtime::size::format_size(a.budget_bytes)
            ),
        );
        if let (Goal::Threshold(asked), Some(effective)) =
            (model.settings.goal, a.effective_threshold)
            && effective > asked
        {
            row(
                "threshold",
                format!("{effective:.2} px (raised from {asked:.2}: memory)"),
            );
        }
    });
    ui.separator();
    let settings = &mut model.settings;
    let mut budget_mode = matches!(settings.goal, Goal::Budget(_));
    ui.horizontal(|ui| {
        ui.selectable_value(&mut budget_mode, false, "threshold");
        ui.selectable_value(&mut budget_mode, true, "budget");
    });
    settings.goal = match (settings.goal, budget_mode) {
        (Goal::Threshold(mut t), false) => {
            ui.add(
                egui::Slider::new(&mut t, 0.1..=50.0)
                    .logarithmic(true)
                    .suffix(" px"),
            );
            Goal::Threshold(t)
        }
        (Goal::Budget(mut n), true) => {
            ui.add(egui::Slider::new(&mut n, 1_000..=50_000_000).logarithmic(true));
            Goal::Budget(n)
        }
        (Goal::Threshold(_), true) => Goal::Budget(a.active_triangles.max(1_000)),
        (Goal::Budget(_), false) => Goal::Threshold(1.0),
    };
    let criteria = &mut settings.criteria;
    let mut silhouette = criteria.silhouette_factor.is_some();
    ui.checkbox(&mut silhouette, "silhouettes at ¼ threshold");
    criteria.silhouette_factor = silhouette.then_some(0.25);
    ui.checkbox(&mut criteria.backface, "fold backfaces");
    egui::ComboBox::from_label("frustum")
        .selected_text(format!("{:?}", criteria.frustum))
        .show_ui(ui, |ui| {
            for mode in [FrustumMode::Fold, FrustumMode::Ignore, FrustumMode::Off] {
                ui.selectable_value(&mut criteria.frustum, mode, format!("{mode:?}"));
            }
        });
    let mut gaze = criteria.gaze.is_some();
    ui.checkbox(&mut gaze, "gaze falloff");
    criteria.gaze = match (gaze, criteria.gaze) {
        (true, Some(g)) => Some(g),
        (true, None) => Some(Gaze {
            direction: [0.0, 0.0, -1.0],
            falloff: 4.0,
        }),
        (false, _) => None,
    };
    ui.checkbox(&mut model.asynchronous, "asynchronous simplification");
    ui.checkbox(&mut model.frozen, "freeze the cut");
    ui.separator();
    let style = &mut model.style;
    ui.checkbox(&mut style.wireframe, "wireframe");
    ui.horizontal(|ui| {
        ui.selectable_value(&mut style.colouring, Colouring::File, "file");
        ui.selectable_value(&mut style.colouring, Colouring::Parts, "parts");
        ui.selectable_value(&mut style.colouring, Colouring::Depth, "depth");
        ui.selectable_value(&mut style.colouring, Colouring::Error, "error");
    });
    ui.horizontal(|ui| {
        ui.selectable_value(&mut style.shading, Shading::Faceted, "faceted");
        ui.selectable_value(&mut style.shading, Shading::Smooth, "smooth");
    });
    ui.label(if model.flying {
        "fly: WASD QE, drag to look (Tab: orbit)"
    } else {
        "orbit: drag, wheel (Tab: fly)"
    });
}
