//! The calibration stimulus sent to a host application through Pupil.
//!
//! During the black/white calibration (001 §5) the stimulus is shown by
//! whatever application drives the display (a VR scene, a PsychoPy
//! script). [`RemoteSink`] tells it what to show with a Pupil notification
//! sent through Pupil Remote: topic `notify.gazelight.stimulus`, a msgpack
//! map `{"subject": "gazelight.stimulus", "color": "black" | "white" |
//! "none"}`. Every subscriber of `notify.` on the Pupil bus receives it.
//!
//! ## Bridging the synchronous sink to the async client
//!
//! [`StimulusSink::show`] is synchronous and is called from inside the
//! calibration loop, which usually runs on a tokio worker thread, so it
//! must neither block nor wait for the network. The sink therefore owns a
//! small bounded queue drained by one tokio task, which sends the
//! notifications in order through a [`PupilNotifier`] and waits for each
//! "Message forwarded." before the next:
//!
//! - `show` only enqueues (`try_send`); it fails at once when the queue is
//!   full ([`QUEUE_CAPACITY`] stimuli in flight: the peer is not answering)
//!   or when the sending task has stopped;
//! - a delivery failure is sticky: the next `show` returns it, and so does
//!   [`RemoteSink::flush`], which waits until everything queued has been
//!   delivered (call it after the calibration, before relying on the host
//!   application having seen `none`).

use std::sync::{Arc, Mutex};

use tokio::runtime::Handle;
use tokio::sync::{mpsc, oneshot};

use crate::client::{PupilError, PupilNotifier};
use gazelight_eye::calibration::{Stimulus, StimulusError, StimulusSink};

/// Subject of the stimulus notification (topic `notify.gazelight.stimulus`).
pub const STIMULUS_SUBJECT: &str = "gazelight.stimulus";

/// Stimuli that may wait for delivery before `show` fails.
pub const QUEUE_CAPACITY: usize = 16;

/// The value of the notification's `color` field.
pub fn color_name(stimulus: Stimulus) -> &'static str {
    match stimulus {
        Stimulus::Black => "black",
        Stimulus::White => "white",
        Stimulus::None => "none",
    }
}

enum Job {
    Show(Stimulus),
    Flush(oneshot::Sender<()>),
}

/// A [`StimulusSink`] that sends `gazelight.stimulus` notifications through
/// a [`crate::PupilClient`]. See the module docs for how the synchronous
/// `show` is bridged to the asynchronous client.
pub struct RemoteSink {
    jobs: mpsc::Sender<Job>,
    /// The first delivery failure, reported by the next `show`/`flush`.
    failure: Arc<Mutex<Option<PupilError>>>,
    /// Stimuli queued so far.
    queued: u64,
}

impl RemoteSink {
    /// A sink sending through `notifier`; its delivery task runs on
    /// `runtime` (`Handle::current()` inside a runtime).
    pub fn new(notifier: PupilNotifier, runtime: &Handle) -> Self {
        let (jobs, mut rx) = mpsc::channel::<Job>(QUEUE_CAPACITY);
        let failure: Arc<Mutex<Option<PupilError>>> = Arc::default();
        let fail = failure.clone();
        // The task ends once the sink is dropped and the queue drained, so
        // stimuli queued before a drop are still delivered.
        runtime.spawn(async move {
            while let Some(job) = rx.recv().await {
                match job {
                    Job::Show(stimulus) => {
                        let color = rmpv::Value::from(color_name(stimulus));
                        let r = notifier
                            .send_notification(STIMULUS_SUBJECT, &[("color", color)])
                            .await;
                        if let Err(e) = r {
                            tracing::warn!(error = %e, ?stimulus, "stimulus notification failed");
                            let mut f = fail.lock().unwrap_or_else(|p| p.into_inner());
                            f.get_or_insert(e);
                        }
                    }
                    Job::Flush(done) => {
                        let _ = done.send(());
                    }
                }
            }
        });
        Self {
            jobs,
            failure,
            queued: 0,
        }
    }

    /// Stimuli queued so far (delivered or not).
    pub fn queued(&self) -> u64 {
        self.queued
    }

    fn failure(&self) -> Option<PupilError> {
        self.failure
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
    }

    /// Waits until every stimulus queued so far has been delivered (or has
    /// failed); returns the first delivery failure, if any.
    pub async fn flush(&mut self) -> Result<(), PupilError> {
        let (done, wait) = oneshot::channel();
        self.jobs
            .send(Job::Flush(done))
            .await
            .map_err(|_| PupilError::Stopped)?;
        wait.await.map_err(|_| PupilError::Stopped)?;
        match self.failure() {
            Some(e) => Err(e),
            None => Ok(()),
        }
    }
}

impl StimulusSink for RemoteSink {
    fn show(&mut self, stimulus: Stimulus, _at_t_secs: f64) -> Result<(), StimulusError> {
        if let Some(e) = self.failure() {
            return Err(StimulusError(format!(
                "an earlier `{STIMULUS_SUBJECT}` notification failed: {e}"
            )));
        }
        match self.jobs.try_send(Job::Show(stimulus)) {
            Ok(()) => {
                self.queued += 1;
                Ok(())
            }
            Err(mpsc::error::TrySendError::Full(_)) => Err(StimulusError(format!(
                "{QUEUE_CAPACITY} `{STIMULUS_SUBJECT}` notifications are still waiting for \
                 Pupil Remote; not sending `{}`",
                color_name(stimulus)
            ))),
            Err(mpsc::error::TrySendError::Closed(_)) => Err(StimulusError(format!(
                "the stimulus sender task has stopped; not sending `{}`",
                color_name(stimulus)
            ))),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{PupilClient, PupilConfig};
    use std::time::Duration;

    #[tokio::test]
    async fn delivery_failure_is_reported_by_flush_and_the_next_show() {
        // Nothing listens on this port: the client stays unconnected and
        // answers notifications with NotConnected.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let (client, _streams) = PupilClient::spawn(PupilConfig {
            remote_port: port,
            connect_timeout: Duration::from_millis(50),
            backoff_initial: Duration::from_millis(20),
            ..PupilConfig::default()
        });
        let mut sink = RemoteSink::new(client.notifier(), &Handle::current());
        // `show` only queues: it succeeds without waiting for the network.
        sink.show(Stimulus::Black, 0.0).unwrap();
        assert_eq!(sink.queued(), 1);
        let e = sink.flush().await.unwrap_err();
        assert_eq!(e, PupilError::NotConnected);
        let e = sink.show(Stimulus::White, 1.0).unwrap_err();
        assert!(
            e.0.contains("earlier `gazelight.stimulus` notification failed"),
            "{e}"
        );
        assert_eq!(sink.queued(), 1);
        // A stopped client: the notifier reports it.
        client.shutdown().await;
        let mut sink2 = RemoteSink::new(
            PupilNotifier {
                cmd: mpsc::channel(1).0,
                limit: Duration::from_millis(10),
            },
            &Handle::current(),
        );
        sink2.show(Stimulus::None, 0.0).unwrap();
        assert_eq!(sink2.flush().await.unwrap_err(), PupilError::Stopped);
    }

    #[test]
    fn colors() {
        assert_eq!(color_name(Stimulus::Black), "black");
        assert_eq!(color_name(Stimulus::White), "white");
        assert_eq!(color_name(Stimulus::None), "none");
    }
}
