//! One shutdown path for SIGINT, SIGTERM and SIGHUP.
//!
//! Every long-running command (`run`, `record`, `replay`, `render`,
//! `calibrate`) treats the three signals the same way Ctrl-C always was:
//! the work stops at the next safe point (a frame boundary, a received
//! datum), the outputs are flushed and closed — whole CSV rows, complete
//! pldata records, `info.player.json` with the real duration — and the
//! command reports what it wrote. A second signal while shutting down
//! exits at once (status 128 + signal number), for a shutdown that hangs.
//!
//! The handlers are registered before the work starts ([`Signals::new`]),
//! so a signal that arrives early is not lost to the default action
//! (which would kill the process with half-written files).

use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};
use std::sync::{Arc, OnceLock};

use tokio::signal::unix::{Signal, SignalKind, signal};

/// The registered handlers (needs a tokio runtime with I/O enabled).
pub struct Signals {
    int: Signal,
    term: Signal,
    hup: Signal,
}

/// The signals handled, with their numbers.
const SIGNALS: [(&str, i32); 3] = [("SIGINT", 2), ("SIGTERM", 15), ("SIGHUP", 1)];

impl Signals {
    /// Registers SIGINT, SIGTERM and SIGHUP. Call inside the runtime.
    pub fn new() -> std::io::Result<Self> {
        Ok(Self {
            int: signal(SignalKind::interrupt())?,
            term: signal(SignalKind::terminate())?,
            hup: signal(SignalKind::hangup())?,
        })
    }

    /// The next signal's name (`"SIGINT"`, `"SIGTERM"`, `"SIGHUP"`).
    pub async fn recv(&mut self) -> &'static str {
        tokio::select! {
            _ = self.int.recv() => SIGNALS[0].0,
            _ = self.term.recv() => SIGNALS[1].0,
            _ = self.hup.recv() => SIGNALS[2].0,
        }
    }

    /// Waits for the first signal, then (in the background) exits the
    /// process on a second one. Returns the first signal's name.
    pub async fn first(mut self) -> &'static str {
        let name = self.recv().await;
        tokio::spawn(async move {
            let second = self.recv().await;
            eprintln!("{second} again while shutting down: exiting now");
            std::process::exit(128 + number(second));
        });
        name
    }
}

fn number(name: &str) -> i32 {
    SIGNALS
        .iter()
        .find(|(n, _)| *n == name)
        .map_or(1, |(_, k)| *k)
}

/// A stop request for a synchronous loop (`render`, `replay`): set by a
/// signal, read at every frame.
#[derive(Debug, Default)]
pub struct StopFlag {
    stop: AtomicBool,
    /// Index into `SIGNALS` + 1 (0 = none yet).
    which: AtomicU8,
}

impl StopFlag {
    /// Whether a signal asked the loop to stop.
    pub fn requested(&self) -> bool {
        self.stop.load(Ordering::Relaxed)
    }

    /// The signal that asked (None before one did).
    pub fn signal(&self) -> Option<&'static str> {
        match self.which.load(Ordering::Relaxed) {
            0 => None,
            i => SIGNALS.get(usize::from(i) - 1).map(|(n, _)| *n),
        }
    }

    fn set(&self, name: &str) {
        let i = SIGNALS.iter().position(|(n, _)| *n == name).unwrap_or(0);
        self.which.store(i as u8 + 1, Ordering::Relaxed);
        self.stop.store(true, Ordering::Relaxed);
    }
}

/// The process-wide stop flag for synchronous commands: the first call
/// registers the handlers (on a small thread of its own) and returns once
/// they are in place; later calls return the same flag. `None` when the
/// handlers cannot be registered (the default actions then stay).
pub fn stop_flag() -> Option<Arc<StopFlag>> {
    static FLAG: OnceLock<Option<Arc<StopFlag>>> = OnceLock::new();
    FLAG.get_or_init(|| {
        let flag = Arc::new(StopFlag::default());
        let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel::<bool>(1);
        let thread_flag = flag.clone();
        let spawned = std::thread::Builder::new()
            .name("gazelight-signals".into())
            .spawn(move || {
                let Ok(rt) = tokio::runtime::Builder::new_current_thread()
                    .enable_io()
                    .build()
                else {
                    let _ = ready_tx.send(false);
                    return;
                };
                rt.block_on(async move {
                    let Ok(signals) = Signals::new() else {
                        let _ = ready_tx.send(false);
                        return;
                    };
                    let _ = ready_tx.send(true);
                    let name = signals.first().await;
                    eprintln!("{name}: stopping after this frame");
                    thread_flag.set(name);
                    // Keep the runtime alive for the second-signal task.
                    std::future::pending::<()>().await;
                });
            });
        match spawned {
            Ok(_) if ready_rx.recv().unwrap_or(false) => Some(flag),
            _ => {
                tracing::warn!("cannot install the SIGINT/SIGTERM/SIGHUP handlers");
                None
            }
        }
    })
    .clone()
}
