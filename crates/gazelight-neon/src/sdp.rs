//! The parts of an SDP session description (RFC 4566) the Neon client
//! needs: each media's type, payload types, `a=rtpmap` encoding and clock
//! rate, and `a=control` URL.

use crate::NeonError;

/// Largest SDP accepted, bytes.
pub const MAX_SDP_BYTES: usize = 64 * 1024;

/// One `m=` section.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct SdpMedia {
    /// `application`, `video`, …
    pub media: String,
    /// The first payload type of the `m=` line.
    pub payload_type: u8,
    /// `a=rtpmap` encoding name for that payload type (e.g.
    /// `com.pupillabs.gaze1`).
    pub encoding: Option<String>,
    /// `a=rtpmap` clock rate, Hz.
    pub clock_rate_hz: Option<u32>,
    /// `a=control` value.
    pub control: Option<String>,
}

/// Parses the media sections of an SDP.
pub fn parse(text: &str) -> Result<Vec<SdpMedia>, NeonError> {
    let bad = |line: usize, reason: String| NeonError::Sdp {
        reason: format!("line {line}: {reason}"),
    };
    if text.len() > MAX_SDP_BYTES {
        return Err(NeonError::Sdp {
            reason: format!("{} bytes, more than {MAX_SDP_BYTES}", text.len()),
        });
    }
    let mut out: Vec<SdpMedia> = Vec::new();
    for (i, raw) in text.lines().enumerate() {
        let n = i + 1;
        let line = raw.trim_end_matches('\r');
        if let Some(m) = line.strip_prefix("m=") {
            let mut parts = m.split_ascii_whitespace();
            let media = parts.next().unwrap_or_default().to_owned();
            let _port = parts.next();
            let _proto = parts.next();
            let pt = parts
                .next()
                .ok_or_else(|| bad(n, format!("`{line}` has no payload type")))?;
            let payload_type = pt
                .parse::<u8>()
                .ok()
                .filter(|p| *p < 128)
                .ok_or_else(|| bad(n, format!("payload type `{pt}` is not 0..=127")))?;
            out.push(SdpMedia {
                media,
                payload_type,
                encoding: None,
                clock_rate_hz: None,
                control: None,
            });
        } else if let Some(a) = line.strip_prefix("a=") {
            let Some(cur) = out.last_mut() else { continue };
            if let Some(v) = a.strip_prefix("rtpmap:") {
                let (pt, enc) = v
                    .split_once(' ')
                    .ok_or_else(|| bad(n, format!("`{line}`: expected rtpmap:PT NAME/RATE")))?;
                if pt.trim().parse::<u8>().ok() != Some(cur.payload_type) {
                    continue;
                }
                let mut fields = enc.trim().split('/');
                let name = fields.next().unwrap_or_default();
                let rate = fields
                    .next()
                    .ok_or_else(|| bad(n, format!("`{line}` has no clock rate")))?;
                let rate = rate
                    .trim()
                    .parse::<u32>()
                    .ok()
                    .filter(|r| (1..=100_000_000).contains(r))
                    .ok_or_else(|| {
                        bad(n, format!("clock rate `{rate}` is not 1..=100000000 Hz"))
                    })?;
                cur.encoding = Some(name.to_owned());
                cur.clock_rate_hz = Some(rate);
            } else if let Some(v) = a.strip_prefix("control:") {
                cur.control = Some(v.trim().to_owned());
            }
        }
    }
    Ok(out)
}

/// The control URL of a media: absolute as is, `*` or absent = `base`,
/// relative joined to `base` with one `/`.
pub fn control_url(base: &str, control: Option<&str>) -> String {
    match control {
        None | Some("*") | Some("") => base.to_owned(),
        Some(c) if c.starts_with("rtsp://") || c.starts_with("rtspt://") => c.to_owned(),
        Some(c) => {
            if base.ends_with('/') {
                format!("{base}{c}")
            } else {
                format!("{base}/{c}")
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaze_track() {
        let sdp = "v=0\r\no=- 0 0 IN IP4 127.0.0.1\r\ns=x\r\nt=0 0\r\n\
                   m=application 0 RTP/AVP 99\r\na=rtpmap:99 com.pupillabs.gaze1/90000\r\n\
                   a=control:trackID=0\r\n";
        let m = parse(sdp).unwrap();
        assert_eq!(m.len(), 1);
        assert_eq!(m[0].media, "application");
        assert_eq!(m[0].encoding.as_deref(), Some("com.pupillabs.gaze1"));
        assert_eq!(m[0].clock_rate_hz, Some(90_000));
        assert_eq!(
            control_url("rtsp://h:8086/?camera=gaze", m[0].control.as_deref()),
            "rtsp://h:8086/?camera=gaze/trackID=0"
        );
    }

    #[test]
    fn bad_lines_name_the_line() {
        for bad in [
            "m=application 0 RTP/AVP\n",
            "m=application 0 RTP/AVP 300\n",
            "m=application 0 RTP/AVP 99\na=rtpmap:99 x\n",
            "m=application 0 RTP/AVP 99\na=rtpmap:99 x/0\n",
            "m=application 0 RTP/AVP 99\na=rtpmap:99 x/abc\n",
        ] {
            let e = parse(bad).unwrap_err().to_string();
            assert!(e.contains("line"), "{bad}: {e}");
        }
    }
}
