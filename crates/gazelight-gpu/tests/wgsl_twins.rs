#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The WGSL side of every pass, read by naga (the version wgpu compiles
//! them with), against its Rust side:
//!
//! - each uniform struct (and the shared `FrameState`) has the size, member
//!   names, member order, member offsets and scalar types of its
//!   `#[repr(C)]` twin (`std::mem::offset_of!`); the Rust members listed
//!   here must cover the whole Rust struct (their sizes sum to its size, and
//!   `Pod` forbids hidden padding), so a field added on either side, or
//!   reordered, or retyped, fails;
//! - each [`PassDescriptor`] declares exactly the shader's `@group(0)`
//!   bindings (index, name, uniform / read / read-write, minimum size) and
//!   compute entry points.
//!
//! No device is needed: this runs everywhere.

use gazelight_gpu::acuity::AcuityParams;
use gazelight_gpu::far_glare::FarParams;
use gazelight_gpu::fft::FftParams;
use gazelight_gpu::frame::FrameState;
use gazelight_gpu::glare::GlareParams;
use gazelight_gpu::pass::{self, BindingKind, PassDescriptor};
use gazelight_gpu::pooling::PoolParams;
use gazelight_gpu::psf::PsfBuild;
use gazelight_gpu::shaders::{self, WgslShader};
use gazelight_gpu::temporal::TemporalParams;
use gazelight_gpu::tone::ToneParams;

/// One member of a Rust twin.
struct Field {
    name: &'static str,
    offset: usize,
    type_name: &'static str,
    size: usize,
}

/// A `#[repr(C)]` Rust struct as the Rust compiler lays it out.
struct RustTwin {
    name: &'static str,
    size: usize,
    fields: Vec<Field>,
}

fn field_type<T, F>(_: fn(&T) -> &F) -> (&'static str, usize) {
    (std::any::type_name::<F>(), size_of::<F>())
}

/// `twin!(Type { a, b, … })`: the struct's size and each named member's
/// offset, type and size.
macro_rules! twin {
    ($t:ident { $($f:ident),* $(,)? }) => {
        RustTwin {
            name: stringify!($t),
            size: size_of::<$t>(),
            fields: vec![$({
                let (type_name, size) = field_type(|s: &$t| &s.$f);
                Field { name: stringify!($f), offset: std::mem::offset_of!($t, $f), type_name, size }
            }),*],
        }
    };
}

/// The `TemporalParams` twin, resolved where it is used (the real struct,
/// or a drifted local one in the negative test).
macro_rules! temporal_twin {
    () => {
        twin!(TemporalParams {
            model,
            reset,
            overshoot,
            _pad0,
            dt_secs,
            a,
            b,
            _pad1,
        })
    };
}

/// The `AcuityParams` twin, resolved where it is used.
macro_rules! acuity_twin {
    () => {
        twin!(AcuityParams {
            width,
            height,
            model,
            max_radius,
            white_cd_m2,
            sigma_scale,
            _pad0,
            _pad1,
        })
    };
}

fn twins() -> Vec<(WgslShader, RustTwin)> {
    let mut twins = stage_1_2_twins();
    twins.extend(stage_4_8_twins());
    twins.push((shaders::FRAME_STATE, frame_state()));
    twins.push((shaders::PSF_BUILD, psf_build()));
    twins
}

/// The glare-kernel build's uniforms (`psf_build.wgsl`).
fn psf_build() -> RustTwin {
    twin!(PsfBuild {
        n,
        kernel_size,
        kernel_radius,
        wavelength_count,
        half,
        r_samples,
        edge,
        defocus_rad_per_sample2,
        intensity_scale,
        near_radius_px,
        lobe_scale,
        lobe_count,
        lobe_per_px,
        budget,
        _pad0,
        _pad1,
    })
}

/// The FFT's and stages 1–2's uniforms.
fn stage_1_2_twins() -> Vec<(WgslShader, RustTwin)> {
    vec![
        (
            shaders::FFT,
            twin!(FftParams {
                n,
                ns,
                radix,
                elem_stride,
                lines_per_plane,
                line_step,
                plane_size,
                total_threads,
                twiddle_step,
                inverse,
                scale,
                _pad,
            }),
        ),
        (
            shaders::POOLING,
            twin!(PoolParams {
                width,
                height,
                small_w,
                small_h,
                ds,
                model,
                partial_count,
                _pad0,
                x0,
                x1,
                y0,
                y1,
                gaze_x,
                gaze_y,
                p0,
                p1,
                p2,
                p3,
                geo,
                _pad1,
                azimuth,
                elevation,
                cos_elevation,
                k,
                tan_x0,
                tan_per_x,
                tan_y0,
                tan_per_y,
            }),
        ),
        (shaders::TEMPORAL, temporal_twin!()),
    ]
}

/// Stages 4–8's uniforms.
fn stage_4_8_twins() -> Vec<(WgslShader, RustTwin)> {
    vec![
        (shaders::GLARE_WINDOW, glare_params()),
        (
            shaders::FAR_GLARE,
            twin!(FarParams {
                width,
                height,
                block_px,
                blocks_w,
                blocks_h,
                n,
                placed,
                cells_at,
                entries_at,
                cols_at,
                rows_at,
                _pad0,
            }),
        ),
        (shaders::ACUITY, acuity_twin!()),
        (
            shaders::TONE,
            twin!(ToneParams {
                width,
                height,
                model,
                colour_shift,
                colour_discrimination,
                keep_linear,
                _pad0,
                _pad1,
                peak_cd_m2,
                tp_da_cd_m2,
                saturation,
                gamma,
                window_lo,
                window_hi,
                _pad2,
                _pad3,
            }),
        ),
    ]
}

/// The glare window's uniforms (`glare_window.wgsl`, prepended to the
/// window glare and the far field).
fn glare_params() -> RustTwin {
    twin!(GlareParams {
        wf,
        wc,
        block,
        r_fine,
        kernel_size,
        width,
        height,
        _pad0,
        ofx,
        ofy,
        ocx,
        ocy,
        sx0,
        sx1,
        sy0,
        sy1,
        x0,
        x1,
        y0,
        y1,
        gaze_x,
        gaze_y,
        d_full,
        sigma,
        keep0,
        keep_slope,
        _pad1,
        _pad2,
    })
}

fn frame_state() -> RustTwin {
    twin!(FrameState {
        target_cd_m2,
        adaptation_cd_m2,
        light_target_cd_m2,
        acuity_sigma_px,
        tone_a,
        tone_b,
        tone_c,
        shift_sigma,
        discrimination_sigma,
        blur_radius,
        _pad0,
        _pad1,
    })
}

/// A parsed shader and its type layouts.
struct Parsed {
    module: naga::Module,
    layouter: naga::proc::Layouter,
}

fn parse(shader: &WgslShader) -> Parsed {
    let module = naga::front::wgsl::parse_str(shader.source)
        .unwrap_or_else(|e| panic!("{}: {}", shader.name, e.emit_to_string(shader.source)));
    let mut layouter = naga::proc::Layouter::default();
    layouter
        .update(module.to_ctx())
        .unwrap_or_else(|e| panic!("{}: layout: {e}", shader.name));
    Parsed { module, layouter }
}

/// The WGSL name of a scalar member's type, as Rust spells it.
fn wgsl_scalar(module: &naga::Module, ty: naga::Handle<naga::Type>) -> String {
    match module.types[ty].inner {
        naga::TypeInner::Scalar(naga::Scalar { kind, width }) => {
            let prefix = match kind {
                naga::ScalarKind::Uint => "u",
                naga::ScalarKind::Sint => "i",
                naga::ScalarKind::Float => "f",
                other => return format!("{other:?}"),
            };
            format!("{prefix}{}", u32::from(width) * 8)
        }
        ref other => format!("{other:?}"),
    }
}

/// Every difference between the WGSL struct `twin.name` in `shader` and
/// its Rust twin (empty when they agree).
fn struct_differences(shader: &WgslShader, twin: &RustTwin) -> Vec<String> {
    let parsed = parse(shader);
    let module = &parsed.module;
    let Some((handle, ty)) = module
        .types
        .iter()
        .find(|(_, t)| t.name.as_deref() == Some(twin.name))
    else {
        return vec![format!("{}: no struct {}", shader.name, twin.name)];
    };
    let naga::TypeInner::Struct { ref members, .. } = ty.inner else {
        return vec![format!("{}: {} is not a struct", shader.name, twin.name)];
    };
    let mut diffs = Vec::new();
    let at = |what: String| format!("{} {}: {what}", shader.name, twin.name);
    let wgsl_size = parsed.layouter[handle].size as usize;
    if wgsl_size != twin.size {
        diffs.push(at(format!("WGSL size {wgsl_size} B, Rust {} B", twin.size)));
    }
    let listed: usize = twin.fields.iter().map(|f| f.size).sum();
    if listed != twin.size {
        diffs.push(at(format!(
            "the Rust fields listed in this test cover {listed} of {} B: a Rust field is missing \
             from the list (or from the WGSL struct)",
            twin.size
        )));
    }
    if members.len() != twin.fields.len() {
        diffs.push(at(format!(
            "WGSL has {} members, Rust {}",
            members.len(),
            twin.fields.len()
        )));
    }
    for (i, (m, f)) in members.iter().zip(&twin.fields).enumerate() {
        let name = m.name.as_deref().unwrap_or("?");
        let wgsl_type = wgsl_scalar(module, m.ty);
        if name != f.name || m.offset as usize != f.offset || wgsl_type != f.type_name {
            diffs.push(at(format!(
                "member {i}: WGSL {name}: {wgsl_type} at {}, Rust {}: {} at {}",
                m.offset, f.name, f.type_name, f.offset
            )));
        }
    }
    diffs
}

#[test]
fn every_uniform_struct_matches_its_repr_c_twin() {
    let mut diffs = Vec::new();
    for (shader, twin) in twins() {
        let found = struct_differences(&shader, &twin);
        println!(
            "{} {}: {} B, {} members: {}",
            shader.name,
            twin.name,
            twin.size,
            twin.fields.len(),
            if found.is_empty() { "match" } else { "DIFFER" }
        );
        diffs.extend(found);
    }
    // Every composed pass source sees the same FrameState.
    for shader in [
        shaders::POOLING,
        shaders::TEMPORAL,
        shaders::ACUITY,
        shaders::TONE,
    ] {
        diffs.extend(struct_differences(&shader, &frame_state()));
    }
    // Both glare passes see the same GlareParams.
    for shader in [shaders::GLARE, shaders::FAR_GLARE] {
        diffs.extend(struct_differences(&shader, &glare_params()));
    }
    // Every glare-kernel build pass sees the same PsfBuild.
    for shader in [
        shaders::PSF_APERTURE,
        shaders::PSF_INTENSITY,
        shaders::PSF_SPECTRAL,
        shaders::PSF_NORMALISE,
    ] {
        diffs.extend(struct_differences(&shader, &psf_build()));
    }
    assert!(diffs.is_empty(), "\n{}", diffs.join("\n"));
}

/// What `@group(0) @binding(i)` of `shader` declares: name, kind, minimum
/// size.
fn wgsl_bindings(parsed: &Parsed) -> Vec<(u32, String, Option<BindingKind>, u64)> {
    let module = &parsed.module;
    let mut out = Vec::new();
    for (_, global) in module.global_variables.iter() {
        let Some(binding) = &global.binding else {
            continue;
        };
        assert_eq!(binding.group, 0, "only group 0 is used");
        let kind = match global.space {
            naga::AddressSpace::Uniform => Some(BindingKind::Uniform),
            naga::AddressSpace::Storage { access }
                if access.contains(naga::StorageAccess::STORE) =>
            {
                Some(BindingKind::StorageReadWrite)
            }
            naga::AddressSpace::Storage { .. } => Some(BindingKind::StorageRead),
            _ => None,
        };
        let min = match module.types[global.ty].inner {
            naga::TypeInner::Array {
                size: naga::ArraySize::Dynamic,
                stride,
                ..
            } => u64::from(stride),
            _ => u64::from(parsed.layouter[global.ty].size),
        };
        let name = global.name.clone().unwrap_or_default();
        out.push((binding.binding, name, kind, min));
    }
    out.sort_by_key(|b| b.0);
    out
}

fn descriptor_differences(d: &PassDescriptor) -> Vec<String> {
    let parsed = parse(&d.shader);
    let mut diffs = Vec::new();
    let wgsl = wgsl_bindings(&parsed);
    if wgsl.len() != d.bindings.len() {
        diffs.push(format!(
            "{}: WGSL declares {} bindings, the descriptor {}",
            d.shader.name,
            wgsl.len(),
            d.bindings.len()
        ));
    }
    for (i, (w, b)) in wgsl.iter().zip(d.bindings).enumerate() {
        let want = (i as u32, b.name.to_owned(), Some(b.kind), b.min_bytes);
        if *w != want {
            diffs.push(format!(
                "{}: binding {i}: WGSL {w:?}, descriptor {want:?}",
                d.shader.name
            ));
        }
    }
    let compute: Vec<&str> = parsed
        .module
        .entry_points
        .iter()
        .filter(|e| e.stage == naga::ShaderStage::Compute)
        .map(|e| e.name.as_str())
        .collect();
    for entry in d.entry_points {
        if !compute.contains(entry) {
            diffs.push(format!("{}: no compute entry point {entry}", d.shader.name));
        }
    }
    if compute.len() != d.entry_points.len() {
        diffs.push(format!(
            "{}: WGSL has compute entry points {compute:?}, the descriptor {:?}",
            d.shader.name, d.entry_points
        ));
    }
    diffs
}

#[test]
fn every_pass_descriptor_declares_its_shaders_bindings_and_entry_points() {
    let mut diffs = Vec::new();
    for d in pass::ALL {
        let found = descriptor_differences(d);
        println!(
            "{}: {} bindings, entry points {:?}: {}",
            d.shader.name,
            d.bindings.len(),
            d.entry_points,
            if found.is_empty() { "match" } else { "DIFFER" }
        );
        diffs.extend(found);
    }
    assert!(diffs.is_empty(), "\n{}", diffs.join("\n"));
    // Every shader with a compute entry point has a descriptor.
    for shader in shaders::ALL {
        let parsed = parse(shader);
        let compute = parsed.module.entry_points.iter();
        if !compute
            .into_iter()
            .any(|e| e.stage == naga::ShaderStage::Compute)
        {
            continue;
        }
        assert!(
            pass::ALL.iter().any(|d| d.shader.name == shader.name),
            "{} has no PassDescriptor",
            shader.name
        );
    }
}

/// `shader` with `from` replaced by `to` (which must occur).
fn edited(shader: WgslShader, from: &str, to: &str) -> WgslShader {
    assert!(
        shader.source.contains(from),
        "{from:?} not in {}",
        shader.name
    );
    WgslShader {
        name: shader.name,
        source: Box::leak(shader.source.replacen(from, to, 1).into_boxed_str()),
    }
}

/// The check itself fails on each kind of drift: two WGSL members swapped,
/// a member added in WGSL only, two Rust fields swapped, a Rust field the
/// WGSL lacks.
/// Asserts that `diffs` (printed under `what`) has a line with each of
/// `needles`.
fn expect_caught(what: &str, diffs: &[String], needles: &[&str]) {
    println!("{what}:\n{}", diffs.join("\n"));
    for needle in needles {
        assert!(
            diffs.iter().any(|d| d.contains(needle)),
            "{what}: {needle} not in {diffs:?}"
        );
    }
}

#[test]
fn the_twin_check_catches_reordered_and_one_sided_fields() {
    let rust = temporal_twin!();
    assert!(struct_differences(&shaders::TEMPORAL, &rust).is_empty());
    let swapped = edited(
        shaders::TEMPORAL,
        "    model: u32,\n    reset: u32,",
        "    reset: u32,\n    model: u32,",
    );
    expect_caught(
        "WGSL members swapped",
        &struct_differences(&swapped, &rust),
        &["member 0: WGSL reset"],
    );
    let added = edited(
        shaders::TEMPORAL,
        "    _pad1: f32,\n}",
        "    _pad1: f32,\n    extra: f32,\n}",
    );
    expect_caught(
        "WGSL member added",
        &struct_differences(&added, &rust),
        &["WGSL size 36 B, Rust 32 B", "9 members, Rust 8"],
    );
    expect_caught(
        "Rust fields swapped",
        &struct_differences(&shaders::TEMPORAL, &reordered_temporal_twin()),
        &["Rust model: u32 at 4"],
    );
    expect_caught(
        "Rust field added",
        &struct_differences(&shaders::ACUITY, &one_sided_acuity_twin()),
        &["cover 32 of 36 B"],
    );
}

/// A Rust `TemporalParams` with `model` and `reset` swapped.
fn reordered_temporal_twin() -> RustTwin {
    #[allow(dead_code)]
    #[repr(C)]
    struct TemporalParams {
        reset: u32,
        model: u32,
        overshoot: u32,
        _pad0: u32,
        dt_secs: f32,
        a: f32,
        b: f32,
        _pad1: f32,
    }
    temporal_twin!()
}

/// A Rust `AcuityParams` with a field the WGSL struct lacks (and the list
/// in this test not updated).
fn one_sided_acuity_twin() -> RustTwin {
    #[allow(dead_code)]
    #[repr(C)]
    struct AcuityParams {
        width: u32,
        height: u32,
        model: u32,
        max_radius: u32,
        white_cd_m2: f32,
        sigma_scale: f32,
        _pad0: f32,
        _pad1: f32,
        extra: f32,
    }
    acuity_twin!()
}
