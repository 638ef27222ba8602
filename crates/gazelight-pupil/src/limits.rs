//! What one ZeroMQ peer may send, per socket kind: the `[limits]` table of
//! the service configuration.
//!
//! Every socket gazelight opens towards Pupil (the `pupil://` client's
//! Remote REQ and bus SUB) or for Pupil clients (the relay's Remote REP,
//! PUB_PORT SUB and bus PUB) bounds each message before allocating it: a
//! frame header announcing more, or a multipart message growing past a
//! limit, drops that peer (see [`crate::relay`]). The defaults are sized to
//! the largest legal datum; [`set_process_limits`] replaces them for every
//! socket opened afterwards (the binary calls it once, from the config).
//!
//! ```
//! use gazelight_pupil::limits::{process_limits, ZmqLimits};
//! let l = ZmqLimits::default();
//! assert!(l.validate().is_ok());
//! assert_eq!(process_limits().max_message_frames, l.max_message_frames);
//! ```

use std::sync::RwLock;

use serde::{Deserialize, Serialize};

use crate::client::MAX_REMOTE_REPLY_BYTES;
use crate::relay::{MAX_DATUM_BYTES, MAX_MESSAGE_FRAMES, MAX_SUBSCRIPTION_BYTES};

/// Smallest byte limit accepted: a Pupil Remote reply or subscription
/// needs a few bytes, a datum hundreds.
pub const MIN_MESSAGE_BYTES: usize = 1 << 10;
/// Largest byte limit accepted (1 GiB): beyond any legal Pupil message.
pub const MAX_MESSAGE_BYTES: usize = 1 << 30;
/// Largest frame-count limit accepted.
pub const MAX_FRAMES_LIMIT: usize = 4096;

/// The limits of every socket kind, bytes per message and frames per
/// multipart message.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct ZmqLimits {
    /// `pupil://` client, Pupil Remote (REQ) replies.
    pub pupil_remote_max_message_bytes: usize,
    /// `pupil://` client, bus (SUB) messages: a frame datum with its image.
    pub pupil_bus_max_message_bytes: usize,
    /// Relay, Pupil Remote (REP) requests.
    pub relay_remote_max_message_bytes: usize,
    /// Relay, PUB_PORT (SUB) messages a client publishes.
    pub relay_pub_port_max_message_bytes: usize,
    /// Relay, bus (PUB) subscription messages.
    pub relay_bus_max_message_bytes: usize,
    /// Frames of one multipart message, on every socket.
    pub max_message_frames: usize,
}

impl Default for ZmqLimits {
    fn default() -> Self {
        Self {
            pupil_remote_max_message_bytes: MAX_REMOTE_REPLY_BYTES,
            pupil_bus_max_message_bytes: MAX_DATUM_BYTES,
            relay_remote_max_message_bytes: MAX_DATUM_BYTES,
            relay_pub_port_max_message_bytes: MAX_DATUM_BYTES,
            relay_bus_max_message_bytes: MAX_SUBSCRIPTION_BYTES,
            max_message_frames: MAX_MESSAGE_FRAMES,
        }
    }
}

/// A limit out of its range, named by its config key.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("limits.{key} = {value}: expected {expected}")]
pub struct LimitsError {
    /// The key in `[limits]`.
    pub key: &'static str,
    /// The value given.
    pub value: usize,
    /// The accepted range, in words.
    pub expected: String,
}

impl ZmqLimits {
    /// Checks every limit against its range.
    pub fn validate(&self) -> Result<(), LimitsError> {
        for (key, value) in [
            (
                "pupil_remote_max_message_bytes",
                self.pupil_remote_max_message_bytes,
            ),
            (
                "pupil_bus_max_message_bytes",
                self.pupil_bus_max_message_bytes,
            ),
            (
                "relay_remote_max_message_bytes",
                self.relay_remote_max_message_bytes,
            ),
            (
                "relay_pub_port_max_message_bytes",
                self.relay_pub_port_max_message_bytes,
            ),
            (
                "relay_bus_max_message_bytes",
                self.relay_bus_max_message_bytes,
            ),
        ] {
            if !(MIN_MESSAGE_BYTES..=MAX_MESSAGE_BYTES).contains(&value) {
                return Err(LimitsError {
                    key,
                    value,
                    expected: format!("{MIN_MESSAGE_BYTES} to {MAX_MESSAGE_BYTES} bytes"),
                });
            }
        }
        if !(1..=MAX_FRAMES_LIMIT).contains(&self.max_message_frames) {
            return Err(LimitsError {
                key: "max_message_frames",
                value: self.max_message_frames,
                expected: format!("1 to {MAX_FRAMES_LIMIT} frames"),
            });
        }
        Ok(())
    }
}

static LIMITS: RwLock<Option<ZmqLimits>> = RwLock::new(None);

/// Replaces the limits of every socket opened from now on (sockets already
/// open keep theirs). Checked first; an error changes nothing.
pub fn set_process_limits(limits: ZmqLimits) -> Result<(), LimitsError> {
    limits.validate()?;
    match LIMITS.write() {
        Ok(mut l) => *l = Some(limits),
        Err(poisoned) => *poisoned.into_inner() = Some(limits),
    }
    Ok(())
}

/// The limits in effect: the last [`set_process_limits`], else the
/// defaults.
pub fn process_limits() -> ZmqLimits {
    let l = match LIMITS.read() {
        Ok(l) => *l,
        Err(poisoned) => *poisoned.into_inner(),
    };
    l.unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_hold_the_largest_legal_datum() {
        let l = ZmqLimits::default();
        // A 3840×2160 BGR frame, as Pupil's Frame Publisher sends it.
        assert!(l.pupil_bus_max_message_bytes >= 3840 * 2160 * 3);
        assert!(l.validate().is_ok());
    }

    #[test]
    fn a_limit_out_of_range_is_named() {
        let l = ZmqLimits {
            relay_bus_max_message_bytes: 10,
            ..ZmqLimits::default()
        };
        let e = l.validate().unwrap_err();
        assert_eq!(e.key, "relay_bus_max_message_bytes");
        assert!(
            e.to_string()
                .contains("limits.relay_bus_max_message_bytes = 10")
        );
        let l = ZmqLimits {
            max_message_frames: 0,
            ..ZmqLimits::default()
        };
        assert_eq!(l.validate().unwrap_err().key, "max_message_frames");
        assert!(set_process_limits(l).is_err());
    }
}
