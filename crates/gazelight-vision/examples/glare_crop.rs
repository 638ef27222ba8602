#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The README's glare figure: the default night view (assets/night.exr, the
//! default render's view at 720×800) with the gaze on the brightest street
//! lamp, through the CPU pipeline with glare on and off; writes a side-by-side
//! crop around the lamp and prints the measured veil.
//!
//! Run: `cargo run --release -p gazelight-vision --example glare_crop -- docs/glare_on_off.png`

use std::path::Path;

use gazelight_vision::RgbImage;
use gazelight_vision::image::{luminance, ring_mean_luminance as ring_mean};
use gazelight_vision::pipeline::{DisplayFrame, FrameInput, FramePipeline, PipelineConfig};
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "glare_on_off.png".to_string());
    let scene_path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../assets/night.exr");
    let scene = Scene::load(&scene_path, LuminanceScale::default())?;
    let view = ViewParams {
        yaw_deg: -78.4,
        pitch_deg: -6.0,
        hfov_deg: 90.0,
        width: 720,
        height: 800,
    };
    let mut img = RgbImage::new(view.width, view.height);
    PanoramaView::new(view)?.render(&scene.image, &mut img);
    let (w, h) = (img.width, img.height);
    // The brightest pixel: the lamp.
    let (lamp_i, _) = img
        .pixels
        .iter()
        .enumerate()
        .map(|(i, p)| (i, luminance(*p)))
        .fold((0, 0.0f32), |a, b| if b.1 > a.1 { b } else { a });
    let (lx, ly) = (lamp_i % w, lamp_i / w);
    let ppd = 1.0 / view.deg_per_px();
    let input = FrameInput {
        gaze_uv: [(lx as f32 + 0.5) / w as f32, (ly as f32 + 0.5) / h as f32],
        pupil_mm: 6.0,
        dt_secs: 1.0 / 90.0,
    };
    let mut frames = Vec::new();
    let mut veils = Vec::new();
    for glare in [true, false] {
        let mut config = PipelineConfig {
            keep_retinal: true,
            ..PipelineConfig::default()
        };
        config.glare.enabled = glare;
        let mut p = FramePipeline::new(config, w, h, view.deg_per_px())?;
        let mut frame = DisplayFrame::new(w, h);
        // Dark-adapted on the ground first, then the gaze lands on the lamp.
        let ground = FrameInput {
            gaze_uv: [input.gaze_uv[0], 0.9],
            ..input
        };
        p.process(&img, &ground, &mut frame)?;
        p.process(&img, &input, &mut frame)?;
        let v: Vec<(f64, f64)> = [1.0, 2.0, 5.0, 10.0]
            .iter()
            .map(|&t| {
                (
                    t,
                    ring_mean(p.retinal(), lx, ly, (t * ppd).round() as usize),
                )
            })
            .collect();
        veils.push(v);
        frames.push(frame);
    }
    println!(
        "lamp at ({lx}, {ly}), {:.0} cd/m², {ppd:.2} ppd, 6 mm pupil, gaze on the lamp",
        luminance(img.get(lx, ly))
    );
    for ((t, on), (_, off)) in veils[0].iter().zip(&veils[1]) {
        println!(
            "retinal luminance at {t:>4.1}° from the lamp: glare on {on:.4} cd/m², off {off:.4} cd/m², ratio {:.1}",
            on / off.max(1e-9)
        );
    }
    // Side by side: ±10° around the lamp, glare on (left) and off (right).
    let half = (10.0 * ppd).round() as isize;
    let side = (2 * half + 1) as usize;
    let gap = 8usize;
    let mut rgb = vec![255u8; (2 * side + gap) * side * 3];
    for (k, frame) in frames.iter().enumerate() {
        for j in 0..side {
            for i in 0..side {
                let x = lx as isize - half + i as isize;
                let y = ly as isize - half + j as isize;
                if x < 0 || y < 0 || x >= w as isize || y >= h as isize {
                    continue;
                }
                let src = (y as usize * w + x as usize) * 4;
                let dst = (j * (2 * side + gap) + k * (side + gap) + i) * 3;
                rgb[dst..dst + 3].copy_from_slice(&frame.rgba8[src..src + 3]);
            }
        }
    }
    image::save_buffer(
        &out,
        &rgb,
        (2 * side + gap) as u32,
        side as u32,
        image::ColorType::Rgb8,
    )?;
    println!(
        "wrote {out} ({}x{side}: glare on | glare off, ±10° around the lamp)",
        2 * side + gap
    );
    Ok(())
}
