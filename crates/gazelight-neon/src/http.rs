//! `GET /api/status` of the Real-time API (HTTP/1.1, `Connection: close`),
//! and the sensors it lists.
//!
//! The reply is `{"message": …, "result": [{"model": "Phone" | "Hardware" |
//! "Sensor" | "Recording" | …, "data": {…}}]}`; a `Sensor` has `sensor`
//! (`gaze`, `eye_events`, `world`, `imu`, `eyes`), `conn_type` (`DIRECT` or
//! `WEBSOCKET`), `connected`, `ip`, `port`, `protocol` and `params`, and
//! its stream is at `PROTOCOL://IP:PORT/?PARAMS` (the official client's
//! `models.py`, `Sensor.url`).

use std::time::Duration;

use serde::Deserialize;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tokio::time::timeout;

use crate::NeonError;

/// Largest status reply accepted, bytes.
pub const MAX_STATUS_BYTES: usize = 1024 * 1024;

/// One `Sensor` entry.
#[derive(Clone, Debug, PartialEq, Eq, Deserialize)]
pub struct Sensor {
    pub sensor: String,
    pub conn_type: String,
    #[serde(default)]
    pub connected: bool,
    #[serde(default)]
    pub ip: Option<String>,
    #[serde(default)]
    pub port: Option<u16>,
    #[serde(default)]
    pub protocol: Option<String>,
    #[serde(default)]
    pub params: Option<String>,
}

impl Sensor {
    /// The stream URL, when connected.
    pub fn url(&self) -> Option<String> {
        if !self.connected {
            return None;
        }
        let ip = self.ip.as_deref()?;
        let port = self.port?;
        let proto = self.protocol.as_deref().unwrap_or("rtsp");
        let ip = if ip.contains(':') && !ip.starts_with('[') {
            format!("[{ip}]")
        } else {
            ip.to_owned()
        };
        Some(match self.params.as_deref() {
            Some(p) => format!("{proto}://{ip}:{port}/?{p}"),
            None => format!("{proto}://{ip}:{port}/"),
        })
    }
}

#[derive(Deserialize)]
struct Component {
    model: String,
    #[serde(default)]
    data: serde_json::Value,
}

#[derive(Deserialize)]
struct StatusReply {
    result: Vec<Component>,
}

/// The sensors of a status reply body.
pub fn parse_status(body: &[u8]) -> Result<Vec<Sensor>, NeonError> {
    let reply: StatusReply = serde_json::from_slice(body).map_err(|e| NeonError::Status {
        reason: format!("not the expected JSON: {e}"),
    })?;
    let mut sensors = Vec::new();
    for (i, c) in reply.result.into_iter().enumerate() {
        if c.model != "Sensor" {
            continue;
        }
        let s: Sensor = serde_json::from_value(c.data).map_err(|e| NeonError::Status {
            reason: format!("result[{i}] (Sensor): {e}"),
        })?;
        sensors.push(s);
    }
    Ok(sensors)
}

/// The Time Echo port the status's `Phone` entry names, if any.
pub fn time_echo_port(body: &[u8]) -> Option<u16> {
    let reply: StatusReply = serde_json::from_slice(body).ok()?;
    reply
        .result
        .iter()
        .filter(|c| c.model == "Phone")
        .find_map(|c| c.data.get("time_echo_port")?.as_u64())
        .and_then(|p| u16::try_from(p).ok())
        .filter(|&p| p != 0)
}

/// The DIRECT sensor named `name`.
pub fn direct_sensor<'a>(sensors: &'a [Sensor], name: &str) -> Option<&'a Sensor> {
    sensors
        .iter()
        .filter(|s| s.sensor == name && s.conn_type == "DIRECT")
        .max_by_key(|s| s.connected)
}

/// `GET http://HOST:PORT/api/status` → the body of a 200 reply.
pub async fn get_status(host: &str, port: u16, io_timeout: Duration) -> Result<Vec<u8>, NeonError> {
    let addr = if host.contains(':') {
        format!("[{host}]:{port}")
    } else {
        format!("{host}:{port}")
    };
    let what = format!("GET http://{addr}/api/status");
    let fut = async {
        let mut s = TcpStream::connect(&addr).await.map_err(|e| NeonError::Io {
            what: what.clone(),
            error: e.to_string(),
        })?;
        let req = format!(
            "GET /api/status HTTP/1.1\r\nHost: {addr}\r\nAccept: application/json\r\n\
             Connection: close\r\n\r\n"
        );
        s.write_all(req.as_bytes())
            .await
            .map_err(|e| NeonError::Io {
                what: what.clone(),
                error: e.to_string(),
            })?;
        let mut buf = Vec::new();
        (&mut s)
            .take(MAX_STATUS_BYTES as u64 + 1)
            .read_to_end(&mut buf)
            .await
            .map_err(|e| NeonError::Io {
                what: what.clone(),
                error: e.to_string(),
            })?;
        Ok::<_, NeonError>(buf)
    };
    let raw = match timeout(io_timeout, fut).await {
        Err(_) => {
            return Err(NeonError::Timeout {
                what,
                secs: io_timeout.as_secs_f64(),
            });
        }
        Ok(r) => r?,
    };
    if raw.len() > MAX_STATUS_BYTES {
        return Err(NeonError::Status {
            reason: format!("{what}: reply longer than {MAX_STATUS_BYTES} bytes"),
        });
    }
    parse_http_reply(&raw).map_err(|reason| NeonError::Status {
        reason: format!("{what}: {reason}"),
    })
}

/// The body of a complete HTTP/1.x 200 reply (Content-Length, chunked or
/// up to the close).
pub(crate) fn parse_http_reply(raw: &[u8]) -> Result<Vec<u8>, String> {
    let split = raw
        .windows(4)
        .position(|w| w == b"\r\n\r\n")
        .ok_or_else(|| format!("no end of headers in {} bytes", raw.len()))?;
    let head = String::from_utf8_lossy(&raw[..split]);
    let body = &raw[split + 4..];
    let mut lines = head.split("\r\n");
    let status_line = lines.next().unwrap_or_default();
    let status = status_line
        .strip_prefix("HTTP/1.")
        .and_then(|r| r.get(2..5))
        .and_then(|s| s.parse::<u16>().ok())
        .ok_or_else(|| format!("bad status line `{}`", crate::rtsp::clip(status_line)))?;
    if status != 200 {
        return Err(format!("answered `{}`", crate::rtsp::clip(status_line)));
    }
    let mut length = None;
    let mut chunked = false;
    for l in lines {
        if let Some((k, v)) = l.split_once(':') {
            let (k, v) = (k.trim().to_ascii_lowercase(), v.trim());
            if k == "content-length" {
                length = Some(
                    v.parse::<usize>()
                        .map_err(|_| format!("bad Content-Length `{}`", crate::rtsp::clip(v)))?,
                );
            } else if k == "transfer-encoding" && v.eq_ignore_ascii_case("chunked") {
                chunked = true;
            }
        }
    }
    if chunked {
        return dechunk(body);
    }
    match length {
        Some(n) if n > body.len() => Err(format!(
            "Content-Length {n} but the connection closed after {} bytes",
            body.len()
        )),
        Some(n) => Ok(body[..n].to_vec()),
        None => Ok(body.to_vec()),
    }
}

fn dechunk(mut b: &[u8]) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    loop {
        let eol = b
            .windows(2)
            .position(|w| w == b"\r\n")
            .ok_or("chunk size line not terminated")?;
        let size_text = String::from_utf8_lossy(&b[..eol]);
        let size_hex = size_text.split(';').next().unwrap_or_default().trim();
        let size = usize::from_str_radix(size_hex, 16)
            .map_err(|_| format!("bad chunk size `{}`", crate::rtsp::clip(size_hex)))?;
        b = &b[eol + 2..];
        if size == 0 {
            return Ok(out);
        }
        if size > b.len() {
            return Err(format!("chunk of {size} bytes but {} remain", b.len()));
        }
        out.extend_from_slice(&b[..size]);
        b = b.get(size + 2..).ok_or("chunk not followed by CRLF")?;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn status_sensors_and_urls() {
        // The shape of the official client's docs
        // (docs/methods/async/connect-to-a-device.md).
        let body = br#"{"message":"Success","result":[
            {"model":"Phone","data":{"device_name":"Neon Companion"}},
            {"model":"Sensor","data":{"sensor":"gaze","conn_type":"DIRECT","connected":true,
             "ip":"192.168.1.60","port":8086,"protocol":"rtsp","params":"camera=gaze&audioenable=on"}},
            {"model":"Sensor","data":{"sensor":"gaze","conn_type":"WEBSOCKET","connected":true,
             "ip":"192.168.1.60","port":8686,"protocol":"ws","params":"camera=gaze"}}]}"#;
        let s = parse_status(body).unwrap();
        let g = direct_sensor(&s, "gaze").unwrap();
        assert_eq!(
            g.url().unwrap(),
            "rtsp://192.168.1.60:8086/?camera=gaze&audioenable=on"
        );
        assert!(direct_sensor(&s, "eye_events").is_none());
        assert!(parse_status(b"{\"result\": 3}").is_err());
    }

    #[test]
    fn http_bodies() {
        let r = b"HTTP/1.1 200 OK\r\nContent-Length: 2\r\n\r\n{}xx";
        assert_eq!(parse_http_reply(r).unwrap(), b"{}");
        let r = b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\n2\r\n{}\r\n0\r\n\r\n";
        assert_eq!(parse_http_reply(r).unwrap(), b"{}");
        assert!(parse_http_reply(b"HTTP/1.1 404 Not Found\r\n\r\n").is_err());
        assert!(parse_http_reply(b"HTTP/1.1 200 OK\r\nContent-Length: 9\r\n\r\n{}").is_err());
        assert!(
            parse_http_reply(b"HTTP/1.1 200 OK\r\nTransfer-Encoding: chunked\r\n\r\nffff\r\n{}")
                .is_err()
        );
    }
}
