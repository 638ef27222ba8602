//! Stage 4's full-field stray light on the GPU, the twin of
//! `shaders/far_glare.wgsl` and of
//! [`gazelight_vision::far_glare::FarField`] (issue 46): the CIE 146:2002
//! veil of every pixel onto every other at their angle, out to 90°, on the
//! CPU's coarse angular grid, joined to the window glare by the same split
//! ([`gazelight_vision::far_glare::FarSplit`]; docs/perception.md, "Energy
//! bookkeeping").
//!
//! The geometry (blocks, their solid angles and grid cells, the bilinear
//! spread back to the pixels) is the CPU [`FarField`]'s, read from one built
//! for the same view when the geometry is set and uploaded as one table;
//! the kernels are sampled by [`FarSplit::cell_kernels`] (the CPU's
//! samples) on the next power of two of the cells the CPU needs (a larger
//! grid only adds zeros: the convolution is linear in both) and transformed
//! once by [`GpuFft2d`]. Per frame: block sums (before the window glare's
//! blend), splat, FFT, spectrum product, inverse FFT, read-back at the
//! blocks, blend (after the window glare's blend). Nothing is allocated per
//! frame.
//!
//! [`FarSplit::cell_kernels`]: gazelight_vision::far_glare::FarSplit::cell_kernels

use bytemuck::{Pod, Zeroable};
use gazelight_vision::far_glare::FarField;

use crate::context::GpuContext;
use crate::error::GpuError;
use crate::fft::{FftDirection, GpuFft2d};
use crate::frame::{STORAGE, UNIFORM, create_buffer, tiles};
use crate::glare::GlareParams;
use crate::pass::{Binding, PassDescriptor, PassLayout};
use crate::shaders;

/// Uniforms of `far_glare.wgsl` (`struct FarParams`), field by field.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Pod, Zeroable)]
pub struct FarParams {
    /// Frame width, pixels.
    pub width: u32,
    /// Frame height, pixels.
    pub height: u32,
    /// Block size, pixels.
    pub block_px: u32,
    /// Blocks per row.
    pub blocks_w: u32,
    /// Blocks per column.
    pub blocks_h: u32,
    /// Grid cells per side (the FFT size, a power of two).
    pub n: u32,
    /// Whether the window glare placed its window this frame (1) or not (0).
    pub placed: u32,
    /// Table index of the cells' entry ranges.
    pub cells_at: u32,
    /// Table index of the cells' entries (block, bilinear weight).
    pub entries_at: u32,
    /// Table index of the display columns' block columns.
    pub cols_at: u32,
    /// Table index of the display rows' block rows.
    pub rows_at: u32,
    /// Padding.
    pub _pad0: u32,
}

/// `shaders/far_glare.wgsl`: block sums, splat, spectrum product, block
/// read-back and blend.
pub const FAR_GLARE_PASS: PassDescriptor = PassDescriptor {
    shader: shaders::FAR_GLARE,
    entry_points: &["block_sums", "splat", "multiply", "read_blocks", "blend"],
    bindings: &[
        Binding::uniform::<FarParams>("params"),
        Binding::uniform::<GlareParams>("glare"),
        Binding::read_write::<[f32; 4]>("work"),
        Binding::read_write::<[f32; 4]>("blocks"),
        Binding::read::<[u32; 4]>("tables"),
        Binding::read_write::<[f32; 2]>("data"),
        Binding::read::<[f32; 2]>("spectrum"),
    ],
};

/// The twin of `shaders/far_glare.wgsl` ([`FAR_GLARE_PASS`]). Bindings:
/// 0 [`FarParams`], 1 the window glare's [`GlareParams`], 2 the working
/// frame (RGBA f32), 3 the block sums and veils, 4 the geometry table,
/// 5 the FFT's data buffer, 6 the kernels' spectra (read-only).
#[derive(Debug, Clone)]
pub struct FarGlarePass {
    pub(crate) layout: PassLayout,
    pub(crate) block_sums: wgpu::ComputePipeline,
    pub(crate) splat: wgpu::ComputePipeline,
    pub(crate) multiply: wgpu::ComputePipeline,
    pub(crate) read_blocks: wgpu::ComputePipeline,
    pub(crate) blend: wgpu::ComputePipeline,
}

impl FarGlarePass {
    /// Checks the shader against the device limits and builds the pipelines.
    pub fn new(ctx: &GpuContext) -> Result<Self, GpuError> {
        let (layout, [block_sums, splat, multiply, read_blocks, blend]) =
            FAR_GLARE_PASS.build(ctx)?;
        Ok(Self {
            layout,
            block_sums,
            splat,
            multiply,
            read_blocks,
            blend,
        })
    }
}

/// The host-side tables of a far field's geometry for the GPU grid of
/// `n` cells per side, in `far_glare.wgsl`'s layout, and the sections'
/// starts (cells, entries, columns, rows).
pub fn far_tables(far: &FarField, n: usize) -> (Vec<[u32; 4]>, [u32; 4]) {
    let (width, height) = far.size();
    let cells: Vec<_> = far.block_cells().collect();
    let nb = cells.len();
    // Per cell, the (block, weight) pairs that splat into it: the CPU's
    // bilinear four of every block, as a gather.
    let mut per_cell: Vec<Vec<(u32, f32)>> = vec![Vec::new(); n * n];
    let mut blocks = Vec::with_capacity(nb);
    for (b, &(om, [ix, iy], fx, fy)) in cells.iter().enumerate() {
        let c = iy * n + ix;
        blocks.push([om.to_bits(), fx.to_bits(), fy.to_bits(), c as u32]);
        for (idx, wgt) in [
            (c, (1.0 - fx) * (1.0 - fy)),
            (c + 1, fx * (1.0 - fy)),
            (c + n, (1.0 - fx) * fy),
            (c + n + 1, fx * fy),
        ] {
            per_cell[idx].push((b as u32, wgt));
        }
    }
    let cells_at = nb;
    let entries_at = cells_at + n * n;
    let total: usize = per_cell.iter().map(Vec::len).sum();
    let cols_at = entries_at + total;
    let rows_at = cols_at + width;
    let mut table = blocks;
    table.reserve(n * n + total + width + height);
    let mut first = 0u32;
    for list in &per_cell {
        table.push([first, list.len() as u32, 0, 0]);
        first += list.len() as u32;
    }
    for list in &per_cell {
        for &(b, w) in list {
            table.push([b, w.to_bits(), 0, 0]);
        }
    }
    for &(i0, fx) in far.column_hat() {
        table.push([i0, fx.to_bits(), 0, 0]);
    }
    for y in 0..height {
        let (j0, j1, fy) = far.row_hat(y);
        table.push([j0 as u32, j1 as u32, fy.to_bits(), 0]);
    }
    let at = [cells_at, entries_at, cols_at, rows_at].map(|v| v as u32);
    (table, at)
}

/// The far field of [`crate::frame::GpuFramePipeline`]'s glare stage: its
/// pass, table, FFT plan, kernel spectra and buffers, for one geometry.
pub(crate) struct FarStage {
    pass: FarGlarePass,
    params: FarParams,
    uniform: wgpu::Buffer,
    fft: GpuFft2d,
    group: wgpu::BindGroup,
    /// `E_tail`, `E_near` of the split.
    energies: (f32, f32),
    _buffers: [wgpu::Buffer; 3],
}

impl FarStage {
    /// The GPU twin of `far` (the CPU far field of the same view), on the
    /// working frame `work`, with the window glare's uniforms `glare`.
    pub(crate) fn new(
        ctx: &GpuContext,
        far: &FarField,
        work: &wgpu::Buffer,
        glare: &wgpu::Buffer,
    ) -> Result<Self, GpuError> {
        let n = far.grid_needed().next_power_of_two();
        let fft = GpuFft2d::new(ctx, n as u32, n as u32, 3)?;
        let pass = FarGlarePass::new(ctx)?;
        let (width, height) = far.size();
        let (bw, bh) = far.blocks();
        let (table, [cells_at, entries_at, cols_at, rows_at]) = far_tables(far, n);
        let params = FarParams {
            width: width as u32,
            height: height as u32,
            block_px: far.block_px() as u32,
            blocks_w: bw as u32,
            blocks_h: bh as u32,
            n: n as u32,
            placed: 0,
            cells_at,
            entries_at,
            cols_at,
            rows_at,
            _pad0: 0,
        };
        let uniform = create_buffer(
            ctx,
            "far glare params",
            size_of::<FarParams>() as u64,
            UNIFORM,
        )?;
        let blocks = create_buffer(ctx, "far glare blocks", (bw * bh * 3 * 16) as u64, STORAGE)?;
        let tables = create_buffer(ctx, "far glare tables", (table.len() * 16) as u64, STORAGE)?;
        let spectrum = create_buffer(
            ctx,
            "far glare kernel spectra",
            (2 * n * n * 8) as u64,
            STORAGE,
        )?;
        let queue = ctx.queue();
        queue.write_buffer(&uniform, 0, bytemuck::bytes_of(&params));
        queue.write_buffer(&tables, 0, bytemuck::cast_slice(&table));
        // The kernels (tail, near) sampled at each cell offset, wrapped,
        // transformed once.
        let split = far.split();
        let mut grid = vec![[0.0f32; 2]; 3 * n * n];
        let offset = |i: usize| {
            if i <= n / 2 {
                i as f64
            } else {
                i as f64 - n as f64
            }
        };
        for iy in 0..n {
            for ix in 0..n {
                let (t, q) = split.cell_kernels(offset(ix), offset(iy));
                grid[iy * n + ix] = [t, 0.0];
                grid[n * n + iy * n + ix] = [q, 0.0];
            }
        }
        fft.upload(ctx, &grid)?;
        let mut encoder = ctx
            .device()
            .create_command_encoder(&wgpu::CommandEncoderDescriptor {
                label: Some("far glare kernel spectra"),
            });
        fft.encode(&mut encoder, FftDirection::Forward, None);
        encoder.copy_buffer_to_buffer(fft.data_buffer(), 0, &spectrum, 0, spectrum.size());
        queue.submit([encoder.finish()]);
        let group = pass.layout.bind_buffers(
            ctx,
            &[
                &uniform,
                glare,
                work,
                &blocks,
                &tables,
                fft.data_buffer(),
                &spectrum,
            ],
        )?;
        Ok(Self {
            pass,
            params,
            uniform,
            fft,
            group,
            energies: far.energies(),
            _buffers: [blocks, tables, spectrum],
        })
    }

    /// `keep0` and `keep_slope` of the window glare's blend: a source pixel
    /// of weight `w` keeps `(1 − w)(1 − E_near) − E_tail` of its light.
    pub(crate) fn keep(&self) -> (f32, f32) {
        let (e_tail, e_near) = self.energies;
        (1.0 - e_near - e_tail, 1.0 - e_near)
    }

    /// Records the block sums of the frame (before the window glare's
    /// blend); `placed`: whether the window glare placed its window (its
    /// uniforms hold it).
    pub(crate) fn encode_sums(
        &mut self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        placed: bool,
    ) {
        let placed = u32::from(placed);
        if placed != self.params.placed {
            self.params.placed = placed;
            ctx.queue()
                .write_buffer(&self.uniform, 0, bytemuck::bytes_of(&self.params));
        }
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("stage 4: far glare block sums"),
            timestamp_writes: None,
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.pass.block_sums);
        let (gx, gy) = tiles(self.params.blocks_w, self.params.blocks_h);
        pass.dispatch_workgroups(gx, gy, 1);
    }

    /// Records the convolution on the grid and the blend (after the window
    /// glare's blend), with `timestamp_writes` on the blend.
    pub(crate) fn encode_veil(
        &self,
        ctx: &GpuContext,
        encoder: &mut wgpu::CommandEncoder,
        timestamp_writes: Option<wgpu::ComputePassTimestampWrites<'_>>,
    ) {
        let n = self.params.n;
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("stage 4: far glare splat"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, &self.group, &[]);
            pass.set_pipeline(&self.pass.splat);
            let (gx, gy) = tiles(n, n);
            pass.dispatch_workgroups(gx, gy, 1);
        }
        self.fft.encode(encoder, FftDirection::Forward, None);
        {
            let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("stage 4: far glare spectrum product"),
                timestamp_writes: None,
            });
            pass.set_bind_group(0, &self.group, &[]);
            pass.set_pipeline(&self.pass.multiply);
            let max = ctx.limits().max_compute_workgroups_per_dimension;
            let groups = (3 * n * n).div_ceil(64);
            let gx = groups.min(max);
            pass.dispatch_workgroups(gx, groups.div_ceil(gx), 1);
        }
        self.fft.encode(encoder, FftDirection::Inverse, None);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("stage 4: far glare blend"),
            timestamp_writes,
        });
        pass.set_bind_group(0, &self.group, &[]);
        pass.set_pipeline(&self.pass.read_blocks);
        let (gx, gy) = tiles(self.params.blocks_w, self.params.blocks_h);
        pass.dispatch_workgroups(gx, gy, 1);
        pass.set_pipeline(&self.pass.blend);
        let (gx, gy) = tiles(self.params.width, self.params.height);
        pass.dispatch_workgroups(gx, gy, 1);
    }
}

#[cfg(test)]
mod tests {
    use crate::frame::FrameSizes;
    use crate::glare::GlareStage;
    use crate::testing::pass_harness::{read, storage, texels};
    use gazelight_vision::RgbImage;
    use gazelight_vision::glare::GlareConvolver;
    use gazelight_vision::pipeline::{PipelineConfig, far_field};
    use gazelight_vision::pooling::PlaneAngles;
    use gazelight_vision::psf::PsfBuilder;

    /// The lamp of the far-field tests (crates/gazelight/tests/
    /// glare_far_field.rs, the table), cd/m².
    const LAMP_CD_M2: f32 = 2e5;
    /// Its dark field, cd/m².
    const FIELD_CD_M2: f32 = 0.02;

    /// The window glare and the far field on the GPU against the CPU
    /// convolver with its far field, on the lamp scene (a dark field, one
    /// lamp of 2 × 2 pixels) in a 100° view of 96 × 80 pixels, uniform and
    /// rectilinear, and a 60° rectilinear view of 160 × 128 (3-pixel
    /// blocks): the gaze on the lamp and 38° from it (the lamp outside the
    /// window, its light on the fovea only through the far field).
    #[test]
    fn far_field_matches_the_cpu() {
        let Some(ctx) = crate::testing::test_context("far_field_matches_the_cpu") else {
            return;
        };
        let mut config = PipelineConfig::default();
        config.glare.far_field = true;
        let mut worst = 0.0f64;
        // (size, field of view, rectilinear): 1 px blocks, then 3 px ones.
        for (w, h, fov_deg, rectilinear) in [
            (96usize, 80usize, 100.0, false),
            (96, 80, 100.0, true),
            (160, 128, 60.0, true),
        ] {
            let dpp = fov_deg / w as f64;
            let angles = if rectilinear {
                PlaneAngles::symmetric(fov_deg, w, h)
            } else {
                PlaneAngles::Uniform { deg_per_px: dpp }
            };
            let mut img = RgbImage::new(w, h);
            for p in &mut img.pixels {
                *p = [FIELD_CD_M2; 3];
            }
            for (x, y) in [(30, 40), (31, 40), (30, 41), (31, 41)] {
                *img.get_mut(x, y) = [LAMP_CD_M2, 0.8 * LAMP_CD_M2, 0.6 * LAMP_CD_M2];
            }
            let mut params = config.glare.psf.clone();
            params.ppd = 1.0 / dpp;
            params.pupil_mm = 4.0;
            let builder = PsfBuilder::new(params.clone()).unwrap();
            let kernel = builder.kernel();
            let sizes = FrameSizes::new(&config, w as u32, h as u32);
            let mut conv = GlareConvolver::new(kernel, config.glare.window()).unwrap();
            let far = far_field(
                &config.glare,
                &params,
                kernel.size,
                kernel.deg_per_px,
                w,
                h,
                angles,
            )
            .unwrap()
            .expect("the far field is on");
            println!(
                "{angles:?}: block {} px, {:?} blocks, grid {} cells (CPU FFT {}, GPU {})",
                far.block_px(),
                far.blocks(),
                far.grid_needed(),
                far.grid_size(),
                far.grid_needed().next_power_of_two()
            );
            conv.set_far_field(Some(far));
            for gaze_px in [[31.0 + 38.0 / dpp, 41.0], [31.0, 41.0]] {
                let work = storage(ctx, &texels(&img));
                let mut stage = GlareStage::new(ctx, &config, dpp, &sizes, &work, angles).unwrap();
                assert!(stage.has_far_field());
                let mut encoder = ctx.device().create_command_encoder(&Default::default());
                stage.encode_kernel_spectrum(&mut encoder, None);
                stage.encode_window(ctx, &mut encoder, gaze_px, None);
                ctx.queue().submit([encoder.finish()]);
                let gpu: Vec<[f32; 4]> = read(ctx, &work);
                let mut cpu = img.clone();
                conv.apply(&mut cpu, gaze_px);
                // Every pixel more than 3° from the lamp within `tol` of
                // the CPU's value, and every pixel within 1e-6 of the peak.
                // With the lamp outside the window the frame holds the far
                // veil alone: 1e-4. With the lamp in it, the window's f32
                // FFTs of a lamp 10⁷× the field (CPU and GPU each) leave
                // noise of 1e-7 of the peak everywhere in the coarse window
                // (the whole frame here), a few per cent of the dark
                // field's veil: 5 %.
                let on_lamp = gaze_px == [31.0, 41.0];
                let tol = if on_lamp { 5e-2 } else { 1e-4 };
                let peak = cpu.pixels.iter().flatten().fold(0.0f32, |m, &v| m.max(v));
                let (mut err, mut peak_err, mut veil) = (0.0f64, 0.0f64, 0.0f64);
                for (i, (g, c)) in gpu.iter().zip(&cpu.pixels).enumerate() {
                    let (x, y) = ((i % w) as f64 + 0.5, (i / w) as f64 + 0.5);
                    let from_lamp_deg = (x - 31.0).hypot(y - 41.0) * dpp;
                    for k in 0..3 {
                        let (g, c) = (f64::from(g[k]), f64::from(c[k]));
                        peak_err = peak_err.max((g - c).abs() / f64::from(peak));
                        if from_lamp_deg > 3.0 {
                            err = err.max((g - c).abs() / c);
                            veil = veil.max(c / f64::from(FIELD_CD_M2));
                        }
                    }
                }
                println!(
                    "  gaze {gaze_px:?}: max relative error {err:.2e} beyond 3° of the lamp (its \
                     veil up to ×{veil:.0} the field), {peak_err:.2e} of the peak"
                );
                assert!(veil > 10.0, "the veil too weak to test: ×{veil}");
                assert!(err < tol, "{err:e}");
                assert!(peak_err < 1e-6, "{peak_err:e}");
                if !on_lamp {
                    worst = worst.max(err);
                }
            }
        }
        println!("worst relative error, the lamp outside the window: {worst:.2e}");
    }
}
