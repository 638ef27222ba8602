//! A small RTSP 1.0 client (RFC 2326) for one RTP stream over TCP
//! interleaved: DESCRIBE, SETUP (`RTP/AVP/TCP;unicast;interleaved=0-1`),
//! PLAY, OPTIONS keepalives, then `$`-framed RTP/RTCP (RFC 2326 §10.12).
//!
//! Every read is bounded in size (headers [`MAX_HEAD_BYTES`], bodies
//! [`MAX_BODY_BYTES`], frames ≤ 65 535 bytes by their u16 length) and in
//! time (the caller's timeout). Nothing allocates from a length before it
//! is checked.

use std::time::Duration;

use tokio::io::{AsyncBufReadExt, AsyncReadExt, AsyncWriteExt, BufReader};
use tokio::net::TcpStream;
use tokio::time::timeout;

use crate::NeonError;

/// Largest response head (status line and headers), bytes.
pub const MAX_HEAD_BYTES: usize = 16 * 1024;
/// Largest response body, bytes.
pub const MAX_BODY_BYTES: usize = 64 * 1024;
/// Default RTSP port (RFC 2326 §3.2); Neon serves on 8086.
pub const DEFAULT_RTSP_PORT: u16 = 554;

/// `rtsp://HOST[:PORT]/…` → (host, port). `rtspt://` is accepted too.
pub fn host_port(url: &str) -> Result<(String, u16), NeonError> {
    let bad = |reason: &str| NeonError::Url {
        url: url.to_owned(),
        reason: reason.to_owned(),
    };
    let rest = url
        .strip_prefix("rtsp://")
        .or_else(|| url.strip_prefix("rtspt://"))
        .ok_or_else(|| bad("expected rtsp://HOST[:PORT]/…"))?;
    let authority = rest.split(['/', '?']).next().unwrap_or_default();
    crate::split_host_port(authority, DEFAULT_RTSP_PORT).map_err(|r| bad(&r))
}

/// One RTSP response.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Response {
    pub status: u16,
    pub reason: String,
    /// Headers, names lower-cased.
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Response {
    /// The first header named `name` (lower case).
    pub fn header(&self, name: &str) -> Option<&str> {
        self.headers
            .iter()
            .find(|(k, _)| k == name)
            .map(|(_, v)| v.as_str())
    }
}

/// What arrives on an interleaved connection.
#[derive(Debug)]
pub enum Item {
    /// A `$` frame on `channel`, its bytes in the connection's frame buffer.
    Frame { channel: u8, len: usize },
    /// An RTSP response (to a keepalive).
    Response(Response),
}

/// An RTSP connection.
pub struct RtspConn {
    io: BufReader<TcpStream>,
    url: String,
    cseq: u32,
    session: Option<String>,
    /// Session timeout the server announced, seconds.
    pub session_timeout_secs: Option<u64>,
    frame: Box<[u8; 65_536]>,
    io_timeout: Duration,
}

impl RtspConn {
    /// Connects to the host of `url`.
    pub async fn connect(url: &str, io_timeout: Duration) -> Result<Self, NeonError> {
        let (host, port) = host_port(url)?;
        let addr = format!("{host}:{port}");
        let stream = match timeout(io_timeout, TcpStream::connect(&addr)).await {
            Err(_) => {
                return Err(NeonError::Timeout {
                    what: format!("RTSP connect to {addr}"),
                    secs: io_timeout.as_secs_f64(),
                });
            }
            Ok(Err(e)) => {
                return Err(NeonError::Io {
                    what: format!("RTSP connect to {addr}"),
                    error: e.to_string(),
                });
            }
            Ok(Ok(s)) => s,
        };
        let _ = stream.set_nodelay(true);
        Ok(Self {
            io: BufReader::with_capacity(64 * 1024, stream),
            url: url.to_owned(),
            cseq: 0,
            session: None,
            session_timeout_secs: None,
            frame: Box::new([0u8; 65_536]),
            io_timeout,
        })
    }

    /// The URL this connection was made for.
    pub fn url(&self) -> &str {
        &self.url
    }

    /// The bytes of the last [`Item::Frame`].
    pub fn frame(&self, len: usize) -> &[u8] {
        &self.frame[..len.min(self.frame.len())]
    }

    async fn send(
        &mut self,
        method: &str,
        url: &str,
        extra: &[(&str, &str)],
    ) -> Result<(), NeonError> {
        self.cseq += 1;
        let mut req = format!(
            "{method} {url} RTSP/1.0\r\nCSeq: {}\r\nUser-Agent: gazelight\r\n",
            self.cseq
        );
        if let Some(s) = &self.session {
            req.push_str(&format!("Session: {s}\r\n"));
        }
        for (k, v) in extra {
            req.push_str(&format!("{k}: {v}\r\n"));
        }
        req.push_str("\r\n");
        let what = format!("RTSP {method} to {url}");
        match timeout(self.io_timeout, self.io.get_mut().write_all(req.as_bytes())).await {
            Err(_) => Err(NeonError::Timeout {
                what,
                secs: self.io_timeout.as_secs_f64(),
            }),
            Ok(Err(e)) => Err(NeonError::Io {
                what,
                error: e.to_string(),
            }),
            Ok(Ok(())) => Ok(()),
        }
    }

    /// Sends a request and reads its response, skipping interleaved frames
    /// that arrive first; a non-2xx status is an error.
    pub async fn request(
        &mut self,
        method: &str,
        url: &str,
        extra: &[(&str, &str)],
    ) -> Result<Response, NeonError> {
        self.send(method, url, extra).await?;
        let limit = self.io_timeout;
        let what = format!("RTSP {method} {url}");
        let fut = async {
            loop {
                match self.read_item().await? {
                    Item::Frame { .. } => continue,
                    Item::Response(r) => return Ok::<_, NeonError>(r),
                }
            }
        };
        let r = match timeout(limit, fut).await {
            Err(_) => {
                return Err(NeonError::Timeout {
                    what: format!("reply to {what}"),
                    secs: limit.as_secs_f64(),
                });
            }
            Ok(r) => r?,
        };
        if !(200..300).contains(&r.status) {
            return Err(NeonError::Rtsp {
                what,
                reason: format!("answered {} {}", r.status, r.reason),
            });
        }
        Ok(r)
    }

    /// DESCRIBE → (SDP text, base URL for relative controls).
    pub async fn describe(&mut self) -> Result<(String, String), NeonError> {
        let url = self.url.clone();
        let r = self
            .request("DESCRIBE", &url, &[("Accept", "application/sdp")])
            .await?;
        let base = r
            .header("content-base")
            .or_else(|| r.header("content-location"))
            .unwrap_or(&url)
            .to_owned();
        let sdp = String::from_utf8(r.body).map_err(|_| NeonError::Sdp {
            reason: format!("DESCRIBE {url}: the SDP is not UTF-8"),
        })?;
        Ok((sdp, base))
    }

    /// SETUP over TCP interleaved → (RTP channel, RTCP channel).
    pub async fn setup_interleaved(&mut self, control: &str) -> Result<(u8, u8), NeonError> {
        let r = self
            .request(
                "SETUP",
                control,
                &[("Transport", "RTP/AVP/TCP;unicast;interleaved=0-1")],
            )
            .await?;
        self.take_session(&r, control)?;
        let mut channels = (0u8, 1u8);
        if let Some(t) = r.header("transport")
            && let Some(il) = t
                .split(';')
                .find_map(|p| p.trim().strip_prefix("interleaved="))
        {
            let (a, b) = il.split_once('-').unwrap_or((il, ""));
            let a = a.parse::<u8>().map_err(|_| NeonError::Rtsp {
                what: format!("RTSP SETUP {control}"),
                reason: format!("bad interleaved channels `{il}`"),
            })?;
            let b = b.parse::<u8>().unwrap_or(a.wrapping_add(1));
            channels = (a, b);
        }
        Ok(channels)
    }

    /// SETUP over UDP: RTP to this host's `rtp_port`, RTCP to the next
    /// port. A reply that does not take UDP is an error naming it.
    pub async fn setup_udp(&mut self, control: &str, rtp_port: u16) -> Result<(), NeonError> {
        let transport = format!(
            "RTP/AVP;unicast;client_port={rtp_port}-{}",
            rtp_port.saturating_add(1)
        );
        let r = self
            .request("SETUP", control, &[("Transport", transport.as_str())])
            .await?;
        self.take_session(&r, control)?;
        if let Some(t) = r.header("transport")
            && (t.contains("/TCP") || t.contains("interleaved="))
        {
            return Err(NeonError::Rtsp {
                what: format!("RTSP SETUP {control}"),
                reason: format!("asked for UDP, the server answered `{}`", clip(t)),
            });
        }
        Ok(())
    }

    /// The local address of the RTSP connection (where UDP media should
    /// arrive).
    pub fn local_ip(&self) -> Option<std::net::IpAddr> {
        self.io.get_ref().local_addr().ok().map(|a| a.ip())
    }

    /// Keeps the Session header (and its timeout) of a SETUP reply.
    fn take_session(&mut self, r: &Response, control: &str) -> Result<(), NeonError> {
        let session = r.header("session").ok_or_else(|| NeonError::Rtsp {
            what: format!("RTSP SETUP {control}"),
            reason: "reply has no Session header".to_owned(),
        })?;
        let mut parts = session.split(';');
        let id = parts.next().unwrap_or_default().trim().to_owned();
        if id.is_empty() || id.len() > 256 {
            return Err(NeonError::Rtsp {
                what: format!("RTSP SETUP {control}"),
                reason: format!("bad Session header `{session}`"),
            });
        }
        self.session_timeout_secs = parts
            .filter_map(|p| p.trim().strip_prefix("timeout="))
            .find_map(|t| t.parse::<u64>().ok());
        self.session = Some(id);
        Ok(())
    }

    /// PLAY the whole presentation.
    pub async fn play(&mut self, url: &str) -> Result<(), NeonError> {
        self.request("PLAY", url, &[("Range", "npt=0.000-")])
            .await?;
        Ok(())
    }

    /// Sends an OPTIONS keepalive without waiting for its reply (the reply
    /// arrives as an [`Item::Response`] between frames).
    pub async fn keepalive(&mut self) -> Result<(), NeonError> {
        let url = self.url.clone();
        self.send("OPTIONS", &url, &[]).await
    }

    /// Reads the next frame or response (no timeout of its own).
    pub async fn read_item(&mut self) -> Result<Item, NeonError> {
        let first = {
            let buf = self.io.fill_buf().await.map_err(|e| NeonError::Io {
                what: format!("RTSP read from {}", self.url),
                error: e.to_string(),
            })?;
            match buf.first() {
                None => {
                    return Err(NeonError::Closed {
                        what: format!("RTSP connection to {}", self.url),
                    });
                }
                Some(b) => *b,
            }
        };
        if first == b'$' {
            let mut head = [0u8; 4];
            self.read_exact(&mut head).await?;
            let len = usize::from(u16::from_be_bytes([head[2], head[3]]));
            let (url, io) = (&self.url, &mut self.io);
            io.read_exact(&mut self.frame[..len])
                .await
                .map_err(|e| NeonError::Io {
                    what: format!("RTSP interleaved frame of {len} bytes from {url}"),
                    error: e.to_string(),
                })?;
            return Ok(Item::Frame {
                channel: head[1],
                len,
            });
        }
        self.read_response().await.map(Item::Response)
    }

    async fn read_exact(&mut self, buf: &mut [u8]) -> Result<(), NeonError> {
        self.io
            .read_exact(buf)
            .await
            .map(|_| ())
            .map_err(|e| NeonError::Io {
                what: format!("RTSP read from {}", self.url),
                error: e.to_string(),
            })
    }

    async fn read_response(&mut self) -> Result<Response, NeonError> {
        let what = format!("RTSP reply from {}", self.url);
        let mut head_bytes = 0usize;
        let mut lines: Vec<String> = Vec::new();
        loop {
            let mut line = Vec::new();
            let n = (&mut self.io)
                .take((MAX_HEAD_BYTES - head_bytes + 1) as u64)
                .read_until(b'\n', &mut line)
                .await
                .map_err(|e| NeonError::Io {
                    what: what.clone(),
                    error: e.to_string(),
                })?;
            if n == 0 {
                return Err(NeonError::Closed { what });
            }
            head_bytes += n;
            if head_bytes > MAX_HEAD_BYTES {
                return Err(NeonError::Rtsp {
                    what,
                    reason: format!("header longer than {MAX_HEAD_BYTES} bytes"),
                });
            }
            let text = String::from_utf8_lossy(&line).trim_end().to_owned();
            if text.is_empty() {
                if lines.is_empty() {
                    continue; // stray CRLF between messages
                }
                break;
            }
            lines.push(text);
        }
        let status_line = &lines[0];
        let mut parts = status_line.splitn(3, ' ');
        let proto = parts.next().unwrap_or_default();
        if !proto.starts_with("RTSP/") {
            return Err(NeonError::Rtsp {
                what,
                reason: format!("expected an RTSP status line, got `{}`", clip(status_line)),
            });
        }
        let status = parts
            .next()
            .and_then(|s| s.parse::<u16>().ok())
            .ok_or_else(|| NeonError::Rtsp {
                what: what.clone(),
                reason: format!("bad status line `{}`", clip(status_line)),
            })?;
        let reason = parts.next().unwrap_or_default().to_owned();
        let headers: Vec<(String, String)> = lines[1..]
            .iter()
            .filter_map(|l| l.split_once(':'))
            .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_owned()))
            .collect();
        let len = match headers.iter().find(|(k, _)| k == "content-length") {
            None => 0,
            Some((_, v)) => v
                .parse::<usize>()
                .ok()
                .filter(|n| *n <= MAX_BODY_BYTES)
                .ok_or_else(|| NeonError::Rtsp {
                    what: what.clone(),
                    reason: format!("Content-Length `{v}` is not 0..={MAX_BODY_BYTES}"),
                })?,
        };
        let mut body = vec![0u8; len];
        self.read_exact(&mut body).await?;
        Ok(Response {
            status,
            reason,
            headers,
            body,
        })
    }
}

/// The first 80 characters of a line, for an error message.
pub(crate) fn clip(s: &str) -> String {
    s.chars().take(80).collect()
}
