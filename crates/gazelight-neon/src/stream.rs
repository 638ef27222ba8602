//! One Neon RTP stream (gaze or eye events): DESCRIBE → SDP clock rate →
//! SETUP → PLAY, then packets with their Unix time from the RTCP sender
//! reports. The media come over the RTSP connection itself (TCP
//! interleaved, `$` frames) or as UDP datagrams to a pair of local ports
//! (RTP on an even port, RTCP on the next), as [`RtpTransport`] says.

use std::net::IpAddr;
use std::time::Duration;

use tokio::net::UdpSocket;
use tokio::time::{Instant, timeout};

use crate::NeonError;
use crate::rtp::{RtpClock, RtpPacket, sender_reports};
use crate::rtsp::{Item, RtspConn};
use crate::sdp;

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

/// How the RTP and RTCP packets travel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RtpTransport {
    /// Interleaved on the RTSP TCP connection (`rtspt://`).
    #[default]
    Tcp,
    /// UDP datagrams to two local ports (the official client's default).
    Udp,
}

/// Where the media arrive.
enum Media {
    Interleaved {
        rtp_channel: u8,
        rtcp_channel: u8,
    },
    Udp {
        rtp: UdpSocket,
        rtcp: UdpSocket,
        rtp_buf: Box<[u8]>,
        rtcp_buf: Box<[u8]>,
    },
}

/// What one read brought.
enum Got {
    Rtp(usize),
    Rtcp(usize),
    Skip,
}

/// Largest UDP datagram read.
const DATAGRAM_BYTES: usize = 65_536;

/// Binds an even UDP port and the next one on `ip`.
async fn bind_pair(ip: IpAddr) -> std::io::Result<(UdpSocket, UdpSocket, u16)> {
    for _ in 0..32 {
        let rtp = UdpSocket::bind((ip, 0)).await?;
        let port = rtp.local_addr()?.port();
        if port % 2 != 0 || port == u16::MAX {
            continue;
        }
        if let Ok(rtcp) = UdpSocket::bind((ip, port + 1)).await {
            return Ok((rtp, rtcp, port));
        }
    }
    Err(std::io::Error::new(
        std::io::ErrorKind::AddrInUse,
        "no free even/odd UDP port pair in 32 tries",
    ))
}

/// A playing RTP stream.
pub struct RtpStream {
    conn: RtspConn,
    media: Media,
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
        Self::open_with(url, RtpTransport::Tcp, io_timeout, read_timeout).await
    }

    /// [`Self::open`] over `transport`.
    pub async fn open_with(
        url: &str,
        transport: RtpTransport,
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
        let transport_media = match transport {
            RtpTransport::Tcp => {
                let (rtp_channel, rtcp_channel) = conn.setup_interleaved(&control).await?;
                Media::Interleaved {
                    rtp_channel,
                    rtcp_channel,
                }
            }
            RtpTransport::Udp => {
                let ip = conn.local_ip().unwrap_or(IpAddr::from([0u8, 0, 0, 0]));
                let (rtp, rtcp, port) = bind_pair(ip).await.map_err(|e| NeonError::Io {
                    what: format!("UDP ports for {url}"),
                    error: e.to_string(),
                })?;
                conn.setup_udp(&control, port).await?;
                Media::Udp {
                    rtp,
                    rtcp,
                    rtp_buf: vec![0u8; DATAGRAM_BYTES].into_boxed_slice(),
                    rtcp_buf: vec![0u8; DATAGRAM_BYTES].into_boxed_slice(),
                }
            }
        };
        conn.play(&base).await?;
        let keepalive_every = Duration::from_secs(
            conn.session_timeout_secs
                .map(|t| (t / 2).clamp(1, 30))
                .unwrap_or(20),
        );
        Ok(Self {
            conn,
            media: transport_media,
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
            let got = match timeout(self.read_timeout, self.read()).await {
                Err(_) => {
                    return Err(NeonError::Timeout {
                        what: format!("RTP data from {}", self.conn.url()),
                        secs: self.read_timeout.as_secs_f64(),
                    });
                }
                Ok(r) => r?,
            };
            let len = match got {
                Got::Skip => continue,
                Got::Rtcp(len) => {
                    match sender_reports(self.data(false, len)) {
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
                Got::Rtp(len) => len,
            };
            let buf = self.data(true, len);
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
            let (seq, ts) = (pkt.sequence, pkt.timestamp);
            let start = pkt.payload.as_ptr() as usize - buf.as_ptr() as usize;
            let end = start + pkt.payload.len();
            self.counters.rtp += 1;
            if let Some(prev) = self.last_sequence
                && seq != prev.wrapping_add(1)
            {
                self.counters.sequence_gaps += 1;
            }
            self.last_sequence = Some(seq);
            match self.clock.unix_secs(ts) {
                None => {
                    self.counters.before_first_report += 1;
                    continue;
                }
                Some(t) => break (len, t, seq, ts, start, end),
            }
        };
        let buf = self.data(true, len);
        Ok(Packet {
            unix_secs,
            sequence,
            rtp_timestamp,
            payload: &buf[start..end],
        })
    }

    /// The bytes of the last RTP (`rtp`) or RTCP packet read.
    fn data(&self, rtp: bool, len: usize) -> &[u8] {
        match &self.media {
            Media::Interleaved { .. } => self.conn.frame(len),
            Media::Udp {
                rtp_buf, rtcp_buf, ..
            } => {
                let b = if rtp { rtp_buf } else { rtcp_buf };
                &b[..len.min(b.len())]
            }
        }
    }

    /// Reads the next packet (no timeout of its own): a `$` frame, or a
    /// datagram on either UDP port; RTSP replies (to keepalives) between.
    async fn read(&mut self) -> Result<Got, NeonError> {
        match &mut self.media {
            Media::Interleaved {
                rtp_channel,
                rtcp_channel,
            } => {
                let (channel, len) = match self.conn.read_item().await? {
                    Item::Response(r) => return response(&r, self.conn.url()).map(|()| Got::Skip),
                    Item::Frame { channel, len } => (channel, len),
                };
                Ok(if channel == *rtcp_channel {
                    Got::Rtcp(len)
                } else if channel == *rtp_channel {
                    Got::Rtp(len)
                } else {
                    self.counters.foreign += 1;
                    Got::Skip
                })
            }
            Media::Udp {
                rtp,
                rtcp,
                rtp_buf,
                rtcp_buf,
            } => {
                let url = self.conn.url().to_owned();
                let io = |e: std::io::Error| NeonError::Io {
                    what: format!("UDP media of {url}"),
                    error: e.to_string(),
                };
                tokio::select! {
                    r = rtp.recv(rtp_buf) => Ok(Got::Rtp(r.map_err(io)?)),
                    r = rtcp.recv(rtcp_buf) => Ok(Got::Rtcp(r.map_err(io)?)),
                    item = self.conn.read_item() => match item? {
                        Item::Response(r) => response(&r, &url).map(|()| Got::Skip),
                        Item::Frame { .. } => {
                            self.counters.foreign += 1;
                            Ok(Got::Skip)
                        }
                    },
                }
            }
        }
    }
}

/// A keepalive's reply: fine when 2xx.
fn response(r: &crate::rtsp::Response, url: &str) -> Result<(), NeonError> {
    if (200..300).contains(&r.status) {
        Ok(())
    } else {
        Err(NeonError::Rtsp {
            what: format!("RTSP keepalive to {url}"),
            reason: format!("answered {} {}", r.status, r.reason),
        })
    }
}
