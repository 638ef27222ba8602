#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! `--backend`: `render --backend gpu` against `--backend cpu` on the
//! embedded demo (same files, frames within 1/255, same model columns in
//! timeline.csv), and the behaviour without any GPU adapter (`gpu` fails
//! clearly, `auto` falls back to the CPU and says so).
//!
//! The GPU test needs an adapter (on CI: lavapipe, `WGPU_BACKEND=vulkan`);
//! without one it prints a skip line, unless `GAZELIGHT_REQUIRE_GPU=1`, in
//! which case it fails.

mod common;

use std::collections::BTreeSet;
use std::path::Path;
use std::time::Instant;

use common::{gazelight, gazelight_env, tmp};

use gazelight_gpu::testing::test_context;

/// Relative paths of every file under `dir`.
fn files(dir: &Path) -> BTreeSet<String> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeSet<String>) {
        for entry in std::fs::read_dir(dir).expect("read_dir") {
            let path = entry.expect("entry").path();
            if path.is_dir() {
                walk(root, &path, out);
            } else {
                out.insert(
                    path.strip_prefix(root)
                        .expect("prefix")
                        .to_string_lossy()
                        .into_owned(),
                );
            }
        }
    }
    let mut out = BTreeSet::new();
    walk(dir, dir, &mut out);
    out
}

/// Max per-channel difference of two PNGs (same size asserted) and the
/// number of channel values that differ.
fn png_diff(a: &Path, b: &Path) -> (u8, usize) {
    let a = image::open(a).expect("png a").to_rgb8();
    let b = image::open(b).expect("png b").to_rgb8();
    assert_eq!(a.dimensions(), b.dimensions());
    let mut max = 0u8;
    let mut differ = 0;
    for (x, y) in a.as_raw().iter().zip(b.as_raw()) {
        let d = x.abs_diff(*y);
        max = max.max(d);
        differ += usize::from(d > 0);
    }
    (max, differ)
}

fn timeline(dir: &Path) -> (String, Vec<Vec<String>>) {
    let text = std::fs::read_to_string(dir.join("timeline.csv")).expect("timeline.csv");
    let mut lines = text.lines();
    let header = lines.next().expect("header").to_owned();
    let rows = lines
        .map(|l| l.split(',').map(str::to_owned).collect())
        .collect();
    (header, rows)
}

fn num(s: &str) -> f64 {
    s.parse().unwrap_or_else(|_| panic!("not a number: {s}"))
}

/// The demo at 96x80, one frame a second for 12 s: ground, the glance up to
/// the street lamp at 3 s and back at 7.5 s, so adaptation moves over
/// decades and the pupil (hence the PSF) changes several times.
const DEMO: &[&str] = &["--size", "96x80", "--fps", "1", "--frames", "12"];

#[test]
fn render_gpu_matches_cpu() {
    let Some(ctx) = test_context("render_gpu_matches_cpu") else {
        return;
    };
    let adapter = ctx.describe();
    let root = tmp("parity");
    let mut summaries = Vec::new();
    for backend in ["cpu", "gpu"] {
        let dir = root.join(backend);
        let mut args = vec!["render", "--backend", backend, "--out"];
        args.push(dir.to_str().expect("utf-8"));
        args.extend_from_slice(DEMO);
        let started = Instant::now();
        let out = gazelight(&args);
        let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{backend}: {stdout}\n{stderr}");
        assert!(!stderr.contains("panicked"), "{stderr}");
        println!(
            "--backend {backend}: {:.1} s\n{}",
            started.elapsed().as_secs_f64(),
            stdout.trim()
        );
        summaries.push(stdout);
    }
    // The summary names the backend and, for the GPU, the adapter.
    assert!(summaries[0].contains("\nbackend cpu\n"), "{}", summaries[0]);
    let gpu_line = summaries[1]
        .lines()
        .find(|l| l.starts_with("backend gpu: "))
        .unwrap_or_else(|| panic!("no `backend gpu:` line: {}", summaries[1]));
    println!("adapter of the test context: {adapter}");
    assert!(
        gpu_line.contains(&ctx.adapter_info().name),
        "{gpu_line} vs {adapter}"
    );

    let (cpu, gpu) = (root.join("cpu"), root.join("gpu"));
    let names = files(&cpu);
    assert_eq!(names, files(&gpu), "the two backends wrote different files");
    let frames: Vec<&String> = names.iter().filter(|n| n.starts_with("frames")).collect();
    assert_eq!(frames.len(), 12, "{names:?}");

    // Every frame (and the contact sheet, made of frames) within 1/255.
    let mut worst = (0u8, String::new());
    let mut differing = 0usize;
    for name in names
        .iter()
        .filter(|n| n.ends_with(".png") && *n != "plot.png")
    {
        let (max, n) = png_diff(&cpu.join(name), &gpu.join(name));
        differing += n;
        if max >= worst.0 {
            worst = (max, name.clone());
        }
        assert!(max <= 1, "{name}: GPU and CPU differ by {max}/255");
    }
    println!(
        "max frame difference {}/255 ({}), {differing} channel values differ in all",
        worst.0, worst.1
    );

    // timeline.csv: same columns; the model columns agree.
    let (cpu_header, cpu_rows) = timeline(&cpu);
    let (gpu_header, gpu_rows) = timeline(&gpu);
    assert_eq!(cpu_header, gpu_header);
    let col = |name: &str| {
        cpu_header
            .split(',')
            .position(|c| c == name)
            .unwrap_or_else(|| panic!("no column {name} in {cpu_header}"))
    };
    assert_eq!(cpu_rows.len(), gpu_rows.len());
    let mut worst_rel: f64 = 0.0;
    for (c, g) in cpu_rows.iter().zip(&gpu_rows) {
        for exact in [
            "t_secs",
            "gaze_u",
            "gaze_v",
            "pupil_mm",
            "pupil_held",
            "psf_pupil_mm",
            "psf_rebuilt",
        ] {
            let i = col(exact);
            assert_eq!(c[i], g[i], "{exact} at t = {}", c[0]);
        }
        for rel in ["target_cd_m2", "adaptation_cd_m2"] {
            let i = col(rel);
            let (a, b) = (num(&c[i]), num(&g[i]));
            let r = (a - b).abs() / a.abs().max(1e-12);
            worst_rel = worst_rel.max(r);
            assert!(
                r <= 1e-4,
                "{rel} at t = {}: cpu {a} gpu {b} (rel {r:e})",
                c[0]
            );
        }
        let i = col("acuity_sigma_px");
        let (a, b) = (num(&c[i]), num(&g[i]));
        assert!(
            (a - b).abs() <= 1e-3 + 1e-4 * a.abs(),
            "acuity_sigma_px at t = {}: cpu {a} gpu {b}",
            c[0]
        );
    }
    println!("adaptation/target max relative difference {worst_rel:e}");

    // The run covered what it is meant to: PSF rebuilds after the first
    // frame and the glance at the lamp (adaptation up by over a decade).
    let rebuilds = cpu_rows
        .iter()
        .skip(1)
        .filter(|r| r[col("psf_rebuilt")] == "1")
        .count();
    assert!(rebuilds >= 2, "only {rebuilds} PSF rebuilds after frame 0");
    let adaptation: Vec<f64> = cpu_rows
        .iter()
        .map(|r| num(&r[col("adaptation_cd_m2")]))
        .collect();
    let (lo, hi) = adaptation
        .iter()
        .fold((f64::INFINITY, 0.0f64), |(lo, hi), &a| {
            (lo.min(a), hi.max(a))
        });
    assert!(hi > 10.0 * lo, "no lamp glance: adaptation {adaptation:?}");
    println!("{rebuilds} PSF rebuilds after frame 0, adaptation {lo:.3e}..{hi:.3e} cd/m²");
}

/// Vulkan with no driver: the loader finds no ICD, so wgpu lists no adapter
/// (this build of wgpu has no GL backend to fall back on).
const NO_ADAPTER_ENV: &[(&str, &str)] = &[
    ("WGPU_BACKEND", "vulkan"),
    ("VK_ICD_FILENAMES", "/nonexistent/icd.json"),
    ("VK_DRIVER_FILES", "/nonexistent/icd.json"),
    ("VK_ADD_DRIVER_FILES", "/nonexistent/icd.json"),
];

#[test]
fn without_an_adapter_gpu_fails_clearly_and_auto_uses_the_cpu() {
    let root = tmp("no-adapter");
    let dir = root.join("gpu");
    let mut args = vec!["render", "--backend", "gpu", "--out"];
    args.push(dir.to_str().expect("utf-8"));
    args.extend_from_slice(&["--size", "96x80", "--frames", "2"]);
    let out = gazelight_env(&args, NO_ADAPTER_ENV);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("--backend gpu without an adapter:\n{stderr}");
    assert!(!out.status.success(), "{stderr}");
    assert!(!stderr.contains("panicked"), "{stderr}");
    for needle in ["--backend gpu", "no GPU adapter", "--backend cpu"] {
        assert!(stderr.contains(needle), "stderr lacks `{needle}`: {stderr}");
    }
    assert!(
        !dir.join("timeline.csv").exists(),
        "a failed GPU render wrote a timeline"
    );

    let dir = root.join("auto");
    let mut args = vec!["render", "--backend", "auto", "--out"];
    args.push(dir.to_str().expect("utf-8"));
    args.extend_from_slice(&["--size", "96x80", "--frames", "2"]);
    let out = gazelight_env(&args, NO_ADAPTER_ENV);
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("--backend auto without an adapter:\n{stdout}\n{stderr}");
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("backend: cpu (auto: no GPU adapter found"),
        "auto does not say it fell back: {stderr}"
    );
    assert!(stdout.contains("\nbackend cpu\n"), "{stdout}");
    assert!(stdout.contains("(cpu)"), "{stdout}");
    for f in [
        "timeline.csv",
        "frames/frame_00001.png",
        "contact_sheet.png",
    ] {
        assert!(dir.join(f).is_file(), "auto did not write {f}");
    }
}

/// A successful GPU render on a headless machine (no `XDG_RUNTIME_DIR`)
/// prints no line containing "error" (Mesa's device-select layer, which
/// probes Wayland and complains, is switched off where no Wayland display
/// is set), and its log on a pipe carries no ANSI colour codes.
#[test]
fn a_headless_render_prints_no_error_and_no_colour_codes() {
    if test_context("a_headless_render_prints_no_error_and_no_colour_codes").is_none() {
        return;
    }
    let dir = tmp("headless");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_gazelight"))
        .args(["render", "--backend", "gpu", "--out"])
        .arg(&dir)
        .args(["--size", "96x80", "--frames", "2"])
        .env_remove("XDG_RUNTIME_DIR")
        .env_remove("WAYLAND_DISPLAY")
        .env_remove("NODEVICE_SELECT")
        .env("RUST_LOG", "info")
        .output()
        .expect("run gazelight");
    let stderr = String::from_utf8_lossy(&out.stderr);
    println!("{stderr}");
    assert!(out.status.success(), "{stderr}");
    assert!(
        stderr.contains("INFO"),
        "the info log did not reach stderr: {stderr}"
    );
    let errors: Vec<&str> = stderr
        .lines()
        .filter(|l| l.to_lowercase().contains("error"))
        .collect();
    assert!(errors.is_empty(), "error lines on success: {errors:?}");
    assert!(
        !stderr.contains('\u{1b}'),
        "colour codes on a pipe: {stderr:?}"
    );
    let _ = std::fs::remove_dir_all(&dir);
}
