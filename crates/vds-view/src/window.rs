//! The interactive viewer: a winit window, a wgpu surface, the orbit/fly controls, the panel
//! (`hud.rs`: figures, a threshold or budget slider, every criterion and mode) and keys for
//! the same. The window title repeats the main figures four times a second.
//!
//! Keys: Tab orbit/fly · WASD QE fly · drag look/turn · wheel zoom/speed · +/- threshold or
//! budget · B threshold/budget · C silhouettes · V backfaces · F frustum mode · G gaze ·
//! Y asynchronous · Z freeze the cut · X wireframe · N smooth/faceted · 1 2 3 4 colour by
//! part / depth / error / file · R reframe · Esc quit. Review (`review.rs`): click picks a
//! part · H hide it · I isolate it · U show all · M measure (two clicks) · K first section
//! on/off · [ ] move it.
//!
//! When neither the camera nor any setting changed and the last adjust changed nothing with
//! no page on its way, the window does no adjust and no redraw: it sleeps until an event.

use std::collections::HashSet;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result};
use vds_render::{Colouring, CutPipeline, Gpu, GpuCut, Shading, Style};
use vds_runtime::{FrustumMode, Gaze, Goal};
use winit::application::ApplicationHandler;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{KeyCode, PhysicalKey};
use winit::window::{Window, WindowId};

use crate::controls::{Controls, Mode};
use crate::hud::{Panel, PanelModel};
use crate::model::Model;
use crate::review::Review;
use crate::simplify::{AdjustFigures, AsyncSimplifier, Batch, Settings, Simplifier};

/// Opens the window and runs until it closes.
pub fn run(
    model: Model,
    settings: Settings,
    style: Style,
    size: (u32, u32),
    asynchronous: bool,
) -> Result<()> {
    let event_loop = EventLoop::new().context("opening the display")?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let root = model.runtime.cut().node(0);
    let pages = model.runtime.cut().store().source();
    let review = Review::new(model.parts, style.sections, model.bounds);
    let mut app = App {
        review,
        pages,
        press: None,
        click: None,
        last_view: None,
        idle: false,
        name: model.name.clone(),
        controls: Controls::framing(root.sphere_center, root.sphere_radius),
        home: Controls::framing(root.sphere_center, root.sphere_radius),
        engine: Some(Engine::Sync(Box::new(Simplifier::new(
            model.runtime,
            false,
        )))),
        want_async: asynchronous,
        settings,
        style,
        size,
        state: None,
        keys: HashSet::new(),
        dragging: false,
        last_cursor: None,
        frozen: false,
        hud: Hud::default(),
        error: None,
    };
    event_loop.run_app(&mut app).context("running the window")?;
    match app.error {
        Some(error) => Err(error),
        None => Ok(()),
    }
}

enum Engine {
    /// Boxed: the runtime is large and the engine moves between the two modes.
    Sync(Box<Simplifier>),
    Async(AsyncSimplifier),
}

struct State {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    gpu: Gpu,
    pipeline: CutPipeline,
    gpu_cut: GpuCut,
    depth: wgpu::TextureView,
    panel: Panel,
    pages: u32,
}

#[derive(Default)]
struct Hud {
    since: Option<Instant>,
    frames: u32,
    frame_ms: f64,
    last: Option<Instant>,
    adjust: AdjustFigures,
    upload_bytes: u64,
    fps: f64,
}

struct App {
    /// Parts, picks, measurements and sections.
    review: Review,
    /// The file, for snapping measurements to its vertices.
    pages: Arc<dyn vds_runtime::PageSource>,
    /// Where the left button went down (a release close by is a click).
    press: Option<(f64, f64)>,
    /// A click to pick at in the next frame (physical pixels).
    click: Option<(u32, u32)>,
    /// The camera, settings and style of the last adjust.
    last_view: Option<(vds_runtime::Camera, Settings, Style)>,
    /// Nothing to do until the next event.
    idle: bool,
    name: String,
    controls: Controls,
    home: Controls,
    engine: Option<Engine>,
    want_async: bool,
    settings: Settings,
    style: Style,
    size: (u32, u32),
    state: Option<State>,
    keys: HashSet<KeyCode>,
    dragging: bool,
    last_cursor: Option<(f64, f64)>,
    frozen: bool,
    hud: Hud,
    error: Option<anyhow::Error>,
}

impl App {
    fn create(&mut self, event_loop: &ActiveEventLoop) -> Result<State> {
        let attributes = Window::default_attributes()
            .with_title(format!("vds-view — {}", self.name))
            .with_inner_size(winit::dpi::PhysicalSize::new(self.size.0, self.size.1));
        let window = Arc::new(event_loop.create_window(attributes)?);
        let instance = wgpu::Instance::new(
            wgpu::InstanceDescriptor::new_with_display_handle_from_env(Box::new(window.clone())),
        );
        let surface = instance.create_surface(window.clone())?;
        let gpu = Gpu::with_instance(instance, Some(&surface))?;
        let size = window.inner_size();
        let mut config = surface
            .get_default_config(&gpu.adapter, size.width.max(1), size.height.max(1))
            .context("the surface does not fit the adapter")?;
        // Draw in sRGB like the offscreen targets do.
        let capabilities = surface.get_capabilities(&gpu.adapter);
        if let Some(srgb) = capabilities.formats.iter().find(|f| f.is_srgb()) {
            config.format = *srgb;
        }
        config.present_mode = wgpu::PresentMode::AutoNoVsync;
        surface.configure(&gpu.device, &config);
        let pipeline = CutPipeline::new(&gpu, config.format);
        let gpu_cut = GpuCut::new(&gpu);
        let pages = match &self.engine {
            Some(Engine::Sync(s)) => s.runtime().cut().store().pages_resident().1,
            _ => 0,
        };
        let panel = Panel::new(&window, &gpu, config.format);
        let depth = vds_render::target::depth_texture(&gpu, config.width, config.height);
        if self.want_async {
            self.toggle_async();
        }
        Ok(State {
            window,
            surface,
            config,
            gpu,
            pipeline,
            gpu_cut,
            depth,
            panel,
            pages,
        })
    }

    fn toggle_async(&mut self) {
        self.engine = match self.engine.take() {
            Some(Engine::Sync(simplifier)) => {
                Some(Engine::Async(AsyncSimplifier::spawn(*simplifier)))
            }
            Some(Engine::Async(worker)) => {
                let (simplifier, queued) = worker.stop();
                if let Err(e) = self.apply(queued) {
                    self.error = Some(e);
                }
                simplifier.map(|s| Engine::Sync(Box::new(s)))
            }
            None => None,
        };
    }

    fn apply(&mut self, batches: Vec<Batch>) -> Result<()> {
        let Some(state) = &mut self.state else {
            return Ok(());
        };
        for batch in batches {
            self.hud.upload_bytes +=
                state
                    .gpu_cut
                    .apply(&state.gpu, &state.pipeline, &batch.update)?;
            self.hud.adjust = batch.figures;
        }
        Ok(())
    }

    fn frame(&mut self) -> Result<()> {
        let now = Instant::now();
        let seconds = self
            .hud
            .last
            .map_or(0.0, |l| (now - l).as_secs_f32())
            .min(0.1);
        self.hud.last = Some(now);
        let key = |k| f32::from(u8::from(self.keys.contains(&k)));
        self.controls.fly(
            key(KeyCode::KeyW) - key(KeyCode::KeyS),
            key(KeyCode::KeyD) - key(KeyCode::KeyA),
            key(KeyCode::KeyE) - key(KeyCode::KeyQ),
            seconds,
        );
        let Some(state) = &self.state else {
            return Ok(());
        };
        let camera = self
            .controls
            .camera(state.config.width, state.config.height);
        let mut settings = self.settings;
        if let Some(gaze) = &mut settings.criteria.gaze {
            gaze.direction = camera.view().forward.into();
        }
        self.hud.upload_bytes = 0;
        let style = Style {
            cull_outside: settings.criteria.frustum != FrustumMode::Off,
            threshold_px: match settings.goal {
                Goal::Threshold(t) => t,
                Goal::Budget(_) => 1.0,
            },
            sections: self.review.planes(),
            ..self.style
        };
        let a = &self.hud.adjust;
        let unchanged = self.last_view == Some((camera, settings, style));
        let settled = unchanged
            && a.added + a.removed + a.changed + a.nodes_changed == 0
            && a.pages_pending == 0;
        let flying = [
            KeyCode::KeyW,
            KeyCode::KeyA,
            KeyCode::KeyS,
            KeyCode::KeyD,
            KeyCode::KeyQ,
            KeyCode::KeyE,
        ]
        .iter()
        .any(|k| self.keys.contains(k));
        self.idle = settled && !flying && self.click.is_none();
        self.last_view = Some((camera, settings, style));
        if !self.frozen && !settled {
            let batches = match &mut self.engine {
                Some(Engine::Sync(simplifier)) => vec![simplifier.step(&camera, &settings)?],
                Some(Engine::Async(worker)) => {
                    worker.request(camera, settings);
                    worker.drain()?
                }
                None => Vec::new(),
            };
            self.apply(batches)?;
        }
        let Some(state) = &mut self.state else {
            return Ok(());
        };
        if self.review.take_looks_changed() {
            state
                .gpu_cut
                .set_parts(&state.gpu, &state.pipeline, &self.review.parts.looks());
        }
        if let Some((x, y)) = self.click.take() {
            let hit = vds_render::pick(
                &state.gpu,
                &state.gpu_cut,
                &state.pipeline,
                &camera,
                &style,
                x,
                y,
            )?;
            if self.review.measuring {
                let vertex = match hit {
                    Some(hit) => crate::probe::snap(&*self.pages, hit)?,
                    None => None,
                };
                self.review.measured(vertex);
            } else {
                self.review.picked(hit);
                // Upload the highlight now rather than next frame.
                state
                    .gpu_cut
                    .set_parts(&state.gpu, &state.pipeline, &self.review.parts.looks());
                self.review.take_looks_changed();
            }
        }
        state.gpu_cut.set_frame(&state.gpu, &camera, &style);
        let texture = match state.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => t,
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                state.surface.configure(&state.gpu.device, &state.config);
                return Ok(());
            }
            _ => return Ok(()),
        };
        let view = texture.texture.create_view(&Default::default());
        let mut encoder =
            state
                .gpu
                .device
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("frame"),
                });
        vds_render::target::draw_pass(
            &mut encoder,
            &view,
            &state.depth,
            &state.gpu_cut,
            &state.pipeline,
            None,
        );
        let mut model = PanelModel {
            settings: self.settings,
            style: self.style,
            frozen: self.frozen,
            asynchronous: matches!(self.engine, Some(Engine::Async(_))),
            fps: self.hud.fps,
            frame_ms: self.hud.frame_ms,
            adjust: self.hud.adjust,
            upload_bytes: self.hud.upload_bytes,
            pages: state.pages,
            flying: self.controls.mode == Mode::Fly,
        };
        let size = [state.config.width, state.config.height];
        state.panel.draw(
            &state.window,
            &state.gpu,
            (&mut encoder, &view, size),
            &mut model,
            &mut self.review,
        );
        state.gpu.queue.submit([encoder.finish()]);
        state.window.pre_present_notify();
        state.gpu.queue.present(texture);
        self.settings = model.settings;
        self.style = model.style;
        self.frozen = model.frozen;
        let window = state.window.clone();
        if model.asynchronous != matches!(self.engine, Some(Engine::Async(_))) {
            self.toggle_async();
        }
        self.hud.frames += 1;
        self.hud.frame_ms = now.elapsed().as_secs_f64() * 1e3;
        let since = *self.hud.since.get_or_insert(now);
        if now.duration_since(since).as_secs_f64() >= 0.25 {
            let fps = f64::from(self.hud.frames) / now.duration_since(since).as_secs_f64();
            self.hud.fps = fps;
            self.hud.since = Some(now);
            self.hud.frames = 0;
            window.set_title(&self.title(fps));
        }
        Ok(())
    }

    fn title(&self, fps: f64) -> String {
        let a = &self.hud.adjust;
        let goal = match self.settings.goal {
            Goal::Threshold(t) => format!("t {t:.2} px"),
            Goal::Budget(n) => format!("budget {n}"),
        };
        let criteria = &self.settings.criteria;
        format!(
            "vds-view — {fps:.0} fps {:.1} ms | simplify {:.2} ms | {} tris {} nodes | {goal} | \
             upload {} B | pages {} | {}{}{}{}{}{}",
            self.hud.frame_ms,
            a.adjust_ms,
            a.active_triangles,
            a.active_nodes,
            self.hud.upload_bytes,
            a.pages_resident,
            if matches!(self.engine, Some(Engine::Async(_))) {
                "async"
            } else {
                "sync"
            },
            if criteria.silhouette_factor.is_some() {
                " silhouette"
            } else {
                ""
            },
            if criteria.backface { " backface" } else { "" },
            match criteria.frustum {
                FrustumMode::Fold => " frustum",
                FrustumMode::Ignore => " frustum-ignore",
                FrustumMode::Off => "",
            },
            if criteria.gaze.is_some() { " gaze" } else { "" },
            if self.frozen { " FROZEN" } else { "" },
        )
    }

    fn key(&mut self, code: KeyCode, event_loop: &ActiveEventLoop) {
        let criteria = &mut self.settings.criteria;
        match code {
            KeyCode::Escape => event_loop.exit(),
            KeyCode::Tab => self.controls.toggle_mode(),
            KeyCode::Equal | KeyCode::NumpadAdd => {
                self.settings.goal = match self.settings.goal {
                    Goal::Threshold(t) => Goal::Threshold(t / 1.5),
                    Goal::Budget(n) => Goal::Budget(n.saturating_mul(3) / 2),
                }
            }
            KeyCode::Minus | KeyCode::NumpadSubtract => {
                self.settings.goal = match self.settings.goal {
                    Goal::Threshold(t) => Goal::Threshold(t * 1.5),
                    Goal::Budget(n) => Goal::Budget(n * 2 / 3),
                }
            }
            KeyCode::KeyB => {
                self.settings.goal = match self.settings.goal {
                    Goal::Threshold(_) => Goal::Budget(self.hud.adjust.active_triangles.max(1000)),
                    Goal::Budget(_) => Goal::Threshold(1.0),
                }
            }
            KeyCode::KeyC => {
                criteria.silhouette_factor = match criteria.silhouette_factor {
                    Some(_) => None,
                    None => Some(0.25),
                }
            }
            KeyCode::KeyV => criteria.backface = !criteria.backface,
            KeyCode::KeyF => {
                criteria.frustum = match criteria.frustum {
                    FrustumMode::Fold => FrustumMode::Ignore,
                    FrustumMode::Ignore => FrustumMode::Off,
                    FrustumMode::Off => FrustumMode::Fold,
                }
            }
            KeyCode::KeyG => {
                criteria.gaze = match criteria.gaze {
                    Some(_) => None,
                    None => Some(Gaze {
                        direction: [0.0, 0.0, -1.0],
                        falloff: 4.0,
                    }),
                }
            }
            KeyCode::KeyY => self.toggle_async(),
            KeyCode::KeyZ => self.frozen = !self.frozen,
            KeyCode::KeyX => self.style.wireframe = !self.style.wireframe,
            KeyCode::KeyN => {
                self.style.shading = match self.style.shading {
                    Shading::Faceted => Shading::Smooth,
                    Shading::Smooth => Shading::Faceted,
                }
            }
            KeyCode::Digit1 => self.style.colouring = Colouring::Parts,
            KeyCode::Digit2 => self.style.colouring = Colouring::Depth,
            KeyCode::Digit3 => self.style.colouring = Colouring::Error,
            KeyCode::Digit4 => self.style.colouring = Colouring::File,
            KeyCode::KeyH => self.review.hide_picked(),
            KeyCode::KeyI => self.review.isolate_picked(),
            KeyCode::KeyU => self.review.show_all(),
            KeyCode::KeyM => self.review.measuring = !self.review.measuring,
            KeyCode::KeyK => self.review.toggle_first_section(),
            KeyCode::BracketLeft => self.review.move_first_section(-0.02),
            KeyCode::BracketRight => self.review.move_first_section(0.02),
            KeyCode::KeyR => self.controls = self.home,
            _ => {}
        }
    }
}

impl ApplicationHandler for App {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.state.is_some() {
            return;
        }
        match self.create(event_loop) {
            Ok(state) => self.state = Some(state),
            Err(error) => {
                self.error = Some(error);
                event_loop.exit();
            }
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        if !matches!(event, WindowEvent::RedrawRequested) {
            self.idle = false;
        }
        let mut for_panel = false;
        if let Some(state) = &mut self.state {
            let consumed = state.panel.on_event(&state.window, &event);
            let pointer = matches!(
                event,
                WindowEvent::MouseInput { .. }
                    | WindowEvent::CursorMoved { .. }
                    | WindowEvent::MouseWheel { .. }
            );
            for_panel = consumed || (pointer && state.panel.wants_pointer());
        }
        if for_panel {
            if let WindowEvent::CursorMoved { position, .. } = event {
                self.last_cursor = Some((position.x, position.y));
            }
            self.dragging = false;
            return;
        }
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => {
                if let Some(state) = &mut self.state {
                    state.config.width = size.width.max(1);
                    state.config.height = size.height.max(1);
                    state.surface.configure(&state.gpu.device, &state.config);
                    state.depth = vds_render::target::depth_texture(
                        &state.gpu,
                        state.config.width,
                        state.config.height,
                    );
                }
            }
            WindowEvent::KeyboardInput { event, .. } => {
                let typing = self
                    .state
                    .as_ref()
                    .is_some_and(|s| s.panel.wants_keyboard());
                if let (PhysicalKey::Code(code), false) = (event.physical_key, typing) {
                    match event.state {
                        ElementState::Pressed => {
                            if !event.repeat {
                                self.key(code, event_loop);
                            }
                            self.keys.insert(code);
                        }
                        ElementState::Released => {
                            self.keys.remove(&code);
                        }
                    }
                }
            }
            WindowEvent::MouseInput {
                state,
                button: MouseButton::Left,
                ..
            } => {
                self.dragging = state == ElementState::Pressed;
                match state {
                    ElementState::Pressed => self.press = self.last_cursor,
                    ElementState::Released => {
                        // A release within a few pixels of the press is a click, not a drag.
                        if let (Some((px, py)), Some((x, y))) =
                            (self.press.take(), self.last_cursor)
                            && (x - px).abs() + (y - py).abs() < 4.0
                            && x >= 0.0
                            && y >= 0.0
                        {
                            self.click = Some((x as u32, y as u32));
                        }
                    }
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                if let (true, Some((x, y))) = (self.dragging, self.last_cursor) {
                    self.controls
                        .drag((position.x - x) as f32, (position.y - y) as f32);
                }
                self.last_cursor = Some((position.x, position.y));
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let lines = match delta {
                    MouseScrollDelta::LineDelta(_, y) => y,
                    MouseScrollDelta::PixelDelta(p) => p.y as f32 / 40.0,
                };
                self.controls.scroll(lines);
            }
            WindowEvent::RedrawRequested => {
                if let Err(error) = self.frame() {
                    self.error = Some(error);
                    event_loop.exit();
                }
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, event_loop: &ActiveEventLoop) {
        // Idle: wait for the next event (which asks for a redraw) instead of polling.
        if self.idle {
            event_loop.set_control_flow(ControlFlow::Wait);
        } else {
            event_loop.set_control_flow(ControlFlow::Poll);
            if let Some(state) = &self.state {
                state.window.request_redraw();
            }
        }
    }
}
