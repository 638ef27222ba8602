//! One Neon RTP stream (gaze or eye events) over RTSP/TCP interleaved:
//! DESCRIBE → SDP clock rate → SETUP → PLAY, then packets with their Unix
//! time from the RTCP sender reports.

use std::time::Duration;

use tokio::time::{Instant, timeout};

use super::NeonError;
use super::rtp::{RtpClock, RtpPacket, sender_reports};
use super::rtsp::{Item, RtspConn};
use super::sdp;

/// Counters of one stream.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StreamCounters {
    /// RTP packets received.
    pub rtp: u64,
    /// RTP packets dropped because no sender report had arrived yet.
    pub before_first_report: u64,
    /// RTP packets of another payload type or on another channel.
    pub foreign: u64,
    /// Sender reports applied.
    pub sender_reports: u64,
    /// Malformed RTP/RTCP packets skipped.
    pub malformed: u64,
    /// Sequence-number gaps (packets lost or reordered).
    pub sequence_gaps: u64,
}

/// One RTP payload with its time.
#[derive(Debug)]
pub struct Packet<'a> {
    /// Unix time from the RTP timestamp and the latest sender report, s.
    pub unix_secs: f64,
    pub sequence: u16,
    pub rtp_timestamp: u32,
    pub payload: &'a [u8],
}

/// A playing RTP stream.
pub struct RtpStream {
    conn: RtspConn,
    rtp_channel: u8,
    rtcp_channel: u8,
    payload_type: u8,
    clock: RtpClock,
    encoding: Option<String>,
    read_timeout: Duration,
    keepalive_every: Duration,
    last_keepalive: Instant,
    last_sequence: Option<u16>,
    counters: StreamCounters,
}

impl RtpStream {
    /// Connects to `url` and starts playing its first media.
    /// `io_timeout` bounds each request, `read_timeout` each packet wait.
    pub async fn open(
        url: &str,
        io_timeout: Duration,
        read_timeout: Duration,
    ) -> Result<Self, NeonError> {
        let mut conn = RtspConn::connect(url, io_timeout).await?;
        let (sdp_text, base) = conn.describe().await?;
        let medias = sdp::parse(&sdp_text)?;
        let media = medias.first().ok_or_else(|| NeonError::Sdp {
            reason: format!("DESCRIBE {url}: the SDP has no m= line"),
        })?;
        let clock_rate = media.clock_rate_hz.ok_or_else(|| NeonError::Sdp {
            reason: format!(
                "DESCRIBE {url}: no a=rtpmap clock rate for payload type {}",
                media.payload_type
            ),
        })?;
        let control = sdp::control_url(&base, media.control.as_deref());
        let (rtp_channel, rtcp_channel) = conn.setup_interleaved(&control).await?;
        conn.play(&base).await?;
        let keepalive_every = Duration::from_secs(
            conn.session_timeout_secs
                .map(|t| (t / 2).clamp(1, 30))
                .unwrap_or(20),
        );
        Ok(Self {
            conn,
            rtp_channel,
            rtcp_channel,
            payload_type: media.payload_type,
            clock: RtpClock::new(clock_rate),
            encoding: media.encoding.clone(),
            read_timeout,
            keepalive_every,
            last_keepalive: Instant::now(),
            last_sequence: None,
            counters: StreamCounters::default(),
        })
    }

    /// The SDP clock rate, Hz.
    pub fn clock_rate_hz(&self) -> u32 {
        self.clock.clock_rate_hz()
    }

    /// The SDP encoding name (e.g. `com.pupillabs.gaze1`).
    pub fn encoding(&self) -> Option<&str> {
        self.encoding.as_deref()
    }

    /// The counters so far.
    pub fn counters(&self) -> StreamCounters {
        self.counters
    }

    /// The URL played.
    pub fn url(&self) -> &str {
        self.conn.url()
    }

    /// The next timed RTP payload. A [`NeonError::Packet`] is one
    /// malformed packet (counted; the stream goes on); any other error
    /// means the stream is lost.
    pub async fn next_packet(&mut self) -> Result<Packet<'_>, NeonError> {
        let (len, unix_secs, sequence, rtp_timestamp, start, end) = loop {
            if self.last_keepalive.elapsed() >= self.keepalive_every {
                self.conn.keepalive().await?;
                self.last_keepalive = Instant::now();
            }
            let item = match timeout(self.read_timeout, self.conn.read_item()).await {
                Err(_) => {
                    return Err(NeonError::Timeout {
                        what: format!("RTP data from {}", self.conn.url()),
                        secs: self.read_timeout.as_secs_f64(),
                    });
                }
                Ok(r) => r?,
            };
            let (channel, len) = match item {
                Item::Response(r) if (200..300).contains(&r.status) => continue,
                Item::Response(r) => {
                    return Err(NeonError::Rtsp {
                        what: format!("RTSP keepalive to {}", self.conn.url()),
                        reason: format!("answered {} {}", r.status, r.reason),
                    });
                }
                Item::Frame { channel, len } => (channel, len),
            };
            let buf = self.conn.frame(len);
            if channel == self.rtcp_channel {
                match sender_reports(buf) {
                    Ok(reports) => {
                        for r in &reports {
                            self.clock.apply(r);
                            self.counters.sender_reports += 1;
                        }
                    }
                    Err(e) => {
                        self.counters.malformed += 1;
                        return Err(e);
                    }
                }
                continue;
            }
            if channel != self.rtp_channel {
                self.counters.foreign += 1;
                continue;
            }
            let pkt = match RtpPacket::parse(buf) {
                Ok(p) => p,
                Err(e) => {
                    self.counters.malformed += 1;
                    return Err(e);
                }
            };
            if pkt.payload_type != self.payload_type {
                self.counters.foreign += 1;
                continue;
            }
            self.counters.rtp += 1;
            if let Some(prev) = self.last_sequence
                && pkt.sequence != prev.wrapping_add(1)
            {
                self.counters.sequence_gaps += 1;
            }
            self.last_sequence = Some(pkt.sequence);
            let (seq, ts) = (pkt.sequence, pkt.timestamp);
            let start = pkt.payload.as_ptr() as usize - buf.as_ptr() as usize;
            let end = start + pkt.payload.len();
            match self.clock.unix_secs(ts) {
                None => {
                    self.counters.before_first_report += 1;
                    continue;
                }
                Some(t) => break (len, t, seq, ts, start, end),
            }
        };
        let buf = self.conn.frame(len);
        Ok(Packet {
            unix_secs,
            sequence,
            rtp_timestamp,
            payload: &buf[start..end],
        })
    }
}
