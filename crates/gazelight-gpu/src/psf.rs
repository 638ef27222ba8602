//! The glare kernel on the GPU: [`GpuPsfBuilder`] holds the kernel the
//! glare convolution reads ([`GpuPsfBuilder::kernel_buffer`]) and rebuilds
//! it for each new pupil.
//!
//! # Interim: the kernel is built on the CPU and uploaded
//!
//! The kernel model changed (issue 10): a wave-optics near field on a
//! pupil-plane grid chosen per request, analytic particle lobes beyond it,
//! and the CIE 146:2002 intraocular stray light out to the edge of the
//! glare field, normalised as a whole ([`gazelight_vision::psf`]). Its WGSL
//! twin is not written yet. Until it is, a rebuild runs the CPU model's
//! [`PsfBuilder::rebuild`] (f64) and uploads the kernel into the GPU buffer
//! (`queue.write_buffer`, `kernel_size²` `vec4<f32>`); everything downstream
//! (the kernel spectrum, the glare convolution, the frame) stays on the GPU.
//! The GPU FFT PSF passes of the previous model (aperture, intensity,
//! summed-area spectral sum, normalisation; commit 795c97d) were retired
//! with that model.
//!
//! The rebuild is synchronous on the calling thread (the CPU build takes
//! milliseconds to tens of milliseconds, depending on the chosen grid);
//! [`GpuPsfBuilder::upload`] takes a kernel built elsewhere (e.g. off the
//! frame thread) instead.

use gazelight_vision::psf::{PsfBuilder, PsfKernel, PsfParams};

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::fft::read_mapped;

/// Timestamps written by [`GpuPsfBuilder::encode_rebuild_timed`]: the
/// beginning and end of one (empty) compute pass at the rebuild's place in
/// the command buffer. The GPU does no work for a rebuild (the kernel is
/// built on the CPU and uploaded), so the pair measures ~0.
pub const REBUILD_TIMESTAMPS: u32 = 2;

fn invalid(source: gazelight_vision::VisionError) -> GpuError {
    GpuError::InvalidParams {
        what: "GPU glare PSF",
        source,
    }
}

/// The glare kernel of [`gazelight_vision::psf`] on the GPU: built once for
/// a [`PsfParams`], rebuilt for each new pupil diameter (see the module
/// docs: built on the CPU, uploaded).
pub struct GpuPsfBuilder {
    ctx: GpuContext,
    cpu: PsfBuilder,
    size: usize,
    pupil_mm: f64,
    host: Vec<[f32; 4]>,
    kernel: wgpu::Buffer,
    staging: wgpu::Buffer,
}

impl std::fmt::Debug for GpuPsfBuilder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GpuPsfBuilder")
            .field("kernel_size", &self.size)
            .field("pupil_mm", &self.pupil_mm)
            .finish_non_exhaustive()
    }
}

impl GpuPsfBuilder {
    /// Validates `params`, builds the first kernel (for `params.pupil_mm`)
    /// and uploads it.
    pub fn new(ctx: &GpuContext, params: &PsfParams) -> Result<Self, GpuError> {
        let cpu = PsfBuilder::new(params.clone()).map_err(invalid)?;
        let size = cpu.kernel().size;
        let bytes = (size * size * 16) as u64;
        let max = crate::pass::max_storage_binding_bytes(ctx);
        if bytes > max {
            return Err(GpuError::Wgpu {
                what: "GPU glare PSF".to_owned(),
                message: format!(
                    "a {size}x{size} kernel ({bytes} bytes) exceeds the device's storage binding \
                     limit of {max} bytes"
                ),
            });
        }
        let make = |label: &'static str, usage| {
            ctx.scoped(&format!("buffer '{label}'"), |device| {
                device.create_buffer(&wgpu::BufferDescriptor {
                    label: Some(label),
                    size: bytes,
                    usage,
                    mapped_at_creation: false,
                })
            })
        };
        let kernel = make(
            "psf kernel",
            wgpu::BufferUsages::STORAGE
                | wgpu::BufferUsages::COPY_DST
                | wgpu::BufferUsages::COPY_SRC,
        )?;
        let staging = make(
            "psf kernel staging",
            wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        )?;
        let mut builder = Self {
            ctx: ctx.clone(),
            pupil_mm: cpu.kernel().pupil_mm,
            cpu,
            size,
            host: vec![[0.0; 4]; size * size],
            kernel,
            staging,
        };
        builder.write_current();
        Ok(builder)
    }

    /// The parameters (with `pupil_mm` as given to `new`).
    pub fn params(&self) -> &PsfParams {
        self.cpu.params()
    }

    /// Kernel size, pixels per side.
    pub fn kernel_size(&self) -> usize {
        self.size
    }

    /// Pupil diameter of the kernel in the buffer, mm.
    pub fn pupil_mm(&self) -> f64 {
        self.pupil_mm
    }

    /// The CPU kernel last uploaded (the same values as the buffer).
    pub fn cpu_kernel(&self) -> &PsfKernel {
        self.cpu.kernel()
    }

    /// The kernel on the GPU: `kernel_size²` `vec4<f32>` (linear sRGB in
    /// xyz, w = 0), row-major, centre at `(size/2, size/2)`, each channel
    /// summing to 1 — the input of the glare convolution.
    pub fn kernel_buffer(&self) -> &wgpu::Buffer {
        &self.kernel
    }

    fn write_current(&mut self) {
        let k = self.cpu.kernel();
        for (d, s) in self.host.iter_mut().zip(&k.rgb) {
            *d = [s[0], s[1], s[2], 0.0];
        }
        self.pupil_mm = k.pupil_mm;
        self.ctx
            .queue()
            .write_buffer(&self.kernel, 0, bytemuck::cast_slice(&self.host));
    }

    /// Uploads a kernel built elsewhere (e.g. off the frame thread by a
    /// [`PsfBuilder`] with the same parameters); its size must match.
    pub fn upload(&mut self, kernel: &PsfKernel) -> Result<(), GpuError> {
        if kernel.size != self.size || kernel.rgb.len() != self.size * self.size {
            return Err(GpuError::Length {
                what: "uploaded PSF kernel",
                expected: self.size * self.size,
                got: kernel.rgb.len(),
            });
        }
        for (d, s) in self.host.iter_mut().zip(&kernel.rgb) {
            *d = [s[0], s[1], s[2], 0.0];
        }
        self.pupil_mm = kernel.pupil_mm;
        self.ctx
            .queue()
            .write_buffer(&self.kernel, 0, bytemuck::cast_slice(&self.host));
        Ok(())
    }

    /// Rebuilds the kernel for `pupil_mm` (on the CPU, see the module docs)
    /// and queues its upload, which lands before any command buffer
    /// submitted afterwards (`encoder` is not used: nothing is recorded).
    /// The pupil is clamped into the builder's `pupil_range_mm`; a
    /// non-finite one keeps the current kernel. Returns the diameter the
    /// kernel now holds.
    pub fn encode_rebuild(&mut self, encoder: &mut wgpu::CommandEncoder, pupil_mm: f64) -> f64 {
        self.encode_rebuild_timed(encoder, pupil_mm, None)
    }

    /// As [`GpuPsfBuilder::encode_rebuild`], with timestamps 0–1 around an
    /// empty compute pass in `encoder` (see [`REBUILD_TIMESTAMPS`]).
    pub fn encode_rebuild_timed(
        &mut self,
        encoder: &mut wgpu::CommandEncoder,
        pupil_mm: f64,
        timestamps: Option<&wgpu::QuerySet>,
    ) -> f64 {
        if let Some(query_set) = timestamps {
            let _ = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("psf rebuild (CPU-built kernel uploaded)"),
                timestamp_writes: Some(wgpu::ComputePassTimestampWrites {
                    query_set,
                    beginning_of_pass_write_index: Some(0),
                    end_of_pass_write_index: Some(1),
                }),
            });
        }
        self.rebuild(pupil_mm)
    }

    /// Rebuilds the kernel for a new pupil diameter and queues its upload.
    /// As the CPU's `PsfBuilder::rebuild`, a diameter outside the pupil
    /// range is clamped into it and a non-finite one keeps the current
    /// kernel. Returns the diameter the kernel now holds.
    pub fn rebuild(&mut self, pupil_mm: f64) -> f64 {
        if pupil_mm.is_finite() {
            self.cpu.rebuild(pupil_mm);
            self.write_current();
        }
        self.pupil_mm
    }

    /// Like [`GpuPsfBuilder::rebuild`], but an unsupported pupil is an error
    /// naming `psf.pupil_mm`.
    pub fn try_rebuild(&mut self, pupil_mm: f64) -> Result<(), GpuError> {
        self.cpu
            .try_rebuild(pupil_mm)
            .map_err(|source| GpuError::InvalidParams {
                what: "GPU glare PSF rebuild",
                source,
            })?;
        self.write_current();
        Ok(())
    }

    /// Copies the kernel back from the GPU buffer (blocking): for tests and
    /// tools, not the frame path.
    pub fn read_kernel(&self) -> Result<PsfKernel, GpuError> {
        let size = self.size;
        let mut rgb = vec![[0.0f32; 3]; size * size];
        let mut encoder =
            self.ctx
                .device()
                .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                    label: Some("psf kernel read-back"),
                });
        encoder.copy_buffer_to_buffer(&self.kernel, 0, &self.staging, 0, self.kernel.size());
        self.ctx.queue().submit([encoder.finish()]);
        read_mapped(&self.ctx, &self.staging, "PSF kernel staging", |bytes| {
            let values: &[[f32; 4]] = bytemuck::cast_slice(bytes);
            for (out, v) in rgb.iter_mut().zip(values) {
                *out = [v[0], v[1], v[2]];
            }
        })?;
        let k = self.cpu.kernel();
        Ok(PsfKernel {
            size,
            deg_per_px: k.deg_per_px,
            pupil_mm: self.pupil_mm,
            wavelengths_nm: k.wavelengths_nm.clone(),
            rgb,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testing::test_context;
    use gazelight_vision::psf::build_kernel;

    /// Max |GPU − CPU| over pixels and channels, relative to the CPU peak.
    fn kernel_error(gpu: &PsfKernel, cpu: &PsfKernel) -> f64 {
        let peak = cpu.rgb.iter().flatten().fold(0.0f32, |m, &v| m.max(v));
        let mut max = 0.0f32;
        for (g, c) in gpu.rgb.iter().zip(&cpu.rgb) {
            for k in 0..3 {
                max = max.max((g[k] - c[k]).abs());
            }
        }
        f64::from(max) / f64::from(peak)
    }

    #[test]
    fn gpu_kernel_buffer_holds_the_cpu_kernel_after_each_rebuild() {
        let Some(ctx) = test_context("gpu_kernel_buffer_holds_the_cpu_kernel_after_each_rebuild")
        else {
            return;
        };
        // A small field (±2° at 14 ppd) keeps the CPU builds quick.
        let params = PsfParams {
            ppd: 14.0,
            field_deg: 4.0,
            ..PsfParams::default()
        };
        let mut gpu = GpuPsfBuilder::new(ctx, &params).unwrap();
        let mut worst = 0.0f64;
        for pupil_mm in [params.pupil_mm, 2.5, 7.0] {
            gpu.rebuild(pupil_mm);
            let fresh = build_kernel(&PsfParams {
                pupil_mm,
                ..params.clone()
            })
            .unwrap();
            let read = gpu.read_kernel().unwrap();
            assert_eq!(read.size, fresh.size);
            assert_eq!(read.pupil_mm, pupil_mm);
            let e = kernel_error(&read, &fresh);
            println!("pupil {pupil_mm} mm: GPU buffer vs fresh CPU kernel {e:.2e} of the peak");
            assert!(e < 1e-4, "{pupil_mm} mm: {e:e}");
            worst = worst.max(e);
        }
        // A kernel of another size is refused; NaN keeps the kernel.
        let other = build_kernel(&PsfParams {
            field_deg: 2.0,
            ..params.clone()
        })
        .unwrap();
        assert!(matches!(gpu.upload(&other), Err(GpuError::Length { .. })));
        assert_eq!(gpu.rebuild(f64::NAN), 7.0);
        assert!(gpu.try_rebuild(-1.0).is_err());
        println!("worst {worst:.2e}");
    }
}
