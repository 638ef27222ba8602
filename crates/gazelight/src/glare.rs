//! `gazelight glare SCENE --gaze-deg AZ,EL [...]`: the glare numbers of a
//! scene image at one or more gazes — vertical illuminance at the eye,
//! luminance at the gaze with and without the veil, the CIE 146 and
//! Stiles–Holladay (evalglare's) veils, the threshold increment, DGP, DGI,
//! UGR, VCP and CGI, and the glare sources found as evalglare finds them
//! (peaks above 50 000 cd/m² sources of their own) — printed, and written
//! as JSON with `--json`. The
//! definitions are [`gazelight_vision::scene_glare`]'s; the projection is
//! the Radiance header's `VIEW=` or `--scene-projection`/`--scene-fov-deg`.

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use clap::Args;
use gazelight_tracker::profile::{
    AGE_YEARS_RANGE, DEFAULT_AGE_YEARS, DEFAULT_PIGMENTATION, PIGMENTATION_RANGE,
};
use gazelight_tracker::pupil_model::unified_mm;
use gazelight_vision::scene::projection::direction_from_angles;
use gazelight_vision::scene::{LuminanceScale, ProjectionKind, Scene, SceneProjection};
use gazelight_vision::scene_glare::{GlareOptions, SceneGlare, SourceThreshold};
use pair::parse_pair;

/// Arguments of `gazelight glare`.
#[derive(Args, Debug)]
pub struct GlareArgs {
    /// The scene: a Radiance .hdr (its VIEW= gives the projection) or an
    /// OpenEXR, in cd/m² (Radiance: 179 lm/W × RGB / EXPOSURE).
    pub scene: PathBuf,
    /// A gaze: azimuth right and elevation up from the image's view
    /// direction, degrees (repeat for several).
    #[arg(
        long = "gaze-deg",
        value_name = "AZ,EL",
        required = true,
        allow_hyphen_values = true
    )]
    pub gaze_deg: Vec<String>,
    /// The image's projection when its header has none (or to override
    /// it): equirectangular, perspective, angular, hemispherical,
    /// equisolid, stereographic.
    #[arg(long, value_name = "KIND")]
    pub scene_projection: Option<String>,
    /// The image's full field, degrees: `H` (square pixels) or `H,V`.
    #[arg(long, value_name = "H[,V]", requires = "scene_projection")]
    pub scene_fov_deg: Option<String>,
    /// Multiply the file's values by this (cd/m² per unit; default 1).
    #[arg(long, value_name = "F")]
    pub luminance_factor: Option<f64>,
    /// Observer's age, years (CIE 146; default 25).
    #[arg(long)]
    pub age_years: Option<f64>,
    /// Ocular pigmentation (CIE 146: 0 very dark … 1.2 very light eyes;
    /// default 0.5).
    #[arg(long)]
    pub pigmentation: Option<f64>,
    /// Pupil diameter, mm, for the retinal illuminance at the gaze.
    #[arg(long, conflicts_with = "adapt")]
    pub pupil_mm: Option<f64>,
    /// Take the pupil from the Watson–Yellott model at the background
    /// luminance (a 60° field, both eyes, the observer's age).
    #[arg(long)]
    pub adapt: bool,
    /// Glare source threshold as evalglare's `-b`: above 100 a luminance
    /// in cd/m², at or below a factor of the average luminance (of the
    /// task area with `--task-opening-rad`). Default as evalglare's: 2000
    /// cd/m², or 5 × the task luminance with a task area.
    #[arg(long, value_name = "B")]
    pub source_threshold: Option<f64>,
    /// evalglare's task area `-t`: a disc of this opening angle, radians,
    /// around each gaze; `--source-threshold` at or below 100 (default 5)
    /// multiplies its mean luminance.
    #[arg(long, value_name = "RAD")]
    pub task_opening_rad: Option<f64>,
    /// evalglare's search radius `-r`, radians (default 0.2).
    #[arg(long, value_name = "RAD", default_value_t = 0.2)]
    pub search_radius_rad: f64,
    /// evalglare's peak extraction level `-Y`, cd/m²: source pixels at or
    /// above it become sources of their own (default 50 000, on as in
    /// evalglare).
    #[arg(long, value_name = "CD_M2", default_value_t = 50_000.0)]
    pub peak_cd_m2: f64,
    /// Turn peak extraction off (evalglare's `-x`).
    #[arg(long, conflicts_with = "peak_cd_m2")]
    pub no_peak_extraction: bool,
    /// evalglare's smoothing `-s` (off by default, as in evalglare): a
    /// pixel next to a source joins it when the source holds more than a
    /// fifth of a small disc around it.
    #[arg(long)]
    pub smooth: bool,
    /// Write the numbers as JSON to this file.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
}

/// Tiny parsers shared by the glare arguments.
mod pair {
    /// `A,B`, or `A` alone (then B is `None`).
    pub fn parse_pair(s: &str, what: &str) -> anyhow::Result<(f64, Option<f64>)> {
        let mut parts = s.split(',').map(str::trim);
        let a = parts.next().unwrap_or_default();
        let b = parts.next();
        if parts.next().is_some() {
            anyhow::bail!("{what} {s:?}: expected one or two numbers separated by a comma");
        }
        let num = |t: &str| -> anyhow::Result<f64> {
            t.parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| anyhow::anyhow!("{what} {s:?}: {t:?} is not a finite number"))
        };
        Ok((num(a)?, b.map(num).transpose()?))
    }
}

/// Loads the scene and settles its projection (the arguments' over the
/// header's).
pub fn load_scene(
    path: &Path,
    projection: Option<&str>,
    fov_deg: Option<&str>,
    factor: Option<f64>,
) -> anyhow::Result<Scene> {
    // The one bound every front end shares (gazelight_vision::scene).
    let factor =
        gazelight_vision::scene::check_factor("--luminance-factor", factor.unwrap_or(1.0))?;
    let scale = LuminanceScale::CdM2PerUnit { factor };
    let mut scene = Scene::load(path, scale)?;
    // A scaled scene that overflows is refused (an implausible one warned).
    crate::bounds::scene_luminance(&scene)?;
    if let Some(kind) = projection {
        let kind = ProjectionKind::parse(kind).with_context(|| {
            format!(
                "--scene-projection {kind:?}: expected one of {}",
                ProjectionKind::ALL.map(ProjectionKind::name).join(", ")
            )
        })?;
        let (w, h) = (scene.image.width, scene.image.height);
        scene.projection = Some(match (kind, fov_deg) {
            (ProjectionKind::Equirectangular, _) => SceneProjection::equirectangular(w, h),
            (_, None) => bail!("--scene-projection {} needs --scene-fov-deg", kind.name()),
            (_, Some(f)) => match parse_pair(f, "--scene-fov-deg")? {
                (hf, None) => SceneProjection::with_square_pixels(kind, hf, w, h)?,
                (hf, Some(vf)) => SceneProjection::new(kind, hf, vf, w, h)?,
            },
        });
    }
    Ok(scene)
}

pub use gazelight_vision::scene_glare::{MAX_GLARE_PIXELS, bin_for_glare};

/// Runs `gazelight glare`.
pub fn run(args: GlareArgs) -> anyhow::Result<()> {
    let age = args.age_years.unwrap_or(DEFAULT_AGE_YEARS);
    let pigmentation = args.pigmentation.unwrap_or(DEFAULT_PIGMENTATION);
    if !(AGE_YEARS_RANGE.0..=AGE_YEARS_RANGE.1).contains(&age) {
        bail!(
            "--age-years {age}: expected {}..={}",
            AGE_YEARS_RANGE.0,
            AGE_YEARS_RANGE.1
        );
    }
    if !(PIGMENTATION_RANGE.0..=PIGMENTATION_RANGE.1).contains(&pigmentation) {
        bail!(
            "--pigmentation {pigmentation}: expected {}..={}",
            PIGMENTATION_RANGE.0,
            PIGMENTATION_RANGE.1
        );
    }
    if let Some(d) = args.pupil_mm
        && !(d.is_finite() && (1.0..=10.0).contains(&d))
    {
        bail!("--pupil-mm {d}: expected 1..=10 mm");
    }
    if let Some(b) = args.source_threshold
        && !(b.is_finite() && b > 0.0)
    {
        bail!("--source-threshold {b}: expected > 0");
    }
    if let Some(t) = args.task_opening_rad
        && !(t.is_finite() && t > 0.0 && t < 3.0)
    {
        bail!("--task-opening-rad {t}: expected 0 < t < 3");
    }
    if !(args.peak_cd_m2.is_finite() && args.peak_cd_m2 > 0.0) {
        bail!("--peak-cd-m2 {}: expected > 0", args.peak_cd_m2);
    }
    if !(args.search_radius_rad.is_finite()
        && args.search_radius_rad > 0.0
        && args.search_radius_rad < 3.0)
    {
        bail!(
            "--search-radius-rad {}: expected 0 < r < 3",
            args.search_radius_rad
        );
    }
    if let Some(path) = &args.json {
        // Before anything is read or written: `--json` must not be the scene.
        crate::out_dir::check_out_file("glare", "--json", path, &[&args.scene])?;
    }
    let gazes: Vec<[f64; 2]> = args
        .gaze_deg
        .iter()
        .map(|g| match parse_pair(g, "--gaze-deg")? {
            (a, Some(e)) if e.abs() <= 90.0 => Ok([a, e]),
            _ => bail!("--gaze-deg {g:?}: expected AZ,EL in degrees with |EL| ≤ 90"),
        })
        .collect::<anyhow::Result<_>>()?;
    let scene = load_scene(
        &args.scene,
        args.scene_projection.as_deref(),
        args.scene_fov_deg.as_deref(),
        args.luminance_factor,
    )?;
    let projection = scene.effective_projection();
    if scene.projection.is_none() {
        eprintln!(
            "note: {} has no known projection: read as an equirectangular panorama",
            args.scene.display()
        );
    }
    let (image, glare_projection, bin) = bin_for_glare(&scene.image, projection);
    if bin > 1 {
        eprintln!(
            "note: {}: {}×{} px is more than the {MAX_GLARE_PIXELS} pixels the glare sums keep: \
             binned {bin}×{bin} to {}×{} px (source positions are given in the scene's pixels, \
             source pixel counts in binned pixels)",
            args.scene.display(),
            projection.width_px,
            projection.height_px,
            glare_projection.width_px,
            glare_projection.height_px
        );
    }
    let glare = SceneGlare::new(&image, glare_projection);
    drop(image);
    // In the scene's pixels (a binned pixel outside the field stands for
    // its block).
    let no_data_pixels =
        (glare.no_data_pixels * bin * bin).min(projection.width_px * projection.height_px);
    // Binned source positions back in the scene's continuous pixels.
    let to_scene_px = |p: [f64; 2]| {
        [
            p[0] * projection.width_px as f64 / glare_projection.width_px as f64,
            p[1] * projection.height_px as f64 / glare_projection.height_px as f64,
        ]
    };
    let opts = GlareOptions {
        threshold: args.source_threshold.map_or(
            SourceThreshold::evalglare_default(args.task_opening_rad.is_some()),
            SourceThreshold::from_evalglare_b,
        ),
        task_opening_rad: args.task_opening_rad,
        search_radius_rad: args.search_radius_rad,
        peak_extraction_cd_m2: (!args.no_peak_extraction).then_some(args.peak_cd_m2),
        smoothing: args.smooth,
        age_years: age,
        pigmentation,
        ..GlareOptions::default()
    };
    println!(
        "{}: {}×{} px, {} {:.1}×{:.1}°, {} pixels outside the field (no data)",
        args.scene.display(),
        projection.width_px,
        projection.height_px,
        projection.kind.name(),
        projection.hfov_deg,
        projection.vfov_deg,
        no_data_pixels
    );
    let mut out = Vec::new();
    for g in &gazes {
        let mut r = glare.at_gaze(direction_from_angles(g[0], g[1]), &opts);
        for src in &mut r.sources {
            src.position_px = to_scene_px(src.position_px);
        }
        let (pupil_mm, pupil_source) = match (args.pupil_mm, args.adapt) {
            (Some(d), _) => (Some(d), "given"),
            (None, true) => (
                Some(unified_mm(
                    r.background_luminance_cd_m2,
                    std::f64::consts::PI * 30.0 * 30.0,
                    age,
                    true,
                )),
                "watson_yellott",
            ),
            (None, false) => (None, "none"),
        };
        let retinal_td = match (pupil_mm, r.luminance_at_gaze_with_veil_cd_m2) {
            (Some(d), Some(l)) => Some(l * std::f64::consts::PI * d * d / 4.0),
            _ => None,
        };
        if !r.gaze_in_field {
            eprintln!(
                "warning: gaze {},{}° is outside the scene's field: no luminance at the gaze",
                g[0], g[1]
            );
        }
        println!(
            "gaze {:>6.1},{:>5.1}°  E_v {:>9.2} lx  L_gaze {:>10}  +veil {:>10}  veil CIE146 {:>8.3}  veil S-H {:>8.3} cd/m²  TI {:>6.1} %  sources {}",
            g[0],
            g[1],
            r.vertical_illuminance_lux,
            r.luminance_at_gaze_cd_m2
                .map_or("outside".into(), |l| format!("{l:.3}")),
            r.luminance_at_gaze_with_veil_cd_m2
                .map_or("outside".into(), |l| format!("{l:.3}")),
            r.veil_cie146_cd_m2,
            r.veil_stiles_holladay_cd_m2,
            r.threshold_increment_pct,
            r.sources.len()
        );
        println!(
            "    DGP {:.3}  DGI {:.2}  UGR {}  VCP {:.1}  CGI {:.2}  L_b {:.2} cd/m²  E_dir {:.2} lx",
            r.indices.dgp,
            r.indices.dgi,
            r.indices
                .ugr
                .map_or("none (no background)".into(), |u| format!("{u:.2}")),
            r.indices.vcp,
            r.indices.cgi,
            r.background_luminance_cd_m2,
            r.source_illuminance_lux
        );
        for s in &r.sources {
            println!(
                "    {} at {:>6.1},{:>5.1}° ({:.1}, {:.1} px): {:.2e} sr, {:.0} cd/m², E {:.2} lx, {:.1}° from the gaze, P {:.2}, veil {:.3} cd/m²",
                if s.peak { "peak  " } else { "source" },
                s.azimuth_elevation_deg[0],
                s.azimuth_elevation_deg[1],
                s.position_px[0],
                s.position_px[1],
                s.solid_angle_sr,
                s.luminance_cd_m2,
                s.illuminance_lux,
                s.angle_from_gaze_deg,
                s.position_index,
                s.veil_stiles_holladay_cd_m2
            );
        }
        let mut v = serde_json::to_value(&r)?;
        if let (Some(view), Some(sources)) = (
            scene.radiance_view,
            v.get_mut("sources").and_then(|s| s.as_array_mut()),
        ) {
            for (s, src) in sources.iter_mut().zip(&r.sources) {
                let world = view.to_world(glam_dir(src.direction));
                s["direction_radiance_world"] = serde_json::json!(world.map(|w| w.to_array()));
                let px_world = view.to_world(glam_dir(src.pixel_direction));
                s["pixel_direction_radiance_world"] =
                    serde_json::json!(px_world.map(|w| w.to_array()));
            }
        }
        v["pupil_mm"] = serde_json::json!(pupil_mm);
        v["pupil_source"] = serde_json::json!(pupil_source);
        v["retinal_illuminance_at_gaze_td"] = serde_json::json!(retinal_td);
        out.push(v);
    }
    if let Some(path) = &args.json {
        let doc = serde_json::json!({
            "schema": "gazelight.glare/2",
            "scene": args.scene.display().to_string(),
            "projection": projection,
            "projection_known": scene.projection.is_some(),
            "radiance_view": scene.radiance_view,
            "pixel_aspect": scene.pixel_aspect,
            "no_data_pixels": no_data_pixels,
            "options": opts,
            "gazes": out,
        });
        crate::out_dir::write_atomic(
            path,
            (serde_json::to_string_pretty(&doc)? + "\n").as_bytes(),
        )?;
    }
    Ok(())
}

fn glam_dir(d: [f64; 3]) -> gazelight_vision::scene::projection::DVec3 {
    gazelight_vision::scene::projection::DVec3::from_array(d)
}
