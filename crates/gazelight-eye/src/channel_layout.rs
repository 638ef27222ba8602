//! How the channels of a multi-channel eye stream (an LSL stream live, an
//! XDF stream replayed) become [`Sample`]s: one rule for both, picked from
//! the channel labels — gazelight's own outlet (`gazelight-eye`), Pupil
//! Capture's LSL relay, Neon's, or a generic `x`, `y`, `pupil` — and one
//! decoder (the LSL inlet and the XDF importer had drifted apart: the live
//! one dropped lost pupils and read neither gazelight's own outlet nor
//! validity channels).

use crate::sample::{DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample};

/// Neon's scene camera, pixels ([`crate::sample::NEON_SCENE_CAMERA_PX`]):
/// Neon's LSL gaze x/y are in these pixels.
pub const NEON_SCENE_PX: [f64; 2] = [
    crate::sample::NEON_SCENE_CAMERA_PX[0] as f64,
    crate::sample::NEON_SCENE_CAMERA_PX[1] as f64,
];

/// How an eye stream's channels become samples.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ChannelLayout {
    /// `gazelight-eye`, `pupil-capture-relay`, `neon` or `generic`.
    pub kind: &'static str,
    pub gaze_x: Option<usize>,
    pub gaze_y: Option<usize>,
    /// Gaze value range: divided by it → normalised.
    pub gaze_range: [f64; 2],
    /// Whether gaze y = 0 is the bottom (Pupil's `norm_pos`).
    pub gaze_y_up: bool,
    /// A channel that says whether the gaze is valid (> 0.5).
    pub gaze_valid: Option<usize>,
    /// One confidence for the sample.
    pub confidence: Option<usize>,
    /// [right, left]: (channel, unit) in order of preference.
    pub pupil: [Vec<(usize, PupilUnit)>; 2],
    /// [right, left]: per-eye confidence channels.
    pub eye_confidence: [Option<usize>; 2],
    /// [right, left]: per-eye validity channels (> 0.5 valid).
    pub eye_valid: [Option<usize>; 2],
    /// A blink channel (> 0.5 during a blink).
    pub blink: Option<usize>,
}

/// A channel unit as a pupil unit (`mm`, `px`, else arbitrary).
pub fn unit_of(unit: &str) -> PupilUnit {
    match unit.trim().to_ascii_lowercase().as_str() {
        "mm" | "millimeters" | "millimetres" => PupilUnit::Mm,
        "px" | "pixel" | "pixels" => PupilUnit::Px,
        _ => PupilUnit::Arbitrary,
    }
}

impl ChannelLayout {
    /// Picks the layout from a stream's channel labels and, where the
    /// stream says them, its channels' units (`None` when the source gives
    /// no units: then gaze `x`/`y` are taken as Neon's scene pixels);
    /// `neon_scene_px` is the scene camera Neon's `x`/`y` are in. `None`
    /// when the channels match no layout (the caller names the stream).
    pub fn detect(
        labels: &[String],
        units: Option<&[String]>,
        neon_scene_px: [f64; 2],
    ) -> Option<Self> {
        let idx = |l: &str| labels.iter().position(|x| x.eq_ignore_ascii_case(l));
        let unit = |i: Option<usize>| {
            i.and_then(|i| units.and_then(|u| u.get(i)))
                .map_or(PupilUnit::Arbitrary, |u| unit_of(u))
        };
        let none = Self {
            kind: "generic",
            gaze_x: None,
            gaze_y: None,
            gaze_range: [1.0, 1.0],
            gaze_y_up: false,
            gaze_valid: None,
            confidence: None,
            pupil: [Vec::new(), Vec::new()],
            eye_confidence: [None, None],
            eye_valid: [None, None],
            blink: None,
        };
        if let (Some(x), Some(y), Some(r), Some(l)) = (
            idx("gaze_x"),
            idx("gaze_y"),
            idx("pupil_right_mm"),
            idx("pupil_left_mm"),
        ) {
            // gazelight's own outlet (crates/gazelight-status/src/lsl_outlets.rs).
            return Some(Self {
                kind: "gazelight-eye",
                gaze_x: Some(x),
                gaze_y: Some(y),
                gaze_valid: idx("gaze_valid"),
                pupil: [vec![(r, PupilUnit::Mm)], vec![(l, PupilUnit::Mm)]],
                eye_confidence: [idx("confidence_right"), idx("confidence_left")],
                eye_valid: [idx("pupil_valid_right"), idx("pupil_valid_left")],
                blink: idx("blink"),
                ..none
            });
        }
        if let (Some(x), Some(y)) = (idx("norm_pos_x"), idx("norm_pos_y")) {
            // Pupil Capture's LSL relay: eye 0 = right, 1 = left; the 3D
            // diameter (mm) first, the 2D one (px) as the fallback.
            let eye = |e: u8| {
                let mut v = Vec::new();
                if let Some(i) = idx(&format!("diameter{e}_3d")) {
                    v.push((i, PupilUnit::Mm));
                }
                if let Some(i) = idx(&format!("diameter{e}_2d")) {
                    v.push((i, PupilUnit::Px));
                }
                v
            };
            return Some(Self {
                kind: "pupil-capture-relay",
                gaze_x: Some(x),
                gaze_y: Some(y),
                gaze_y_up: true,
                confidence: idx("confidence"),
                pupil: [eye(0), eye(1)],
                ..none
            });
        }
        let x = idx("x");
        let y = idx("y");
        let neon_pupils = [idx("pupil_diameter_right"), idx("pupil_diameter_left")];
        let neon_xy = units.is_none() || unit(x) == PupilUnit::Px;
        if x.is_some() && y.is_some() && (neon_xy || neon_pupils.iter().any(Option::is_some)) {
            return Some(Self {
                kind: "neon",
                gaze_x: x,
                gaze_y: y,
                gaze_range: neon_scene_px,
                pupil: neon_pupils.map(|i| i.map(|i| vec![(i, PupilUnit::Mm)]).unwrap_or_default()),
                ..none
            });
        }
        let pupil = idx("pupil");
        if (x.is_some() && y.is_some()) || pupil.is_some() {
            let p = pupil.map(|i| vec![(i, unit(pupil))]).unwrap_or_default();
            return Some(Self {
                kind: "generic",
                gaze_x: x.and(y).and(x),
                gaze_y: x.and(y),
                confidence: idx("confidence"),
                // One pupil for the stream: given to both eyes.
                pupil: [p.clone(), p],
                ..none
            });
        }
        None
    }

    /// The samples of one stream sample (values `v` at time `t_secs`),
    /// given to `out` in order: each eye's pupil (a lost one — 0, NaN,
    /// negative, or its validity channel says so — as a sample of
    /// confidence 0, so blinks and dropouts are counted downstream and the
    /// counts equal the stream's rows), then the gaze (lost: NaN,
    /// confidence 0). At most three samples.
    pub fn decode(&self, v: &[f64], t_secs: f64, out: &mut impl FnMut(Sample)) {
        let get = |i: Option<usize>| i.and_then(|i| v.get(i).copied());
        let flag = |i: Option<usize>| get(i).map(|x| x > 0.5);
        let confidence = get(self.confidence)
            .filter(|c| c.is_finite())
            .map_or(1.0, |c| c.clamp(0.0, 1.0)) as f32;
        let mut valid = [false; 2];
        for (e, prefs) in self.pupil.iter().enumerate() {
            let found = prefs.iter().find_map(|&(i, u)| {
                v.get(i)
                    .copied()
                    .filter(|d| d.is_finite() && *d > 0.0)
                    .map(|d| (d, u))
            });
            let eye_valid = flag(self.eye_valid[e]).unwrap_or(true);
            let conf = get(self.eye_confidence[e])
                .filter(|c| c.is_finite())
                .map_or(confidence, |c| c.clamp(0.0, 1.0) as f32);
            // The detector of the value found; a lost pupil belongs to the
            // preferred one (the 3D model where the relay has it).
            let unit = found.map(|f| f.1).or(prefs.first().map(|p| p.1));
            let method = match (self.kind, unit) {
                ("pupil-capture-relay", Some(PupilUnit::Mm)) => DetectorMethod::Pupil3d,
                ("pupil-capture-relay", _) => DetectorMethod::Pupil2d,
                _ => DetectorMethod::Other,
            };
            if prefs.is_empty() {
                // The layout has no pupil channel for this eye.
                continue;
            }
            match found {
                Some((d, unit)) if eye_valid => {
                    valid[e] = true;
                    out(Sample::Pupil(PupilSample {
                        t_secs,
                        eye: e as u8,
                        diameter_raw: d as f32,
                        unit,
                        diameter_mm: (unit == PupilUnit::Mm).then_some(d as f32),
                        confidence: conf,
                        norm_pos: [f32::NAN; 2],
                        method,
                    }));
                }
                // No usable diameter (0, NaN, negative: a blink or a lost
                // pupil), or a validity channel that says so: still a
                // sample of this eye, lost (confidence 0), so blinks and
                // dropouts are counted downstream and the counts equal
                // the stream's rows.
                _ => out(Sample::Pupil(PupilSample {
                    t_secs,
                    eye: e as u8,
                    diameter_raw: 0.0,
                    unit: prefs.first().map_or(PupilUnit::Mm, |p| p.1),
                    diameter_mm: None,
                    confidence: 0.0,
                    norm_pos: [f32::NAN; 2],
                    method,
                })),
            }
        }
        let (Some(_), Some(_)) = (self.gaze_x, self.gaze_y) else {
            return;
        };
        let eyes = match valid {
            [true, false] => GazeEyes::Right,
            [false, true] => GazeEyes::Left,
            _ => GazeEyes::Binocular,
        };
        let xy = (get(self.gaze_x), get(self.gaze_y));
        let gaze = match xy {
            (Some(x), Some(y))
                if x.is_finite() && y.is_finite() && flag(self.gaze_valid) != Some(false) =>
            {
                let u = x / self.gaze_range[0];
                let v = y / self.gaze_range[1];
                let v = if self.gaze_y_up { 1.0 - v } else { v };
                GazeSample {
                    t_secs,
                    gaze_uv: [u as f32, v as f32],
                    confidence,
                    eyes,
                }
            }
            // A row without a usable gaze (NaN, or its validity channel
            // says lost): a lost gaze sample, confidence 0, NaN position.
            _ => GazeSample {
                t_secs,
                gaze_uv: [f32::NAN; 2],
                confidence: 0.0,
                eyes,
            },
        };
        out(Sample::Gaze(gaze));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(l: &[&str]) -> Vec<String> {
        l.iter().map(|s| (*s).to_owned()).collect()
    }

    fn decode(l: &ChannelLayout, v: &[f64]) -> Vec<Sample> {
        let mut out = Vec::new();
        l.decode(v, 1.0, &mut |s| out.push(s));
        out
    }

    #[test]
    fn gazelights_own_outlet_with_a_blink_row() {
        let l = ChannelLayout::detect(
            &labels(&[
                "gaze_x",
                "gaze_y",
                "pupil_right_mm",
                "pupil_left_mm",
                "pupil_valid_right",
                "pupil_valid_left",
                "blink",
            ]),
            None,
            NEON_SCENE_PX,
        )
        .unwrap();
        assert_eq!(l.kind, "gazelight-eye");
        // The right eye measured, the left one marked invalid: a lost
        // sample of confidence 0, not a missing one.
        let out = decode(&l, &[0.4, 0.6, 3.5, 4.0, 1.0, 0.0, 0.0]);
        let Sample::Pupil(r) = out[0] else {
            panic!("{out:?}")
        };
        assert_eq!((r.eye, r.diameter_mm, r.confidence), (0, Some(3.5), 1.0));
        let Sample::Pupil(left) = out[1] else {
            panic!("{out:?}")
        };
        assert_eq!(
            (left.eye, left.diameter_mm, left.confidence),
            (1, None, 0.0)
        );
        let Sample::Gaze(g) = out[2] else {
            panic!("{out:?}")
        };
        assert_eq!((g.gaze_uv, g.eyes), ([0.4, 0.6], GazeEyes::Right));
    }

    #[test]
    fn a_lost_relay_pupil_is_a_sample_of_confidence_zero() {
        let l = ChannelLayout::detect(
            &labels(&[
                "confidence",
                "norm_pos_x",
                "norm_pos_y",
                "diameter0_3d",
                "diameter1_3d",
            ]),
            None,
            NEON_SCENE_PX,
        )
        .unwrap();
        let out = decode(&l, &[0.9, 0.5, 0.25, 0.0, f64::NAN]);
        assert_eq!(out.len(), 3, "two lost pupils and the gaze: {out:?}");
        for s in &out[..2] {
            let Sample::Pupil(p) = s else {
                panic!("{out:?}")
            };
            assert_eq!((p.confidence, p.diameter_mm), (0.0, None));
        }
        let Sample::Gaze(g) = out[2] else {
            panic!("{out:?}")
        };
        assert_eq!(g.gaze_uv, [0.5, 0.75], "norm_pos y is up");
    }

    #[test]
    fn neon_xy_needs_pixels_when_units_are_known() {
        let xy = labels(&["x", "y", "pupil"]);
        let known = ChannelLayout::detect(&xy, Some(&labels(&["", "", "mm"])), NEON_SCENE_PX);
        assert_eq!(known.map(|l| l.kind), Some("generic"));
        let px = ChannelLayout::detect(&xy, Some(&labels(&["px", "px", "mm"])), NEON_SCENE_PX);
        assert_eq!(px.map(|l| l.gaze_range), Some(NEON_SCENE_PX));
        assert!(ChannelLayout::detect(&labels(&["a", "b"]), None, NEON_SCENE_PX).is_none());
    }
}
