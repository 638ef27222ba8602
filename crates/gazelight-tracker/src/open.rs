//! Opening the source a URI names — every scheme, behind one
//! [`AnySource`]: the Pupil client, a replay of any recording, the
//! synthetic demo, an LSL stream and the hardware transports of
//! `gazelight-devices`.

use std::sync::Arc;

use gazelight_devices::lsl::LslMarkers;
use gazelight_devices::lsl::{LslConfig, LslSource};
use gazelight_devices::{gazepoint, hid, serial, usb};
use gazelight_eye::clock::SharedClockStats;
use gazelight_eye::live_events::EventQueue;
use gazelight_eye::source::{SampleSource, SourceError};
use gazelight_eye::{Sample, TraceSample};
use gazelight_import::Importer;
use gazelight_neon::stream::RtpTransport;
use gazelight_neon::{NeonConfig, NeonSource};
use gazelight_pupil::PupilSource;

use crate::live::AgeClock;
use crate::source::{Pacing, ReplaySource};
use crate::trace_source::LoopedTrace;
use crate::uri::SourceUri;

/// What opening needs beyond the URI.
#[derive(Clone, Debug, Default)]
pub struct OpenOptions {
    /// Settings of `lsl://` inlets.
    pub lsl: LslConfig,
    /// The trace `synthetic://demo` loops, with its lap length in seconds
    /// (the binary builds it for its scene and view); without one,
    /// `synthetic://demo` is refused.
    pub synthetic: Option<(Vec<TraceSample>, f64)>,
    /// Where a source that carries events beside its samples (Pupil
    /// Capture's annotations) puts them, on the host clock; `None`: they
    /// are not read.
    pub events: Option<Arc<EventQueue>>,
}

/// Any source, as opened from a [`SourceUri`].
pub enum AnySource {
    /// Pupil Capture / Service (`pupil://`): decoded, clock-aligned samples.
    Pupil(PupilSource),
    /// A recording (`replay://`), paced on tokio's clock.
    Replay {
        source: ReplaySource<Box<dyn Importer + Send>>,
        /// The importer's format name.
        format: &'static str,
    },
    /// The looped demo trace (`synthetic://demo`), paced in real time.
    Synthetic(ReplaySource<LoopedTrace>),
    /// A Lab Streaming Layer stream (`lsl://`).
    Lsl(Box<LslSource>),
    /// A HID tracker (`hid://`).
    Hid(hid::HidSource),
    /// A vendor bulk endpoint (`usb://`).
    Usb(usb::UsbSource),
    /// A serial line (`serial://`).
    Serial(serial::SerialSource),
    /// The Gazepoint Open Gaze API (`gazepoint://`).
    Gazepoint(gazepoint::GazepointSource),
    /// A Pupil Labs Neon over its Real-time API (`neon://`): samples on
    /// the host clock.
    Neon(Box<NeonSource>),
}

impl AnySource {
    /// Which clock the source's sample times are on: host time for the
    /// sources that align their clock to the host's (Pupil, LSL), the
    /// recording's or device's own for the rest.
    pub fn age_clock(&self) -> AgeClock {
        match self {
            AnySource::Pupil(_) | AnySource::Lsl(_) | AnySource::Neon(_) => AgeClock::SampleTime,
            _ => AgeClock::PublishTime,
        }
    }
}

impl SampleSource for AnySource {
    async fn next(&mut self) -> Result<Option<Sample>, SourceError> {
        match self {
            AnySource::Pupil(s) => s.next().await,
            AnySource::Replay { source, .. } => source.next().await,
            AnySource::Synthetic(s) => s.next().await,
            AnySource::Lsl(s) => s.next().await,
            AnySource::Hid(s) => s.next().await,
            AnySource::Usb(s) => s.next().await,
            AnySource::Serial(s) => s.next().await,
            AnySource::Gazepoint(s) => s.next().await,
            AnySource::Neon(s) => s.next().await,
        }
    }

    fn describe(&self) -> String {
        match self {
            AnySource::Pupil(s) => {
                let c = s.client().config();
                format!("Pupil Capture at {}:{}", c.host, c.remote_port)
            }
            AnySource::Replay { source, format } => format!("{} ({format})", source.describe()),
            AnySource::Synthetic(s) => s.describe(),
            AnySource::Lsl(s) => s.describe(),
            AnySource::Hid(s) => s.describe(),
            AnySource::Usb(s) => s.describe(),
            AnySource::Serial(s) => s.describe(),
            AnySource::Gazepoint(s) => s.describe(),
            AnySource::Neon(s) => s.describe(),
        }
    }

    fn dropped(&self) -> u64 {
        match self {
            AnySource::Pupil(s) => s.dropped(),
            AnySource::Neon(s) => s.dropped(),
            _ => 0,
        }
    }

    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        match self {
            AnySource::Pupil(s) => s.clock_stats(),
            AnySource::Replay { .. } | AnySource::Synthetic(_) => None,
            AnySource::Lsl(s) => s.clock_stats(),
            AnySource::Hid(s) => s.clock_stats(),
            AnySource::Usb(s) => s.clock_stats(),
            AnySource::Serial(s) => s.clock_stats(),
            AnySource::Gazepoint(s) => s.clock_stats(),
            AnySource::Neon(s) => s.clock_stats(),
        }
    }
}

/// Opens the source a URI names with default [`OpenOptions`] (no
/// synthetic trace).
pub fn open(uri: &SourceUri) -> Result<AnySource, SourceError> {
    open_with(uri, &OpenOptions::default())
}

/// Opens the source a URI names. Must be called inside a tokio runtime
/// (the Pupil client and the LSL inlet start tasks). Opening does not wait
/// for data: a HID or serial device or a recording is opened (so a missing
/// file, device or permission is reported here), a Pupil or Gazepoint
/// connection is made in the background / on the first
/// [`SampleSource::next`].
pub fn open_with(uri: &SourceUri, options: &OpenOptions) -> Result<AnySource, SourceError> {
    let fatal = |reason: String| SourceError::Fatal {
        source_name: uri.to_string(),
        reason,
    };
    match uri {
        SourceUri::Pupil { .. } => {
            let mut config = uri
                .pupil_config()
                .ok_or_else(|| fatal("not a Pupil URI".to_owned()))?;
            config.events = options.events.clone();
            let (source, _raw) = PupilSource::spawn(config);
            Ok(AnySource::Pupil(source))
        }
        SourceUri::Replay { path, speed } => {
            let importer = gazelight_import::open(path)
                .map_err(|e| fatal(format!("cannot open the recording: {e}")))?;
            let format = importer.format();
            Ok(AnySource::Replay {
                source: ReplaySource::new(
                    path.display().to_string(),
                    importer,
                    Pacing::Scaled { speed: *speed },
                ),
                format,
            })
        }
        SourceUri::Synthetic { .. } => {
            let (trace, lap_secs) = options
                .synthetic
                .clone()
                .ok_or_else(|| fatal("no synthetic trace was prepared".to_owned()))?;
            Ok(AnySource::Synthetic(ReplaySource::new(
                "synthetic demo (looped)",
                LoopedTrace::new(trace, lap_secs),
                Pacing::Scaled { speed: 1.0 },
            )))
        }
        SourceUri::Lsl(query) => Ok(AnySource::Lsl(Box::new(
            LslSource::new(query.clone(), options.lsl.clone()).map_err(|e| fatal(e.to_string()))?,
        ))),
        SourceUri::Hid(target) => Ok(AnySource::Hid(hid::HidSource::open(
            target.clone(),
            hid::HidOptions::default(),
        )?)),
        SourceUri::Usb {
            vendor_id,
            product_id,
            interface,
        } => Ok(AnySource::Usb(usb::UsbSource::open(
            *vendor_id,
            *product_id,
            *interface,
        )?)),
        SourceUri::Serial { path, baud, format } => Ok(AnySource::Serial(
            serial::SerialSource::open(path, *baud, *format)?,
        )),
        SourceUri::Gazepoint { host, port } => Ok(AnySource::Gazepoint(
            gazepoint::GazepointSource::new(host.clone(), *port),
        )),
        SourceUri::Neon { host, port, udp } => {
            Ok(AnySource::Neon(Box::new(NeonSource::new(NeonConfig {
                host: host.clone(),
                port: *port,
                transport: if *udp {
                    RtpTransport::Udp
                } else {
                    RtpTransport::Tcp
                },
                ..NeonConfig::default()
            }))))
        }
    }
}

/// A source could not be opened ([`open_live`]): its URI as the user
/// wrote it, and why.
#[derive(Debug, thiserror::Error)]
#[error("source `{uri}`")]
pub struct OpenLiveError {
    /// The URI as given.
    pub uri: String,
    /// Why it could not be opened.
    #[source]
    pub source: SourceError,
}

/// Opens `uri` (written `name` by the user) with `options` and starts its
/// live eye task ([`crate::live::spawn`]): the one way every front end — the
/// CLI's `run`, the OpenXR layer, Python's `Source` — turns a source URI
/// into a running, filtered eye. Must be called inside a tokio runtime.
pub fn open_live(
    name: &str,
    uri: &SourceUri,
    options: &OpenOptions,
    chain: crate::filter::FilterChain,
    shutdown: tokio::sync::watch::Receiver<bool>,
    config: crate::live::LiveConfig,
) -> Result<crate::live::LiveEye, OpenLiveError> {
    let source = open_with(uri, options).map_err(|source| OpenLiveError {
        uri: name.to_owned(),
        source,
    })?;
    let age_clock = source.age_clock();
    Ok(crate::live::spawn(
        name, source, chain, age_clock, shutdown, config,
    ))
}

/// Starts reading the marker stream `uri` names (`lsl://?name=…`,
/// `?type=…`, `?source_id=…`: a string stream) into `events`, on the host
/// clock; the only scheme whose stream is events alone. The stream may
/// appear later: it is resolved by the reader.
pub fn open_markers(
    uri: &str,
    lsl: &LslConfig,
    events: Arc<EventQueue>,
) -> Result<LslMarkers, SourceError> {
    let fatal = |reason: String| SourceError::Fatal {
        source_name: uri.to_owned(),
        reason,
    };
    match SourceUri::parse(uri).map_err(|e| fatal(e.to_string()))? {
        SourceUri::Lsl(query) => {
            LslMarkers::start(query, lsl, events).map_err(|e| fatal(e.to_string()))
        }
        _ => Err(fatal(
            "events are read from an LSL marker stream (lsl://?name=NAME or \
             lsl://?type=Markers); a Pupil source's annotations come with it"
                .to_owned(),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_recording_is_a_fatal_error_naming_it() {
        let uri: SourceUri = "replay:///nonexistent/gazelight/rec.csv".parse().unwrap();
        let Err(SourceError::Fatal {
            source_name,
            reason,
        }) = open(&uri)
        else {
            panic!("a missing recording must be refused");
        };
        assert!(source_name.contains("/nonexistent/gazelight/rec.csv"));
        assert!(reason.contains("cannot open the recording"), "{reason}");
    }

    #[test]
    fn markers_come_from_lsl_only() {
        let q = Arc::new(EventQueue::default());
        let Err(SourceError::Fatal { reason, .. }) =
            open_markers("pupil://127.0.0.1:9", &LslConfig::default(), q)
        else {
            panic!("a Pupil URI is not a marker stream");
        };
        assert!(reason.contains("LSL marker stream"), "{reason}");
    }

    #[test]
    fn synthetic_needs_its_trace() {
        let uri: SourceUri = "synthetic://demo".parse().unwrap();
        assert!(matches!(open(&uri), Err(SourceError::Fatal { .. })));
        let trace = vec![TraceSample {
            t_secs: 0.0,
            gaze_uv: [0.5, 0.5],
            pupil_mm: Some(4.0),
            confidence: 1.0,
        }];
        let options = OpenOptions {
            synthetic: Some((trace, 1.0)),
            ..OpenOptions::default()
        };
        let s = open_with(&uri, &options).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.age_clock(), AgeClock::PublishTime);
        assert!(s.describe().contains("synthetic demo"));
    }

    #[tokio::test]
    async fn pupil_is_opened_with_the_client_and_ages_on_sample_time() {
        let uri: SourceUri = "pupil://127.0.0.1:9".parse().unwrap();
        let s = open(&uri).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(s.age_clock(), AgeClock::SampleTime);
        assert_eq!(s.describe(), "Pupil Capture at 127.0.0.1:9");
    }
}
