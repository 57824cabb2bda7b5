//! The desktop viewer (`cbdam view`), as a library function: a winit window; each frame moves
//! the camera, runs one step of the refinement loop within its time budget (records of remote
//! sources arrive asynchronously, so nothing blocks), draws the cut with the renderer of
//! `cbdam-render`, lays the HUD over it and copies the result onto the window's surface.

use std::collections::VecDeque;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use anyhow::{Context, Result, anyhow, bail};
use cbdam_client::access::DataSource;
use cbdam_client::camera::Camera;
use cbdam_client::controls::{Controls, Mode};
use cbdam_client::patch::HalfPatch;
use cbdam_client::refine::{FrameStats, Refiner};
use cbdam_client::viewer::{Effect, Gestures, HeldKeys, Toggles, action_for_key};
use cbdam_client::world::World;
use winit::application::ApplicationHandler;
use winit::dpi::PhysicalSize;
use winit::event::{ElementState, MouseButton, MouseScrollDelta, WindowEvent};
use winit::event_loop::{ActiveEventLoop, ControlFlow, EventLoop};
use winit::keyboard::{Key, PhysicalKey};
use winit::window::{Window, WindowId};

use cbdam_client::stats::percentile;

use cbdam_render::hud::{self, Hud};
use cbdam_render::present::Presenter;
use cbdam_render::{CacheConfig, Colouring, DrawStats, Gpu, RenderOptions, Renderer, write_png};

mod hud_text;

/// Printed at start and in `cbdam view --help`.
pub const KEY_HELP: &str = "\
Keys and mouse of `cbdam view`:
  orbit camera (default): left-drag rotate, right-drag pan, wheel zoom, W/A/S/D move the target
  fly camera:             W/A/S/D forward/left/back/right, Q/E up/down, Shift faster,
                          drag (any button) to look, wheel forward/back
  C  switch orbit / fly        R  reset the camera to the overview
  +  finer (pixel-error target / 2)   -  coarser (target x 2)
  F  freeze the cut (the camera still moves; refinement stops)
  Tab or 1  wireframe          L  colour by diamond level
  H  hide / show the HUD (the figures in the top-left corner)
  P  save a screenshot (cbdam-view-NNNN.png)     Esc  quit";

/// Frames the HUD's frame-time median spans.
const FPS_WINDOW: usize = 60;

/// What the viewer is asked for, besides the refiner it drives.
#[derive(Clone, Debug, Default)]
pub struct ViewOptions {
    /// The repository's name or URL, for the title and the HUD.
    pub name: String,
    /// The repository is fetched over the network (the HUD shows the fetcher's figures).
    pub remote: bool,
    /// Initial window size, pixels.
    pub size: (u32, u32),
    /// Present as fast as possible (immediate or mailbox) instead of waiting for vsync.
    pub no_vsync: bool,
    /// Quit after this many frames.
    pub max_frames: Option<u64>,
    /// Save the last frame (with the HUD) to this PNG when the viewer stops.
    pub screenshot: Option<PathBuf>,
    /// Start with the wireframe on.
    pub wireframe: bool,
    /// Start colouring by diamond level.
    pub levels: bool,
    /// GPU height pool, MiB (default: 256 or what the adapter allows).
    pub pool_mib: Option<u64>,
}

/// Opens a window and runs the viewer until it is closed (or `max_frames` have been drawn):
/// each frame moves the camera, runs one step of `refiner` within its budget, draws the cut and
/// the HUD and presents them. Prints [`KEY_HELP`] first and a summary of frame times last.
pub fn view<S: DataSource>(refiner: Refiner<S>, args: &ViewOptions) -> Result<()> {
    let (name, remote) = (args.name.clone(), args.remote);
    println!("{KEY_HELP}");
    let event_loop = EventLoop::new().map_err(|e| {
        anyhow!(
            "cannot open a window ({e}); is there a display (DISPLAY)? Without one, use \
             `cbdam render`, or run under Xvfb"
        )
    })?;
    event_loop.set_control_flow(ControlFlow::Poll);
    let world = *refiner.world();
    let start = Camera::framed(&world, args.size);
    let mut app = App {
        args,
        name,
        remote,
        world,
        controls: Controls::new(&world, &start),
        refiner,
        patches: Vec::new(),
        options: RenderOptions::default(),
        toggles: Toggles {
            wireframe: args.wireframe,
            levels: args.levels,
            ..Toggles::default()
        },
        keys: HeldKeys::default(),
        gestures: Gestures::default(),
        mouse: Mouse::default(),
        window: None,
        last_refine: FrameStats::default(),
        last_draw: Default::default(),
        frame_times: VecDeque::new(),
        all_frame_times: Vec::new(),
        triangles: Vec::new(),
        last_instant: None,
        frames: 0,
        screenshot_now: false,
        error: None,
    };
    event_loop.run_app(&mut app).context("window event loop")?;
    if let Some(e) = app.error {
        return Err(e);
    }
    app.summary();
    Ok(())
}

/// The mouse buttons held and where the cursor was.
#[derive(Default)]
struct Mouse {
    rotating: bool,
    panning: bool,
    cursor: Option<(f64, f64)>,
}

/// What exists once the window does.
struct WindowState {
    window: Arc<Window>,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    renderer: Renderer,
    hud: Hud,
    presenter: Presenter,
    adapter: String,
}

struct App<'a, S: DataSource> {
    args: &'a ViewOptions,
    name: String,
    remote: bool,
    world: World,
    controls: Controls,
    refiner: Refiner<S>,
    patches: Vec<Arc<HalfPatch>>,
    options: RenderOptions,
    toggles: Toggles,
    keys: HeldKeys,
    gestures: Gestures,
    mouse: Mouse,
    window: Option<WindowState>,
    last_refine: FrameStats,
    last_draw: DrawStats,
    /// Seconds between the last frames, newest last (HUD).
    frame_times: VecDeque<f64>,
    /// Every frame's interval (summary at exit).
    all_frame_times: Vec<f64>,
    triangles: Vec<u64>,
    last_instant: Option<Instant>,
    frames: u64,
    screenshot_now: bool,
    error: Option<anyhow::Error>,
}

impl<S: DataSource> App<'_, S> {
    fn open_window(&mut self, event_loop: &ActiveEventLoop) -> Result<()> {
        let (w, h) = self.args.size;
        let attributes = Window::default_attributes()
            .with_title(format!("cbdam view — {}", self.name))
            .with_inner_size(PhysicalSize::new(w, h));
        let window = Arc::new(
            event_loop
                .create_window(attributes)
                .context("creating the window")?,
        );
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let surface = instance
            .create_surface(window.clone())
            .context("creating the window's surface")?;
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: Some(&surface),
            apply_limit_buckets: false,
        }))
        .map_err(|e| {
            anyhow!(
                "no GPU adapter can present to this window ({e}); on a machine without a GPU \
                 install Mesa's software Vulkan driver: apt-get install mesa-vulkan-drivers \
                 libvulkan1"
            )
        })?;
        let gpu = Gpu::from_adapter(&adapter)?;
        let config = surface_config(
            &surface.get_capabilities(&adapter),
            window.inner_size(),
            self.args.no_vsync,
        )?;
        let (format, present_mode) = (config.format, config.present_mode);
        surface.configure(&gpu.device, &config);
        let adapter_name = gpu.describe();
        let hud = Hud::new(&gpu.device, &gpu.queue);
        let presenter = Presenter::new(&gpu.device, format);
        let renderer = Renderer::with_colour(
            gpu,
            self.world,
            CacheConfig {
                pool_bytes: self.args.pool_mib.map(|m| m << 20),
                ..CacheConfig::default()
            },
            Colouring::draped_if(self.refiner.source().drape().is_some()),
        )?;
        eprintln!("cbdam view: {adapter_name}, surface {format:?}, {present_mode:?}");
        self.window = Some(WindowState {
            window,
            surface,
            config,
            renderer,
            hud,
            presenter,
            adapter: adapter_name,
        });
        Ok(())
    }

    fn resize(&mut self, size: PhysicalSize<u32>) {
        if let Some(ws) = &mut self.window
            && size.width > 0
            && size.height > 0
        {
            ws.config.width = size.width;
            ws.config.height = size.height;
            ws.surface.configure(&ws.renderer.gpu().device, &ws.config);
        }
    }

    /// One frame: move, refine, draw, overlay, present.
    fn frame(&mut self, event_loop: &ActiveEventLoop) -> Result<()> {
        let now = Instant::now();
        let dt = self
            .last_instant
            .map_or(0.0, |t| now.duration_since(t).as_secs_f64());
        self.last_instant = Some(now);
        let Some(ws) = &mut self.window else {
            return Ok(());
        };
        let size = (ws.config.width, ws.config.height);
        self.gestures
            .apply(&mut self.controls, &mut self.keys, size.1, dt);
        let cam = self.controls.camera(&self.world, size);
        self.options.wireframe = self.toggles.wireframe;
        self.options.level_colours = self.toggles.levels;
        if !self.toggles.frozen {
            self.last_refine = self.refiner.frame(&cam);
            self.patches.clear();
            self.patches.extend(self.refiner.drawn().cloned());
        }
        let (mut encoder, draw) = ws.renderer.encode(&cam, &self.patches, &self.options)?;
        self.last_draw = draw;
        self.count_frame(dt, draw.triangles);
        let lines = if self.toggles.hud {
            hud_text::lines(&hud_figures(self, size))
        } else {
            Vec::new()
        };
        let Some(ws) = &mut self.window else {
            return Ok(());
        };
        let color = ws
            .renderer
            .color_texture()
            .expect("encode made the target")
            .clone();
        let view = color.create_view(&Default::default());
        let gpu = ws.renderer.gpu();
        let quads = hud::layout(&lines, size, hud::scale_for(size));
        ws.hud
            .draw(&gpu.device, &gpu.queue, &mut encoder, &view, size, &quads);
        present(ws, encoder, &color, size)?;
        self.frames += 1;
        let done = self.args.max_frames.is_some_and(|n| self.frames >= n);
        if std::mem::take(&mut self.screenshot_now) {
            let path = next_screenshot_path();
            write_png(&path, &ws.renderer.read_color()?)?;
            println!("saved {}", path.display());
        }
        if done {
            event_loop.exit();
        }
        Ok(())
    }

    /// Counts a frame `dt` seconds after the last one, of `triangles` (HUD and summary).
    fn count_frame(&mut self, dt: f64, triangles: u64) {
        if self.frames > 0 {
            self.frame_times.push_back(dt);
            self.all_frame_times.push(dt);
            self.triangles.push(triangles);
            if self.frame_times.len() > FPS_WINDOW {
                self.frame_times.pop_front();
            }
        }
    }

    /// Saves `--screenshot` (when asked) from the last frame drawn.
    fn finish(&mut self) -> Result<()> {
        if let (Some(path), Some(ws)) = (&self.args.screenshot, &self.window)
            && ws.renderer.color_texture().is_some()
        {
            write_png(path, &ws.renderer.read_color()?)?;
            println!("saved {}", path.display());
        }
        Ok(())
    }

    fn summary(&self) {
        let mut times = self.all_frame_times.clone();
        times.sort_by(f64::total_cmp);
        let mut tris = self.triangles.clone();
        tris.sort_unstable();
        if times.is_empty() {
            return;
        }
        let median = percentile(&times, 0.5);
        let tri = percentile(&tris, 0.5);
        println!(
            "{} frames at {}×{}, target {} px: frame ms median {:.2}, p99 {:.2}; triangles per \
             frame median {}; {:.1} M triangles/s (median triangles / median frame time)",
            self.frames,
            self.window.as_ref().map_or(0, |w| w.config.width),
            self.window.as_ref().map_or(0, |w| w.config.height),
            self.refiner.config().pixel_error,
            median * 1e3,
            percentile(&times, 0.99) * 1e3,
            tri,
            tri as f64 / median / 1e6,
        );
    }

    /// A key going down or up, named as the viewer core names keys (W3C codes and values).
    fn key(&mut self, event_loop: &ActiveEventLoop, key: &Key, code: PhysicalKey, down: bool) {
        // winit's key codes and named keys carry the W3C names.
        let code = match code {
            PhysicalKey::Code(c) => format!("{c:?}"),
            PhysicalKey::Unidentified(_) => String::new(),
        };
        if self.keys.set(&code, down) || !down {
            return;
        }
        let key = match key {
            Key::Character(c) => c.to_string(),
            Key::Named(named) => format!("{named:?}"),
            _ => String::new(),
        };
        let Some(action) = action_for_key(&code, &key) else {
            return;
        };
        let wireframe_supported = self.window.as_ref().is_some_and(|ws| {
            let features = ws.renderer.gpu().device.features();
            features.contains(wgpu::Features::POLYGON_MODE_LINE)
        });
        let (controls, refiner) = (&mut self.controls, &mut self.refiner);
        match self
            .toggles
            .act(action, controls, refiner, wireframe_supported)
        {
            Effect::Quit => event_loop.exit(),
            Effect::Screenshot => self.screenshot_now = true,
            Effect::NoWireframe => eprintln!("cbdam view: this adapter cannot draw a wireframe"),
            Effect::None | Effect::CutChanged => {}
        }
    }
}

impl<S: DataSource> ApplicationHandler for App<'_, S> {
    fn resumed(&mut self, event_loop: &ActiveEventLoop) {
        if self.window.is_none()
            && let Err(e) = self.open_window(event_loop)
        {
            self.error = Some(e);
            event_loop.exit();
        }
    }

    fn window_event(&mut self, event_loop: &ActiveEventLoop, _: WindowId, event: WindowEvent) {
        match event {
            WindowEvent::CloseRequested => event_loop.exit(),
            WindowEvent::Resized(size) => self.resize(size),
            WindowEvent::RedrawRequested => {
                if let Err(e) = self.frame(event_loop) {
                    self.error = Some(e);
                    event_loop.exit();
                }
            }
            // Auto-repeat would step the pixel error or toggle modes many times per press.
            WindowEvent::KeyboardInput { event, .. }
                if !event.repeat || event.state == ElementState::Released =>
            {
                self.key(
                    event_loop,
                    &event.logical_key,
                    event.physical_key,
                    event.state == ElementState::Pressed,
                );
            }
            WindowEvent::MouseInput { state, button, .. } => {
                let down = state == ElementState::Pressed;
                match (self.controls.mode(), button) {
                    (Mode::Orbit, MouseButton::Right | MouseButton::Middle) => {
                        self.mouse.panning = down
                    }
                    _ => self.mouse.rotating = down,
                }
            }
            WindowEvent::CursorMoved { position, .. } => {
                let now = (position.x, position.y);
                if let Some((x, y)) = self.mouse.cursor
                    && (self.mouse.panning || self.mouse.rotating)
                {
                    self.gestures.drag(now.0 - x, now.1 - y, self.mouse.panning);
                }
                self.mouse.cursor = Some(now);
            }
            WindowEvent::MouseWheel { delta, .. } => {
                let steps = match delta {
                    MouseScrollDelta::LineDelta(_, y) => f64::from(y),
                    MouseScrollDelta::PixelDelta(p) => p.y / 40.0,
                };
                self.gestures.zoom += steps;
            }
            _ => {}
        }
    }

    fn about_to_wait(&mut self, _: &ActiveEventLoop) {
        if let Some(ws) = &self.window {
            ws.window.request_redraw();
        }
    }

    fn exiting(&mut self, _: &ActiveEventLoop) {
        if self.error.is_none()
            && let Err(e) = self.finish()
        {
            self.error = Some(e);
        }
    }
}

/// Submits `encoder` and presents `color` (the frame and its HUD) on the window's surface.
fn present(
    ws: &mut WindowState,
    mut encoder: wgpu::CommandEncoder,
    color: &wgpu::Texture,
    size: (u32, u32),
) -> Result<()> {
    let gpu = ws.renderer.gpu();
    let surface_texture = match ws.surface.get_current_texture() {
        wgpu::CurrentSurfaceTexture::Success(t) | wgpu::CurrentSurfaceTexture::Suboptimal(t) => {
            Some(t)
        }
        wgpu::CurrentSurfaceTexture::Timeout | wgpu::CurrentSurfaceTexture::Occluded => None,
        wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
            ws.surface.configure(&gpu.device, &ws.config);
            None
        }
        other => bail!("the window's surface failed: {other:?}"),
    };
    // The frame's commands are submitted even when there is nothing to present on: they
    // hold the height uploads the patch cache now counts as resident.
    if let Some(t) = &surface_texture {
        // A resize between encoding and acquiring: skip presenting this frame.
        if (t.texture.width(), t.texture.height()) == size {
            let target = t.texture.create_view(&Default::default());
            ws.presenter.draw(&gpu.device, &mut encoder, color, &target);
        }
    }
    gpu.queue.submit([encoder.finish()]);
    if let Some(t) = surface_texture {
        ws.window.pre_present_notify();
        gpu.queue.present(t);
    }
    Ok(())
}

/// The window surface's configuration: its first format, vsync unless `no_vsync` (and the
/// surface can present without it).
fn surface_config(
    caps: &wgpu::SurfaceCapabilities,
    size: PhysicalSize<u32>,
    no_vsync: bool,
) -> Result<wgpu::SurfaceConfiguration> {
    let format = *caps
        .formats
        .first()
        .ok_or_else(|| anyhow!("the window's surface offers no texture format"))?;
    let present_mode = if no_vsync {
        [wgpu::PresentMode::Immediate, wgpu::PresentMode::Mailbox]
            .into_iter()
            .find(|m| caps.present_modes.contains(m))
            .unwrap_or_else(|| {
                eprintln!("cbdam: warning: this surface cannot present without vsync");
                wgpu::PresentMode::Fifo
            })
    } else {
        wgpu::PresentMode::Fifo
    };
    Ok(wgpu::SurfaceConfiguration {
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        format,
        width: size.width.max(1),
        height: size.height.max(1),
        present_mode,
        desired_maximum_frame_latency: 2,
        alpha_mode: caps.alpha_modes.first().copied().unwrap_or_default(),
        view_formats: vec![],
        color_space: wgpu::SurfaceColorSpace::Auto,
    })
}

/// The HUD's figures of this frame.
fn hud_figures<'a, S: DataSource>(app: &'a App<'_, S>, size: (u32, u32)) -> hud_text::Figures<'a> {
    let mut sorted: Vec<f64> = app.frame_times.iter().copied().collect();
    sorted.sort_by(f64::total_cmp);
    let ws = app.window.as_ref();
    hud_text::Figures {
        size,
        mode: app.controls.mode(),
        adapter: ws.map_or("", |w| w.adapter.as_str()),
        frame_s: if sorted.is_empty() {
            0.0
        } else {
            percentile(&sorted, 0.5)
        },
        draw: app.last_draw,
        refine: app.last_refine,
        pixel_error: app.refiner.config().pixel_error,
        frozen: app.toggles.frozen,
        cpu: app.refiner.cache_use(),
        gpu: ws.map(|w| {
            let cache = w.renderer.cache();
            hud_text::GpuCache {
                resident: cache.resident(),
                capacity: cache.capacity(),
                stats: cache.stats(),
            }
        }),
        remote: app.remote,
    }
}

/// `cbdam-view-0001.png`, `…0002.png`, …: the first name not taken in the working directory.
fn next_screenshot_path() -> PathBuf {
    (1..)
        .map(|i| PathBuf::from(format!("cbdam-view-{i:04}.png")))
        .find(|p| !p.exists())
        .expect("some name is free")
}
