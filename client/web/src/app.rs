//! The viewer on a canvas: connects to the repository, finds a WebGPU adapter (or, built with
//! the `webgl` feature, a WebGL2 one where the browser has no WebGPU), and each
//! animation frame applies the input (`input.rs`), runs one step of the refinement loop
//! within its budget (records arrive between frames; nothing blocks), draws the cut offscreen and
//! copies it onto the canvas.

use std::cell::{Cell, RefCell};
use std::collections::VecDeque;
use std::rc::Rc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use cbdam_client::access::{ColouredSource, DataSource, RemoteSource};
use cbdam_client::camera::Camera;
use cbdam_client::controls::{Controls, Mode};
use cbdam_client::fetch::FetchOptions;
use cbdam_client::patch::HalfPatch;
use cbdam_client::refine::{FrameStats, HeadBytes, RefineConfig, Refiner};
use cbdam_client::viewer::{Action, Effect, Toggles};
use cbdam_client::world::World;
use cbdam_render::present::Presenter;
use cbdam_render::{CacheConfig, Colouring, Gpu, RenderOptions, Renderer, VertexFetch};
use glam::DVec3;
use wasm_bindgen::JsCast;
use wasm_bindgen::closure::Closure;
use wasm_bindgen::prelude::wasm_bindgen;
use web_sys::HtmlCanvasElement;

use crate::flight::{self, Playback};
use crate::input::Input;
use crate::status::Status;
use crate::workers::{WorkerPool, worker_count};

/// Refinement time per frame on the page's thread (applying the workers' results; decoding too
/// when no worker runs): leaves most of a 60 Hz frame to drawing and the browser.
const REFINE_BUDGET: Duration = Duration::from_millis(8);
/// GPU height pool: about 3 900 patches of 65²; browsers limit a storage binding to 128 MiB
/// by default. On WebGL2 the pool texture may hold less (2048 words a row, as many rows as the
/// largest texture side: 64 MiB at 8192).
const POOL_BYTES: u64 = 64 << 20;

/// What a browser needs to show terrain (after what it offers instead).
const NEEDS: &str = if cfg!(feature = "webgl") {
    "the viewer draws through WebGPU or WebGL2: use a browser with either (any recent Chrome, \
     Edge, Firefox or Safari), with hardware acceleration or WebGL turned on"
} else {
    "this build of the viewer draws through WebGPU only (built without its `webgl` feature): \
     use a browser with WebGPU, such as a recent Chrome or Edge, or Firefox or Safari with \
     WebGPU turned on"
};
/// Frames the frame rate's median spans.
const FPS_WINDOW: usize = 60;

/// GPU errors reported outside an error scope, collected for the status (the handler must be
/// `Send + Sync`; the page has one thread).
static GPU_ERRORS: Mutex<Vec<String>> = Mutex::new(Vec::new());

/// Starts the viewer on `canvas` for the repository at `repo_url` (absolute: a `.cbdam` file on
/// a server with Range support, or a `cbdam serve` repository), with the colour repository at
/// `colour_url` draped over it if given (`cbdam build IMAGE --colour --like REPO`), decoding in
/// Web Workers started from `worker_script` (the URL of `worker.js`; `None`: decode on the
/// page). Returns at once; progress and errors go to `window.cbdam` ([`Status`]).
#[wasm_bindgen]
pub fn start(
    canvas: HtmlCanvasElement,
    repo_url: String,
    worker_script: Option<String>,
    colour_url: Option<String>,
) {
    let status = Status::install();
    install_panic_hook(status.clone());
    wasm_bindgen_futures::spawn_local(async move {
        let urls = (repo_url.as_str(), colour_url.as_deref());
        match App::new(canvas, urls, worker_script.as_deref(), status.clone()).await {
            Ok(app) => run(Rc::new(RefCell::new(app))),
            Err(message) => status.fail(&message),
        }
    });
}

thread_local! {
    /// The page's status, for the panic hook (which must be `Send + Sync`).
    static PAGE_STATUS: RefCell<Option<Status>> = const { RefCell::new(None) };
    /// A pixel-error target set by the page (its slider), applied at the next frame.
    static PIXEL_ERROR_REQUEST: Cell<Option<f64>> = const { Cell::new(None) };
}

/// Sets the pixel-error target (pixels, 1/64 to 256) from the page, e.g. its slider; the
/// status's `pixelError` shows the value in use.
#[wasm_bindgen]
pub fn set_pixel_error(pixels: f64) {
    if pixels.is_finite() && pixels > 0.0 {
        PIXEL_ERROR_REQUEST.with(|r| r.set(Some(pixels.clamp(1.0 / 64.0, 256.0))));
    }
}

/// Whether the browser gives a WebGL2 context (on a canvas of its own: the viewer's canvas
/// must stay free for WebGPU).
fn has_webgl2() -> bool {
    web_sys::window()
        .and_then(|w| w.document())
        .and_then(|d| d.create_element("canvas").ok())
        .and_then(|c| c.dyn_into::<HtmlCanvasElement>().ok())
        .and_then(|c| c.get_context("webgl2").ok().flatten())
        .is_some()
}

/// The message for a browser without an adapter this build can draw with.
fn no_adapter_message() -> String {
    if has_webgl2() {
        format!("this browser offers WebGL2 but no WebGPU adapter; {NEEDS}")
    } else {
        format!("this browser offers neither WebGPU nor WebGL2; {NEEDS}")
    }
}

/// A panic ends the module: say why on the page and the console.
fn install_panic_hook(status: Status) {
    PAGE_STATUS.with(|s| *s.borrow_mut() = Some(status));
    std::panic::set_hook(Box::new(|info| {
        let message = format!("internal error: {info}");
        PAGE_STATUS.with(|s| match s.try_borrow().ok().as_deref() {
            Some(Some(status)) => status.fail(&message),
            _ => web_sys::console::error_1(&message.into()),
        });
    }));
}

struct App {
    canvas: HtmlCanvasElement,
    status: Status,
    world: World,
    /// Over the repository alone, or over it and a draped colour repository.
    refiner: Refiner<Box<dyn DataSource>, WorkerPool>,
    /// Where the refiner's decode jobs run (a clone of its spawner), for the status.
    workers: WorkerPool,
    renderer: Renderer,
    presenter: Presenter,
    surface: wgpu::Surface<'static>,
    config: wgpu::SurfaceConfiguration,
    controls: Controls,
    input: Input,
    options: RenderOptions,
    patches: Vec<Arc<HalfPatch>>,
    frames: u64,
    /// Whether the cut was reported converged for the current camera.
    reported_converged: bool,
    /// The page's switches (F freezes refinement: the camera still moves).
    toggles: Toggles,
    last_stats: FrameStats,
    /// The camera of the last frame, for refinement steps between frames.
    last_camera: Option<Camera>,
    /// Since the page started: diamonds decoded (in workers or on the page) and their decode
    /// time where they ran, ms; the page's time in the refinement step, ms, total and largest.
    decoded: u64,
    decode_ms: f64,
    refine_ms: f64,
    refine_ms_max: f64,
    /// `performance.now()` of the last frame, and the intervals between the last frames.
    last_frame_ms: Option<f64>,
    intervals_ms: VecDeque<f64>,
    /// A camera flight being played (`flight.rs`): it moves the camera instead of the controls.
    playback: Option<Playback>,
}

impl App {
    async fn new(
        canvas: HtmlCanvasElement,
        urls: (&str, Option<&str>),
        worker_script: Option<&str>,
        status: Status,
    ) -> Result<Self, String> {
        status.set("phase", "connecting");
        let (refiner, workers) = connect(urls, worker_script, &status).await?;
        let world = *refiner.world();
        let (gpu, surface, config) = open_canvas(&canvas, &status).await?;
        let presenter = Presenter::new(&gpu.device, config.format);
        let cache = CacheConfig {
            pool_bytes: Some(POOL_BYTES),
            ..CacheConfig::default()
        };
        let draped = refiner.source().drape().is_some();
        let renderer = Renderer::with_colour(gpu, world, cache, Colouring::draped_if(draped))
            .map_err(|e| e.to_string())?;
        // Storage buffers (WebGPU) or the texture path (WebGL2, no storage in vertex shaders).
        status.set(
            "vertexFetch",
            match renderer.vertex_fetch() {
                VertexFetch::Texture => "texture",
                _ => "storage",
            },
        );
        let size = (config.width, config.height);
        let start = match camera_from_hash() {
            // 45°, as `Camera::framed` and `cbdam render --camera`: the same hash gives the same
            // view and cut as the command line's camera.
            Some((eye, target)) => {
                Camera::looking_at(&world, eye, target, 45f64.to_radians(), size)
            }
            None => Camera::framed(&world, size),
        };
        let controls = Controls::new(&world, &start);
        let input = Input::listen(&canvas);
        status.set("phase", "running");
        Ok(Self {
            canvas,
            status,
            world,
            refiner,
            workers,
            renderer,
            presenter,
            surface,
            config,
            controls,
            input,
            options: RenderOptions::default(),
            patches: Vec::new(),
            frames: 0,
            reported_converged: false,
            toggles: Toggles::default(),
            last_stats: FrameStats::default(),
            last_camera: None,
            decoded: 0,
            decode_ms: 0.0,
            refine_ms: 0.0,
            refine_ms_max: 0.0,
            last_frame_ms: None,
            intervals_ms: VecDeque::new(),
            playback: None,
        })
    }

    /// One animation frame.
    fn frame(&mut self) -> Result<(), String> {
        let size = canvas_size(&self.canvas);
        let device = self.renderer.gpu().device.clone();
        if size != (self.config.width, self.config.height) {
            self.config.width = size.0;
            self.config.height = size.1;
            self.surface.configure(&device, &self.config);
        }
        let now = now_ms();
        let dt_ms = self.last_frame_ms.map_or(0.0, |t| now - t);
        self.last_frame_ms = Some(now);
        if self.frames > 0 {
            self.intervals_ms.push_back(dt_ms);
            if self.intervals_ms.len() > FPS_WINDOW {
                self.intervals_ms.pop_front();
            }
        }
        let camera = self.move_camera(size, dt_ms / 1e3, now);
        self.last_camera = Some(camera);
        self.refine(&camera);
        if self.playback.is_some() {
            self.flown(&camera, dt_ms, now);
        }
        let stats = self.last_stats;
        let (encoder, draw) = self
            .renderer
            .encode(&camera, &self.patches, &self.options)
            .map_err(|e| e.to_string())?;
        self.present(encoder, size)?;
        self.frames += 1;
        self.report(&stats, &camera, draw.triangles);
        let errors = std::mem::take(&mut *GPU_ERRORS.lock().map_err(|e| e.to_string())?);
        if let Some(first) = errors.first() {
            return Err(format!("GPU error: {first}"));
        }
        Ok(())
    }

    /// Carries out a key's action; whether it changes the cut to converge to.
    fn act(&mut self, action: Action) -> bool {
        let features = self.renderer.gpu().device.features();
        let wireframe = features.contains(wgpu::Features::POLYGON_MODE_LINE);
        let effect = self
            .toggles
            .act(action, &mut self.controls, &mut self.refiner, wireframe);
        self.options.wireframe = self.toggles.wireframe;
        self.options.level_colours = self.toggles.levels;
        if effect == Effect::NoWireframe {
            self.status
                .set("notice", "this browser's adapter cannot draw a wireframe");
        }
        effect == Effect::CutChanged
    }

    /// Moves the camera by the input since the last frame (`dt` seconds, the clock at `now`
    /// ms) or the flight being played; whether the cut to converge to changed is remembered
    /// for the status, and a camera the user moved goes to the page's address.
    fn move_camera(&mut self, size: (u32, u32), dt: f64, now: f64) -> Camera {
        let (moved, actions) = self.input.apply(&mut self.controls, size.1, dt);
        let mut changed = moved;
        if let Some(requested) = flight::requested() {
            self.playback = Some(requested);
        }
        // Moving the camera by hand ends a flight; the controls go on from where it was.
        if moved && let Some(playback) = self.playback.take() {
            if let Some(camera) = &self.last_camera {
                self.controls = Controls::new(&self.world, camera);
            }
            self.status
                .set_object("flight", &playback.status(now, true));
        }
        for action in actions {
            changed |= self.act(action);
        }
        if let Some(px) = PIXEL_ERROR_REQUEST.with(Cell::take) {
            self.refiner.set_pixel_error(px);
            changed = true;
        }
        let camera = match &self.playback {
            Some(playback) => {
                changed = true;
                playback.camera(&self.world, size)
            }
            None => self.controls.camera(&self.world, size),
        };
        if changed {
            self.reported_converged = false;
        }
        if moved {
            camera_to_hash(&camera);
        }
        camera
    }

    /// Draws the frame's colour target onto the canvas and submits `encoder`.
    fn present(
        &mut self,
        mut encoder: wgpu::CommandEncoder,
        size: (u32, u32),
    ) -> Result<(), String> {
        let device = self.renderer.gpu().device.clone();
        let color = self
            .renderer
            .color_texture()
            .ok_or("the renderer made no colour target")?
            .clone();
        let surface_texture = match self.surface.get_current_texture() {
            wgpu::CurrentSurfaceTexture::Success(t)
            | wgpu::CurrentSurfaceTexture::Suboptimal(t) => Some(t),
            wgpu::CurrentSurfaceTexture::Outdated | wgpu::CurrentSurfaceTexture::Lost => {
                self.surface.configure(&device, &self.config);
                None
            }
            _ => None,
        };
        if let Some(t) = &surface_texture
            && (t.texture.width(), t.texture.height()) == size
        {
            let target = t.texture.create_view(&Default::default());
            self.presenter.draw(&device, &mut encoder, &color, &target);
        }
        let queue = &self.renderer.gpu().queue;
        // Submitted even without a texture to present on: the frame's height uploads are in it.
        queue.submit([encoder.finish()]);
        if let Some(t) = surface_texture {
            queue.present(t);
        }
        Ok(())
    }

    /// One step of the refinement loop for `camera` (unless frozen): the cut and its patches.
    fn refine(&mut self, camera: &Camera) {
        if self.toggles.frozen {
            return;
        }
        self.last_stats = self.refiner.frame(camera);
        let st = &self.last_stats;
        self.decoded += st.decoded as u64;
        self.decode_ms += st.decode_ms;
        self.refine_ms += st.refine_ms;
        self.refine_ms_max = self.refine_ms_max.max(st.refine_ms);
        self.patches.clear();
        self.patches.extend(self.refiner.drawn().cloned());
    }

    /// Records the flight's frame just refined for `camera`; at the flight's end the controls
    /// take over from its last camera, which goes into the URL's hash.
    fn flown(&mut self, camera: &Camera, interval_ms: f64, now: f64) {
        let Some(playback) = &mut self.playback else {
            return;
        };
        let st = &self.last_stats;
        // Timed, not the step's `budget_exhausted`: a step on the page never waits for the
        // workers, so it also ends "exhausted" whenever decodes are still out.
        let over_budget = st.refine_ms > REFINE_BUDGET.as_secs_f64() * 1e3;
        playback.flown(
            st.refine_ms,
            over_budget,
            st.max_screen_error_px,
            interval_ms,
            now,
        );
        self.status
            .set_object("flight", &playback.status(now, false));
        if playback.finished() {
            self.playback = None;
            self.controls = Controls::new(&self.world, camera);
            camera_to_hash(camera);
        }
    }

    /// A refinement step between animation frames, when a worker's answer arrived: it is
    /// applied (and what it unblocks handed to the workers) now rather than at the next frame,
    /// which on a slow page is hundreds of milliseconds away. The next frame draws the result.
    fn refine_between_frames(&mut self) {
        if let Some(camera) = self.last_camera {
            self.refine(&camera);
        }
    }

    fn report(&mut self, stats: &FrameStats, camera: &Camera, triangles: u64) {
        let s = &self.status;
        let now = now_ms();
        if self.frames == 1 {
            s.set("firstFrameMs", now);
        }
        let mut sorted: Vec<f64> = self.intervals_ms.iter().copied().collect();
        sorted.sort_by(f64::total_cmp);
        if let Some(&median) = sorted.get(sorted.len() / 2)
            && median > 0.0
        {
            s.set("fps", 1e3 / median);
            s.set("frameMs", median);
        }
        s.set("pixelError", self.refiner.config().pixel_error);
        s.set(
            "mode",
            match self.controls.mode() {
                Mode::Orbit => "orbit",
                Mode::Fly => "fly",
            },
        );
        s.set("frozen", self.toggles.frozen);
        s.set("levels", self.options.level_colours);
        s.set("wireframe", self.options.wireframe);
        self.report_resources(stats);
        self.report_cut(stats, camera, triangles, now);
    }

    /// The status's caches, fetches and workers.
    fn report_resources(&self, stats: &FrameStats) {
        let s = &self.status;
        let c = self.refiner.cache_use();
        s.set_numbers(
            "cpuCache",
            &[
                c.record_bytes as f64,
                c.record_budget as f64,
                c.decoded_bytes as f64,
                c.decoded_budget as f64,
            ],
        );
        let gpu_cache = self.renderer.cache();
        s.set_numbers(
            "gpuCache",
            &[gpu_cache.resident() as f64, f64::from(gpu_cache.capacity())],
        );
        s.set("inFlight", stats.access.in_flight as f64);
        s.set("decoded", self.decoded as f64);
        s.set("decodeMs", self.decode_ms);
        s.set_numbers("refineMs", &[self.refine_ms, self.refine_ms_max]);
        let w = self.workers.status();
        s.set_object(
            "workers",
            &[
                ("count", (w.count as f64).into()),
                ("ready", (w.ready as f64).into()),
                ("decoded", (w.decoded as f64).into()),
                ("busyMs", w.busy_ms.into()),
                ("onPage", (w.on_page as f64).into()),
                ("problem", w.problem.unwrap_or_default().into()),
            ],
        );
        s.set("recordsRequested", stats.access.requests_issued as f64);
        s.set("bytes", stats.access.bytes_fetched as f64);
        s.set("fetchErrors", stats.access.errors as f64);
    }

    /// The status's cut and camera; the cut once it converged.
    fn report_cut(&mut self, stats: &FrameStats, camera: &Camera, triangles: u64, now: f64) {
        let s = &self.status;
        s.set("frames", self.frames as f64);
        s.set("refined", stats.refined as f64);
        s.set("drawnHalves", stats.drawn_halves as f64);
        s.set("triangles", triangles as f64);
        s.set("maxErrorPx", stats.max_screen_error_px);
        s.set("converged", stats.converged);
        s.set_numbers(
            "camera",
            &[
                camera.eye.x,
                camera.eye.y,
                camera.eye.z,
                camera.target.x,
                camera.target.y,
                camera.target.z,
            ],
        );
        if stats.converged && !self.reported_converged {
            self.reported_converged = true;
            s.set("convergedMs", now);
            let mut cut: Vec<String> = self
                .refiner
                .cut()
                .refined()
                .map(|id| id.to_string())
                .collect();
            cut.sort();
            s.set_strings("cut", &cut);
        }
    }
}

/// Connects to the elevation repository (and the colour one draped over it) and starts the
/// refiner, its decode workers running `worker_script` where one is given.
async fn connect(
    (repo_url, colour_url): (&str, Option<&str>),
    worker_script: Option<&str>,
    status: &Status,
) -> Result<(Refiner<Box<dyn DataSource>, WorkerPool>, WorkerPool), String> {
    let elevation = RemoteSource::connect(repo_url, FetchOptions::default())
        .await
        .map_err(|e| format!("cannot read the repository: {e}"))?;
    // The heads the decode workers are set up from, kept: the sources move into the refiner.
    let head = |s: &RemoteSource| {
        let h = s.head_bytes();
        (h.bytes.to_vec(), h.file_len)
    };
    let elevation_head = head(&elevation);
    let (source, colour_head): (Box<dyn DataSource>, _) = match colour_url {
        None => (Box::new(elevation), None),
        Some(url) => {
            let colour = RemoteSource::connect(url, FetchOptions::default())
                .await
                .map_err(|e| format!("cannot read the colour repository: {e}"))?;
            let colour_head = head(&colour);
            let paired = ColouredSource::new(elevation, colour).map_err(|e| {
                format!("cannot drape the colour repository {url} over the terrain: {e}")
            })?;
            (Box::new(paired), Some(colour_head))
        }
    };
    status.set("draped", colour_head.is_some());
    let config = RefineConfig {
        budget: Some(REFINE_BUDGET),
        ..RefineConfig::default()
    };
    let workers = WorkerPool::new();
    let refiner = Refiner::with_spawner(source, config, workers.clone())
        .map_err(|e| format!("cannot decode the repository's root: {e}"))?;
    // The same module as the page's (this build's), in each worker.
    let module = if cfg!(feature = "webgl") {
        "cbdam_web_gl"
    } else {
        "cbdam_web"
    };
    if let Some(script) = worker_script {
        let context = refiner.worker_context(
            head_bytes(&elevation_head),
            colour_head.as_ref().map(head_bytes),
        );
        workers.start(script, module, &context, worker_count());
    }
    Ok((refiner, workers))
}

/// Opens the GPU (WebGPU, else WebGL2 in the `webgl` build) and configures the canvas for it.
async fn open_canvas(
    canvas: &HtmlCanvasElement,
    status: &Status,
) -> Result<(Gpu, wgpu::Surface<'static>, wgpu::SurfaceConfiguration), String> {
    // Always false in a module built without the `webgpu` feature (the WebGL2 one, which
    // main.js loads only where the browser has no WebGPU adapter): it cannot use WebGPU.
    let webgpu = wgpu::util::is_browser_webgpu_supported().await;
    status.set("webgpu", webgpu);
    if !webgpu {
        let webgl2 = has_webgl2();
        status.set("webgl2", webgl2);
        if !webgl2 || !cfg!(feature = "webgl") {
            return Err(no_adapter_message());
        }
    }
    let mut desc = wgpu::InstanceDescriptor::new_without_display_handle();
    desc.backends = wgpu::Backends::BROWSER_WEBGPU | wgpu::Backends::GL;
    let instance = wgpu::util::new_instance_with_webgpu_detection(desc).await;
    let surface = instance
        .create_surface(wgpu::SurfaceTarget::Canvas(canvas.clone()))
        .map_err(|e| format!("cannot draw on the canvas: {e}"))?;
    let adapter = instance
        .request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: Some(&surface),
            apply_limit_buckets: false,
        })
        .await
        .map_err(|e| format!("{} ({e})", no_adapter_message()))?;
    let info = adapter.get_info();
    let backend = match info.backend {
        wgpu::Backend::BrowserWebGpu => "webgpu",
        wgpu::Backend::Gl => "webgl",
        _ => "other",
    };
    status.set("backend", backend);
    status.set("adapter", info.name.as_str());
    let gpu = Gpu::from_adapter_async(&adapter)
        .await
        .map_err(|e| e.to_string())?;
    gpu.device.on_uncaptured_error(Arc::new(|e: wgpu::Error| {
        if let Ok(mut errors) = GPU_ERRORS.lock() {
            errors.push(e.to_string());
        }
    }));
    let config = surface_config(&surface.get_capabilities(&adapter), canvas_size(canvas))?;
    surface.configure(&gpu.device, &config);
    Ok((gpu, surface, config))
}

/// The canvas surface's configuration for `size`.
fn surface_config(
    caps: &wgpu::SurfaceCapabilities,
    size: (u32, u32),
) -> Result<wgpu::SurfaceConfiguration, String> {
    // A non-sRGB format: WebGPU offers Rgba8Unorm/Bgra8Unorm first, WebGL Rgba8UnormSrgb,
    // which would show the offscreen image's bytes lighter.
    let format = caps
        .formats
        .iter()
        .copied()
        .find(|f| !f.is_srgb())
        .or_else(|| caps.formats.first().copied())
        .ok_or("the canvas offers no texture format")?;
    Ok(wgpu::SurfaceConfiguration {
        usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
        format,
        width: size.0,
        height: size.1,
        present_mode: wgpu::PresentMode::Fifo,
        desired_maximum_frame_latency: 2,
        alpha_mode: caps.alpha_modes.first().copied().unwrap_or_default(),
        view_formats: vec![],
        color_space: wgpu::SurfaceColorSpace::Auto,
    })
}

/// The animation-frame callback, shared with itself so it can ask for the next frame.
type FrameCallback = Rc<RefCell<Option<Closure<dyn FnMut()>>>>;

/// Runs `app`'s frames on `requestAnimationFrame` until one fails.
fn run(app: Rc<RefCell<App>>) {
    let weak = Rc::downgrade(&app);
    app.borrow().workers.on_answer(Rc::new(move || {
        if let Some(app) = weak.upgrade()
            && let Ok(mut app) = app.try_borrow_mut()
        {
            app.refine_between_frames();
        }
    }));
    let callback: FrameCallback = Rc::new(RefCell::new(None));
    let again = callback.clone();
    *callback.borrow_mut() = Some(Closure::new(move || {
        let result = app.borrow_mut().frame();
        match result {
            Ok(()) => request_frame(again.borrow().as_ref().expect("set before the first frame")),
            // No next frame: the loop ends.
            Err(message) => app.borrow().status.fail(&message),
        }
    }));
    request_frame(callback.borrow().as_ref().expect("just set"));
}

fn request_frame(callback: &Closure<dyn FnMut()>) {
    if let Some(window) = web_sys::window() {
        let _ = window.request_animation_frame(callback.as_ref().unchecked_ref());
    }
}

/// A repository's head as the decode workers' context takes it: its bytes and the file's
/// length.
fn head_bytes((bytes, file_len): &(Vec<u8>, u64)) -> HeadBytes<'_> {
    HeadBytes {
        bytes,
        file_len: *file_len,
    }
}

/// The canvas's drawing buffer size (at least 1×1).
fn canvas_size(canvas: &HtmlCanvasElement) -> (u32, u32) {
    (canvas.width().max(1), canvas.height().max(1))
}

/// The camera in the page URL's hash, `#camera=EX,EY,EZ,TX,TY,TZ` (eye and target, metres), so
/// a view can be shared as a link; `None` when there is none or it is not six finite numbers
/// with the eye apart from the target.
fn camera_from_hash() -> Option<(DVec3, DVec3)> {
    let hash = web_sys::window()?.location().hash().ok()?;
    let values = hash.strip_prefix("#camera=")?;
    let v: Vec<f64> = values
        .split(',')
        .map(|x| x.parse::<f64>().ok().filter(|x| x.is_finite()))
        .collect::<Option<_>>()?;
    let [ex, ey, ez, tx, ty, tz] = v[..] else {
        return None;
    };
    let (eye, target) = (DVec3::new(ex, ey, ez), DVec3::new(tx, ty, tz));
    (eye.distance(target) > 0.0).then_some((eye, target))
}

/// Writes `camera` into the URL's hash (replacing the history entry, so moving around does not
/// fill the back button's history); centimetres are plenty.
fn camera_to_hash(camera: &Camera) {
    let (e, t) = (camera.eye, camera.target);
    let hash = format!(
        "#camera={:.2},{:.2},{:.2},{:.2},{:.2},{:.2}",
        e.x, e.y, e.z, t.x, t.y, t.z
    );
    if let Some(history) = web_sys::window().and_then(|w| w.history().ok()) {
        let _ = history.replace_state_with_url(&wasm_bindgen::JsValue::NULL, "", Some(&hash));
    }
}

/// `performance.now()`, ms since the page's navigation began.
fn now_ms() -> f64 {
    web_sys::window()
        .and_then(|w| w.performance())
        .map_or(0.0, |p| p.now())
}
