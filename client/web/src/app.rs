//! The viewer on a canvas: connects to the repository, finds a WebGPU adapter, and each
//! animation frame applies the mouse, runs one step of the refinement loop within its budget
//! (records arrive between frames; nothing blocks), draws the cut offscreen and copies it onto
//! the canvas.

use std::cell::RefCell;
use std::rc::Rc;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use cbdam_client::access::RemoteSource;
use cbdam_client::camera::Camera;
use cbdam_client::controls::Controls;
use cbdam_client::fetch::FetchOptions;
use cbdam_client::patch::HalfPatch;
use cbdam_client::refine::{FrameStats, RefineConfig, Refiner};
use cbdam_client::spawn::Inline;
use cbdam_client::world::World;
use cbdam_render::present::Presenter;
use cbdam_render::{CacheConfig, Gpu, RenderOptions, Renderer};
use glam::DVec3;
use wasm_bindgen::JsCast;
use wasm_bindgen::closure::Closure;
use wasm_bindgen::prelude::wasm_bindgen;
use web_sys::HtmlCanvasElement;

use crate::input::Input;
use crate::status::Status;

/// Refinement time per frame on the page's thread (decoding included): leaves most of a 60 Hz
/// frame to drawing and the browser.
const REFINE_BUDGET: Duration = Duration::from_millis(8);
/// GPU height pool: about 3 900 patches of 65²; browsers limit a storage binding to 128 MiB
/// by default.
const POOL_BYTES: u64 = 64 << 20;

/// Why a browser without WebGPU cannot show terrain.
const NO_WEBGPU: &str = "this browser offers no WebGPU adapter, which the terrain renderer \
                         needs (WebGL2 is not supported yet): use a browser with WebGPU";

/// GPU errors reported outside an error scope, collected for the status (the handler must be
/// `Send + Sync`; the page has one thread).
static GPU_ERRORS: Mutex<Vec<String>> = Mutex::new(Vec::new());

/// Starts the viewer on `canvas` for the repository at `repo_url` (absolute: a `.cbdam` file on
/// a server with Range support, or a `cbdam serve` repository). Returns at once; progress and
/// errors go to `window.cbdam` ([`Status`]).
#[wasm_bindgen]
pub fn start(canvas: HtmlCanvasElement, repo_url: String) {
    let status = Status::install();
    install_panic_hook(status.clone());
    wasm_bindgen_futures::spawn_local(async move {
        match App::new(canvas, &repo_url, status.clone()).await {
            Ok(app) => run(Rc::new(RefCell::new(app))),
            Err(message) => status.fail(&message),
        }
    });
}

thread_local! {
    /// The page's status, for the panic hook (which must be `Send + Sync`).
    static PAGE_STATUS: RefCell<Option<Status>> = const { RefCell::new(None) };
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
    refiner: Refiner<RemoteSource, Inline>,
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
}

impl App {
    async fn new(
        canvas: HtmlCanvasElement,
        repo_url: &str,
        status: Status,
    ) -> Result<Self, String> {
        status.set("phase", "connecting");
        let source = RemoteSource::connect(repo_url, FetchOptions::default())
            .await
            .map_err(|e| format!("cannot read the repository: {e}"))?;
        let config = RefineConfig {
            budget: Some(REFINE_BUDGET),
            ..RefineConfig::default()
        };
        let refiner = Refiner::with_spawner(source, config, Inline)
            .map_err(|e| format!("cannot decode the repository's root: {e}"))?;
        let world = *refiner.world();

        let webgpu = wgpu::util::is_browser_webgpu_supported().await;
        status.set("webgpu", webgpu);
        if !webgpu && !cfg!(feature = "webgl") {
            return Err(NO_WEBGPU.into());
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
            .map_err(|e| format!("{NO_WEBGPU} ({e})"))?;
        let info = adapter.get_info();
        let backend = match info.backend {
            wgpu::Backend::BrowserWebGpu => "webgpu",
            wgpu::Backend::Gl => "webgl",
            _ => "other",
        };
        status.set("backend", backend);
        status.set("adapter", info.name.as_str());
        if adapter.limits().max_storage_buffers_per_shader_stage < 2
            || !adapter
                .get_downlevel_capabilities()
                .flags
                .contains(wgpu::DownlevelFlags::VERTEX_STORAGE)
        {
            return Err(format!(
                "this browser offers only {backend} ({}), without storage buffers in vertex \
                 shaders, which the terrain renderer needs: use a browser with WebGPU (WebGL2 \
                 support is not written yet)",
                info.name
            ));
        }
        let gpu = Gpu::from_adapter_async(&adapter)
            .await
            .map_err(|e| e.to_string())?;
        gpu.device.on_uncaptured_error(Arc::new(|e: wgpu::Error| {
            if let Ok(mut errors) = GPU_ERRORS.lock() {
                errors.push(e.to_string());
            }
        }));
        let caps = surface.get_capabilities(&adapter);
        // A non-sRGB format: WebGPU offers Rgba8Unorm/Bgra8Unorm first, WebGL Rgba8UnormSrgb,
        // which would show the offscreen image's bytes lighter.
        let format = caps
            .formats
            .iter()
            .copied()
            .find(|f| !f.is_srgb())
            .or_else(|| caps.formats.first().copied())
            .ok_or("the canvas offers no texture format")?;
        let size = canvas_size(&canvas);
        let config = wgpu::SurfaceConfiguration {
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT,
            format,
            width: size.0,
            height: size.1,
            present_mode: wgpu::PresentMode::Fifo,
            desired_maximum_frame_latency: 2,
            alpha_mode: caps.alpha_modes.first().copied().unwrap_or_default(),
            view_formats: vec![],
            color_space: wgpu::SurfaceColorSpace::Auto,
        };
        surface.configure(&gpu.device, &config);
        let presenter = Presenter::new(&gpu.device, format);
        let cache = CacheConfig {
            pool_bytes: Some(POOL_BYTES),
            ..CacheConfig::default()
        };
        let renderer = Renderer::new(gpu, world, cache).map_err(|e| e.to_string())?;
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
        let moved = self.input.apply(&mut self.controls, size.1);
        let camera = self.controls.camera(&self.world, size);
        if moved {
            self.reported_converged = false;
            camera_to_hash(&camera);
        }
        let stats = self.refiner.frame(&camera);
        self.patches.clear();
        self.patches.extend(self.refiner.drawn().cloned());
        let (mut encoder, draw) = self
            .renderer
            .encode(&camera, &self.patches, &self.options)
            .map_err(|e| e.to_string())?;
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
        self.frames += 1;
        self.report(&stats, &camera, draw.triangles);
        let errors = std::mem::take(&mut *GPU_ERRORS.lock().map_err(|e| e.to_string())?);
        if let Some(first) = errors.first() {
            return Err(format!("GPU error: {first}"));
        }
        Ok(())
    }

    fn report(&mut self, stats: &FrameStats, camera: &Camera, triangles: u64) {
        let s = &self.status;
        let now = now_ms();
        if self.frames == 1 {
            s.set("firstFrameMs", now);
        }
        s.set("frames", self.frames as f64);
        s.set("refined", stats.refined as f64);
        s.set("drawnHalves", stats.drawn_halves as f64);
        s.set("triangles", triangles as f64);
        s.set("maxErrorPx", stats.max_screen_error_px);
        s.set("converged", stats.converged);
        s.set("recordsRequested", stats.access.requests_issued as f64);
        s.set("bytes", stats.access.bytes_fetched as f64);
        s.set("fetchErrors", stats.access.errors as f64);
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

/// The animation-frame callback, shared with itself so it can ask for the next frame.
type FrameCallback = Rc<RefCell<Option<Closure<dyn FnMut()>>>>;

/// Runs `app`'s frames on `requestAnimationFrame` until one fails.
fn run(app: Rc<RefCell<App>>) {
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
