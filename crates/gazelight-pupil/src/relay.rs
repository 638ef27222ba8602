//! The Pupil-compatible relay: re-publishes a session's filtered,
//! calibrated eye stream as a Pupil Core Network API, so that existing
//! Pupil clients (Pupil Labs' Python client `pupil-core-network-client`,
//! hmd-eyes, the LSL relay, gazelight's own
//! [`crate::PupilClient`]) consume the
//! cleaned stream unchanged.
//!
//! The protocol is Pupil Capture's (`pupil_remote.py`, `zmq_tools.py`):
//!
//! - **Pupil Remote** (REP, the relay's address) answers `SUB_PORT` and
//!   `PUB_PORT` (ports of the bus, as text), `t` (the relay's clock,
//!   seconds, as Python's `repr(float)`), `v` (version), `T <secs>` (sets the
//!   relay's clock, "Timesync successful."; |T| ≤ 1e10 s, else refused), and forwards any multi-frame
//!   request `[topic, payload, …]` — notifications are
//!   `[notify.<subject>, msgpack]` — onto the bus, answering
//!   "Message forwarded." exactly like Capture. Anything else gets a reply
//!   too ("Unknown command.", or a sentence saying what is not available):
//!   a REP socket that does not answer would hang the client.
//! - **The bus** (PUB, port `SUB_PORT`) publishes `[topic, msgpack map]`
//!   with named keys:
//!   - `pupil.0.3d`, `pupil.1.3d`: `diameter_3d` (the calibrated, filtered
//!     pupil, mm), `diameter` (eye-camera px of the newest raw sample, when
//!     the source reports px), `confidence`, `norm_pos` (of the newest raw
//!     sample, when known), `timestamp`, `id`, `method` = `"gazelight
//!     filtered"`;
//!   - `gaze.3d.01.`: the filtered gaze as `norm_pos` (Pupil's bottom-left
//!     origin), `confidence`, `timestamp`, `base_data` (the two pupil
//!     datums);
//!   - `gazelight.adaptation`: the frame loop's adaptation luminance,
//!     pooled target luminance and pupils (from [`RelayFeed::frame`]);
//!   - `gazelight.pupil_light`: per eye the pupil the light predicts
//!     (`pupil_light_mm`), the measured pupil (`pupil_mm`) and their
//!     difference (`pupil_residual_mm`, NaN where the pupil is not
//!     measured), per frame (docs/pupil-light-response.md).
//! - **PUB_PORT** (SUB, bound, subscribed to everything): what clients'
//!   PUB sockets send is forwarded onto the bus, as Capture's IPC does.
//!
//! **Source and rates.** The publisher wakes on each change of the feed's
//! `EyeState` watch. Several source updates may coalesce into one wake
//! (the watch keeps the newest value); [`LiveEyeState::updates`] tells how
//! many, and they are counted in [`RelayStats::coalesced_updates`]. A wake
//! publishes the pupil datum of each eye whose filtered channel changed
//! (a valid sample always moves `last_valid_t_secs`), and a gaze datum
//! when the gaze changed or when neither eye did (the update was a gaze
//! sample whose filtered value stayed put). The newest raw per-eye fields
//! (`norm_pos`, px diameter, raw gaze confidence) come from the feed's
//! sample broadcast, drained without waiting at each wake.
//!
//! **Time base.** Datums carry the `EyeState` time (the process-wide host
//! clock, [`host_now_secs`]) plus the relay's offset (0 until a client
//! sends `T`), and `t` answers the same clock, so a client's clock-offset
//! estimate from `t` applies to the datums.
//!
//! All queues are bounded: requests are served one at a time, forwarded
//! messages go through a bounded channel (dropped and counted when full,
//! in messages and in bytes), and the PUB socket drops messages for
//! subscribers that do not keep up.
//!
//! **Receive limits.** Every socket bounds what one peer may send
//! ([`RelayLimits`]: bytes of one frame or multipart message, frames of one
//! message), checked from each frame header before anything is allocated
//! for it (the patched `zeromq`, `vendor/zeromq/GAZELIGHT_PATCH.md`). A peer
//! over a limit is disconnected with a logged reason and counted in
//! [`RelayStats::peers_dropped`]; the relay keeps serving everyone else.

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use bytes::Bytes;
use gazelight_eye::clock::host_now_secs;
use gazelight_eye::{EyeChannel, EyeState, PupilUnit, Sample};
use serde::Serialize;
use tokio::sync::{OwnedSemaphorePermit, Semaphore, broadcast, mpsc, watch};
use tokio::task::JoinHandle;
use zeromq::{
    PubSocket, RepSocket, Socket, SocketEvent, SocketOptions, SocketRecv, SocketSend, SubSocket,
    ZmqMessage,
};

use gazelight_eye::state::LiveEyeState;

/// What the relay reads from a running session: the filtered eye state,
/// the raw sample broadcast, the frame loop's latest figures and the
/// shutdown flag.
pub trait RelayFeed: Send + Sync + 'static {
    /// The latest filtered, calibrated eye state.
    fn eye(&self) -> watch::Receiver<LiveEyeState>;
    /// A new subscription to the samples as they arrive.
    fn subscribe_samples(&self) -> broadcast::Receiver<Sample>;
    /// The newest frame's figures (`frames` = 0 before the first frame).
    fn frame(&self) -> FrameFigures;
    /// Turns true when the session ends.
    fn shutdown_signal(&self) -> watch::Receiver<bool>;
}

/// The frame loop's figures the relay publishes on [`ADAPTATION_TOPIC`].
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameFigures {
    /// Frame counter (0: no frame yet).
    pub frames: u64,
    /// Session time of the frame, s.
    pub t_secs: f64,
    /// Adaptation luminance, cd/m².
    pub adaptation_cd_m2: f64,
    /// Pooled target luminance, cd/m².
    pub target_cd_m2: f64,
    /// Pupil the frame used (binocular), mm.
    pub frame_pupil_mm: f32,
    /// Calibrated pupil per eye [right, left], mm.
    pub pupil_mm: [f32; 2],
    /// Age of the `EyeState` the frame used, ms.
    pub eye_state_age_ms: f64,
    /// The pupil the light predicts per eye [right, left], mm.
    pub pupil_light_mm: [f32; 2],
    /// Measured − predicted pupil per eye [right, left], mm; NaN where
    /// the pupil is not measured.
    pub pupil_residual_mm: [f32; 2],
}

/// Why the relay could not start.
#[derive(Debug, thiserror::Error)]
pub enum RelayError {
    /// A socket could not be bound (a port in use, an address not here).
    #[error("relay: binding the {what} to {host}:{port}")]
    Bind {
        what: &'static str,
        host: String,
        port: u16,
        #[source]
        source: zeromq::ZmqError,
    },
    /// A socket bound to something that is not a TCP port.
    #[error("relay: the {what} bound to {endpoint}, not a TCP port")]
    NotTcp {
        what: &'static str,
        endpoint: String,
    },
    /// The PUB_PORT socket could not subscribe.
    #[error("relay: subscribing the PUB_PORT socket")]
    Subscribe(#[source] zeromq::ZmqError),
}

/// The Pupil Network API level the relay speaks; `v` answers it with
/// gazelight's version as build metadata.
pub const PUPIL_API_VERSION: &str = "3.5.0";
/// `method` of the relay's pupil datums.
pub const RELAY_METHOD: &str = "gazelight filtered";
/// Topic of the adaptation state.
pub const ADAPTATION_TOPIC: &str = "gazelight.adaptation";
/// Topic of the pupil light response (predicted and residual pupil).
pub const PUPIL_LIGHT_TOPIC: &str = "gazelight.pupil_light";
/// Capacity of the channel of messages forwarded onto the bus.
const FORWARD_CAPACITY: usize = 256;
/// Bytes the channel of forwarded messages may hold at once (two of the
/// largest legal messages); a message that does not fit is dropped and
/// counted like one that finds the channel full.
const FORWARD_MAX_BYTES: usize = 2 * MAX_DATUM_BYTES;

/// Largest legal Pupil message a peer may send: a frame datum with its
/// image, `[topic, msgpack, raw image]`, as Pupil Capture's Frame Publisher
/// (format `bgr`) and hmd-eyes' screen cast send it. 32 MiB holds a
/// 3840×2160 BGR image (24 883 200 bytes) with its header; Pupil's own
/// cameras go to 1920×1080 (6.2 MB in BGR).
pub const MAX_DATUM_BYTES: usize = 32 << 20;
/// Largest subscription message a bus subscriber may send (`0x01` + topic
/// prefix; Pupil's topics are tens of bytes).
pub const MAX_SUBSCRIPTION_BYTES: usize = 64 << 10;
/// Most frames of one multipart message: Pupil sends `[topic, payload]`
/// plus one frame per `__raw_data__` item (one image); a REP request adds
/// its envelope.
pub const MAX_MESSAGE_FRAMES: usize = 64;

/// What one peer may send to each of the relay's sockets. A frame whose
/// header announces more, or a multipart message that grows past a limit,
/// disconnects that peer (logged, counted in [`RelayStats::peers_dropped`])
/// before the bytes are allocated; the relay keeps serving.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RelayLimits {
    /// Pupil Remote (REP): bytes of one request (commands, notifications
    /// and forwarded messages).
    pub remote_max_message_bytes: usize,
    /// PUB_PORT (SUB): bytes of one message a client publishes.
    pub pub_port_max_message_bytes: usize,
    /// The bus (PUB): bytes of one subscription message.
    pub bus_max_message_bytes: usize,
    /// Frames of one multipart message, on every socket.
    pub max_message_frames: usize,
}

impl Default for RelayLimits {
    /// The relay's part of [`crate::limits::process_limits`].
    fn default() -> Self {
        let limits = crate::limits::process_limits();
        Self {
            remote_max_message_bytes: limits.relay_remote_max_message_bytes,
            pub_port_max_message_bytes: limits.relay_pub_port_max_message_bytes,
            bus_max_message_bytes: limits.relay_bus_max_message_bytes,
            max_message_frames: limits.max_message_frames,
        }
    }
}

/// Socket options bounding what one peer may send (see [`RelayLimits`]).
pub(crate) fn limited_options(
    max_message_bytes: usize,
    max_message_frames: usize,
) -> SocketOptions {
    let mut o = SocketOptions::default();
    o.max_message_size(Some(max_message_bytes))
        .max_message_frames(Some(max_message_frames.max(1)));
    o
}

/// Whether a receive error means the peer sent more than the limits.
pub(crate) fn is_over_limit(e: &zeromq::ZmqError) -> bool {
    matches!(
        e,
        zeromq::ZmqError::Codec(zeromq::CodecError::MessageTooLarge { .. })
    )
}

/// A message on its way onto the bus, holding its share of
/// [`FORWARD_MAX_BYTES`] until it is published.
struct Forwarded {
    message: ZmqMessage,
    _bytes: OwnedSemaphorePermit,
}

/// The sending side of the forward channel, bounded in messages and bytes.
#[derive(Clone)]
struct ForwardTx {
    tx: mpsc::Sender<Forwarded>,
    bytes: Arc<Semaphore>,
}

impl ForwardTx {
    /// Queues `message`; `false` when the channel is full (in messages or
    /// bytes).
    fn try_send(&self, message: ZmqMessage) -> bool {
        let size: usize = message.iter().map(|f| f.len()).sum();
        let Ok(n) = u32::try_from(size.max(1)) else {
            return false;
        };
        let Ok(permit) = self.bytes.clone().try_acquire_many_owned(n) else {
            return false;
        };
        self.tx
            .try_send(Forwarded {
                message,
                _bytes: permit,
            })
            .is_ok()
    }
}
/// How often the adaptation topic is checked for a new frame (≥ a 90 Hz
/// display's rate).
const ADAPTATION_POLL: Duration = Duration::from_millis(10);

/// Counters of a running relay.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct RelayStats {
    /// Pupil Remote requests answered.
    pub requests: u64,
    /// Pupil datums published (both eyes).
    pub pupil_published: u64,
    /// Gaze datums published.
    pub gaze_published: u64,
    /// `gazelight.adaptation` datums published.
    pub adaptation_published: u64,
    /// `gazelight.pupil_light` datums published.
    pub pupil_light_published: u64,
    /// Source updates that coalesced into a later wake (not published one
    /// by one).
    pub coalesced_updates: u64,
    /// Messages forwarded onto the bus (Remote multi-frame requests and
    /// PUB_PORT input).
    pub forwarded: u64,
    /// Forwarded messages dropped because the bus queue was full.
    pub forward_dropped: u64,
    /// Raw samples the relay missed from the feed's broadcast (lagging).
    pub samples_lagged: u64,
    /// Messages the PUB socket refused.
    pub publish_errors: u64,
    /// Peers disconnected for sending a frame or message over the limits
    /// ([`RelayLimits`]) or a corrupt frame, on any socket.
    pub peers_dropped: u64,
}

#[derive(Default)]
struct Counters {
    requests: AtomicU64,
    pupil_published: AtomicU64,
    gaze_published: AtomicU64,
    adaptation_published: AtomicU64,
    pupil_light_published: AtomicU64,
    coalesced_updates: AtomicU64,
    forwarded: AtomicU64,
    forward_dropped: AtomicU64,
    samples_lagged: AtomicU64,
    publish_errors: AtomicU64,
    peers_dropped: AtomicU64,
}

fn bump(c: &AtomicU64, n: u64) {
    c.fetch_add(n, Ordering::Relaxed);
}

/// Largest |T| accepted by `T <secs>`: 10¹⁰ s (317 years) covers Pupil
/// time (seconds since the tracker started) and Unix time up to year 2286;
/// a larger value would make every published timestamp absurd (1e308 makes
/// them all 1e308) and is refused with the clock left as it was.
pub const MAX_SYNC_T_SECS: f64 = 1e10;

/// The relay's clock: host time plus an offset a client may set with `T`.
#[derive(Default)]
struct RelayClock {
    offset_bits: AtomicU64,
}

impl RelayClock {
    fn offset_secs(&self) -> f64 {
        f64::from_bits(self.offset_bits.load(Ordering::Relaxed))
    }
    fn now_secs(&self) -> f64 {
        host_now_secs() + self.offset_secs()
    }
    fn set_now(&self, t_secs: f64) {
        let offset = t_secs - host_now_secs();
        self.offset_bits.store(offset.to_bits(), Ordering::Relaxed);
    }
}

/// Handle to a running relay.
pub struct RelayHandle {
    remote_addr: SocketAddr,
    sub_port: u16,
    pub_port: u16,
    counters: Arc<Counters>,
    tasks: Vec<JoinHandle<()>>,
}

impl RelayHandle {
    /// The bound Pupil Remote address.
    pub fn local_addr(&self) -> SocketAddr {
        self.remote_addr
    }

    /// Port of the bus clients subscribe to (`SUB_PORT`).
    pub fn sub_port(&self) -> u16 {
        self.sub_port
    }

    /// Port clients' PUB sockets connect to (`PUB_PORT`).
    pub fn pub_port(&self) -> u16 {
        self.pub_port
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> RelayStats {
        let c = &self.counters;
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        RelayStats {
            requests: l(&c.requests),
            pupil_published: l(&c.pupil_published),
            gaze_published: l(&c.gaze_published),
            adaptation_published: l(&c.adaptation_published),
            pupil_light_published: l(&c.pupil_light_published),
            coalesced_updates: l(&c.coalesced_updates),
            forwarded: l(&c.forwarded),
            forward_dropped: l(&c.forward_dropped),
            samples_lagged: l(&c.samples_lagged),
            publish_errors: l(&c.publish_errors),
            peers_dropped: l(&c.peers_dropped),
        }
    }

    /// Waits for the relay's tasks to end (after the feed's shutdown).
    pub async fn join(mut self) {
        for t in self.tasks.drain(..) {
            let _ = t.await;
        }
    }
}

impl Drop for RelayHandle {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

async fn bind<S: Socket>(
    socket: &mut S,
    host: &str,
    port: u16,
    what: &'static str,
) -> Result<u16, RelayError> {
    let endpoint = format!("tcp://{host}:{port}");
    let bound = socket
        .bind(&endpoint)
        .await
        .map_err(|source| RelayError::Bind {
            what,
            host: host.to_owned(),
            port,
            source,
        })?;
    match bound {
        zeromq::Endpoint::Tcp(_, p) => Ok(p),
        other => Err(RelayError::NotTcp {
            what,
            endpoint: other.to_string(),
        }),
    }
}

/// Starts the relay: binds Pupil Remote at `remote_addr` (port 0 picks a
/// free port) and the bus and PUB_PORT on free ports of the same host, and
/// runs until [`RelayFeed::shutdown_signal`] turns true. A port in use is
/// an error naming the address. The sockets take the default
/// [`RelayLimits`].
pub async fn spawn(
    hub: Arc<dyn RelayFeed>,
    remote_addr: SocketAddr,
) -> Result<RelayHandle, RelayError> {
    spawn_with_limits(hub, remote_addr, RelayLimits::default()).await
}

/// [`spawn`] with the receive limits of each socket.
pub async fn spawn_with_limits(
    hub: Arc<dyn RelayFeed>,
    remote_addr: SocketAddr,
    limits: RelayLimits,
) -> Result<RelayHandle, RelayError> {
    let host = remote_addr.ip().to_string();
    let host = if remote_addr.is_ipv6() {
        format!("[{host}]")
    } else {
        host
    };
    let frames = limits.max_message_frames;
    let mut rep = RepSocket::with_options(limited_options(limits.remote_max_message_bytes, frames));
    let remote_port = bind(&mut rep, &host, remote_addr.port(), "Pupil Remote (REP)").await?;
    let mut bus = PubSocket::with_options(limited_options(limits.bus_max_message_bytes, frames));
    let bus_events = bus.monitor();
    let sub_port = bind(&mut bus, &host, 0, "bus (PUB)").await?;
    let mut inbound =
        SubSocket::with_options(limited_options(limits.pub_port_max_message_bytes, frames));
    let pub_port = bind(&mut inbound, &host, 0, "PUB_PORT (SUB)").await?;
    inbound.subscribe("").await.map_err(RelayError::Subscribe)?;

    let counters = Arc::new(Counters::default());
    let clock = Arc::new(RelayClock::default());
    let (tx, fwd_rx) = mpsc::channel::<Forwarded>(FORWARD_CAPACITY);
    let fwd_tx = ForwardTx {
        tx,
        bytes: Arc::new(Semaphore::new(FORWARD_MAX_BYTES)),
    };

    let remote = Remote {
        rep,
        sub_port,
        pub_port,
        clock: clock.clone(),
        counters: counters.clone(),
        forward: fwd_tx.clone(),
    };
    let publisher = Publisher::new(hub.clone(), bus, clock, counters.clone(), fwd_rx);
    let shutdown = hub.shutdown_signal();
    let tasks = vec![
        tokio::spawn(remote.run(hub.shutdown_signal())),
        tokio::spawn(publisher.run(hub.shutdown_signal())),
        tokio::spawn(forward_inbound(inbound, fwd_tx, counters.clone(), shutdown)),
        tokio::spawn({
            // The PUB socket's monitor (a futures channel): counts and logs
            // the subscribers it dropped, whose receive errors never reach
            // the relay otherwise.
            let (mut events, counters, mut shutdown) =
                (bus_events, counters.clone(), hub.shutdown_signal());
            async move {
                loop {
                    let event = tokio::select! {
                        _ = shutdown_requested(&mut shutdown) => break,
                        e = events.recv() => e,
                    };
                    match event {
                        Ok(e) => on_bus_event(&counters, e),
                        Err(_) => break,
                    }
                }
            }
        }),
    ];
    let remote_addr = SocketAddr::new(remote_addr.ip(), remote_port);
    tracing::info!(%remote_addr, sub_port, pub_port, "Pupil relay listening");
    Ok(RelayHandle {
        remote_addr,
        sub_port,
        pub_port,
        counters,
        tasks,
    })
}

/// Resolves when the shutdown flag is (or becomes) true, or its sender is
/// gone.
async fn shutdown_requested(rx: &mut watch::Receiver<bool>) {
    let _ = rx.wait_for(|v| *v).await;
}

/// Pupil Remote: one request at a time, every request answered.
struct Remote {
    rep: RepSocket,
    sub_port: u16,
    pub_port: u16,
    clock: Arc<RelayClock>,
    counters: Arc<Counters>,
    forward: ForwardTx,
}

impl Remote {
    async fn run(mut self, mut shutdown: watch::Receiver<bool>) {
        loop {
            let request = tokio::select! {
                _ = shutdown_requested(&mut shutdown) => break,
                r = self.rep.recv() => r,
            };
            let request = match request {
                Ok(m) => m,
                Err(e) => {
                    if is_over_limit(&e) {
                        bump(&self.counters.peers_dropped, 1);
                    }
                    tracing::warn!(error = %e, "relay: Pupil Remote receive failed; that client is disconnected");
                    continue;
                }
            };
            let reply = self.answer(request);
            bump(&self.counters.requests, 1);
            if let Err(e) = self.rep.send(ZmqMessage::from(reply)).await {
                tracing::warn!(error = %e, "relay: Pupil Remote reply failed");
            }
        }
    }

    /// The reply to one request (Capture's `PupilRemote.on_recv`).
    fn answer(&self, request: ZmqMessage) -> String {
        if request.len() > 1 {
            return if self.forward.try_send(request) {
                "Message forwarded.".to_owned()
            } else {
                bump(&self.counters.forward_dropped, 1);
                "Message dropped: the relay's bus queue is full.".to_owned()
            };
        }
        let Some(frame) = request.get(0) else {
            return "Unknown command.".to_owned();
        };
        let Ok(cmd) = std::str::from_utf8(frame) else {
            return "Unknown command.".to_owned();
        };
        match cmd {
            "SUB_PORT" => self.sub_port.to_string(),
            "PUB_PORT" => self.pub_port.to_string(),
            "t" => format_time(self.clock.now_secs()),
            "v" => format!(
                "{PUPIL_API_VERSION}+gazelight.{}",
                env!("CARGO_PKG_VERSION")
            ),
            _ if cmd.starts_with('T') => {
                let arg = cmd.get(2..).unwrap_or("").trim();
                match arg.parse::<f64>() {
                    Ok(t) if t.is_finite() && t.abs() <= MAX_SYNC_T_SECS => {
                        self.clock.set_now(t);
                        "Timesync successful.".to_owned()
                    }
                    Ok(t) if t.is_finite() => format!(
                        "'{arg}' is outside the clock range this relay accepts \
                         (|T| ≤ {MAX_SYNC_T_SECS:e} s); clock unchanged."
                    ),
                    _ => format!("'{arg}' cannot be converted to float."),
                }
            }
            _ if cmd.starts_with('R') || cmd.starts_with('r') => {
                "gazelight relay: recording is not available here.".to_owned()
            }
            "C" | "c" => "gazelight relay: calibration is not available here.".to_owned(),
            _ => "Unknown command.".to_owned(),
        }
    }
}

/// A time as Python's `repr(float)` writes it (shortest round-trip form,
/// always with a decimal point), so `float(reply)` gives the value back.
fn format_time(t_secs: f64) -> String {
    let s = format!("{t_secs:?}");
    if s.contains(['.', 'e', 'E', 'N', 'n']) {
        s
    } else {
        format!("{s}.0")
    }
}

/// Forwards what clients publish on PUB_PORT onto the bus.
async fn forward_inbound(
    mut inbound: SubSocket,
    forward: ForwardTx,
    counters: Arc<Counters>,
    mut shutdown: watch::Receiver<bool>,
) {
    loop {
        let m = tokio::select! {
            _ = shutdown_requested(&mut shutdown) => break,
            m = inbound.recv() => m,
        };
        match m {
            Ok(m) => {
                if !forward.try_send(m) {
                    bump(&counters.forward_dropped, 1);
                }
            }
            Err(e) => {
                if is_over_limit(&e) {
                    bump(&counters.peers_dropped, 1);
                }
                tracing::warn!(error = %e, "relay: PUB_PORT receive failed; that client is disconnected");
            }
        }
    }
}

/// Counts (and logs) a bus subscriber the PUB socket dropped for what it
/// sent.
fn on_bus_event(counters: &Counters, event: SocketEvent) {
    if let SocketEvent::PeerDropped(_, reason) = event {
        bump(&counters.peers_dropped, 1);
        tracing::warn!(%reason, "relay: bus subscriber disconnected");
    }
}

/// The newest raw per-eye and gaze fields seen on the sample broadcast.
#[derive(Clone, Copy, Debug)]
struct RawFields {
    norm_pos: [Option<[f64; 2]>; 2],
    diameter_px: [Option<f64>; 2],
    gaze_confidence: Option<f64>,
}

impl RawFields {
    fn new() -> Self {
        Self {
            norm_pos: [None; 2],
            diameter_px: [None; 2],
            gaze_confidence: None,
        }
    }

    fn observe(&mut self, s: &Sample) {
        match s {
            Sample::Pupil(p) if p.eye < 2 => {
                let e = p.eye as usize;
                let [x, y] = p.norm_pos;
                if x.is_finite() && y.is_finite() {
                    self.norm_pos[e] = Some([f64::from(x), f64::from(y)]);
                }
                if p.unit == PupilUnit::Px && p.diameter_raw.is_finite() && p.diameter_raw > 0.0 {
                    self.diameter_px[e] = Some(f64::from(p.diameter_raw));
                }
            }
            Sample::Gaze(g) if g.confidence.is_finite() => {
                self.gaze_confidence = Some(f64::from(g.confidence.clamp(0.0, 1.0)));
            }
            _ => {}
        }
    }
}

/// A pupil datum as the relay publishes it.
#[derive(Serialize, Clone, Copy, Debug, PartialEq)]
pub struct PupilOut {
    pub topic: &'static str,
    pub id: u8,
    pub method: &'static str,
    pub timestamp: f64,
    pub confidence: f64,
    /// Calibrated, filtered pupil, mm.
    pub diameter_3d: f64,
    /// Eye-camera px of the newest raw sample, when the source reports px.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub diameter: Option<f64>,
    /// Pupil centre of the newest raw sample (eye image, bottom-left
    /// origin), when known.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub norm_pos: Option<[f64; 2]>,
}

/// A binocular gaze datum as the relay publishes it.
#[derive(Serialize, Clone, Copy, Debug, PartialEq)]
pub struct GazeOut {
    pub topic: &'static str,
    /// Filtered gaze, normalised, bottom-left origin (Pupil's convention).
    pub norm_pos: [f64; 2],
    pub confidence: f64,
    pub timestamp: f64,
    pub base_data: [PupilOut; 2],
}

/// The pupil light response as the relay publishes it, per eye [right,
/// left].
#[derive(Serialize, Clone, Copy, Debug, PartialEq)]
pub struct PupilLightOut {
    pub topic: &'static str,
    /// The relay's clock when the frame was observed, s.
    pub timestamp: f64,
    /// Session time of the frame, s.
    pub frame_t_secs: f64,
    /// Frame counter.
    pub frame: u64,
    /// The pupil the light predicts, mm.
    pub pupil_light_mm: [f64; 2],
    /// The calibrated, filtered pupil, mm.
    pub pupil_mm: [f64; 2],
    /// `pupil_mm − pupil_light_mm` where the pupil is measured, else NaN.
    pub pupil_residual_mm: [f64; 2],
}

/// The adaptation state as the relay publishes it.
#[derive(Serialize, Clone, Copy, Debug, PartialEq)]
pub struct AdaptationOut {
    pub topic: &'static str,
    /// The relay's clock when the frame was observed, s.
    pub timestamp: f64,
    /// Session time of the frame, s.
    pub frame_t_secs: f64,
    /// Frame counter.
    pub frame: u64,
    pub adaptation_cd_m2: f64,
    pub target_cd_m2: f64,
    /// Pupil the frame used (binocular), mm.
    pub pupil_mm: f64,
    /// Calibrated pupil per eye [right, left], mm.
    pub pupil_eye_mm: [f64; 2],
    /// Age of the `EyeState` the frame used, ms.
    pub eye_state_age_ms: f64,
}

const PUPIL_TOPICS: [&str; 2] = ["pupil.0.3d", "pupil.1.3d"];
const GAZE_TOPIC: &str = "gaze.3d.01.";

/// One eye's pupil datum: the measured pupil in mm as `diameter_3d`, or —
/// where the eye is not measured now (a blink and its margins, lost, no
/// physical scale) — 0 with confidence 0, as Pupil Capture reports a lost
/// pupil. The model aperture is never relayed as a measurement.
fn pupil_out(eye: usize, ch: &EyeChannel, t: f64, raw: &RawFields) -> PupilOut {
    let (diameter_3d, confidence) = match ch.measured_mm() {
        Some(mm) => (f64::from(mm), f64::from(ch.confidence)),
        None => (0.0, 0.0),
    };
    PupilOut {
        topic: PUPIL_TOPICS[eye],
        id: eye as u8,
        method: RELAY_METHOD,
        timestamp: t,
        confidence,
        diameter_3d,
        diameter: raw.diameter_px[eye],
        norm_pos: raw.norm_pos[eye],
    }
}

fn gaze_out(state: &EyeState, t: f64, raw: &RawFields) -> GazeOut {
    // Without a raw gaze confidence, the filter's verdict: a valid
    // filtered gaze is certain, an invalid one is not.
    let confidence = raw
        .gaze_confidence
        .unwrap_or(if state.gaze_valid { 1.0 } else { 0.0 });
    GazeOut {
        topic: GAZE_TOPIC,
        // In f64, 1 − (1 − v) gives v back exactly for an f32 v.
        norm_pos: [
            f64::from(state.gaze_uv[0]),
            1.0 - f64::from(state.gaze_uv[1]),
        ],
        confidence: if state.blink { 0.0 } else { confidence },
        timestamp: t,
        base_data: [
            pupil_out(0, &state.eyes[0], t, raw),
            pupil_out(1, &state.eyes[1], t, raw),
        ],
    }
}

/// Which datums a new state calls for, given the last published one.
fn datums_for(prev: Option<&EyeState>, next: &EyeState) -> ([bool; 2], bool) {
    let Some(prev) = prev else {
        return ([true, true], true);
    };
    let eyes = [prev.eyes[0] != next.eyes[0], prev.eyes[1] != next.eyes[1]];
    let gaze_changed = prev.gaze_uv != next.gaze_uv
        || prev.gaze_valid != next.gaze_valid
        || prev.blink != next.blink;
    (eyes, gaze_changed || !(eyes[0] || eyes[1]))
}

/// The bus publisher.
struct Publisher {
    hub: Arc<dyn RelayFeed>,
    eye: watch::Receiver<LiveEyeState>,
    samples: broadcast::Receiver<Sample>,
    bus: PubSocket,
    clock: Arc<RelayClock>,
    counters: Arc<Counters>,
    forwarded: mpsc::Receiver<Forwarded>,
    raw: RawFields,
    last: Option<LiveEyeState>,
    /// `updates` of the newest state seen.
    last_updates: u64,
    last_frame: u64,
}

impl Publisher {
    fn new(
        hub: Arc<dyn RelayFeed>,
        bus: PubSocket,
        clock: Arc<RelayClock>,
        counters: Arc<Counters>,
        forwarded: mpsc::Receiver<Forwarded>,
    ) -> Self {
        let mut eye = hub.eye();
        // Publish the state as it is now only once it changes: a state
        // nobody has written yet (updates == 0) is the chain's default.
        let current = *eye.borrow_and_update();
        let samples = hub.subscribe_samples();
        Self {
            hub,
            eye,
            samples,
            bus,
            clock,
            counters,
            forwarded,
            raw: RawFields::new(),
            last: (current.updates > 0).then_some(current),
            last_updates: current.updates,
            last_frame: 0,
        }
    }

    async fn run(mut self, mut shutdown: watch::Receiver<bool>) {
        let mut tick = tokio::time::interval(ADAPTATION_POLL);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
        let mut eye_open = true;
        loop {
            tokio::select! {
                _ = shutdown_requested(&mut shutdown) => break,
                changed = self.eye.changed(), if eye_open => {
                    if changed.is_err() {
                        // The source is gone; keep serving Remote and the
                        // adaptation topic until shutdown.
                        eye_open = false;
                        continue;
                    }
                    let live = *self.eye.borrow_and_update();
                    self.on_state(live).await;
                }
                m = self.forwarded.recv() => {
                    if let Some(m) = m {
                        self.send(m.message).await;
                        bump(&self.counters.forwarded, 1);
                    }
                }
                _ = tick.tick() => self.on_tick().await,
            }
        }
    }

    fn drain_samples(&mut self) {
        loop {
            match self.samples.try_recv() {
                Ok(s) => self.raw.observe(&s),
                Err(broadcast::error::TryRecvError::Lagged(n)) => {
                    bump(&self.counters.samples_lagged, n);
                }
                Err(_) => break,
            }
        }
    }

    async fn on_state(&mut self, live: LiveEyeState) {
        // A state with no new sample (the live eye task stepping its stale
        // fallback) is no new datum: a relay client sees tracker times only.
        if self.last.is_some() && live.updates == self.last_updates {
            return;
        }
        let missed = live
            .updates
            .saturating_sub(self.last_updates.saturating_add(1));
        if missed > 0 {
            bump(&self.counters.coalesced_updates, missed);
        }
        self.last_updates = live.updates;
        self.drain_samples();
        let (eyes, gaze) = datums_for(self.last.as_ref().map(|l| &l.state), &live.state);
        self.last = Some(live);
        let state = live.state;
        let t = state.t_secs + self.clock.offset_secs();
        for (e, publish) in eyes.iter().enumerate() {
            if *publish {
                let d = pupil_out(e, &state.eyes[e], t, &self.raw);
                if self.publish(d.topic, &d).await {
                    bump(&self.counters.pupil_published, 1);
                }
            }
        }
        if gaze {
            let d = gaze_out(&state, t, &self.raw);
            if self.publish(d.topic, &d).await {
                bump(&self.counters.gaze_published, 1);
            }
        }
    }

    async fn on_tick(&mut self) {
        let f = self.hub.frame();
        if f.frames == 0 || f.frames == self.last_frame {
            return;
        }
        self.last_frame = f.frames;
        let d = AdaptationOut {
            topic: ADAPTATION_TOPIC,
            timestamp: self.clock.now_secs(),
            frame_t_secs: f.t_secs,
            frame: f.frames,
            adaptation_cd_m2: f.adaptation_cd_m2,
            target_cd_m2: f.target_cd_m2,
            pupil_mm: f64::from(f.frame_pupil_mm),
            pupil_eye_mm: [f64::from(f.pupil_mm[0]), f64::from(f.pupil_mm[1])],
            eye_state_age_ms: f.eye_state_age_ms,
        };
        if self.publish(ADAPTATION_TOPIC, &d).await {
            bump(&self.counters.adaptation_published, 1);
        }
        let d = PupilLightOut {
            topic: PUPIL_LIGHT_TOPIC,
            timestamp: d.timestamp,
            frame_t_secs: f.t_secs,
            frame: f.frames,
            pupil_light_mm: f.pupil_light_mm.map(f64::from),
            pupil_mm: f.pupil_mm.map(f64::from),
            pupil_residual_mm: f.pupil_residual_mm.map(f64::from),
        };
        if self.publish(PUPIL_LIGHT_TOPIC, &d).await {
            bump(&self.counters.pupil_light_published, 1);
        }
    }

    async fn publish<T: Serialize>(&mut self, topic: &'static str, datum: &T) -> bool {
        let payload = match rmp_serde::to_vec_named(datum) {
            Ok(p) => p,
            Err(e) => {
                tracing::warn!(topic, error = %e, "relay: encoding failed");
                bump(&self.counters.publish_errors, 1);
                return false;
            }
        };
        let mut m = ZmqMessage::from(Bytes::from_static(topic.as_bytes()));
        m.push_back(Bytes::from(payload));
        self.send(m).await
    }

    async fn send(&mut self, m: ZmqMessage) -> bool {
        match self.bus.send(m).await {
            Ok(()) => true,
            Err(e) => {
                bump(&self.counters.publish_errors, 1);
                tracing::debug!(error = %e, "relay: publish failed");
                false
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{PupilClient, PupilConfig};
    use gazelight_eye::{DetectorMethod, PupilOrigin, PupilSample};
    use std::collections::HashMap;
    use std::sync::Mutex;
    use zeromq::ReqSocket;

    /// A session as the relay sees it, driven by the test.
    struct Hub {
        eye: watch::Receiver<LiveEyeState>,
        samples: broadcast::Sender<Sample>,
        frame: Mutex<FrameFigures>,
        shutdown: watch::Sender<bool>,
    }

    impl Hub {
        fn new(_uri: &str, eye: watch::Receiver<LiveEyeState>) -> Arc<Self> {
            Arc::new(Self {
                eye,
                samples: broadcast::channel(1024).0,
                frame: Mutex::new(FrameFigures::default()),
                shutdown: watch::channel(false).0,
            })
        }
        fn publish_frame(&self, f: FrameFigures) {
            *self.frame.lock().unwrap() = f;
        }
        fn request_shutdown(&self) {
            self.shutdown.send_replace(true);
        }
    }

    impl RelayFeed for Hub {
        fn eye(&self) -> watch::Receiver<LiveEyeState> {
            self.eye.clone()
        }
        fn subscribe_samples(&self) -> broadcast::Receiver<Sample> {
            self.samples.subscribe()
        }
        fn frame(&self) -> FrameFigures {
            *self.frame.lock().unwrap()
        }
        fn shutdown_signal(&self) -> watch::Receiver<bool> {
            self.shutdown.subscribe()
        }
    }

    fn loopback() -> SocketAddr {
        "127.0.0.1:0".parse().unwrap()
    }

    async fn request(req: &mut ReqSocket, m: ZmqMessage) -> String {
        let exchange = async {
            req.send(m).await.unwrap();
            req.recv().await.unwrap()
        };
        let reply = tokio::time::timeout(Duration::from_secs(2), exchange)
            .await
            .expect("Pupil Remote must answer every request");
        String::from_utf8(reply.get(0).unwrap().to_vec()).unwrap()
    }

    /// The n-th state of a test session: both pupils, the gaze and the
    /// confidences move with `k`, so every datum is traceable to its state.
    fn session_state(k: u64, t_secs: f64) -> EyeState {
        let mut s = EyeState {
            t_secs,
            gaze_uv: [0.2 + (k % 50) as f32 * 0.01, 0.7 - (k % 40) as f32 * 0.01],
            gaze_valid: true,
            ..EyeState::default()
        };
        for (e, ch) in s.eyes.iter_mut().enumerate() {
            // The measured pupil, and apart from it the aperture: the relay
            // publishes the measurement, never the aperture.
            let mm = 3.0 + e as f32 + (k % 100) as f32 * 0.0125;
            ch.measured = Some(mm);
            ch.measured_unit = Some(PupilUnit::Mm);
            ch.present = true;
            ch.pupil_mm = mm + 0.5;
            ch.confidence = 0.8 + (k % 10) as f32 * 0.01;
            ch.pupil_origin = PupilOrigin::Measured;
            ch.last_valid_t_secs = Some(t_secs);
        }
        s
    }

    fn px_sample(eye: u8, t_secs: f64, px: f32) -> Sample {
        Sample::Pupil(PupilSample {
            t_secs,
            eye,
            diameter_raw: px,
            unit: PupilUnit::Px,
            diameter_mm: None,
            confidence: 0.9,
            norm_pos: [0.41, 0.52],
            method: DetectorMethod::Pupil2d,
        })
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn remote_answers_every_request_and_forwards_notifications() {
        let (_tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let relay = spawn(hub.clone(), loopback()).await.unwrap();
        let addr = relay.local_addr();
        assert_ne!(addr.port(), 0);
        let mut req = ReqSocket::new();
        req.connect(&format!("tcp://{addr}")).await.unwrap();
        let sub_port: u16 = request(&mut req, "SUB_PORT".into()).await.parse().unwrap();
        let pub_port: u16 = request(&mut req, "PUB_PORT".into()).await.parse().unwrap();
        assert_eq!(sub_port, relay.sub_port());
        assert_eq!(pub_port, relay.pub_port());
        assert!(
            request(&mut req, "v".into())
                .await
                .starts_with(PUPIL_API_VERSION)
        );

        // `t` is the host clock (no `T` yet), in a form float() parses.
        let before = host_now_secs();
        let t: f64 = request(&mut req, "t".into()).await.parse().unwrap();
        let after = host_now_secs();
        assert!(before <= t && t <= after, "{before} <= {t} <= {after}");
        // `T` moves the relay's clock.
        assert_eq!(
            request(&mut req, "T 1000.25".into()).await,
            "Timesync successful."
        );
        let t: f64 = request(&mut req, "t".into()).await.parse().unwrap();
        assert!((t - 1000.25).abs() < 0.5, "{t}");
        assert!(
            request(&mut req, "T abc".into())
                .await
                .contains("cannot be converted"),
            "a bad T argument is refused"
        );
        // An absurd T is refused and leaves the clock where it was; so are
        // the non-finite ones.
        for absurd in [
            "T 1e308", "T -1e308", "T 1.0e11", "T nan", "T inf", "T -inf",
        ] {
            let reply = request(&mut req, absurd.into()).await;
            assert_ne!(reply, "Timesync successful.", "{absurd}");
            let t: f64 = request(&mut req, "t".into()).await.parse().unwrap();
            assert!((t - 1000.25).abs() < 0.5, "{absurd} moved the clock to {t}");
        }
        assert!(
            request(&mut req, "T 1e308".into())
                .await
                .contains("outside the clock range"),
        );
        // The edge of the range is accepted (Unix time is well inside it).
        assert_eq!(
            request(&mut req, "T 1e10".into()).await,
            "Timesync successful."
        );
        assert_eq!(
            request(&mut req, "T 1000.25".into()).await,
            "Timesync successful."
        );

        // Anything else is answered, never left hanging.
        for junk in ["", "SUB", "x", "R", "C"] {
            let reply = request(&mut req, junk.into()).await;
            assert!(!reply.is_empty(), "{junk:?}");
        }
        let reply = request(&mut req, ZmqMessage::from(vec![0xffu8, 0xfe])).await;
        assert_eq!(reply, "Unknown command.");

        // A notification is forwarded onto the bus.
        let mut bus = SubSocket::new();
        bus.connect(&format!("tcp://127.0.0.1:{sub_port}"))
            .await
            .unwrap();
        bus.subscribe("notify.").await.unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
        let (topic, payload) =
            crate::msg::encode_notification("gazelight.test", &[("n", rmpv::Value::from(7))])
                .unwrap();
        let mut m = ZmqMessage::from(topic.clone());
        m.push_back(Bytes::from(payload.clone()));
        assert_eq!(request(&mut req, m).await, "Message forwarded.");
        let got = tokio::time::timeout(Duration::from_secs(2), bus.recv())
            .await
            .expect("the notification reaches the bus")
            .unwrap();
        assert_eq!(got.get(0).unwrap().as_ref(), topic.as_bytes());
        assert_eq!(got.get(1).unwrap().as_ref(), &payload[..]);
        assert!(relay.stats().requests >= 14);
        assert_eq!(relay.stats().forwarded, 1);

        hub.request_shutdown();
        tokio::time::timeout(Duration::from_secs(2), relay.join())
            .await
            .expect("the relay stops on shutdown");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn port_in_use_is_an_error_naming_the_address() {
        let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = taken.local_addr().unwrap();
        let (_tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let err = match spawn(hub, addr).await {
            Ok(_) => panic!("binding a taken port must fail"),
            Err(e) => format!("{e:#}"),
        };
        assert!(err.contains(&addr.to_string()), "{err}");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn tracker_client_decodes_the_relay_like_pupil_capture() {
        let (tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let relay = spawn(hub.clone(), loopback()).await.unwrap();
        let config = PupilConfig {
            host: relay.local_addr().ip().to_string(),
            remote_port: relay.local_addr().port(),
            ..PupilConfig::default()
        };
        let (client, mut streams) = PupilClient::spawn(config);
        client.wait_connected(Duration::from_secs(5)).await.unwrap();
        tokio::time::sleep(Duration::from_millis(300)).await;

        // 400 updates at 2 ms; eye 0 also has raw px samples on the
        // broadcast, eye 1 has none.
        let mut fed: HashMap<u32, (u64, EyeState)> = HashMap::new();
        let mut fed_by_k = Vec::new();
        for k in 1..=400u64 {
            let t = host_now_secs();
            let s = session_state(k, t);
            let _ = hub.samples.send(px_sample(0, t, 30.0 + k as f32 * 0.25));
            tx.send_replace(LiveEyeState {
                state: s,
                updated_host_secs: t,
                updates: k,
            });
            fed.insert(s.eyes[1].measured.unwrap_or(f32::NAN).to_bits(), (k, s));
            fed_by_k.push(s);
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        tokio::time::sleep(Duration::from_millis(300)).await;
        let stats = client.stats();
        let offset = stats.clock.unwrap().offset_secs;
        assert!(offset.abs() < 0.01, "same clock, offset {offset}");
        assert_eq!(stats.malformed, 0);
        assert_eq!(stats.unknown_topic, 0);
        assert_eq!(stats.unknown_fields, 0, "only Pupil's own keys");

        // The client converts Pupil time to host time with its clock
        // estimate (error ≤ half a loopback round trip, far below the 2 ms
        // between states): each sample belongs to the nearest fed state.
        let nearest = |t: f64| {
            let s = fed_by_k
                .iter()
                .min_by(|a, b| (a.t_secs - t).abs().total_cmp(&(b.t_secs - t).abs()))
                .unwrap();
            assert!((s.t_secs - t).abs() < 0.001, "no fed state near {t}");
            *s
        };
        let (mut pupils, mut gazes) = ([0usize; 2], 0usize);
        while let Ok(s) = streams.samples.try_recv() {
            match s {
                Sample::Pupil(p) => {
                    pupils[p.eye as usize] += 1;
                    let state = nearest(p.t_secs);
                    let ch = &state.eyes[p.eye as usize];
                    assert_eq!(p.method, DetectorMethod::Pupil3d);
                    assert_eq!(p.confidence, ch.confidence);
                    if p.eye == 0 {
                        // px known: `diameter` px, `diameter_3d` mm.
                        assert_eq!(p.unit, PupilUnit::Px);
                        assert_eq!(p.diameter_mm, ch.measured);
                        assert_eq!(p.norm_pos, [0.41, 0.52]);
                    } else {
                        assert_eq!(p.unit, PupilUnit::Mm);
                        assert_eq!(Some(p.diameter_raw), ch.measured);
                        assert!(fed.contains_key(&p.diameter_raw.to_bits()));
                    }
                }
                Sample::Gaze(g) => {
                    gazes += 1;
                    let state = nearest(g.t_secs);
                    assert_eq!(g.gaze_uv, state.gaze_uv);
                    assert_eq!(g.eyes, gazelight_eye::GazeEyes::Binocular);
                }
                Sample::Blink(_) => {}
            }
        }
        let rs = relay.stats();
        let woken = 400 - rs.coalesced_updates as usize;
        // Every wake changed both eyes: one datum per eye, and the gaze.
        assert_eq!(rs.pupil_published as usize, 2 * woken);
        assert!(
            pupils[0] + 5 >= woken && pupils[1] + 5 >= woken,
            "{pupils:?} of {woken}"
        );
        assert!(gazes + 5 >= woken, "{gazes} of {woken}");
        client.shutdown().await;
        hub.request_shutdown();
        relay.join().await;
    }

    // One thread: the relay cannot wake between the test's sends.
    #[tokio::test(flavor = "current_thread")]
    async fn coalesced_updates_are_counted_and_unchanged_eyes_not_republished() {
        let (tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let relay = spawn(hub.clone(), loopback()).await.unwrap();
        let t0 = host_now_secs();
        let s = session_state(1, t0);
        // Three updates before the relay can wake: one wake, two coalesced.
        for k in 1..=3 {
            tx.send_replace(LiveEyeState {
                state: s,
                updated_host_secs: t0,
                updates: k,
            });
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
        let st = relay.stats();
        assert_eq!(st.coalesced_updates, 2);
        assert_eq!((st.pupil_published, st.gaze_published), (2, 1));
        // A gaze-only update: the eyes did not change, only the gaze goes out.
        let mut g = s;
        g.gaze_uv = [0.9, 0.1];
        g.t_secs = t0 + 0.004;
        tx.send_replace(LiveEyeState {
            state: g,
            updated_host_secs: t0,
            updates: 4,
        });
        tokio::time::sleep(Duration::from_millis(100)).await;
        let st = relay.stats();
        assert_eq!((st.pupil_published, st.gaze_published), (2, 2));
        // A pupil update of eye 1 alone.
        let mut p = g;
        p.eyes[1].measured = Some(5.5);
        tx.send_replace(LiveEyeState {
            state: p,
            updated_host_secs: t0,
            updates: 5,
        });
        tokio::time::sleep(Duration::from_millis(100)).await;
        let st = relay.stats();
        assert_eq!((st.pupil_published, st.gaze_published), (3, 2));
        assert_eq!(st.coalesced_updates, 2);
        hub.request_shutdown();
        relay.join().await;
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn adaptation_topic_carries_the_frame_figures() {
        let (_tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let relay = spawn(hub.clone(), loopback()).await.unwrap();
        let mut bus = SubSocket::new();
        bus.connect(&format!("tcp://127.0.0.1:{}", relay.sub_port()))
            .await
            .unwrap();
        bus.subscribe("gazelight.").await.unwrap();
        tokio::time::sleep(Duration::from_millis(200)).await;
        let frame = FrameFigures {
            frames: 17,
            t_secs: 0.19,
            pupil_mm: [4.25, 4.5],
            frame_pupil_mm: 4.375,
            adaptation_cd_m2: 12.5,
            target_cd_m2: 80.0,
            eye_state_age_ms: 3.25,
            pupil_light_mm: [3.5, 3.625],
            pupil_residual_mm: [0.75, f32::NAN],
        };
        hub.publish_frame(frame);
        let m = tokio::time::timeout(Duration::from_secs(2), bus.recv())
            .await
            .expect("adaptation datum")
            .unwrap();
        assert_eq!(m.get(0).unwrap().as_ref(), ADAPTATION_TOPIC.as_bytes());
        let v: serde_json::Value = rmp_serde::from_slice(m.get(1).unwrap()).unwrap();
        assert_eq!(v["adaptation_cd_m2"], 12.5);
        assert_eq!(v["target_cd_m2"], 80.0);
        assert_eq!(v["pupil_mm"], 4.375);
        assert_eq!(v["pupil_eye_mm"][1], 4.5);
        assert_eq!(v["frame"], 17);
        assert!(v["timestamp"].as_f64().unwrap() <= host_now_secs());
        // Then the pupil light response of the same frame.
        let m = tokio::time::timeout(Duration::from_secs(2), bus.recv())
            .await
            .expect("pupil light datum")
            .unwrap();
        assert_eq!(m.get(0).unwrap().as_ref(), PUPIL_LIGHT_TOPIC.as_bytes());
        let v: rmpv::Value = rmp_serde::from_slice(m.get(1).unwrap()).unwrap();
        let field = |k: &str| {
            v.as_map()
                .unwrap()
                .iter()
                .find(|(key, _)| key.as_str() == Some(k))
                .unwrap()
                .1
                .clone()
        };
        let arr = |k: &str| -> Vec<f64> {
            field(k)
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect()
        };
        assert_eq!(arr("pupil_light_mm"), [3.5, 3.625]);
        assert_eq!(arr("pupil_mm"), [4.25, 4.5]);
        let r = arr("pupil_residual_mm");
        assert_eq!(r[0], 0.75);
        assert!(r[1].is_nan(), "not measured: NaN");
        assert_eq!(field("frame").as_u64(), Some(17));
        // The same frame is not published twice.
        tokio::time::sleep(Duration::from_millis(100)).await;
        assert_eq!(relay.stats().adaptation_published, 1);
        assert_eq!(relay.stats().pupil_light_published, 1);
        hub.request_shutdown();
        relay.join().await;
    }

    /// Pupil Labs' official Python client (`pupil-core-network-client`)
    /// reads the relay: every pupil and gaze datum it receives carries the
    /// values of a state the session published, at that state's time, and
    /// `t` answers the clock of the datums.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn official_python_client_reads_pupil_and_gaze() {
        use std::io::BufRead;
        let (tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let relay = spawn(hub.clone(), loopback()).await.unwrap();
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/relay_client.py");
        let mut child = std::process::Command::new("python3")
            .arg(script)
            .args(["--port", &relay.local_addr().port().to_string()])
            .args(["--pupil", "200", "--gaze", "100", "--timeout", "20"])
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::inherit())
            .spawn()
            .expect("python3");
        let stdout = child.stdout.take().unwrap();
        let (line_tx, line_rx) = std::sync::mpsc::channel::<String>();
        std::thread::spawn(move || {
            for line in std::io::BufReader::new(stdout)
                .lines()
                .map_while(Result::ok)
            {
                if line_tx.send(line).is_err() {
                    break;
                }
            }
        });

        let mut fed: Vec<EyeState> = Vec::new();
        let mut lines: Vec<serde_json::Value> = Vec::new();
        let deadline = std::time::Instant::now() + Duration::from_secs(30);
        let mut k = 0u64;
        let mut ended = false;
        while !ended && std::time::Instant::now() < deadline {
            while let Ok(l) = line_rx.try_recv() {
                let v: serde_json::Value = serde_json::from_str(&l).unwrap();
                if v["kind"] == "error" {
                    panic!("relay_client.py: {}", v["error"]);
                }
                ended |= v["kind"] == "end";
                lines.push(v);
            }
            // Keep publishing until the client has what it wants.
            if lines.iter().any(|v| v["kind"] == "hello") {
                k += 1;
                let t = host_now_secs();
                let s = session_state(k, t);
                tx.send_replace(LiveEyeState {
                    state: s,
                    updated_host_secs: t,
                    updates: k,
                });
                fed.push(s);
            }
            tokio::time::sleep(Duration::from_millis(2)).await;
        }
        let status = child.wait().unwrap();
        assert!(status.success(), "relay_client.py: {status}; {lines:?}");

        let hello = &lines[0];
        assert_eq!(hello["kind"], "hello");
        assert_eq!(hello["sub_port"], relay.sub_port());
        assert_eq!(hello["pub_port"], relay.pub_port());
        let (mut n_pupil, mut n_gaze, mut max_ts) = (0, 0, f64::MIN);
        for v in lines.iter().filter(|v| v["kind"] == "datum") {
            let p = &v["payload"];
            let ts = p["timestamp"].as_f64().unwrap();
            max_ts = max_ts.max(ts);
            // serde_json parses floats to within an ulp: match to 1 ns.
            let state = fed
                .iter()
                .find(|s| (s.t_secs - ts).abs() < 1e-9)
                .unwrap_or_else(|| panic!("datum at {ts} matches no published state"));
            let close = |v: &serde_json::Value, want: f64| {
                let got = v.as_f64().unwrap();
                assert!(
                    (got - want).abs() <= 1e-12 * want.abs().max(1.0),
                    "{got} vs {want}"
                );
            };
            let topic = v["topic"].as_str().unwrap();
            assert_eq!(p["topic"], topic);
            if topic.starts_with("pupil.") {
                n_pupil += 1;
                let id = p["id"].as_u64().unwrap() as usize;
                assert_eq!(topic, PUPIL_TOPICS[id]);
                assert_eq!(p["method"], RELAY_METHOD);
                close(
                    &p["diameter_3d"],
                    f64::from(state.eyes[id].measured.unwrap_or(f32::NAN)),
                );
                close(&p["confidence"], f64::from(state.eyes[id].confidence));
            } else {
                assert_eq!(topic, GAZE_TOPIC);
                n_gaze += 1;
                let np = &p["norm_pos"];
                close(&np[0], f64::from(state.gaze_uv[0]));
                close(&np[1], 1.0 - f64::from(state.gaze_uv[1]));
                close(
                    &p["base_data"][1]["diameter_3d"],
                    f64::from(state.eyes[1].measured.unwrap_or(f32::NAN)),
                );
            }
        }
        assert!(
            n_pupil >= 200 && n_gaze >= 100,
            "{n_pupil} pupil, {n_gaze} gaze"
        );
        // `t` is the datums' clock: after the newest datum, not far after.
        let end = lines.iter().find(|v| v["kind"] == "end").unwrap();
        let t = end["t"].as_f64().unwrap();
        assert!(
            t >= max_ts && t - max_ts < 2.0,
            "t {t}, newest datum {max_ts}"
        );
        hub.request_shutdown();
        relay.join().await;
    }
}
