//! The observer of a session: age and ocular pigmentation, the CIE
//! 146:2002 parameters of the glare kernel's stray light
//! (`PsfParams::age_years`, `PsfParams::pigmentation`).
//!
//! Where they come from, first found wins: the flags `--age-years` and
//! `--pigmentation` (`render`, `replay`, `run`); the service
//! configuration's `[observer]` table (`run`); the calibration profile's
//! `observer` (`replay --calibration`, `run --calibration`); the render
//! configuration's `pipeline.glare.psf` values (defaults 25 years, 0.5).

use anyhow::bail;
use gazelight_tracker::profile::{AGE_YEARS_RANGE, Observer, PIGMENTATION_RANGE};
use gazelight_vision::psf::PsfParams;
use serde::Deserialize;

/// `--age-years` and `--pigmentation`.
#[derive(Clone, Copy, Debug, Default, PartialEq, clap::Args)]
pub struct ObserverArgs {
    /// Observer age, years (CIE 146:2002 stray light; default 25, or the
    /// calibration profile's).
    #[arg(long, value_name = "YEARS")]
    pub age_years: Option<f64>,
    /// Ocular pigmentation, 0 very dark … 0.5 brown … 1.0 blue-green … 1.2
    /// very light eyes (CIE 146:2002; default 0.5, or the profile's).
    #[arg(long, value_name = "P")]
    pub pigmentation: Option<f64>,
}

/// The `[observer]` table of the service configuration.
#[derive(Clone, Copy, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObserverSettings {
    pub age_years: Option<f64>,
    pub pigmentation: Option<f64>,
}

fn check(what: &str, v: f64, (lo, hi): (f64, f64)) -> anyhow::Result<f64> {
    if !(v.is_finite() && (lo..=hi).contains(&v)) {
        bail!("{what} {v}: expected a number in {lo}..={hi}");
    }
    Ok(v)
}

impl ObserverSettings {
    /// Checks both fields; the error names the field.
    pub fn validate(&self) -> anyhow::Result<()> {
        if let Some(a) = self.age_years {
            check("observer.age_years =", a, AGE_YEARS_RANGE)?;
        }
        if let Some(p) = self.pigmentation {
            check("observer.pigmentation =", p, PIGMENTATION_RANGE)?;
        }
        Ok(())
    }
}

/// Sets `psf.age_years` and `psf.pigmentation` from the flags, else the
/// configuration's `[observer]`, else the profile's observer, else leaves
/// them. Out-of-range values are errors naming the flag or field.
pub fn apply(
    psf: &mut PsfParams,
    args: &ObserverArgs,
    settings: Option<&ObserverSettings>,
    profile: Option<&Observer>,
) -> anyhow::Result<()> {
    let age = match (args.age_years, settings.and_then(|s| s.age_years)) {
        (Some(a), _) => Some(check("--age-years", a, AGE_YEARS_RANGE)?),
        (None, Some(a)) => Some(check("observer.age_years =", a, AGE_YEARS_RANGE)?),
        (None, None) => profile.map(|o| o.age_years),
    };
    let pig = match (args.pigmentation, settings.and_then(|s| s.pigmentation)) {
        (Some(p), _) => Some(check("--pigmentation", p, PIGMENTATION_RANGE)?),
        (None, Some(p)) => Some(check("observer.pigmentation =", p, PIGMENTATION_RANGE)?),
        (None, None) => profile.map(|o| o.pigmentation),
    };
    if let Some(a) = age {
        psf.age_years = a;
    }
    if let Some(p) = pig {
        psf.pigmentation = p;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags_beat_config_beat_profile() {
        let profile = Observer {
            age_years: 70.0,
            pigmentation: 1.0,
        };
        let mut psf = PsfParams::default();
        apply(&mut psf, &ObserverArgs::default(), None, None).unwrap();
        assert_eq!((psf.age_years, psf.pigmentation), (25.0, 0.5));
        apply(&mut psf, &ObserverArgs::default(), None, Some(&profile)).unwrap();
        assert_eq!((psf.age_years, psf.pigmentation), (70.0, 1.0));
        let settings = ObserverSettings {
            age_years: Some(40.0),
            pigmentation: None,
        };
        apply(
            &mut psf,
            &ObserverArgs::default(),
            Some(&settings),
            Some(&profile),
        )
        .unwrap();
        assert_eq!((psf.age_years, psf.pigmentation), (40.0, 1.0));
        let args = ObserverArgs {
            age_years: Some(55.0),
            pigmentation: Some(1.2),
        };
        apply(&mut psf, &args, Some(&settings), Some(&profile)).unwrap();
        assert_eq!((psf.age_years, psf.pigmentation), (55.0, 1.2));
    }

    #[test]
    fn bad_values_name_the_flag_or_field() {
        let mut psf = PsfParams::default();
        let e = apply(
            &mut psf,
            &ObserverArgs {
                age_years: Some(-1.0),
                pigmentation: None,
            },
            None,
            None,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("--age-years"), "{e}");
        let e = apply(
            &mut psf,
            &ObserverArgs {
                age_years: None,
                pigmentation: Some(f64::NAN),
            },
            None,
            None,
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("--pigmentation"), "{e}");
        let bad = ObserverSettings {
            age_years: None,
            pigmentation: Some(2.0),
        };
        assert!(
            bad.validate()
                .unwrap_err()
                .to_string()
                .contains("observer.pigmentation")
        );
        let e = apply(&mut psf, &ObserverArgs::default(), Some(&bad), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("observer.pigmentation"), "{e}");
        assert_eq!((psf.age_years, psf.pigmentation), (25.0, 0.5));
    }
}
