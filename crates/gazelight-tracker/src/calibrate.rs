//! The hardware-in-loop black/white pupil calibration (001 §5) against a
//! live Pupil Core tracker: `gazelight calibrate`'s routine.
//!
//! The stimulus (black, then white, then nothing) goes to a sink
//! ([`StimulusTarget`]): to the host application as the
//! `gazelight.stimulus` notification through the tracker's Pupil Remote
//! (the host shows the colour full screen), to a sink of the caller's (the
//! CLI's own full-screen window), or only to the log (a technician
//! switching the display by hand, or tests); every change is reported as
//! an [`Event`] (the technician's cue). The samples come from the live
//! source; each phase's robust statistics map the raw pupil units linearly
//! onto 2–8 mm per eye ([`CalibrationSession`]). The per-eye summary is
//! reported whether it succeeds or not; the profile is returned only on
//! success — a phase with too few valid samples, or a white phase whose
//! pupil is not smaller, is refused with the reason.
//!
//! The caller owns the rest: the flags and the `--out` rule, the signals
//! (passed in as the `stop` future), the window, printing and writing the
//! profile.

use std::future::Future;
use std::time::Duration;

use crate::calibration::{
    CalibrationConfig, CalibrationError, CalibrationSession, LogSink, PhaseSummary, Progress,
    Stimulus, StimulusError, StimulusSink,
};
use crate::profile::PupilCalibration;
use crate::pupil::{PupilConfig, PupilSource, RemoteSink};
use crate::{PupilError, Sample, SampleSource, SourceError};

/// Why a calibration could not run or was refused.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    /// No Pupil Capture answered within the silence time.
    #[error(transparent)]
    NoTracker(#[from] crate::NoTracker),
    /// The stop future resolved (the CLI: a signal): the stimulus is
    /// turned off and no profile is made.
    #[error("{reason}: calibration aborted; no profile written")]
    Aborted {
        /// The stop future's output (the CLI: the signal's name).
        reason: &'static str,
    },
    /// The caller's cancel check said stop (the CLI: the stimulus window
    /// was closed).
    #[error("the calibration window was closed")]
    Cancelled,
    /// The tracker sent nothing for the silence time.
    #[error("{uri}: no samples for {silence_secs:.1} s ({progress:?})")]
    Silent {
        /// The source URI as given.
        uri: String,
        /// The silence time as given, s.
        silence_secs: f64,
        /// Where the routine was.
        progress: Progress,
    },
    /// The source ended during the routine.
    #[error("{uri} ended before the calibration finished")]
    Ended {
        /// The source URI as given.
        uri: String,
    },
    /// The routine failed (a stimulus that could not be shown, bad
    /// settings).
    #[error(transparent)]
    Calibration(#[from] CalibrationError),
    /// The source cannot continue.
    #[error(transparent)]
    Source(SourceError),
    /// A `gazelight.stimulus` notification did not reach the host.
    #[error("the host application did not receive every stimulus")]
    NotDelivered(#[source] PupilError),
    /// The phases were recorded but the data does not make a profile.
    #[error("calibration refused; no profile written")]
    Refused(#[source] CalibrationError),
}

/// Where the stimulus goes.
pub enum StimulusTarget<'a> {
    /// To the host application as a `gazelight.stimulus` notification
    /// through the tracker's Pupil Remote (flushed before the routine
    /// returns; turned off when it fails).
    Remote,
    /// Nowhere but the [`Event`]s (and a log).
    Log,
    /// To a sink of the caller's (the CLI's window).
    Sink(&'a mut (dyn StimulusSink + Send)),
}

/// The source and its timing.
#[derive(Clone, Debug)]
pub struct CalibrateOptions {
    /// The source URI as given (for messages).
    pub uri: String,
    /// Give up when the tracker answers or sends nothing for this long.
    pub silence: Duration,
    /// The same, s, as given (for the message).
    pub silence_secs: f64,
}

/// What the routine reports while it runs (the caller prints it).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Event<'a> {
    /// Pupil Capture answered; the routine starts.
    Connected {
        /// Pupil Capture's version (empty when it gave none).
        version: &'a str,
    },
    /// The stimulus changed.
    Stimulus {
        /// What is shown from now on.
        stimulus: Stimulus,
        /// Since the first stimulus, s (the session's clock).
        since_first_secs: f64,
    },
    /// The per-eye, per-phase summary, reported whether the routine
    /// succeeded or not (empty: no pupil samples were received).
    Summary(&'a [PhaseSummary]),
}

/// Reports every stimulus change as it happens (the technician's cue) and
/// forwards it to an inner sink.
struct AnnouncingSink<'a, F> {
    inner: &'a mut (dyn StimulusSink + Send),
    on_event: &'a mut F,
    first_t: Option<f64>,
}

impl<F: FnMut(Event<'_>)> StimulusSink for AnnouncingSink<'_, F> {
    fn show(&mut self, stimulus: Stimulus, at_t_secs: f64) -> Result<(), StimulusError> {
        let t0 = *self.first_t.get_or_insert(at_t_secs);
        (self.on_event)(Event::Stimulus {
            stimulus,
            since_first_secs: at_t_secs - t0,
        });
        self.inner.show(stimulus, at_t_secs)
    }
}

/// Runs the routine with `cfg` (validated by the caller) against the Pupil
/// source `pupil` until the profile is made, `stop` resolves (its output is
/// the reason reported) or `cancelled` says so (checked at every sample).
/// Call inside a tokio runtime with time and I/O enabled.
pub async fn calibrate(
    pupil: PupilConfig,
    cfg: CalibrationConfig,
    opts: &CalibrateOptions,
    target: StimulusTarget<'_>,
    cancelled: impl Fn() -> bool,
    stop: impl Future<Output = &'static str>,
    mut on_event: impl FnMut(Event<'_>),
) -> Result<PupilCalibration, CalibrateError> {
    tokio::pin!(stop);
    let (mut source, _raw) = PupilSource::spawn(pupil);
    source
        .client()
        .wait_connected(opts.silence)
        .await
        .map_err(|source| crate::NoTracker {
            uri: opts.uri.clone(),
            source,
        })?;
    let version = source.client().stats().version.unwrap_or_default();
    on_event(Event::Connected { version: &version });
    let mut remote = None;
    let mut log = LogSink::default();
    let inner: &mut (dyn StimulusSink + Send) = match target {
        StimulusTarget::Remote => remote.insert(RemoteSink::new(
            source.client().notifier(),
            &tokio::runtime::Handle::current(),
        )),
        StimulusTarget::Log => &mut log,
        StimulusTarget::Sink(sink) => sink,
    };
    let mut session = CalibrationSession::new(cfg)?;
    let mut sink = AnnouncingSink {
        inner,
        on_event: &mut on_event,
        first_t: None,
    };
    let mut skipped = 0u64;
    let outcome: Result<(), CalibrateError> = loop {
        if cancelled() {
            break Err(CalibrateError::Cancelled);
        }
        let next = tokio::select! {
            reason = &mut stop => break Err(CalibrateError::Aborted { reason }),
            r = tokio::time::timeout(opts.silence, source.next()) => r,
        };
        let Ok(next) = next else {
            break Err(CalibrateError::Silent {
                uri: opts.uri.clone(),
                silence_secs: opts.silence_secs,
                progress: session.progress(),
            });
        };
        match next {
            Ok(Some(Sample::Pupil(p))) => match session.feed(&p, &mut sink) {
                Ok(Progress::Done) => break Ok(()),
                Ok(_) => {}
                Err(e) => break Err(e.into()),
            },
            Ok(Some(_)) => {}
            Ok(None) => {
                break Err(CalibrateError::Ended {
                    uri: opts.uri.clone(),
                });
            }
            Err(e @ (SourceError::Item { .. } | SourceError::Disconnected { .. })) => {
                skipped += 1;
                if skipped <= 10 {
                    tracing::warn!(error = %e, "calibration: source item skipped");
                }
            }
            Err(e @ SourceError::Fatal { .. }) => break Err(CalibrateError::Source(e)),
        }
    };
    // Whatever happened, turn the stimulus off and make sure it arrived.
    if let Some(r) = &mut remote {
        if outcome.is_err() {
            let _ = r.show(Stimulus::None, f64::NAN);
        }
        r.flush().await.map_err(CalibrateError::NotDelivered)?;
    }
    on_event(Event::Summary(&session.summary()));
    outcome?;
    session.finish().map_err(CalibrateError::Refused)
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup

    use super::*;

    #[test]
    fn every_stimulus_change_is_announced_and_forwarded() {
        let mut log = LogSink::default();
        let mut events = Vec::new();
        let mut on_event = |e: Event<'_>| {
            if let Event::Stimulus {
                stimulus,
                since_first_secs,
            } = e
            {
                events.push((stimulus, since_first_secs));
            }
        };
        let mut sink = AnnouncingSink {
            inner: &mut log,
            on_event: &mut on_event,
            first_t: None,
        };
        sink.show(Stimulus::Black, 10.0).unwrap();
        sink.show(Stimulus::White, 15.0).unwrap();
        sink.show(Stimulus::None, 20.5).unwrap();
        assert_eq!(
            events,
            [
                (Stimulus::Black, 0.0),
                (Stimulus::White, 5.0),
                (Stimulus::None, 10.5)
            ]
        );
        assert_eq!(
            log.shown,
            [
                (10.0, Stimulus::Black),
                (15.0, Stimulus::White),
                (20.5, Stimulus::None)
            ]
        );
    }

    #[test]
    fn messages() {
        assert_eq!(
            CalibrateError::Aborted { reason: "SIGTERM" }.to_string(),
            "SIGTERM: calibration aborted; no profile written"
        );
        assert_eq!(
            CalibrateError::Ended {
                uri: "pupil://h:1".into()
            }
            .to_string(),
            "pupil://h:1 ended before the calibration finished"
        );
        let silent = CalibrateError::Silent {
            uri: "pupil://h:1".into(),
            silence_secs: 2.25,
            progress: Progress::Done,
        };
        assert_eq!(
            silent.to_string(),
            "pupil://h:1: no samples for 2.2 s (Done)"
        );
    }

    #[tokio::test]
    async fn no_tracker_is_refused_with_the_uri() {
        let uri = "pupil://127.0.0.1:9";
        let opts = CalibrateOptions {
            uri: uri.to_owned(),
            silence: Duration::from_millis(300),
            silence_secs: 0.3,
        };
        let mut events = 0;
        let err = calibrate(
            crate::uri::pupil_config(uri).unwrap(),
            CalibrationConfig::default(),
            &opts,
            StimulusTarget::Log,
            || false,
            std::future::pending(),
            |_| events += 1,
        )
        .await
        .unwrap_err();
        assert!(
            err.to_string().starts_with(
                "no tracker at pupil://127.0.0.1:9: is Pupil Capture (or Pupil Service) running"
            ),
            "{err}"
        );
        assert_eq!(events, 0);
    }
}
