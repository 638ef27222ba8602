//! The glare PSF rebuilt off the frame thread (issue 10 §2: a rebuild must
//! not stall a frame).
//!
//! A worker thread owns a [`PsfBuilder`] with the frame pipeline's PSF
//! parameters. Two bounded slots connect it to the frame loop:
//!
//! * the request slot holds at most one pupil diameter (an `f64` in an
//!   atomic): a newer request overwrites an unserved one (the newest pupil
//!   wins) and posting never blocks the frame loop;
//! * the ready slot holds at most one finished kernel, in a buffer
//!   allocated once at start: the worker copies its builder's kernel into
//!   it, the frame loop takes it with `try_lock` (never waits) and installs
//!   it ([`crate::backend::Renderer::set_kernel`]), with the first dark
//!   ring the worker measured on its builder's 575 nm field for that build
//!   ([`PsfBuilder::first_ring_rad`]; `psf.csv`).
//!
//! Frames keep the previous kernel until the new one is ready. Neither side
//! allocates per request (the builder reuses its buffers; the ready buffer
//! is copied into in place).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};
use std::thread::{JoinHandle, Thread};
use std::time::Duration;

use gazelight_vision::psf::{PsfBuilder, PsfKernel, PsfParams};

/// The request slot's "empty" value (a NaN bit pattern no request uses:
/// requests are finite).
const NO_REQUEST: u64 = u64::MAX;
/// How often an idle worker looks at the stop flag.
const IDLE_POLL: Duration = Duration::from_millis(100);

struct Shared {
    request_bits: AtomicU64,
    /// The finished kernel and its measured first ring, radians (NaN:
    /// no minimum found).
    ready: Mutex<(PsfKernel, f64)>,
    ready_flag: AtomicBool,
    stop: AtomicBool,
}

/// The worker and its two slots; dropping it stops and joins the thread.
pub struct PsfWorker {
    shared: Arc<Shared>,
    thread: Thread,
    handle: Option<JoinHandle<()>>,
}

impl PsfWorker {
    /// Starts the worker. `params` are the pipeline's PSF parameters (with
    /// its `ppd`); `initial` is the kernel the pipeline holds now, which
    /// sizes the ready buffer. The builder is made on the worker thread (it
    /// costs as much as a rebuild); if that fails the worker logs it and
    /// ends, and frames keep the initial kernel.
    pub fn start(params: PsfParams, initial: &PsfKernel) -> std::io::Result<Self> {
        let shared = Arc::new(Shared {
            request_bits: AtomicU64::new(NO_REQUEST),
            ready: Mutex::new((initial.clone(), f64::NAN)),
            ready_flag: AtomicBool::new(false),
            stop: AtomicBool::new(false),
        });
        let worker = Arc::clone(&shared);
        let handle = std::thread::Builder::new()
            .name("gazelight-psf".into())
            .spawn(move || work(&worker, params))?;
        Ok(Self {
            shared,
            thread: handle.thread().clone(),
            handle: Some(handle),
        })
    }

    /// Asks for a kernel for `pupil_mm` (replacing an unserved request).
    /// Never blocks, never allocates. Non-finite diameters are ignored.
    pub fn request(&self, pupil_mm: f64) {
        if pupil_mm.is_finite() {
            self.shared
                .request_bits
                .store(pupil_mm.to_bits(), Ordering::Release);
            self.thread.unpark();
        }
    }

    /// If a finished kernel is waiting and its slot is free right now,
    /// passes it and its measured first ring (radians) to `install` and
    /// empties the slot; returns what `install` returned. Never blocks.
    pub fn take<R>(&self, install: impl FnOnce(&PsfKernel, f64) -> R) -> Option<R> {
        if !self.shared.ready_flag.load(Ordering::Acquire) {
            return None;
        }
        let guard = self.shared.ready.try_lock().ok()?;
        self.shared.ready_flag.store(false, Ordering::Release);
        Some(install(&guard.0, guard.1))
    }

    /// Whether a request is waiting to be picked up by the worker.
    #[cfg(test)]
    pub fn request_pending(&self) -> bool {
        self.shared.request_bits.load(Ordering::Acquire) != NO_REQUEST
    }
}

impl Drop for PsfWorker {
    fn drop(&mut self) {
        self.shared.stop.store(true, Ordering::Release);
        self.thread.unpark();
        if let Some(h) = self.handle.take()
            && h.join().is_err()
        {
            tracing::warn!("the PSF worker thread panicked");
        }
    }
}

fn work(shared: &Shared, params: PsfParams) {
    let mut builder = match PsfBuilder::new(params) {
        Ok(b) => b,
        Err(e) => {
            tracing::warn!(error = %e, "PSF worker: cannot build the glare PSF; frames keep the initial kernel");
            return;
        }
    };
    while !shared.stop.load(Ordering::Acquire) {
        let bits = shared.request_bits.swap(NO_REQUEST, Ordering::AcqRel);
        if bits == NO_REQUEST {
            std::thread::park_timeout(IDLE_POLL);
            continue;
        }
        builder.rebuild(f64::from_bits(bits));
        let ring_rad = builder.first_ring_rad().unwrap_or(f64::NAN);
        let kernel = builder.kernel();
        let mut guard = shared.ready.lock().unwrap_or_else(PoisonError::into_inner);
        guard.1 = ring_rad;
        let ready = &mut guard.0;
        if ready.rgb.len() == kernel.rgb.len() {
            ready.rgb.copy_from_slice(&kernel.rgb);
            ready.size = kernel.size;
            ready.deg_per_px = kernel.deg_per_px;
            ready.pupil_mm = kernel.pupil_mm;
            ready.wavelengths_nm.clone_from(&kernel.wavelengths_nm);
        } else {
            // Cannot happen with the pipeline's own parameters.
            ready.clone_from(kernel);
        }
        drop(guard);
        shared.ready_flag.store(true, Ordering::Release);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn small_params() -> PsfParams {
        PsfParams {
            field_deg: 4.0,
            ppd: 8.0,
            ..PsfParams::default()
        }
    }

    /// A kernel requested from the worker arrives, matches a builder's own
    /// rebuild for that pupil exactly, and the newest of two quick requests
    /// is the one built last.
    #[test]
    fn the_worker_builds_the_newest_requested_pupil() {
        let params = small_params();
        let mut reference = PsfBuilder::new(params.clone()).expect("builder");
        let initial = reference.kernel().clone();
        let worker = PsfWorker::start(params, &initial).expect("worker");
        worker.request(3.0);
        worker.request(6.0);
        let deadline = std::time::Instant::now() + Duration::from_secs(120);
        let mut got: Option<PsfKernel> = None;
        while std::time::Instant::now() < deadline {
            if let Some(k) = worker.take(|k, _| k.clone()) {
                let done = k.pupil_mm == 6.0;
                got = Some(k);
                if done && !worker.request_pending() {
                    break;
                }
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        let got = got.expect("no kernel from the worker");
        assert_eq!(got.pupil_mm, 6.0);
        let expected = reference.rebuild(6.0);
        assert_eq!(got.size, expected.size);
        assert_eq!(got.rgb, expected.rgb);
        assert_ne!(got.rgb, initial.rgb, "the kernel did not change");
    }

    /// The ring the worker reports is measured on the field it built: with
    /// no particles it is the Airy pattern's first zero, 1.22 λ / D
    /// (λ = 575 nm), for the pupil actually built: within 12 % (the ring
    /// lies a few FFT samples out, as in `tests/run_live.rs`), and the two
    /// rings scale as 1/D within 15 % (the same limits as `run_live`).
    #[test]
    fn the_reported_ring_is_the_airy_zero_of_the_built_pupil() {
        let params = PsfParams {
            particles: 0,
            stray_light: false,
            ..small_params()
        };
        let initial = PsfBuilder::new(params.clone())
            .expect("builder")
            .kernel()
            .clone();
        let worker = PsfWorker::start(params, &initial).expect("worker");
        let mut rings = Vec::new();
        for pupil_mm in [6.0, 2.5] {
            worker.request(pupil_mm);
            let deadline = std::time::Instant::now() + Duration::from_secs(120);
            let (got_mm, ring) = loop {
                assert!(std::time::Instant::now() < deadline, "no kernel");
                if let Some(r) = worker.take(|k, ring| (k.pupil_mm, ring)) {
                    break r;
                }
                std::thread::sleep(Duration::from_millis(5));
            };
            assert_eq!(got_mm, pupil_mm);
            let airy = 1.22 * 575e-9 / (pupil_mm * 1e-3);
            assert!(
                (ring - airy).abs() < 0.12 * airy,
                "{pupil_mm} mm: ring {ring} rad vs 1.22 λ/D = {airy} rad"
            );
            rings.push(ring);
        }
        let ratio = rings[1] / rings[0];
        assert!(
            (ratio / (6.0 / 2.5) - 1.0).abs() < 0.15,
            "ring ratio {ratio} vs pupil ratio 2.4 ({rings:?})"
        );
    }
}
