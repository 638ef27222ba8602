//! Both backends through [`Renderer`]: an installed kernel is the one each
//! convolves with, and the GPU's kernel and adaptation follow the CPU's.

use super::*;
use gazelight_gpu::testing::test_context;
use gazelight_vision::scene::{LuminanceScale, PanoramaView, Scene};
use gazelight_vision::temporal::AdaptationState;

/// The embedded night panorama seen towards the street lamp, at `w × h`.
fn demo_view(w: usize, h: usize) -> (RgbImage, f64) {
    let scene = Scene::from_bytes(
        gazelight_render::demo::NIGHT_EXR,
        gazelight_render::demo::name_path(),
        LuminanceScale::default(),
    )
    .unwrap();
    let view = gazelight_render::demo::default_view(w, h);
    let mut img = RgbImage::new(w, h);
    PanoramaView::new(view)
        .unwrap()
        .render(&scene.image, &mut img);
    (img, view.deg_per_px())
}

/// Max |GPU − CPU| over pixels and channels, relative to the CPU peak.
fn kernel_error(gpu: &PsfKernel, cpu: &PsfKernel) -> f64 {
    assert_eq!(gpu.size, cpu.size);
    let peak = cpu.rgb.iter().flatten().fold(0.0f32, |a, &b| a.max(b));
    let diff = gpu
        .rgb
        .iter()
        .zip(&cpu.rgb)
        .flat_map(|(g, c)| (0..3).map(move |k| (g[k] - c[k]).abs()))
        .fold(0.0f32, f32::max);
    f64::from(diff / peak)
}

/// With the in-frame rebuild off, a kernel built elsewhere and installed
/// with `set_kernel` is the one both backends convolve with: the frames
/// match each other within 1/255 and each backend's kernel reads back as
/// the installed one, not the initial 4 mm one (at 96×80 the two differ
/// by under 1e-4 of the peak: the Airy core is inside one pixel).
#[test]
fn an_installed_kernel_is_used_on_both_backends() {
    let Some(_ctx) = test_context("an_installed_kernel_is_used_on_both_backends") else {
        return;
    };
    let (w, h) = (96, 80);
    let (view, deg_per_px) = demo_view(w, h);
    let config = PipelineConfig::default();
    let mut params = config.glare.psf.clone();
    params.ppd = 1.0 / deg_per_px;
    let mut builder = gazelight_vision::psf::PsfBuilder::new(params).unwrap();
    let kernel = builder.rebuild(7.0).clone();
    let input = FrameInput {
        gaze_uv: [0.5, 0.4],
        pupil_mm: 7.0,
        dt_secs: 0.0,
    };
    let mut frames = Vec::new();
    for choice in [BackendChoice::Cpu, BackendChoice::Gpu] {
        let mut r = Renderer::new(choice, &config, w, h, deg_per_px).unwrap();
        r.set_psf_auto_rebuild(false);
        let mut before = DisplayFrame::new(w, h);
        let s0 = r.process(&view, &input, &mut before).unwrap();
        assert!(!s0.psf_rebuilt, "{choice}: rebuilt in the frame");
        assert_eq!(s0.psf_pupil_mm, 4.0, "{choice}");
        let initial = r.psf_kernel().unwrap().unwrap().clone();
        assert!(
            initial.rgb != kernel.rgb && initial.pupil_mm == 4.0,
            "{choice}: 4 mm = 7 mm kernel"
        );
        r.set_kernel(&kernel).unwrap();
        let mut after = DisplayFrame::new(w, h);
        let s1 = r.process(&view, &input, &mut after).unwrap();
        assert_eq!(s1.psf_pupil_mm, 7.0, "{choice}");
        let back = r.psf_kernel().unwrap().unwrap().clone();
        assert!(
            kernel_error(&back, &kernel) <= 1e-6,
            "{choice}: kernel read back"
        );
        frames.push(after);
    }
    let max_diff = frames[0]
        .rgba8
        .iter()
        .zip(&frames[1].rgba8)
        .map(|(a, b)| a.abs_diff(*b))
        .max()
        .unwrap();
    assert!(
        max_diff <= 1,
        "CPU vs GPU with the installed kernel: {max_diff}/255"
    );
}

/// The GPU renderer's kernel is read back again after a rebuild (not the
/// stale cached copy), matches the CPU's, and a set adaptation state
/// carries over on both backends.
#[test]
fn psf_kernel_and_adaptation_follow_on_both_backends() {
    let Some(ctx) = test_context("psf_kernel_and_adaptation_follow_on_both_backends") else {
        return;
    };
    let (w, h) = (96, 80);
    let (view, deg_per_px) = demo_view(w, h);
    let config = PipelineConfig::default();
    let mut cpu = Renderer::new(BackendChoice::Cpu, &config, w, h, deg_per_px).unwrap();
    let mut gpu = Renderer::new(BackendChoice::Gpu, &config, w, h, deg_per_px).unwrap();
    assert!(!cpu.is_gpu() && gpu.is_gpu());
    assert_eq!(cpu.describe(), "cpu");
    assert!(
        gpu.describe().contains(&ctx.adapter_info().name),
        "{}",
        gpu.describe()
    );
    println!("{} / {} ({})", cpu.describe(), gpu.describe(), gpu.reason());

    // Start both adapted to 50 cd/m² (photopic), far from the night
    // scene's ~0.01–1 cd/m², so the first frame's adaptation shows it.
    let start = AdaptationState::new(50.0);
    cpu.set_adaptation(start);
    gpu.set_adaptation(start);
    let (mut out_cpu, mut out_gpu) = (DisplayFrame::new(w, h), DisplayFrame::new(w, h));
    for (i, pupil_mm) in [4.0f32, 4.0, 6.5, 6.5, 2.5].into_iter().enumerate() {
        let input = FrameInput {
            gaze_uv: [0.5, 0.4],
            pupil_mm,
            dt_secs: 1.0 / 30.0,
        };
        let sc = cpu.process(&view, &input, &mut out_cpu).unwrap();
        let sg = gpu.process(&view, &input, &mut out_gpu).unwrap();
        assert_eq!(sc.psf_rebuilt, sg.psf_rebuilt, "frame {i}");
        let rel = (sc.adaptation_cd_m2 - sg.adaptation_cd_m2).abs() / sc.adaptation_cd_m2;
        assert!(rel <= 1e-4, "frame {i}: {sc:?} vs {sg:?}");
        if i == 0 {
            // One 33 ms step from 50 cd/m² stays far above the scene.
            assert!(sc.adaptation_cd_m2 > 5.0 * sc.target_cd_m2, "{sc:?}");
        }
        let kc = cpu.psf_kernel().unwrap().unwrap().clone();
        let kg = gpu.psf_kernel().unwrap().unwrap().clone();
        assert_eq!(
            kg.pupil_mm,
            f64::from(pupil_mm),
            "frame {i}: stale GPU kernel"
        );
        assert_eq!(kc.pupil_mm, kg.pupil_mm);
        let err = kernel_error(&kg, &kc);
        println!("frame {i}: pupil {pupil_mm} mm, kernel max error {err:e} of the peak");
        assert!(err <= 1e-4, "frame {i}: kernel error {err:e}");
        let max_diff = out_cpu
            .rgba8
            .iter()
            .zip(&out_gpu.rgba8)
            .map(|(a, b)| a.abs_diff(*b))
            .max()
            .unwrap();
        assert!(
            max_diff <= 1,
            "frame {i}: display differs by {max_diff}/255"
        );
    }
}
