//! The GPU device the renderer draws with: headless (offscreen, tests) or on a window's or a
//! canvas's adapter.

use crate::DrawError;

/// A device and queue, with what the adapter is.
pub struct Gpu {
    /// The device.
    pub device: wgpu::Device,
    /// Its queue.
    pub queue: wgpu::Queue,
    /// Adapter name, driver, device type.
    pub info: wgpu::AdapterInfo,
    /// Whether vertex shaders can read (two) storage buffers (`DownlevelFlags::VERTEX_STORAGE`;
    /// not on WebGL2): [`VertexFetch::Auto`] draws through storage buffers when they can.
    pub vertex_storage: bool,
}

impl Gpu {
    /// A device without any window, the adapter wgpu's defaults pick (environment variables such
    /// as `WGPU_BACKEND` apply). Takes every limit the adapter offers (the height pool wants
    /// large storage buffers) and `POLYGON_MODE_LINE` when available (wireframe). Blocks: native
    /// targets only.
    #[cfg(not(target_arch = "wasm32"))]
    pub fn headless() -> Result<Self, DrawError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let adapter = pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
            power_preference: wgpu::PowerPreference::HighPerformance,
            force_fallback_adapter: false,
            compatible_surface: None,
            apply_limit_buckets: false,
        }))
        .map_err(|e| DrawError::NoAdapter(e.to_string()))?;
        Self::from_adapter(&adapter)
    }

    /// A device on `adapter`. Blocks: native targets only (a browser awaits
    /// [`Gpu::from_adapter_async`]).
    #[cfg(not(target_arch = "wasm32"))]
    pub fn from_adapter(adapter: &wgpu::Adapter) -> Result<Self, DrawError> {
        pollster::block_on(Self::from_adapter_async(adapter))
    }

    /// A device on `adapter`, every limit the adapter offers and `POLYGON_MODE_LINE` when
    /// available.
    pub async fn from_adapter_async(adapter: &wgpu::Adapter) -> Result<Self, DrawError> {
        let features = adapter.features() & wgpu::Features::POLYGON_MODE_LINE;
        let (device, queue) = adapter
            .request_device(&wgpu::DeviceDescriptor {
                label: Some("cbdam"),
                required_features: features,
                required_limits: adapter.limits(),
                ..Default::default()
            })
            .await
            .map_err(|e| DrawError::Device(e.to_string()))?;
        let vertex_storage = adapter
            .get_downlevel_capabilities()
            .flags
            .contains(wgpu::DownlevelFlags::VERTEX_STORAGE)
            && adapter.limits().max_storage_buffers_per_shader_stage >= 2;
        Ok(Self {
            device,
            queue,
            info: adapter.get_info(),
            vertex_storage,
        })
    }

    /// "name (backend, device type)".
    pub fn describe(&self) -> String {
        format!(
            "{} ({:?}, {:?})",
            self.info.name, self.info.backend, self.info.device_type
        )
    }
}
