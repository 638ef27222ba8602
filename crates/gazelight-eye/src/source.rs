//! The one interface every sample source implements: a live tracker
//! client, a hardware transport or a replay.
//!
//! A [`SampleSource`] yields [`Sample`]s one at a time, asynchronously,
//! with times on the host clock (live sources map the tracker's clock
//! through a [`crate::clock::SourceClock`] first) or on the recording's clock (replays).
//! `Ok(None)` is the end of the stream; an `Err` is one bad item or a lost
//! connection and the caller may keep calling `next` (a replay skips to the
//! following item). The trait names no runtime: implementations bring their
//! own I/O.

use std::future::Future;
use std::sync::Arc;

use crate::clock::SharedClockStats;
use crate::sample::Sample;

/// Why a source could not deliver a sample.
#[derive(Debug, thiserror::Error)]
pub enum SourceError {
    /// One item of a replay could not be read; the source can go on.
    #[error("{source_name}: item {index}: {error}")]
    Item {
        source_name: String,
        index: u64,
        #[source]
        error: Box<dyn std::error::Error + Send + Sync>,
    },
    /// A live source lost its device or peer; it may recover.
    #[error("{source_name}: {reason}")]
    Disconnected { source_name: String, reason: String },
    /// The source cannot continue.
    #[error("{source_name}: {reason}")]
    Fatal { source_name: String, reason: String },
}

/// Something that produces samples: a live tracker client or a replay.
pub trait SampleSource: Send {
    /// The next sample; `Ok(None)` at the end of the stream.
    fn next(&mut self) -> impl Future<Output = Result<Option<Sample>, SourceError>> + Send;
    /// A one-line human-readable description (kind and location).
    fn describe(&self) -> String;
    /// Samples the source itself dropped so far (a full internal queue);
    /// 0 for sources without one.
    fn dropped(&self) -> u64 {
        0
    }
    /// The counters of the source's clock mapping
    /// ([`crate::clock::SourceClock`]), the same handle for the source's
    /// whole life (reconnects included); `None` for sources without one
    /// (replays, which run on their recording's clock).
    fn clock_stats(&self) -> Option<Arc<SharedClockStats>> {
        None
    }
}
