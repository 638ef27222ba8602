//! # gazelight-tracker
//!
//! The one door to gazelight's eye side. It parses source URIs (the only
//! parser: [`uri`]), opens the source a URI names ([`open`]), replays
//! recordings on a virtual clock ([`source::ReplaySource`]), and re-exports
//! the crates that do the work, so `gazelight_tracker::…` paths cover all of
//! them:
//!
//! - `gazelight-eye`: samples, [`EyeState`], the [`filter`] chain,
//!   [`calibration`] and its [`profile`], the [`pupil_model`], traces and
//!   the host clock;
//! - `gazelight-pupil`: the Pupil Core client ([`pupil`]) and `.pldata`
//!   ([`recording`]);
//! - `gazelight-neon`: the live Pupil Labs Neon client and its mDNS
//!   discovery ([`neon`]);
//! - `gazelight-devices`: HID, USB, serial, Gazepoint ([`transport`]) and
//!   Lab Streaming Layer ([`lsl`]);
//! - `gazelight-import`: recorded logs ([`import`]) and [`summary`].
//!
//! Eye indices follow Pupil Core: index 0 is the right eye, index 1 the
//! left eye.

pub mod calibrate;
pub mod live;
pub mod lsl;
pub mod open;
pub mod record;
pub mod source;
pub mod summarize;
pub mod trace_source;
pub mod uri;

pub use gazelight_eye::{
    BlinkEvent, DetectorMethod, EYE_LEFT, EYE_RIGHT, EyeChannel, EyeState, GazeEyes, GazeSample,
    GazeTrace, LiveEyeState, PupilOrigin, PupilSample, PupilUnit, Sample, TraceError, TraceSample,
};
pub use gazelight_eye::{
    calibration, filter, live_events, profile, pupil_model, pupil_response, sample, state,
    synthetic, trace,
};
pub use gazelight_import as import;
pub use gazelight_import::summary;
pub use gazelight_neon as neon;
pub use gazelight_pupil::recording;
pub use gazelight_pupil::recording::{PldataReader, PldataWriter, RecordingError};
pub use gazelight_pupil::{
    PupilClient, PupilConfig, PupilError, PupilNotifier, PupilSource, PupilStats, RemoteSink,
};
pub use source::{Pacing, ReplaySource, SampleSource, SourceError};

/// The Pupil Core network client (`gazelight-pupil`) and the host clock.
pub mod pupil {
    pub use gazelight_eye::clock;
    pub use gazelight_pupil::client::*;
    pub use gazelight_pupil::{limits, msg, relay, stimulus};
}

/// Hardware transports (`gazelight-devices`), the source URIs that name
/// them and [`open`](crate::open::open).
pub mod transport {
    pub use crate::open::{
        AnySource, OpenLiveError, OpenOptions, open, open_live, open_markers, open_with,
    };
    pub use crate::uri;
    pub use crate::uri::{SourceUri, UriError};
    pub use gazelight_devices::{
        SerialFormat, discover, framing, gazepoint, hid, serial, target, usb,
    };
}

/// No Pupil Capture answered a live routine (`record`, `calibrate`) in
/// time: the one wording of it.
#[derive(Debug, thiserror::Error)]
#[error(
    "no tracker at {uri}: is Pupil Capture (or Pupil Service) running with Pupil Remote enabled?"
)]
pub struct NoTracker {
    /// The source URI as given.
    pub uri: String,
    #[source]
    pub source: PupilError,
}
