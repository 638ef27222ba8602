//! The glare PSF rebuilt off the frame thread (issue 10 §2: a rebuild must
//! not stall a frame).
//!
//! A worker thread owns a [`PsfBuilder`] with the frame pipelines' PSF
//! parameters and, on the CPU backend, a [`GlarePreparer`] for their
//! convolvers. It serves one view, or the two of a stereo frame; per view
//! two bounded slots connect it to the frame loop:
//!
//! * the request slot holds at most one pupil diameter (an `f64` in an
//!   atomic): a newer request overwrites an unserved one (the newest pupil
//!   wins) and posting never blocks the frame loop;
//! * the ready slot holds at most one [`PreparedKernel`]: the kernel and
//!   its convolver spectra (the FFTs of its fine core and coarse wide
//!   field), both made on the worker. The worker fills a staging copy
//!   allocated once at start and swaps it into the slot; the frame loop
//!   takes the slot with `try_lock` (never waits) and installs it
//!   (gazelight's `Renderer::install_prepared`), which on the CPU
//!   swaps buffers: no FFT, no copy, no allocation on the frame thread.
//!   With it comes the first dark ring the worker measured on its
//!   builder's 575 nm field for that build ([`PsfBuilder::first_ring_rad`];
//!   `psf.csv`).
//!
//! Two views asking for the same pupil at once (the shared kernel of two
//! agreeing pupils, `KernelPolicy::plan`) are served by one build: the
//! second view's slot gets a copy of the kernel and its spectra.
//!
//! Frames keep the previous kernel until the new one is ready. The worker
//! and the rayon pool it builds on (its own single thread, not the global
//! pool the frame passes use, so no frame thread can steal a build task
//! while it waits in a join) run at a low CPU [`Priority`]:
//!
//! * [`Priority::Idle`] (`run`): the kernel's idle priority (Linux
//!   `SCHED_IDLE`), so a build never takes a core from a frame: it gets
//!   one only while no other thread wants it, in the gaps between frames
//!   and in a frame's serial parts. Kernel latency pays for that, and a
//!   machine whose cores other processes keep busy starves the worker.
//! * [`Priority::Background`] (the OpenXR layer, a guest in an app's
//!   process on a machine it does not own): nice +10, a small but certain
//!   share of a core (about a tenth against one busy normal thread), so
//!   kernels keep following the pupil, late, however loaded the machine.
//!
//! # Example
//!
//! ```
//! use gazelight_psf_worker::{PsfWorker, Priority};
//! use gazelight_vision::psf::{PsfBuilder, PsfParams};
//!
//! let params = PsfParams { field_deg: 2.0, ppd: 8.0, ..PsfParams::default() };
//! let initial = PsfBuilder::new(params.clone())?.kernel().clone();
//! let worker = PsfWorker::start(params, &initial, None, 1, Priority::Background)?;
//! worker.request_views([Some(6.0), None]);
//! let pupil_mm = loop {
//!     // A frame loop would render here and look again next frame.
//!     if let Some(p) = worker.take(0, |prepared, _ring_rad| prepared.kernel.pupil_mm) {
//!         break p;
//!     }
//!     std::thread::sleep(std::time::Duration::from_millis(5));
//! };
//! assert_eq!(pupil_mm, 6.0);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```
//!
//! A build running on the other core while a frame renders still costs
//! that frame shared cache and memory bandwidth (its FFT grids, tens of
//! MB). So on the CPU backend builds also wait for the gaps between
//! frames: the frame loop marks each frame's start and end ([`PsfWorker::frame_started`],
//! [`PsfWorker::frame_ended`]), and the build
//! ([`PsfBuilder::rebuild_paced`], [`GlarePreparer::prepare_paced`])
//! stops between steps of about a MiB of grid while a frame renders and
//! goes on when it ends. Frames that leave no gap (an overloaded run)
//! cannot starve the worker: after [`MAX_DEFERRAL`] of waiting a build runs
//! to its end beside frames, counted in [`PsfWorker::builds_unpaced`].
//! `run` counts the dropped deadlines of frames rendered beside a build
//! apart (BENCHMARKS.md).
//!
//! Neither side allocates per request once both buffers have held a kernel (the builder
//! reuses its buffers; kernels and spectra circulate between the staging
//! copy, the slot and the pipeline by swapping).

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex, OnceLock, PoisonError};
use std::thread::{JoinHandle, Thread};
use std::time::{Duration, Instant};

use gazelight_vision::glare::{GlarePreparer, PreparedKernel};
use gazelight_vision::kernel_policy::KernelFollower;
use gazelight_vision::psf::{PsfBuilder, PsfKernel, PsfParams};

/// The request slot's "empty" value (a NaN bit pattern no request uses:
/// requests are finite).
const NO_REQUEST: u64 = u64::MAX;
/// How often an idle worker looks at the stop flag.
const IDLE_POLL: Duration = Duration::from_millis(100);

/// Threads of the worker's own build pool.
const BUILD_THREADS: usize = 1;
/// How often a build held by a rendering frame looks again (the frame's end
/// also wakes it).
const GAP_POLL: Duration = Duration::from_millis(2);
/// The longest a build waits for gaps between frames in all, before it
/// runs beside frames as well: frames that leave no gap (an overloaded
/// stereo run) still get their kernels, about this much later.
const MAX_DEFERRAL: Duration = Duration::from_secs(1);

/// How the worker's threads share the CPU with everything else.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Priority {
    /// Linux `SCHED_IDLE`: a core only when no other thread wants it.
    Idle,
    /// Nice +10 (`SCHED_OTHER`): a small share even on a busy machine.
    Background,
}

/// Nice value of [`Priority::Background`].
const BACKGROUND_NICE: libc::c_int = 10;

/// Puts the calling thread at `priority`. A failure is logged and the
/// thread keeps its priority; other systems keep it too.
fn lower_priority(priority: Priority) {
    #[cfg(target_os = "linux")]
    {
        let rc = match priority {
            Priority::Idle => {
                let param = libc::sched_param { sched_priority: 0 };
                // SAFETY: pid 0 is the calling thread; `param` is a valid,
                // live sched_param for the duration of the call.
                unsafe { libc::sched_setscheduler(0, libc::SCHED_IDLE, &param) }
            }
            // SAFETY: on Linux, PRIO_PROCESS with who 0 is the calling
            // thread alone; raising one's own nice value needs no privilege.
            Priority::Background => unsafe {
                libc::setpriority(libc::PRIO_PROCESS, 0, BACKGROUND_NICE)
            },
        };
        if rc != 0 {
            tracing::warn!(error = %std::io::Error::last_os_error(), ?priority, "PSF worker: cannot lower its priority");
        }
    }
    #[cfg(not(target_os = "linux"))]
    let _ = priority;
}

/// The largest number of views one worker serves (a stereo frame's two).
pub const MAX_VIEWS: usize = 2;

/// One view's two slots.
struct ViewSlots {
    request_bits: AtomicU64,
    /// The finished kernel (with its spectra) and its measured first ring,
    /// radians (NaN: no minimum found).
    ready: Mutex<(PreparedKernel, f64)>,
    ready_flag: AtomicBool,
}

struct Shared {
    views: Vec<ViewSlots>,
    stop: AtomicBool,
    /// The worker is building (from taking requests to publishing).
    busy: AtomicBool,
    /// Kernels built so far (a shared kernel counts once).
    builds: AtomicU64,
    /// A frame is rendering: the build waits between its steps.
    frame_running: AtomicBool,
    /// The thread that runs the builds (the build pool's), woken when a
    /// frame ends.
    build_thread: OnceLock<Thread>,
    /// Builds that gave up waiting for gaps ([`MAX_DEFERRAL`]).
    builds_unpaced: AtomicU64,
}

impl Shared {
    /// The build's pace callback ([`PsfBuilder::rebuild_paced`]): between
    /// two steps, waits while a frame renders, until the build has waited
    /// [`MAX_DEFERRAL`] in all (`deferred`).
    fn wait_for_gap(&self, deferred: &mut Duration) {
        if !self.frame_running.load(Ordering::Acquire) || *deferred >= MAX_DEFERRAL {
            return;
        }
        let t0 = Instant::now();
        while self.frame_running.load(Ordering::Acquire) && !self.stop.load(Ordering::Acquire) {
            std::thread::park_timeout(GAP_POLL);
            if *deferred + t0.elapsed() >= MAX_DEFERRAL {
                self.builds_unpaced.fetch_add(1, Ordering::Relaxed);
                break;
            }
        }
        *deferred += t0.elapsed();
    }
}

/// The worker and its slots (two per view); dropping it stops and joins
/// the thread.
pub struct PsfWorker {
    shared: Arc<Shared>,
    thread: Thread,
    handle: Option<JoinHandle<()>>,
}

impl PsfWorker {
    /// Starts the worker for `views` views (1, or 2 for a stereo frame;
    /// more are refused). `params` are the pipelines' PSF parameters (with
    /// their `ppd`); `initial` is the kernel the pipelines hold now, which
    /// sizes the kernel buffers; `preparer` (the CPU pipeline's
    /// [`gazelight_vision::pipeline::FramePipeline::kernel_preparer`]; `None`
    /// on the GPU, which makes its spectra itself) also makes each kernel's
    /// convolver spectra on the worker. Two views with the same geometry
    /// share it: when both ask for the same pupil (one shared kernel) the
    /// kernel and its spectra are made once and copied to both slots. The
    /// builder is made on the worker thread (it costs as much as a
    /// rebuild); if that fails the worker logs it and ends, and frames keep
    /// the initial kernel. Its threads run at `priority`.
    pub fn start(
        params: PsfParams,
        initial: &PsfKernel,
        preparer: Option<GlarePreparer>,
        views: usize,
        priority: Priority,
    ) -> std::io::Result<Self> {
        if views == 0 || views > MAX_VIEWS {
            return Err(std::io::Error::new(
                std::io::ErrorKind::InvalidInput,
                format!("a PSF worker serves 1 to {MAX_VIEWS} views, not {views}"),
            ));
        }
        let prepared = || PreparedKernel {
            kernel: initial.clone(),
            spectra: preparer.as_ref().map(GlarePreparer::new_spectra),
        };
        let shared = Arc::new(Shared {
            views: (0..views)
                .map(|_| ViewSlots {
                    request_bits: AtomicU64::new(NO_REQUEST),
                    ready: Mutex::new((prepared(), f64::NAN)),
                    ready_flag: AtomicBool::new(false),
                })
                .collect(),
            stop: AtomicBool::new(false),
            busy: AtomicBool::new(false),
            builds: AtomicU64::new(0),
            frame_running: AtomicBool::new(false),
            build_thread: OnceLock::new(),
            builds_unpaced: AtomicU64::new(0),
        });
        let staging: Vec<PreparedKernel> = (0..views).map(|_| prepared()).collect();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(BUILD_THREADS)
            .thread_name(|i| format!("gazelight-psf-{i}"))
            .start_handler(move |_| lower_priority(priority))
            .build()
            .map_err(std::io::Error::other)?;
        let worker = Arc::clone(&shared);
        let handle = std::thread::Builder::new()
            .name("gazelight-psf".into())
            .spawn(move || {
                lower_priority(priority);
                pool.install(|| work(&worker, params, preparer, staging));
            })?;
        Ok(Self {
            shared,
            thread: handle.thread().clone(),
            handle: Some(handle),
        })
    }

    /// Asks for kernels for several views at once (`None`: no request for
    /// that view), waking the worker once, so that views asking for the
    /// same pupil (a shared kernel) are served by one build.
    pub fn request_views(&self, pupils_mm: [Option<f64>; MAX_VIEWS]) {
        let mut any = false;
        for (v, p) in self.shared.views.iter().zip(pupils_mm) {
            if let Some(p) = p.filter(|p| p.is_finite()) {
                v.request_bits.store(p.to_bits(), Ordering::Release);
                any = true;
            }
        }
        if any {
            self.thread.unpark();
        }
    }

    /// This frame's pupils (indexed like the views) through the one
    /// kernel rule, `follower`: asks for the kernels it says are due (one
    /// wake-up for both views) and returns them. Never blocks.
    pub fn follow(&self, follower: &mut KernelFollower, pupils_mm: [f32; 2]) -> [Option<f64>; 2] {
        let wanted = follower.follow(pupils_mm);
        let mut requests = [None; MAX_VIEWS];
        for (r, w) in requests.iter_mut().zip(wanted) {
            *r = w;
        }
        self.request_views(requests);
        wanted
    }

    /// If a finished kernel for view `view` is waiting and its slot is free
    /// right now, passes it (to be installed by swapping: what `install`
    /// leaves in it goes back to the worker for reuse) and its measured
    /// first ring (radians) to `install` and empties the slot; returns what
    /// `install` returned. Never blocks.
    pub fn take<R>(
        &self,
        view: usize,
        install: impl FnOnce(&mut PreparedKernel, f64) -> R,
    ) -> Option<R> {
        let v = self.shared.views.get(view)?;
        if !v.ready_flag.load(Ordering::Acquire) {
            return None;
        }
        let mut guard = v.ready.try_lock().ok()?;
        v.ready_flag.store(false, Ordering::Release);
        let ring_rad = guard.1;
        Some(install(&mut guard.0, ring_rad))
    }

    /// A frame starts rendering: builds wait between their steps until
    /// [`PsfWorker::frame_ended`] (never longer than [`MAX_DEFERRAL`] per
    /// build in all), so that a frame does not share the caches and the
    /// memory bus with a build's FFT grids.
    pub fn frame_started(&self) {
        self.shared.frame_running.store(true, Ordering::Release);
    }

    /// The frame is done: a waiting build goes on in the gap.
    pub fn frame_ended(&self) {
        self.shared.frame_running.store(false, Ordering::Release);
        if self.shared.busy.load(Ordering::Acquire)
            && let Some(t) = self.shared.build_thread.get()
        {
            t.unpark();
        }
    }

    /// Builds that ran partly beside frames because frames left no gap
    /// for [`MAX_DEFERRAL`].
    pub fn builds_unpaced(&self) -> u64 {
        self.shared.builds_unpaced.load(Ordering::Relaxed)
    }

    /// Kernels built so far (a kernel shared by two views counts once).
    pub fn builds(&self) -> u64 {
        self.shared.builds.load(Ordering::Relaxed)
    }

    /// Whether a kernel is being built or a request waits for the worker
    /// (what a frame renders beside; the run counts dropped deadlines of
    /// such frames apart).
    pub fn building(&self) -> bool {
        self.shared.busy.load(Ordering::Acquire) || self.request_pending()
    }

    /// Whether a request is waiting to be picked up by the worker.
    pub fn request_pending(&self) -> bool {
        self.shared
            .views
            .iter()
            .any(|v| v.request_bits.load(Ordering::Acquire) != NO_REQUEST)
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

/// Copies `src` into `dst`, reusing `dst`'s buffers when the sizes match.
fn copy_kernel(dst: &mut PsfKernel, src: &PsfKernel) {
    if dst.rgb.len() == src.rgb.len() {
        dst.rgb.copy_from_slice(&src.rgb);
    } else {
        dst.rgb.clone_from(&src.rgb);
    }
    dst.size = src.size;
    dst.deg_per_px = src.deg_per_px;
    dst.pupil_mm = src.pupil_mm;
    dst.wavelengths_nm.clone_from(&src.wavelengths_nm);
}

/// Hands `staging` to view `v`'s ready slot (by swapping) with its ring.
fn publish(slots: &ViewSlots, staging: &mut PreparedKernel, ring_rad: f64) {
    let mut guard = slots.ready.lock().unwrap_or_else(PoisonError::into_inner);
    std::mem::swap(&mut guard.0, staging);
    guard.1 = ring_rad;
    drop(guard);
    slots.ready_flag.store(true, Ordering::Release);
}

fn work(
    shared: &Shared,
    params: PsfParams,
    mut preparer: Option<GlarePreparer>,
    mut staging: Vec<PreparedKernel>,
) {
    let mut builder = match PsfBuilder::new(params) {
        Ok(b) => b,
        Err(e) => {
            tracing::warn!(error = %e, "PSF worker: cannot build the glare PSF; frames keep the initial kernel");
            return;
        }
    };
    // Builds run on this thread (the build pool's only thread).
    let _ = shared.build_thread.set(std::thread::current());
    let mut requests = [NO_REQUEST; MAX_VIEWS];
    while !shared.stop.load(Ordering::Acquire) {
        for (r, v) in requests.iter_mut().zip(&shared.views) {
            *r = v.request_bits.swap(NO_REQUEST, Ordering::AcqRel);
        }
        if requests.iter().all(|&r| r == NO_REQUEST) {
            std::thread::park_timeout(IDLE_POLL);
            continue;
        }
        shared.busy.store(true, Ordering::Release);
        let mut deferred = Duration::ZERO;
        // View by view; a view asking for the kernel just built for an
        // earlier view (a shared kernel) gets a copy of it.
        let mut built: Option<(u64, usize, f64)> = None;
        let mut rings = [f64::NAN; MAX_VIEWS];
        for view in 0..shared.views.len() {
            let bits = requests[view];
            if bits == NO_REQUEST {
                continue;
            }
            let (done, rest) = staging.split_at_mut(view);
            let Some(out) = rest.first_mut() else { break };
            rings[view] = match built {
                Some((b, from, ring)) if b == bits => {
                    let src = &done[from];
                    copy_kernel(&mut out.kernel, &src.kernel);
                    if let (Some(d), Some(s)) = (out.spectra.as_mut(), src.spectra.as_ref())
                        && let Err(e) = d.copy_from(s)
                    {
                        tracing::warn!(error = %e, "PSF worker: cannot copy the glare spectra");
                    }
                    ring
                }
                _ => {
                    builder.rebuild_paced(f64::from_bits(bits), &mut || {
                        shared.wait_for_gap(&mut deferred)
                    });
                    shared.builds.fetch_add(1, Ordering::Relaxed);
                    let ring = builder.first_ring_rad().unwrap_or(f64::NAN);
                    copy_kernel(&mut out.kernel, builder.kernel());
                    if let (Some(p), Some(s)) = (preparer.as_mut(), out.spectra.as_mut())
                        && let Err(e) = p.prepare_paced(&out.kernel, s, &mut || {
                            shared.wait_for_gap(&mut deferred)
                        })
                    {
                        // Cannot happen with the pipeline's own parameters;
                        // the frame thread then computes the spectra itself.
                        tracing::warn!(error = %e, "PSF worker: cannot prepare the glare spectra");
                    }
                    built = Some((bits, view, ring));
                    ring
                }
            };
        }
        // Handed over only now: a later view may have copied from an
        // earlier view's staging copy.
        for (view, (slots, out)) in shared.views.iter().zip(&mut staging).enumerate() {
            if requests[view] != NO_REQUEST {
                publish(slots, out, rings[view]);
            }
        }
        shared.busy.store(false, Ordering::Release);
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
        let worker = PsfWorker::start(params, &initial, None, 1, Priority::Idle).expect("worker");
        worker.request_views([Some(3.0), None]);
        worker.request_views([Some(6.0), None]);
        let deadline = std::time::Instant::now() + Duration::from_secs(120);
        let mut got: Option<PsfKernel> = None;
        while std::time::Instant::now() < deadline {
            if let Some(k) = worker.take(0, |k, _| k.kernel.clone()) {
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

    /// A build waits while a frame renders: a kernel requested during a
    /// frame that lasts 300 ms is not ready before the frame ends, then
    /// arrives; a frame that leaves no gap for longer than `MAX_DEFERRAL`
    /// no longer holds the build (it is counted as unpaced).
    #[test]
    fn builds_wait_for_the_gaps_between_frames() {
        let params = small_params();
        let initial = PsfBuilder::new(params.clone())
            .expect("builder")
            .kernel()
            .clone();
        let worker = PsfWorker::start(params, &initial, None, 1, Priority::Idle).expect("worker");
        let wait = |limit: Duration| {
            let deadline = std::time::Instant::now() + limit;
            while std::time::Instant::now() < deadline {
                if let Some(mm) = worker.take(0, |k, _| k.kernel.pupil_mm) {
                    return Some(mm);
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            None
        };
        worker.frame_started();
        worker.request_views([Some(3.0), None]);
        assert_eq!(
            wait(Duration::from_millis(300)),
            None,
            "a kernel was built during a frame"
        );
        worker.frame_ended();
        assert_eq!(wait(Duration::from_secs(120)), Some(3.0));
        assert_eq!(worker.builds_unpaced(), 0);
        // A frame that never ends: the build goes on after MAX_DEFERRAL.
        worker.frame_started();
        worker.request_views([Some(6.0), None]);
        let t0 = std::time::Instant::now();
        assert_eq!(wait(Duration::from_secs(120)), Some(6.0));
        assert!(t0.elapsed() >= MAX_DEFERRAL, "{:?}", t0.elapsed());
        assert_eq!(worker.builds_unpaced(), 1);
        worker.frame_ended();
    }

    /// Two views: the same pupil for both (a shared kernel) is built once
    /// and both get it with its spectra; different pupils are built each.
    #[test]
    fn two_views_share_one_build() {
        use gazelight_vision::glare::{GlareConvolver, GlareWindow};
        let params = small_params();
        let mut reference = PsfBuilder::new(params.clone()).expect("builder");
        let initial = reference.kernel().clone();
        let window = GlareWindow {
            full_weight_deg: 1.0,
            fade_sigma_deg: 0.5,
        };
        let conv = GlareConvolver::new(&initial, window).expect("convolver");
        let worker = PsfWorker::start(params, &initial, Some(conv.preparer()), 2, Priority::Idle)
            .expect("worker");
        let wait = |view: usize| {
            let deadline = std::time::Instant::now() + Duration::from_secs(120);
            loop {
                assert!(
                    std::time::Instant::now() < deadline,
                    "no kernel for view {view}"
                );
                if let Some(r) = worker.take(view, |p, _| {
                    let spectra_mm = p.spectra.as_ref().map_or(f64::NAN, |s| s.pupil_mm());
                    (p.kernel.clone(), spectra_mm)
                }) {
                    break r;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
        };
        // Requested together (before the worker wakes): one build.
        worker.request_views([Some(5.0), Some(5.0)]);
        let (a, a_spectra) = wait(0);
        let (b, b_spectra) = wait(1);
        assert_eq!(
            (a.pupil_mm, b.pupil_mm, a_spectra, b_spectra),
            (5.0, 5.0, 5.0, 5.0)
        );
        assert_eq!(a.rgb, b.rgb);
        assert_eq!(a.rgb, reference.rebuild(5.0).rgb);
        assert_eq!(worker.builds(), 1, "a shared kernel was built twice");
        // Different pupils: one build each.
        worker.request_views([Some(3.0), Some(7.0)]);
        let (a, _) = wait(0);
        let (b, _) = wait(1);
        assert_eq!((a.pupil_mm, b.pupil_mm), (3.0, 7.0));
        assert_eq!(b.rgb, reference.rebuild(7.0).rgb);
        assert_eq!(worker.builds(), 3);
        assert!(PsfWorker::start(small_params(), &initial, None, 3, Priority::Idle).is_err());
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
        let worker = PsfWorker::start(params, &initial, None, 1, Priority::Idle).expect("worker");
        let mut rings = Vec::new();
        for pupil_mm in [6.0, 2.5] {
            worker.request_views([Some(pupil_mm), None]);
            let deadline = std::time::Instant::now() + Duration::from_secs(120);
            let (got_mm, ring) = loop {
                assert!(std::time::Instant::now() < deadline, "no kernel");
                if let Some(r) = worker.take(0, |k, ring| (k.kernel.pupil_mm, ring)) {
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

    /// With a preparer, the worker also makes the convolver spectra: a
    /// convolver that installs them (a buffer swap) glares a frame exactly
    /// as one that computed them itself from the same kernel
    /// (`GlareConvolver::set_kernel`), and the spectra it gives back are
    /// the previous kernel's.
    #[test]
    fn prepared_spectra_convolve_as_the_kernel_they_came_from() {
        use gazelight_vision::RgbImage;
        use gazelight_vision::glare::{GlareConvolver, GlareWindow};

        let params = small_params();
        let mut reference = PsfBuilder::new(params.clone()).expect("builder");
        let initial = reference.kernel().clone();
        let window = GlareWindow {
            full_weight_deg: 1.0,
            fade_sigma_deg: 0.5,
        };
        let mut conv = GlareConvolver::new(&initial, window).expect("convolver");
        let worker = PsfWorker::start(params, &initial, Some(conv.preparer()), 1, Priority::Idle)
            .expect("worker");
        worker.request_views([Some(6.5), None]);
        let deadline = std::time::Instant::now() + Duration::from_secs(120);
        let (got_mm, spectra_mm) = loop {
            assert!(std::time::Instant::now() < deadline, "no kernel");
            let taken = worker.take(0, |p, _| {
                let spectra = p.spectra.as_mut().expect("spectra made on the worker");
                let mm = (p.kernel.pupil_mm, spectra.pupil_mm());
                conv.install(spectra).expect("install");
                // The slot now holds the spectra installed before (4 mm).
                (mm, spectra.pupil_mm())
            });
            if let Some((mm, previous_mm)) = taken {
                assert_eq!(previous_mm, initial.pupil_mm);
                break mm;
            }
            std::thread::sleep(Duration::from_millis(5));
        };
        assert_eq!((got_mm, spectra_mm), (6.5, 6.5));
        assert_eq!(conv.kernel_pupil_mm(), 6.5);
        let mut own = GlareConvolver::new(&initial, window).expect("convolver");
        own.set_kernel(reference.rebuild(6.5)).expect("kernel");
        let (w, h) = (48, 40);
        let mut img = RgbImage::new(w, h);
        for (i, p) in img.pixels.iter_mut().enumerate() {
            let v = if i % 97 == 0 {
                1e4
            } else {
                0.1 * (i % 7) as f32
            };
            *p = [v, 0.5 * v, 0.25 * v];
        }
        let (mut a, mut b) = (img.clone(), img.clone());
        conv.apply(&mut a, [20.5, 18.0]);
        own.apply(&mut b, [20.5, 18.0]);
        assert_ne!(a, img, "the glare did nothing");
        let peak = b.pixels.iter().flatten().fold(0.0f32, |m, &v| m.max(v));
        let err = a
            .pixels
            .iter()
            .flatten()
            .zip(b.pixels.iter().flatten())
            .fold(0.0f32, |m, (x, y)| m.max((x - y).abs()));
        assert!(
            err <= 1e-6 * peak,
            "installed vs own spectra: {err} of peak {peak}"
        );
    }
}
