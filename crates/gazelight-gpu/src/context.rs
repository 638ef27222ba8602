//! The wgpu device the passes run on.
//!
//! A [`GpuContext`] either wraps a caller's `wgpu::Device` + `wgpu::Queue`
//! (library use inside a host renderer, which keeps its own device, limits and
//! error handler) or creates its own. When it creates its own, the adapter is
//! chosen hardware first (discrete, integrated, virtual, other), then a
//! software adapter (Mesa's lavapipe, WARP, …; `force_fallback_adapter`).
//! The backends searched come from `WGPU_BACKEND` (e.g. `vulkan`) when set,
//! all native backends otherwise. The chosen adapter is logged (name,
//! backend, device type). No usable adapter is an error value, not a panic:
//! the caller then falls back to the CPU pipeline of `gazelight-vision`.
//!
//! Pipelines are built through [`GpuContext::create_compute_pipeline`], which
//! first checks the shader against the device limits (see
//! [`crate::shaders::check_shader`]) and captures wgpu validation errors
//! into [`GpuError::Wgpu`] instead of wgpu's default panicking handler.

use crate::error::GpuError;
use crate::shaders::{WgslShader, check_shader};

/// What is known about an adapter (name, backend, device type, driver).
pub use wgpu::AdapterInfo;

/// Which kind of adapter to accept.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum AdapterChoice {
    /// A hardware GPU when present, a software adapter otherwise.
    #[default]
    Auto,
    /// A hardware GPU only (discrete, integrated, virtual or other).
    Hardware,
    /// A software (CPU) adapter only.
    Software,
}

impl std::fmt::Display for AdapterChoice {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            AdapterChoice::Auto => "auto",
            AdapterChoice::Hardware => "hardware",
            AdapterChoice::Software => "software",
        })
    }
}

/// How to create an own device.
#[derive(Debug, Clone)]
pub struct ContextOptions {
    /// Kind of adapter to accept.
    pub adapter: AdapterChoice,
    /// Limits requested from the device; the WebGPU defaults unless a caller
    /// needs more (the passes of this crate fit the defaults).
    pub required_limits: wgpu::Limits,
    /// Request `TIMESTAMP_QUERY` when the adapter supports it (benchmarks).
    pub timestamp_queries: bool,
}

impl Default for ContextOptions {
    fn default() -> Self {
        Self {
            adapter: AdapterChoice::Auto,
            required_limits: wgpu::Limits::default(),
            timestamp_queries: false,
        }
    }
}

/// A device + queue and what is known about the adapter behind them.
#[derive(Debug, Clone)]
pub struct GpuContext {
    device: wgpu::Device,
    queue: wgpu::Queue,
    adapter_info: wgpu::AdapterInfo,
    limits: wgpu::Limits,
    /// The instance and adapter of an own device (`None` for a caller's):
    /// what a window surface on this device is created from and checked
    /// against ([`crate::present`]).
    surface_source: Option<(wgpu::Instance, wgpu::Adapter)>,
}

/// Preference order of adapter types: hardware first, software last.
fn device_type_rank(device_type: wgpu::DeviceType) -> u8 {
    match device_type {
        wgpu::DeviceType::DiscreteGpu => 0,
        wgpu::DeviceType::IntegratedGpu => 1,
        wgpu::DeviceType::VirtualGpu => 2,
        wgpu::DeviceType::Other => 3,
        wgpu::DeviceType::Cpu => 4,
    }
}

fn accepts(choice: AdapterChoice, device_type: wgpu::DeviceType) -> bool {
    match choice {
        AdapterChoice::Auto => true,
        AdapterChoice::Hardware => device_type != wgpu::DeviceType::Cpu,
        AdapterChoice::Software => device_type == wgpu::DeviceType::Cpu,
    }
}

/// "name (backend, device type)" of an adapter.
pub fn describe_adapter(info: &wgpu::AdapterInfo) -> String {
    format!(
        "{} ({:?}, {:?}, driver {} {})",
        info.name, info.backend, info.device_type, info.driver, info.driver_info
    )
}

/// Every adapter the searched backends (`WGPU_BACKEND`, or all native ones)
/// list, without creating a device: for a caller's choice between the GPU
/// and the CPU pipeline.
pub fn probe_adapters() -> Vec<wgpu::AdapterInfo> {
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    pollster::block_on(instance.enumerate_adapters(wgpu::Backends::all().with_env()))
        .iter()
        .map(wgpu::Adapter::get_info)
        .collect()
}

/// Whether an adapter is a software (CPU) one: lavapipe/llvmpipe, WARP, …
pub fn is_software_adapter(info: &wgpu::AdapterInfo) -> bool {
    info.device_type == wgpu::DeviceType::Cpu
}

/// The backends an own device is searched on, for messages ("VULKAN").
pub fn searched_backends() -> String {
    format!("{:?}", wgpu::Backends::all().with_env())
}

impl GpuContext {
    /// Wraps a caller's device and queue (a host renderer's). The caller keeps
    /// its limits and its uncaptured-error handler.
    pub fn from_device(device: wgpu::Device, queue: wgpu::Queue) -> Self {
        let adapter_info = device.adapter_info();
        let limits = device.limits();
        tracing::info!(adapter = %describe_adapter(&adapter_info), "gazelight-gpu on the host's device");
        Self {
            device,
            queue,
            adapter_info,
            limits,
            surface_source: None,
        }
    }

    /// Creates an own device (blocking). See the module docs for the order
    /// in which adapters are tried.
    pub fn new(options: &ContextOptions) -> Result<Self, GpuError> {
        pollster::block_on(Self::new_async(options))
    }

    /// Async form of [`GpuContext::new`].
    pub async fn new_async(options: &ContextOptions) -> Result<Self, GpuError> {
        let instance =
            wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
        let backends = wgpu::Backends::all().with_env();
        let mut adapters = instance.enumerate_adapters(backends).await;
        adapters.retain(|a| accepts(options.adapter, a.get_info().device_type));
        adapters.sort_by_key(|a| device_type_rank(a.get_info().device_type));
        if adapters.is_empty() && options.adapter != AdapterChoice::Hardware {
            let fallback = instance
                .request_adapter(&wgpu::RequestAdapterOptions {
                    power_preference: wgpu::PowerPreference::HighPerformance,
                    force_fallback_adapter: true,
                    compatible_surface: None,
                    apply_limit_buckets: false,
                })
                .await;
            if let Ok(adapter) = fallback {
                adapters.push(adapter);
            }
        }
        let mut failures = Vec::new();
        for adapter in adapters {
            let info = adapter.get_info();
            let mut features = wgpu::Features::empty();
            if options.timestamp_queries
                && adapter.features().contains(wgpu::Features::TIMESTAMP_QUERY)
            {
                features |= wgpu::Features::TIMESTAMP_QUERY;
            }
            let request = adapter
                .request_device(&wgpu::DeviceDescriptor {
                    label: Some("gazelight-gpu"),
                    required_features: features,
                    required_limits: options.required_limits.clone(),
                    experimental_features: wgpu::ExperimentalFeatures::disabled(),
                    memory_hints: wgpu::MemoryHints::Performance,
                    trace: wgpu::Trace::Off,
                })
                .await;
            match request {
                Ok((device, queue)) => {
                    tracing::info!(
                        adapter = %info.name,
                        backend = ?info.backend,
                        device_type = ?info.device_type,
                        driver = %info.driver,
                        "gazelight-gpu adapter"
                    );
                    let limits = device.limits();
                    return Ok(Self {
                        device,
                        queue,
                        adapter_info: info,
                        limits,
                        surface_source: Some((instance.clone(), adapter)),
                    });
                }
                Err(e) => failures.push(format!("{}: {e}", describe_adapter(&info))),
            }
        }
        Err(GpuError::NoAdapter {
            choice: options.adapter.to_string(),
            backends: format!("{backends:?}"),
            reason: if failures.is_empty() {
                "no adapter of that kind found".to_owned()
            } else {
                format!("device request failed on {}", failures.join("; "))
            },
        })
    }

    /// The device.
    pub fn device(&self) -> &wgpu::Device {
        &self.device
    }

    /// The queue.
    pub fn queue(&self) -> &wgpu::Queue {
        &self.queue
    }

    /// The adapter behind the device.
    pub fn adapter_info(&self) -> &wgpu::AdapterInfo {
        &self.adapter_info
    }

    /// The instance and adapter behind an own device, for creating and
    /// checking window surfaces on it; `None` for a caller's device.
    pub fn surface_source(&self) -> Option<(&wgpu::Instance, &wgpu::Adapter)> {
        self.surface_source.as_ref().map(|(i, a)| (i, a))
    }

    /// The device's limits (what the shaders are checked against).
    pub fn limits(&self) -> &wgpu::Limits {
        &self.limits
    }

    /// Whether the device has `TIMESTAMP_QUERY` enabled.
    pub fn has_timestamp_queries(&self) -> bool {
        self.device
            .features()
            .contains(wgpu::Features::TIMESTAMP_QUERY)
    }

    /// "name (backend, device type, driver)" of the adapter.
    pub fn describe(&self) -> String {
        describe_adapter(&self.adapter_info)
    }

    /// Blocks until all submitted work is done.
    pub fn wait_idle(&self) -> Result<(), GpuError> {
        self.device.poll(wgpu::PollType::wait_indefinitely())?;
        Ok(())
    }

    /// Runs `create` with validation and out-of-memory errors captured, and
    /// returns them as [`GpuError::Wgpu`] naming `what`.
    pub fn scoped<T>(
        &self,
        what: &str,
        create: impl FnOnce(&wgpu::Device) -> T,
    ) -> Result<T, GpuError> {
        let validation = self.device.push_error_scope(wgpu::ErrorFilter::Validation);
        let oom = self.device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
        let value = create(&self.device);
        let oom_error = pollster::block_on(oom.pop());
        let validation_error = pollster::block_on(validation.pop());
        match oom_error.or(validation_error) {
            Some(e) => Err(GpuError::Wgpu {
                what: what.to_owned(),
                message: e.to_string(),
            }),
            None => Ok(value),
        }
    }

    /// Checks `shader` against this device's limits (workgroup storage and
    /// size, see [`check_shader`]), then builds a compute pipeline for its
    /// `entry_point` with the given bind group layouts.
    pub fn create_compute_pipeline(
        &self,
        shader: &WgslShader,
        entry_point: &str,
        bind_group_layouts: &[&wgpu::BindGroupLayout],
    ) -> Result<wgpu::ComputePipeline, GpuError> {
        let report = check_shader(shader, &self.limits)?;
        if !report.entry_points.iter().any(|e| e.name == entry_point) {
            return Err(GpuError::MissingEntryPoint {
                shader: shader.name,
                entry_point: entry_point.to_owned(),
            });
        }
        let module = self.scoped(&format!("shader module '{}'", shader.name), |device| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(shader.name),
                source: wgpu::ShaderSource::Wgsl(shader.source.into()),
            })
        })?;
        let layouts: Vec<Option<&wgpu::BindGroupLayout>> =
            bind_group_layouts.iter().map(|l| Some(*l)).collect();
        self.scoped(
            &format!("compute pipeline '{}::{entry_point}'", shader.name),
            |device| {
                let layout = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
                    label: Some(shader.name),
                    bind_group_layouts: &layouts,
                    immediate_size: 0,
                });
                device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                    label: Some(shader.name),
                    layout: Some(&layout),
                    module: &module,
                    entry_point: Some(entry_point),
                    compilation_options: wgpu::PipelineCompilationOptions::default(),
                    cache: None,
                })
            },
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shaders::WgslShader;
    use crate::testing::test_context;

    #[test]
    fn test_device_has_the_webgpu_default_limits() {
        let Some(ctx) = test_context("test_device_has_the_webgpu_default_limits") else {
            return;
        };
        let defaults = wgpu::Limits::default();
        assert_eq!(
            ctx.limits().max_compute_workgroup_storage_size,
            defaults.max_compute_workgroup_storage_size
        );
        assert_eq!(
            ctx.limits().max_storage_buffer_binding_size,
            defaults.max_storage_buffer_binding_size
        );
        assert!(!ctx.adapter_info().name.is_empty());
    }

    #[test]
    fn adapter_choice_filters_by_device_type() {
        let Some(shared) = test_context("adapter_choice_filters_by_device_type") else {
            return;
        };
        for choice in [AdapterChoice::Hardware, AdapterChoice::Software] {
            let options = ContextOptions {
                adapter: choice,
                ..ContextOptions::default()
            };
            match GpuContext::new(&options) {
                Ok(ctx) => {
                    println!("{choice}: {}", ctx.describe());
                    assert_eq!(
                        ctx.adapter_info().device_type == wgpu::DeviceType::Cpu,
                        choice == AdapterChoice::Software
                    );
                }
                Err(e) => {
                    println!("{choice}: {e}");
                    assert!(matches!(&e, GpuError::NoAdapter { .. }), "{e}");
                    assert!(e.to_string().contains(&choice.to_string()), "{e}");
                }
            }
        }
        // Auto picks the shared device's adapter type first (hardware if any).
        let auto = GpuContext::new(&ContextOptions::default()).unwrap();
        assert_eq!(
            auto.adapter_info().device_type,
            shared.adapter_info().device_type
        );
    }

    #[test]
    fn pipeline_creation_rejects_oversized_workgroup_storage_on_the_device() {
        let Some(ctx) =
            test_context("pipeline_creation_rejects_oversized_workgroup_storage_on_the_device")
        else {
            return;
        };
        // wgpu 30 itself accepts this 64 KiB shader; the check must not.
        let oversized = WgslShader {
            name: "oversized_device_test.wgsl",
            source: "
                var<workgroup> tile: array<vec4<f32>, 4096>;
                @group(0) @binding(0) var<storage, read_write> out: array<vec4<f32>>;
                @compute @workgroup_size(64)
                fn main(@builtin(local_invocation_index) i: u32) {
                    tile[i] = vec4<f32>(f32(i));
                    workgroupBarrier();
                    out[i] = tile[4095u - i];
                }
            ",
        };
        let layout = ctx
            .device()
            .create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: None,
                entries: &[wgpu::BindGroupLayoutEntry {
                    binding: 0,
                    visibility: wgpu::ShaderStages::COMPUTE,
                    ty: wgpu::BindingType::Buffer {
                        ty: wgpu::BufferBindingType::Storage { read_only: false },
                        has_dynamic_offset: false,
                        min_binding_size: None,
                    },
                    count: None,
                }],
            });
        let err = ctx
            .create_compute_pipeline(&oversized, "main", &[&layout])
            .unwrap_err();
        assert!(
            matches!(
                &err,
                GpuError::WorkgroupStorage {
                    shader: "oversized_device_test.wgsl",
                    bytes: 65536,
                    ..
                }
            ),
            "{err}"
        );
        let err = ctx
            .create_compute_pipeline(&crate::shaders::FFT, "nope", &[&layout])
            .unwrap_err();
        assert!(matches!(&err, GpuError::MissingEntryPoint { .. }), "{err}");
        // A layout that does not match the shader: wgpu's validation error is
        // captured and returned, not a panic.
        let err = ctx
            .create_compute_pipeline(&crate::shaders::FFT, "fft_stage", &[&layout])
            .unwrap_err();
        assert!(matches!(&err, GpuError::Wgpu { .. }), "{err}");
        println!("captured: {err}");
    }

    #[test]
    fn wraps_a_callers_device() {
        let Some(ctx) = test_context("wraps_a_callers_device") else {
            return;
        };
        let host = GpuContext::from_device(ctx.device().clone(), ctx.queue().clone());
        assert_eq!(host.adapter_info().name, ctx.adapter_info().name);
        assert_eq!(
            host.limits().max_compute_workgroup_storage_size,
            ctx.limits().max_compute_workgroup_storage_size
        );
        // The host's device runs the passes.
        let fft = crate::fft::GpuFft2d::new(&host, 4, 4, 1).unwrap();
        let x: Vec<[f32; 2]> = (0..16).map(|i| [i as f32, 0.0]).collect();
        fft.upload(&host, &x).unwrap();
        fft.run(&host, crate::fft::FftDirection::Forward);
        let mut out = vec![[0.0; 2]; 16];
        fft.download(&host, &mut out).unwrap();
        // DC term = Σ x = 120.
        assert!(
            (out[0][0] - 120.0).abs() < 1e-4 && out[0][1].abs() < 1e-4,
            "{:?}",
            out[0]
        );
    }
}
