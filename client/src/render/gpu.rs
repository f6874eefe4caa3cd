//! The wgpu device: adapter choice (honouring `WGPU_BACKEND`), and errors collected
//! from the device so that a failing or lost GPU becomes an error message, not a panic.

use super::error::RenderError;
use std::sync::{Arc, Mutex};

/// Which graphics API to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Backend {
    /// `WGPU_BACKEND` if set, else whatever the system offers (Vulkan first).
    Auto,
    Vulkan,
    Gl,
}

#[derive(Debug)]
pub struct Gpu {
    pub device: wgpu::Device,
    pub queue: wgpu::Queue,
    pub adapter: wgpu::AdapterInfo,
    pub limits: wgpu::Limits,
    /// What the device can do beyond WebGL 2 (compute shaders for normal maps).
    pub downlevel: wgpu::DownlevelCapabilities,
    /// Uncaptured errors and device loss, reported by wgpu's callbacks.
    errors: Arc<Mutex<Vec<String>>>,
}

impl Gpu {
    pub fn new(backend: Backend) -> Result<Self, RenderError> {
        // Auto without WGPU_BACKEND: Vulkan first, GL only if there is no Vulkan
        // adapter (probing EGL prints noise on machines without a display).
        let tries: Vec<wgpu::Backends> = match backend {
            Backend::Vulkan => vec![wgpu::Backends::VULKAN],
            Backend::Gl => vec![wgpu::Backends::GL],
            Backend::Auto if std::env::var_os("WGPU_BACKEND").is_some() => {
                vec![wgpu::InstanceDescriptor::new_without_display_handle_from_env().backends]
            }
            Backend::Auto => vec![
                wgpu::Backends::PRIMARY - wgpu::Backends::BROWSER_WEBGPU,
                wgpu::Backends::GL,
            ],
        };
        let mut adapter = None;
        for (i, &backends) in tries.iter().enumerate() {
            let mut desc = wgpu::InstanceDescriptor::new_without_display_handle_from_env();
            desc.backends = backends;
            let instance = wgpu::Instance::new(desc);
            if let Ok(a) =
                pollster::block_on(instance.request_adapter(&wgpu::RequestAdapterOptions {
                    power_preference: wgpu::PowerPreference::HighPerformance,
                    ..Default::default()
                }))
            {
                // A machine without a Vulkan driver silently drew through GL in
                // stop 28's benchmarks; a different API changes what is measured.
                if i > 0 {
                    tracing::warn!(
                        adapter = %a.get_info().name,
                        "no adapter for {:?}; falling back to {backends:?}",
                        &tries[..i]
                    );
                }
                adapter = Some(a);
                break;
            }
        }
        let adapter = adapter.ok_or_else(|| RenderError::NoAdapter {
            tries: format!("{tries:?}"),
        })?;
        Self::from_adapter(&adapter)
    }

    /// Opens the device on a chosen adapter (the windowed client picks one that
    /// can present to its window).
    pub fn from_adapter(adapter: &wgpu::Adapter) -> Result<Self, RenderError> {
        let features = wgpu::Features::TEXTURE_FORMAT_16BIT_NORM;
        if !adapter.features().contains(features) {
            return Err(RenderError::No16BitTextures {
                name: adapter.get_info().name,
            });
        }
        let limits = adapter.limits();
        let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
            label: Some("tessera"),
            required_features: features,
            required_limits: wgpu::Limits {
                max_texture_array_layers: limits.max_texture_array_layers,
                max_texture_dimension_2d: limits.max_texture_dimension_2d,
                max_storage_buffers_per_shader_stage: 4,
                max_storage_buffer_binding_size: limits.max_storage_buffer_binding_size,
                max_buffer_size: limits.max_buffer_size,
                ..wgpu::Limits::downlevel_defaults()
            },
            ..Default::default()
        }))
        .map_err(RenderError::Device)?;
        let errors = Arc::new(Mutex::new(Vec::new()));
        let sink = errors.clone();
        device.on_uncaptured_error(Arc::new(move |e: wgpu::Error| {
            if let Ok(mut v) = sink.lock() {
                v.push(e.to_string());
            }
        }));
        let sink = errors.clone();
        device.set_device_lost_callback(move |reason, message| {
            if let Ok(mut v) = sink.lock() {
                v.push(format!("GPU device lost ({reason:?}): {message}"));
            }
        });
        Ok(Self {
            device,
            queue,
            adapter: adapter.get_info(),
            limits,
            downlevel: adapter.get_downlevel_capabilities(),
            errors,
        })
    }

    /// The first error the device reported since the last check, as an `Err`.
    pub fn check(&self) -> Result<(), RenderError> {
        let mut v = self.errors.lock().map_err(|_| RenderError::LogPoisoned)?;
        match v.drain(..).next() {
            Some(error) => Err(RenderError::Reported {
                adapter: self.adapter.name.clone(),
                error,
            }),
            None => Ok(()),
        }
    }

    /// Waits for submitted work, turning a timeout or loss into an error.
    pub fn wait(&self) -> Result<(), RenderError> {
        self.device
            .poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| RenderError::Wait {
                adapter: self.adapter.name.clone(),
                error: e.to_string(),
            })?;
        self.check()
    }

    /// "llvmpipe (Vulkan)" and the like, for logs and statistics.
    pub fn describe(&self) -> String {
        format!("{} ({:?})", self.adapter.name, self.adapter.backend)
    }
}
