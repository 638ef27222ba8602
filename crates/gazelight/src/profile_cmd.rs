//! `gazelight profile`: calibration profiles (raw tracker pupil → mm)
//! without a live black/white session, for trackers that report pupils in
//! arbitrary units (EyeLink area or diameter units, eye-camera pixels):
//!
//! * `profile scale --unit U --mm-per-unit F`: a known scale, mm per unit
//!   of diameter (for area units, per unit of √area): `mm = F · raw`
//!   (`F · √area`);
//! * `profile phases REC --black FROM..TO --white FROM..TO`: from the
//!   recording's own dark and bright stretches, as 001 §5's black/white
//!   calibration does live (median of each stretch → 8 mm and 2 mm);
//! * `profile schema`: the profile's JSON schema (`calibration/schema.json`).
//!
//! The profile is then given with `--calibration FILE` to `replay`,
//! `inspect`, `run` (or `source.calibration` in the configuration).

use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand, ValueEnum};
use gazelight_tracker::calibration::{CalibrationConfig, CalibrationSession};
use gazelight_tracker::profile::{
    DEFAULT_MM_MAX, DEFAULT_MM_MIN, EyeCalibration, EyeCalibrations, Observer, PupilCalibration,
    SCHEMA,
};
use gazelight_tracker::{PupilUnit, Sample};

/// The profile's JSON schema, as shipped in the source tree.
const SCHEMA_JSON: &str = include_str!("../../../calibration/schema.json");

/// Arguments of `gazelight profile`.
#[derive(Args, Debug)]
pub struct ProfileArgs {
    #[command(subcommand)]
    pub action: ProfileAction,
}

/// What `gazelight profile` does.
#[derive(Subcommand, Debug)]
pub enum ProfileAction {
    /// Write a profile from a known scale: millimetres per unit of
    /// diameter (per unit of √area for area units).
    Scale(ScaleArgs),
    /// Write a profile from a recording's own dark and bright stretches
    /// (the black/white calibration of 001 §5 on recorded data).
    Phases(PhasesArgs),
    /// Print the profile's JSON schema.
    Schema,
}

/// A raw pupil unit, as on the command line.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum UnitArg {
    /// Eye-camera pixels (Pupil Core 2D).
    Px,
    /// Arbitrary area units (EyeLink PUPIL AREA).
    ArbitraryArea,
    /// Arbitrary diameter units (EyeLink DIAMETER, vendor units).
    Arbitrary,
}

impl From<UnitArg> for PupilUnit {
    fn from(u: UnitArg) -> Self {
        match u {
            UnitArg::Px => PupilUnit::Px,
            UnitArg::ArbitraryArea => PupilUnit::ArbitraryArea,
            UnitArg::Arbitrary => PupilUnit::Arbitrary,
        }
    }
}

/// `gazelight profile scale`.
#[derive(Args, Debug)]
pub struct ScaleArgs {
    /// The tracker's raw unit.
    #[arg(long, value_enum)]
    pub unit: UnitArg,
    /// Millimetres per unit of diameter (for `arbitrary-area`: per unit of
    /// √area), e.g. from an artificial pupil of known size.
    #[arg(long, value_name = "F")]
    pub mm_per_unit: f64,
    /// Where the profile is written (JSON).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
}

/// `gazelight profile phases`.
#[derive(Args, Debug)]
pub struct PhasesArgs {
    /// The recording (any format `replay` reads).
    pub recording: PathBuf,
    /// The dark stretch, seconds from the recording's first sample,
    /// `FROM..TO` (the pupil dilated; choose it after the pupil settled).
    #[arg(long, value_name = "FROM..TO", value_parser = parse_window)]
    pub black: (f64, f64),
    /// The bright stretch, `FROM..TO` seconds (the pupil constricted).
    #[arg(long, value_name = "FROM..TO", value_parser = parse_window)]
    pub white: (f64, f64),
    /// Where the profile is written (JSON).
    #[arg(long, value_name = "FILE")]
    pub out: PathBuf,
}

/// Parses `FROM..TO` (seconds).
fn parse_window(s: &str) -> anyhow::Result<(f64, f64)> {
    let (a, b) = s
        .split_once("..")
        .ok_or_else(|| anyhow::anyhow!("`{s}`: expected FROM..TO seconds, e.g. 10..15"))?;
    let num = |v: &str| -> anyhow::Result<f64> {
        let x: f64 = v
            .trim()
            .parse()
            .map_err(|_| anyhow::anyhow!("`{s}`: `{v}` is not a number"))?;
        anyhow::ensure!(
            x.is_finite() && x >= 0.0,
            "`{s}`: `{v}` must be ≥ 0 and finite"
        );
        Ok(x)
    };
    let (a, b) = (num(a)?, num(b)?);
    anyhow::ensure!(a < b, "`{s}`: FROM must be before TO");
    Ok((a, b))
}

/// A proportional profile: `mm = mm_per_unit · raw` (raw = √area for area
/// units), written as the two-point map of the schema: the raw values that
/// give 8 mm and 2 mm.
pub fn scale_profile(unit: PupilUnit, mm_per_unit: f64) -> anyhow::Result<PupilCalibration> {
    anyhow::ensure!(
        mm_per_unit.is_finite() && mm_per_unit > 0.0,
        "--mm-per-unit {mm_per_unit}: expected a number > 0"
    );
    let map = EyeCalibration {
        kind: gazelight_tracker::profile::MapKind::Scale,
        raw_unit: unit,
        raw_black: DEFAULT_MM_MAX / mm_per_unit,
        raw_white: DEFAULT_MM_MIN / mm_per_unit,
        mm_min: DEFAULT_MM_MIN,
        mm_max: DEFAULT_MM_MAX,
    };
    Ok(PupilCalibration {
        schema: SCHEMA.to_owned(),
        description: Some(format!(
            "gazelight profile scale: {mm_per_unit} mm per unit of {} ({})",
            if unit == PupilUnit::ArbitraryArea {
                "√area"
            } else {
                "diameter"
            },
            crate::session::pupil_unit_words(unit)
        )),
        eyes: EyeCalibrations {
            right: Some(map),
            left: Some(map),
        },
        observer: Observer::default(),
    })
}

/// The profile of a recording's dark and bright stretches (seconds from
/// its first sample), with a per-eye summary line each.
pub fn phases_profile(
    recording: &Path,
    black: (f64, f64),
    white: (f64, f64),
) -> anyhow::Result<(PupilCalibration, Vec<String>)> {
    let mut importer = gazelight_tracker::import::open(recording)?;
    let mut session: Option<CalibrationSession> = None;
    let mut sink = gazelight_tracker::calibration::LogSink::default();
    let mut t0 = None;
    let mut t_last = f64::NEG_INFINITY;
    for item in importer.by_ref() {
        let sample = item.with_context(|| format!("reading {}", recording.display()))?;
        let Sample::Pupil(p) = sample else { continue };
        let t0 = *t0.get_or_insert(p.t_secs);
        if p.t_secs.is_finite() {
            t_last = t_last.max(p.t_secs);
        }
        let session = match &mut session {
            Some(s) => s,
            None => session.insert(
                CalibrationSession::with_windows(
                    CalibrationConfig::default(),
                    (t0 + black.0, t0 + black.1),
                    (t0 + white.0, t0 + white.1),
                )
                .map_err(|e| anyhow::anyhow!("{e}"))?,
            ),
        };
        session
            .feed(&p, &mut sink)
            .map_err(|e| anyhow::anyhow!("{e}"))?;
    }
    let session =
        session.ok_or_else(|| anyhow::anyhow!("{}: no pupil samples", recording.display()))?;
    // A window past the recording's pupil samples: say which and how long
    // the recording is (its summary would only say "0 % valid").
    let length = t0.map_or(0.0, |t0| (t_last - t0).max(0.0));
    for (flag, (from, to)) in [("--black", black), ("--white", white)] {
        if from >= length {
            anyhow::bail!(
                "{flag} {from}..{to}: the window starts after the recording's last pupil sample: \
                 {} holds {length:.3} s of pupil samples (windows are seconds from its first \
                 sample)",
                recording.display()
            );
        }
    }
    let lines = session
        .summary()
        .iter()
        .map(|s| {
            format!(
                "eye {} {}: {} of {} samples valid, raw median {:.3} {}",
                s.eye,
                format!("{:?}", s.phase).to_lowercase(),
                s.valid,
                s.samples,
                s.raw_median,
                crate::session::raw_pupil_words(s.unit)
            )
        })
        .collect();
    let mut profile = session
        .finish()
        .map_err(|e| anyhow::anyhow!("{}: {e}", recording.display()))?;
    profile.description = Some(format!(
        "gazelight profile phases: {}, black {}..{} s, white {}..{} s",
        recording.display(),
        black.0,
        black.1,
        white.0,
        white.1
    ));
    Ok((profile, lines))
}

/// Runs `gazelight profile`.
pub fn run(args: ProfileArgs) -> anyhow::Result<()> {
    match args.action {
        ProfileAction::Schema => {
            print!("{SCHEMA_JSON}");
            Ok(())
        }
        ProfileAction::Scale(a) => {
            let profile = scale_profile(a.unit.into(), a.mm_per_unit)?;
            profile.save(&a.out).map_err(|e| anyhow::anyhow!("{e}"))?;
            println!(
                "wrote {}: {} mm per unit ({}); give it with --calibration",
                a.out.display(),
                a.mm_per_unit,
                crate::session::pupil_unit_words(PupilUnit::from(a.unit))
            );
            Ok(())
        }
        ProfileAction::Phases(a) => {
            // Before the recording is read: `--out` must not be it.
            crate::out_dir::check_out_file("profile phases", "--out", &a.out, &[&a.recording])?;
            let (profile, lines) = phases_profile(&a.recording, a.black, a.white)?;
            for l in &lines {
                println!("{l}");
            }
            profile.save(&a.out).map_err(|e| anyhow::anyhow!("{e}"))?;
            println!("wrote {}; give it with --calibration", a.out.display());
            Ok(())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The proportional map reproduces mm = F·raw (F·√area) inside 2–8 mm:
    /// checked through the profile's own mapping of a sample.
    #[test]
    fn scale_profile_is_proportional() {
        let p = scale_profile(PupilUnit::ArbitraryArea, 0.1).unwrap();
        let map = p.eyes.right.unwrap();
        // √2500 = 50 units → 5 mm.
        let mm = map.map(50.0).unwrap();
        assert!((mm - 5.0).abs() < 1e-9, "{mm}");
        assert!(scale_profile(PupilUnit::Px, 0.0).is_err());
        assert!(scale_profile(PupilUnit::Px, f64::NAN).is_err());
    }

    #[test]
    fn windows_parse_and_refuse() {
        assert_eq!(parse_window("10..15.5").unwrap(), (10.0, 15.5));
        for bad in ["10", "15..10", "a..2", "-1..2", "1..inf"] {
            assert!(parse_window(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn the_schema_is_json_naming_the_version() {
        let v: serde_json::Value = serde_json::from_str(SCHEMA_JSON).unwrap();
        assert!(v.to_string().contains("pupil-calibration/2"), "{v}");
    }
}
