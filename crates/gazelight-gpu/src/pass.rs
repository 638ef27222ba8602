//! One declaration per compute pass: [`PassDescriptor`].
//!
//! Every compute pass of the crate is a `const` descriptor in its pass file
//! (`pooling.rs`, `temporal.rs`, `psf.rs`, `glare.rs`, `acuity.rs`,
//! `tone.rs`, `fft.rs`): the WGSL file, the compute entry points it runs and, per
//! `@binding` of `@group(0)` in order, what the shader declares there —
//! uniform or storage, read-only or read-write, and the binding's minimum
//! size in bytes (the uniform struct, a storage struct, or one array
//! element). From the descriptor come the bind-group layout, one compute
//! pipeline per entry point ([`PassDescriptor::build`]) and the bind groups
//! ([`PassLayout::bind_buffers`], [`PassLayout::bind`]), so no pass writes a
//! `wgpu::BindGroupLayoutEntry` by hand.
//!
//! [`ALL`] lists every descriptor; `tests/wgsl_twins.rs` checks each one
//! against the bindings naga reads from its WGSL, and each uniform struct
//! against its `#[repr(C)]` Rust twin.

use std::num::NonZeroU64;

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::shaders::WgslShader;

/// How the shader reads a binding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BindingKind {
    /// `var<uniform>`.
    Uniform,
    /// `var<storage, read>`.
    StorageRead,
    /// `var<storage, read_write>`.
    StorageReadWrite,
}

/// One `@group(0) @binding(i)` of a pass; `i` is its index in
/// [`PassDescriptor::bindings`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Binding {
    /// The WGSL variable's name (for errors and the twin test).
    pub name: &'static str,
    /// Uniform or storage, and the access.
    pub kind: BindingKind,
    /// Minimum binding size, bytes: the struct's size, or one element's
    /// stride for a runtime-sized array.
    pub min_bytes: u64,
}

impl Binding {
    /// A `var<uniform>` of the `#[repr(C)]` struct `T`.
    pub const fn uniform<T>(name: &'static str) -> Self {
        Self {
            name,
            kind: BindingKind::Uniform,
            min_bytes: size_of::<T>() as u64,
        }
    }

    /// A `var<storage, read>` whose smallest binding holds one `T`.
    pub const fn read<T>(name: &'static str) -> Self {
        Self {
            name,
            kind: BindingKind::StorageRead,
            min_bytes: size_of::<T>() as u64,
        }
    }

    /// A `var<storage, read_write>` whose smallest binding holds one `T`.
    pub const fn read_write<T>(name: &'static str) -> Self {
        Self {
            name,
            kind: BindingKind::StorageReadWrite,
            min_bytes: size_of::<T>() as u64,
        }
    }

    fn layout_entry(&self, binding: u32) -> wgpu::BindGroupLayoutEntry {
        let ty = match self.kind {
            BindingKind::Uniform => wgpu::BufferBindingType::Uniform,
            BindingKind::StorageRead => wgpu::BufferBindingType::Storage { read_only: true },
            BindingKind::StorageReadWrite => wgpu::BufferBindingType::Storage { read_only: false },
        };
        wgpu::BindGroupLayoutEntry {
            binding,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty,
                has_dynamic_offset: false,
                min_binding_size: NonZeroU64::new(self.min_bytes),
            },
            count: None,
        }
    }
}

/// A compute pass: its shader, the entry points it runs and its bindings.
#[derive(Debug, Clone, Copy)]
pub struct PassDescriptor {
    /// The WGSL source (with its prepended helpers).
    pub shader: WgslShader,
    /// The compute entry points, in the order [`PassDescriptor::build`]
    /// returns their pipelines.
    pub entry_points: &'static [&'static str],
    /// `@group(0)` bindings 0, 1, 2, … in order.
    pub bindings: &'static [Binding],
}

impl PassDescriptor {
    /// Builds the bind-group layout and one pipeline per entry point, each
    /// checked against the device limits first
    /// ([`GpuContext::create_compute_pipeline`]). `N` must be the number of
    /// entry points.
    pub fn build<const N: usize>(
        &'static self,
        ctx: &GpuContext,
    ) -> Result<(PassLayout, [wgpu::ComputePipeline; N]), GpuError> {
        if self.entry_points.len() != N {
            return Err(GpuError::Wgpu {
                what: format!("pass '{}'", self.shader.name),
                message: format!(
                    "{} entry points declared, {N} pipelines asked for",
                    self.entry_points.len()
                ),
            });
        }
        let layout = self.bind_group_layout(ctx)?;
        let mut pipelines = Vec::with_capacity(N);
        for entry in self.entry_points {
            pipelines.push(ctx.create_compute_pipeline(&self.shader, entry, &[&layout])?);
        }
        let pipelines = pipelines.try_into().map_err(|_| GpuError::Wgpu {
            what: format!("pass '{}'", self.shader.name),
            message: "pipeline count changed while building".to_owned(),
        })?;
        Ok((
            PassLayout {
                descriptor: self,
                layout,
            },
            pipelines,
        ))
    }

    fn bind_group_layout(&self, ctx: &GpuContext) -> Result<wgpu::BindGroupLayout, GpuError> {
        let entries: Vec<wgpu::BindGroupLayoutEntry> = self
            .bindings
            .iter()
            .enumerate()
            .map(|(i, b)| b.layout_entry(i as u32))
            .collect();
        let label = self.shader.name;
        ctx.scoped(&format!("{label} bind group layout"), |device| {
            device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                label: Some(label),
                entries: &entries,
            })
        })
    }
}

/// A pass's built bind-group layout, which makes its bind groups.
#[derive(Debug, Clone)]
pub struct PassLayout {
    descriptor: &'static PassDescriptor,
    layout: wgpu::BindGroupLayout,
}

impl PassLayout {
    /// The descriptor it was built from.
    pub fn descriptor(&self) -> &'static PassDescriptor {
        self.descriptor
    }

    /// The bind-group layout (group 0).
    pub fn layout(&self) -> &wgpu::BindGroupLayout {
        &self.layout
    }

    /// A bind group of one resource per binding, in binding order; an error
    /// names the pass when the count is wrong or wgpu rejects a resource
    /// (e.g. a buffer smaller than the binding's minimum size).
    pub fn bind(
        &self,
        ctx: &GpuContext,
        resources: &[wgpu::BindingResource<'_>],
    ) -> Result<wgpu::BindGroup, GpuError> {
        let label = self.descriptor.shader.name;
        let expected = self.descriptor.bindings.len();
        if resources.len() != expected {
            return Err(GpuError::Length {
                what: "bind group resources",
                expected,
                got: resources.len(),
            });
        }
        let entries: Vec<wgpu::BindGroupEntry<'_>> = resources
            .iter()
            .enumerate()
            .map(|(i, resource)| wgpu::BindGroupEntry {
                binding: i as u32,
                resource: resource.clone(),
            })
            .collect();
        ctx.scoped(&format!("{label} bind group"), |device| {
            device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some(label),
                layout: &self.layout,
                entries: &entries,
            })
        })
    }

    /// [`PassLayout::bind`] with each buffer bound whole.
    pub fn bind_buffers(
        &self,
        ctx: &GpuContext,
        buffers: &[&wgpu::Buffer],
    ) -> Result<wgpu::BindGroup, GpuError> {
        let resources: Vec<wgpu::BindingResource<'_>> =
            buffers.iter().map(|b| b.as_entire_binding()).collect();
        self.bind(ctx, &resources)
    }
}

/// The largest storage binding the device takes, bytes (the binding limit,
/// capped by the buffer size limit).
pub(crate) fn max_storage_binding_bytes(ctx: &GpuContext) -> u64 {
    let limits = ctx.limits();
    limits
        .max_storage_buffer_binding_size
        .min(limits.max_buffer_size)
}

/// Every compute pass of the crate.
pub const ALL: &[&PassDescriptor] = &[
    &crate::fft::FFT_PASS,
    &crate::psf::PSF_APERTURE_PASS,
    &crate::psf::PSF_INTENSITY_PASS,
    &crate::psf::PSF_SPECTRAL_PASS,
    &crate::psf::PSF_NORMALISE_PASS,
    &crate::pooling::POOLING_PASS,
    &crate::temporal::TEMPORAL_PASS,
    &crate::glare::GLARE_PASS,
    &crate::far_glare::FAR_GLARE_PASS,
    &crate::acuity::ACUITY_PASS,
    &crate::tone::TONE_PASS,
];
