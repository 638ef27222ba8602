//! RTP packets, RTCP sender reports and the RTP-to-Unix clock (RFC 3550).
//!
//! Neon puts no timestamp in its gaze payload: a packet's Unix time is its
//! RTP timestamp divided by the clock rate from the SDP, anchored by the
//! latest RTCP sender report, which pairs an RTP timestamp with an NTP
//! wall-clock time (RFC 3550 §6.4.1). The 32-bit RTP timestamp wraps
//! (after 13.3 h at 90 kHz, or at any time from a random start): every
//! timestamp is extended to 64 bits against the newest one seen, so a wrap
//! between two sender reports does not move the time.

use crate::NeonError;

/// Fixed RTP header length (RFC 3550 §5.1).
pub const RTP_HEADER_LEN: usize = 12;
/// RTCP packet type of a sender report (RFC 3550 §6.4.1).
pub const RTCP_SR: u8 = 200;
/// Seconds from the NTP epoch (1900-01-01) to the Unix epoch (1970-01-01).
pub const NTP_UNIX_OFFSET_SECS: u64 = 2_208_988_800;

/// One RTP packet, borrowing its payload.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RtpPacket<'a> {
    pub payload_type: u8,
    pub marker: bool,
    pub sequence: u16,
    pub timestamp: u32,
    pub ssrc: u32,
    pub payload: &'a [u8],
}

impl<'a> RtpPacket<'a> {
    /// Parses an RTP packet; every length is checked against the buffer.
    pub fn parse(buf: &'a [u8]) -> Result<Self, NeonError> {
        let bad = |reason: String| NeonError::Packet {
            what: "RTP packet",
            reason,
        };
        if buf.len() < RTP_HEADER_LEN {
            return Err(bad(format!(
                "{} bytes, shorter than the {RTP_HEADER_LEN}-byte header",
                buf.len()
            )));
        }
        let version = buf[0] >> 6;
        if version != 2 {
            return Err(bad(format!("version {version}, expected 2")));
        }
        let padding = buf[0] & 0x20 != 0;
        let extension = buf[0] & 0x10 != 0;
        let csrc_count = usize::from(buf[0] & 0x0f);
        let mut start = RTP_HEADER_LEN + 4 * csrc_count;
        if buf.len() < start {
            return Err(bad(format!(
                "{} bytes, shorter than the header with {csrc_count} CSRCs ({start})",
                buf.len()
            )));
        }
        if extension {
            if buf.len() < start + 4 {
                return Err(bad(format!(
                    "header extension at byte {start} cut off ({} bytes)",
                    buf.len()
                )));
            }
            let words = usize::from(u16::from_be_bytes([buf[start + 2], buf[start + 3]]));
            start += 4 + 4 * words;
            if buf.len() < start {
                return Err(bad(format!(
                    "header extension of {words} words runs past the packet end ({} bytes)",
                    buf.len()
                )));
            }
        }
        let mut end = buf.len();
        if padding {
            let pad = usize::from(buf[end - 1]);
            if pad == 0 || start + pad > end {
                return Err(bad(format!(
                    "padding of {pad} bytes does not fit a {}-byte payload",
                    end - start
                )));
            }
            end -= pad;
        }
        Ok(Self {
            payload_type: buf[1] & 0x7f,
            marker: buf[1] & 0x80 != 0,
            sequence: u16::from_be_bytes([buf[2], buf[3]]),
            timestamp: u32::from_be_bytes([buf[4], buf[5], buf[6], buf[7]]),
            ssrc: u32::from_be_bytes([buf[8], buf[9], buf[10], buf[11]]),
            payload: &buf[start..end],
        })
    }
}

/// The part of an RTCP sender report the clock needs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SenderReport {
    pub ssrc: u32,
    /// The report's NTP time as Unix seconds.
    pub unix_secs: f64,
    /// The RTP timestamp that corresponds to `unix_secs`.
    pub rtp_timestamp: u32,
}

/// Converts a 64-bit NTP timestamp (seconds since 1900, 32.32 fixed point)
/// to Unix seconds.
pub fn ntp_to_unix_secs(msw: u32, lsw: u32) -> f64 {
    (f64::from(msw) - NTP_UNIX_OFFSET_SECS as f64) + f64::from(lsw) / 4_294_967_296.0
}

/// The sender reports in a compound RTCP packet (other packet types are
/// skipped). Every packet's length field is checked against the buffer.
pub fn sender_reports(buf: &[u8]) -> Result<Vec<SenderReport>, NeonError> {
    let bad = |reason: String| NeonError::Packet {
        what: "RTCP packet",
        reason,
    };
    let mut out = Vec::new();
    let mut at = 0usize;
    while at < buf.len() {
        if buf.len() - at < 4 {
            return Err(bad(format!(
                "{} trailing bytes at byte {at}, shorter than an RTCP header",
                buf.len() - at
            )));
        }
        let version = buf[at] >> 6;
        if version != 2 {
            return Err(bad(format!("version {version} at byte {at}, expected 2")));
        }
        let packet_type = buf[at + 1];
        let len = 4 * (usize::from(u16::from_be_bytes([buf[at + 2], buf[at + 3]])) + 1);
        if at + len > buf.len() {
            return Err(bad(format!(
                "packet at byte {at} says {len} bytes, {} remain",
                buf.len() - at
            )));
        }
        if packet_type == RTCP_SR {
            if len < 28 {
                return Err(bad(format!(
                    "sender report at byte {at} is {len} bytes, shorter than 28"
                )));
            }
            let word = |i: usize| {
                let o = at + 4 + 4 * i;
                u32::from_be_bytes([buf[o], buf[o + 1], buf[o + 2], buf[o + 3]])
            };
            out.push(SenderReport {
                ssrc: word(0),
                unix_secs: ntp_to_unix_secs(word(1), word(2)),
                rtp_timestamp: word(3),
            });
        }
        at += len;
    }
    Ok(out)
}

/// RTP timestamps to Unix seconds: 64-bit extension of the 32-bit
/// timestamp, anchored by the latest sender report.
#[derive(Clone, Debug)]
pub struct RtpClock {
    clock_rate_hz: u32,
    /// The newest extended timestamp seen.
    newest: Option<i64>,
    /// (extended RTP timestamp, Unix seconds) of the latest sender report.
    anchor: Option<(i64, f64)>,
    reports: u64,
}

impl RtpClock {
    /// A clock for `clock_rate_hz` (the SDP's rtpmap rate, > 0).
    pub fn new(clock_rate_hz: u32) -> Self {
        Self {
            clock_rate_hz: clock_rate_hz.max(1),
            newest: None,
            anchor: None,
            reports: 0,
        }
    }

    /// The clock rate, Hz.
    pub fn clock_rate_hz(&self) -> u32 {
        self.clock_rate_hz
    }

    /// Sender reports applied so far.
    pub fn reports(&self) -> u64 {
        self.reports
    }

    /// Extends a 32-bit timestamp to 64 bits: the nearest value (within
    /// ±2³¹ ticks) to the newest timestamp seen. Reordered (older) packets
    /// do not move the reference back.
    pub fn extend(&mut self, timestamp: u32) -> i64 {
        let ext = match self.newest {
            None => i64::from(timestamp),
            Some(newest) => {
                // Two's-complement difference of the low 32 bits.
                let delta = timestamp.wrapping_sub(newest as u32) as i32;
                newest + i64::from(delta)
            }
        };
        if self.newest.is_none_or(|n| ext > n) {
            self.newest = Some(ext);
        }
        ext
    }

    /// Anchors the clock on a sender report.
    pub fn apply(&mut self, report: &SenderReport) {
        let ext = self.extend(report.rtp_timestamp);
        self.anchor = Some((ext, report.unix_secs));
        self.reports += 1;
    }

    /// Unix seconds of an RTP timestamp; `None` until the first sender
    /// report.
    pub fn unix_secs(&mut self, timestamp: u32) -> Option<f64> {
        let ext = self.extend(timestamp);
        let (a_ext, a_unix) = self.anchor?;
        Some(a_unix + (ext - a_ext) as f64 / f64::from(self.clock_rate_hz))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rtp(ts: u32, payload: &[u8]) -> Vec<u8> {
        let mut v = vec![0x80, 99, 0, 1];
        v.extend_from_slice(&ts.to_be_bytes());
        v.extend_from_slice(&7u32.to_be_bytes());
        v.extend_from_slice(payload);
        v
    }

    #[test]
    fn parses_header_and_rejects_short_or_bad() {
        let p = rtp(0xdead_beef, &[1, 2, 3]);
        let pkt = RtpPacket::parse(&p).unwrap();
        assert_eq!(pkt.payload_type, 99);
        assert_eq!(pkt.timestamp, 0xdead_beef);
        assert_eq!(pkt.payload, &[1, 2, 3]);
        assert!(RtpPacket::parse(&p[..11]).is_err());
        let mut v1 = p.clone();
        v1[0] = 0x40;
        assert!(RtpPacket::parse(&v1).is_err());
        // 15 CSRCs claimed, none present.
        let mut cc = p.clone();
        cc[0] = 0x8f;
        assert!(RtpPacket::parse(&cc).is_err());
        // Padding longer than the payload.
        let mut pad = p.clone();
        pad[0] |= 0x20;
        *pad.last_mut().unwrap() = 200;
        assert!(RtpPacket::parse(&pad).is_err());
    }

    #[test]
    fn ntp_epoch_conversion() {
        // RFC 3550: NTP seconds since 1900; 2208988800 s to 1970 (RFC 868).
        assert_eq!(ntp_to_unix_secs(2_208_988_800, 0), 0.0);
        assert_eq!(ntp_to_unix_secs(2_208_988_801, 1 << 31), 1.5);
    }

    #[test]
    fn wrap_does_not_move_time() {
        let mut c = RtpClock::new(90_000);
        let t0 = u32::MAX - 44_999; // 0.5 s before the wrap
        c.apply(&SenderReport {
            ssrc: 1,
            unix_secs: 1000.0,
            rtp_timestamp: t0,
        });
        let after = t0.wrapping_add(90_000); // 1 s later, past the wrap
        assert!(after < t0);
        let t = c.unix_secs(after).unwrap();
        assert!((t - 1001.0).abs() < 1e-9, "{t}");
        // A reordered packet from before the wrap keeps its time.
        let t = c.unix_secs(t0.wrapping_add(45_000 - 9_000)).unwrap();
        assert!((t - 1000.4).abs() < 1e-9, "{t}");
    }

    #[test]
    fn truncated_rtcp_is_an_error() {
        let mut sr = vec![0x80, RTCP_SR, 0, 6];
        sr.extend_from_slice(&[0; 24]);
        assert_eq!(sender_reports(&sr).unwrap().len(), 1);
        assert!(sender_reports(&sr[..20]).is_err());
        let mut long = sr.clone();
        long[3] = 60;
        assert!(sender_reports(&long).is_err());
    }
}
