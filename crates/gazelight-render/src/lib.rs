//! # gazelight-render
//!
//! The offline frame step of `gazelight render` and `gazelight replay`, in
//! one library so that the CLI and the Python package (`gazelight.render`)
//! run the same code and write the same frames:
//!
//! * [`feed`]: a stream of samples (a gaze/pupil trace or a recording,
//!   never loaded whole) through the tracker's one chain on the
//!   recording's clock → the filtered [`gazelight_tracker::EyeState`] at
//!   each frame's time; [`feed::scan`], the first pass over a recording
//!   (its time range, and the errors for a recording without samples or
//!   with a sliver of a time range).
//! * [`frame`]: the per-frame step — that state → each view's pipeline
//!   input → the frame pipeline(s) (the CPU reference here; the CLI plugs
//!   in its GPU renderer through [`frame::ViewRenderer`]) → the display
//!   frame (stereo: left | right) and each view's [`timeline::TimelineRow`].
//! * [`analysis`]: the same rows without the image pipeline, for a run
//!   that writes no image (`--no-frames`): the view's block plane once,
//!   then per frame only what the numbers need (issue 47); and the few
//!   frames a contact sheet shows, drawn in the state the numbers carried.
//! * [`timeline`]: the rows and the columns of `timeline.csv`.
//! * [`gaze_glare`]: `--glare-numbers`, the CIE 146 veil at each frame's
//!   gaze and the DGP and UGR of its line of sight, by `gazelight glare`'s
//!   functions on the frame's scene view.
//! * [`pupil_light`]: `replay`'s pupil light response per view (the pupil
//!   the light predicts and the residual columns, each view's parameters
//!   from the observer, a calibration profile or a `--pupil-fit` block);
//!   the CLI's live frame loop steps its models too.
//! * [`png`]: the PNG encoder of the frames (the bytes the CLI writes).
//! * [`demo`]: the embedded scene and its demo trace.
//!
//! Writing files (the contact sheet, the plot, `session.json`), the CLI's
//! flags and configuration file, and the GPU backend stay in the `gazelight`
//! binary crate.

pub mod analysis;
pub mod demo;
pub mod display_light;
pub mod feed;
pub mod frame;
pub mod gaze_glare;
pub mod png;
pub mod pupil_light;
pub mod rows;
pub mod timeline;
pub mod trials;
pub mod veil_map;

/// What can go wrong in a render step. The messages are the CLI's: it
/// prints them as they are (`error: {message}`), and the Python package
/// raises them.
#[derive(Debug, thiserror::Error)]
pub enum RenderError {
    /// The frame pipeline failed (its own error and causes, `outer: inner`).
    #[error("{0}")]
    Pipeline(String),
    /// A parameter of the vision crate (a kernel, a view) is out of range.
    #[error(transparent)]
    Vision(#[from] gazelight_vision::VisionError),
    /// The recording cannot be opened.
    #[error(transparent)]
    Import(#[from] gazelight_tracker::import::ImportError),
    /// The recording cannot be replayed as it is (no readable samples; a
    /// time range that is mostly a gap): the message names the file and why.
    #[error("{0}")]
    Recording(String),
    /// The demo trace cannot be built for this view.
    #[error("{0}")]
    Demo(String),
    /// A frame cannot be encoded or written.
    #[error("cannot write {path}: {reason}")]
    Write { path: String, reason: String },
}
