//! `gazelight.Source`: a live source (any URI `gazelight run` takes:
//! `pupil://`, `neon://`, `lsl://`, `hid://`, …, or a recording replayed in
//! real time) through gazelight-tracker's live eye task, the one place a
//! live `EyeState` is filtered.
//!
//! The task runs on a tokio runtime of the `Source`'s own (two worker
//! threads). Iterating waits for the next state the task publishes after
//! new samples, with the GIL released, in slices of 50 ms between which
//! Python's signals are checked (Ctrl-C). Closing (the end of the `with`
//! block) tells the task to stop, waits for it, then shuts the runtime
//! down: no thread of it is left.

use std::sync::{Mutex, PoisonError};
use std::time::Duration;

use pyo3::exceptions::PyRuntimeError;
use pyo3::prelude::*;
use tokio::sync::watch;

use gazelight_tracker::LiveEyeState;
use gazelight_tracker::filter::FilterChain;
use gazelight_tracker::live::LiveConfig;
use gazelight_tracker::transport::{self, SourceUri};

use crate::err;
use crate::filter::EyeState;

/// How long closing waits for the task and the runtime, s.
const CLOSE_TIMEOUT: Duration = Duration::from_secs(5);
/// The slice of a wait between two checks of Python's signals.
const WAIT_SLICE: Duration = Duration::from_millis(50);

struct Running {
    runtime: tokio::runtime::Runtime,
    shutdown: watch::Sender<bool>,
    eye: watch::Receiver<LiveEyeState>,
    task: tokio::task::JoinHandle<()>,
    last_updates: u64,
}

/// A live eye source: a context manager and an iterator of `EyeState`s.
///
/// Usable from any Python thread (not `unsendable`, whose use from a
/// second thread is a Rust panic, `PanicException`, across the boundary):
/// the state lives behind mutexes (only ever locked through `&mut self`,
/// so never contended), and two threads using one `Source` at the same
/// time get PyO3's `RuntimeError` ("Already borrowed") for the second,
/// a Python exception.
#[pyclass(module = "gazelight", name = "Source")]
pub(crate) struct Source {
    uri: String,
    chain: Mutex<Option<FilterChain>>,
    timeout: Option<f64>,
    running: Mutex<Option<Running>>,
}

/// The value behind a mutex reached through `&mut` (no locking; a mutex
/// poisoned by an earlier panic still gives its value).
fn inner<T>(m: &mut Mutex<T>) -> &mut T {
    m.get_mut().unwrap_or_else(PoisonError::into_inner)
}

impl Source {
    fn start(&mut self) -> PyResult<()> {
        if inner(&mut self.running).is_some() {
            return Ok(());
        }
        let chain = inner(&mut self.chain)
            .take()
            .ok_or_else(|| PyRuntimeError::new_err("this Source was closed; open a new one"))?;
        let parsed = SourceUri::parse(&self.uri).map_err(err)?;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .thread_name("gazelight-source")
            .enable_all()
            .build()
            .map_err(|e| err(format!("cannot start the async runtime: {e}")))?;
        let uri = self.uri.clone();
        let (shutdown, shutdown_rx) = watch::channel(false);
        let opened = runtime.block_on(async {
            transport::open_live(
                &uri,
                &parsed,
                &transport::OpenOptions::default(),
                chain,
                shutdown_rx,
                LiveConfig::default(),
            )
            .map_err(|e| crate::chain_msg(&e))
        });
        let live = match opened {
            Ok(l) => l,
            Err(e) => {
                runtime.shutdown_timeout(CLOSE_TIMEOUT);
                return Err(err(e));
            }
        };
        *inner(&mut self.running) = Some(Running {
            runtime,
            shutdown,
            eye: live.eye,
            task: live.task,
            last_updates: 0,
        });
        Ok(())
    }

    fn stop(&mut self) {
        stop(inner(&mut self.running).take());
    }
}

/// Tells the task to stop, waits for it, then shuts the runtime down (its
/// threads are joined); runs without the GIL where Python holds one.
fn stop(running: Option<Running>) {
    if let Some(r) = running {
        let _ = r.shutdown.send(true);
        let task = r.task;
        let _ = r
            .runtime
            .block_on(async { tokio::time::timeout(CLOSE_TIMEOUT, task).await });
        r.runtime.shutdown_timeout(CLOSE_TIMEOUT);
    }
}

#[pymethods]
impl Source {
    /// `uri`: a source as `gazelight run --source` takes it (`pupil://HOST:PORT`,
    /// `neon://…`, `lsl://?name=…`, `hid://…`, `replay://PATH`, …);
    /// `config`/`calibration`: the filter chain's, as for `read`;
    /// `timeout`: seconds to wait for a state before iteration stops
    /// (None: until the source ends).
    #[new]
    #[pyo3(signature = (uri, config=None, calibration=None, timeout=None))]
    fn new(
        uri: String,
        config: Option<&Bound<'_, PyAny>>,
        calibration: Option<&Bound<'_, PyAny>>,
        timeout: Option<f64>,
    ) -> PyResult<Self> {
        if let Some(t) = timeout
            && !(t.is_finite() && t > 0.0)
        {
            return Err(pyo3::exceptions::PyValueError::new_err(format!(
                "timeout {t}: expected a time > 0 in seconds"
            )));
        }
        // The URI is checked here, so a typo fails before the `with`.
        SourceUri::parse(&uri).map_err(err)?;
        Ok(Self {
            uri,
            chain: Mutex::new(Some(crate::read::chain_for(config, calibration)?)),
            timeout,
            running: Mutex::new(None),
        })
    }

    /// Starts the source (opens it and its live eye task).
    fn __enter__(mut slf: PyRefMut<'_, Self>) -> PyResult<PyRefMut<'_, Self>> {
        slf.start()?;
        Ok(slf)
    }

    /// Stops the task and the runtime; exceptions propagate.
    #[pyo3(signature = (*_args))]
    fn __exit__(&mut self, py: Python<'_>, _args: &Bound<'_, pyo3::types::PyTuple>) -> bool {
        let running = inner(&mut self.running).take();
        py.detach(|| stop(running));
        false
    }

    /// Stops the source (as the end of a `with` block does).
    fn close(&mut self, py: Python<'_>) {
        let running = inner(&mut self.running).take();
        py.detach(|| stop(running));
    }

    fn __iter__(slf: PyRefMut<'_, Self>) -> PyRefMut<'_, Self> {
        slf
    }

    /// The next state after new samples; waits with the GIL released.
    fn __next__(&mut self, py: Python<'_>) -> PyResult<Option<EyeState>> {
        self.start()?;
        let timeout = self.timeout;
        let Some(r) = inner(&mut self.running).as_mut() else {
            return Ok(None);
        };
        let started = std::time::Instant::now();
        loop {
            let eye = &mut r.eye;
            let runtime = &r.runtime;
            let last = r.last_updates;
            // Ok(Some): a new state; Ok(None): the slice ended; Err: the
            // task ended.
            let got = py.detach(|| {
                runtime.block_on(async {
                    match tokio::time::timeout(WAIT_SLICE, async {
                        loop {
                            eye.changed().await?;
                            let s = *eye.borrow_and_update();
                            if s.updates > last {
                                return Ok::<_, watch::error::RecvError>(s);
                            }
                        }
                    })
                    .await
                    {
                        Ok(Ok(s)) => Ok(Some(s)),
                        Ok(Err(e)) => Err(e),
                        Err(_) => Ok(None),
                    }
                })
            });
            match got {
                Ok(Some(s)) => {
                    r.last_updates = s.updates;
                    return Ok(Some(EyeState::from(&s.state)));
                }
                Ok(None) => {}
                Err(_) => return Ok(None),
            }
            py.check_signals()?;
            if timeout.is_some_and(|t| started.elapsed().as_secs_f64() >= t) {
                return Ok(None);
            }
        }
    }

    /// The URI it was opened with.
    #[getter]
    fn uri(&self) -> String {
        self.uri.clone()
    }
}

impl Drop for Source {
    fn drop(&mut self) {
        self.stop();
    }
}
