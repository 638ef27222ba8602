//! The observer of a session: age and ocular pigmentation, the CIE
//! 146:2002 parameters of the glare kernel's stray light
//! (`PsfParams::age_years`, `PsfParams::pigmentation`). The rule and its
//! tests are the application core's (`gazelight_app::observer`); here are
//! the CLI's flags.
//!
//! Where they come from, first found wins: the flags `--age-years` and
//! `--pigmentation` (`render`, `replay`, `run`); the service
//! configuration's `[observer]` table (`run`); the calibration profile's
//! `observer` (`replay --calibration`, `run --calibration`); the render
//! configuration's `pipeline.glare.psf` values (defaults 25 years, 0.5).

use gazelight_tracker::profile::Observer;
use gazelight_vision::psf::PsfParams;

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

pub use gazelight_app::observer::ObserverSettings;

impl ObserverArgs {
    /// The flags as the application core takes them.
    pub fn flags(&self) -> gazelight_app::observer::ObserverFlags {
        gazelight_app::observer::ObserverFlags {
            age_years: self.age_years,
            pigmentation: self.pigmentation,
        }
    }
}

/// The observer's age and pigmentation from the flags, else the
/// configuration's `[observer]`, else the profile's
/// (`gazelight_app::observer::apply`, the rule Python and the OpenXR layer
/// follow too).
pub fn apply(
    psf: &mut PsfParams,
    args: &ObserverArgs,
    settings: Option<&ObserverSettings>,
    profile: Option<&Observer>,
) -> anyhow::Result<()> {
    Ok(gazelight_app::observer::apply(
        psf,
        &args.flags(),
        settings,
        profile,
    )?)
}
