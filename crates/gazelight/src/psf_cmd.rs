//! `gazelight psf`: one glare kernel → kernel.exr, kernel.png, psf.json.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use gazelight_vision::RgbImage;
use gazelight_vision::psf::{PsfParams, build_kernel};
use gazelight_vision::scene::write_exr;

/// Arguments of `gazelight psf`.
#[derive(Args, Debug)]
pub struct PsfArgs {
    /// Pupil diameter, mm.
    #[arg(long)]
    pub pupil_mm: f64,
    /// Number of scattering particles in the lens/cornea field (0 = a clean
    /// aperture: an Airy pattern).
    #[arg(long)]
    pub particles: Option<usize>,
    /// Output kernel size, display pixels.
    #[arg(long)]
    pub size: Option<usize>,
    /// Display pixels per degree (default 13.85, the HTC Vive Pro of 001).
    #[arg(long)]
    pub ppd: Option<f64>,
    /// Pupil-plane grid (FFT) size, a power of two.
    #[arg(long)]
    pub grid: Option<usize>,
    /// Output directory (created).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

/// Runs `gazelight psf`.
pub fn run(args: PsfArgs) -> anyhow::Result<()> {
    let mut params = PsfParams {
        pupil_mm: args.pupil_mm,
        ..PsfParams::default()
    };
    if let Some(n) = args.particles {
        params.particles = n;
    }
    if let Some(s) = args.size {
        params.kernel_size = s;
    }
    if let Some(p) = args.ppd {
        params.ppd = p;
    }
    if let Some(g) = args.grid {
        params.grid_size = g;
    }
    let started = std::time::Instant::now();
    let kernel = build_kernel(&params)?;
    let build_ms = started.elapsed().as_secs_f64() * 1e3;
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
        "particles": params.particles,
        "grid_size": params.grid_size,
        "pupil_plane_mm": params.pupil_plane_mm,
        "wavelengths_nm": kernel.wavelengths_nm,
        "energy": energy,
        "build_ms": build_ms,
        "preview": "kernel.png is log10 scaled: black = 1e-6 of the peak, white = the peak",
    });
    let json_path = args.out.join("psf.json");
    std::fs::write(&json_path, serde_json::to_string_pretty(&json)? + "\n")
        .with_context(|| format!("cannot write {}", json_path.display()))?;
    println!(
        "PSF for a {:.2} mm pupil: {}x{} px at {:.4}°/px, energy R {:.6} G {:.6} B {:.6}, built in {:.0} ms → {}",
        kernel.pupil_mm,
        kernel.size,
        kernel.size,
        kernel.deg_per_px,
        energy[0],
        energy[1],
        energy[2],
        build_ms,
        args.out.display()
    );
    Ok(())
}
