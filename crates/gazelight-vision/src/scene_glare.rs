//! Glare numbers of a scene image at a gaze: the vertical illuminance at
//! the eye, the glare sources, the veiling luminance by CIE 146:2002 and by
//! the Stiles–Holladay formula evalglare reports, the threshold increment
//! and the glare indices DGP, DGI, UGR, VCP and CGI
//! ([`crate::glare_indices`]) — for any [`SceneProjection`], each pixel
//! weighted by its own solid angle, pixels outside the image's field
//! ignored. Sources are found as evalglare 3.06 finds them by default, so
//! that the numbers at the image's own view direction are evalglare's.
//!
//! Definitions (for a gaze direction g; a pixel's luminance L in cd/m², its
//! solid angle ω in sr, its direction d; only pixels in the field and in
//! front of the eye, d·g ≥ 0, count — the half space a fisheye centred on
//! g sees, as evalglare's `pict_is_validpixel`):
//!
//! * vertical illuminance at the eye, on the plane facing g:
//!   `E_v = Σ L ω (d·g)` lux;
//! * glare sources, evalglare 3.06's defaults (`main`, `find_near_pgs`,
//!   `find_split`):
//!   1. pixels brighter than a threshold: 2000 cd/m² (its `-b` above 100
//!      is an absolute luminance, at or below 100 a factor of the average
//!      luminance Σ L ω / Σ ω — of the task area when one is set, where the
//!      factor defaults to 5: `-t`, here a disc around the gaze);
//!   2. grouped: a pixel joins a source when it lies within half the
//!      search radius `-r` (default 0.2 rad: evalglare compares twice the
//!      angle with it) of one of its pixels;
//!   3. peak extraction (`-y`, on by default; `-x` off; `-Y` sets the
//!      level, default 50 000 cd/m²): the pixels of a source at or above
//!      the level are taken out of it and grouped among themselves the
//!      same way, each group a source of its own; a source left without
//!      pixels is gone;
//!   4. smoothing (`-s`), off by default as in evalglare
//!      ([`GlareOptions::smoothing`]), before the peak extraction: a pixel
//!      in no source joins one that holds more than a fifth of a disc of
//!      pixels around it.
//!
//!   Each source: its solid angle Σ ω, its mean luminance Σ L ω / Σ ω,
//!   its position the L ω-weighted mean pixel position (evalglare 2.14
//!   on) and the direction through it, its illuminance at the eye
//!   `E_i = Σ L ω (d·g)`; evalglare then reads the direction of the whole
//!   pixel its truncated position index names (its `(int)av_posx`, rows
//!   counted from the bottom), up to a pixel off the position: that
//!   pixel's direction gives the source's angle from the gaze for the
//!   veil and its position index ([`crate::glare_indices::position_index`],
//!   with the image's up, camera +y, as evalglare's `-vu`);
//! * Stiles–Holladay veil (evalglare's `Lveil_cie`):
//!   `L_v = Σ_i 10 E_i / θ_i²`, θ_i in degrees between g and source i's
//!   whole pixel. evalglare divides by θ² + 10⁻¹⁶, which a gaze on a
//!   pixel centre turns into 10¹⁷ E; here θ is kept at least the angular
//!   radius √(ω/π) of that pixel, so a gaze on or next to a source gives a
//!   finite veil — evalglare's own, since at its image's axis (an even
//!   number of pixels across) the nearest pixel centre is farther away;
//! * CIE 146:2002 veil of the whole image at the observer's age and
//!   pigmentation: `L_v = Σ L ω (d·g) f_CIE146(θ)` over the pixels with
//!   θ ≥ [`GlareOptions::cie146_inner_deg`] (the central disc is what the
//!   eye looks at, not a glare source);
//! * luminance at the gaze: the ω-weighted mean over a disc of
//!   [`GlareOptions::gaze_disc_deg`] around g, and the same plus the CIE
//!   146 veil ("as the eye sees it");
//! * background luminance, evalglare's default (`-q 0`): `(E_v − Σ E_i) / π`;
//! * threshold increment (CIE 140-2000 eq. 5 and 6, for road lighting):
//!   `TI = 65 L_v / L_ad^0.8` % for L_ad ≤ 5 cd/m², `95 L_v / L_ad^1.05` %
//!   above, with the CIE 146 veil and the adaptation luminance L_ad taken
//!   as the background luminance.

use std::sync::Mutex;

use glam::DVec3;
use serde::Serialize;

use crate::RgbImage;
use crate::glare_indices::{
    GlareIndices, IndexScene, IndexSource, glare_indices, position_index,
    veil_stiles_holladay_cd_m2,
};
use crate::image::luminance;
use crate::scene::SceneProjection;
use crate::scene::projection::angles_from_direction;
use crate::stray_light::cie146_veil_per_sr;

/// evalglare's default fixed source threshold, cd/m² (evalglare 2.05 on,
/// after C. Pierson's study).
pub const EVALGLARE_DEFAULT_THRESHOLD_CD_M2: f64 = 2000.0;
/// evalglare's default factor of the task luminance when a task area is
/// set and `-b` is not (evalglare 2.06).
pub const EVALGLARE_TASK_FACTOR: f64 = 5.0;
/// evalglare's default peak extraction level `-y`, cd/m² (evalglare 0.9c).
pub const EVALGLARE_PEAK_CD_M2: f64 = 50_000.0;
/// evalglare's default search radius `-r`, radians.
pub const EVALGLARE_SEARCH_RADIUS_RAD: f64 = 0.2;

/// The glare source threshold (evalglare's `-b`).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum SourceThreshold {
    /// Pixels brighter than this luminance, cd/m².
    AbsoluteCdM2 { cd_m2: f64 },
    /// Pixels brighter than this factor times the average luminance: of
    /// the task area when [`GlareOptions::task_opening_rad`] is set, else
    /// of the whole half space in front of the eye.
    TimesAverage { factor: f64 },
}

impl SourceThreshold {
    /// evalglare's reading of `-b x`: above 100 a luminance, else a factor.
    pub fn from_evalglare_b(b: f64) -> Self {
        if b > 100.0 {
            Self::AbsoluteCdM2 { cd_m2: b }
        } else {
            Self::TimesAverage { factor: b }
        }
    }

    /// evalglare's default without `-b`: 2000 cd/m², or 5 × the task
    /// luminance when a task area is set.
    pub fn evalglare_default(task: bool) -> Self {
        if task {
            Self::TimesAverage {
                factor: EVALGLARE_TASK_FACTOR,
            }
        } else {
            Self::AbsoluteCdM2 {
                cd_m2: EVALGLARE_DEFAULT_THRESHOLD_CD_M2,
            }
        }
    }
}

/// Settings of a glare evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct GlareOptions {
    /// Which pixels are glare sources (evalglare's default 2000 cd/m²).
    pub threshold: SourceThreshold,
    /// evalglare's task area `-t`: a disc of this opening angle (its
    /// diameter), radians, around the gaze, whose mean luminance a
    /// [`SourceThreshold::TimesAverage`] factor multiplies. `None`: no
    /// task area (evalglare's default).
    pub task_opening_rad: Option<f64>,
    /// evalglare's search radius `-r`, radians (default 0.2): pixels within
    /// half of it join a source.
    pub search_radius_rad: f64,
    /// evalglare's peak extraction (`-y`/`-Y`): source pixels at or above
    /// this luminance, cd/m², become sources of their own (default 50 000);
    /// `None` turns it off (`-x`).
    pub peak_extraction_cd_m2: Option<f64>,
    /// evalglare's smoothing `-s` (off by default, as in evalglare): a
    /// pixel in no source joins one whose own pixels hold more than a
    /// fifth of the solid angle of a disc of pixels around it.
    pub smoothing: bool,
    /// Observer's age, years (CIE 146).
    pub age_years: f64,
    /// Ocular pigmentation (CIE 146: 0 very dark … 1.2 very light eyes).
    pub pigmentation: f64,
    /// Pixels closer to the gaze than this (degrees) add no CIE 146 veil.
    pub cie146_inner_deg: f64,
    /// Diameter of the disc the luminance at the gaze is averaged over,
    /// degrees.
    pub gaze_disc_deg: f64,
}

impl Default for GlareOptions {
    fn default() -> Self {
        Self {
            threshold: SourceThreshold::evalglare_default(false),
            task_opening_rad: None,
            search_radius_rad: EVALGLARE_SEARCH_RADIUS_RAD,
            peak_extraction_cd_m2: Some(EVALGLARE_PEAK_CD_M2),
            smoothing: false,
            age_years: 25.0,
            pigmentation: 0.5,
            cie146_inner_deg: 1.0,
            gaze_disc_deg: 1.0,
        }
    }
}

/// One glare source at a gaze.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GlareSource {
    /// Pixels in it.
    pub pixels: usize,
    /// Whether peak extraction made it (its pixels are all at or above
    /// the peak level).
    pub peak: bool,
    /// L ω-weighted mean pixel position (x right, y down; pixel centres at
    /// +0.5).
    pub position_px: [f64; 2],
    /// The direction through that position, camera frame (−z forward,
    /// +x right, +y up).
    pub direction: [f64; 3],
    /// Its azimuth (right) and elevation (up) from the image's view
    /// direction, degrees.
    pub azimuth_elevation_deg: [f64; 2],
    /// Angle from the gaze to that direction, degrees.
    pub angle_from_gaze_deg: f64,
    /// The direction of the whole pixel evalglare takes for the source
    /// (its truncated mean pixel index, rows counted from the bottom),
    /// camera frame: evalglare's `xdir ydir zdir`.
    pub pixel_direction: [f64; 3],
    /// The angle from the gaze to that pixel's centre, degrees (kept at
    /// least the pixel's angular radius): the veil's θ.
    pub angle_from_gaze_pixel_deg: f64,
    /// Guth's position index at that pixel (evalglare's `Posindx`).
    pub position_index: f64,
    /// Solid angle, sr.
    pub solid_angle_sr: f64,
    /// Mean luminance (ω-weighted), cd/m².
    pub luminance_cd_m2: f64,
    /// Brightest pixel, cd/m².
    pub max_luminance_cd_m2: f64,
    /// Illuminance it gives at the eye on the plane facing the gaze, lux.
    pub illuminance_lux: f64,
    /// Its Stiles–Holladay veil, 10 E / θ², cd/m² (evalglare's
    /// `Lveil_cie` term).
    pub veil_stiles_holladay_cd_m2: f64,
}

/// The glare numbers at one gaze.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GazeGlare {
    /// The gaze, azimuth and elevation from the image's view direction,
    /// degrees.
    pub gaze_deg: [f64; 2],
    /// Whether the gaze direction lies in the image's field.
    pub gaze_in_field: bool,
    /// Vertical illuminance at the eye (the plane facing the gaze), lux.
    pub vertical_illuminance_lux: f64,
    /// Average luminance of the half space in front (Σ L ω / Σ ω), cd/m².
    pub average_luminance_cd_m2: f64,
    /// Solid angle with data in front of the eye, sr (2π for a full half
    /// space).
    pub solid_angle_with_data_sr: f64,
    /// Mean luminance of the task area, cd/m², when one is set.
    pub task_luminance_cd_m2: Option<f64>,
    /// The source threshold used, cd/m².
    pub source_threshold_cd_m2: f64,
    /// Luminance at the gaze (mean over the gaze disc), cd/m²; `None` when
    /// the gaze is outside the field.
    pub luminance_at_gaze_cd_m2: Option<f64>,
    /// The same plus the CIE 146 veil, cd/m².
    pub luminance_at_gaze_with_veil_cd_m2: Option<f64>,
    /// CIE 146:2002 veil of the whole image, cd/m².
    pub veil_cie146_cd_m2: f64,
    /// Stiles–Holladay veil of the glare sources, Σ 10 E_i / θ_i², θ_i to
    /// each source's whole pixel: evalglare's `Lveil_cie`, cd/m².
    pub veil_stiles_holladay_cd_m2: f64,
    /// The glare sources' illuminance at the eye (evalglare's `E_v_dir`),
    /// lux.
    pub source_illuminance_lux: f64,
    /// Background luminance, (E_v − Σ E_i)/π (evalglare's `lum_backg`),
    /// cd/m².
    pub background_luminance_cd_m2: f64,
    /// Threshold increment, percent (CIE 140 eq. 5/6 with the CIE 146 veil).
    pub threshold_increment_pct: f64,
    /// DGP, DGI, UGR, VCP and CGI as evalglare computes them.
    #[serde(flatten)]
    pub indices: GlareIndices,
    /// The glare sources, brightest illuminance first.
    pub sources: Vec<GlareSource>,
}

/// A scene image prepared for glare evaluations: each pixel's luminance,
/// direction and solid angle.
pub struct SceneGlare {
    projection: SceneProjection,
    luminance: Vec<f64>,
    /// Unit direction and solid angle of the pixels in the field.
    pixels: Vec<(usize, DVec3, f64)>,
    /// Pixels outside the field (no data).
    pub no_data_pixels: usize,
    /// The buffers of [`SceneGlare::at_gaze`], kept between gazes so that
    /// a gaze trace allocates nothing once they are large enough (a gaze
    /// evaluated while another holds them gets its own).
    scratch: Mutex<Scratch>,
}

/// The working buffers of one glare evaluation (indices into `front`).
#[derive(Default)]
struct Scratch {
    front: Vec<FrontPixel>,
    /// The front pixels above the source threshold.
    bright: Vec<u32>,
    /// The groups (sources), the first `n_groups` in use; their vectors
    /// keep their capacity.
    groups: Vec<Vec<u32>>,
    n_groups: usize,
    /// A group's pixels at or above the peak level.
    high: Vec<u32>,
    linkage: Linkage,
    /// The sources in group order, then the order of their illuminance.
    found: Vec<GlareSource>,
    order: Vec<u32>,
    index_sources: Vec<IndexSource>,
    /// Smoothing (`-s`): per image pixel its solid angle, its source
    /// (+1) and whether it may join one; the shares and joins.
    omega: Vec<f64>,
    label: Vec<usize>,
    candidate: Vec<bool>,
    shares: Vec<(usize, f64)>,
    joins: Vec<(usize, u32)>,
}

/// The buffers of [`single_linkage`].
#[derive(Default)]
struct Linkage {
    dirs: Vec<DVec3>,
    cells: Vec<([i64; 3], u32)>,
    parent: Vec<usize>,
    dense: Vec<usize>,
    labels: Vec<usize>,
}

/// A pixel in front of the eye: its index, direction, solid angle and
/// cosine to the gaze.
type FrontPixel = (usize, DVec3, f64, f64);

impl SceneGlare {
    /// Prepares `image` (cd/m²) seen through `projection` (whose size must
    /// be the image's; the caller checks). Pixels outside the field are
    /// never read; a pixel whose luminance is not a number (a rendered
    /// view's "no data", NaN) counts as outside the field.
    pub fn new(image: &RgbImage, projection: SceneProjection) -> Self {
        use rayon::prelude::*;
        let w = image.width;
        let n = image.width * image.height;
        let luminance: Vec<f64> = image
            .pixels
            .iter()
            .map(|&p| f64::from(luminance(p)).max(0.0))
            .collect();
        let pixels: Vec<(usize, DVec3, f64)> = (0..n)
            .into_par_iter()
            .filter_map(|i| {
                let (x, y) = (i % w, i / w);
                if image.pixels[i].iter().any(|c| c.is_nan()) {
                    return None;
                }
                let d = projection.pixel_direction(x, y)?;
                let om = projection.pixel_solid_angle_sr(x, y);
                (om > 0.0).then_some((i, d, om))
            })
            .collect();
        let no_data_pixels = n - pixels.len();
        Self {
            projection,
            luminance,
            pixels,
            no_data_pixels,
            scratch: Mutex::new(Scratch::default()),
        }
    }

    /// The projection.
    pub fn projection(&self) -> &SceneProjection {
        &self.projection
    }

    /// The CIE 146:2002 veil at a gaze direction (camera frame) alone,
    /// cd/m²: `Σ L ω (d·g) f_CIE146(θ)` over the pixels in front of the
    /// eye with θ ≥ [`GlareOptions::cie146_inner_deg`] — the
    /// [`GazeGlare::veil_cie146_cd_m2`] of [`Self::at_gaze`], which calls
    /// it. Never allocates.
    pub fn veil_cie146_cd_m2(&self, gaze: DVec3, opts: &GlareOptions) -> f64 {
        let g = gaze.normalize_or(DVec3::NEG_Z);
        let inner_cos = opts.cie146_inner_deg.to_radians().cos();
        let mut veil = 0.0;
        for &(i, d, om) in &self.pixels {
            let c = d.dot(g);
            if c >= 0.0 && c <= inner_cos {
                let l = self.luminance[i];
                let theta_deg = c.clamp(-1.0, 1.0).acos().to_degrees();
                veil +=
                    l * om * c * cie146_veil_per_sr(theta_deg, opts.age_years, opts.pigmentation);
            }
        }
        veil
    }

    /// [`Self::veil_cie146_cd_m2`] at each of `gazes` (camera frame), in
    /// parallel: a veil map. Costs one term per pixel in the field per
    /// gaze ([`Self::pixels_in_field`]).
    pub fn veil_map_cie146(&self, gazes: &[DVec3], opts: &GlareOptions) -> Vec<f64> {
        use rayon::prelude::*;
        gazes
            .par_iter()
            .map(|&g| self.veil_cie146_cd_m2(g, opts))
            .collect()
    }

    /// The number of pixels in the image's field.
    pub fn pixels_in_field(&self) -> usize {
        self.pixels.len()
    }

    /// The glare numbers at a gaze direction (camera frame).
    pub fn at_gaze(&self, gaze: DVec3, opts: &GlareOptions) -> GazeGlare {
        self.evaluate(gaze, opts, Vec::new())
    }

    /// [`SceneGlare::at_gaze`] into `out`, reusing its source list: with
    /// the scene's own buffers kept between gazes, a gaze trace allocates
    /// nothing once they have grown to its largest gaze (the counting
    /// allocator test `tests/tests/glare_alloc.rs`).
    pub fn at_gaze_into(&self, gaze: DVec3, opts: &GlareOptions, out: &mut GazeGlare) {
        let sources = std::mem::take(&mut out.sources);
        *out = self.evaluate(gaze, opts, sources);
    }

    /// The glare numbers, the sources written into `sources` (cleared).
    fn evaluate(&self, gaze: DVec3, opts: &GlareOptions, sources: Vec<GlareSource>) -> GazeGlare {
        match self.scratch.try_lock() {
            Ok(mut scratch) => self.evaluate_with(gaze, opts, &mut scratch, sources),
            // Held by another gaze (or poisoned by a panic in one): buffers
            // of its own.
            Err(_) => self.evaluate_with(gaze, opts, &mut Scratch::default(), sources),
        }
    }

    fn evaluate_with(
        &self,
        gaze: DVec3,
        opts: &GlareOptions,
        scratch: &mut Scratch,
        mut sources: Vec<GlareSource>,
    ) -> GazeGlare {
        let g = gaze.normalize_or(DVec3::NEG_Z);
        scratch.front.clear();
        scratch
            .front
            .extend(self.pixels.iter().filter_map(|&(i, d, om)| {
                let c = d.dot(g);
                (c >= 0.0).then_some((i, d, om, c))
            }));
        let mut e_v = 0.0;
        let mut sum_l_om = 0.0;
        let mut sum_om = 0.0;
        let veil_cie = self.veil_cie146_cd_m2(g, opts);
        let disc_cos = (opts.gaze_disc_deg * 0.5).to_radians().cos();
        let (mut disc_l_om, mut disc_om) = (0.0, 0.0);
        // evalglare get_task_lum: pixels within half the opening angle.
        let task_cos = opts.task_opening_rad.map(|a| (a * 0.5).cos());
        let (mut task_l_om, mut task_om) = (0.0, 0.0);
        for &(i, _, om, c) in &scratch.front {
            let l = self.luminance[i];
            e_v += l * om * c;
            sum_l_om += l * om;
            sum_om += om;
            if c >= disc_cos {
                disc_l_om += l * om;
                disc_om += om;
            }
            if task_cos.is_some_and(|t| c >= t) {
                task_l_om += l * om;
                task_om += om;
            }
        }
        let average = if sum_om > 0.0 { sum_l_om / sum_om } else { 0.0 };
        let task = task_cos.map(|_| {
            if task_om > 0.0 {
                task_l_om / task_om
            } else {
                0.0
            }
        });
        let threshold = match opts.threshold {
            SourceThreshold::AbsoluteCdM2 { cd_m2 } => cd_m2,
            SourceThreshold::TimesAverage { factor } => factor * task.unwrap_or(average),
        };
        self.sources(scratch, g, threshold, opts, &mut sources);
        let veil_sh: f64 = sources.iter().map(|s| s.veil_stiles_holladay_cd_m2).sum();
        let e_sources: f64 = sources.iter().map(|s| s.illuminance_lux).sum();
        let gaze_px = self.projection.pixel(g);
        let gaze_in_field = gaze_px.is_some();
        let at_gaze = gaze_px.map(|p| {
            if disc_om > 0.0 {
                disc_l_om / disc_om
            } else {
                let x = (p[0].floor() as usize).min(self.projection.width_px - 1);
                let y = (p[1].floor() as usize).min(self.projection.height_px - 1);
                self.luminance[y * self.projection.width_px + x]
            }
        });
        // evalglare -q 0 (default): L_b = (E_v − E_v_dir) / π.
        let background = ((e_v - e_sources) / std::f64::consts::PI).max(0.0);
        scratch.index_sources.clear();
        scratch
            .index_sources
            .extend(sources.iter().map(|s| IndexSource {
                luminance_cd_m2: s.luminance_cd_m2,
                solid_angle_sr: s.solid_angle_sr,
                position_index: s.position_index,
            }));
        let indices = glare_indices(
            &scratch.index_sources,
            &IndexScene {
                vertical_illuminance_lux: e_v,
                direct_illuminance_lux: e_sources,
                background_luminance_cd_m2: background,
                average_luminance_cd_m2: average,
            },
        );
        GazeGlare {
            gaze_deg: angles_from_direction(g),
            gaze_in_field,
            vertical_illuminance_lux: e_v,
            average_luminance_cd_m2: average,
            solid_angle_with_data_sr: sum_om,
            task_luminance_cd_m2: task,
            source_threshold_cd_m2: threshold,
            luminance_at_gaze_cd_m2: at_gaze,
            luminance_at_gaze_with_veil_cd_m2: at_gaze.map(|l| l + veil_cie),
            veil_cie146_cd_m2: veil_cie,
            veil_stiles_holladay_cd_m2: veil_sh,
            source_illuminance_lux: e_sources,
            background_luminance_cd_m2: background,
            threshold_increment_pct: threshold_increment_pct(veil_cie, background),
            indices,
            sources,
        }
    }

    /// The front pixels brighter than `threshold` as evalglare's glare
    /// sources: grouped, then their peaks extracted; into `out`, brightest
    /// illuminance first (ties in group order).
    fn sources(
        &self,
        scratch: &mut Scratch,
        g: DVec3,
        threshold: f64,
        opts: &GlareOptions,
        out: &mut Vec<GlareSource>,
    ) {
        out.clear();
        let lum = &self.luminance;
        let Scratch {
            front,
            bright,
            groups,
            n_groups,
            linkage,
            ..
        } = scratch;
        bright.clear();
        bright.extend((0..front.len() as u32).filter(|&k| lum[front[k as usize].0] > threshold));
        // evalglare find_near_pgs: joined when 2 × angle ≤ r.
        let link = (opts.search_radius_rad * 0.5).max(1e-6);
        *n_groups = 0;
        add_groups(front, bright, link, linkage, groups, n_groups);
        if opts.smoothing {
            self.smooth(scratch, opts.search_radius_rad);
        }
        let Scratch {
            front,
            bright,
            groups,
            n_groups,
            high,
            linkage,
            found,
            order,
            ..
        } = scratch;
        let mut n_primary = *n_groups;
        // Peak extraction, only when some source pixel exceeds the level
        // (evalglare: lum_total_max > limit; pixels ≥ limit move).
        if let Some(limit) = opts.peak_extraction_cd_m2
            && bright.iter().any(|&k| lum[front[k as usize].0] > limit)
        {
            for k in 0..n_primary {
                high.clear();
                high.extend(
                    groups[k]
                        .iter()
                        .copied()
                        .filter(|&p| lum[front[p as usize].0] >= limit),
                );
                if high.is_empty() {
                    continue;
                }
                groups[k].retain(|&p| lum[front[p as usize].0] < limit);
                // The split pixels are linked at r/4 and their groups
                // merged at r/2 (evalglare find_split, then find_near_pgs
                // among them): single linkage at r/2.
                add_groups(front, high, link, linkage, groups, n_groups);
            }
            // Groups left without pixels are gone (in order; their vectors
            // move behind the ones in use).
            let (mut kept, mut kept_primary) = (0, 0);
            for k in 0..*n_groups {
                if groups[k].is_empty() {
                    continue;
                }
                groups.swap(kept, k);
                kept += 1;
                if k < n_primary {
                    kept_primary += 1;
                }
            }
            n_primary = kept_primary;
            *n_groups = kept;
        }
        found.clear();
        order.clear();
        for (k, grp) in groups[..*n_groups].iter().enumerate() {
            if let Some(s) = self.source(front, grp, g, k >= n_primary) {
                order.push(found.len() as u32);
                found.push(s);
            }
        }
        // Brightest first; ties keep their order (a stable sort, without
        // its buffer).
        order.sort_unstable_by(|&a, &b| {
            found[b as usize]
                .illuminance_lux
                .total_cmp(&found[a as usize].illuminance_lux)
                .then(a.cmp(&b))
        });
        out.extend(order.iter().map(|&k| found[k as usize].clone()));
    }

    /// evalglare's smoothing (`-s`, its `add_secondary_gs`): the disc of
    /// pixels of radius r / (1.75 δ) around each pixel in front of the
    /// eye and in no source, δ evalglare's pixel pitch at the image's
    /// centre (a fifth of the angle across a 10 × 10 px diagonal); the
    /// pixel joins the source whose own pixels hold the largest share of
    /// the disc's solid angle when that share exceeds 0.2 (evalglare adds
    /// it to every such source; with two, this is the larger). Joined
    /// pixels do not count for others.
    fn smooth(&self, scratch: &mut Scratch, search_radius_rad: f64) {
        let (w, h) = (self.projection.width_px, self.projection.height_px);
        let (cx, cy) = (w / 2, h / 2);
        let (Some(a), Some(b)) = (
            self.projection.pixel_direction(cx, cy),
            self.projection.pixel_direction(cx + 10, cy + 10),
        ) else {
            return;
        };
        // evalglare: r_center = 2 × angle / 10, search_pix = r / r_center / 1.75.
        let r_center = a.dot(b).clamp(-1.0, 1.0).acos() * 2.0 / 10.0;
        if r_center <= 0.0 {
            return;
        }
        let Scratch {
            front,
            groups,
            n_groups,
            omega,
            label,
            candidate,
            shares,
            joins,
            ..
        } = scratch;
        let groups = &mut groups[..*n_groups];
        let radius = search_radius_rad / r_center / 1.75;
        omega.clear();
        omega.resize(w * h, 0.0);
        for &(i, _, om) in &self.pixels {
            omega[i] = om;
        }
        // The source of each pixel (its index + 1), 0 for none.
        label.clear();
        label.resize(w * h, 0);
        for (k, grp) in groups.iter().enumerate() {
            for &p in grp.iter() {
                label[front[p as usize].0] = k + 1;
            }
        }
        let reach = radius.floor() as usize;
        candidate.clear();
        candidate.resize(w * h, false);
        for grp in groups.iter() {
            for &p in grp.iter() {
                let i = front[p as usize].0;
                let (x, y) = (i % w, i / w);
                for yy in y.saturating_sub(reach)..=(y + reach).min(h - 1) {
                    for xx in x.saturating_sub(reach)..=(x + reach).min(w - 1) {
                        candidate[yy * w + xx] = label[yy * w + xx] == 0;
                    }
                }
            }
        }
        joins.clear();
        for (k, p) in front.iter().enumerate() {
            if !candidate[p.0] {
                continue;
            }
            let (x, y) = ((p.0 % w) as f64, (p.0 / w) as f64);
            // evalglare's window: truncated bounds, the last column and
            // row left out at the far edges.
            let lo = |c: f64| (c - radius).max(0.0) as usize;
            let hi = |c: f64, n: usize| {
                let m = (c + radius) as usize;
                if m > n - 1 { n.saturating_sub(2) } else { m }
            };
            let (mut total, r2) = (0.0, radius * radius);
            shares.clear();
            for iy in lo(y)..=hi(y, h) {
                for ix in lo(x)..=hi(x, w) {
                    let (dx, dy) = (x - ix as f64, y - iy as f64);
                    if dx * dx + dy * dy > r2 {
                        continue;
                    }
                    let j = iy * w + ix;
                    total += omega[j];
                    if label[j] > 0 {
                        match shares.iter_mut().find(|s| s.0 == label[j]) {
                            Some(s) => s.1 += omega[j],
                            None => shares.push((label[j], omega[j])),
                        }
                    }
                }
            }
            if let Some(&(g, om)) = shares.iter().max_by(|a, b| a.1.total_cmp(&b.1))
                && total > 0.0
                && om / total > 0.2
            {
                joins.push((g - 1, k as u32));
            }
        }
        for &(g, p) in joins.iter() {
            groups[g].push(p);
        }
    }

    /// One source from its pixels (indices into `front`).
    fn source(
        &self,
        front: &[FrontPixel],
        pixels: &[u32],
        g: DVec3,
        peak: bool,
    ) -> Option<GlareSource> {
        let w = self.projection.width_px;
        let (mut om_sum, mut l_om, mut x_l_om, mut y_l_om, mut l_max, mut e) =
            (0.0, 0.0, 0.0, 0.0, 0.0f64, 0.0);
        for &k in pixels {
            let (i, _d, om, c) = front[k as usize];
            let l = self.luminance[i];
            om_sum += om;
            l_om += l * om;
            x_l_om += ((i % w) as f64 + 0.5) * l * om;
            y_l_om += ((i / w) as f64 + 0.5) * l * om;
            l_max = l_max.max(l);
            e += l * om * c;
        }
        if pixels.is_empty() || om_sum <= 0.0 || l_om <= 0.0 {
            return None;
        }
        let pos = [x_l_om / l_om, y_l_om / l_om];
        let dir = self.projection.direction_any(pos).unwrap_or(g);
        let theta_deg = dir.dot(g).clamp(-1.0, 1.0).acos().to_degrees();
        // evalglare: the mean integer column and row-from-bottom index,
        // truncated; here in top-down continuous pixels.
        let (mean_col, mean_row) = (pos[0] - 0.5, pos[1] - 0.5);
        let col = (mean_col.floor().max(0.0) as usize).min(w - 1);
        let row = (mean_row.ceil().max(0.0) as usize).min(self.projection.height_px - 1);
        let px_centre = [col as f64 + 0.5, row as f64 + 0.5];
        let px_dir = self.projection.direction_any(px_centre).unwrap_or(dir);
        // The pixel's angular radius keeps θ, and the veil, finite.
        let px_radius_deg = (self.projection.pixel_solid_angle_sr(col, row).max(0.0)
            / std::f64::consts::PI)
            .sqrt()
            .to_degrees();
        let theta_px_deg = px_dir
            .dot(g)
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees()
            .max(px_radius_deg)
            .max(1e-6);
        Some(GlareSource {
            pixels: pixels.len(),
            peak,
            position_px: pos,
            direction: dir.to_array(),
            azimuth_elevation_deg: angles_from_direction(dir),
            angle_from_gaze_deg: theta_deg,
            pixel_direction: px_dir.to_array(),
            angle_from_gaze_pixel_deg: theta_px_deg,
            // The image's up (camera +y) as evalglare's -vu.
            position_index: position_index(g, DVec3::Y, px_dir),
            solid_angle_sr: om_sum,
            luminance_cd_m2: l_om / om_sum,
            max_luminance_cd_m2: l_max,
            illuminance_lux: e,
            veil_stiles_holladay_cd_m2: veil_stiles_holladay_cd_m2(e, theta_px_deg),
        })
    }
}

/// Groups `members` (indices into `front`) by single linkage at
/// `link_rad` and appends the groups, in the order of their first member,
/// after the `n_groups` in use (reusing the vectors there).
fn add_groups(
    front: &[FrontPixel],
    members: &[u32],
    link_rad: f64,
    linkage: &mut Linkage,
    groups: &mut Vec<Vec<u32>>,
    n_groups: &mut usize,
) {
    linkage.dirs.clear();
    linkage
        .dirs
        .extend(members.iter().map(|&k| front[k as usize].1));
    let n = single_linkage(linkage, link_rad);
    let base = *n_groups;
    if groups.len() < base + n {
        groups.resize_with(base + n, Vec::new);
    }
    for grp in &mut groups[base..base + n] {
        grp.clear();
    }
    for (&k, &label) in members.iter().zip(&linkage.labels) {
        groups[base + label].push(k);
    }
    *n_groups = base + n;
}

/// Threshold increment, percent: CIE 140-2000 eq. 5 (L_ad ≤ 5 cd/m²) and
/// eq. 6 (above); 0 for no adaptation luminance.
pub fn threshold_increment_pct(veil_cd_m2: f64, adaptation_cd_m2: f64) -> f64 {
    if adaptation_cd_m2 <= 0.0 {
        return 0.0;
    }
    if adaptation_cd_m2 <= 5.0 {
        // CIE 140-2000 eq. 5: TI = 65 L_v / L_av^0.8
        65.0 * veil_cd_m2 / adaptation_cd_m2.powf(0.8)
    } else {
        // CIE 140-2000 eq. 6: TI = 95 L_v / L_av^1.05
        95.0 * veil_cd_m2 / adaptation_cd_m2.powf(1.05)
    }
}

/// Single-linkage groups of the unit directions `linkage.dirs`: two join
/// when their angle is at most `link_rad`. Writes a group label per
/// direction into `linkage.labels` (0-based, dense, in the order of each
/// group's first direction) and returns the number of groups. A grid of
/// cells the link's chord wide (sorted, searched by bisection: nothing
/// allocated once the buffers have grown) keeps it linear.
fn single_linkage(linkage: &mut Linkage, link_rad: f64) -> usize {
    let Linkage {
        dirs,
        cells,
        parent,
        dense,
        labels,
    } = linkage;
    let n = dirs.len();
    parent.clear();
    parent.extend(0..n);
    fn find(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    let chord = 2.0 * (link_rad * 0.5).sin();
    let cos_link = link_rad.cos();
    let cell = |d: DVec3| -> [i64; 3] {
        [
            (d.x / chord).floor() as i64,
            (d.y / chord).floor() as i64,
            (d.z / chord).floor() as i64,
        ]
    };
    cells.clear();
    cells.extend(dirs.iter().enumerate().map(|(i, &d)| (cell(d), i as u32)));
    cells.sort_unstable();
    for (i, &d) in dirs.iter().enumerate() {
        let c = cell(d);
        for dx in -1..=1 {
            for dy in -1..=1 {
                for dz in -1..=1 {
                    let key = [c[0] + dx, c[1] + dy, c[2] + dz];
                    let start = cells.partition_point(|e| e.0 < key);
                    for &(k, j) in &cells[start..] {
                        if k != key {
                            break;
                        }
                        let j = j as usize;
                        if j > i && dirs[j].dot(d) >= cos_link {
                            let (a, b) = (find(parent, i), find(parent, j));
                            if a != b {
                                parent[a.max(b)] = a.min(b);
                            }
                        }
                    }
                }
            }
        }
    }
    dense.clear();
    dense.resize(n, usize::MAX);
    labels.clear();
    let mut groups = 0;
    for i in 0..n {
        let r = find(parent, i);
        if dense[r] == usize::MAX {
            dense[r] = groups;
            groups += 1;
        }
        labels.push(dense[r]);
    }
    groups
}

/// Most scene pixels the glare sums keep per pixel (luminance, direction
/// and solid angle: ~50 bytes each, ~100 per gaze while sources are
/// grouped): 2²³ (a 4096×2048 panorama) is ~0.4 GB + ~0.8 GB per gaze. A
/// larger scene (up to the loader's 16384×8192) is binned k×k first
/// ([`bin_for_glare`]), so `glare` works on any scene `render` loads.
pub const MAX_GLARE_PIXELS: usize = 1 << 23;

/// The image the glare sums see: `image` itself when it has at most
/// [`MAX_GLARE_PIXELS`], else its k×k block means (the smallest k that
/// fits; partial blocks at the right and bottom edges average the pixels
/// they hold) with the same field. Returns the image, its projection and k.
pub fn bin_for_glare(
    image: &RgbImage,
    projection: SceneProjection,
) -> (std::borrow::Cow<'_, RgbImage>, SceneProjection, usize) {
    let (w, h) = (image.width, image.height);
    let mut k = 1;
    while w.div_ceil(k) * h.div_ceil(k) > MAX_GLARE_PIXELS {
        k += 1;
    }
    if k == 1 {
        return (std::borrow::Cow::Borrowed(image), projection, 1);
    }
    let (bw, bh) = (w.div_ceil(k), h.div_ceil(k));
    let mut sum = vec![[0.0f64; 4]; bw * bh];
    for (y, row) in image.pixels.chunks_exact(w.max(1)).enumerate() {
        let brow = &mut sum[(y / k) * bw..(y / k + 1) * bw];
        for (x, p) in row.iter().enumerate() {
            let b = &mut brow[x / k];
            b[0] += f64::from(p[0]);
            b[1] += f64::from(p[1]);
            b[2] += f64::from(p[2]);
            b[3] += 1.0;
        }
    }
    let pixels = sum
        .into_iter()
        .map(|b| {
            let n = b[3].max(1.0);
            [(b[0] / n) as f32, (b[1] / n) as f32, (b[2] / n) as f32]
        })
        .collect();
    let binned = RgbImage {
        width: bw,
        height: bh,
        pixels,
    };
    let mut p = projection;
    p.width_px = bw;
    p.height_px = bh;
    (std::borrow::Cow::Owned(binned), p, k)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_scene_over_the_glare_cap_is_binned_to_fit_keeping_its_light() {
        // Just over 2²³ pixels: binned 2×2 (partial blocks at the edges).
        let (w, h) = (4097, 2049);
        let mut image = RgbImage::new(w, h);
        image.pixels[0] = [4.0, 8.0, 12.0];
        let total: f64 = image.pixels.iter().map(|p| f64::from(p[1])).sum();
        let (binned, p, k) = bin_for_glare(&image, SceneProjection::equirectangular(w, h));
        assert_eq!(k, 2);
        assert_eq!((binned.width, binned.height), (2049, 1025));
        assert_eq!((p.width_px, p.height_px), (2049, 1025));
        assert!(binned.width * binned.height <= MAX_GLARE_PIXELS);
        // The top-left block holds the bright pixel and three black ones.
        assert_eq!(binned.pixels[0], [1.0, 2.0, 3.0]);
        // The last column's blocks hold one column of two pixels each.
        let binned_total: f64 = binned.pixels.iter().map(|p| f64::from(p[1])).sum();
        assert!((binned_total * 4.0 - total).abs() < 1e-9, "{binned_total}");
        // At or under the cap: the image itself.
        let small = RgbImage::new(4096, 2048);
        let (same, _, k) = bin_for_glare(&small, SceneProjection::equirectangular(4096, 2048));
        assert_eq!(k, 1);
        assert!(matches!(same, std::borrow::Cow::Borrowed(_)));
        // The loader's largest scene fits after binning.
        let mut k = 1;
        while 16384usize.div_ceil(k) * 8192usize.div_ceil(k) > MAX_GLARE_PIXELS {
            k += 1;
        }
        assert_eq!(k, 4);
    }

    #[test]
    fn linkage_joins_chains_and_keeps_gaps() {
        let at = |deg: f64| {
            let r = deg.to_radians();
            DVec3::new(r.sin(), 0.0, -r.cos())
        };
        // 0°, 4°, 8° chain at a 5° link; 20° alone.
        let mut linkage = Linkage {
            dirs: vec![at(0.0), at(4.0), at(20.0), at(8.0)],
            ..Linkage::default()
        };
        assert_eq!(single_linkage(&mut linkage, 5f64.to_radians()), 2);
        let labels = &linkage.labels;
        // Dense, in the order of each group's first direction.
        assert_eq!(labels[0], 0);
        assert_eq!(labels[2], 1);
        assert_eq!(labels[0], labels[1]);
        assert_eq!(labels[1], labels[3]);
        assert_ne!(labels[0], labels[2]);
    }

    #[test]
    fn a_lamp_brighter_than_the_peak_level_is_split_off_its_diffuser() {
        use crate::scene::ProjectionKind;
        use crate::scene::projection::direction_from_angles;
        // A 180° angular fisheye; a 3° diffuser disc of 5000 cd/m² with a
        // 1° lamp of 10⁶ cd/m² at its centre, 20° right and 10° up.
        let n = 801;
        let p = SceneProjection::new(ProjectionKind::Angular, 180.0, 180.0, n, n).unwrap();
        let centre = direction_from_angles(20.0, 10.0);
        let mut img = RgbImage::new(n, n);
        for y in 0..n {
            for x in 0..n {
                if let Some(d) = p.pixel_direction(x, y) {
                    let a = d.dot(centre).clamp(-1.0, 1.0).acos().to_degrees();
                    let l = if a <= 1.0 {
                        1e6
                    } else if a <= 3.0 {
                        5000.0
                    } else {
                        10.0
                    };
                    *img.get_mut(x, y) = [l; 3];
                }
            }
        }
        let cap = |deg: f64| std::f64::consts::TAU * (1.0 - deg.to_radians().cos());
        let glare = SceneGlare::new(&img, p);
        let split = glare.at_gaze(DVec3::NEG_Z, &GlareOptions::default());
        assert_eq!(split.sources.len(), 2, "{:?}", split.sources);
        let lamp = split.sources.iter().find(|s| s.peak).unwrap();
        let ring = split.sources.iter().find(|s| !s.peak).unwrap();
        assert!((lamp.solid_angle_sr / cap(1.0) - 1.0).abs() < 0.1);
        assert!((ring.solid_angle_sr / (cap(3.0) - cap(1.0)) - 1.0).abs() < 0.1);
        assert!((lamp.luminance_cd_m2 / 1e6 - 1.0).abs() < 1e-6);
        assert!((ring.luminance_cd_m2 / 5000.0 - 1.0).abs() < 1e-6);
        let off = DVec3::from_array(lamp.direction)
            .dot(centre)
            .clamp(-1.0, 1.0)
            .acos();
        assert!(off.to_degrees() < 0.3, "{}", off.to_degrees());
        // evalglare's -x: one source, the disc.
        let whole = glare.at_gaze(
            DVec3::NEG_Z,
            &GlareOptions {
                peak_extraction_cd_m2: None,
                ..GlareOptions::default()
            },
        );
        assert_eq!(whole.sources.len(), 1);
        assert!((whole.sources[0].solid_angle_sr / cap(3.0) - 1.0).abs() < 0.1);
        // The indices see the split: a small bright source glares more.
        assert!(split.indices.dgp > whole.indices.dgp);
        // The gaze on the lamp: a finite veil.
        let on = glare.at_gaze(centre, &GlareOptions::default());
        assert!(on.veil_stiles_holladay_cd_m2.is_finite());
    }

    #[test]
    fn threshold_increment_follows_cie_140() {
        // CIE 140 eq. 5 at L_av = 1: TI = 65 L_v.
        assert!((threshold_increment_pct(0.1, 1.0) - 6.5).abs() < 1e-12);
        // eq. 6 at L_av = 10: 95 × 0.5 / 10^1.05.
        let expected = 95.0 * 0.5 / 10f64.powf(1.05);
        assert!((threshold_increment_pct(0.5, 10.0) - expected).abs() < 1e-12);
    }
}
