//! The status page's images (`/frame.png`, `/psf.png`): each published
//! display frame and each glare kernel is encoded **at most once**, on one
//! encoder thread of the server's own (`gazelight-status-png`, nice 10),
//! and every request is answered from a cache that holds only the newest
//! encoding of each image — however many clients ask.
//!
//! Before, each request copied the frame out of the hub and encoded it on
//! the tokio runtime the tracker's live eye task runs on: 64 clients
//! polling `/frame.png` kept both of its workers encoding PNGs and the
//! `EyeState` age at the frame loop went from tens of milliseconds to over
//! a second on two cores.
//!
//! A request reads the hub's frame counter (one short lock, no copy). When
//! the cache already holds that frame it is sent at once (the bytes are
//! shared, not copied). Otherwise the request asks the encoder and waits
//! for it, at most [`ENCODE_WAIT`]; past that it gets the previous
//! encoding (or 503 before the first). Requests arriving while a frame is
//! encoded wait for that one encoding; the encoder takes the newest frame
//! each time, so at most one encoding per published frame (10 per second,
//! the frame loop's `DISPLAY_PUBLISH_SECS`) happens, and none without
//! clients. Memory: one copy of the frame, one PNG of each image.

use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::Duration;

use axum::body::Bytes;
use tokio::sync::watch;

use super::ServeError;
use crate::hub::Hub;

/// Longest a request waits for an encoding before it gets the previous one.
pub const ENCODE_WAIT: Duration = Duration::from_secs(2);
/// Niceness of the encoder thread: it yields to the frame loop, the tracker
/// task and the writers.
const ENCODER_NICE: i32 = 10;

/// The two images the page shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Image {
    /// The newest display frame (RGBA8), keyed by its frame counter.
    Frame,
    /// The glare kernel, log-scaled grey, keyed by its rebuild counter.
    Psf,
}

/// One encoded image.
#[derive(Clone, Debug)]
pub struct Png {
    /// The frame or rebuild counter it shows.
    pub generation: u64,
    /// The PNG, or why it could not be encoded.
    pub bytes: Result<Bytes, String>,
}

/// The newest encoding of each image.
#[derive(Clone, Debug, Default)]
pub struct Encoded {
    pub frame: Option<Png>,
    pub psf: Option<Png>,
    /// Encodings done since start (both images).
    pub encodes: u64,
}

impl Encoded {
    fn get(&self, image: Image) -> Option<&Png> {
        match image {
            Image::Frame => self.frame.as_ref(),
            Image::Psf => self.psf.as_ref(),
        }
    }
}

#[derive(Default)]
struct Wanted {
    frame: bool,
    psf: bool,
    stop: bool,
}

struct Shared {
    wanted: Mutex<Wanted>,
    wake: Condvar,
}

fn lock(m: &Mutex<Wanted>) -> MutexGuard<'_, Wanted> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}

/// The encoder thread and its cache; stops the thread when dropped.
pub struct ImageCache {
    hub: Arc<Hub>,
    shared: Arc<Shared>,
    ready: watch::Receiver<Encoded>,
    _thread: JoinHandle<()>,
}

impl ImageCache {
    /// Starts the encoder thread for `hub`'s images.
    pub fn start(hub: Arc<Hub>) -> Result<Self, ServeError> {
        let shared = Arc::new(Shared {
            wanted: Mutex::new(Wanted::default()),
            wake: Condvar::new(),
        });
        let (tx, ready) = watch::channel(Encoded::default());
        let thread = {
            let (hub, shared) = (hub.clone(), shared.clone());
            std::thread::Builder::new()
                .name("gazelight-status-png".into())
                .spawn(move || encoder(&hub, &shared, &tx))
                .map_err(ServeError::Encoder)?
        };
        Ok(Self {
            hub,
            shared,
            ready,
            _thread: thread,
        })
    }

    /// Encodings done so far.
    pub fn encodes(&self) -> u64 {
        self.ready.borrow().encodes
    }

    /// The current generation of `image` in the hub (0: none yet).
    fn published(&self, image: Image) -> u64 {
        match image {
            Image::Frame => self.hub.with_display(|d| {
                let whole = d.width > 0 && d.rgba8.len() == d.width * d.height * 4;
                if whole { d.frame } else { 0 }
            }),
            Image::Psf => self.hub.with_psf(|p| {
                let whole = p.size_px > 0 && p.values.len() == p.size_px * p.size_px;
                if whole { p.rebuild } else { 0 }
            }),
        }
    }

    /// The newest `image` for a request: `None` when none is published
    /// yet; otherwise an encoding of the published generation, or of an
    /// older one when the encoder did not finish within [`ENCODE_WAIT`]
    /// (`None` too when there is none at all).
    pub async fn get(&self, image: Image) -> Option<Png> {
        let wanted = self.published(image);
        if wanted == 0 {
            return None;
        }
        let mut rx = self.ready.clone();
        let fresh = |e: &Encoded| e.get(image).is_some_and(|p| p.generation >= wanted);
        if !fresh(&rx.borrow()) {
            {
                let mut w = lock(&self.shared.wanted);
                match image {
                    Image::Frame => w.frame = true,
                    Image::Psf => w.psf = true,
                }
            }
            self.shared.wake.notify_one();
            // A closed channel (the encoder gone) or the time limit: serve
            // what there is.
            let _ = tokio::time::timeout(ENCODE_WAIT, rx.wait_for(fresh)).await;
        }
        rx.borrow().get(image).cloned()
    }
}

impl Drop for ImageCache {
    fn drop(&mut self) {
        lock(&self.shared.wanted).stop = true;
        self.shared.wake.notify_one();
    }
}

/// The encoder thread: waits for a request, encodes the newest published
/// generation of each wanted image unless it is already in the cache.
fn encoder(hub: &Hub, shared: &Shared, tx: &watch::Sender<Encoded>) {
    lower_this_threads_priority();
    let mut rgba: Vec<u8> = Vec::new();
    let mut values: Vec<f32> = Vec::new();
    loop {
        let (frame, psf) = {
            let mut w = lock(&shared.wanted);
            while !(w.frame || w.psf || w.stop) {
                w = shared.wake.wait(w).unwrap_or_else(|p| p.into_inner());
            }
            if w.stop {
                return;
            }
            let wanted = (w.frame, w.psf);
            // Requests from now on ask again (a newer frame may come).
            w.frame = false;
            w.psf = false;
            wanted
        };
        if frame {
            let have = tx.borrow().frame.as_ref().map_or(0, |p| p.generation);
            // Copy under the hub's lock (the frame loop's publish waits at
            // most this copy), encode outside it.
            let snap = hub.with_display(|d| {
                let whole = d.width > 0 && d.rgba8.len() == d.width * d.height * 4;
                (whole && d.frame > have).then(|| {
                    rgba.clear();
                    rgba.extend_from_slice(&d.rgba8);
                    (d.frame, d.width, d.height)
                })
            });
            if let Some((generation, w, h)) = snap {
                let bytes = encode(w, h, image::ExtendedColorType::Rgba8, &rgba);
                tx.send_modify(|e| {
                    e.frame = Some(Png { generation, bytes });
                    e.encodes += 1;
                });
            }
        }
        if psf {
            let have = tx.borrow().psf.as_ref().map_or(0, |p| p.generation);
            let snap = hub.with_psf(|p| {
                let whole = p.size_px > 0 && p.values.len() == p.size_px * p.size_px;
                (whole && p.rebuild > have).then(|| {
                    values.clear();
                    values.extend_from_slice(&p.values);
                    (p.rebuild, p.size_px)
                })
            });
            if let Some((generation, n)) = snap {
                let gray = super::psf_log_gray(&values);
                let bytes = encode(n, n, image::ExtendedColorType::L8, &gray);
                tx.send_modify(|e| {
                    e.psf = Some(Png { generation, bytes });
                    e.encodes += 1;
                });
            }
        }
    }
}

/// A lossless PNG of `data` (fdeflate: the fast mode; the page polls).
fn encode(
    width: usize,
    height: usize,
    color: image::ExtendedColorType,
    data: &[u8],
) -> Result<Bytes, String> {
    use image::ImageEncoder as _;
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    let (Ok(w), Ok(h)) = (u32::try_from(width), u32::try_from(height)) else {
        return Err(format!("image {width}x{height} too large"));
    };
    let mut buf = Vec::new();
    PngEncoder::new_with_quality(&mut buf, CompressionType::Fast, FilterType::Adaptive)
        .write_image(data, w, h, color)
        .map_err(|e| format!("encoding PNG {width}x{height}: {e}"))?;
    Ok(Bytes::from(buf))
}

/// Lowers the calling thread's priority to nice [`ENCODER_NICE`] (Linux:
/// `setpriority` on the thread id). A failure only costs the other
/// threads some CPU, so it is logged and ignored.
fn lower_this_threads_priority() {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain system calls on the calling thread.
        let rc = unsafe {
            let tid = libc::syscall(libc::SYS_gettid) as libc::id_t;
            libc::setpriority(libc::PRIO_PROCESS, tid, ENCODER_NICE)
        };
        if rc != 0 {
            tracing::debug!(
                "status PNG encoder: cannot lower the thread's priority: {}",
                std::io::Error::last_os_error()
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_tracker::LiveEyeState;

    fn decoded(p: &Png) -> image::RgbaImage {
        let bytes = p.bytes.as_ref().expect("encoded");
        image::load_from_memory(bytes).expect("a PNG").to_rgba8()
    }

    /// 64 requests for one published frame cost one encoding and all get
    /// the same bytes; a new frame costs one more; nothing is encoded
    /// before a request, and a request before the first frame gets none.
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn one_encoding_per_published_frame_whatever_the_requests() {
        let (_tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let cache = Arc::new(ImageCache::start(hub.clone()).unwrap());
        assert!(cache.get(Image::Frame).await.is_none(), "no frame yet");
        let (w, h) = (32usize, 24usize);
        let px: Vec<u8> = (0..w * h * 4).map(|i| (i * 13 % 251) as u8).collect();
        hub.publish_display(7, w, h, &px);
        tokio::time::sleep(Duration::from_millis(50)).await;
        assert_eq!(cache.encodes(), 0, "encoded before anyone asked");

        let requests: Vec<_> = (0..64)
            .map(|_| {
                let c = cache.clone();
                tokio::spawn(async move { c.get(Image::Frame).await })
            })
            .collect();
        let mut bodies = Vec::new();
        for r in requests {
            let png = r.await.unwrap().expect("an image");
            assert_eq!(png.generation, 7);
            bodies.push(png.bytes.clone().unwrap());
        }
        assert_eq!(cache.encodes(), 1, "64 requests, one frame");
        assert!(bodies.windows(2).all(|b| b[0] == b[1]));
        let png = cache.get(Image::Frame).await.unwrap();
        assert_eq!(decoded(&png).as_raw(), &px, "lossless");

        let px2: Vec<u8> = px.iter().map(|v| 255 - v).collect();
        hub.publish_display(8, w, h, &px2);
        for _ in 0..8 {
            let png = cache.get(Image::Frame).await.unwrap();
            assert_eq!(png.generation, 8);
            assert_eq!(decoded(&png).as_raw(), &px2);
        }
        assert_eq!(cache.encodes(), 2);

        // The kernel, once per rebuild.
        let mut k = vec![0.0f32; 9];
        k[4] = 1.0;
        hub.publish_psf(3, 4.0, 3, &k);
        for _ in 0..8 {
            assert_eq!(cache.get(Image::Psf).await.unwrap().generation, 3);
        }
        assert_eq!(cache.encodes(), 3);
    }
}
