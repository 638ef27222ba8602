//! The source side of a live session: one function dispatches a source URI
//! ([`open_source`]) and one generic task ([`spawn_source_task`]) runs any
//! [`SampleSource`] through the filter chain into the [`Hub`].
//!
//! - `pupil://HOST:PORT` — Pupil Capture / Service through
//!   [`PupilClient::spawn_filtered`]: the client task filters inline and
//!   publishes the `EyeState` itself; a companion task forwards the decoded
//!   samples to the hub's broadcast, keeps the rate/confidence/dropout
//!   window, polls the client's counters (connected → Live, lost → Lost
//!   with the reason) and feeds the frame loop's adaptation luminance back
//!   to the chain.
//! - `replay://PATH[?speed=S]` — any recording `import::open` reads, paced
//!   on the real clock by [`ReplaySource`].
//! - `synthetic://demo` — the demo's keyframed trace, looped, paced on the
//!   real clock.
//!
//! Other schemes plug into [`open_source`] and reuse [`spawn_source_task`].

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use anyhow::{Context, bail};
use gazelight_tracker::filter::{ConfidenceGate, FilterChain};
use gazelight_tracker::import;
use gazelight_tracker::pupil::clock::host_now_secs;
use gazelight_tracker::pupil::{LiveEyeState, PupilClient, PupilConfig};
use gazelight_tracker::transport::{self, SourceUri};
use gazelight_tracker::{
    DetectorMethod, EYE_LEFT, EYE_RIGHT, GazeEyes, GazeSample, Pacing, PupilSample, PupilUnit,
    ReplaySource, Sample, SampleSource, SourceError, TraceSample,
};
use gazelight_vision::RgbImage;
use gazelight_vision::scene::ViewParams;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::demo;
use crate::hub::{Hub, SourceHealth};

/// How often source figures are published to the hub.
const STATUS_PERIOD: Duration = Duration::from_millis(250);
/// How often the adaptation luminance is forwarded to a Pupil client.
const FEEDBACK_PERIOD: Duration = Duration::from_millis(100);
/// A source silent this long is reported Lost.
const SILENT_LOST_SECS: f64 = 1.0;
/// With no Pupil Capture answering within this time, say so.
const NO_TRACKER_AFTER: Duration = Duration::from_millis(1500);

/// Which clock the `EyeState`'s age is measured on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AgeClock {
    /// `EyeState::t_secs` is host time (live sources that align clocks):
    /// age = now − time of the newest sample, transport included.
    SampleTime,
    /// The state's times are on a recording's clock: age = now − when the
    /// source task published it.
    PublishTime,
}

/// The adaptation luminance the frame loop feeds back to the filter chain
/// (cd/m², stored as `f64` bits; NaN = none yet). Lock-free, no allocation.
#[derive(Debug)]
pub struct AdaptationCell(AtomicU64);

impl Default for AdaptationCell {
    fn default() -> Self {
        Self(AtomicU64::new(f64::NAN.to_bits()))
    }
}

impl AdaptationCell {
    /// Stores the newest adaptation luminance.
    pub fn set(&self, luminance_cd_m2: f64) {
        self.0.store(luminance_cd_m2.to_bits(), Ordering::Relaxed);
    }

    /// The newest value, if any.
    pub fn get(&self) -> Option<f64> {
        let v = f64::from_bits(self.0.load(Ordering::Relaxed));
        v.is_finite().then_some(v)
    }
}

/// A running source: the hub it feeds and the tasks behind it.
pub struct SourceHandle {
    pub hub: Arc<Hub>,
    pub age_clock: AgeClock,
    pub adaptation: Arc<AdaptationCell>,
    pub tasks: Vec<JoinHandle<()>>,
    /// One line for the log.
    pub describe: String,
}

/// What a synthetic source needs from the session: the view it runs on.
pub struct DemoContext<'a> {
    pub view: &'a ViewParams,
    pub view_img: &'a RgbImage,
}

/// Opens the source named by `uri` and starts its task(s). Must be called
/// inside a tokio runtime. The one place URI schemes are dispatched.
#[allow(dead_code)] // `run` calls open_source_with (for [lsl]); kept for other callers
pub fn open_source(
    uri: &str,
    chain: FilterChain,
    demo_ctx: &DemoContext<'_>,
) -> anyhow::Result<SourceHandle> {
    open_source_with(
        uri,
        chain,
        demo_ctx,
        &gazelight_tracker::lsl::LslConfig::default(),
    )
}

/// [`open_source`] with the session's `[lsl]` settings (used by `lsl://`).
pub fn open_source_with(
    uri: &str,
    chain: FilterChain,
    demo_ctx: &DemoContext<'_>,
    lsl: &gazelight_tracker::lsl::LslConfig,
) -> anyhow::Result<SourceHandle> {
    let adaptation = Arc::new(AdaptationCell::default());
    let (scheme, rest) = uri
        .split_once("://")
        .ok_or_else(|| anyhow::anyhow!("source `{uri}`: expected SCHEME://…, e.g. pupil://127.0.0.1:50020, replay://PATH, synthetic://demo"))?;
    match scheme {
        "pupil" | "tcp" => {
            let config = PupilConfig::from_uri(uri).with_context(|| format!("source `{uri}`"))?;
            let gate = chain.config().confidence;
            let endpoint = format!("{}:{}", config.host, config.remote_port);
            let (client, streams, eye_rx) = PupilClient::spawn_filtered(config, chain);
            let hub = Hub::new(uri, eye_rx);
            let task = tokio::spawn(pupil_companion(
                client,
                streams.samples,
                gate,
                hub.clone(),
                adaptation.clone(),
                endpoint.clone(),
            ));
            Ok(SourceHandle {
                hub,
                age_clock: AgeClock::SampleTime,
                adaptation,
                tasks: vec![task],
                describe: format!("Pupil Capture at {endpoint}"),
            })
        }
        "replay" => {
            let (path, speed) = parse_replay(uri, rest)?;
            let importer = import::open(&path)
                .with_context(|| format!("source `{uri}`: cannot open the recording"))?;
            let format = importer.format();
            let source = ReplaySource::new(
                path.display().to_string(),
                importer,
                Pacing::Scaled { speed },
            );
            let describe = format!("{} ({format})", source.describe());
            let (hub, task) = start_generic(uri, source, chain, adaptation.clone());
            Ok(SourceHandle {
                hub,
                age_clock: AgeClock::PublishTime,
                adaptation,
                tasks: vec![task],
                describe,
            })
        }
        "synthetic" => {
            if rest != "demo" {
                bail!("source `{uri}`: the only synthetic source is synthetic://demo");
            }
            let trace = demo::demo_trace(demo_ctx.view, demo_ctx.view_img)
                .with_context(|| format!("source `{uri}`"))?;
            let samples = DemoSamples::new(trace.samples, demo::DEMO_SECS);
            let source = ReplaySource::new(
                "synthetic demo (looped)",
                samples,
                Pacing::Scaled { speed: 1.0 },
            );
            let describe = source.describe();
            let (hub, task) = start_generic(uri, source, chain, adaptation.clone());
            Ok(SourceHandle {
                hub,
                age_clock: AgeClock::PublishTime,
                adaptation,
                tasks: vec![task],
                describe,
            })
        }
        // Hardware transports of the tracker crate: HID, raw USB, serial,
        // the Gazepoint Open Gaze API. They go through the same generic
        // task (filter chain → hub) as a replay, on the host clock.
        "hid" | "usb" | "serial" | "gazepoint" => {
            let parsed =
                SourceUri::parse(uri).map_err(|e| anyhow::anyhow!("source `{uri}`: {e}"))?;
            let source = transport::open(&parsed).with_context(|| format!("source `{uri}`"))?;
            let describe = source.describe();
            let (hub, task) = start_generic(uri, source, chain, adaptation.clone());
            Ok(SourceHandle {
                hub,
                age_clock: AgeClock::PublishTime,
                adaptation,
                tasks: vec![task],
                describe,
            })
        }
        // An LSL stream (`lsl://?name=…`, `lsl://?type=…`): its timestamps
        // are mapped onto the host clock (time correction), so the age is
        // measured from the sample time.
        "lsl" => {
            let query = gazelight_tracker::lsl::LslQuery::parse(uri)
                .map_err(|e| anyhow::anyhow!("source {e}"))?;
            let source = gazelight_tracker::lsl::LslSource::new(query, lsl.clone())
                .with_context(|| format!("source `{uri}`"))?;
            let describe = source.describe();
            let (hub, task) = start_generic(uri, source, chain, adaptation.clone());
            Ok(SourceHandle {
                hub,
                age_clock: AgeClock::SampleTime,
                adaptation,
                tasks: vec![task],
                describe,
            })
        }
        other => bail!(
            "source `{uri}`: unknown scheme `{other}` (expected pupil://, replay://, synthetic://, \
             hid://, usb://, serial://, gazepoint:// or lsl://)"
        ),
    }
}

/// `replay://PATH[?speed=S]` → (path, speed).
fn parse_replay(uri: &str, rest: &str) -> anyhow::Result<(PathBuf, f64)> {
    let (path, query) = match rest.split_once('?') {
        Some((p, q)) => (p, Some(q)),
        None => (rest, None),
    };
    if path.is_empty() {
        bail!("source `{uri}`: expected replay://PATH[?speed=S]");
    }
    let mut speed = 1.0;
    if let Some(q) = query {
        for kv in q.split('&') {
            match kv.split_once('=') {
                Some(("speed", v)) => {
                    speed = v
                        .parse::<f64>()
                        .ok()
                        .filter(|s| s.is_finite() && *s > 0.0 && *s <= 1000.0)
                        .ok_or_else(|| {
                            anyhow::anyhow!(
                                "source `{uri}`: speed `{v}`: expected a number 0 < speed ≤ 1000"
                            )
                        })?;
                }
                _ => bail!("source `{uri}`: unknown parameter `{kv}` (only speed=S)"),
            }
        }
    }
    Ok((Path::new(path).to_path_buf(), speed))
}

fn start_generic<S: SampleSource + 'static>(
    uri: &str,
    source: S,
    chain: FilterChain,
    adaptation: Arc<AdaptationCell>,
) -> (Arc<Hub>, JoinHandle<()>) {
    let (eye_tx, eye_rx) = watch::channel(LiveEyeState {
        state: *chain.state(),
        updated_host_secs: host_now_secs(),
        updates: 0,
    });
    let hub = Hub::new(uri, eye_rx);
    let task = spawn_source_task(source, chain, eye_tx, hub.clone(), adaptation);
    (hub, task)
}

/// Rate, confidence and dropout over a window of about a second.
#[derive(Debug, Default)]
struct RateWindow {
    start_secs: f64,
    samples: u64,
    confidence_sum: f64,
    pupil: u64,
    pupil_dropped: u64,
    last_sample_secs: Option<f64>,
}

impl RateWindow {
    fn new(now: f64) -> Self {
        Self {
            start_secs: now,
            ..Self::default()
        }
    }

    fn add(&mut self, now: f64, confidence: f32, pupil_dropped: Option<bool>) {
        self.samples += 1;
        if confidence.is_finite() {
            self.confidence_sum += f64::from(confidence.clamp(0.0, 1.0));
        }
        if let Some(d) = pupil_dropped {
            self.pupil += 1;
            self.pupil_dropped += u64::from(d);
        }
        self.last_sample_secs = Some(now);
    }

    /// Publishes the window into the hub when it has run ≥ 1 s (then
    /// restarts it); always updates the running total.
    fn publish(&mut self, now: f64, hub: &Hub, total: u64) {
        let elapsed = now - self.start_secs;
        let full = elapsed >= 1.0;
        let (samples, conf, pupil, dropped) = (
            self.samples,
            self.confidence_sum,
            self.pupil,
            self.pupil_dropped,
        );
        hub.update_source(|s| {
            s.samples_total = total;
            if full {
                s.sample_rate_hz = samples as f64 / elapsed;
                s.confidence = if samples > 0 {
                    conf / samples as f64
                } else {
                    0.0
                };
                s.dropout_rate = if pupil > 0 {
                    dropped as f64 / pupil as f64
                } else if samples == 0 {
                    1.0
                } else {
                    0.0
                };
            }
        });
        if full {
            let last = self.last_sample_secs;
            *self = Self::new(now);
            self.last_sample_secs = last;
        }
    }

    fn silent_for(&self, now: f64) -> Option<f64> {
        self.last_sample_secs.map(|t| now - t)
    }
}

fn sample_confidence(s: &Sample) -> f32 {
    match s {
        Sample::Pupil(p) => p.confidence,
        Sample::Gaze(g) => g.confidence,
        Sample::Blink(_) => f32::NAN,
    }
}

/// Runs `source` through `chain`: every sample is filtered, the new
/// `EyeState` is published on `eye_tx` (the frame loop reads it with
/// `borrow()`), the sample goes to the hub's bounded broadcast (never
/// blocks; a lagging receiver loses the oldest), and the source status
/// (rate, confidence, dropout rate, health) is kept current. The
/// adaptation luminance the frame loop stores in `adaptation` is fed to the
/// chain before each sample. Ends at the end of the stream (health
/// `Ended`), on a fatal error (health `Lost`) or on the hub's shutdown.
pub fn spawn_source_task<S: SampleSource + 'static>(
    mut source: S,
    mut chain: FilterChain,
    eye_tx: watch::Sender<LiveEyeState>,
    hub: Arc<Hub>,
    adaptation: Arc<AdaptationCell>,
) -> JoinHandle<()> {
    tokio::spawn(async move {
        let mut shutdown = hub.shutdown_signal();
        let mut tick = tokio::time::interval(STATUS_PERIOD);
        tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
        let mut window = RateWindow::new(host_now_secs());
        let mut updates = 0u64;
        let mut item_errors = 0u64;
        let mut last_luminance = None;
        let mut live = false;
        let describe = source.describe();
        tracing::info!(source = %describe, "source started");
        loop {
            if *shutdown.borrow() {
                break;
            }
            let next = source.next();
            tokio::pin!(next);
            let result = loop {
                tokio::select! {
                    r = &mut next => break Some(r),
                    _ = shutdown.changed() => break None,
                    _ = tick.tick() => {
                        let now = host_now_secs();
                        window.publish(now, &hub, updates);
                        if let Some(silent) = window.silent_for(now)
                            && silent > SILENT_LOST_SECS
                            && live
                        {
                            live = false;
                            tracing::warn!(source = %describe, "no samples for {silent:.1} s: source lost; frames continue");
                            hub.update_source(|s| {
                                s.health = SourceHealth::Lost;
                                s.last_error = Some(format!("no samples for {silent:.1} s"));
                            });
                        }
                    }
                }
            };
            let Some(result) = result else { break };
            match result {
                Ok(Some(sample)) => {
                    if let Some(l) = adaptation.get()
                        && last_luminance != Some(l)
                    {
                        chain.set_adaptation_luminance(l);
                        last_luminance = Some(l);
                    }
                    let up = chain.push(&sample);
                    updates += 1;
                    let now = host_now_secs();
                    eye_tx.send_replace(LiveEyeState {
                        state: up.state,
                        updated_host_secs: now,
                        updates,
                    });
                    window.add(
                        now,
                        sample_confidence(&sample),
                        up.pupil_eye.map(|_| !up.measured),
                    );
                    // No receiver is fine; a full ring drops its oldest.
                    let _ = hub.samples.send(sample);
                    if !live {
                        live = true;
                        tracing::info!(source = %describe, "source live");
                        hub.update_source(|s| s.health = SourceHealth::Live);
                    }
                }
                Ok(None) => {
                    window.publish(host_now_secs(), &hub, updates);
                    tracing::info!(source = %describe, samples = updates, "source ended; frames continue with the last state");
                    hub.update_source(|s| s.health = SourceHealth::Ended);
                    break;
                }
                Err(e @ SourceError::Item { .. }) => {
                    item_errors += 1;
                    if item_errors <= 10 {
                        tracing::warn!(error = %e, "skipped a bad item");
                    }
                }
                Err(SourceError::Disconnected { reason, .. }) => {
                    let was_live = std::mem::replace(&mut live, false);
                    hub.update_source(|s| {
                        if was_live {
                            s.reconnects += 1;
                        }
                        s.health = SourceHealth::Lost;
                        s.last_error = Some(reason.clone());
                    });
                    tokio::time::sleep(Duration::from_millis(50)).await;
                }
                Err(SourceError::Fatal { reason, .. }) => {
                    tracing::error!(source = %describe, "source failed: {reason}; frames continue");
                    hub.update_source(|s| {
                        s.health = SourceHealth::Lost;
                        s.last_error = Some(reason);
                    });
                    break;
                }
            }
        }
    })
}

/// The companion of a filtering [`PupilClient`]: forwards the decoded
/// samples to the hub (and counts them), publishes the client's health and
/// feeds the adaptation luminance back to the inline chain.
async fn pupil_companion(
    client: PupilClient,
    mut samples: tokio::sync::mpsc::Receiver<Sample>,
    gate: ConfidenceGate,
    hub: Arc<Hub>,
    adaptation: Arc<AdaptationCell>,
    endpoint: String,
) {
    let mut shutdown = hub.shutdown_signal();
    let mut status_tick = tokio::time::interval(STATUS_PERIOD);
    let mut feedback_tick = tokio::time::interval(FEEDBACK_PERIOD);
    status_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    feedback_tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let started = tokio::time::Instant::now();
    let mut window = RateWindow::new(host_now_secs());
    let mut total = 0u64;
    let mut ever_connected = false;
    let mut said_absent = false;
    let mut last_luminance = None;
    let mut was_live = false;
    loop {
        tokio::select! {
            _ = shutdown.changed() => break,
            s = samples.recv() => {
                let Some(sample) = s else { break };
                total += 1;
                let dropped = match &sample {
                    Sample::Pupil(p) => Some(
                        !(gate.accept(p.confidence)
                            && p.diameter_raw.is_finite()
                            && p.diameter_raw > 0.0),
                    ),
                    _ => None,
                };
                window.add(host_now_secs(), sample_confidence(&sample), dropped);
                let _ = hub.samples.send(sample);
            }
            _ = feedback_tick.tick() => {
                if let Some(l) = adaptation.get()
                    && last_luminance.is_none_or(|p: f64| (l - p).abs() > 1e-3 * p.abs())
                    && client.set_adaptation_luminance(l).is_ok()
                {
                    last_luminance = Some(l);
                }
            }
            _ = status_tick.tick() => {
                let now = host_now_secs();
                window.publish(now, &hub, total);
                let stats = client.stats();
                let health = if stats.connected {
                    SourceHealth::Live
                } else if ever_connected {
                    SourceHealth::Lost
                } else {
                    SourceHealth::Connecting
                };
                if stats.connected && !was_live {
                    if ever_connected {
                        tracing::info!(endpoint = %endpoint, reconnects = stats.reconnects, "Pupil Capture is back: live again");
                    } else {
                        tracing::info!(endpoint = %endpoint, version = stats.version.as_deref().unwrap_or("?"), "connected to Pupil Capture");
                    }
                } else if !stats.connected && was_live {
                    tracing::warn!(
                        endpoint = %endpoint,
                        "lost Pupil Capture at {endpoint}: {}; frames continue, the pupil eases to the model",
                        stats.last_error.as_deref().unwrap_or("no answer")
                    );
                }
                if !stats.connected && !ever_connected && !said_absent && started.elapsed() >= NO_TRACKER_AFTER {
                    said_absent = true;
                    tracing::warn!(
                        "no Pupil Capture at {endpoint}: {}; frames continue with the pupil model (--mouse-gaze needs a window); still trying to connect",
                        stats.last_error.as_deref().unwrap_or("no answer from Pupil Remote")
                    );
                }
                ever_connected |= stats.connected;
                was_live = stats.connected;
                hub.update_source(|s| {
                    s.health = health;
                    s.reconnects = stats.reconnects;
                    s.samples_dropped = stats.dropped;
                    if stats.last_error.is_some() {
                        s.last_error.clone_from(&stats.last_error);
                    }
                });
            }
        }
    }
    client.shutdown().await;
}

/// The demo's keyframed trace as samples (both pupils in mm, gaze), looped
/// forever with the times advanced by the trace's duration each lap.
struct DemoSamples {
    trace: Vec<TraceSample>,
    lap_secs: f64,
    lap: u64,
    index: usize,
    part: u8,
}

impl DemoSamples {
    fn new(trace: Vec<TraceSample>, lap_secs: f64) -> Self {
        Self {
            trace,
            lap_secs,
            lap: 0,
            index: 0,
            part: 0,
        }
    }
}

impl Iterator for DemoSamples {
    type Item = Result<Sample, std::convert::Infallible>;

    fn next(&mut self) -> Option<Self::Item> {
        if self.trace.is_empty() {
            return None;
        }
        if self.index >= self.trace.len() {
            self.index = 0;
            self.lap += 1;
        }
        let s = self.trace[self.index];
        let t_secs = s.t_secs + self.lap as f64 * self.lap_secs;
        let sample = match self.part {
            0 | 1 => Sample::Pupil(PupilSample {
                t_secs,
                eye: if self.part == 0 {
                    EYE_RIGHT as u8
                } else {
                    EYE_LEFT as u8
                },
                diameter_raw: s.pupil_mm.unwrap_or(0.0),
                unit: PupilUnit::Mm,
                diameter_mm: s.pupil_mm,
                confidence: s.confidence,
                norm_pos: [f32::NAN; 2],
                method: DetectorMethod::Other,
            }),
            _ => Sample::Gaze(GazeSample {
                t_secs,
                gaze_uv: s.gaze_uv,
                confidence: s.confidence,
                eyes: GazeEyes::Binocular,
            }),
        };
        self.part += 1;
        if self.part == 3 {
            self.part = 0;
            self.index += 1;
        }
        Some(Ok(sample))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replay_uris_parse() {
        let (p, s) = parse_replay("replay://a/b?speed=2", "a/b?speed=2").unwrap();
        assert_eq!((p, s), (PathBuf::from("a/b"), 2.0));
        assert!(parse_replay("replay://a?speed=0", "a?speed=0").is_err());
        assert!(parse_replay("replay://a?x=1", "a?x=1").is_err());
        assert!(parse_replay("replay://", "").is_err());
    }

    #[test]
    fn demo_samples_loop_with_advancing_time() {
        let tr = vec![
            TraceSample {
                t_secs: 0.0,
                gaze_uv: [0.5, 0.5],
                pupil_mm: Some(4.0),
                confidence: 1.0,
            },
            TraceSample {
                t_secs: 1.0,
                gaze_uv: [0.5, 0.5],
                pupil_mm: Some(4.0),
                confidence: 1.0,
            },
        ];
        let ts: Vec<f64> = DemoSamples::new(tr, 2.0)
            .take(9)
            .map(|s| s.unwrap().t_secs())
            .collect();
        assert_eq!(ts, vec![0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 2.0, 2.0, 2.0]);
    }

    #[tokio::test]
    async fn the_task_filters_publishes_and_ends() {
        let samples = (0..50).map(|i| {
            Ok::<_, std::convert::Infallible>(Sample::Pupil(PupilSample {
                t_secs: i as f64 * 0.01,
                eye: 0,
                diameter_raw: 5.0,
                unit: PupilUnit::Mm,
                diameter_mm: Some(5.0),
                confidence: 0.95,
                norm_pos: [0.5, 0.5],
                method: DetectorMethod::Other,
            }))
        });
        let source = ReplaySource::new("t", samples, Pacing::AsFastAsPossible);
        let adaptation = Arc::new(AdaptationCell::default());
        let (hub, task) =
            start_generic("test://", source, FilterChain::with_defaults(), adaptation);
        let mut rx = hub.samples.subscribe();
        tokio::time::timeout(Duration::from_secs(5), task)
            .await
            .unwrap()
            .unwrap();
        let live = *hub.eye.borrow();
        assert_eq!(live.updates, 50);
        assert!((live.state.eyes[0].pupil_mm - 5.0).abs() < 0.5, "{live:?}");
        assert_eq!(hub.source().health, SourceHealth::Ended);
        assert_eq!(hub.source().samples_total, 50);
        assert!(rx.try_recv().is_ok());
    }
}
