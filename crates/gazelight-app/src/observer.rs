//! The observer of a session: age and ocular pigmentation, the CIE
//! 146:2002 parameters of the glare kernel's stray light
//! (`PsfParams::age_years`, `PsfParams::pigmentation`), decided the same
//! way by every front end.
//!
//! Where they come from, first found wins: the front end's own arguments
//! (the CLI's `--age-years` / `--pigmentation`; none in Python or the
//! layer); the configuration's `[observer]` table; the calibration
//! profile's `observer`; the configuration's `pipeline.glare.psf` values
//! (defaults 25 years, 0.5).

use gazelight_eye::profile::{AGE_YEARS_RANGE, Observer, PIGMENTATION_RANGE};
use gazelight_vision::psf::PsfParams;
use serde::Deserialize;

use crate::bounds::{BoundsError, Num, Result};

/// The observer a front end was given directly (the CLI's flags), each
/// value named as the user wrote it in an error.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ObserverFlags {
    /// `--age-years`.
    pub age_years: Option<f64>,
    /// `--pigmentation`.
    pub pigmentation: Option<f64>,
}

/// The `[observer]` table of the configuration (the CLI's configs, the
/// Python module's `config=`, the OpenXR layer's `layer.toml`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ObserverSettings {
    /// Years; [`AGE_YEARS_RANGE`].
    pub age_years: Option<f64>,
    /// CIE 146 pigmentation factor; [`PIGMENTATION_RANGE`].
    pub pigmentation: Option<f64>,
}

/// `v` when it is finite and within `lo..=hi`; the error names `what`.
fn check(what: &str, v: f64, (lo, hi): (f64, f64)) -> Result<f64> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(v)
    } else {
        Err(BoundsError(format!(
            "{what} {}: expected a number in {lo}..={hi}",
            Num(v)
        )))
    }
}

impl ObserverSettings {
    /// Checks both fields; the error names the field
    /// (`observer.age_years = …`).
    pub fn validate(&self) -> Result<()> {
        self.validate_fields().map_err(|(_, e)| e)
    }

    /// [`Self::validate`], with the key of the field that is wrong
    /// (`observer.age_years`) beside the sentence.
    pub fn validate_fields(&self) -> std::result::Result<(), (&'static str, BoundsError)> {
        if let Some(a) = self.age_years {
            check("observer.age_years =", a, AGE_YEARS_RANGE)
                .map_err(|e| ("observer.age_years", e))?;
        }
        if let Some(p) = self.pigmentation {
            check("observer.pigmentation =", p, PIGMENTATION_RANGE)
                .map_err(|e| ("observer.pigmentation", e))?;
        }
        Ok(())
    }
}

/// Sets `psf.age_years` and `psf.pigmentation` from `flags`, else the
/// configuration's `[observer]`, else the profile's observer, else leaves
/// them. Out-of-range values are errors naming the flag or field.
pub fn apply(
    psf: &mut PsfParams,
    flags: &ObserverFlags,
    settings: Option<&ObserverSettings>,
    profile: Option<&Observer>,
) -> Result<()> {
    let age = match (flags.age_years, settings.and_then(|s| s.age_years)) {
        (Some(a), _) => Some(check("--age-years", a, AGE_YEARS_RANGE)?),
        (None, Some(a)) => Some(check("observer.age_years =", a, AGE_YEARS_RANGE)?),
        (None, None) => profile.map(|o| o.age_years),
    };
    let pig = match (flags.pigmentation, settings.and_then(|s| s.pigmentation)) {
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
        let none = ObserverFlags::default();
        let mut psf = PsfParams::default();
        apply(&mut psf, &none, None, None).unwrap();
        assert_eq!((psf.age_years, psf.pigmentation), (25.0, 0.5));
        apply(&mut psf, &none, None, Some(&profile)).unwrap();
        assert_eq!((psf.age_years, psf.pigmentation), (70.0, 1.0));
        let settings = ObserverSettings {
            age_years: Some(40.0),
            pigmentation: None,
        };
        apply(&mut psf, &none, Some(&settings), Some(&profile)).unwrap();
        assert_eq!((psf.age_years, psf.pigmentation), (40.0, 1.0));
        let flags = ObserverFlags {
            age_years: Some(55.0),
            pigmentation: Some(1.2),
        };
        apply(&mut psf, &flags, Some(&settings), Some(&profile)).unwrap();
        assert_eq!((psf.age_years, psf.pigmentation), (55.0, 1.2));
    }

    #[test]
    fn bad_values_name_the_flag_or_field() {
        let mut psf = PsfParams::default();
        let flags = ObserverFlags {
            age_years: Some(-1.0),
            pigmentation: None,
        };
        let e = apply(&mut psf, &flags, None, None).unwrap_err().to_string();
        assert!(e.contains("--age-years"), "{e}");
        let flags = ObserverFlags {
            age_years: None,
            pigmentation: Some(f64::NAN),
        };
        let e = apply(&mut psf, &flags, None, None).unwrap_err().to_string();
        assert!(e.contains("--pigmentation"), "{e}");
        let bad = ObserverSettings {
            age_years: None,
            pigmentation: Some(2.0),
        };
        let e = bad.validate().unwrap_err().to_string();
        assert!(
            e.contains("observer.pigmentation") && e.contains("0..=1.2"),
            "{e}"
        );
        let e = apply(&mut psf, &ObserverFlags::default(), Some(&bad), None)
            .unwrap_err()
            .to_string();
        assert!(e.contains("observer.pigmentation"), "{e}");
        assert_eq!((psf.age_years, psf.pigmentation), (25.0, 0.5));
    }
}
