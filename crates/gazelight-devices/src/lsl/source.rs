//! `lsl://?name=…` / `lsl://?type=…`: an LSL stream as a [`SampleSource`].
//!
//! A reader thread resolves the stream, opens an inlet, reads the
//! channel labels from the stream's description and picks a [`Layout`]
//! (the rule the XDF importer uses too, `gazelight_eye::channel_layout`):
//! gazelight's own outlet, Pupil Capture's LSL relay (`pupil_capture`:
//! `confidence`, `norm_pos_x`, `norm_pos_y`, …, `diameter0_2d`,
//! `diameter1_2d`, `diameter0_3d`, `diameter1_3d`), Neon's stream (`x`, `y`
//! in scene camera pixels, `pupil_diameter_left`, `pupil_diameter_right` in
//! mm), a generic `pupil` stream, or the mapping in `[lsl.inlet]`. A lost
//! pupil (0, NaN) is a sample of confidence 0, as in a replay. Every sample becomes gaze and per-eye
//! pupil samples on the host clock: its timestamp goes through the
//! stream's [`SourceClock`], anchored on the inlet's `time_correction()`
//! (refreshed every few seconds; it gives this machine's LSL clock) and
//! [`LslClock`] (the host clock), and checked against the sample's arrival,
//! so one sample stamped +1e5 s is dropped and counted, and a sender whose
//! clock steps is followed after a few samples.
//!
//! A stream that vanishes (liblsl reports it lost) ends the reader with
//! [`SourceError::Disconnected`]; the next [`SampleSource::next`] resolves
//! it again, so it resumes when it comes back.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use serde::Serialize;
use tokio::sync::mpsc;

use super::{Inlet, InletMapping, LslClock, LslConfig, LslError, Pulled, resolve};
use crate::{ThreadItem, ThreadedSource, recv_reopenable, send_blocking};
use gazelight_eye::clock::{SharedClockStats, SourceClock, SourceClockConfig, host_now_secs};
use gazelight_eye::sample::{PupilUnit, Sample};
use gazelight_eye::source::{SampleSource, SourceError};

/// How often the time correction is refreshed, seconds.
const TIME_CORRECTION_PERIOD_SECS: f64 = 5.0;
/// How long one pull waits before the stop flag is checked, seconds.
const PULL_TIMEOUT_SECS: f64 = 0.05;
/// How long one resolve waits before the stop flag is checked, seconds.
const RESOLVE_STEP_SECS: f64 = 0.5;
use gazelight_eye::channel_layout::NEON_SCENE_PX;

/// Why an `lsl://` URI names no stream; the message quotes the URI.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("`{uri}`: {reason}")]
pub struct LslQueryError {
    /// The URI as given.
    pub uri: String,
    /// What is wrong and what was expected.
    pub reason: String,
}

impl LslQueryError {
    fn new(uri: &str, reason: impl Into<String>) -> Self {
        Self {
            uri: uri.to_owned(),
            reason: reason.into(),
        }
    }
}

/// Why a stream's channels match no known layout.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum LayoutError {
    /// The inlet mapping names a channel the stream does not have.
    #[error("no channel labelled `{0}`")]
    MissingChannel(String),
    /// Neither a known layout nor a mapping.
    #[error(
        "channel labels [{}] are none of gazelight's own outlet (gaze_x, gaze_y, \
         pupil_right_mm, pupil_left_mm, …), Pupil Capture's LSL relay (norm_pos_x, norm_pos_y, \
         diameter0_3d, …), Neon's (x, y, pupil_diameter_left, …) or a generic pupil stream \
         (pupil): map them in [lsl.inlet] (gaze_x, gaze_y, gaze_range, pupil_right, \
         pupil_left, pupil_unit, confidence)",
        .labels.join(", ")
    )]
    Unknown { labels: Vec<String> },
}

/// Which stream an `lsl://` URI asks for.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LslQuery {
    /// `name`, `type` or `source_id`.
    pub prop: &'static str,
    pub value: String,
}

impl LslQuery {
    /// Parses the query part of `lsl://?name=…` (one of name, type,
    /// source_id).
    pub fn parse(uri: &str) -> Result<Self, LslQueryError> {
        let rest = uri.strip_prefix("lsl://").ok_or_else(|| {
            LslQueryError::new(uri, "expected lsl://?name=NAME or lsl://?type=TYPE")
        })?;
        let q = rest.trim_start_matches('/');
        let q = q.strip_prefix('?').ok_or_else(|| {
            LslQueryError::new(
                uri,
                "expected lsl://?name=NAME, lsl://?type=TYPE or lsl://?source_id=ID",
            )
        })?;
        let mut found = None;
        for pair in q.split('&').filter(|p| !p.is_empty()) {
            let (k, v) = pair
                .split_once('=')
                .ok_or_else(|| LslQueryError::new(uri, format!("`{pair}` is not KEY=VALUE")))?;
            let prop = match k {
                "name" => "name",
                "type" => "type",
                "source_id" => "source_id",
                other => {
                    return Err(LslQueryError::new(
                        uri,
                        format!("unknown parameter `{other}` (expected name, type or source_id)"),
                    ));
                }
            };
            if v.is_empty() || v.contains('\0') {
                return Err(LslQueryError::new(uri, format!("empty {k}")));
            }
            if found.is_some() {
                return Err(LslQueryError::new(
                    uri,
                    "give one of name, type or source_id",
                ));
            }
            found = Some(Self {
                prop,
                value: percent_decode(v),
            });
        }
        found.ok_or_else(|| LslQueryError::new(uri, "expected ?name=NAME or ?type=TYPE"))
    }
}

impl std::fmt::Display for LslQuery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "lsl://?{}={}", self.prop, self.value)
    }
}

fn percent_decode(s: &str) -> String {
    let b = s.as_bytes();
    let mut out = Vec::with_capacity(b.len());
    let mut i = 0;
    while i < b.len() {
        if b[i] == b'%'
            && i + 2 < b.len()
            && let Some(Ok(v)) = s.get(i + 1..i + 3).map(|h| u8::from_str_radix(h, 16))
        {
            out.push(v);
            i += 3;
            continue;
        }
        out.push(if b[i] == b'+' { b' ' } else { b[i] });
        i += 1;
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// How a stream's channels are read: the one rule shared with the XDF
/// importer (`gazelight_eye::channel_layout`).
pub use gazelight_eye::channel_layout::ChannelLayout as Layout;

/// Picks the layout from the channel labels, or from `mapping` when it is
/// set (`[lsl.inlet]`: kind `mapped`).
pub fn detect_layout(labels: &[String], mapping: &InletMapping) -> Result<Layout, LayoutError> {
    let idx = |l: &str| labels.iter().position(|x| x == l);
    let need = |l: &str| idx(l).ok_or_else(|| LayoutError::MissingChannel(l.to_owned()));
    if !mapping.is_set() {
        let scene_px = mapping.scene_camera_px.unwrap_or(NEON_SCENE_PX);
        // liblsl gives the labels only: no units.
        return Layout::detect(labels, None, scene_px).ok_or_else(|| LayoutError::Unknown {
            labels: labels.to_vec(),
        });
    }
    let unit = match mapping.pupil_unit.as_deref() {
        None | Some("mm") => PupilUnit::Mm,
        Some("px") => PupilUnit::Px,
        _ => PupilUnit::Arbitrary,
    };
    let opt = |l: &Option<String>| l.as_deref().map(need).transpose();
    let eye = |l: &Option<String>| -> Result<Vec<(usize, PupilUnit)>, LayoutError> {
        Ok(opt(l)?.map(|i| vec![(i, unit)]).unwrap_or_default())
    };
    Ok(Layout {
        kind: "mapped",
        gaze_x: opt(&mapping.gaze_x)?,
        gaze_y: opt(&mapping.gaze_y)?,
        gaze_range: mapping.gaze_range.unwrap_or([1.0, 1.0]),
        gaze_y_up: mapping.gaze_origin.as_deref() == Some("bottom"),
        gaze_valid: None,
        confidence: opt(&mapping.confidence)?,
        pupil: [eye(&mapping.pupil_right)?, eye(&mapping.pupil_left)?],
        eye_confidence: [None, None],
        eye_valid: [None, None],
        blink: None,
    })
}

/// What the reader thread learnt about the stream it opened.
#[derive(Clone, Debug, Default, Serialize)]
pub struct StreamFacts {
    pub name: String,
    pub kind: String,
    pub source_id: String,
    pub channels: usize,
    pub nominal_srate_hz: f64,
    pub layout: Option<String>,
    /// Newest `time_correction()`, seconds.
    pub time_correction_s: Option<f64>,
    pub opened: u64,
}

/// An LSL stream as a sample source (reopens after a loss).
pub struct LslSource {
    query: LslQuery,
    config: LslConfig,
    clock: LslClock,
    reader: Option<ThreadedSource>,
    facts: Arc<std::sync::Mutex<StreamFacts>>,
    /// The counters of the stream's clock mapping (across reopens).
    mapping: Arc<SharedClockStats>,
}

impl LslSource {
    /// Loads liblsl and measures the clock; the stream is resolved on the
    /// first [`SampleSource::next`] (it may not exist yet).
    pub fn new(query: LslQuery, config: LslConfig) -> Result<Self, LslError> {
        let clock = LslClock::measure(&config)?;
        Ok(Self {
            query,
            config,
            clock,
            reader: None,
            facts: Arc::default(),
            mapping: Arc::default(),
        })
    }

    /// What is known about the stream now.
    pub fn facts(&self) -> StreamFacts {
        self.facts.lock().map(|f| f.clone()).unwrap_or_default()
    }

    fn start(&mut self) -> Result<(), SourceError> {
        let query = self.query.clone();
        let config = self.config.clone();
        let clock = self.clock;
        let facts = self.facts.clone();
        let mapping = SourceClock::with_stats(
            self.query.to_string(),
            SourceClockConfig::default(),
            self.mapping.clone(),
        );
        let reader = ThreadedSource::spawn("gazelight-lsl", move |tx, stop| {
            read_stream(&query, &config, clock, mapping, &facts, &tx, &stop);
        })
        .map_err(|e| SourceError::Fatal {
            source_name: self.query.to_string(),
            reason: format!("cannot start the LSL reader thread: {e}"),
        })?;
        self.reader = Some(reader);
        Ok(())
    }
}

impl SampleSource for LslSource {
    async fn next(&mut self) -> Result<Option<Sample>, SourceError> {
        loop {
            if self.reader.is_none() {
                self.start()?;
            }
            if let Some(s) = recv_reopenable(&mut self.reader, &self.query.to_string()).await? {
                return Ok(Some(s));
            }
        }
    }

    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        Some(self.mapping.clone())
    }

    fn describe(&self) -> String {
        let f = self.facts();
        if f.name.is_empty() {
            format!("LSL stream {} (not found yet)", self.query)
        } else {
            format!(
                "LSL stream `{}` (type {}, {} channels, {} Hz, layout {})",
                f.name,
                f.kind,
                f.channels,
                f.nominal_srate_hz,
                f.layout.as_deref().unwrap_or("?")
            )
        }
    }
}

fn lost(query: &LslQuery, reason: impl Into<String>) -> ThreadItem {
    Err(SourceError::Disconnected {
        source_name: query.to_string(),
        reason: reason.into(),
    })
}

fn fatal(source_name: String, reason: String) -> ThreadItem {
    Err(SourceError::Fatal {
        source_name,
        reason,
    })
}

/// The reader thread: resolve → inlet → layout → pull until lost or stopped.
fn read_stream(
    query: &LslQuery,
    config: &LslConfig,
    clock: LslClock,
    mut mapping: SourceClock,
    facts: &std::sync::Mutex<StreamFacts>,
    tx: &mpsc::Sender<ThreadItem>,
    stop: &AtomicBool,
) {
    let info = loop {
        if stop.load(Ordering::Relaxed) {
            return;
        }
        match resolve(config, query.prop, &query.value, RESOLVE_STEP_SECS) {
            Ok(Some(i)) => break i,
            Ok(None) => {}
            Err(e) => {
                let _ = send_blocking(tx, stop, fatal(query.to_string(), e.to_string()));
                return;
            }
        }
    };
    let mut inlet = match Inlet::new(&info) {
        Ok(i) => i,
        Err(e) => {
            let _ = send_blocking(tx, stop, fatal(query.to_string(), e.to_string()));
            return;
        }
    };
    let full = match inlet.full_info(2.0) {
        Ok(Some(f)) => f,
        Ok(None) => {
            let _ = send_blocking(tx, stop, lost(query, "no stream description within 2 s"));
            return;
        }
        Err(e) => {
            let _ = send_blocking(tx, stop, lost(query, e.to_string()));
            return;
        }
    };
    let labels = full.channel_labels();
    let layout = match detect_layout(&labels, &config.inlet) {
        Ok(l) => l,
        Err(reason) => {
            let source_name = format!("{query} (`{}`)", full.name());
            let _ = send_blocking(tx, stop, fatal(source_name, reason.to_string()));
            return;
        }
    };
    if let Ok(mut f) = facts.lock() {
        f.name = full.name();
        f.kind = full.kind();
        f.source_id = full.source_id();
        f.channels = full.channel_count();
        f.nominal_srate_hz = full.nominal_srate_hz();
        f.layout = Some(layout.kind.to_owned());
        f.opened += 1;
    }
    tracing::info!(stream = %full.name(), layout = layout.kind, channels = inlet.channels(), "LSL inlet open");
    drop(full);
    drop(info);
    // host = sender stamp + correction − (lsl − host): the mapping's
    // offset is correction − (lsl − host). Measured before subscribing: the
    // measurement takes up to a second, and samples queued meanwhile would
    // arrive that old.
    let correction = match inlet.time_correction(2.0) {
        Ok(c) => c,
        Err(e) => {
            let _ = send_blocking(tx, stop, lost(query, e.to_string()));
            return;
        }
    };
    if let Some(c) = correction {
        mapping.anchor(c - clock.lsl_minus_host_secs, host_now_secs());
    }
    if let Ok(mut f) = facts.lock() {
        f.time_correction_s = correction;
    }
    match inlet.open(2.0) {
        Ok(true) => {}
        Ok(false) => {
            let _ = send_blocking(tx, stop, lost(query, "could not subscribe within 2 s"));
            return;
        }
        Err(e) => {
            let _ = send_blocking(tx, stop, lost(query, e.to_string()));
            return;
        }
    }
    let mut last_correction = Instant::now();
    let mut buf = vec![0.0f64; inlet.channels()];
    let mut out = Vec::with_capacity(4);
    while !stop.load(Ordering::Relaxed) {
        if last_correction.elapsed() >= Duration::from_secs_f64(TIME_CORRECTION_PERIOD_SECS) {
            last_correction = Instant::now();
            match inlet.time_correction(0.2) {
                Ok(Some(c)) => {
                    mapping.anchor(c - clock.lsl_minus_host_secs, host_now_secs());
                    if let Ok(mut f) = facts.lock() {
                        f.time_correction_s = Some(c);
                    }
                }
                Ok(None) => {}
                Err(e) => {
                    let _ = send_blocking(tx, stop, lost(query, e.to_string()));
                    return;
                }
            }
        }
        match inlet.pull(&mut buf, PULL_TIMEOUT_SECS) {
            Ok(Pulled::Sample(ts)) => {
                // Dropped (and counted) when the mapping rejects the stamp.
                let Some(host) = mapping.to_host(ts, host_now_secs()) else {
                    continue;
                };
                out.clear();
                layout.decode(&buf, host, &mut |s| out.push(s));
                for s in out.drain(..) {
                    if !send_blocking(tx, stop, Ok(s)) {
                        return;
                    }
                }
            }
            Ok(Pulled::Nothing) => {}
            Err(e) => {
                let _ = send_blocking(tx, stop, lost(query, e.to_string()));
                return;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn labels(v: &[&str]) -> Vec<String> {
        v.iter().map(|s| (*s).to_owned()).collect()
    }

    // Channel order of the Pupil Capture LSL relay (App-PupilLabs,
    // pupil_capture/README.md "Data Format").
    const RELAY: [&str; 22] = [
        "confidence",
        "norm_pos_x",
        "norm_pos_y",
        "gaze_point_3d_x",
        "gaze_point_3d_y",
        "gaze_point_3d_z",
        "eye_center0_3d_x",
        "eye_center0_3d_y",
        "eye_center0_3d_z",
        "eye_center1_3d_x",
        "eye_center1_3d_y",
        "eye_center1_3d_z",
        "gaze_normal0_x",
        "gaze_normal0_y",
        "gaze_normal0_z",
        "gaze_normal1_x",
        "gaze_normal1_y",
        "gaze_normal1_z",
        "diameter0_2d",
        "diameter1_2d",
        "diameter0_3d",
        "diameter1_3d",
    ];

    #[test]
    fn queries_parse() {
        assert_eq!(
            LslQuery::parse("lsl://?name=pupil_capture").unwrap(),
            LslQuery {
                prop: "name",
                value: "pupil_capture".into()
            }
        );
        assert_eq!(LslQuery::parse("lsl://?type=Gaze").unwrap().prop, "type");
        assert_eq!(
            LslQuery::parse("lsl://?name=Neon%20Gaze").unwrap().value,
            "Neon Gaze"
        );
        for bad in [
            "lsl://",
            "lsl://?",
            "lsl://?name=",
            "lsl://?host=x",
            "lsl://?name=a&type=b",
            "pupil://?name=a",
        ] {
            assert!(LslQuery::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn relay_layout_reads_gaze_and_prefers_3d_diameters() {
        let l = detect_layout(&labels(&RELAY), &InletMapping::default()).unwrap();
        assert_eq!(l.kind, "pupil-capture-relay");
        let mut v = vec![f64::NAN; 22];
        v[0] = 0.9;
        v[1] = 0.25;
        v[2] = 0.75;
        v[18] = 30.0;
        v[19] = 33.0;
        v[20] = 3.5;
        let mut out = Vec::new();
        l.decode(&v, 10.0, &mut |s| out.push(s));
        // Right eye: 3D mm; left eye: no 3D (NaN) → 2D px.
        let Sample::Pupil(r) = out[0] else { panic!() };
        assert_eq!(
            (r.eye, r.diameter_mm, r.unit),
            (0, Some(3.5), PupilUnit::Mm)
        );
        let Sample::Pupil(le) = out[1] else { panic!() };
        assert_eq!((le.eye, le.diameter_raw, le.unit), (1, 33.0, PupilUnit::Px));
        let Sample::Gaze(g) = out[2] else { panic!() };
        // norm_pos has its origin bottom-left: v = 1 − y.
        assert_eq!(g.gaze_uv, [0.25, 0.25]);
        assert!((g.confidence - 0.9).abs() < 1e-6);
        assert_eq!(g.t_secs, 10.0);
    }

    #[test]
    fn neon_and_mapped_layouts() {
        let l = detect_layout(
            &labels(&["x", "y", "pupil_diameter_left", "pupil_diameter_right"]),
            &InletMapping::default(),
        )
        .unwrap();
        assert_eq!(l.kind, "neon");
        let mut out = Vec::new();
        l.decode(&[800.0, 300.0, 4.0, 3.0], 1.0, &mut |s| out.push(s));
        let Sample::Pupil(r) = out[0] else { panic!() };
        assert_eq!((r.eye, r.diameter_mm), (0, Some(3.0)));
        let Sample::Gaze(g) = out[2] else { panic!() };
        assert_eq!(g.gaze_uv, [0.5, 0.25]);

        let err = detect_layout(&labels(&["a", "b"]), &InletMapping::default())
            .unwrap_err()
            .to_string();
        assert!(err.contains("[lsl.inlet]") && err.contains("a, b"), "{err}");
        let m = InletMapping {
            gaze_x: Some("b".into()),
            gaze_y: Some("a".into()),
            gaze_range: Some([1920.0, 1080.0]),
            pupil_left: Some("a".into()),
            pupil_unit: Some("px".into()),
            ..InletMapping::default()
        };
        let l = detect_layout(&labels(&["a", "b"]), &m).unwrap();
        out.clear();
        l.decode(&[540.0, 960.0], 2.0, &mut |s| out.push(s));
        let Sample::Pupil(p) = out[0] else { panic!() };
        assert_eq!((p.eye, p.unit, p.diameter_raw), (1, PupilUnit::Px, 540.0));
        let Sample::Gaze(g) = out[1] else { panic!() };
        assert_eq!(g.gaze_uv, [0.5, 0.5]);
        let bad = InletMapping {
            gaze_x: Some("zz".into()),
            ..InletMapping::default()
        };
        assert!(
            detect_layout(&labels(&["a"]), &bad)
                .unwrap_err()
                .to_string()
                .contains("zz")
        );
    }
}
