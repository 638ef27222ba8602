//! What gazelight writes, for every front end: [`out_dir`], the one rule
//! for "may this command write its `--out` here" (inputs never
//! overwritten, other programs' recordings never written into, a previous
//! run's outputs cleared only with `--force`) and [`write_atomic`], the
//! whole-file write a reader never sees half of; what `render` writes
//! besides the timeline ([`sheet`]: PNG frames and the contact sheet;
//! [`plot`]: `plot.png` and the chart writer, with the one embedded
//! [`font`]); and [`live`], the writer thread of a live run's `--out`
//! (`timeline.csv`, `psf.csv`, `xr.csv`, `events.csv`, `frames/`).

pub mod font;
pub mod live;
pub mod out_dir;
pub mod plot;
pub mod sheet;

pub use out_dir::{OutError, OutKind, write_atomic};

/// The columns of `events.csv` (replay's and a live run's).
pub const EVENTS_COLUMNS: [&str; 8] = [
    "t_secs",
    "recording_t_secs",
    "t_clock",
    "duration_secs",
    "source",
    "text",
    "trial",
    "frame",
];

/// An error and its causes on one line, `outer: inner: …` — how every
/// front end words an error for the user (the CLI's `error: {err:#}`,
/// Python's exception text, the batch's row messages).
pub fn error_chain(e: &dyn std::error::Error) -> String {
    let mut msg = e.to_string();
    let mut cause = e.source();
    while let Some(c) = cause {
        msg.push_str(": ");
        msg.push_str(&c.to_string());
        cause = c.source();
    }
    msg
}
