//! The WGSL sources of the passes and their check against device limits.
//!
//! Every pass is one file under the workspace's `shaders/` directory, embedded
//! into the binary at build time (`include_str!`); passes that use the
//! shared helpers get `shaders/common.wgsl` prepended at compile time
//! (`concat!`), so naga's line numbers in errors count from the top of
//! common.wgsl.
//!
//! wgpu 30 does not reject a compute shader whose `var<workgroup>` storage
//! exceeds the device's `max_compute_workgroup_storage_size` (16 KiB in the
//! WebGPU defaults): such a shader runs on lavapipe and fails on real GPUs.
//! [`check_shader`] therefore parses and validates each shader with naga
//! (the version wgpu itself uses), sums, per compute entry point, the sizes
//! of the workgroup-address-space globals that entry point uses (each
//! rounded up to its alignment, as a driver lays them out), and checks the
//! workgroup size against `max_compute_workgroup_size_{x,y,z}` and
//! `max_compute_invocations_per_workgroup`. Every pipeline of this crate is
//! built through [`crate::GpuContext::create_compute_pipeline`], which runs
//! this check first.

use crate::error::GpuError;

/// A WGSL shader: its file name (used in every error) and full source.
#[derive(Debug, Clone, Copy)]
pub struct WgslShader {
    /// File name under `shaders/` (the pass file, for composed sources).
    pub name: &'static str,
    /// Complete WGSL source (common helpers included where needed).
    pub source: &'static str,
}

/// `shaders/<file>` with `shaders/common.wgsl` prepended, at compile time.
macro_rules! with_common {
    ($file:literal) => {
        concat!(
            include_str!("../../../shaders/common.wgsl"),
            "\n",
            include_str!(concat!("../../../shaders/", $file))
        )
    };
}

/// `shaders/<file>` with `shaders/common.wgsl` and `shaders/frame_state.wgsl`
/// (the per-frame state struct and encoding helpers) prepended.
macro_rules! with_frame_state {
    ($file:literal) => {
        concat!(
            include_str!("../../../shaders/common.wgsl"),
            "\n",
            include_str!("../../../shaders/frame_state.wgsl"),
            "\n",
            include_str!(concat!("../../../shaders/", $file))
        )
    };
}

/// Shared helpers (complex arithmetic, constants).
pub const COMMON: WgslShader = WgslShader {
    name: "common.wgsl",
    source: include_str!("../../../shaders/common.wgsl"),
};

/// One Stockham FFT stage (radix 4/2) along rows or columns.
pub const FFT: WgslShader = WgslShader {
    name: "fft.wgsl",
    source: with_common!("fft.wgsl"),
};

/// `shaders/<file>` with `shaders/psf_build.wgsl` (the glare-kernel build's
/// uniform struct) prepended.
macro_rules! with_psf_build {
    ($file:literal) => {
        concat!(
            include_str!("../../../shaders/psf_build.wgsl"),
            "\n",
            include_str!(concat!("../../../shaders/", $file))
        )
    };
}

/// The uniform struct shared by the glare-kernel build passes.
pub const PSF_BUILD: WgslShader = WgslShader {
    name: "psf_build.wgsl",
    source: include_str!("../../../shaders/psf_build.wgsl"),
};

/// Stage 3, kernel build 1: the pupil-plane field P · F · A (001 eq 7).
pub const PSF_APERTURE: WgslShader = WgslShader {
    name: "psf_aperture.wgsl",
    source: with_psf_build!("psf_aperture.wgsl"),
};

/// Stage 3, kernel build 2: |FFT|², fftshifted, as fractions of the light.
pub const PSF_INTENSITY: WgslShader = WgslShader {
    name: "psf_intensity.wgsl",
    source: with_psf_build!("psf_intensity.wgsl"),
};

/// Stage 3, kernel build 3: spectral sum onto display pixels, particle lobes.
pub const PSF_SPECTRAL: WgslShader = WgslShader {
    name: "psf_spectral.wgsl",
    source: with_psf_build!("psf_spectral.wgsl"),
};

/// Stage 3, kernel build 4: unit energy, plus the CIE 146 stray light.
pub const PSF_NORMALISE: WgslShader = WgslShader {
    name: "psf_normalise.wgsl",
    source: with_psf_build!("psf_normalise.wgsl"),
};

/// The per-frame state struct shared by the frame passes.
pub const FRAME_STATE: WgslShader = WgslShader {
    name: "frame_state.wgsl",
    source: include_str!("../../../shaders/frame_state.wgsl"),
};

/// Stage 1: scene import, block luminance and gaze-weighted pooling.
pub const POOLING: WgslShader = WgslShader {
    name: "pooling.wgsl",
    source: with_frame_state!("pooling.wgsl"),
};

/// Stage 2: temporal adaptation step (one thread).
pub const TEMPORAL: WgslShader = WgslShader {
    name: "temporal.wgsl",
    source: with_frame_state!("temporal.wgsl"),
};

/// `shaders/<file>` with `shaders/glare_window.wgsl` (the glare window's
/// uniforms and source weight) prepended.
macro_rules! with_glare_window {
    ($file:literal) => {
        concat!(
            include_str!("../../../shaders/glare_window.wgsl"),
            "\n",
            include_str!(concat!("../../../shaders/", $file))
        )
    };
}

/// The glare window's uniform struct and source weight, shared by the
/// window glare and the far field.
pub const GLARE_WINDOW: WgslShader = WgslShader {
    name: "glare_window.wgsl",
    source: include_str!("../../../shaders/glare_window.wgsl"),
};

/// Stage 4: windowed FFT glare at the gaze with the Gaussian falloff blend.
pub const GLARE: WgslShader = WgslShader {
    name: "glare.wgsl",
    source: with_glare_window!("glare.wgsl"),
};

/// Stage 4: the full-field stray light (CIE 146 veil of every pixel on a
/// coarse angular grid), after the window glare.
pub const FAR_GLARE: WgslShader = WgslShader {
    name: "far_glare.wgsl",
    source: with_glare_window!("far_glare.wgsl"),
};

/// Stage 5 (+ 8): acuity blur of Lab lightness, then encoding.
pub const ACUITY: WgslShader = WgslShader {
    name: "acuity.wgsl",
    source: with_frame_state!("acuity.wgsl"),
};

/// Stages 6–8: tone reproduction, colour, display encoding.
pub const TONE: WgslShader = WgslShader {
    name: "tone.wgsl",
    source: with_frame_state!("tone.wgsl"),
};

/// Presentation: the display frame (or a solid colour) into a window's
/// surface (vertex + fragment; see [`crate::present`]).
pub const PRESENT: WgslShader = WgslShader {
    name: "present.wgsl",
    source: include_str!("../../../shaders/present.wgsl"),
};

/// Every shader of the crate (for the limits test and tooling).
pub const ALL: &[WgslShader] = &[
    COMMON,
    FFT,
    FRAME_STATE,
    PSF_BUILD,
    PSF_APERTURE,
    PSF_INTENSITY,
    PSF_SPECTRAL,
    PSF_NORMALISE,
    POOLING,
    TEMPORAL,
    GLARE_WINDOW,
    GLARE,
    FAR_GLARE,
    ACUITY,
    TONE,
    PRESENT,
];

/// What one compute entry point needs from the device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EntryPointResources {
    /// Entry point name.
    pub name: String,
    /// `@workgroup_size(x, y, z)`.
    pub workgroup_size: [u32; 3],
    /// Bytes of `var<workgroup>` globals the entry point uses.
    pub workgroup_storage_bytes: u64,
}

/// Result of [`check_shader`]: the compute entry points and their needs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ShaderReport {
    /// Shader file name.
    pub shader: &'static str,
    /// One entry per compute entry point.
    pub entry_points: Vec<EntryPointResources>,
}

/// Parses and validates `shader` with naga and checks every compute entry
/// point's workgroup storage and workgroup size against `limits`.
pub fn check_shader(shader: &WgslShader, limits: &wgpu::Limits) -> Result<ShaderReport, GpuError> {
    let module =
        naga::front::wgsl::parse_str(shader.source).map_err(|e| GpuError::ShaderParse {
            shader: shader.name,
            message: e.emit_to_string(shader.source),
        })?;
    let info = naga::valid::Validator::new(
        naga::valid::ValidationFlags::all(),
        naga::valid::Capabilities::default(),
    )
    .validate(&module)
    .map_err(|e| GpuError::ShaderValidation {
        shader: shader.name,
        message: e.emit_to_string(shader.source),
    })?;
    let mut layouter = naga::proc::Layouter::default();
    layouter
        .update(module.to_ctx())
        .map_err(|e| GpuError::ShaderValidation {
            shader: shader.name,
            message: format!("type layout: {e}"),
        })?;
    let mut entry_points = Vec::new();
    for (index, entry) in module.entry_points.iter().enumerate() {
        if entry.stage != naga::ShaderStage::Compute {
            continue;
        }
        let bytes = workgroup_storage_bytes(&module, &layouter, info.get_entry_point(index));
        let resources = EntryPointResources {
            name: entry.name.clone(),
            workgroup_size: entry.workgroup_size,
            workgroup_storage_bytes: bytes,
        };
        check_entry_point(shader, &resources, limits)?;
        entry_points.push(resources);
    }
    Ok(ShaderReport {
        shader: shader.name,
        entry_points,
    })
}

/// Bytes of the `var<workgroup>` globals an entry point uses, each rounded
/// up to its alignment as a driver lays them out.
fn workgroup_storage_bytes(
    module: &naga::Module,
    layouter: &naga::proc::Layouter,
    function_info: &naga::valid::FunctionInfo,
) -> u64 {
    let mut bytes: u64 = 0;
    for (handle, global) in module.global_variables.iter() {
        if global.space != naga::AddressSpace::WorkGroup || function_info[handle].is_empty() {
            continue;
        }
        let layout = layouter[global.ty];
        bytes = u64::from(layout.alignment.round_up(bytes as u32)) + u64::from(layout.size);
    }
    bytes
}

/// An entry point's workgroup storage and size against the device limits.
fn check_entry_point(
    shader: &WgslShader,
    entry: &EntryPointResources,
    limits: &wgpu::Limits,
) -> Result<(), GpuError> {
    if entry.workgroup_storage_bytes > u64::from(limits.max_compute_workgroup_storage_size) {
        return Err(GpuError::WorkgroupStorage {
            shader: shader.name,
            entry_point: entry.name.clone(),
            bytes: entry.workgroup_storage_bytes,
            limit: limits.max_compute_workgroup_storage_size,
        });
    }
    let size = entry.workgroup_size;
    let too_big = |limit_name, limit| GpuError::WorkgroupSize {
        shader: shader.name,
        entry_point: entry.name.clone(),
        size,
        limit_name,
        limit,
    };
    let per_axis = [
        (
            "max_compute_workgroup_size_x",
            limits.max_compute_workgroup_size_x,
        ),
        (
            "max_compute_workgroup_size_y",
            limits.max_compute_workgroup_size_y,
        ),
        (
            "max_compute_workgroup_size_z",
            limits.max_compute_workgroup_size_z,
        ),
    ];
    for (axis, (limit_name, limit)) in per_axis.into_iter().enumerate() {
        if size[axis] > limit {
            return Err(too_big(limit_name, limit));
        }
    }
    let invocations = u64::from(size[0]) * u64::from(size[1]) * u64::from(size[2]);
    if invocations > u64::from(limits.max_compute_invocations_per_workgroup) {
        return Err(too_big(
            "max_compute_invocations_per_workgroup",
            limits.max_compute_invocations_per_workgroup,
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_real_shaders_fit_the_webgpu_default_limits() {
        let limits = wgpu::Limits::default();
        for shader in ALL {
            let report = check_shader(shader, &limits).unwrap_or_else(|e| panic!("{e}"));
            for entry in &report.entry_points {
                println!(
                    "{}::{} workgroup {:?}, {} B workgroup storage",
                    shader.name, entry.name, entry.workgroup_size, entry.workgroup_storage_bytes
                );
            }
        }
        let fft = check_shader(&FFT, &limits).unwrap();
        assert_eq!(fft.entry_points.len(), 1);
        assert_eq!(fft.entry_points[0].name, "fft_stage");
        assert_eq!(fft.entry_points[0].workgroup_size, [64, 1, 1]);
    }

    /// 64 KiB of workgroup storage: runs on lavapipe, fails on real GPUs,
    /// and wgpu 30 does not reject it; the check must.
    const OVERSIZED: WgslShader = WgslShader {
        name: "oversized_test.wgsl",
        source: "
            var<workgroup> tile: array<vec4<f32>, 4096>;
            @group(0) @binding(0) var<storage, read_write> out: array<vec4<f32>>;
            @compute @workgroup_size(64)
            fn main(@builtin(local_invocation_index) i: u32) {
                tile[i] = vec4<f32>(f32(i));
                workgroupBarrier();
                out[i] = tile[4095u - i];
            }
        ",
    };

    #[test]
    fn oversized_workgroup_storage_is_rejected_with_the_shader_name() {
        let err = check_shader(&OVERSIZED, &wgpu::Limits::default()).unwrap_err();
        match &err {
            GpuError::WorkgroupStorage {
                shader,
                entry_point,
                bytes,
                limit,
            } => {
                assert_eq!(*shader, "oversized_test.wgsl");
                assert_eq!(entry_point, "main");
                assert_eq!(*bytes, 4096 * 16);
                assert_eq!(*limit, 16384);
            }
            other => panic!("wrong error: {other}"),
        }
        assert!(err.to_string().contains("oversized_test.wgsl"), "{err}");
        // A device with a larger limit accepts it.
        let big = wgpu::Limits {
            max_compute_workgroup_storage_size: 65536,
            ..wgpu::Limits::default()
        };
        assert!(check_shader(&OVERSIZED, &big).is_ok());
    }

    #[test]
    fn storage_counts_only_globals_the_entry_point_uses_with_alignment() {
        // Two entry points, each 12 KiB + padding: each fits alone, the sum
        // (24 KiB) would not; `b` adds an f32 then a vec4 array (align 16).
        let shader = WgslShader {
            name: "two_entries_test.wgsl",
            source: "
                var<workgroup> a: array<vec4<f32>, 768>;
                var<workgroup> s: f32;
                var<workgroup> b: array<vec4<f32>, 768>;
                @compute @workgroup_size(64) fn first(@builtin(local_invocation_index) i: u32) { a[i] = vec4<f32>(1.0); }
                @compute @workgroup_size(64) fn second(@builtin(local_invocation_index) i: u32) { s = 1.0; b[i] = vec4<f32>(s); }
            ",
        };
        let report = check_shader(&shader, &wgpu::Limits::default()).unwrap();
        assert_eq!(report.entry_points[0].workgroup_storage_bytes, 768 * 16);
        assert_eq!(
            report.entry_points[1].workgroup_storage_bytes,
            16 + 768 * 16
        );
    }

    #[test]
    fn oversized_workgroup_size_is_rejected() {
        let shader = WgslShader {
            name: "wide_test.wgsl",
            source: "@compute @workgroup_size(32, 16) fn main() {}",
        };
        let err = check_shader(&shader, &wgpu::Limits::default()).unwrap_err();
        assert!(
            matches!(
                &err,
                GpuError::WorkgroupSize {
                    limit_name: "max_compute_invocations_per_workgroup",
                    size: [32, 16, 1],
                    ..
                }
            ),
            "{err}"
        );
        let tall = WgslShader {
            name: "tall_test.wgsl",
            source: "@compute @workgroup_size(1, 1, 128) fn main() {}",
        };
        let err = check_shader(&tall, &wgpu::Limits::default()).unwrap_err();
        assert!(
            matches!(
                &err,
                GpuError::WorkgroupSize {
                    limit_name: "max_compute_workgroup_size_z",
                    ..
                }
            ),
            "{err}"
        );
    }

    #[test]
    fn parse_errors_name_the_shader() {
        let shader = WgslShader {
            name: "broken_test.wgsl",
            source: "@compute @workgroup_size(64) fn main( {}",
        };
        let err = check_shader(&shader, &wgpu::Limits::default()).unwrap_err();
        assert!(
            matches!(
                err,
                GpuError::ShaderParse {
                    shader: "broken_test.wgsl",
                    ..
                }
            ),
            "{err}"
        );
    }
}
