//! [`NeonSource`]: a live Neon as a [`SampleSource`].
//!
//! One task per source fetches `/api/status`, plays the gaze stream (and
//! the eye-events stream beside it, in a second task, when the phone lists
//! one) and turns each packet into samples on the host clock:
//!
//! - a binocular [`GazeSample`] (scene-camera px divided by the 1600×1200
//!   scene camera, origin top-left) — or one per eye from the 17-byte
//!   dual-monocular layout;
//! - with eye state (65/89/105 bytes) one [`PupilSample`] per eye in mm
//!   (eye 1 = left, eye 0 = right). Neon gives no pupil confidence, so it
//!   is derived from the eyelid aperture where the packet has one (0 at or
//!   below [`APERTURE_CLOSED_MM`], 1 at or above [`APERTURE_OPEN_MM`],
//!   linear between; the thresholds of the Neon recording importer), else
//!   1 for a finite positive diameter; 0 while the glasses are not worn;
//! - a [`BlinkEvent`] (both eyes) for each blink on `eye_events`.
//!
//! Times: a packet's phone time (its RTP timestamp through the latest
//! RTCP sender report, [`crate::rtp`]) goes to host time through the
//! source's [`SourceClock`], anchored at each connection on the Time Echo
//! offset (or on NTP when the phone offers none). The mapping checks every
//! packet's time against its arrival: a sender report that is 1e5 s off
//! moves the packets' times, which the mapping sees as a clock jump (and
//! the next, correct report as another one) after
//! [`gazelight_eye::clock::DEFAULT_JUMP_CONFIRM`]
//! packets, and a Time Echo answer that lies (the phone 1e6 s ahead, or in
//! 1970) is overruled by the packets' arrivals the same way, with a
//! warning. Blinks use the offset the gaze packets established.
//!
//! A malformed packet is one [`SourceError::Item`] naming the stream and
//! what is wrong; a lost connection is a [`SourceError::Disconnected`] and
//! the task reconnects (status, DESCRIBE, SETUP, PLAY) with a backoff of
//! `backoff_initial` doubling to `backoff_max`. A gaze stream without eye
//! state is reported as an item error every [`NO_EYE_STATE_REPORT_EVERY`]
//! packets telling to turn on "Compute eye state".

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::sync::mpsc;
use tokio::task::JoinHandle;

use crate::NeonError;
use crate::http::{direct_sensor, get_status, parse_status};
use crate::payload::{EyeEvent, GazeDatum, decode_eye_event, decode_gaze};
use crate::stream::{RtpStream, RtpTransport};
use gazelight_eye::clock::{
    ClockStats, SharedClockStats, SourceClock, SourceClockConfig, host_now_secs,
};
use gazelight_eye::sample::{
    BlinkEvent, DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample,
};
use gazelight_eye::source::{SampleSource, SourceError};

/// The Real-time API's HTTP port.
pub const DEFAULT_HTTP_PORT: u16 = 8080;
/// Neon's scene camera, px (gaze is reported in its pixels;
/// `gazelight_eye`'s one definition).
pub const SCENE_CAMERA_PX: [f32; 2] = gazelight_eye::sample::NEON_SCENE_CAMERA_PX;
/// Eyelid aperture at or below which an eye counts as closed (confidence
/// 0): open eyes in the Neon demo recording measure 5–9 mm, closed 0–0.5.
pub const APERTURE_CLOSED_MM: f32 = 1.0;
/// Eyelid aperture at or above which an eye counts as open (confidence 1).
pub const APERTURE_OPEN_MM: f32 = 3.0;
/// Gaze packets without eye state between two "turn on Compute eye state"
/// reports (1 s at 200 Hz).
pub const NO_EYE_STATE_REPORT_EVERY: u64 = 200;
/// Time Echo round trips per connection (their median is the offset).
pub const TIME_ECHOES: usize = 20;

/// Where and how to reach a Neon.
#[derive(Clone, Debug, PartialEq)]
pub struct NeonConfig {
    pub host: String,
    /// HTTP port of the Real-time API.
    pub port: u16,
    /// How the RTP media travel (TCP interleaved by default).
    pub transport: RtpTransport,
    /// Bound of every connect and request/reply.
    pub io_timeout: Duration,
    /// A gaze stream silent this long is lost.
    pub gaze_timeout: Duration,
    /// An eye-events stream silent this long is reconnected (Neon sends
    /// keepalive events).
    pub events_timeout: Duration,
    pub backoff_initial: Duration,
    pub backoff_max: Duration,
    /// Samples buffered for the consumer; more are dropped and counted.
    pub channel_capacity: usize,
    pub scene_camera_px: [f32; 2],
}

impl Default for NeonConfig {
    fn default() -> Self {
        Self {
            host: "127.0.0.1".to_owned(),
            port: DEFAULT_HTTP_PORT,
            transport: RtpTransport::Tcp,
            io_timeout: Duration::from_secs(3),
            gaze_timeout: Duration::from_secs(2),
            events_timeout: Duration::from_secs(15),
            backoff_initial: Duration::from_millis(200),
            backoff_max: Duration::from_secs(2),
            channel_capacity: 8192,
            scene_camera_px: SCENE_CAMERA_PX,
        }
    }
}

/// Counters of a running source.
#[derive(Debug, Default)]
pub struct NeonStats {
    connected: AtomicBool,
    connections: AtomicU64,
    losses: AtomicU64,
    gaze_packets: AtomicU64,
    malformed: AtomicU64,
    no_eye_state: AtomicU64,
    blinks: AtomicU64,
    dropped_full: AtomicU64,
    clock_rate_hz: AtomicU64,
    /// The Time Echo offset, ms, as f64 bits, once measured.
    time_echo_offset_ms_bits: AtomicU64,
    time_echo_measured: AtomicBool,
    /// The clock mapping's counters.
    clock: Arc<SharedClockStats>,
    last_error: Mutex<Option<String>>,
}

/// A copy of [`NeonStats`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NeonStatsSnapshot {
    pub connected: bool,
    /// Gaze streams played.
    pub connections: u64,
    /// Gaze streams lost.
    pub losses: u64,
    pub gaze_packets: u64,
    /// Malformed packets skipped (both streams).
    pub malformed: u64,
    /// Gaze packets without eye state (no pupil).
    pub no_eye_state: u64,
    pub blinks: u64,
    /// Samples dropped because the consumer lagged.
    pub dropped_full: u64,
    /// The gaze stream's SDP clock rate (0 before the first connection).
    pub clock_rate_hz: u64,
    /// Host clock − phone clock by Time Echo, ms (`None`: the phone offers
    /// no Time Echo port, or it failed; NTP is trusted then).
    pub time_echo_offset_ms: Option<f64>,
    /// The clock mapping: packets mapped, time stamps dropped, jumps.
    pub clock: ClockStats,
    pub last_error: Option<String>,
}

impl NeonStats {
    /// A consistent-enough copy of the counters.
    pub fn snapshot(&self) -> NeonStatsSnapshot {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        NeonStatsSnapshot {
            connected: self.connected.load(Ordering::Relaxed),
            connections: l(&self.connections),
            losses: l(&self.losses),
            gaze_packets: l(&self.gaze_packets),
            malformed: l(&self.malformed),
            no_eye_state: l(&self.no_eye_state),
            blinks: l(&self.blinks),
            dropped_full: l(&self.dropped_full),
            clock_rate_hz: l(&self.clock_rate_hz),
            time_echo_offset_ms: self
                .time_echo_measured
                .load(Ordering::Relaxed)
                .then(|| f64::from_bits(l(&self.time_echo_offset_ms_bits))),
            clock: self.clock.snapshot(),
            last_error: self.last_error.lock().map(|e| e.clone()).unwrap_or(None),
        }
    }

    fn set_error(&self, e: String) {
        if let Ok(mut g) = self.last_error.lock() {
            *g = Some(e);
        }
    }
}

/// What the task hands the source.
#[derive(Debug)]
enum Event {
    Sample(Sample),
    Bad(String),
    Lost(String),
}

/// Aborts a task when dropped.
struct AbortOnDrop(JoinHandle<()>);

impl Drop for AbortOnDrop {
    fn drop(&mut self) {
        self.0.abort();
    }
}

/// A live Neon. The task starts on the first [`SampleSource::next`] (so
/// the source can be built outside a runtime) and stops when the source is
/// dropped.
pub struct NeonSource {
    config: NeonConfig,
    stats: Arc<NeonStats>,
    rx: Option<mpsc::Receiver<Event>>,
    task: Option<AbortOnDrop>,
    bad_items: u64,
}

impl NeonSource {
    pub fn new(config: NeonConfig) -> Self {
        Self {
            config,
            stats: Arc::new(NeonStats::default()),
            rx: None,
            task: None,
            bad_items: 0,
        }
    }

    /// The source's counters.
    pub fn stats(&self) -> Arc<NeonStats> {
        self.stats.clone()
    }

    pub fn config(&self) -> &NeonConfig {
        &self.config
    }
}

impl SampleSource for NeonSource {
    async fn next(&mut self) -> Result<Option<Sample>, SourceError> {
        if self.rx.is_none() {
            let (tx, rx) = mpsc::channel(self.config.channel_capacity.max(16));
            let handle = tokio::spawn(run(self.config.clone(), tx, self.stats.clone()));
            self.rx = Some(rx);
            self.task = Some(AbortOnDrop(handle));
        }
        let source_name = self.describe();
        let Some(rx) = self.rx.as_mut() else {
            return Err(SourceError::Fatal {
                source_name,
                reason: "no receiver".to_owned(),
            });
        };
        match rx.recv().await {
            Some(Event::Sample(s)) => Ok(Some(s)),
            Some(Event::Bad(reason)) => {
                self.bad_items += 1;
                Err(SourceError::Item {
                    source_name,
                    index: self.bad_items,
                    error: reason.into(),
                })
            }
            Some(Event::Lost(reason)) => Err(SourceError::Disconnected {
                source_name,
                reason,
            }),
            None => Err(SourceError::Fatal {
                source_name,
                reason: "Neon task stopped".to_owned(),
            }),
        }
    }

    fn describe(&self) -> String {
        format!("neon://{}:{}", self.config.host, self.config.port)
    }

    fn dropped(&self) -> u64 {
        self.stats.dropped_full.load(Ordering::Relaxed)
    }

    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        Some(self.stats.clock.clone())
    }
}

/// Unix time now, seconds (0 if the system clock is before 1970).
fn unix_now_secs() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map(|d| d.as_secs_f64())
        .unwrap_or(0.0)
}

fn send(tx: &mpsc::Sender<Event>, stats: &NeonStats, ev: Event) {
    if tx.try_send(ev).is_err() {
        stats.dropped_full.fetch_add(1, Ordering::Relaxed);
    }
}

async fn run(cfg: NeonConfig, tx: mpsc::Sender<Event>, stats: Arc<NeonStats>) {
    let mut backoff = cfg.backoff_initial;
    let mut clock = SourceClock::with_stats(
        format!("neon://{}:{}", cfg.host, cfg.port),
        SourceClockConfig::default(),
        stats.clock.clone(),
    );
    loop {
        let mut delivered = false;
        let err = session(&cfg, &tx, &stats, &mut clock, &mut delivered).await;
        if tx.is_closed() {
            return;
        }
        stats.connected.store(false, Ordering::Relaxed);
        stats.losses.fetch_add(1, Ordering::Relaxed);
        let reason = err.to_string();
        tracing::warn!(host = %cfg.host, port = cfg.port, "Neon stream lost or not established: {reason}");
        stats.set_error(reason.clone());
        send(&tx, &stats, Event::Lost(reason));
        if delivered {
            backoff = cfg.backoff_initial;
        }
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(cfg.backoff_max);
    }
}

/// One connection: runs until the gaze stream is lost; returns why.
async fn session(
    cfg: &NeonConfig,
    tx: &mpsc::Sender<Event>,
    stats: &Arc<NeonStats>,
    clock: &mut SourceClock,
    delivered: &mut bool,
) -> NeonError {
    let r: Result<std::convert::Infallible, NeonError> = async {
        let body = get_status(&cfg.host, cfg.port, cfg.io_timeout).await?;
        let sensors = parse_status(&body)?;
        // The phone's clock against ours (Time Echo), else trust NTP.
        let mut time_echo = false;
        let offset_secs = match crate::http::time_echo_port(&body) {
            Some(port) => match crate::time_echo::estimate_offset(
                &cfg.host,
                port,
                TIME_ECHOES,
                cfg.io_timeout,
            )
            .await
            {
                Ok(e) => {
                    tracing::info!(
                        offset_ms = e.offset_ms,
                        roundtrip_ms = e.roundtrip_ms,
                        echoes = e.echoes,
                        "Neon clock offset (Time Echo): phone time + offset = host time"
                    );
                    stats
                        .time_echo_offset_ms_bits
                        .store(e.offset_ms.to_bits(), Ordering::Relaxed);
                    stats.time_echo_measured.store(true, Ordering::Relaxed);
                    time_echo = true;
                    e.offset_ms * 1e-3
                }
                Err(e) => {
                    tracing::warn!(error = %e, "Time Echo failed; assuming the phone's clock follows NTP as ours does");
                    0.0
                }
            },
            None => 0.0,
        };
        let gaze = direct_sensor(&sensors, "gaze").ok_or_else(|| NeonError::Status {
            reason: format!(
                "http://{}:{}/api/status lists no DIRECT gaze sensor",
                cfg.host, cfg.port
            ),
        })?;
        let url = gaze.url().ok_or_else(|| NeonError::Status {
            reason: format!(
                "the gaze sensor is not connected (connected={}, ip={:?}, port={:?}): \
                 is the Neon module plugged into the phone?",
                gaze.connected, gaze.ip, gaze.port
            ),
        })?;
        let events_url = direct_sensor(&sensors, "eye_events").and_then(|s| s.url());
        let mut stream = RtpStream::open_with(&url, cfg.transport, cfg.io_timeout, cfg.gaze_timeout).await?;
        stats
            .clock_rate_hz
            .store(u64::from(stream.clock_rate_hz()), Ordering::Relaxed);
        stats.connections.fetch_add(1, Ordering::Relaxed);
        stats.connected.store(true, Ordering::Relaxed);
        tracing::info!(%url, clock_rate_hz = stream.clock_rate_hz(), "Neon gaze stream playing");
        // The phone's Unix time − host time; a sample's host time = its Unix
        // time − this (phone time + offset = our Unix time). The mapping
        // holds host − phone time, and checks it against every packet.
        let unix_minus_host = unix_now_secs() - offset_secs - host_now_secs();
        clock.reset();
        clock.anchor(-unix_minus_host, host_now_secs());
        // The offset the gaze packets establish, for the blinks (f64 bits).
        let host_minus_phone = Arc::new(AtomicU64::new((-unix_minus_host).to_bits()));
        let _events = events_url.map(|u| {
            AbortOnDrop(tokio::spawn(events_loop(
                u,
                cfg.clone(),
                tx.clone(),
                stats.clone(),
                host_minus_phone.clone(),
            )))
        });
        let jumps_at_start = clock.stats().jumps;
        let mut no_eye_state_run = 0u64;
        let mut out = [None; 3];
        loop {
            let packet = match stream.next_packet().await {
                Ok(p) => p,
                Err(e @ NeonError::Packet { .. }) => {
                    stats.malformed.fetch_add(1, Ordering::Relaxed);
                    send(tx, stats, Event::Bad(format!("{url}: {e}")));
                    continue;
                }
                Err(e) => return Err(e),
            };
            let arrival = host_now_secs();
            let Some(t_host) = clock.to_host(packet.unix_secs, arrival) else {
                // Dropped and counted by the mapping (an absurd time, or
                // the first packets of a clock jump).
                continue;
            };
            if let Some(o) = clock.offset_secs() {
                host_minus_phone.store(o.to_bits(), Ordering::Relaxed);
            }
            if time_echo && !*delivered && clock.stats().jumps > jumps_at_start {
                // The first packets of the connection already jumped: the
                // Time Echo answer was wrong.
                time_echo = false;
                tracing::warn!(
                    host = %cfg.host,
                    time_echo_offset_ms = offset_secs * 1e3,
                    step_s = clock.stats().last_jump_secs,
                    "the phone's packets disagree with its Time Echo answer: their arrival times \
                     are used instead"
                );
            }
            let datum = match decode_gaze(packet.payload) {
                Ok(d) => d,
                Err(e) => {
                    stats.malformed.fetch_add(1, Ordering::Relaxed);
                    let seq = packet.sequence;
                    send(tx, stats, Event::Bad(format!("{url}: RTP seq {seq}: {e}")));
                    continue;
                }
            };
            stats.gaze_packets.fetch_add(1, Ordering::Relaxed);
            *delivered = true;
            if datum.eye_state.is_none() {
                no_eye_state_run += 1;
                stats.no_eye_state.fetch_add(1, Ordering::Relaxed);
                if no_eye_state_run.is_multiple_of(NO_EYE_STATE_REPORT_EVERY) {
                    send(
                        tx,
                        stats,
                        Event::Bad(format!(
                            "{url}: {no_eye_state_run} gaze packets of {} bytes carry no pupil \
                             diameter: turn on \"Compute eye state\" in the Neon Companion app",
                            datum.len
                        )),
                    );
                }
            } else {
                no_eye_state_run = 0;
            }
            let n = gaze_samples(&datum, t_host, cfg.scene_camera_px, &mut out);
            for s in out.iter_mut().take(n) {
                if let Some(s) = s.take() {
                    send(tx, stats, Event::Sample(s));
                }
            }
        }
    }
    .await;
    match r {
        Err(e) => e,
        Ok(never) => match never {},
    }
}

/// The longest blink event taken as it is, s (a longer one is cut).
const MAX_BLINK_SECS: f64 = 10.0;

/// Host times of a blink from `start_ns` to `end_ns` on the phone's clock,
/// reported at host time `arrival`: mapped by the gaze stream's offset
/// `host − phone` (s); an end not within [`MAX_BLINK_SECS`] before its
/// arrival (the offset is not yet known, or the event's times are absurd)
/// is taken as the arrival.
fn blink_host_secs(start_ns: i64, end_ns: i64, host_minus_phone: f64, arrival: f64) -> (f64, f64) {
    let duration = ((end_ns as f64 - start_ns as f64) * 1e-9).clamp(0.0, MAX_BLINK_SECS);
    let end = end_ns as f64 * 1e-9 + host_minus_phone;
    let end = if (arrival - MAX_BLINK_SECS..=arrival).contains(&end) {
        end
    } else {
        arrival
    };
    (end - duration, end)
}

/// Plays `eye_events` until the gaze session ends (the caller aborts this
/// task), reconnecting on loss.
async fn events_loop(
    url: String,
    cfg: NeonConfig,
    tx: mpsc::Sender<Event>,
    stats: Arc<NeonStats>,
    host_minus_phone: Arc<AtomicU64>,
) {
    let mut backoff = cfg.backoff_initial;
    loop {
        let err =
            match RtpStream::open_with(&url, cfg.transport, cfg.io_timeout, cfg.events_timeout)
                .await
            {
                Err(e) => e,
                Ok(mut stream) => loop {
                    let p = match stream.next_packet().await {
                        Ok(p) => p,
                        Err(e @ NeonError::Packet { .. }) => {
                            stats.malformed.fetch_add(1, Ordering::Relaxed);
                            send(&tx, &stats, Event::Bad(format!("{url}: {e}")));
                            continue;
                        }
                        Err(e) => break e,
                    };
                    backoff = cfg.backoff_initial;
                    match decode_eye_event(p.payload) {
                        Ok(EyeEvent::Blink { start_ns, end_ns }) => {
                            stats.blinks.fetch_add(1, Ordering::Relaxed);
                            let (start_t_secs, end_t_secs) = blink_host_secs(
                                start_ns,
                                end_ns,
                                f64::from_bits(host_minus_phone.load(Ordering::Relaxed)),
                                host_now_secs(),
                            );
                            send(
                                &tx,
                                &stats,
                                Event::Sample(Sample::Blink(BlinkEvent {
                                    start_t_secs,
                                    end_t_secs,
                                    eye: None,
                                })),
                            );
                        }
                        Ok(_) => {}
                        Err(e) => {
                            stats.malformed.fetch_add(1, Ordering::Relaxed);
                            let seq = p.sequence;
                            send(
                                &tx,
                                &stats,
                                Event::Bad(format!("{url}: RTP seq {seq}: {e}")),
                            );
                        }
                    }
                },
            };
        tracing::warn!(%url, "Neon eye events lost: {err}; retrying");
        tokio::time::sleep(backoff).await;
        backoff = (backoff * 2).min(cfg.backoff_max);
    }
}

/// Pupil confidence from the eyelid aperture (mm).
pub fn aperture_confidence(aperture_mm: f32) -> f32 {
    if !aperture_mm.is_finite() {
        return 0.0;
    }
    ((aperture_mm - APERTURE_CLOSED_MM) / (APERTURE_OPEN_MM - APERTURE_CLOSED_MM)).clamp(0.0, 1.0)
}

/// The samples of one gaze packet at host time `t_secs`, written to `out`
/// (no allocation); returns how many.
pub fn gaze_samples(
    d: &GazeDatum,
    t_secs: f64,
    scene_px: [f32; 2],
    out: &mut [Option<Sample>; 3],
) -> usize {
    let worn = d.worn();
    let norm = |p: [f32; 2]| [p[0] / scene_px[0], p[1] / scene_px[1]];
    let gaze_conf = |p: [f32; 2]| {
        if worn && p[0].is_finite() && p[1].is_finite() {
            1.0
        } else {
            0.0
        }
    };
    let mut n = 0;
    let mut push = |s: Sample| {
        if n < out.len() {
            out[n] = Some(s);
            n += 1;
        }
    };
    match (d.gaze_px, d.monocular_px) {
        (Some(g), _) => push(Sample::Gaze(GazeSample {
            t_secs,
            gaze_uv: norm(g),
            confidence: gaze_conf(g),
            eyes: GazeEyes::Binocular,
        })),
        (None, Some([l, r])) => {
            for (p, eyes) in [(l, GazeEyes::Left), (r, GazeEyes::Right)] {
                push(Sample::Gaze(GazeSample {
                    t_secs,
                    gaze_uv: norm(p),
                    confidence: gaze_conf(p),
                    eyes,
                }));
            }
        }
        (None, None) => {}
    }
    if let Some(states) = d.eye_state {
        // Payload order is [left, right]; gazelight's eye 1 = left, 0 = right.
        for (i, eye) in [(0usize, 1u8), (1, 0)] {
            let mm = states[i].pupil_diameter_mm;
            let confidence = if !(worn && mm.is_finite() && mm > 0.0) {
                0.0
            } else if let Some(lids) = d.eyelid {
                aperture_confidence(lids[i].aperture_mm)
            } else {
                1.0
            };
            push(Sample::Pupil(PupilSample {
                t_secs,
                eye,
                diameter_raw: mm,
                unit: PupilUnit::Mm,
                diameter_mm: Some(mm),
                confidence,
                norm_pos: [f32::NAN, f32::NAN],
                method: DetectorMethod::Other,
            }));
        }
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_eye_and_not_worn_have_zero_confidence() {
        assert_eq!(aperture_confidence(0.0), 0.0);
        assert_eq!(aperture_confidence(2.0), 0.5);
        assert_eq!(aperture_confidence(8.0), 1.0);
        assert_eq!(aperture_confidence(f32::NAN), 0.0);
    }
}
