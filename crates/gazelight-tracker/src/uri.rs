//! Source URIs: one string names every kind of source gazelight can read.
//!
//! | URI | source |
//! | --- | --- |
//! | `pupil://HOST[:PORT]` (or `tcp://HOST[:PORT]`) | Pupil Core network API (Pupil Remote port, 50020 by default) |
//! | `hid://VVVV:PPPP` | first HID device with that vendor/product id (hex) |
//! | `hid:///dev/hidrawN` | a HID device by its hidraw node |
//! | `usb://VVVV:PPPP[?interface=N]` | vendor bulk-IN endpoint of a USB device |
//! | `serial:///dev/ttyACM0?baud=115200&format=gazepoint\|csv\|framed` | serial line |
//! | `gazepoint://HOST[:PORT]` | Gazepoint Open Gaze API over TCP (port 4242 by default) |
//! | `neon://HOST[:PORT][?transport=udp]` | Pupil Labs Neon Real-time API (HTTP port 8080 by default; gaze and eye state over RTSP, the media interleaved on TCP or over UDP) |
//! | `replay://PATH[?speed=S]` | a recording any importer reads, replayed at S × real time (0 < S ≤ 1000, default 1) |
//! | `synthetic://demo` | the demo's keyframed trace, looped |
//! | `lsl://?name=NAME`, `lsl://?type=TYPE`, `lsl://?source_id=ID` | a Lab Streaming Layer stream |
//!
//! This is the one parser of source URIs: `run`, `record`, `calibrate` and
//! `inspect` all go through [`SourceUri::parse`]. Parsing never panics; an
//! error names the part of the URI that is wrong and what was expected. A
//! new scheme is one entry in [`SCHEMES`], one variant and one arm.

use std::fmt;
use std::path::PathBuf;
use std::str::FromStr;

use gazelight_devices::lsl::LslQuery;
use gazelight_neon::DEFAULT_HTTP_PORT as NEON_DEFAULT_HTTP_PORT;
use gazelight_pupil::{DEFAULT_REMOTE_PORT, PupilConfig};

pub use gazelight_devices::target::{
    DEFAULT_BAUD, GAZEPOINT_DEFAULT_PORT, HidTarget, SerialFormat,
};

/// A parsed source URI.
#[derive(Clone, Debug, PartialEq)]
pub enum SourceUri {
    /// Pupil Core network API (`pupil://`, `tcp://`).
    Pupil { host: String, port: u16 },
    /// A HID tracker.
    Hid(HidTarget),
    /// A vendor bulk endpoint.
    Usb {
        vendor_id: u16,
        product_id: u16,
        /// Interface number to claim; `None` = the first vendor-class
        /// interface with a bulk-IN endpoint.
        interface: Option<u8>,
    },
    /// A serial line.
    Serial {
        path: PathBuf,
        baud: u32,
        format: SerialFormat,
    },
    /// Gazepoint Open Gaze API over TCP.
    Gazepoint { host: String, port: u16 },
    /// Pupil Labs Neon's Real-time API (its HTTP port); the media over UDP
    /// (`?transport=udp`) or, by default, interleaved on the RTSP TCP
    /// connection.
    Neon { host: String, port: u16, udp: bool },
    /// A recording, replayed at `speed` × real time.
    Replay { path: PathBuf, speed: f64 },
    /// A synthetic session (`synthetic://demo`).
    Synthetic { name: String },
    /// A Lab Streaming Layer stream.
    Lsl(LslQuery),
}

/// The schemes [`SourceUri::parse`] knows, as named in its errors.
pub const SCHEMES: &[&str] = &[
    "pupil",
    "tcp",
    "hid",
    "usb",
    "serial",
    "gazepoint",
    "neon",
    "replay",
    "synthetic",
    "lsl",
];

/// The only synthetic source.
pub const SYNTHETIC_DEMO: &str = "demo";
/// The source every front end uses when none is given (`run`, `calibrate`,
/// `record`, the OpenXR layer's config): Pupil Capture's Pupil Remote on
/// this machine, at its default port.
pub const DEFAULT_SOURCE: &str = "pupil://127.0.0.1:50020";
/// Fastest replay speed `replay://…?speed=S` accepts (× real time).
pub const MAX_REPLAY_SPEED: f64 = 1000.0;

/// Why a URI could not be parsed.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("source URI `{uri}`: {part}: {reason}")]
pub struct UriError {
    /// The whole URI as given.
    pub uri: String,
    /// The part that is wrong (`scheme`, `host`, `port`, `vendor id`, …).
    pub part: &'static str,
    /// What was expected.
    pub reason: String,
}

impl SourceUri {
    /// Parse a source URI.
    pub fn parse(uri: &str) -> Result<Self, UriError> {
        let err = |part: &'static str, reason: String| UriError {
            uri: uri.to_owned(),
            part,
            reason,
        };
        let Some((scheme, rest)) = uri.split_once("://") else {
            return Err(err(
                "scheme",
                format!(
                    "expected SCHEME://… with SCHEME one of {} (e.g. pupil://127.0.0.1:50020, \
                     replay://PATH, synthetic://demo)",
                    SCHEMES.join(", ")
                ),
            ));
        };
        let (body, query) = match rest.split_once('?') {
            Some((b, q)) => (b, Some(q)),
            None => (rest, None),
        };
        let params = parse_query(query).map_err(|r| err("query", r))?;
        let allow = |allowed: &[&str]| -> Result<(), UriError> {
            for (k, _) in &params {
                if !allowed.contains(k) {
                    return Err(err(
                        "query",
                        format!(
                            "unknown parameter `{k}` (allowed: {})",
                            if allowed.is_empty() {
                                "none".to_owned()
                            } else {
                                allowed.join(", ")
                            }
                        ),
                    ));
                }
            }
            Ok(())
        };
        match scheme.to_ascii_lowercase().as_str() {
            "pupil" | "tcp" => {
                allow(&[])?;
                let (host, port) =
                    host_port(body, Some(DEFAULT_REMOTE_PORT)).map_err(|(p, r)| err(p, r))?;
                Ok(SourceUri::Pupil { host, port })
            }
            "lsl" => LslQuery::parse(uri)
                .map(SourceUri::Lsl)
                .map_err(|e| err("query", e.reason)),
            "synthetic" => {
                allow(&[])?;
                let name = body.trim_end_matches('/');
                if name != SYNTHETIC_DEMO {
                    return Err(err(
                        "name",
                        format!("`{name}`: the only synthetic source is synthetic://demo"),
                    ));
                }
                Ok(SourceUri::Synthetic {
                    name: name.to_owned(),
                })
            }
            "gazepoint" => {
                allow(&[])?;
                let (host, port) =
                    host_port(body, Some(GAZEPOINT_DEFAULT_PORT)).map_err(|(p, r)| err(p, r))?;
                Ok(SourceUri::Gazepoint { host, port })
            }
            "neon" => {
                allow(&["transport"])?;
                let (host, port) =
                    host_port(body, Some(NEON_DEFAULT_HTTP_PORT)).map_err(|(p, r)| err(p, r))?;
                let udp = match params.iter().find(|(k, _)| *k == "transport") {
                    None | Some((_, "tcp")) => false,
                    Some((_, "udp")) => true,
                    Some((_, other)) => {
                        return Err(err(
                            "transport",
                            format!("`{other}`: expected tcp (RTP interleaved on RTSP) or udp"),
                        ));
                    }
                };
                Ok(SourceUri::Neon { host, port, udp })
            }
            "hid" => {
                allow(&[])?;
                if body.starts_with('/') {
                    Ok(SourceUri::Hid(HidTarget::Path(PathBuf::from(body))))
                } else {
                    let (vendor_id, product_id) = vid_pid(body).map_err(|(p, r)| err(p, r))?;
                    Ok(SourceUri::Hid(HidTarget::VidPid {
                        vendor_id,
                        product_id,
                    }))
                }
            }
            "usb" => {
                allow(&["interface"])?;
                let (vendor_id, product_id) = vid_pid(body).map_err(|(p, r)| err(p, r))?;
                let interface = match params.iter().find(|(k, _)| *k == "interface") {
                    None => None,
                    Some((_, v)) => Some(v.parse::<u8>().map_err(|_| {
                        err(
                            "interface",
                            format!("`{v}` is not an interface number 0-255"),
                        )
                    })?),
                };
                Ok(SourceUri::Usb {
                    vendor_id,
                    product_id,
                    interface,
                })
            }
            "serial" => {
                allow(&["baud", "format"])?;
                if !body.starts_with('/') {
                    return Err(err(
                        "path",
                        format!(
                            "expected an absolute device path (serial:///dev/ttyACM0), got `{body}`"
                        ),
                    ));
                }
                let mut baud = DEFAULT_BAUD;
                let mut format = SerialFormat::Csv;
                for (k, v) in &params {
                    match *k {
                        "baud" => {
                            baud = v.parse::<u32>().ok().filter(|b| *b > 0).ok_or_else(|| {
                                err("baud", format!("`{v}` is not a positive line rate"))
                            })?
                        }
                        "format" => {
                            format = match *v {
                                "gazepoint" => SerialFormat::Gazepoint,
                                "csv" => SerialFormat::Csv,
                                "framed" => SerialFormat::Framed,
                                other => {
                                    return Err(err(
                                        "format",
                                        format!("`{other}`: expected gazepoint, csv or framed"),
                                    ));
                                }
                            }
                        }
                        _ => {}
                    }
                }
                Ok(SourceUri::Serial {
                    path: PathBuf::from(body),
                    baud,
                    format,
                })
            }
            "replay" => {
                allow(&["speed"])?;
                if body.is_empty() {
                    return Err(err("path", "expected replay://PATH[?speed=S]".to_owned()));
                }
                let speed = match params.iter().find(|(k, _)| *k == "speed") {
                    None => 1.0,
                    Some((_, v)) => v
                        .parse::<f64>()
                        .ok()
                        .filter(|s| s.is_finite() && *s > 0.0 && *s <= MAX_REPLAY_SPEED)
                        .ok_or_else(|| {
                            err(
                                "speed",
                                format!("`{v}`: expected a number 0 < speed ≤ {MAX_REPLAY_SPEED}"),
                            )
                        })?,
                };
                Ok(SourceUri::Replay {
                    path: PathBuf::from(body),
                    speed,
                })
            }
            other => Err(err(
                "scheme",
                format!(
                    "unknown scheme `{other}` (expected {}://)",
                    SCHEMES.join("://, ")
                ),
            )),
        }
    }
}

impl FromStr for SourceUri {
    type Err = UriError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        SourceUri::parse(s)
    }
}

impl fmt::Display for SourceUri {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SourceUri::Pupil { host, port } => write!(f, "pupil://{}:{port}", bracket(host)),
            SourceUri::Gazepoint { host, port } => {
                write!(f, "gazepoint://{}:{port}", bracket(host))
            }
            SourceUri::Neon { host, port, udp } => {
                write!(f, "neon://{}:{port}", bracket(host))?;
                if *udp {
                    write!(f, "?transport=udp")?;
                }
                Ok(())
            }
            SourceUri::Hid(HidTarget::VidPid {
                vendor_id,
                product_id,
            }) => write!(f, "hid://{vendor_id:04x}:{product_id:04x}"),
            SourceUri::Hid(HidTarget::Path(p)) => write!(f, "hid://{}", p.display()),
            SourceUri::Usb {
                vendor_id,
                product_id,
                interface,
            } => {
                write!(f, "usb://{vendor_id:04x}:{product_id:04x}")?;
                if let Some(i) = interface {
                    write!(f, "?interface={i}")?;
                }
                Ok(())
            }
            SourceUri::Serial { path, baud, format } => write!(
                f,
                "serial://{}?baud={baud}&format={}",
                path.display(),
                format.as_str()
            ),
            SourceUri::Replay { path, speed } => {
                write!(f, "replay://{}", path.display())?;
                if *speed != 1.0 {
                    write!(f, "?speed={speed}")?;
                }
                Ok(())
            }
            SourceUri::Synthetic { name } => write!(f, "synthetic://{name}"),
            SourceUri::Lsl(q) => write!(f, "{q}"),
        }
    }
}

impl SourceUri {
    /// The Pupil client settings for a `pupil://` URI (other settings
    /// default); `None` for every other scheme.
    pub fn pupil_config(&self) -> Option<PupilConfig> {
        match self {
            SourceUri::Pupil { host, port } => Some(PupilConfig {
                host: host.clone(),
                remote_port: *port,
                ..PupilConfig::default()
            }),
            _ => None,
        }
    }
}

/// Parses a URI that must name a Pupil Core endpoint (`record`,
/// `calibrate`, `inspect pupil://…`): the client settings, or an error
/// naming the wrong part (another scheme is the `scheme` part).
pub fn pupil_config(uri: &str) -> Result<PupilConfig, UriError> {
    let parsed = SourceUri::parse(uri)?;
    parsed.pupil_config().ok_or_else(|| UriError {
        uri: uri.to_owned(),
        part: "scheme",
        reason: "expected pupil://HOST[:PORT] or tcp://HOST[:PORT] (Pupil Remote)".to_owned(),
    })
}

fn bracket(host: &str) -> String {
    if host.contains(':') {
        format!("[{host}]")
    } else {
        host.to_owned()
    }
}

fn parse_query(query: Option<&str>) -> Result<Vec<(&str, &str)>, String> {
    let mut out = Vec::new();
    let Some(q) = query else { return Ok(out) };
    for pair in q.split('&').filter(|p| !p.is_empty()) {
        let Some((k, v)) = pair.split_once('=') else {
            return Err(format!("`{pair}` is not KEY=VALUE"));
        };
        if out.iter().any(|(k2, _)| *k2 == k) {
            return Err(format!("parameter `{k}` given twice"));
        }
        out.push((k, v));
    }
    Ok(out)
}

fn host_port(
    body: &str,
    default_port: Option<u16>,
) -> Result<(String, u16), (&'static str, String)> {
    let body = body.trim_end_matches('/');
    if body.is_empty() {
        return Err(("host", "missing host".to_owned()));
    }
    // [v6]:port, host:port or host.
    let (host, port) = if let Some(rest) = body.strip_prefix('[') {
        let Some((h, after)) = rest.split_once(']') else {
            return Err(("host", format!("unclosed `[` in `{body}`")));
        };
        match after.strip_prefix(':') {
            Some(p) => (h, Some(p)),
            None if after.is_empty() => (h, None),
            None => return Err(("port", format!("unexpected `{after}` after `]`"))),
        }
    } else {
        match body.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (body, None),
        }
    };
    if host.is_empty() {
        return Err(("host", "missing host".to_owned()));
    }
    if host.contains('/') {
        return Err(("host", format!("`{host}` is not a host name")));
    }
    let port = match (port, default_port) {
        (Some(p), _) => p
            .parse::<u16>()
            .ok()
            .filter(|p| *p != 0)
            .ok_or_else(|| ("port", format!("`{p}` is not a port 1-65535")))?,
        (None, Some(d)) => d,
        (None, None) => return Err(("port", "missing :PORT".to_owned())),
    };
    Ok((host.to_owned(), port))
}

fn vid_pid(body: &str) -> Result<(u16, u16), (&'static str, String)> {
    let body = body.trim_end_matches('/');
    let Some((v, p)) = body.split_once(':') else {
        return Err((
            "vendor id",
            format!("expected VVVV:PPPP (hexadecimal vendor and product id), got `{body}`"),
        ));
    };
    let hex = |s: &str, part: &'static str| {
        let digits = s
            .strip_prefix("0x")
            .or_else(|| s.strip_prefix("0X"))
            .unwrap_or(s);
        if digits.is_empty() || digits.len() > 4 {
            return Err((part, format!("`{s}` is not a 1-4 digit hexadecimal id")));
        }
        u16::from_str_radix(digits, 16)
            .map_err(|_| (part, format!("`{s}` is not a hexadecimal id")))
    };
    Ok((hex(v, "vendor id")?, hex(p, "product id")?))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_scheme_parses_and_round_trips() {
        let cases = [
            "pupil://127.0.0.1:50020",
            "hid://0861:3437",
            "hid:///dev/hidraw0",
            "usb://1209:0001",
            "usb://1209:0001?interface=2",
            "serial:///dev/ttyACM0?baud=115200&format=gazepoint",
            "serial:///dev/ttyGS0?baud=9600&format=framed",
            "gazepoint://127.0.0.1:4242",
            "gazepoint://[::1]:4242",
            "neon://192.168.1.60:8080",
            "neon://[::1]:9000",
            "replay:///data/rec/pupil.pldata",
            "replay:///data/rec?speed=2.5",
            "synthetic://demo",
            "lsl://?name=gazelight-eye",
            "lsl://?type=Gaze",
        ];
        for c in cases {
            let u = SourceUri::parse(c).unwrap_or_else(|e| panic!("{c}: {e}"));
            assert_eq!(u.to_string(), c);
            assert_eq!(SourceUri::parse(&u.to_string()).unwrap(), u);
        }
    }

    #[test]
    fn neon_defaults_to_the_realtime_api_port() {
        assert_eq!(
            SourceUri::parse("neon://192.168.1.60/").unwrap(),
            SourceUri::Neon {
                host: "192.168.1.60".into(),
                port: 8080,
                udp: false
            }
        );
        let udp = SourceUri::parse("neon://10.0.0.2:8081?transport=udp").unwrap();
        assert_eq!(
            udp,
            SourceUri::Neon {
                host: "10.0.0.2".into(),
                port: 8081,
                udp: true
            }
        );
        assert_eq!(udp.to_string(), "neon://10.0.0.2:8081?transport=udp");
        let e = SourceUri::parse("neon://10.0.0.2?transport=quic").unwrap_err();
        assert_eq!(e.part, "transport");
    }

    #[test]
    fn values_are_decoded() {
        assert_eq!(
            SourceUri::parse("hid://0861:3437").unwrap(),
            SourceUri::Hid(HidTarget::VidPid {
                vendor_id: 0x0861,
                product_id: 0x3437
            })
        );
        assert_eq!(
            SourceUri::parse("gazepoint://localhost").unwrap(),
            SourceUri::Gazepoint {
                host: "localhost".into(),
                port: 4242
            }
        );
        assert_eq!(
            SourceUri::parse("serial:///dev/ttyUSB1").unwrap(),
            SourceUri::Serial {
                path: "/dev/ttyUSB1".into(),
                baud: 115_200,
                format: SerialFormat::Csv
            }
        );
        assert_eq!(
            SourceUri::parse("usb://0x1209:0x0001?interface=3").unwrap(),
            SourceUri::Usb {
                vendor_id: 0x1209,
                product_id: 1,
                interface: Some(3)
            }
        );
    }

    #[test]
    fn the_spellings_the_binary_accepted_still_parse() {
        // PupilConfig::from_uri's defaults: no port = Pupil Remote's 50020,
        // tcp:// as an alias of pupil://.
        for (uri, host, port) in [
            ("pupil://localhost", "localhost", 50020),
            ("pupil://10.0.0.2:50021", "10.0.0.2", 50021),
            ("tcp://127.0.0.1:50020", "127.0.0.1", 50020),
            ("pupil://127.0.0.1:50020/", "127.0.0.1", 50020),
        ] {
            let c = pupil_config(uri).unwrap_or_else(|e| panic!("{uri}: {e}"));
            assert_eq!((c.host.as_str(), c.remote_port), (host, port), "{uri}");
        }
        let e = pupil_config("replay:///x").unwrap_err();
        assert_eq!(e.part, "scheme");
        // parse_replay's: a relative path and a speed.
        assert_eq!(
            SourceUri::parse("replay://a/b?speed=2").unwrap(),
            SourceUri::Replay {
                path: "a/b".into(),
                speed: 2.0
            }
        );
        assert_eq!(
            SourceUri::parse("replay://a/b").unwrap(),
            SourceUri::Replay {
                path: "a/b".into(),
                speed: 1.0
            }
        );
        let e = SourceUri::parse("replay://a?speed=0").unwrap_err();
        assert!(e.to_string().contains("0 < speed ≤ 1000"), "{e}");
        let e = SourceUri::parse("synthetic://x").unwrap_err();
        assert!(e.to_string().contains("synthetic://demo"), "{e}");
        let e = SourceUri::parse("nope://x").unwrap_err();
        for s in SCHEMES {
            assert!(e.to_string().contains(&format!("{s}://")), "{e}");
        }
    }

    #[test]
    fn errors_name_the_wrong_part() {
        let cases = [
            ("127.0.0.1:4242", "scheme"),
            ("pupil://127.0.0.1:99999", "port"),
            ("pupil://h:0", "port"),
            ("pupil://h:x", "port"),
            ("tcp://:5", "host"),
            ("pupil://:50020", "host"),
            ("hid://zz61:3437", "vendor id"),
            ("hid://0861:34370", "product id"),
            ("hid://0861", "vendor id"),
            ("usb://1209:0001?interface=x", "interface"),
            ("usb://1209:0001?iface=1", "query"),
            ("serial:///dev/ttyACM0?baud=fast", "baud"),
            ("serial:///dev/ttyACM0?baud=0", "baud"),
            ("serial:///dev/ttyACM0?format=xml", "format"),
            ("serial:///dev/ttyACM0?format", "query"),
            ("serial://dev/ttyACM0", "path"),
            ("serial:///dev/ttyACM0?baud=1&baud=2", "query"),
            ("gazepoint://[::1", "host"),
            ("neon://", "host"),
            ("neon://h:x", "port"),
            ("neon://h/api", "host"),
            ("neon://h?x=1", "query"),
            ("replay://", "path"),
            ("replay://a?speed=0", "speed"),
            ("replay://a?speed=1001", "speed"),
            ("replay://a?speed=fast", "speed"),
            ("replay://a?x=1", "query"),
            ("synthetic://other", "name"),
            ("lsl://", "query"),
            ("http://x:1", "scheme"),
        ];
        for (uri, part) in cases {
            let e = SourceUri::parse(uri).expect_err(uri);
            assert_eq!(e.part, part, "{uri}: {e}");
            assert!(e.to_string().contains(uri), "{e}");
        }
    }
}
