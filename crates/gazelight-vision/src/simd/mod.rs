//! CPU SIMD: which instruction-set tier the row kernels run on, and the
//! kernels written with explicit intrinsics.
//!
//! Every kernel has a portable twin (plain Rust, written for the
//! auto-vectoriser) and computes **the same bits**: the same float
//! operations in the same order, no fused multiply-adds. The tiers,
//! narrowest first ([`Tier`]):
//!
//! | tier | needs | runs |
//! | --- | --- | --- |
//! | `portable` | any CPU | the portable loops |
//! | `avx2` | AVX2 + FMA | the band engine's row loops on blocks of 8 ([`crate::band`]), pass A's block sums ([`avx2::block_sums_row`]), the affine encoding ([`avx2::encode_affine`]); the band pass and the pipeline's row source compiled for AVX2 |
//! | `avx512` | AVX-512F + BW as well | the row loops on blocks of 16 (a row's last 8 in AVX2), the encoding's table search ([`avx512::encode_affine`]) |
//! | `avx512vbmi2` | AVX-512 VBMI2 as well | the encoding built with VBMI2 ([`avx512::encode_affine_vbmi2`]) |
//!
//! The CPU is asked once ([`Simd::host`]). A [`Simd`] value is the proof
//! that the CPU runs its tier: it is made only by detection, so the
//! `unsafe` calls of `#[target_feature]` kernels behind it are sound. The
//! frame paths take a [`Simd`] (the band engine, the pipeline's pass A,
//! row source and encoder), so the tests can run any tier the host has,
//! the portable one included, side by side in one process.
//!
//! ## Environment
//!
//! * `GAZELIGHT_SIMD=portable|avx2|avx512|avx512vbmi2` caps the tier of
//!   [`Simd::host`] (read once per process): `GAZELIGHT_SIMD=portable`
//!   renders with the portable loops only, on any CPU. Unknown values are
//!   ignored with a warning.
//! * `GAZELIGHT_REQUIRE_SIMD=avx2,avx512,…` (tests): a SIMD parity test
//!   whose tier is listed but that the CPU lacks **fails** instead of
//!   printing a `SKIP` line and passing; `.ci/run` lists the tiers of the
//!   CI machine, so a CI run that silently compared nothing fails.
//!
//! ## Kernels
//!
//! [`avx2`] and [`avx512`] hold each width's vector primitives under one
//! set of names (`ld`, `st`, `splat`, `add`, `gt`, `select`, …, and the
//! 3-channel transposes), so that code doing the same maths at both widths
//! is written once and compiled inside each `#[target_feature]` function
//! (the band engine's row loops, `band::kernels`); besides them, the
//! kernels that exist at one width or differ between the two: pass A's
//! block sums (AVX2), the affine encoding (a table lookup per lane in
//! AVX2, a branchless search with word permutes in AVX-512).

#[cfg(target_arch = "x86_64")]
pub(crate) mod avx2;
#[cfg(target_arch = "x86_64")]
pub(crate) mod avx512;

use std::sync::OnceLock;

/// Lanes of the portable blocks (one AVX2 register of f32): the band
/// engine, the encoder and pass A work on blocks of this many pixels.
pub(crate) const LANES: usize = 8;

/// An instruction-set tier, narrowest first (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub(crate) enum Tier {
    /// The portable loops.
    Portable,
    /// AVX2 + FMA.
    Avx2,
    /// AVX-512F + BW, AVX2 and FMA.
    Avx512,
    /// AVX-512 VBMI2 besides [`Tier::Avx512`].
    Avx512Vbmi2,
}

impl Tier {
    /// Every tier, narrowest first.
    pub(crate) const ALL: [Tier; 4] = [Tier::Portable, Tier::Avx2, Tier::Avx512, Tier::Avx512Vbmi2];

    /// The tier's name in `GAZELIGHT_SIMD` and `GAZELIGHT_REQUIRE_SIMD`.
    pub(crate) fn name(self) -> &'static str {
        match self {
            Tier::Portable => "portable",
            Tier::Avx2 => "avx2",
            Tier::Avx512 => "avx512",
            Tier::Avx512Vbmi2 => "avx512vbmi2",
        }
    }

    /// The tier named `name` (surrounding white space ignored).
    pub(crate) fn parse(name: &str) -> Option<Tier> {
        let name = name.trim();
        Tier::ALL.into_iter().find(|t| t.name() == name)
    }

    /// The widest tier this CPU runs.
    #[cfg(target_arch = "x86_64")]
    fn of_cpu() -> Tier {
        use std::arch::is_x86_feature_detected as has;
        if !(has!("avx2") && has!("fma")) {
            Tier::Portable
        } else if !(has!("avx512f") && has!("avx512bw")) {
            Tier::Avx2
        } else if !has!("avx512vbmi2") {
            Tier::Avx512
        } else {
            Tier::Avx512Vbmi2
        }
    }

    /// Not an x86-64 CPU: the portable loops only.
    #[cfg(not(target_arch = "x86_64"))]
    fn of_cpu() -> Tier {
        Tier::Portable
    }
}

impl std::fmt::Display for Tier {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Environment variable that caps [`Simd::host`]'s tier.
pub(crate) const SIMD_ENV: &str = "GAZELIGHT_SIMD";

/// A tier this CPU runs: made only by detection, so holding one proves the
/// CPU has the tier's instructions (the `unsafe` kernel calls rely on it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub(crate) struct Simd(Tier);

impl Simd {
    /// The portable loops (every CPU).
    #[cfg(test)]
    pub(crate) const PORTABLE: Simd = Simd(Tier::Portable);

    /// The widest tier of this CPU, capped by `GAZELIGHT_SIMD` when set;
    /// both read once per process.
    pub(crate) fn host() -> Simd {
        static HOST: OnceLock<Simd> = OnceLock::new();
        *HOST.get_or_init(|| {
            let cpu = Tier::of_cpu();
            let cap = match std::env::var(SIMD_ENV) {
                Ok(v) => match Tier::parse(&v) {
                    Some(t) => t,
                    None => {
                        tracing::warn!(
                            "{SIMD_ENV}={v:?} is not one of portable, avx2, avx512, \
                             avx512vbmi2: ignored"
                        );
                        cpu
                    }
                },
                Err(_) => cpu,
            };
            Simd(cpu.min(cap))
        })
    }

    /// `tier`, if this CPU runs it (whatever `GAZELIGHT_SIMD` says).
    #[cfg(test)]
    pub(crate) fn new(tier: Tier) -> Option<Simd> {
        (tier <= Tier::of_cpu()).then_some(Simd(tier))
    }

    /// The tier.
    #[cfg(test)]
    pub(crate) fn tier(self) -> Tier {
        self.0
    }

    /// Whether this tier includes `tier`'s instructions.
    #[inline(always)]
    pub(crate) fn has(self, tier: Tier) -> bool {
        self.0 >= tier
    }

    /// Runs `f` compiled for this tier: `f`'s code (inlined: mark closures
    /// `#[inline(always)]`) with the tier's target features enabled, so
    /// that the portable loops in it are vectorised for the tier, or as it
    /// is for [`Tier::Portable`]. The same operations either way (no fused
    /// multiply-adds are requested), so the same bits.
    #[inline(always)]
    pub(crate) fn compiled<R>(self, f: impl FnOnce() -> R) -> R {
        #[cfg(target_arch = "x86_64")]
        match self.0 {
            // SAFETY: a `Simd` of these tiers exists only where the CPU
            // has AVX-512F, AVX2 and FMA (`Simd::host`, `Simd::new`).
            Tier::Avx512 | Tier::Avx512Vbmi2 => return unsafe { compiled_avx512(f) },
            // SAFETY: as above, AVX2 and FMA.
            Tier::Avx2 => return unsafe { compiled_avx2(f) },
            Tier::Portable => {}
        }
        f()
    }
}

/// `f` compiled for AVX-512F (with AVX2 and FMA).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2,fma")]
fn compiled_avx512<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// `f` compiled for AVX2 + FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
fn compiled_avx2<R>(f: impl FnOnce() -> R) -> R {
    f()
}

/// `[f(a), f(b), f(c)]`: `[T; 3]::map` for the SIMD passes. Always
/// inlined, so that `f` is inlined into the `#[target_feature]` caller too:
/// LLVM left `map` and its closures out of line there (calls passing the
/// vectors through memory, compiled without the caller's features).
#[inline(always)]
pub(crate) fn map3<T, U>(a: [T; 3], mut f: impl FnMut(T) -> U) -> [U; 3] {
    let [x, y, z] = a;
    [f(x), f(y), f(z)]
}

/// Channel planes of exactly `LANES` pixels: the 24 floats are loaded as
/// one block and deinterleaved with constant indices, which the compiler
/// turns into a few vector loads and shuffles instead of 24 inserts.
#[inline(always)]
pub(crate) fn planes_full(px: &[[f32; 3]; LANES]) -> [[f32; LANES]; 3] {
    let flat: &[f32; 3 * LANES] = px.as_flattened().try_into().unwrap_or(&[0.0; 3 * LANES]);
    let mut p = [[0.0; LANES]; 3];
    for i in 0..LANES {
        p[0][i] = flat[3 * i];
        p[1][i] = flat[3 * i + 1];
        p[2][i] = flat[3 * i + 2];
    }
    p
}

/// The `GAZELIGHT_REQUIRE_SIMD` rule of the SIMD parity tests.
#[cfg(test)]
pub(crate) mod testing {
    use super::{Simd, Tier};

    /// Environment variable listing the tiers the tests must run.
    pub(crate) const REQUIRE_SIMD_ENV: &str = "GAZELIGHT_REQUIRE_SIMD";

    /// The tiers `GAZELIGHT_REQUIRE_SIMD` lists (empty when unset). An
    /// unknown name panics: a typo must not turn a requirement off.
    pub(crate) fn required() -> Vec<Tier> {
        let Ok(list) = std::env::var(REQUIRE_SIMD_ENV) else {
            return Vec::new();
        };
        list.split(',')
            .filter(|s| !s.trim().is_empty())
            .map(|s| {
                Tier::parse(s).unwrap_or_else(|| {
                    panic!(
                        "{REQUIRE_SIMD_ENV}: unknown tier {s:?} (portable, avx2, avx512, \
                         avx512vbmi2)"
                    )
                })
            })
            .collect()
    }

    /// The tiers of `wanted` this CPU runs, for the parity test `test`.
    /// A tier it lacks prints a `SKIP` line, or panics when
    /// `GAZELIGHT_REQUIRE_SIMD` lists it.
    pub(crate) fn tiers(test: &str, wanted: &[Tier]) -> Vec<Simd> {
        let required = required();
        let mut run = Vec::new();
        for &tier in wanted {
            match Simd::new(tier) {
                Some(s) => run.push(s),
                None if required.contains(&tier) => {
                    panic!("{test}: {REQUIRE_SIMD_ENV} lists {tier}, but this CPU does not run it")
                }
                None => eprintln!(
                    "SKIP {test} at {tier}: not on this CPU; list it in {REQUIRE_SIMD_ENV} \
                     to make this a failure"
                ),
            }
        }
        run
    }

    /// Whether the parity test `test` runs `tier` (see [`tiers`]).
    pub(crate) fn runs(test: &str, tier: Tier) -> bool {
        !tiers(test, &[tier]).is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tiers_parse_by_name_and_are_ordered() {
        for t in Tier::ALL {
            assert_eq!(Tier::parse(t.name()), Some(t));
            assert_eq!(Tier::parse(&format!(" {t} ")), Some(t));
        }
        assert_eq!(Tier::parse("avx-512"), None);
        assert_eq!(Tier::parse(""), None);
        assert!(Tier::Portable < Tier::Avx2 && Tier::Avx2 < Tier::Avx512);
        assert!(Tier::Avx512 < Tier::Avx512Vbmi2);
    }

    #[test]
    fn every_tier_up_to_the_cpus_is_available_and_none_above() {
        let cpu = Tier::of_cpu();
        eprintln!("this CPU runs up to {cpu}");
        for t in Tier::ALL {
            assert_eq!(Simd::new(t).is_some(), t <= cpu, "{t}");
        }
        assert_eq!(Simd::new(Tier::Portable), Some(Simd::PORTABLE));
        assert!(Simd::host() <= Simd(cpu));
        // The compiled wrapper runs its closure at every tier.
        for t in Tier::ALL {
            if let Some(s) = Simd::new(t) {
                assert_eq!(s.compiled(|| 40 + 2), 42);
            }
        }
    }

    /// The CI fails here when a tier it expects is not on the machine, even
    /// where no other test would look.
    #[test]
    fn the_required_tiers_are_on_this_cpu() {
        let required = testing::required();
        if required.is_empty() {
            eprintln!(
                "SKIP the_required_tiers_are_on_this_cpu: {} is not set",
                testing::REQUIRE_SIMD_ENV
            );
        }
        for t in required {
            assert!(
                Simd::new(t).is_some(),
                "{} lists {t}, but this CPU runs only up to {}",
                testing::REQUIRE_SIMD_ENV,
                Tier::of_cpu()
            );
        }
    }
}

/// The whole frame pipeline at every tier this CPU runs against the
/// portable one: pass A, the row source, the band engine and the encoder
/// each have SIMD twins, so the frames must be the same bytes.
#[cfg(test)]
mod frame_tests {
    use super::{Simd, Tier, testing};
    use crate::RgbImage;
    use crate::acuity::AcuityModel;
    use crate::pipeline::{DisplayFrame, FrameInput, FramePipeline, PipelineConfig};
    use crate::scene::{LuminanceScale, PanoramaView, Scene, ViewParams};
    use crate::tone::ToneModel;

    /// A view of the shared night panorama at `gain` × its luminance.
    fn night_view(width: usize, height: usize, hfov_deg: f64, gain: f32) -> (RgbImage, f64) {
        let path = gazelight_test_support::data_path("hdr/blender-world/night.exr");
        let scene = Scene::load(&path, LuminanceScale::default()).expect("shared night.exr");
        let params = ViewParams {
            yaw_deg: -78.4,
            pitch_deg: -6.0,
            hfov_deg,
            width,
            height,
        };
        let mut view = RgbImage::new(width, height);
        PanoramaView::new(params)
            .expect("view")
            .render(&scene.image, &mut view);
        for p in &mut view.pixels {
            *p = p.map(|v| v * gain);
        }
        (view, params.deg_per_px())
    }

    /// The display frames (and retinal images) of three frames of `img`
    /// rendered with `cfg` on `simd`'s tier.
    fn frames(cfg: &PipelineConfig, img: &RgbImage, dpp: f64, simd: Simd) -> Vec<Vec<u8>> {
        let (w, h) = (img.width, img.height);
        let mut p = FramePipeline::new(cfg.clone(), w, h, dpp).expect("pipeline");
        p.set_simd(simd);
        let mut out = DisplayFrame::new(w, h);
        let mut got = Vec::new();
        for (k, gaze_uv) in [[0.5f32, 0.45], [0.2, 0.7], [0.9, 0.1]]
            .into_iter()
            .enumerate()
        {
            let input = FrameInput {
                gaze_uv,
                pupil_mm: 3.0 + k as f32,
                dt_secs: 0.05,
            };
            p.process(img, &input, &mut out).expect("frame");
            got.push(out.rgba8.clone());
            if cfg.keep_retinal {
                got.push(
                    p.retinal()
                        .pixels
                        .iter()
                        .flat_map(|q| q.map(f32::to_bits))
                        .flat_map(u32::to_le_bytes)
                        .collect(),
                );
            }
            if cfg.keep_display_linear {
                got.push(
                    p.display_linear()
                        .pixels
                        .iter()
                        .flat_map(|q| q.map(f32::to_bits))
                        .flat_map(u32::to_le_bytes)
                        .collect(),
                );
            }
        }
        got
    }

    #[test]
    fn frames_are_the_same_bytes_on_the_portable_path_and_every_simd_tier() {
        let test = "frames_are_the_same_bytes_on_the_portable_path_and_every_simd_tier";
        let tiers = testing::tiers(test, &[Tier::Avx2, Tier::Avx512, Tier::Avx512Vbmi2]);
        // Widths that leave tails at 8 and 16 lanes; a dim night (the blur
        // runs, L*'s linear and cubic parts) and a brighter one.
        let mut cases = Vec::new();
        for (w, h, hfov, gain) in [(203, 157, 20.0, 1e-3), (181, 90, 12.0, 0.1)] {
            let (img, dpp) = night_view(w, h, hfov, gain);
            for (tone, acuity, keep) in [
                (ToneModel::default(), AcuityModel::default(), false),
                (ToneModel::naka_rushton(), AcuityModel::LarsonKrawczyk, true),
                (ToneModel::gaze_exposure(), AcuityModel::default(), false),
            ] {
                let cfg = PipelineConfig {
                    tone,
                    acuity,
                    keep_retinal: keep,
                    keep_display_linear: keep,
                    ..PipelineConfig::default()
                };
                cases.push((
                    format!("{w}x{h} ×{gain} {tone:?} {acuity:?} keep {keep}"),
                    cfg,
                    img.clone(),
                    dpp,
                ));
            }
        }
        let mut compared = 0;
        for (what, cfg, img, dpp) in &cases {
            let portable = frames(cfg, img, *dpp, Simd::PORTABLE);
            // Not a frame of one colour: the comparison can fail.
            assert!(
                portable[0].chunks_exact(4).any(|p| p != &portable[0][..4]),
                "{what}"
            );
            for &simd in &tiers {
                let got = frames(cfg, img, *dpp, simd);
                assert_eq!(got.len(), portable.len());
                for (k, (a, b)) in got.iter().zip(&portable).enumerate() {
                    let first = a.iter().zip(b).position(|(x, y)| x != y);
                    assert_eq!(
                        first,
                        None,
                        "{what}, {}, output {k}: first differing byte",
                        simd.tier()
                    );
                }
                compared += 1;
            }
        }
        eprintln!("{compared} configurations compared with the portable path at {tiers:?}");
    }

    #[test]
    fn a_changed_frame_is_caught() {
        // The comparison above would see one bit: the encoder's output
        // changes when one pixel's luminance moves by one table step.
        let (img, dpp) = night_view(64, 48, 20.0, 0.1);
        let cfg = PipelineConfig::default();
        let a = frames(&cfg, &img, dpp, Simd::PORTABLE);
        let mut brighter = img.clone();
        brighter.pixels[10 * 64 + 20] = brighter.pixels[10 * 64 + 20].map(|v| v * 1.5 + 0.01);
        let b = frames(&cfg, &brighter, dpp, Simd::PORTABLE);
        assert_ne!(a[0], b[0]);
    }
}
