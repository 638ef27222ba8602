//! `gazelight psf`: one glare kernel → kernel.exr, kernel.png, psf.json
//! (and optionally a log-log plot of its radial profile against CIE 146).

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::Args;
use gazelight_vision::RgbImage;
use gazelight_vision::psf::{GlareScale, PsfBuilder, PsfKernel, PsfParams};
use gazelight_vision::scene::write_exr;
use gazelight_vision::stray_light::cie146_veil_per_sr;
use plotters::prelude::*;

/// `on` / `off`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum OnOff {
    On,
    Off,
}

/// Arguments of `gazelight psf`.
#[derive(Args, Debug)]
pub struct PsfArgs {
    /// Pupil diameter, mm.
    #[arg(long)]
    pub pupil_mm: f64,
    /// Display pixels per degree (default 13.85, the HTC Vive Pro of 001).
    #[arg(long)]
    pub ppd: Option<f64>,
    /// Kernel field, degrees: the kernel covers ±F/2 (default 40).
    #[arg(long, value_name = "F")]
    pub field_deg: Option<f64>,
    /// Observer age, years (CIE 146:2002; default 25).
    #[arg(long)]
    pub age_years: Option<f64>,
    /// Ocular pigmentation (CIE 146:2002: 0 very dark … 1.2 very light eyes;
    /// default 0.5).
    #[arg(long)]
    pub pigmentation: Option<f64>,
    /// Number of scattering particles in the lens/cornea field (0 = a clean
    /// aperture: an Airy pattern).
    #[arg(long)]
    pub particles: Option<usize>,
    /// Particle diameter, µm (default 5).
    #[arg(long)]
    pub particle_um: Option<f64>,
    /// Intraocular stray light (the CIE 146 veil) in the kernel.
    #[arg(long, value_enum, default_value = "on")]
    pub stray_light: OnOff,
    /// Angular scale: `physical` (default) or `seed` (001's own: the FFT
    /// field laid over the glare window).
    #[arg(long, default_value = "physical")]
    pub glare_scale: GlareScale,
    /// Also write a log-log plot of the kernel's radial luminance profile
    /// against the CIE 146 equation to this PNG.
    #[arg(long, value_name = "PNG")]
    pub plot: Option<PathBuf>,
    /// Output directory (created). A previous kernel in it (kernel.exr,
    /// kernel.png, psf.json) is refused unless --force.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Clear a previous kernel's files in --out first.
    #[arg(long)]
    pub force: bool,
}

/// Runs `gazelight psf`.
pub fn run(args: PsfArgs) -> anyhow::Result<()> {
    let mut params = PsfParams {
        pupil_mm: args.pupil_mm,
        stray_light: args.stray_light == OnOff::On,
        glare_scale: args.glare_scale,
        ..PsfParams::default()
    };
    // One pupil: the sampling is chosen for it alone.
    if args.pupil_mm.is_finite() && args.pupil_mm > 0.0 {
        params.pupil_range_mm = [args.pupil_mm, args.pupil_mm];
    }
    if let Some(n) = args.particles {
        params.particles = n;
    }
    if let Some(s) = args.particle_um {
        params.particle_um = s;
    }
    if let Some(p) = args.ppd {
        params.ppd = p;
    }
    if let Some(f) = args.field_deg {
        params.field_deg = f;
    }
    if let Some(a) = args.age_years {
        params.age_years = a;
    }
    if let Some(p) = args.pigmentation {
        params.pigmentation = p;
    }
    crate::out_dir::prepare(
        "psf",
        &args.out,
        crate::out_dir::OutKind::Kernel,
        &[],
        args.force,
    )?;
    let started = std::time::Instant::now();
    let builder = PsfBuilder::new(params.clone())?;
    let build_ms = started.elapsed().as_secs_f64() * 1e3;
    let kernel = builder.kernel();
    let sampling = *builder.sampling();
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {}", args.out.display()))?;
    let img = RgbImage::from_pixels(kernel.size, kernel.size, kernel.rgb.clone())?;
    write_exr(&args.out.join("kernel.exr"), &img)?;

    // Log-scaled preview: 6 decades below the peak.
    let peak = kernel
        .rgb
        .iter()
        .flat_map(|p| p.iter().copied())
        .fold(0.0f32, f32::max)
        .max(f32::MIN_POSITIVE);
    let decades = 6.0f32;
    let png: Vec<u8> = kernel
        .rgb
        .iter()
        .flat_map(|p| {
            p.map(|v| {
                let l = ((v.max(0.0) / peak).max(1e-12).log10() + decades) / decades;
                (l.clamp(0.0, 1.0) * 255.0).round() as u8
            })
        })
        .collect();
    let png_path = args.out.join("kernel.png");
    image::save_buffer(
        &png_path,
        &png,
        kernel.size as u32,
        kernel.size as u32,
        image::ColorType::Rgb8,
    )
    .with_context(|| format!("cannot write {}", png_path.display()))?;

    let energy = kernel.energy();
    let json = serde_json::json!({
        "pupil_mm": kernel.pupil_mm,
        "deg_per_px": kernel.deg_per_px,
        "ppd": 1.0 / kernel.deg_per_px,
        "size": kernel.size,
        "field_deg": params.field_deg,
        "age_years": params.age_years,
        "pigmentation": params.pigmentation,
        "stray_light": params.has_stray_light(),
        "glare_scale": params.glare_scale.to_string(),
        "particles": params.particles,
        "particle_um": params.particle_um,
        "particle_scatter_fraction": builder.particle_scatter_fraction(kernel.pupil_mm),
        "stray_light_energy": builder.stray_light_energy(),
        "grid_size": sampling.grid_size,
        "pupil_plane_mm": sampling.pupil_plane_mm,
        "near_radius_px": sampling.near_radius_px,
        "wavelengths_nm": kernel.wavelengths_nm,
        "energy": energy,
        "build_ms": build_ms,
        "preview": "kernel.png is log10 scaled: black = 1e-6 of the peak, white = the peak",
    });
    let json_path = args.out.join("psf.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("cannot write {}", json_path.display()))?;
    if let Some(plot) = &args.plot {
        write_profile_plot(plot, kernel, &params)?;
    }
    println!(
        "PSF for a {:.2} mm pupil: {}x{} px at {:.4}°/px (±{:.2}°), grid {} over {:.1} mm, energy R {:.6} G {:.6} B {:.6}, stray light {:.3}, built in {:.0} ms → {}",
        kernel.pupil_mm,
        kernel.size,
        kernel.size,
        kernel.deg_per_px,
        params.field_deg / 2.0,
        sampling.grid_size,
        sampling.pupil_plane_mm,
        energy[0],
        energy[1],
        energy[2],
        builder.stray_light_energy(),
        build_ms,
        args.out.display()
    );
    Ok(())
}

/// Azimuthal mean of the kernel's luminance per steradian in rings of one
/// pixel: `(θ degrees, per sr)`, θ > 0.
fn radial_profile(kernel: &PsfKernel) -> Vec<(f64, f64)> {
    let r = kernel.centre() as isize;
    let mut sum = vec![0.0f64; r as usize + 1];
    let mut count = vec![0usize; r as usize + 1];
    for dy in -r..=r {
        for dx in -r..=r {
            let d = ((dx * dx + dy * dy) as f64).sqrt().round() as usize;
            if d <= r as usize {
                sum[d] += kernel.luminance_per_sr(dx, dy);
                count[d] += 1;
            }
        }
    }
    (1..=r as usize)
        .filter(|&i| count[i] > 0)
        .map(|i| (i as f64 * kernel.deg_per_px, sum[i] / count[i] as f64))
        .collect()
}

/// Log-log plot: the kernel's radial luminance profile per sr and the CIE
/// 146:2002 equation for the same observer.
fn write_profile_plot(path: &Path, kernel: &PsfKernel, params: &PsfParams) -> anyhow::Result<()> {
    crate::output::register_font()?;
    let profile: Vec<(f64, f64)> = radial_profile(kernel)
        .into_iter()
        .filter(|&(_, v)| v > 0.0)
        .map(|(t, v)| (t.log10(), v.log10()))
        .collect();
    let t_lo = 0.1f64.max(kernel.deg_per_px);
    let t_hi = params.field_deg / 2.0;
    let cie: Vec<(f64, f64)> = (0..=200)
        .map(|i| {
            let t = t_lo * (t_hi / t_lo).powf(f64::from(i) / 200.0);
            (
                t.log10(),
                cie146_veil_per_sr(t, params.age_years, params.pigmentation).log10(),
            )
        })
        .collect();
    let (y_lo, y_hi) = profile
        .iter()
        .chain(&cie)
        .filter(|p| p.0 >= t_lo.log10() - 1e-9)
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.1), b.max(p.1))
        });
    let (y_lo, y_hi) = if y_lo.is_finite() {
        (y_lo.floor() - 0.2, y_hi.ceil() + 0.2)
    } else {
        (-4.0, 6.0)
    };
    let draw = |buf: &mut [u8], size: (u32, u32)| -> Result<(), Box<dyn std::error::Error>> {
        let root = BitMapBackend::with_buffer(buf, size).into_drawing_area();
        root.fill(&WHITE)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "glare kernel vs CIE 146:2002 ({:.1} mm pupil, {:.1} ppd, age {:.0}, p = {:.2})",
                    kernel.pupil_mm,
                    1.0 / kernel.deg_per_px,
                    params.age_years,
                    params.pigmentation
                ),
                ("sans-serif", 20),
            )
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(t_lo.log10()..t_hi.log10(), y_lo..y_hi)?;
        chart
            .configure_mesh()
            .x_desc("log10 θ (degrees)")
            .y_desc("log10 L_veil / E_glare (sr⁻¹)")
            .draw()?;
        chart
            .draw_series(LineSeries::new(cie.iter().copied(), BLUE.stroke_width(3)))?
            .label("CIE 146:2002 General Disability Glare equation")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE));
        chart
            .draw_series(LineSeries::new(
                profile.iter().copied().filter(|p| p.0 >= t_lo.log10()),
                RED.stroke_width(2),
            ))?
            .label("kernel: ring mean of luminance per sr")
            .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], RED));
        chart
            .configure_series_labels()
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .draw()?;
        root.present()?;
        Ok(())
    };
    crate::output::write_chart_png(path, (900, 600), draw)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))
}
