//! # gazelight-neon
//!
//! One job: live Pupil Labs Neon through its Real-time API, from the
//! phone's HTTP status to [`gazelight_eye::Sample`]s on the host clock
//! ([`NeonSource`]). Recorded Neon sessions are read by
//! `gazelight-import` (`neon`), not here; Pupil Core is `gazelight-pupil`.
//!
//! How a Neon streams (checked against Pupil Labs' official Python client
//! `pupil-labs/realtime-python-api`: `models.py`, `streaming/base.py`,
//! `streaming/gaze.py`, `streaming/eye_events.py`):
//!
//! - `GET http://HOST:8080/api/status` lists the sensors; the `DIRECT`
//!   `gaze` and `eye_events` sensors give RTSP URLs such as
//!   `rtsp://192.168.1.60:8086/?camera=gaze&audioenable=on` ([`http`]).
//! - Each URL is one RTSP presentation with one RTP media whose SDP
//!   `a=rtpmap` carries the clock rate ([`sdp`], [`rtsp`]). gazelight plays
//!   it over TCP interleaved (`RTP/AVP/TCP;unicast;interleaved=0-1`, the
//!   default) or over UDP (`RTP/AVP;unicast;client_port=A-B`, the official
//!   client's default; `neon://…?transport=udp`) ([`stream`]).
//! - The RTSP client is written here (a few hundred lines: DESCRIBE, SETUP,
//!   PLAY, OPTIONS keepalives, `$` frames) rather than taken from a crate:
//!   `retina`, the one Rust RTSP client that fits, is built around audio
//!   and video depacketisers and its own session state machine, and would
//!   have added a large dependency tree for two `application` streams of
//!   raw RTP payloads.
//! - The payload carries no time: Unix time = RTP timestamp / clock rate,
//!   anchored by the latest RTCP sender report ([`rtp`]); the 32-bit
//!   timestamp is extended to 64 bits so its wrap does not move the time.
//! - Gaze payloads are decoded by length ([`payload`]): pupil diameters in
//!   mm and eyelid apertures need "Compute eye state" on in the Companion
//!   app (65/89/105-byte packets); without it the 9–25-byte packets carry
//!   no pupil and the source says so.
//!
//! [`NeonSource`] (URI `neon://HOST[:PORT]`, port 8080 by default) runs
//! both streams in a task that reconnects with a bounded backoff and
//! delivers [`gazelight_eye::Sample`]s on the host clock: at each
//! connection the phone's clock is measured against the host's with Pupil
//! Labs' Time Echo protocol ([`time_echo`], when the status names its port;
//! else both clocks are assumed to follow NTP), and a sample's host time is
//! its Unix time on the phone's clock mapped through that offset by the
//! source's [`gazelight_eye::clock::SourceClock`], which checks each
//! packet's time against its arrival (a sender report or a Time Echo answer
//! that lies is overruled by the packets, see [`source`]). Neons on the
//! network are found by mDNS ([`discover`]).

pub mod discover;
pub mod http;
pub mod payload;
pub mod rtp;
pub mod rtsp;
pub mod sdp;
pub mod source;
pub mod stream;
pub mod time_echo;

pub use source::{DEFAULT_HTTP_PORT, NeonConfig, NeonSource, NeonStats};
pub use stream::RtpStream;

/// Errors of the Neon client. Every message names what and where.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum NeonError {
    /// A URI or URL that cannot be used.
    #[error("`{url}`: {reason}")]
    Url { url: String, reason: String },
    /// A socket operation failed.
    #[error("{what}: {error}")]
    Io { what: String, error: String },
    /// The peer closed the connection.
    #[error("{what}: closed by the peer")]
    Closed { what: String },
    /// Nothing arrived in time.
    #[error("{what}: nothing within {secs:.1} s")]
    Timeout { what: String, secs: f64 },
    /// `/api/status` could not be used.
    #[error("Neon status: {reason}")]
    Status { reason: String },
    /// An RTSP exchange failed.
    #[error("{what}: {reason}")]
    Rtsp { what: String, reason: String },
    /// The SDP cannot be used.
    #[error("SDP: {reason}")]
    Sdp { reason: String },
    /// One malformed packet (skipped; the stream goes on).
    #[error("malformed {what}: {reason}")]
    Packet { what: &'static str, reason: String },
}

/// `HOST[:PORT]` (IPv6 in brackets) → (host, port).
pub(crate) fn split_host_port(authority: &str, default_port: u16) -> Result<(String, u16), String> {
    let (host, port) = if let Some(rest) = authority.strip_prefix('[') {
        let (h, after) = rest
            .split_once(']')
            .ok_or("IPv6 host without a closing `]`")?;
        (h, after.strip_prefix(':'))
    } else {
        match authority.rsplit_once(':') {
            Some((h, p)) => (h, Some(p)),
            None => (authority, None),
        }
    };
    if host.is_empty() {
        return Err("empty host".to_owned());
    }
    let port = match port {
        None => default_port,
        Some(p) => p
            .parse::<u16>()
            .ok()
            .filter(|p| *p != 0)
            .ok_or_else(|| format!("port `{p}` is not 1..=65535"))?,
    };
    Ok((host.to_owned(), port))
}
