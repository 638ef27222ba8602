//! Sample sources: the one interface the service reads live trackers and
//! replays through.
//!
//! A [`SampleSource`] yields [`Sample`]s one at a time, asynchronously,
//! with times on the host clock (live sources align the tracker's clock
//! first) or on the recording's clock (replays). `Ok(None)` is the end of
//! the stream; an `Err` is one bad item or a lost connection and the
//! caller may keep calling `next` (a replay skips to the following item).
//!
//! [`ReplaySource`] turns any iterator of samples (a recording reader, an
//! importer, a synthetic trace) into a source driven by a virtual clock:
//! either as fast as possible (fully deterministic, no timers) or paced
//! against tokio's clock at a chosen speed (1.0 = real time), which under
//! `tokio::time::pause` is deterministic as well.

use std::future::Future;

use tokio::time::Instant;

use gazelight_eye::Sample;
pub use gazelight_eye::source::{SampleSource, SourceError};

/// Longest wall-clock offset from the first sample a paced replay waits
/// for, s (one day): an absurd timestamp cannot overflow the clock.
const MAX_PACING_GAP_SECS: f64 = 86_400.0;

/// How a replay advances its virtual clock.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pacing {
    /// Deliver every sample immediately; the virtual clock jumps to each
    /// sample's time.
    AsFastAsPossible,
    /// Deliver each sample when `(t − t_first) / speed` has elapsed on
    /// tokio's clock since the first one (`speed` = 1.0 is real time).
    Scaled { speed: f64 },
}

/// A replay of an iterator of samples on a virtual clock.
pub struct ReplaySource<I> {
    items: I,
    name: String,
    pacing: Pacing,
    /// Wall instant and sample time of the first delivered sample.
    anchor: Option<(Instant, f64)>,
    /// Latest wall target, so that out-of-order times never pace backwards.
    last_target: Option<Instant>,
    virtual_now_secs: Option<f64>,
    index: u64,
    delivered: u64,
    errors: u64,
}

impl<I, E> ReplaySource<I>
where
    I: Iterator<Item = Result<Sample, E>>,
    E: std::error::Error + Send + Sync + 'static,
{
    /// A replay named `name` (shown by [`SampleSource::describe`] and in
    /// errors). A non-finite or non-positive speed is treated as
    /// [`Pacing::AsFastAsPossible`].
    pub fn new(name: impl Into<String>, items: I, pacing: Pacing) -> Self {
        let pacing = match pacing {
            Pacing::Scaled { speed } if !(speed.is_finite() && speed > 0.0) => {
                Pacing::AsFastAsPossible
            }
            p => p,
        };
        Self {
            items,
            name: name.into(),
            pacing,
            anchor: None,
            last_target: None,
            virtual_now_secs: None,
            index: 0,
            delivered: 0,
            errors: 0,
        }
    }

    /// The virtual clock: the time of the newest delivered sample (seconds,
    /// recording clock), `None` before the first.
    pub fn virtual_now_secs(&self) -> Option<f64> {
        self.virtual_now_secs
    }

    /// Samples delivered so far.
    pub fn delivered(&self) -> u64 {
        self.delivered
    }

    /// Items that were errors so far.
    pub fn errors(&self) -> u64 {
        self.errors
    }

    async fn next_inner(&mut self) -> Result<Option<Sample>, SourceError> {
        let index = self.index;
        let item = match self.items.next() {
            None => return Ok(None),
            Some(item) => item,
        };
        self.index += 1;
        let sample = match item {
            Ok(s) => s,
            Err(e) => {
                self.errors += 1;
                return Err(SourceError::Item {
                    source_name: self.name.clone(),
                    index,
                    error: Box::new(e),
                });
            }
        };
        let t = sample.t_secs();
        if let Pacing::Scaled { speed } = self.pacing
            && t.is_finite()
        {
            match self.anchor {
                None => {
                    let now = Instant::now();
                    self.anchor = Some((now, t));
                    self.last_target = Some(now);
                }
                Some((wall0, t0)) => {
                    // An absurd gap (a timestamp of 1e308 among good ones)
                    // is paced at most a day past the anchor instead of panicking
                    // in `Duration::from_secs_f64` or the `Instant` addition;
                    // the session's shutdown still ends the wait.
                    let dt = ((t - t0) / speed).clamp(0.0, MAX_PACING_GAP_SECS);
                    let gap = std::time::Duration::try_from_secs_f64(dt).unwrap_or_default();
                    let mut target = wall0.checked_add(gap).unwrap_or_else(Instant::now);
                    if let Some(last) = self.last_target {
                        target = target.max(last);
                    }
                    self.last_target = Some(target);
                    tokio::time::sleep_until(target).await;
                }
            }
        }
        if t.is_finite() {
            self.virtual_now_secs = Some(self.virtual_now_secs.map_or(t, |v| v.max(t)));
        }
        self.delivered += 1;
        Ok(Some(sample))
    }
}

impl<I, E> SampleSource for ReplaySource<I>
where
    I: Iterator<Item = Result<Sample, E>> + Send,
    E: std::error::Error + Send + Sync + 'static,
{
    fn next(&mut self) -> impl Future<Output = Result<Option<Sample>, SourceError>> + Send {
        self.next_inner()
    }

    fn describe(&self) -> String {
        let pacing = match self.pacing {
            Pacing::AsFastAsPossible => "as fast as possible".to_owned(),
            Pacing::Scaled { speed } => format!("{speed}× real time"),
        };
        format!("replay of {} ({pacing})", self.name)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_eye::sample::{DetectorMethod, PupilSample, PupilUnit};

    #[derive(Debug, thiserror::Error)]
    #[error("bad line {0}")]
    struct BadLine(u32);

    fn pupil(t: f64) -> Sample {
        Sample::Pupil(PupilSample {
            t_secs: t,
            eye: 0,
            diameter_raw: 4.0,
            unit: PupilUnit::Mm,
            diameter_mm: Some(4.0),
            confidence: 1.0,
            norm_pos: [0.5, 0.5],
            method: DetectorMethod::Other,
        })
    }

    fn items() -> Vec<Result<Sample, BadLine>> {
        vec![
            Ok(pupil(10.0)),
            Ok(pupil(10.5)),
            Err(BadLine(3)),
            Ok(pupil(12.0)),
        ]
    }

    #[tokio::test(start_paused = true)]
    async fn as_fast_as_possible_takes_no_time_and_reports_errors() {
        let start = Instant::now();
        let mut src = ReplaySource::new("trace", items().into_iter(), Pacing::AsFastAsPossible);
        assert_eq!(src.next().await.unwrap().unwrap().t_secs(), 10.0);
        assert_eq!(src.next().await.unwrap().unwrap().t_secs(), 10.5);
        let e = src.next().await.unwrap_err();
        assert_eq!(e.to_string(), "trace: item 2: bad line 3");
        assert_eq!(src.next().await.unwrap().unwrap().t_secs(), 12.0);
        assert!(src.next().await.unwrap().is_none());
        assert_eq!(Instant::now(), start);
        assert_eq!((src.delivered(), src.errors()), (3, 1));
        assert_eq!(src.virtual_now_secs(), Some(12.0));
        assert!(src.describe().contains("as fast as possible"));
    }

    #[tokio::test(start_paused = true)]
    async fn scaled_pacing_follows_the_timestamps() {
        let start = Instant::now();
        let mut src =
            ReplaySource::new("trace", items().into_iter(), Pacing::Scaled { speed: 2.0 });
        src.next().await.unwrap();
        assert_eq!(Instant::now() - start, std::time::Duration::ZERO);
        src.next().await.unwrap();
        // 0.5 s of recording at 2× = 0.25 s.
        assert_eq!(
            Instant::now() - start,
            std::time::Duration::from_millis(250)
        );
        assert!(src.next().await.is_err());
        src.next().await.unwrap();
        assert_eq!(
            Instant::now() - start,
            std::time::Duration::from_millis(1000)
        );
    }

    #[tokio::test(start_paused = true)]
    async fn out_of_order_times_never_pace_backwards() {
        let v: Vec<Result<Sample, BadLine>> = vec![
            Ok(pupil(1.0)),
            Ok(pupil(2.0)),
            Ok(pupil(1.5)),
            Ok(pupil(2.5)),
        ];
        let start = Instant::now();
        let mut src = ReplaySource::new("t", v.into_iter(), Pacing::Scaled { speed: 1.0 });
        let mut waits = Vec::new();
        while let Some(_s) = src.next().await.unwrap() {
            waits.push((Instant::now() - start).as_millis());
        }
        assert_eq!(waits, vec![0, 1000, 1000, 1500]);
        assert_eq!(src.virtual_now_secs(), Some(2.5));
    }
}
