//! Pupil Core Network API client (Pupil Capture / Pupil Service).
//!
//! Protocol (Pupil Labs' `pupil_remote.py`, `zmq_tools.py`):
//! - **Pupil Remote**, a REQ/REP socket (default port 50020), answers the
//!   single-frame commands `SUB_PORT` and `PUB_PORT` (ports of the IPC
//!   bus), `t` (current Pupil time as text) and `v` (version). A two-frame
//!   request `[topic, msgpack]` is forwarded onto the bus and answered
//!   `Message forwarded.`; that is how notifications
//!   (`notify.<subject>`, a map with `subject`) are sent.
//! - The **bus** publishes `[topic, msgpack map, extra frames…]` on
//!   SUB_PORT; the client subscribes to `pupil.` and `gaze.` and decodes
//!   with [`msg`]. Extra frames are ignored.
//!
//! The client runs as one tokio task owning both sockets. Every request and
//! every receive is bounded by `tokio::time::timeout`. Datum times go to
//! host time through the client's [`SourceClock`] (the one mapping of
//! [`gazelight_eye::clock`]): the offset is measured with `t` round trips
//! on connection and then every `clock_interval`, and each datum's time is
//! checked against its arrival. The client never sends `T` (which resets
//! Pupil's clock for every client), but another client may (hmd-eyes syncs
//! Pupil time to Unix time that way): the mapping sees the step as a clock
//! jump after a few datums, re-anchors on their arrival, and the client
//! measures the offset again at once. A single datum with an absurd time
//! (1e308) is dropped and counted; the mapping's counters are in
//! [`PupilStats::mapping`].
//! When Remote stops answering or the bus goes silent and a `t` probe
//! fails, the sockets are dropped and rebuilt with a bounded exponential
//! backoff; the sample channel, the counters and the caller's handles
//! survive the reconnect.
//!
//! Both sockets bound what Pupil may send: a Remote reply or a bus message
//! over [`PupilConfig::remote_max_message_bytes`] /
//! [`PupilConfig::bus_max_message_bytes`] / `max_message_frames` (checked
//! from each frame header, before anything is allocated for the frame)
//! ends the connection like a lost one, with the reason logged, in
//! [`PupilStats::last_error`] and counted in [`PupilStats::too_large`].
//!
//! Samples leave through a bounded channel with their times converted to
//! host time; when the consumer lags, new samples are dropped and counted,
//! the channel never grows. The client only decodes and aligns clocks: the
//! samples are filtered once, by the live eye task of `gazelight-tracker`,
//! which reads them through [`PupilSource`] like any other source.

pub use crate::stimulus::{RemoteSink, STIMULUS_SUBJECT};

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use bytes::Bytes;
use tokio::sync::{mpsc, oneshot};
use tokio::time::{Instant, timeout};
use zeromq::{ReqSocket, Socket, SocketOptions, SocketRecv, SocketSend, SubSocket, ZmqMessage};

use crate::msg;
use gazelight_eye::clock::{
    ClockEstimate, ClockProbe, ClockStats, ClockTracker, SharedClockStats, SourceClock,
    SourceClockConfig, host_now_secs, parse_time_reply,
};
use gazelight_eye::live_events::{EventQueue, LiveEvent};
use gazelight_eye::sample::Sample;
use gazelight_eye::source::{SampleSource, SourceError};

/// Default Pupil Remote port.
pub const DEFAULT_REMOTE_PORT: u16 = 50020;
/// Default bound on one Pupil Remote reply: Capture answers with short
/// text (a port, a time, a version, "Message forwarded.").
pub const MAX_REMOTE_REPLY_BYTES: usize = 1 << 20;

/// Errors of the Pupil client.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PupilError {
    /// Connecting a socket failed.
    #[error("connecting to {endpoint}: {reason}")]
    Connect { endpoint: String, reason: String },
    /// A request or receive did not complete in time.
    #[error("{what}: no answer within {after_ms} ms")]
    Timeout { what: String, after_ms: u128 },
    /// The ZeroMQ layer reported an error.
    #[error("{what}: {reason}")]
    Socket { what: String, reason: String },
    /// Pupil Remote answered something unexpected.
    #[error("Pupil Remote answered {request:?} with {reply:?}")]
    BadReply { request: String, reply: String },
    /// A notification could not be encoded.
    #[error("encoding notification `{subject}`: {reason}")]
    Encode { subject: String, reason: String },
    /// The client is between connections (reconnecting).
    #[error("not connected to Pupil Remote (reconnecting)")]
    NotConnected,
    /// The client task has stopped.
    #[error("the Pupil client has stopped")]
    Stopped,
}

/// Client settings.
#[derive(Clone, Debug)]
pub struct PupilConfig {
    /// Host of Pupil Capture/Service.
    pub host: String,
    /// Pupil Remote port.
    pub remote_port: u16,
    /// Topic prefixes to subscribe to.
    pub topics: Vec<String>,
    /// Capacity of the sample channel; samples beyond it are dropped.
    pub channel_capacity: usize,
    /// Capacity of the raw-message channel for recording; 0 = no raw
    /// channel.
    pub raw_capacity: usize,
    /// Limit for one request/reply with Pupil Remote.
    pub request_timeout: Duration,
    /// Limit for establishing one socket connection.
    pub connect_timeout: Duration,
    /// Silence on the bus after which Remote is probed with `t`.
    pub idle_timeout: Duration,
    /// Probes per clock estimate (the fastest is kept).
    pub clock_probes: usize,
    /// Time between clock estimates.
    pub clock_interval: Duration,
    /// First reconnect delay; doubled after each failure.
    pub backoff_initial: Duration,
    /// Upper bound of the reconnect delay.
    pub backoff_max: Duration,
    /// Largest Pupil Remote reply, bytes (replies are a few bytes of text).
    pub remote_max_message_bytes: usize,
    /// Largest bus message, bytes: a frame datum with its image when
    /// `topics` asks for frames ([`crate::relay::MAX_DATUM_BYTES`]).
    pub bus_max_message_bytes: usize,
    /// Most frames of one message, on both sockets.
    pub max_message_frames: usize,
    /// Where Pupil Capture's annotations go (`None`: not subscribed).
    /// With a queue the client also subscribes to [`msg::ANNOTATION_TOPIC`]
    /// and puts each annotation's `timestamp` on the host clock with the
    /// measured offset (not checked against its arrival: an annotation may
    /// mark a moment before it was sent); a full queue drops and counts.
    pub events: Option<Arc<EventQueue>>,
}

impl Default for PupilConfig {
    /// Message limits from [`crate::limits::process_limits`].
    fn default() -> Self {
        let limits = crate::limits::process_limits();
        Self {
            host: "127.0.0.1".to_owned(),
            remote_port: DEFAULT_REMOTE_PORT,
            topics: vec!["pupil.".to_owned(), "gaze.".to_owned()],
            channel_capacity: 4096,
            raw_capacity: 0,
            request_timeout: Duration::from_millis(1000),
            connect_timeout: Duration::from_millis(1000),
            idle_timeout: Duration::from_millis(1000),
            clock_probes: 10,
            clock_interval: Duration::from_secs(10),
            backoff_initial: Duration::from_millis(100),
            backoff_max: Duration::from_secs(5),
            remote_max_message_bytes: limits.pupil_remote_max_message_bytes,
            bus_max_message_bytes: limits.pupil_bus_max_message_bytes,
            max_message_frames: limits.max_message_frames,
            events: None,
        }
    }
}

impl PupilConfig {
    fn remote_endpoint(&self) -> String {
        format!("tcp://{}:{}", self.host, self.remote_port)
    }
}

/// A message as it came off the bus, for recording (see
/// [`crate::recording`]).
#[derive(Clone, Debug, PartialEq)]
pub struct RawDatum {
    pub topic: String,
    /// The msgpack payload frame, unchanged.
    pub payload: Bytes,
    /// The datum's `timestamp` (Pupil time, seconds).
    pub pupil_t_secs: f64,
}

/// A snapshot of the client's counters and clock.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PupilStats {
    /// Messages received on the bus.
    pub received: u64,
    /// Messages decoded into samples.
    pub decoded: u64,
    /// Messages with a topic the decoder does not know (ignored).
    pub unknown_topic: u64,
    /// Unknown keys skipped inside decoded datums.
    pub unknown_fields: u64,
    /// Messages that could not be decoded (truncated, corrupt, bad field).
    pub malformed: u64,
    /// Samples dropped because the sample channel was full or closed.
    pub dropped: u64,
    /// Annotations decoded and queued ([`PupilConfig::events`]).
    pub annotations: u64,
    /// Raw messages dropped because the raw channel was full.
    pub raw_dropped: u64,
    /// Successful re-connections after a lost connection.
    pub reconnects: u64,
    /// Connections dropped because Pupil sent a frame or message over the
    /// limits ([`PupilConfig::bus_max_message_bytes`] and the others).
    pub too_large: u64,
    /// Whether a session is established now.
    pub connected: bool,
    /// Newest clock estimate (`offset_secs` = Pupil time − host time).
    pub clock: Option<ClockEstimate>,
    /// Drift of Pupil's clock against the host's, s/s, over recent
    /// estimates of this connection.
    pub drift_secs_per_sec: Option<f64>,
    /// The clock mapping: datums mapped, time stamps dropped, jumps (a `T`
    /// from another client), measurements refused.
    pub mapping: ClockStats,
    /// Pupil's answer to `v`.
    pub version: Option<String>,
    /// Why the last connection was lost.
    pub last_error: Option<String>,
}

#[derive(Default)]
struct Counters {
    received: AtomicU64,
    decoded: AtomicU64,
    unknown_topic: AtomicU64,
    unknown_fields: AtomicU64,
    malformed: AtomicU64,
    dropped: AtomicU64,
    annotations: AtomicU64,
    raw_dropped: AtomicU64,
    reconnects: AtomicU64,
    too_large: AtomicU64,
    connected: AtomicBool,
    clock: Arc<SharedClockStats>,
    slow: Mutex<SlowState>,
}

#[derive(Default)]
struct SlowState {
    clock: Option<ClockEstimate>,
    drift: Option<f64>,
    version: Option<String>,
    last_error: Option<String>,
}

impl Counters {
    fn slow(&self) -> std::sync::MutexGuard<'_, SlowState> {
        // A poisoned lock only means a panic elsewhere; the data is plain.
        self.slow.lock().unwrap_or_else(|p| p.into_inner())
    }
}

pub(crate) enum Command {
    Notify {
        topic: String,
        payload: Vec<u8>,
        reply: oneshot::Sender<Result<(), PupilError>>,
    },
    Shutdown,
}

/// The receiving ends of a client.
pub struct PupilStreams {
    /// Decoded samples, host time.
    pub samples: mpsc::Receiver<Sample>,
    /// Raw messages, when `raw_capacity > 0`.
    pub raw: Option<mpsc::Receiver<RawDatum>>,
}

/// Sends notifications through a running [`PupilClient`]; cheap to clone.
#[derive(Clone, Debug)]
pub struct PupilNotifier {
    pub(crate) cmd: mpsc::Sender<Command>,
    /// Bound on one notification: the worker answers within one request
    /// timeout once it gets to the command; this allows for one clock round
    /// in front of it.
    pub(crate) limit: Duration,
}

impl PupilNotifier {
    /// Sends a notification `notify.<subject>` with `fields` through Pupil
    /// Remote and waits (bounded) for "Message forwarded.".
    pub async fn send_notification(
        &self,
        subject: &str,
        fields: &[(&str, rmpv::Value)],
    ) -> Result<(), PupilError> {
        let (topic, payload) =
            msg::encode_notification(subject, fields).map_err(|e| PupilError::Encode {
                subject: subject.to_owned(),
                reason: e.to_string(),
            })?;
        let (reply, rx) = oneshot::channel();
        self.cmd
            .send(Command::Notify {
                topic,
                payload,
                reply,
            })
            .await
            .map_err(|_| PupilError::Stopped)?;
        match timeout(self.limit, rx).await {
            Ok(Ok(r)) => r,
            Ok(Err(_)) => Err(PupilError::Stopped),
            Err(_) => Err(PupilError::Timeout {
                what: format!("notification `{subject}`"),
                after_ms: self.limit.as_millis(),
            }),
        }
    }
}

/// Handle to a running client task. Dropping it stops the task.
pub struct PupilClient {
    cmd: mpsc::Sender<Command>,
    counters: Arc<Counters>,
    task: tokio::task::JoinHandle<()>,
    config: PupilConfig,
}

impl PupilClient {
    /// Starts the client task (it connects, and keeps reconnecting, in the
    /// background). Must be called within a tokio runtime.
    pub fn spawn(config: PupilConfig) -> (Self, PupilStreams) {
        Self::spawn_inner(config)
    }

    fn spawn_inner(config: PupilConfig) -> (Self, PupilStreams) {
        let (sample_tx, samples) = mpsc::channel(config.channel_capacity.max(1));
        let (raw_tx, raw) = if config.raw_capacity > 0 {
            let (t, r) = mpsc::channel(config.raw_capacity);
            (Some(t), Some(r))
        } else {
            (None, None)
        };
        let (cmd, cmd_rx) = mpsc::channel(16);
        let counters = Arc::new(Counters::default());
        let worker = Worker {
            config: config.clone(),
            counters: counters.clone(),
            cmd_rx,
            sample_tx,
            raw_tx,
            tracker: ClockTracker::new(32),
            clock: SourceClock::with_stats(
                format!("pupil://{}:{}", config.host, config.remote_port),
                SourceClockConfig::default(),
                counters.clock.clone(),
            ),
            reprobe: false,
            probes: Vec::with_capacity(config.clock_probes.max(1)),
        };
        let task = tokio::spawn(worker.run());
        (
            Self {
                cmd,
                counters,
                task,
                config,
            },
            PupilStreams { samples, raw },
        )
    }

    /// A snapshot of the counters and the clock.
    pub fn stats(&self) -> PupilStats {
        let c = &self.counters;
        let slow = c.slow();
        PupilStats {
            received: c.received.load(Ordering::Relaxed),
            decoded: c.decoded.load(Ordering::Relaxed),
            unknown_topic: c.unknown_topic.load(Ordering::Relaxed),
            unknown_fields: c.unknown_fields.load(Ordering::Relaxed),
            malformed: c.malformed.load(Ordering::Relaxed),
            dropped: c.dropped.load(Ordering::Relaxed),
            annotations: c.annotations.load(Ordering::Relaxed),
            raw_dropped: c.raw_dropped.load(Ordering::Relaxed),
            reconnects: c.reconnects.load(Ordering::Relaxed),
            too_large: c.too_large.load(Ordering::Relaxed),
            connected: c.connected.load(Ordering::Relaxed),
            clock: slow.clock,
            drift_secs_per_sec: slow.drift,
            mapping: c.clock.snapshot(),
            version: slow.version.clone(),
            last_error: slow.last_error.clone(),
        }
    }

    /// The settings the client runs with.
    pub fn config(&self) -> &PupilConfig {
        &self.config
    }

    /// Sends a notification `notify.<subject>` with `fields` through Pupil
    /// Remote and waits for "Message forwarded.".
    pub async fn send_notification(
        &self,
        subject: &str,
        fields: &[(&str, rmpv::Value)],
    ) -> Result<(), PupilError> {
        self.notifier().send_notification(subject, fields).await
    }

    /// A cloneable handle that sends notifications through this client
    /// (for [`RemoteSink`] and other tasks); it stops working with
    /// [`PupilError::Stopped`] once the client is dropped or shut down.
    pub fn notifier(&self) -> PupilNotifier {
        PupilNotifier {
            cmd: self.cmd.clone(),
            limit: self.config.request_timeout * (self.config.clock_probes as u32 + 2),
        }
    }

    /// Waits until a session is established, up to `limit`.
    pub async fn wait_connected(&self, limit: Duration) -> Result<(), PupilError> {
        let deadline = Instant::now() + limit;
        while !self.counters.connected.load(Ordering::Relaxed) {
            if Instant::now() >= deadline || self.task.is_finished() {
                return Err(PupilError::Timeout {
                    what: format!("connecting to {}", self.config.remote_endpoint()),
                    after_ms: limit.as_millis(),
                });
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        Ok(())
    }

    /// Stops the task and waits (bounded) for it to close its sockets.
    pub async fn shutdown(self) {
        let _ = self.cmd.try_send(Command::Shutdown);
        let limit = self.config.request_timeout * (self.config.clock_probes as u32 + 2);
        let mut this = self;
        if timeout(limit, &mut this.task).await.is_err() {
            this.task.abort();
        }
    }
}

impl Drop for PupilClient {
    fn drop(&mut self) {
        if !self.task.is_finished() {
            self.task.abort();
        }
    }
}

enum End {
    Shutdown,
}

struct Worker {
    config: PupilConfig,
    counters: Arc<Counters>,
    cmd_rx: mpsc::Receiver<Command>,
    sample_tx: mpsc::Sender<Sample>,
    raw_tx: Option<mpsc::Sender<RawDatum>>,
    tracker: ClockTracker,
    /// Pupil time → host time.
    clock: SourceClock,
    /// The mapping found a jump: measure the offset again now.
    reprobe: bool,
    probes: Vec<ClockProbe>,
}

impl Worker {
    async fn run(mut self) {
        let mut backoff = self.config.backoff_initial;
        let mut ever_connected = false;
        loop {
            let mut established = false;
            let err = match self.session(&mut established, ever_connected).await {
                Ok(End::Shutdown) => break,
                Err(e) => e,
            };
            self.counters.connected.store(false, Ordering::Relaxed);
            tracing::warn!(error = %err, "Pupil connection lost or not established; retrying");
            self.counters.slow().last_error = Some(err.to_string());
            if established {
                ever_connected = true;
                backoff = self.config.backoff_initial;
            }
            // Wait, answering commands meanwhile.
            let sleep = tokio::time::sleep(backoff);
            tokio::pin!(sleep);
            loop {
                tokio::select! {
                    _ = &mut sleep => break,
                    cmd = self.cmd_rx.recv() => match cmd {
                        None | Some(Command::Shutdown) => return,
                        Some(Command::Notify { reply, .. }) => {
                            let _ = reply.send(Err(PupilError::NotConnected));
                        }
                    },
                }
            }
            backoff = (backoff * 2).min(self.config.backoff_max);
        }
    }

    fn socket_options(&self, max_message_bytes: usize) -> SocketOptions {
        let mut o =
            crate::relay::limited_options(max_message_bytes, self.config.max_message_frames);
        o.connect_timeout(self.config.connect_timeout);
        o
    }

    /// Counts a receive error that means Pupil sent more than the limits.
    fn note_receive_error(&self, e: &zeromq::ZmqError) {
        if crate::relay::is_over_limit(e) {
            self.counters.too_large.fetch_add(1, Ordering::Relaxed);
        }
    }

    async fn connect<S: Socket>(&self, socket: &mut S, endpoint: &str) -> Result<(), PupilError> {
        let limit = self.config.connect_timeout + Duration::from_millis(100);
        match timeout(limit, socket.connect(endpoint)).await {
            Ok(Ok(())) => Ok(()),
            Ok(Err(e)) => Err(PupilError::Connect {
                endpoint: endpoint.to_owned(),
                reason: e.to_string(),
            }),
            Err(_) => Err(PupilError::Timeout {
                what: format!("connecting to {endpoint}"),
                after_ms: limit.as_millis(),
            }),
        }
    }

    async fn request(
        &self,
        req: &mut ReqSocket,
        message: ZmqMessage,
        what: &str,
    ) -> Result<ZmqMessage, PupilError> {
        let limit = self.config.request_timeout;
        let exchange = async {
            req.send(message).await.map_err(|e| PupilError::Socket {
                what: format!("sending {what}"),
                reason: e.to_string(),
            })?;
            req.recv().await.map_err(|e| {
                self.note_receive_error(&e);
                PupilError::Socket {
                    what: format!("reply to {what}"),
                    reason: e.to_string(),
                }
            })
        };
        match timeout(limit, exchange).await {
            Ok(r) => r,
            Err(_) => Err(PupilError::Timeout {
                what: format!("request {what}"),
                after_ms: limit.as_millis(),
            }),
        }
    }

    async fn request_text(&self, req: &mut ReqSocket, command: &str) -> Result<Bytes, PupilError> {
        let reply = self
            .request(req, ZmqMessage::from(command), &format!("`{command}`"))
            .await?;
        reply.get(0).cloned().ok_or_else(|| PupilError::BadReply {
            request: command.to_owned(),
            reply: "(no frame)".to_owned(),
        })
    }

    async fn estimate_clock(&mut self, req: &mut ReqSocket) -> Result<ClockEstimate, PupilError> {
        self.probes.clear();
        for _ in 0..self.config.clock_probes.max(1) {
            let sent = host_now_secs();
            let reply = self.request_text(req, "t").await?;
            let received = host_now_secs();
            let pupil = parse_time_reply(&reply).map_err(|reason| PupilError::BadReply {
                request: "t".to_owned(),
                reply: reason.to_string(),
            })?;
            self.probes.push(ClockProbe {
                sent_host_secs: sent,
                pupil_secs: pupil,
                received_host_secs: received,
            });
        }
        let est = ClockEstimate::from_probes(&self.probes).ok_or_else(|| PupilError::BadReply {
            request: "t".to_owned(),
            reply: "round trips with negative or non-finite times".to_owned(),
        })?;
        self.tracker.push(est);
        // offset = Pupil − host; the mapping holds host − Pupil.
        if !self.clock.anchor(-est.offset_secs, host_now_secs()) {
            tracing::warn!(
                offset_s = est.offset_secs,
                "Pupil's answer to `t` disagrees with the times of its datums; the datums' \
                 arrivals keep the mapping"
            );
        }
        let drift = self.tracker.drift_secs_per_sec();
        {
            let mut slow = self.counters.slow();
            slow.clock = Some(est);
            slow.drift = drift;
        }
        tracing::debug!(
            offset_s = est.offset_secs,
            rtt_s = est.rtt_secs,
            ?drift,
            "Pupil clock estimate"
        );
        Ok(est)
    }

    async fn session(
        &mut self,
        established: &mut bool,
        ever_connected: bool,
    ) -> Result<End, PupilError> {
        let remote = self.config.remote_endpoint();
        let mut req =
            ReqSocket::with_options(self.socket_options(self.config.remote_max_message_bytes));
        self.connect(&mut req, &remote).await?;
        let sub_port_reply = self.request_text(&mut req, "SUB_PORT").await?;
        let sub_port: u16 = std::str::from_utf8(&sub_port_reply)
            .ok()
            .and_then(|s| s.trim().parse().ok())
            .filter(|p| *p != 0)
            .ok_or_else(|| PupilError::BadReply {
                request: "SUB_PORT".to_owned(),
                reply: String::from_utf8_lossy(&sub_port_reply).into_owned(),
            })?;
        let version = self.request_text(&mut req, "v").await?;
        // A restarted Pupil may have a reset clock: drift and the mapping
        // restart too.
        self.tracker.clear();
        self.clock.reset();
        self.estimate_clock(&mut req).await?;

        let mut sub =
            SubSocket::with_options(self.socket_options(self.config.bus_max_message_bytes));
        let bus = format!("tcp://{}:{}", self.config.host, sub_port);
        self.connect(&mut sub, &bus).await?;
        let annotations = self
            .config
            .events
            .is_some()
            .then_some(msg::ANNOTATION_TOPIC);
        for topic in self
            .config
            .topics
            .iter()
            .map(String::as_str)
            .chain(annotations)
        {
            let r = timeout(self.config.request_timeout, sub.subscribe(topic)).await;
            match r {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    return Err(PupilError::Socket {
                        what: format!("subscribing to `{topic}`"),
                        reason: e.to_string(),
                    });
                }
                Err(_) => {
                    return Err(PupilError::Timeout {
                        what: format!("subscribing to `{topic}`"),
                        after_ms: self.config.request_timeout.as_millis(),
                    });
                }
            }
        }
        *established = true;
        if ever_connected {
            self.counters.reconnects.fetch_add(1, Ordering::Relaxed);
        }
        {
            let mut slow = self.counters.slow();
            slow.version = Some(String::from_utf8_lossy(&version).trim().to_owned());
        }
        self.counters.connected.store(true, Ordering::Relaxed);
        tracing::info!(%remote, %bus, "connected to Pupil");

        let mut next_clock = Instant::now() + self.config.clock_interval;
        loop {
            tokio::select! {
                biased;
                cmd = self.cmd_rx.recv() => match cmd {
                    None | Some(Command::Shutdown) => return Ok(End::Shutdown),
                    Some(Command::Notify { topic, payload, reply }) => {
                        let mut m = ZmqMessage::from(topic.clone());
                        m.push_back(Bytes::from(payload));
                        let r = self.request(&mut req, m, &format!("`{topic}`")).await;
                        let r = match r {
                            Ok(rep) => {
                                let text = rep.get(0).map(|b| String::from_utf8_lossy(b).into_owned()).unwrap_or_default();
                                if text == "Message forwarded." {
                                    Ok(())
                                } else {
                                    Err(PupilError::BadReply { request: topic, reply: text })
                                }
                            }
                            Err(e) => Err(e),
                        };
                        let lost = matches!(r, Err(PupilError::Timeout { .. } | PupilError::Socket { .. }));
                        let err = r.as_ref().err().cloned();
                        let _ = reply.send(r);
                        if lost && let Some(e) = err {
                            return Err(e);
                        }
                    }
                },
                r = timeout(self.config.idle_timeout, sub.recv()) => match r {
                    Ok(Ok(m)) => {
                        self.handle(m, host_now_secs());
                        if std::mem::take(&mut self.reprobe) {
                            // Pupil's clock jumped (a `T` from another
                            // client): measure the new offset now.
                            next_clock = Instant::now();
                        }
                    }
                    Ok(Err(e)) => {
                        self.note_receive_error(&e);
                        return Err(PupilError::Socket { what: "receiving from the bus".to_owned(), reason: e.to_string() });
                    }
                    Err(_) => {
                        // Silence: is Pupil still there? Use it as a clock probe.
                        self.estimate_clock(&mut req).await?;
                    }
                },
                _ = tokio::time::sleep_until(next_clock) => {
                    self.estimate_clock(&mut req).await?;
                    next_clock = Instant::now() + self.config.clock_interval;
                }
            }
        }
    }

    /// Decodes one bus message that arrived at host time `arrival`.
    fn handle(&mut self, m: ZmqMessage, arrival: f64) {
        let c = &self.counters;
        let n = c.received.fetch_add(1, Ordering::Relaxed);
        let (Some(topic), Some(payload)) = (m.get(0), m.get(1)) else {
            let count = c.malformed.fetch_add(1, Ordering::Relaxed) + 1;
            if should_log(count) {
                tracing::warn!(
                    message = n,
                    malformed = count,
                    "bus message with fewer than 2 frames skipped"
                );
            }
            return;
        };
        if let Some(events) = &self.config.events
            && topic.starts_with(msg::ANNOTATION_TOPIC.as_bytes())
        {
            return self.annotation(events.clone(), payload, arrival);
        }
        match msg::decode_message(topic, payload) {
            Ok(datum) => {
                c.decoded.fetch_add(1, Ordering::Relaxed);
                let unknown = datum.unknown_fields();
                if unknown > 0 {
                    c.unknown_fields
                        .fetch_add(u64::from(unknown), Ordering::Relaxed);
                }
                let jumps = self.clock.stats().jumps;
                // A datum whose time the mapping drops (not finite, or off
                // by more than its bound) is still recorded raw below.
                if let Some(t) = self.clock.to_host(datum.timestamp(), arrival)
                    && self.sample_tx.try_send(datum.sample_at(t)).is_err()
                {
                    c.dropped.fetch_add(1, Ordering::Relaxed);
                }
                self.reprobe |= self.clock.stats().jumps > jumps;
                if let Some(raw) = &self.raw_tx {
                    let r = RawDatum {
                        topic: String::from_utf8_lossy(topic).into_owned(),
                        payload: payload.clone(),
                        pupil_t_secs: datum.timestamp(),
                    };
                    if raw.try_send(r).is_err() {
                        c.raw_dropped.fetch_add(1, Ordering::Relaxed);
                    }
                }
            }
            Err(e) if e.is_unknown_topic() => {
                let count = c.unknown_topic.fetch_add(1, Ordering::Relaxed) + 1;
                if should_log(count) {
                    tracing::debug!(error = %e, unknown_topics = count, "ignored");
                }
            }
            Err(e) => {
                let count = c.malformed.fetch_add(1, Ordering::Relaxed) + 1;
                if should_log(count) {
                    tracing::warn!(error = %e, message = n, malformed = count, "bus message skipped");
                }
            }
        }
    }
}

impl Worker {
    /// Queues one annotation datum that arrived at host time `arrival`.
    fn annotation(&mut self, events: Arc<EventQueue>, payload: &[u8], arrival: f64) {
        let c = &self.counters;
        match msg::decode_annotation(payload) {
            Ok(a) if a.timestamp.is_finite() => {
                c.decoded.fetch_add(1, Ordering::Relaxed);
                // host − Pupil, measured by the `t` round trips (set before
                // the bus is subscribed); the arrival if there is none yet.
                let host = self
                    .clock
                    .offset_secs()
                    .map_or(arrival, |o| a.timestamp + o);
                let e = LiveEvent::new(
                    host,
                    a.timestamp,
                    a.duration_secs,
                    msg::ANNOTATION_TOPIC,
                    &a.label,
                );
                if events.push(e) {
                    c.annotations.fetch_add(1, Ordering::Relaxed);
                }
            }
            Ok(_) | Err(_) => {
                let count = c.malformed.fetch_add(1, Ordering::Relaxed) + 1;
                if should_log(count) {
                    tracing::warn!(
                        malformed = count,
                        "annotation skipped: no finite `timestamp` or no text `label`"
                    );
                }
            }
        }
    }
}

/// Logs the first ten occurrences, then every thousandth.
fn should_log(count: u64) -> bool {
    count <= 10 || count.is_multiple_of(1000)
}

/// With no Pupil Capture answering within this time, [`PupilSource`]
/// says so (once).
pub const NO_TRACKER_AFTER: Duration = Duration::from_millis(1500);
/// How often [`PupilSource`] looks at the client's connection.
const HEALTH_POLL: Duration = Duration::from_millis(250);

/// The Pupil client as a [`SampleSource`]: decoded samples on the host
/// clock. A lost connection (or none within [`NO_TRACKER_AFTER`]) is
/// reported once as [`SourceError::Disconnected`] while the client keeps
/// reconnecting; the next sample after it means the connection is back.
pub struct PupilSource {
    client: PupilClient,
    samples: mpsc::Receiver<Sample>,
    started: Instant,
    next_poll: Instant,
    ever_connected: bool,
    was_connected: bool,
    said_absent: bool,
}

impl PupilSource {
    /// Starts a client for `config` and reads its sample channel.
    pub fn spawn(config: PupilConfig) -> (Self, Option<mpsc::Receiver<RawDatum>>) {
        let (client, streams) = PupilClient::spawn(config);
        let now = Instant::now();
        (
            Self {
                client,
                samples: streams.samples,
                started: now,
                next_poll: now + HEALTH_POLL,
                ever_connected: false,
                was_connected: false,
                said_absent: false,
            },
            streams.raw,
        )
    }

    /// The underlying client (stats, notifications).
    pub fn client(&self) -> &PupilClient {
        &self.client
    }

    fn endpoint(&self) -> String {
        format!(
            "{}:{}",
            self.client.config.host, self.client.config.remote_port
        )
    }

    /// Looks at the connection: `Some(reason)` when it was just lost, or
    /// when no tracker has answered for [`NO_TRACKER_AFTER`].
    fn poll_health(&mut self) -> Option<String> {
        let stats = self.client.stats();
        let endpoint = self.endpoint();
        let mut lost = None;
        if stats.connected && !self.was_connected {
            if self.ever_connected {
                tracing::info!(endpoint = %endpoint, reconnects = stats.reconnects, "Pupil Capture is back: live again");
            } else {
                tracing::info!(endpoint = %endpoint, version = stats.version.as_deref().unwrap_or("?"), "connected to Pupil Capture");
            }
        } else if !stats.connected && self.was_connected {
            let reason = format!(
                "lost Pupil Capture at {endpoint}: {}; frames continue, the pupil eases to the model",
                stats.last_error.as_deref().unwrap_or("no answer")
            );
            tracing::warn!(endpoint = %endpoint, "{reason}");
            lost = Some(reason);
        }
        if !stats.connected
            && !self.ever_connected
            && !self.said_absent
            && self.started.elapsed() >= NO_TRACKER_AFTER
        {
            self.said_absent = true;
            let reason = format!(
                "no Pupil Capture at {endpoint}: {}; frames continue with the pupil model (--mouse-gaze needs a window); still trying to connect",
                stats
                    .last_error
                    .as_deref()
                    .unwrap_or("no answer from Pupil Remote")
            );
            tracing::warn!("{reason}");
            lost = Some(reason);
        }
        self.ever_connected |= stats.connected;
        self.was_connected = stats.connected;
        lost
    }
}

impl SampleSource for PupilSource {
    async fn next(&mut self) -> Result<Option<Sample>, SourceError> {
        loop {
            tokio::select! {
                s = self.samples.recv() => {
                    return match s {
                        Some(s) => Ok(Some(s)),
                        None => Err(SourceError::Fatal {
                            source_name: self.describe(),
                            reason: "client task stopped".to_owned(),
                        }),
                    };
                }
                _ = tokio::time::sleep_until(self.next_poll) => {
                    self.next_poll = Instant::now() + HEALTH_POLL;
                    if let Some(reason) = self.poll_health() {
                        return Err(SourceError::Disconnected {
                            source_name: self.describe(),
                            reason,
                        });
                    }
                }
            }
        }
    }

    fn describe(&self) -> String {
        format!(
            "pupil://{}:{}",
            self.client.config.host, self.client.config.remote_port
        )
    }

    fn dropped(&self) -> u64 {
        self.client.counters.dropped.load(Ordering::Relaxed)
    }

    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        Some(self.client.counters.clock.clone())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn unreachable_peer_backs_off_and_answers_not_connected() {
        // A port with nothing listening: bind then drop to get a free one.
        let port = std::net::TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let cfg = PupilConfig {
            remote_port: port,
            connect_timeout: Duration::from_millis(100),
            backoff_initial: Duration::from_millis(50),
            backoff_max: Duration::from_millis(200),
            ..PupilConfig::default()
        };
        let (client, _streams) = PupilClient::spawn(cfg);
        assert!(
            client
                .wait_connected(Duration::from_millis(300))
                .await
                .is_err()
        );
        let stats = client.stats();
        assert!(!stats.connected);
        assert!(stats.last_error.is_some());
        let r = client.send_notification("x", &[]).await;
        assert!(matches!(r, Err(PupilError::NotConnected)), "{r:?}");
        client.shutdown().await;
    }
}
