//! # gazelight-eye
//!
//! The eye, without I/O: eye-tracker [`Sample`]s, the [`EyeState`] the
//! rest of gazelight reads, the [`filter`] chain that cleans samples, the
//! black/white pupil [`calibration`] (001 §5) and its [`profile`]s, the
//! luminance-driven [`pupil_model`] and its dynamics, the
//! [`pupil_response`] to light, gaze [`trace`]s, [`synthetic`] sessions,
//! the process-wide host [`clock`], and the [`SampleSource`] interface every
//! live source and replay implements.
//!
//! This crate depends on no network, USB, serial or async-runtime crate, so
//! anything that only wants an `EyeState` or a filter stays small. Eye
//! indices follow Pupil Core: index 0 is the right eye, index 1 the left.
//!
//! # Example
//!
//! A second of a steady 4 mm right pupil at 100 Hz through the default
//! filter chain: the state holds the measured pupil.
//!
//! ```
//! use gazelight_eye::filter::FilterChain;
//! use gazelight_eye::{DetectorMethod, EYE_RIGHT, PupilOrigin, PupilSample, PupilUnit, Sample};
//!
//! let mut chain = FilterChain::with_defaults();
//! for k in 0..100 {
//!     chain.push(&Sample::Pupil(PupilSample {
//!         t_secs: f64::from(k) * 0.01,
//!         eye: 0,
//!         diameter_raw: 4.0,
//!         unit: PupilUnit::Mm,
//!         diameter_mm: Some(4.0),
//!         confidence: 0.95,
//!         norm_pos: [0.5, 0.5],
//!         method: DetectorMethod::Pupil3d,
//!     }));
//! }
//! let right = chain.state().eyes[EYE_RIGHT];
//! assert_eq!(right.pupil_origin, PupilOrigin::Measured);
//! assert!((right.pupil_mm - 4.0).abs() < 0.05, "{}", right.pupil_mm);
//! ```

pub mod calibration;
pub mod channel_layout;
pub mod clock;
pub mod filter;
pub mod live_events;
pub mod profile;
pub mod pupil_model;
pub mod pupil_response;
pub mod sample;
pub mod setting;
pub mod source;
pub mod state;
pub mod synthetic;
pub mod trace;

pub use sample::{
    BlinkEvent, DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
};
pub use setting::SettingError;
pub use source::{SampleSource, SourceError};
pub use state::{EYE_LEFT, EYE_RIGHT, EyeChannel, EyeState, LiveEyeState, PupilOrigin};
pub use trace::{GazeTrace, TraceError, TraceSample};
