//! Events a live source carries beside its samples: Pupil Capture's
//! annotations, an LSL marker stream's strings. Each is put on the host
//! clock by the source that receives it and handed to a bounded
//! [`EventQueue`] that the consumer (`run`'s output writer) drains: a flood
//! of markers is dropped and counted, never grows memory, and pushing never
//! blocks the source.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

/// The longest text kept, bytes (as a recording's events:
/// `gazelight_import::events::MAX_TEXT_BYTES`); longer texts are cut at a
/// character boundary.
pub const MAX_LIVE_EVENT_TEXT_BYTES: usize = 1024;

/// Events a queue holds before it drops new ones (counted).
pub const DEFAULT_EVENT_QUEUE: usize = 4096;

/// One event as received live.
#[derive(Clone, Debug, PartialEq)]
pub struct LiveEvent {
    /// When it happened on the host clock
    /// ([`crate::clock::host_now_secs`]), s: the source's own stamp mapped
    /// through its clock offset (an annotation stamped in the past stays
    /// in the past).
    pub host_secs: f64,
    /// The stamp on the source's own clock (Pupil time, the sender's LSL
    /// clock), s.
    pub source_secs: f64,
    /// Where the source gives one, s.
    pub duration_secs: Option<f64>,
    /// Where it came from: `annotation`, an LSL stream's name.
    pub source: String,
    /// The label or marker (at most [`MAX_LIVE_EVENT_TEXT_BYTES`]).
    pub text: String,
}

impl LiveEvent {
    /// An event with its text cut to [`MAX_LIVE_EVENT_TEXT_BYTES`].
    pub fn new(
        host_secs: f64,
        source_secs: f64,
        duration_secs: Option<f64>,
        source: &str,
        text: &str,
    ) -> Self {
        Self {
            host_secs,
            source_secs,
            duration_secs,
            source: cut(source).to_owned(),
            text: cut(text).to_owned(),
        }
    }
}

fn cut(s: &str) -> &str {
    if s.len() <= MAX_LIVE_EVENT_TEXT_BYTES {
        return s;
    }
    let mut end = MAX_LIVE_EVENT_TEXT_BYTES;
    while !s.is_char_boundary(end) {
        end -= 1;
    }
    &s[..end]
}

/// A bounded multi-producer queue of [`LiveEvent`]s (shared as an `Arc`):
/// sources [`push`](Self::push), one consumer [`drain_into`](Self::drain_into).
#[derive(Debug)]
pub struct EventQueue {
    capacity: usize,
    items: Mutex<VecDeque<LiveEvent>>,
    pushed: AtomicU64,
    dropped: AtomicU64,
}

impl Default for EventQueue {
    fn default() -> Self {
        Self::new(DEFAULT_EVENT_QUEUE)
    }
}

impl EventQueue {
    /// A queue that holds at most `capacity` (≥ 1) events.
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            capacity,
            items: Mutex::new(VecDeque::with_capacity(capacity.min(DEFAULT_EVENT_QUEUE))),
            pushed: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, VecDeque<LiveEvent>> {
        // A poisoned lock only means a panic elsewhere; the data is plain.
        self.items.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Queues `event`; when the queue is full it is dropped and counted
    /// (`false`). Never blocks beyond the short lock.
    pub fn push(&self, event: LiveEvent) -> bool {
        let mut q = self.lock();
        if q.len() >= self.capacity {
            drop(q);
            self.dropped.fetch_add(1, Ordering::Relaxed);
            return false;
        }
        q.push_back(event);
        self.pushed.fetch_add(1, Ordering::Relaxed);
        true
    }

    /// Moves every queued event into `out` (in arrival order).
    pub fn drain_into(&self, out: &mut Vec<LiveEvent>) {
        out.extend(self.lock().drain(..));
    }

    /// Events queued so far (not counting the dropped ones).
    pub fn pushed(&self) -> u64 {
        self.pushed.load(Ordering::Relaxed)
    }

    /// Events dropped because the queue was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ev(t: f64) -> LiveEvent {
        LiveEvent::new(t, t + 100.0, None, "annotation", "x")
    }

    #[test]
    fn a_flood_is_dropped_and_counted_and_the_queue_stays_bounded() {
        let q = EventQueue::new(3);
        let accepted: Vec<bool> = (0..5).map(|i| q.push(ev(f64::from(i)))).collect();
        assert_eq!(accepted, [true, true, true, false, false]);
        assert_eq!((q.pushed(), q.dropped()), (3, 2));
        let mut out = Vec::new();
        q.drain_into(&mut out);
        let times: Vec<f64> = out.iter().map(|e| e.host_secs).collect();
        assert_eq!(times, [0.0, 1.0, 2.0]);
        // Drained: room again.
        assert!(q.push(ev(9.0)));
        out.clear();
        q.drain_into(&mut out);
        assert_eq!(out.len(), 1);
    }

    #[test]
    fn long_texts_are_cut_at_a_character_boundary() {
        let long = "é".repeat(MAX_LIVE_EVENT_TEXT_BYTES); // 2 bytes each
        let e = LiveEvent::new(0.0, 0.0, None, "s", &long);
        assert_eq!(e.text.len(), MAX_LIVE_EVENT_TEXT_BYTES);
        assert!(e.text.chars().all(|c| c == 'é'));
        let odd = format!("a{long}");
        let e = LiveEvent::new(0.0, 0.0, None, "s", &odd);
        assert_eq!(e.text.len(), MAX_LIVE_EVENT_TEXT_BYTES - 1);
    }
}
