//! Batched 2D FFT on the GPU: Stockham autosort, radix 4 with a radix-2 final
//! stage when log2 N is odd, complex f32 (`vec2<f32>`) in storage buffers,
//! power-of-two sizes 1..=2048 per side, over several planes at once
//! (3 for RGB, or k wavelengths for the spectral PSF, 001 eq 9–10).
//!
//! Layout: `channels` planes of `width`×`height`, row-major, one after the
//! other; element (c, y, x) at `c·W·H + y·W + x`. A transform is one compute
//! pass: the row stages, then the column stages, one dispatch of
//! `shaders/fft.wgsl` per stage, ping-ponging between the data buffer and a
//! scratch buffer; when the total stage count is odd (only for some
//! non-square sizes) a copy brings the result back into the data buffer.
//!
//! Normalisation: forward X = Σ x·e^(−2πi(kx/W + ly/H)), unnormalised (as
//! rustfft and numpy); inverse with e^(+2πi…) and 1/(W·H), applied as 1/W on
//! the last row stage and 1/H on the last column stage, so
//! inverse(forward(x)) = x. The PSF of 001 eq 8 therefore divides the
//! forward result by N itself.
//!
//! Twiddles come from a table e^(−2πi·m/N_max), m < N_max = max(W, H),
//! computed in f64 on the CPU when the plan is made (conjugated in the
//! shader for the inverse). All buffers, bind groups and per-stage uniforms
//! are made once per plan; running a transform allocates only wgpu's
//! command encoder.

use std::num::NonZeroU64;

use bytemuck::{Pod, Zeroable};

use crate::context::GpuContext;
use crate::cpu::{check_len, radix_plan};
use crate::error::GpuError;
use crate::pass::{Binding, PassDescriptor, PassLayout};
use crate::shaders;

/// Threads per workgroup of `fft_stage` (`FFT_WORKGROUP_SIZE` in fft.wgsl).
pub const WORKGROUP_SIZE: u32 = 64;

/// Uniforms of one FFT stage: the twin of `struct FftParams` in
/// `shaders/fft.wgsl`, field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct FftParams {
    /// Transform length along this axis (N).
    pub n: u32,
    /// Sub-transform length already done (Ns).
    pub ns: u32,
    /// Radix of this stage: 4 or 2.
    pub radix: u32,
    /// Distance between consecutive elements of a line.
    pub elem_stride: u32,
    /// Lines in one plane.
    pub lines_per_plane: u32,
    /// Distance between the first elements of consecutive lines in a plane.
    pub line_step: u32,
    /// Elements in one plane (W·H).
    pub plane_size: u32,
    /// Butterflies in the dispatch: lines·N/radix.
    pub total_threads: u32,
    /// Twiddle table step: N_max / (Ns·radix).
    pub twiddle_step: u32,
    /// 0 forward, 1 inverse.
    pub inverse: u32,
    /// Factor applied to every output of the stage.
    pub scale: f32,
    /// Padding to the WGSL struct size (48 bytes).
    pub _pad: u32,
}

/// Direction of a transform.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FftDirection {
    /// e^(−2πi…), unnormalised.
    Forward,
    /// e^(+2πi…), scaled by 1/(W·H).
    Inverse,
}

/// `shaders/fft.wgsl`: one Stockham stage per dispatch.
pub const FFT_PASS: PassDescriptor = PassDescriptor {
    shader: shaders::FFT,
    entry_points: &["fft_stage"],
    bindings: &[
        Binding::uniform::<FftParams>("params"),
        Binding::read::<[f32; 2]>("src"),
        Binding::read_write::<[f32; 2]>("dst"),
        Binding::read::<[f32; 2]>("twiddles"),
    ],
};

/// The twin of `shaders/fft.wgsl` ([`FFT_PASS`]): its bind group layout and
/// pipeline.
///
/// Bindings: 0 `FftParams` uniform, 1 source (read-only storage),
/// 2 destination (read-write storage), 3 twiddle table (read-only storage).
#[derive(Debug, Clone)]
pub struct FftPass {
    layout: PassLayout,
    pipeline: wgpu::ComputePipeline,
}

impl FftPass {
    /// Checks `fft.wgsl` against the device limits and builds the pipeline.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (layout, [pipeline]) = FFT_PASS.build(ctx)?;
        Ok(Self { layout, pipeline })
    }

    /// The bind group layout (group 0).
    pub fn bind_group_layout(&self) -> &wgpu::BindGroupLayout {
        self.layout.layout()
    }

    /// The compute pipeline.
    pub fn pipeline(&self) -> &wgpu::ComputePipeline {
        &self.pipeline
    }
}

/// One dispatch: its bind group and workgroup grid.
#[derive(Debug)]
struct Stage {
    bind_group: wgpu::BindGroup,
    groups: [u32; 2],
}

/// A planned batched 2D FFT with its own data, scratch and staging buffers.
#[derive(Debug)]
pub struct GpuFft2d {
    width: u32,
    height: u32,
    channels: u32,
    pass: FftPass,
    data: wgpu::Buffer,
    scratch: wgpu::Buffer,
    staging: wgpu::Buffer,
    forward: Vec<Stage>,
    inverse: Vec<Stage>,
}

/// The buffers of one plan.
struct PlanBuffers {
    data: wgpu::Buffer,
    scratch: wgpu::Buffer,
    staging: wgpu::Buffer,
    uniforms: wgpu::Buffer,
    twiddles: wgpu::Buffer,
}

/// e^(−2πi·m/n), m < n, computed in f64.
fn twiddle_table(n: u32) -> Vec<[f32; 2]> {
    (0..n)
        .map(|m| {
            let angle = -2.0 * std::f64::consts::PI * f64::from(m) / f64::from(n);
            [angle.cos() as f32, angle.sin() as f32]
        })
        .collect()
}

/// The uniforms of every stage: rows then columns, forward then inverse.
fn stage_params(width: u32, height: u32, channels: u32) -> Vec<FftParams> {
    let n_max = width.max(height);
    let axes = [
        // (n, elem_stride, lines_per_plane, line_step)
        (width, 1, height, width),
        (height, width, width, 1),
    ];
    let mut params = Vec::new();
    for inverse in [false, true] {
        for (n, elem_stride, lines_per_plane, line_step) in axes {
            let plan = radix_plan(n);
            let mut ns = 1;
            for (i, &radix) in plan.iter().enumerate() {
                let last = i + 1 == plan.len();
                params.push(FftParams {
                    n,
                    ns,
                    radix,
                    elem_stride,
                    lines_per_plane,
                    line_step,
                    plane_size: width * height,
                    total_threads: lines_per_plane * channels * (n / radix),
                    twiddle_step: n_max / (ns * radix),
                    inverse: u32::from(inverse),
                    scale: if inverse && last { 1.0 / n as f32 } else { 1.0 },
                    _pad: 0,
                });
                ns *= radix;
            }
        }
    }
    params
}

/// The stage uniforms packed at `align`-byte offsets.
fn pack_uniforms(params: &[FftParams], align: u64) -> Vec<u8> {
    let mut bytes = vec![0u8; (align as usize) * params.len().max(1)];
    for (i, p) in params.iter().enumerate() {
        let offset = i * align as usize;
        bytes[offset..offset + size_of::<FftParams>()].copy_from_slice(bytemuck::bytes_of(p));
    }
    bytes
}

fn plan_buffers(
    ctx: &GpuContext,
    bytes: u64,
    uniform_bytes: u64,
    twiddle_bytes: u64,
) -> Result<PlanBuffers, GpuError> {
    ctx.scoped("FFT buffers", |device| {
        let buffer = |label, size, usage| {
            device.create_buffer(&wgpu::BufferDescriptor {
                label: Some(label),
                size,
                usage,
                mapped_at_creation: false,
            })
        };
        let storage = wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC;
        PlanBuffers {
            data: buffer("fft data", bytes, storage),
            scratch: buffer("fft scratch", bytes, storage),
            staging: buffer(
                "fft staging",
                bytes,
                wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            ),
            uniforms: buffer(
                "fft stage params",
                uniform_bytes,
                wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            ),
            twiddles: buffer(
                "fft twiddles",
                twiddle_bytes,
                wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            ),
        }
    })
}

impl GpuFft2d {
    /// Plans a transform of `channels` planes of `width`×`height` complex
    /// values. Sizes must be powers of two in 1..=2048 and the planes must fit
    /// one storage binding of the device.
    pub fn new(ctx: &GpuContext, width: u32, height: u32, channels: u32) -> Result<Self, GpuError> {
        Self::with_pass(ctx, &FftPass::new(ctx)?, width, height, channels)
    }

    /// As [`GpuFft2d::new`], sharing an already built [`FftPass`] (one
    /// pipeline for all plans of a device).
    pub fn with_pass(
        ctx: &GpuContext,
        pass: &FftPass,
        width: u32,
        height: u32,
        channels: u32,
    ) -> Result<Self, GpuError> {
        let bytes = Self::checked_bytes(ctx, width, height, channels)?;
        let twiddles = twiddle_table(width.max(height));
        let params = stage_params(width, height, channels);
        let align = u64::from(ctx.limits().min_uniform_buffer_offset_alignment)
            .max(size_of::<FftParams>() as u64);
        let uniform_bytes = pack_uniforms(&params, align);
        let buffers = plan_buffers(
            ctx,
            bytes,
            uniform_bytes.len() as u64,
            (twiddles.len() * 8) as u64,
        )?;
        ctx.queue()
            .write_buffer(&buffers.uniforms, 0, &uniform_bytes);
        ctx.queue()
            .write_buffer(&buffers.twiddles, 0, bytemuck::cast_slice(&twiddles));
        let mut forward = Vec::with_capacity(params.len());
        let per_direction = (params.len() / 2).max(1);
        for (i, p) in params.iter().enumerate() {
            let even = (i % per_direction).is_multiple_of(2);
            let offset = i as u64 * align;
            let groups = Self::stage_groups(ctx, p, [width, height, channels])?;
            forward.push(Stage {
                bind_group: Self::stage_bind_group(ctx, pass, &buffers, even, offset)?,
                groups,
            });
        }
        let inverse = forward.split_off(params.len() / 2);
        Ok(Self {
            width,
            height,
            channels,
            pass: pass.clone(),
            data: buffers.data,
            scratch: buffers.scratch,
            staging: buffers.staging,
            forward,
            inverse,
        })
    }

    fn size_error(size: [u32; 3], reason: String) -> GpuError {
        GpuError::FftSize {
            width: size[0],
            height: size[1],
            channels: size[2],
            reason,
        }
    }

    /// The bytes of the data buffer, after checking the sizes.
    fn checked_bytes(
        ctx: &GpuContext,
        width: u32,
        height: u32,
        channels: u32,
    ) -> Result<u64, GpuError> {
        let size = [width, height, channels];
        check_len(width as usize).map_err(|r| Self::size_error(size, format!("width: {r}")))?;
        check_len(height as usize).map_err(|r| Self::size_error(size, format!("height: {r}")))?;
        if channels == 0 {
            return Err(Self::size_error(size, "no channels".to_owned()));
        }
        let elements = u64::from(width) * u64::from(height) * u64::from(channels);
        let bytes = elements * 8;
        let max_binding = crate::pass::max_storage_binding_bytes(ctx);
        if bytes > max_binding || elements > u64::from(u32::MAX) {
            return Err(Self::size_error(
                size,
                format!(
                    "{bytes} bytes exceed the device's storage binding limit of {max_binding} bytes"
                ),
            ));
        }
        Ok(bytes)
    }

    /// The workgroup grid of one stage (x first, then y when x is full).
    fn stage_groups(ctx: &GpuContext, p: &FftParams, size: [u32; 3]) -> Result<[u32; 2], GpuError> {
        let max_groups = ctx.limits().max_compute_workgroups_per_dimension;
        let total_groups = p.total_threads.div_ceil(WORKGROUP_SIZE);
        let groups_x = total_groups.min(max_groups);
        let groups_y = total_groups.div_ceil(groups_x);
        if groups_y > max_groups {
            return Err(Self::size_error(
                size,
                format!(
                    "{total_groups} workgroups exceed {max_groups}² (max_compute_workgroups_per_dimension)"
                ),
            ));
        }
        Ok([groups_x, groups_y])
    }

    /// A stage's bind group: its uniforms at `offset`, data → scratch on
    /// even stages, scratch → data on odd ones.
    fn stage_bind_group(
        ctx: &GpuContext,
        pass: &FftPass,
        buffers: &PlanBuffers,
        even: bool,
        offset: u64,
    ) -> Result<wgpu::BindGroup, GpuError> {
        let (src, dst) = if even {
            (&buffers.data, &buffers.scratch)
        } else {
            (&buffers.scratch, &buffers.data)
        };
        pass.layout.bind(
            ctx,
            &[
                wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                    buffer: &buffers.uniforms,
                    offset,
                    size: NonZeroU64::new(size_of::<FftParams>() as u64),
                }),
                src.as_entire_binding(),
                dst.as_entire_binding(),
                buffers.twiddles.as_entire_binding(),
            ],
        )
    }

    /// Width (row length).
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height (column length).
    pub fn height(&self) -> u32 {
        self.height
    }

    /// Number of planes.
    pub fn channels(&self) -> u32 {
        self.channels
    }

    /// Complex elements in the data buffer (W·H·channels).
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize * self.channels as usize
    }

    /// Whether the plan holds no elements (never: sizes are ≥ 1).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The buffer the transform reads and writes (`array<vec2<f32>>`); other
    /// passes write their input here and read the result from here.
    pub fn data_buffer(&self) -> &wgpu::Buffer {
        &self.data
    }

    /// Number of dispatches per transform (row + column stages).
    pub fn stage_count(&self) -> usize {
        self.forward.len()
    }

    /// Records one transform of the data buffer into `encoder`, as a single
    /// compute pass (optionally with timestamp writes).
    pub fn encode(
        &self,
        encoder: &mut wgpu::CommandEncoder,
        direction: FftDirection,
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let stages = match direction {
            FftDirection::Forward => &self.forward,
            FftDirection::Inverse => &self.inverse,
        };
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("fft"),
                timestamp_writes,
            });
            pass.set_pipeline(&self.pass.pipeline);
            for stage in stages {
                pass.set_bind_group(0, &stage.bind_group, &[]);
                pass.dispatch_workgroups(stage.groups[0], stage.groups[1], 1);
            }
        }
        if stages.len() % 2 == 1 {
            encoder.copy_buffer_to_buffer(&self.scratch, 0, &self.data, 0, self.data.size());
        }
    }

    /// Writes `input` (W·H·channels complex values) into the data buffer.
    pub fn upload(&self, ctx: &GpuContext, input: &[[f32; 2]]) -> Result<(), GpuError> {
        if input.len() != self.len() {
            return Err(GpuError::Length {
                what: "FFT upload",
                expected: self.len(),
                got: input.len(),
            });
        }
        ctx.queue()
            .write_buffer(&self.data, 0, bytemuck::cast_slice(input));
        Ok(())
    }

    /// Transforms the data buffer in place and submits.
    pub fn run(&self, ctx: &GpuContext, direction: FftDirection) {
        let mut encoder = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor { label: Some("fft") });
        self.encode(&mut encoder, direction, None);
        ctx.queue().submit([encoder.finish()]);
    }

    /// Copies the data buffer back into `out` (blocking).
    pub fn download(&self, ctx: &GpuContext, out: &mut [[f32; 2]]) -> Result<(), GpuError> {
        if out.len() != self.len() {
            return Err(GpuError::Length {
                what: "FFT download",
                expected: self.len(),
                got: out.len(),
            });
        }
        let mut encoder = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("fft download"),
            });
        encoder.copy_buffer_to_buffer(&self.data, 0, &self.staging, 0, self.data.size());
        ctx.queue().submit([encoder.finish()]);
        read_mapped(ctx, &self.staging, "FFT staging buffer", |bytes| {
            out.copy_from_slice(bytemuck::cast_slice(bytes));
        })
    }
}

/// Maps `buffer` for reading, waits, hands its bytes to `read`, unmaps.
pub fn read_mapped(
    ctx: &GpuContext,
    buffer: &wgpu::Buffer,
    what: &'static str,
    read: impl FnOnce(&[u8]),
) -> Result<(), GpuError> {
    let slice = buffer.slice(..);
    let (sender, receiver) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |result| {
        // The receiver lives until after the poll below.
        let _ = sender.send(result);
    });
    ctx.wait_idle()?;
    match receiver.recv() {
        Ok(Ok(())) => {}
        Ok(Err(source)) => return Err(GpuError::Map { what, source }),
        Err(_) => {
            return Err(GpuError::Wgpu {
                what: what.to_owned(),
                message: "map callback dropped without a result".to_owned(),
            });
        }
    }
    let result = match slice.get_mapped_range() {
        Ok(view) => {
            read(&view);
            Ok(())
        }
        Err(e) => Err(GpuError::Wgpu {
            what: what.to_owned(),
            message: format!("mapped range: {e}"),
        }),
    };
    buffer.unmap();
    result
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cpu::{self, Complex64, relative_l2_error};
    use crate::testing::test_context;

    /// Deterministic pseudo-random complex samples in [−1, 1), exactly
    /// representable in f32 (splitmix64).
    fn signal(len: usize, seed: u64) -> Vec<[f32; 2]> {
        let mut state = seed;
        let mut next = || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^= z >> 31;
            (z >> 40) as f32 / (1u32 << 24) as f32 * 2.0 - 1.0
        };
        (0..len).map(|_| [next(), next()]).collect()
    }

    fn widen(x: &[[f32; 2]]) -> Vec<Complex64> {
        x.iter()
            .map(|v| [f64::from(v[0]), f64::from(v[1])])
            .collect()
    }

    /// Forward on the GPU vs the f64 reference, then inverse back to the
    /// input; returns (forward error, round-trip error).
    fn parity(ctx: &GpuContext, w: u32, h: u32, c: u32) -> (f64, f64) {
        let fft = GpuFft2d::new(ctx, w, h, c).unwrap();
        let x = signal(fft.len(), u64::from(w * 31 + h * 7 + c));
        let mut reference = widen(&x);
        cpu::fft2d(&mut reference, w as usize, h as usize, c as usize, false).unwrap();
        fft.upload(ctx, &x).unwrap();
        fft.run(ctx, FftDirection::Forward);
        let mut out = vec![[0.0f32; 2]; fft.len()];
        fft.download(ctx, &mut out).unwrap();
        let forward_err = relative_l2_error(&widen(&out), &reference);
        fft.run(ctx, FftDirection::Inverse);
        fft.download(ctx, &mut out).unwrap();
        let round_trip_err = relative_l2_error(&widen(&out), &widen(&x));
        println!(
            "{w}x{h}x{c}: {} stages, forward rel err {forward_err:.2e}, round trip {round_trip_err:.2e}",
            fft.stage_count()
        );
        (forward_err, round_trip_err)
    }

    #[test]
    fn fft_8x8_rgb_matches_the_naive_dft() {
        let Some(ctx) = test_context("fft_8x8_rgb_matches_the_naive_dft") else {
            return;
        };
        // Independent definition: 2D naive DFT, rows then columns.
        let (w, h, c) = (8usize, 8usize, 3usize);
        let fft = GpuFft2d::new(ctx, 8, 8, 3).unwrap();
        let x = signal(w * h * c, 8);
        let mut reference = widen(&x);
        for plane in reference.chunks_exact_mut(w * h) {
            for row in plane.chunks_exact_mut(w) {
                row.copy_from_slice(&cpu::dft_naive(row, false));
            }
            for xi in 0..w {
                let column: Vec<Complex64> = (0..h).map(|y| plane[y * w + xi]).collect();
                for (y, v) in cpu::dft_naive(&column, false).into_iter().enumerate() {
                    plane[y * w + xi] = v;
                }
            }
        }
        fft.upload(ctx, &x).unwrap();
        fft.run(ctx, FftDirection::Forward);
        let mut out = vec![[0.0f32; 2]; fft.len()];
        fft.download(ctx, &mut out).unwrap();
        let err = relative_l2_error(&widen(&out), &reference);
        println!("8x8x3 vs naive DFT: rel err {err:.2e}");
        assert!(err <= 1e-5, "{err:e}");
        let (forward, round_trip) = parity(ctx, 8, 8, 3);
        assert!(forward <= 1e-5 && round_trip <= 1e-5);
    }

    #[test]
    fn fft_64_and_256_rgb_match_the_f64_reference() {
        let Some(ctx) = test_context("fft_64_and_256_rgb_match_the_f64_reference") else {
            return;
        };
        for n in [64, 256] {
            let (forward, round_trip) = parity(ctx, n, n, 3);
            assert!(forward <= 1e-5, "{n}²: forward {forward:e}");
            assert!(round_trip <= 1e-5, "{n}²: round trip {round_trip:e}");
        }
    }

    #[test]
    fn fft_non_square_odd_stage_count_and_wavelength_batch() {
        let Some(ctx) = test_context("fft_non_square_odd_stage_count_and_wavelength_batch") else {
            return;
        };
        // 16 = 4² (2 stages) by 32 = 4²·2 (3 stages): odd total, result
        // copied back from scratch; 2 = one radix-2 stage; 9 planes.
        for (w, h, c) in [(16, 32, 2), (32, 16, 1), (2, 4, 1), (128, 8, 9)] {
            let (forward, round_trip) = parity(ctx, w, h, c);
            assert!(forward <= 1e-5, "{w}x{h}x{c}: forward {forward:e}");
            assert!(round_trip <= 1e-5, "{w}x{h}x{c}: round trip {round_trip:e}");
        }
    }

    #[test]
    fn fft_2048_rows_match_the_f64_reference() {
        let Some(ctx) = test_context("fft_2048_rows_match_the_f64_reference") else {
            return;
        };
        // 1-D transforms of length 2048 (4⁵·2): 4 rows, no column stages.
        let (forward, round_trip) = parity(ctx, 2048, 4, 1);
        assert!(forward <= 1e-5, "forward {forward:e}");
        assert!(round_trip <= 1e-5, "round trip {round_trip:e}");
    }

    #[test]
    fn bad_sizes_and_lengths_are_errors() {
        let Some(ctx) = test_context("bad_sizes_and_lengths_are_errors") else {
            return;
        };
        for (w, h, c) in [(12, 8, 1), (8, 4096, 1), (8, 8, 0), (0, 8, 1)] {
            let err = GpuFft2d::new(ctx, w, h, c).unwrap_err();
            assert!(matches!(err, GpuError::FftSize { .. }), "{err}");
        }
        // 2048²×5 planes = 160 MiB: over the default 128 MiB storage binding.
        let err = GpuFft2d::new(ctx, 2048, 2048, 5).unwrap_err();
        assert!(err.to_string().contains("storage binding limit"), "{err}");
        let pass = FftPass::new(ctx).unwrap();
        let fft = GpuFft2d::with_pass(ctx, &pass, 4, 4, 1).unwrap();
        assert!(matches!(
            fft.upload(ctx, &[[0.0; 2]; 15]),
            Err(GpuError::Length {
                expected: 16,
                got: 15,
                ..
            })
        ));
        let mut out = [[0.0; 2]; 17];
        assert!(matches!(
            fft.download(ctx, &mut out),
            Err(GpuError::Length { .. })
        ));
    }
}
