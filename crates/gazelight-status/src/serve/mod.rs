//! The live status page: HTTP + WebSocket (axum) on 127.0.0.1 by default.
//!
//! | route | content |
//! | --- | --- |
//! | `GET /` | a self-contained page (no CDN): plain JS + `<canvas>` plots of the pupil per eye and the adaptation luminance over time, the PSF image and the latest frame |
//! | `GET /page.js` | the page's script |
//! | `GET /api/status` | [`Status`] as JSON, versioned by `schema` |
//! | `GET /api/history` | [`HistoryJson`]: the hub's history ring as arrays |
//! | `GET /frame.png` | the latest display frame (404 before the first) |
//! | `GET /psf.png` | the glare kernel in use, log-scaled over [`PSF_DECADES`] decades (404 before the first) |
//!
//! **Images off the session's threads.** `/frame.png` and `/psf.png` are
//! encoded at most once per published frame or kernel, on the server's own
//! low-priority encoder thread, and served from a cache of the newest
//! encoding of each ([`images`]): however many clients poll them, the
//! tracker's runtime and the frame loop do no encoding.
//! | `GET /ws` | WebSocket pushing the status JSON every [`ServeOptions::push_interval`] (100 ms) |
//!
//! **Bounded WebSocket memory.** One task renders the status JSON per
//! push interval into a `watch` channel (latest value only), and only while
//! clients are connected. Each client task sends the newest value when it
//! changes; a client slower than the pushes skips values (counted in
//! [`ServeStats::ws_skipped`]) instead of queueing them, and a send that
//! does not complete within [`ServeOptions::send_timeout`] (a client that
//! stopped reading and whose socket buffers are full) drops the client
//! ([`ServeStats::ws_dropped_slow`]). At most one message per client is in
//! flight at any time ([`ServeStats::ws_in_flight_max`]).

mod capped;
pub mod images;

use std::net::SocketAddr;
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Duration;

use axum::Router;
use axum::extract::State;
use axum::extract::ws::{Message, Utf8Bytes, WebSocket, WebSocketUpgrade};
use axum::http::{StatusCode, header};
use axum::response::{IntoResponse, Response};
use axum::routing::get;
use gazelight_tracker::pupil::clock::host_now_secs;
use gazelight_tracker::{PupilOrigin, PupilUnit};
use serde::Serialize;
use tokio::sync::watch;
use tokio::task::JoinHandle;

use crate::hub::{FrameStatus, Hub};
use gazelight_app::session::SessionSettings;
use gazelight_tracker::live::SourceStatus;

/// Version of the `/api/status` and `/api/history` JSON layouts; bumped on
/// any incompatible change.
pub const STATUS_SCHEMA: u32 = 1;
/// Decades of kernel values shown in `/psf.png` (the peak is white, values
/// below peak·10⁻⁶ black).
pub const PSF_DECADES: f64 = 6.0;

const PAGE_HTML: &str = include_str!("page.html");
const PAGE_JS: &str = include_str!("page.js");

/// Why the status server did not start.
#[derive(Debug, thiserror::Error)]
pub enum ServeError {
    /// The address could not be bound (a port in use, an address not here).
    #[error("status server: binding {addr}")]
    Bind {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    /// The bound socket's address could not be read.
    #[error("status server: address of the socket bound to {addr}")]
    LocalAddr {
        addr: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    /// The PNG encoder thread could not be started.
    #[error("status server: cannot start the PNG encoder: {0}")]
    Encoder(std::io::Error),
}

/// Server settings.
#[derive(Clone, Copy, Debug)]
pub struct ServeOptions {
    /// Interval of the WebSocket status pushes.
    pub push_interval: Duration,
    /// A WebSocket send that takes longer drops the client.
    pub send_timeout: Duration,
}

impl Default for ServeOptions {
    fn default() -> Self {
        Self {
            push_interval: Duration::from_millis(100),
            send_timeout: Duration::from_secs(1),
        }
    }
}

/// Counters of a running server.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct ServeStats {
    /// WebSocket clients connected now.
    pub ws_clients: u64,
    /// WebSocket messages sent.
    pub ws_sent: u64,
    /// Pushes a client skipped because it was still sending an older one.
    pub ws_skipped: u64,
    /// Clients dropped because a send did not complete in time.
    pub ws_dropped_slow: u64,
    /// Sends in progress now (all clients).
    pub ws_in_flight: u64,
    /// Most sends ever in progress at once, all clients together (each
    /// client task awaits its one send, so at most the number of clients).
    pub ws_in_flight_max: u64,
    /// Status pushes rendered.
    pub pushes: u64,
    /// PNG encodings of `/frame.png` and `/psf.png` (at most one per
    /// published frame or kernel, whatever the number of requests).
    pub png_encodes: u64,
    /// `/frame.png` and `/psf.png` requests answered with an image.
    pub png_served: u64,
}

#[derive(Default)]
struct Counters {
    ws_clients: AtomicU64,
    ws_sent: AtomicU64,
    ws_skipped: AtomicU64,
    ws_dropped_slow: AtomicU64,
    ws_in_flight: AtomicU64,
    ws_in_flight_max: AtomicU64,
    pushes: AtomicU64,
    png_served: AtomicU64,
}

impl Counters {
    fn snapshot(&self) -> ServeStats {
        let l = |a: &AtomicU64| a.load(Ordering::Relaxed);
        ServeStats {
            ws_clients: l(&self.ws_clients),
            ws_sent: l(&self.ws_sent),
            ws_skipped: l(&self.ws_skipped),
            ws_dropped_slow: l(&self.ws_dropped_slow),
            ws_in_flight: l(&self.ws_in_flight),
            ws_in_flight_max: l(&self.ws_in_flight_max),
            pushes: l(&self.pushes),
            png_encodes: 0,
            png_served: l(&self.png_served),
        }
    }
}

/// Handle to a running server.
pub struct ServeHandle {
    addr: SocketAddr,
    counters: Arc<Counters>,
    images: Arc<images::ImageCache>,
    tasks: Vec<JoinHandle<()>>,
}

impl ServeHandle {
    /// The bound address.
    pub fn local_addr(&self) -> SocketAddr {
        self.addr
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> ServeStats {
        ServeStats {
            png_encodes: self.images.encodes(),
            ..self.counters.snapshot()
        }
    }

    /// Waits for the server to end (after the hub's shutdown).
    pub async fn join(mut self) {
        for t in self.tasks.drain(..) {
            let _ = t.await;
        }
    }
}

impl Drop for ServeHandle {
    fn drop(&mut self) {
        for t in &self.tasks {
            t.abort();
        }
    }
}

#[derive(Clone)]
struct AppState {
    hub: Arc<Hub>,
    counters: Arc<Counters>,
    pushes: watch::Receiver<Utf8Bytes>,
    options: ServeOptions,
    images: Arc<images::ImageCache>,
}

/// Starts the status server on `addr` (port 0 picks a free port) with the
/// default options; it runs until [`Hub::shutdown_signal`] turns true. A
/// port in use is an error naming the address.
pub async fn spawn(hub: Arc<Hub>, addr: SocketAddr) -> Result<ServeHandle, ServeError> {
    spawn_with(hub, addr, ServeOptions::default()).await
}

/// [`spawn`] with explicit options.
pub async fn spawn_with(
    hub: Arc<Hub>,
    addr: SocketAddr,
    options: ServeOptions,
) -> Result<ServeHandle, ServeError> {
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|source| ServeError::Bind { addr, source })?;
    let addr = listener
        .local_addr()
        .map_err(|source| ServeError::LocalAddr { addr, source })?;
    // The page shows the display frame: the frame loop publishes (and on
    // the GPU reads back) one at its low rate from now on.
    hub.want_display();
    let counters = Arc::new(Counters::default());
    let (push_tx, push_rx) = watch::channel(Utf8Bytes::from_static("{}"));
    let images = Arc::new(images::ImageCache::start(hub.clone())?);
    let state = AppState {
        hub: hub.clone(),
        counters: counters.clone(),
        pushes: push_rx,
        options,
        images: images.clone(),
    };
    let app = router(state);
    let mut shutdown = hub.shutdown_signal();
    let server = tokio::spawn(async move {
        let stop = async move { shutdown_requested(&mut shutdown).await };
        // At most `capped::MAX_CONNECTIONS` open at once: clients can never
        // starve the session's writers of descriptors.
        let listener = capped::CappedListener::new(listener, capped::MAX_CONNECTIONS);
        if let Err(e) = axum::serve(listener, app)
            .with_graceful_shutdown(stop)
            .await
        {
            tracing::warn!(error = %e, "status server stopped with an error");
        }
    });
    let pusher = tokio::spawn(push_status(hub, push_tx, counters.clone(), options));
    tracing::info!(%addr, "status page at http://{addr}/");
    Ok(ServeHandle {
        addr,
        counters,
        images,
        tasks: vec![server, pusher],
    })
}

/// Resolves when the shutdown flag is (or becomes) true, or its sender is
/// gone.
async fn shutdown_requested(rx: &mut watch::Receiver<bool>) {
    let _ = rx.wait_for(|v| *v).await;
}

fn router(state: AppState) -> Router {
    Router::new()
        .route("/", get(page))
        .route("/page.js", get(script))
        .route("/api/status", get(status_json))
        .route("/api/history", get(history_json))
        .route("/frame.png", get(frame_png))
        .route("/psf.png", get(psf_png))
        .route("/ws", get(ws_upgrade))
        .with_state(state)
}

/// Renders the status into the push channel once per interval while
/// anyone listens.
async fn push_status(
    hub: Arc<Hub>,
    tx: watch::Sender<Utf8Bytes>,
    counters: Arc<Counters>,
    options: ServeOptions,
) {
    let mut tick = tokio::time::interval(options.push_interval);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    let mut shutdown = hub.shutdown_signal();
    loop {
        tokio::select! {
            _ = shutdown_requested(&mut shutdown) => break,
            _ = tick.tick() => {}
        }
        // The server's own clone in AppState is one receiver.
        if tx.receiver_count() <= 1 {
            continue;
        }
        match serde_json::to_string(&Status::collect(&hub)) {
            Ok(json) => {
                tx.send_replace(Utf8Bytes::from(json));
                counters.pushes.fetch_add(1, Ordering::Relaxed);
            }
            Err(e) => tracing::warn!(error = %e, "status server: encoding the status"),
        }
    }
}

/// The live eye state as the status reports it.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct EyeStatus {
    /// Updates of the filter chain since start.
    pub updates: u64,
    /// Host time of the state, s.
    pub t_secs: f64,
    /// Age of the state now, ms.
    pub age_ms: f64,
    /// Filtered gaze, normalised, top-left origin.
    pub gaze_uv: [f32; 2],
    pub gaze_valid: bool,
    pub blink: bool,
    /// The measured pupil per eye [right, left], mm: the newest clean
    /// sample (the tracker's mm, or raw × a physical scale); null where the
    /// eye is not measured now or has no physical scale.
    pub pupil_mm: [Option<f32>; 2],
    /// The measured pupil per eye in its unit (raw where no physical
    /// scale), with the unit; null where not measured.
    pub measured: [Option<f32>; 2],
    pub measured_unit: [Option<PupilUnit>; 2],
    /// The model aperture per eye [right, left], mm: the pupil the glare
    /// PSF is built for (001 §5's map or the measured mm; not a
    /// measurement).
    pub aperture_mm: [f32; 2],
    /// Where each eye's aperture came from.
    pub pupil_origin: [PupilOrigin; 2],
    /// Confidence of each eye's newest raw sample.
    pub confidence: [f32; 2],
    /// Aperture the pipeline uses (binocular), mm.
    pub binocular_pupil_mm: f32,
}

/// The kernel in use.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct PsfStatus {
    /// Rebuild counter of the kernel (0 = none yet).
    pub rebuild: u64,
    pub pupil_mm: f64,
    pub size_px: usize,
}

/// The newest display frame.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct DisplayStatus {
    /// Frame counter of the snapshot (0 = none yet).
    pub frame: u64,
    pub width: usize,
    pub height: usize,
}

/// `/api/status` (schema [`STATUS_SCHEMA`]).
#[derive(Clone, Debug, Serialize)]
pub struct Status {
    pub schema: u32,
    pub service: &'static str,
    pub version: &'static str,
    /// Host time of this status, s.
    pub now_secs: f64,
    pub shutting_down: bool,
    /// Tracker source: uri, health, sample rate, confidence, dropout rate.
    pub source: SourceStatus,
    pub eye: EyeStatus,
    /// Frame loop: frames, late frames, timings, adaptation, EyeState age
    /// at frame time, PSF rebuilds.
    pub frame: FrameStatus,
    pub psf: PsfStatus,
    pub display: DisplayStatus,
    /// Every setting in effect and where it came from (`session.json`).
    pub settings: Option<SessionSettings>,
}

impl Status {
    /// Collects the hub's current values.
    pub fn collect(hub: &Hub) -> Self {
        let now = host_now_secs();
        let live = *hub.eye.borrow();
        let s = live.state;
        Self {
            schema: STATUS_SCHEMA,
            service: "gazelight",
            version: env!("CARGO_PKG_VERSION"),
            now_secs: now,
            shutting_down: hub.shutting_down(),
            source: hub.source(),
            eye: EyeStatus {
                updates: live.updates,
                t_secs: s.t_secs,
                age_ms: s.age_secs(now) * 1e3,
                gaze_uv: s.gaze_uv,
                gaze_valid: s.gaze_valid,
                blink: s.blink,
                pupil_mm: [s.eyes[0].measured_mm(), s.eyes[1].measured_mm()],
                measured: [s.eyes[0].measured, s.eyes[1].measured],
                measured_unit: [s.eyes[0].measured_unit, s.eyes[1].measured_unit],
                aperture_mm: [s.eyes[0].pupil_mm, s.eyes[1].pupil_mm],
                pupil_origin: [s.eyes[0].pupil_origin, s.eyes[1].pupil_origin],
                confidence: [s.eyes[0].confidence, s.eyes[1].confidence],
                binocular_pupil_mm: s.pupil_mm(),
            },
            frame: hub.frame(),
            psf: hub.with_psf(|p| PsfStatus {
                rebuild: p.rebuild,
                pupil_mm: p.pupil_mm,
                size_px: p.size_px,
            }),
            display: hub.with_display(|d| DisplayStatus {
                frame: d.frame,
                width: d.width,
                height: d.height,
            }),
            settings: hub.settings().cloned(),
        }
    }
}

/// `/api/history`: the history ring, oldest first, as parallel arrays.
#[derive(Clone, Debug, Default, Serialize)]
pub struct HistoryJson {
    pub schema: u32,
    pub t_secs: Vec<f64>,
    pub pupil_right_mm: Vec<f32>,
    pub pupil_left_mm: Vec<f32>,
    pub adaptation_cd_m2: Vec<f64>,
    /// Per view in stereo: left, right (empty in mono).
    pub adaptation_left_cd_m2: Vec<f64>,
    pub adaptation_right_cd_m2: Vec<f64>,
    /// The pupil the light predicts per eye, mm.
    pub pupil_light_right_mm: Vec<f32>,
    pub pupil_light_left_mm: Vec<f32>,
    pub eye_state_age_ms: Vec<f64>,
    pub frame_ms: Vec<f64>,
}

impl HistoryJson {
    /// Copies the hub's history ring.
    pub fn collect(hub: &Hub) -> Self {
        hub.with_history(|h| {
            let n = h.len();
            let mut out = HistoryJson {
                schema: STATUS_SCHEMA,
                t_secs: Vec::with_capacity(n),
                pupil_right_mm: Vec::with_capacity(n),
                pupil_left_mm: Vec::with_capacity(n),
                adaptation_cd_m2: Vec::with_capacity(n),
                adaptation_left_cd_m2: Vec::new(),
                adaptation_right_cd_m2: Vec::new(),
                pupil_light_right_mm: Vec::with_capacity(n),
                pupil_light_left_mm: Vec::with_capacity(n),
                eye_state_age_ms: Vec::with_capacity(n),
                frame_ms: Vec::with_capacity(n),
            };
            for p in h.iter() {
                out.t_secs.push(p.t_secs);
                out.pupil_right_mm.push(p.pupil_mm[0]);
                out.pupil_left_mm.push(p.pupil_mm[1]);
                out.adaptation_cd_m2.push(p.adaptation_cd_m2);
                out.pupil_light_right_mm.push(p.pupil_light_mm[0]);
                out.pupil_light_left_mm.push(p.pupil_light_mm[1]);
                if p.view_adaptation_cd_m2[1].is_finite() {
                    out.adaptation_left_cd_m2.push(p.view_adaptation_cd_m2[0]);
                    out.adaptation_right_cd_m2.push(p.view_adaptation_cd_m2[1]);
                }
                out.eye_state_age_ms.push(p.eye_state_age_ms);
                out.frame_ms.push(p.frame_ms);
            }
            out
        })
    }
}

fn no_store<T: IntoResponse>(content_type: &'static str, body: T) -> Response {
    (
        [
            (header::CONTENT_TYPE, content_type),
            (header::CACHE_CONTROL, "no-store"),
        ],
        body,
    )
        .into_response()
}

/// Where [`page`] puts the status and history the page shows at once.
const INITIAL_PLACEHOLDER: &str = "__GAZELIGHT_INITIAL__";

/// The page with the current status and history inside it (a JSON
/// `<script>` the page script applies before its first WebSocket update),
/// so it has content on first load.
fn page_html(hub: &Hub) -> String {
    let initial = serde_json::json!({
        "status": Status::collect(hub),
        "history": HistoryJson::collect(hub),
    });
    // Inside <script>, "</" would end the element; JSON allows "<\/".
    let json = initial.to_string().replace("</", "<\\/");
    PAGE_HTML.replacen(INITIAL_PLACEHOLDER, &json, 1)
}

async fn page(State(st): State<AppState>) -> Response {
    no_store("text/html; charset=utf-8", page_html(&st.hub))
}

async fn script() -> Response {
    no_store("text/javascript; charset=utf-8", PAGE_JS)
}

fn json_response<T: Serialize>(value: &T) -> Response {
    match serde_json::to_string(value) {
        Ok(s) => no_store("application/json", s),
        Err(e) => (
            StatusCode::INTERNAL_SERVER_ERROR,
            format!("encoding JSON: {e}"),
        )
            .into_response(),
    }
}

async fn status_json(State(st): State<AppState>) -> Response {
    json_response(&Status::collect(&st.hub))
}

async fn history_json(State(st): State<AppState>) -> Response {
    json_response(&HistoryJson::collect(&st.hub))
}

/// Serves the newest encoding of `image` from the cache (see [`images`]).
async fn image_response(st: &AppState, image: images::Image) -> Response {
    match st.images.get(image).await {
        Some(images::Png { bytes: Ok(png), .. }) => {
            st.counters.png_served.fetch_add(1, Ordering::Relaxed);
            no_store("image/png", png)
        }
        Some(images::Png { bytes: Err(e), .. }) => {
            (StatusCode::INTERNAL_SERVER_ERROR, e).into_response()
        }
        None if matches!(image, images::Image::Frame) && st.hub.with_display(|d| d.frame) == 0 => {
            (StatusCode::NOT_FOUND, "no frame yet").into_response()
        }
        None if matches!(image, images::Image::Psf) && st.hub.with_psf(|p| p.rebuild) == 0 => {
            (StatusCode::NOT_FOUND, "no PSF yet").into_response()
        }
        None => (
            StatusCode::SERVICE_UNAVAILABLE,
            [(header::RETRY_AFTER, "1")],
            "the image is being encoded; try again",
        )
            .into_response(),
    }
}

async fn frame_png(State(st): State<AppState>) -> Response {
    image_response(&st, images::Image::Frame).await
}

/// The kernel as 8-bit grey, log-scaled: the peak is 255, a value
/// `PSF_DECADES` decades below it (or less, or non-finite) is 0.
pub fn psf_log_gray(values: &[f32]) -> Vec<u8> {
    let peak = values
        .iter()
        .copied()
        .filter(|v| v.is_finite())
        .fold(0.0f32, f32::max);
    values
        .iter()
        .map(|&v| {
            if !(peak > 0.0 && v.is_finite() && v > 0.0) {
                return 0;
            }
            let level = 1.0 + f64::from(v / peak).log10() / PSF_DECADES;
            (level.clamp(0.0, 1.0) * 255.0).round() as u8
        })
        .collect()
}

async fn psf_png(State(st): State<AppState>) -> Response {
    image_response(&st, images::Image::Psf).await
}

async fn ws_upgrade(State(st): State<AppState>, ws: WebSocketUpgrade) -> Response {
    ws.on_upgrade(move |socket| ws_client(socket, st))
}

/// One WebSocket client: sends the newest status when it changes; never
/// more than one send in flight; a stuck send drops the client.
async fn ws_client(mut socket: WebSocket, st: AppState) {
    let c = &st.counters;
    c.ws_clients.fetch_add(1, Ordering::Relaxed);
    let mut pushes = st.pushes.clone();
    let mut shutdown = st.hub.shutdown_signal();
    // Generation counting for skipped pushes.
    let mut seen = st.counters.pushes.load(Ordering::Relaxed);
    loop {
        tokio::select! {
            _ = shutdown_requested(&mut shutdown) => {
                let _ = tokio::time::timeout(st.options.send_timeout, socket.send(Message::Close(None))).await;
                break;
            }
            incoming = socket.recv() => match incoming {
                // The page sends nothing; pings are answered by the library.
                Some(Ok(Message::Close(_))) | None | Some(Err(_)) => break,
                Some(Ok(_)) => {}
            },
            changed = pushes.changed() => {
                if changed.is_err() {
                    break;
                }
                let msg = pushes.borrow_and_update().clone();
                let now = c.pushes.load(Ordering::Relaxed);
                if now > seen + 1 {
                    c.ws_skipped.fetch_add(now - seen - 1, Ordering::Relaxed);
                }
                seen = now;
                let in_flight = c.ws_in_flight.fetch_add(1, Ordering::Relaxed) + 1;
                c.ws_in_flight_max.fetch_max(in_flight, Ordering::Relaxed);
                let sent = tokio::time::timeout(st.options.send_timeout, socket.send(Message::Text(msg))).await;
                c.ws_in_flight.fetch_sub(1, Ordering::Relaxed);
                match sent {
                    Ok(Ok(())) => {
                        c.ws_sent.fetch_add(1, Ordering::Relaxed);
                    }
                    Ok(Err(_)) => break,
                    Err(_) => {
                        c.ws_dropped_slow.fetch_add(1, Ordering::Relaxed);
                        tracing::info!("status server: dropping a WebSocket client that stopped reading");
                        break;
                    }
                }
            }
        }
    }
    c.ws_clients.fetch_sub(1, Ordering::Relaxed);
}

#[cfg(test)]
mod tests {
    use super::*;
    use gazelight_tracker::EyeState;
    use gazelight_tracker::LiveEyeState;
    use tokio::io::{AsyncReadExt, AsyncWriteExt};
    use tokio::net::TcpStream;

    fn loopback() -> SocketAddr {
        "127.0.0.1:0".parse().unwrap()
    }

    /// A raw HTTP/1.1 GET: (status code, body).
    async fn get(addr: SocketAddr, path: &str) -> (u16, Vec<u8>) {
        let mut s = TcpStream::connect(addr).await.unwrap();
        let req = format!("GET {path} HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n");
        s.write_all(req.as_bytes()).await.unwrap();
        let mut buf = Vec::new();
        tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut buf))
            .await
            .expect("response in time")
            .unwrap();
        let end = buf.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
        let head = String::from_utf8_lossy(&buf[..end]).to_string();
        let code = head.split(' ').nth(1).unwrap().parse().unwrap();
        assert!(
            !head
                .to_ascii_lowercase()
                .contains("transfer-encoding: chunked"),
            "{head}"
        );
        (code, buf[end + 4..].to_vec())
    }

    async fn get_json(addr: SocketAddr, path: &str) -> serde_json::Value {
        let (code, body) = get(addr, path).await;
        assert_eq!(code, 200, "{path}");
        serde_json::from_slice(&body).unwrap()
    }

    fn live(k: u64, pupil_mm: [f32; 2]) -> LiveEyeState {
        let mut state = EyeState {
            t_secs: host_now_secs(),
            gaze_uv: [0.25, 0.75],
            gaze_valid: true,
            ..EyeState::default()
        };
        for (e, ch) in state.eyes.iter_mut().enumerate() {
            // The measured pupil and, a little apart, the aperture: the
            // page shows both, never one for the other.
            ch.measured = Some(pupil_mm[e]);
            ch.measured_unit = Some(PupilUnit::Mm);
            ch.present = true;
            ch.pupil_mm = pupil_mm[e] + 0.5;
            ch.pupil_origin = PupilOrigin::Measured;
            ch.confidence = 0.9;
        }
        LiveEyeState {
            state,
            updated_host_secs: state.t_secs,
            updates: k,
        }
    }

    fn frame(n: u64, adaptation_cd_m2: f64, pupil_mm: [f32; 2]) -> FrameStatus {
        FrameStatus {
            frames: n,
            frames_late: n / 10,
            t_secs: n as f64 / 90.0,
            pupil_mm,
            frame_pupil_mm: 0.5 * (pupil_mm[0] + pupil_mm[1]),
            adaptation_cd_m2,
            target_cd_m2: adaptation_cd_m2 * 2.0,
            eye_state_age_ms: 1.5,
            frame_ms: 6.0,
            psf_rebuilds: n / 3,
            ..FrameStatus::default()
        }
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn status_history_and_images_follow_the_hub() {
        let (tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("pupil://127.0.0.1:50020", rx);
        let server = spawn(hub.clone(), loopback()).await.unwrap();
        let addr = server.local_addr();

        let (code, body) = get(addr, "/").await;
        assert_eq!(code, 200);
        let html = String::from_utf8(body).unwrap();
        assert!(html.contains("<canvas") && html.contains("/page.js"));
        assert!(
            !html.contains("http://") && !html.contains("https://"),
            "no CDN"
        );
        let (code, js) = get(addr, "/page.js").await;
        assert_eq!(code, 200);
        assert!(String::from_utf8(js).unwrap().contains("new WebSocket"));
        assert_eq!(get(addr, "/frame.png").await.0, 404);
        assert_eq!(get(addr, "/psf.png").await.0, 404);
        assert_eq!(get(addr, "/nope").await.0, 404);

        // Session state 1.
        tx.send_replace(live(10, [3.5, 3.75]));
        hub.update_source(|s| {
            s.health = gazelight_tracker::live::SourceHealth::Live;
            s.sample_rate_hz = 600.0;
            s.confidence = 0.93;
            s.dropout_rate = 0.02;
            s.clock = Some(gazelight_tracker::pupil::clock::ClockStats {
                jumps: 1,
                last_jump_secs: Some(-1234.5),
                rejected: 3,
                ..Default::default()
            });
        });
        hub.publish_frame(frame(9, 40.0, [3.5, 3.75]));
        let s1 = get_json(addr, "/api/status").await;
        // The source's clock mapping, as the page shows it.
        assert_eq!(s1["source"]["clock"]["jumps"], 1);
        assert_eq!(s1["source"]["clock"]["last_jump_secs"], -1234.5);
        assert_eq!(s1["source"]["clock"]["rejected"], 3);
        assert!(s1["source"]["degraded_reason"].is_null());
        assert_eq!(s1["schema"], STATUS_SCHEMA);
        assert_eq!(s1["source"]["uri"], "pupil://127.0.0.1:50020");
        assert_eq!(s1["source"]["health"], "live");
        assert_eq!(s1["source"]["sample_rate_hz"], 600.0);
        assert_eq!(s1["source"]["dropout_rate"], 0.02);
        assert_eq!(s1["eye"]["updates"], 10);
        assert_eq!(s1["eye"]["pupil_mm"][1], 3.75);
        assert_eq!(s1["eye"]["measured_unit"][1], "mm");
        assert_eq!(s1["eye"]["aperture_mm"][1], 4.25);
        assert_eq!(s1["eye"]["pupil_origin"][0], "measured");
        assert_eq!(s1["frame"]["frames"], 9);
        assert_eq!(s1["frame"]["adaptation_cd_m2"], 40.0);
        assert_eq!(s1["frame"]["eye_state_age_ms"], 1.5);
        assert_eq!(s1["frame"]["psf_rebuilds"], 3);
        assert!(s1["frame"]["timings"]["total_ms"].is_number());
        assert!(s1["eye"]["age_ms"].as_f64().unwrap() >= 0.0);

        // Session state 2: the values move.
        tx.send_replace(live(11, [4.0, 4.25]));
        hub.publish_frame(frame(10, 12.5, [4.0, 4.25]));
        let s2 = get_json(addr, "/api/status").await;
        assert_eq!(s2["eye"]["updates"], 11);
        assert_eq!(s2["eye"]["pupil_mm"][0], 4.0);
        assert_eq!(s2["frame"]["frames"], 10);
        assert_eq!(s2["frame"]["adaptation_cd_m2"], 12.5);
        assert!(s2["now_secs"].as_f64() > s1["now_secs"].as_f64());

        let h = get_json(addr, "/api/history").await;
        assert_eq!(h["schema"], STATUS_SCHEMA);
        assert_eq!(h["adaptation_cd_m2"], serde_json::json!([40.0, 12.5]));
        assert_eq!(h["pupil_left_mm"], serde_json::json!([3.75, 4.25]));
        assert_eq!(h["t_secs"].as_array().unwrap().len(), 2);

        // The page itself carries the state and history at load (content
        // before the first WebSocket update), in a JSON script element.
        let (_, body) = get(addr, "/").await;
        let html = String::from_utf8(body).unwrap();
        let start = html
            .find(r#"<script id="initial" type="application/json">"#)
            .unwrap();
        let json = &html[start..];
        let json = &json[json.find('>').unwrap() + 1..json.find("</script>").unwrap()];
        let initial: serde_json::Value = serde_json::from_str(json).unwrap();
        assert_eq!(initial["status"]["eye"]["updates"], 11, "{initial}");
        assert_eq!(initial["status"]["frame"]["frames"], 10);
        assert_eq!(
            initial["history"]["pupil_left_mm"],
            serde_json::json!([3.75, 4.25])
        );
        assert!(!html.contains("__GAZELIGHT_INITIAL__"));

        // The latest frame, exactly.
        let (w, hgt) = (6usize, 4usize);
        let px: Vec<u8> = (0..w * hgt * 4).map(|i| (i * 7 % 251) as u8).collect();
        hub.publish_display(10, w, hgt, &px);
        let (code, png) = get(addr, "/frame.png").await;
        assert_eq!(code, 200);
        let img = image::load_from_memory(&png).unwrap().to_rgba8();
        assert_eq!((img.width() as usize, img.height() as usize), (w, hgt));
        assert_eq!(img.as_raw(), &px);

        // The kernel, log-scaled: peak → 255, 10⁻³ of it → half way
        // (3 of 6 decades), 10⁻⁷ → 0.
        let mut k = vec![0.0f32; 9];
        k[4] = 0.5;
        k[1] = 0.5e-3;
        k[7] = 0.5e-7;
        hub.publish_psf(1, 4.0, 3, &k);
        let (code, png) = get(addr, "/psf.png").await;
        assert_eq!(code, 200);
        let img = image::load_from_memory(&png).unwrap().to_luma8();
        assert_eq!(img.get_pixel(1, 1).0[0], 255);
        assert_eq!(img.get_pixel(1, 0).0[0], 128);
        assert_eq!(img.get_pixel(1, 2).0[0], 0);
        assert_eq!(img.get_pixel(0, 0).0[0], 0);

        hub.request_shutdown();
        tokio::time::timeout(Duration::from_secs(3), server.join())
            .await
            .expect("the server stops on shutdown");
    }

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn port_in_use_is_an_error_naming_the_address() {
        let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = taken.local_addr().unwrap();
        let (_tx, rx) = watch::channel(LiveEyeState::default());
        let err = match spawn(Hub::new("test://", rx), addr).await {
            Ok(_) => panic!("a taken port must fail"),
            Err(e) => format!("{e:#}"),
        };
        assert!(err.contains(&addr.to_string()), "{err}");
    }

    /// Completes a WebSocket handshake on a raw socket; returns the socket
    /// and any bytes read past the response head.
    async fn ws_handshake(stream: &mut TcpStream, addr: SocketAddr) -> Vec<u8> {
        let req = format!(
            "GET /ws HTTP/1.1\r\nHost: {addr}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n\
             Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\nSec-WebSocket-Version: 13\r\n\r\n"
        );
        stream.write_all(req.as_bytes()).await.unwrap();
        let mut buf = Vec::new();
        let mut chunk = [0u8; 512];
        loop {
            let n = tokio::time::timeout(Duration::from_secs(3), stream.read(&mut chunk))
                .await
                .unwrap()
                .unwrap();
            assert!(n > 0, "closed during the handshake");
            buf.extend_from_slice(&chunk[..n]);
            if let Some(end) = buf.windows(4).position(|w| w == b"\r\n\r\n") {
                let head = String::from_utf8_lossy(&buf[..end]).to_string();
                assert!(head.starts_with("HTTP/1.1 101"), "{head}");
                // RFC 6455 §1.3's example key and accept value.
                assert!(head.contains("s3pPLMBiTxaQ9kYGzzhZRbK+xOo="), "{head}");
                return buf[end + 4..].to_vec();
            }
        }
    }

    /// Reads one unmasked server text frame.
    async fn ws_read_text(stream: &mut TcpStream, pending: &mut Vec<u8>) -> String {
        async fn need(stream: &mut TcpStream, pending: &mut Vec<u8>, n: usize) {
            let mut chunk = [0u8; 4096];
            while pending.len() < n {
                let k = stream.read(&mut chunk).await.unwrap();
                assert!(k > 0, "closed");
                pending.extend_from_slice(&chunk[..k]);
            }
        }
        need(stream, pending, 2).await;
        assert_eq!(pending[0], 0x81, "a final text frame");
        let (len, head) = match pending[1] & 0x7f {
            126 => {
                need(stream, pending, 4).await;
                (u16::from_be_bytes([pending[2], pending[3]]) as usize, 4)
            }
            127 => {
                need(stream, pending, 10).await;
                let mut b = [0u8; 8];
                b.copy_from_slice(&pending[2..10]);
                (u64::from_be_bytes(b) as usize, 10)
            }
            n => (n as usize, 2),
        };
        need(stream, pending, head + len).await;
        let text = String::from_utf8(pending[head..head + len].to_vec()).unwrap();
        pending.drain(..head + len);
        text
    }

    fn rss_kib() -> Option<u64> {
        let s = std::fs::read_to_string("/proc/self/status").ok()?;
        let line = s.lines().find(|l| l.starts_with("VmRSS:"))?;
        line.split_whitespace().nth(1)?.parse().ok()
    }

    /// A client that completes the handshake and never reads: pushes at
    /// 1 kHz (≈ 100× the page's rate) for at least 3 s while a second,
    /// reading client must keep receiving. The stalled client is dropped once its
    /// socket buffers are full, nothing queues per client, and the
    /// process's memory stays flat (measured in a process of its own).
    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn websocket_client_that_never_reads_is_dropped_memory_bounded() {
        // RSS is the process's: measured with no other test running.
        if !gazelight_test_support::isolated::in_own_process(
            "serve::tests::websocket_client_that_never_reads_is_dropped_memory_bounded",
        ) {
            return;
        }
        let (tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("test://", rx);
        let options = ServeOptions {
            push_interval: Duration::from_millis(1),
            send_timeout: Duration::from_millis(300),
        };
        let server = spawn_with(hub.clone(), loopback(), options).await.unwrap();
        let addr = server.local_addr();

        // The stalled client: a small receive buffer, never read.
        let sock = tokio::net::TcpSocket::new_v4().unwrap();
        sock.set_recv_buffer_size(4096).unwrap();
        let mut stalled = sock.connect(addr).await.unwrap();
        let _ = ws_handshake(&mut stalled, addr).await;
        // The reading client.
        let mut reader = TcpStream::connect(addr).await.unwrap();
        let mut pending = ws_handshake(&mut reader, addr).await;

        let rss_before = rss_kib();
        let start = std::time::Instant::now();
        let mut k = 0u64;
        let mut received = 0u64;
        let mut seen_updates = std::collections::BTreeSet::new();
        // At least 3 s, and until the stalled client's socket buffers (the
        // kernel's, up to a few MB on loopback) are full and it is dropped.
        while start.elapsed() < Duration::from_secs(3)
            || (server.stats().ws_dropped_slow == 0 && start.elapsed() < Duration::from_secs(15))
        {
            k += 1;
            tx.send_replace(live(k, [3.0 + (k % 100) as f32 * 0.01, 4.0]));
            hub.publish_frame(frame(k, 10.0 + k as f64, [3.0, 4.0]));
            // Read what the reading client has, without stalling: at most
            // 8 messages a round (at a 1 kHz push a drain "until 1 ms of
            // silence" never ends, and the values would stop changing).
            for _ in 0..8 {
                let Ok(text) = tokio::time::timeout(
                    Duration::from_millis(1),
                    ws_read_text(&mut reader, &mut pending),
                )
                .await
                else {
                    break;
                };
                let v: serde_json::Value = serde_json::from_str(&text).unwrap();
                assert_eq!(v["schema"], STATUS_SCHEMA);
                seen_updates.insert(v["eye"]["updates"].as_u64().unwrap());
                received += 1;
            }
        }
        let stats = server.stats();
        let rss_after = rss_kib();
        eprintln!(
            "ws stats after {:?}: {stats:?}; received by the reader: {received} ({} distinct values); RSS {rss_before:?} → {rss_after:?} KiB",
            start.elapsed(),
            seen_updates.len()
        );
        assert_eq!(stats.ws_dropped_slow, 1, "the stalled client is dropped");
        assert_eq!(stats.ws_clients, 1, "the reading client stays");
        assert!(stats.ws_in_flight_max <= 2, "one send per client at most");
        assert!(received > 100, "the reader keeps receiving ({received})");
        assert!(seen_updates.len() > 50, "with changing values");
        if let (Some(a), Some(b)) = (rss_before, rss_after) {
            assert!(b < a + 32 * 1024, "RSS grew from {a} to {b} KiB");
        }
        drop(stalled);
        hub.request_shutdown();
        tokio::time::timeout(Duration::from_secs(3), server.join())
            .await
            .expect("the server stops on shutdown");
    }
}

/// The page in headless Chromium (Debian's `chromium`) against a hub fed
/// like a session: the page loads, its values change between two loads,
/// it reports no script errors; a screenshot renders.
#[cfg(test)]
mod browser_tests {
    use super::*;
    use gazelight_test_support::chromium::{self, dump_with_updates, page_state};
    use gazelight_tracker::EyeState;
    use gazelight_tracker::LiveEyeState;

    #[tokio::test(flavor = "multi_thread", worker_threads = 2)]
    async fn page_loads_updates_and_has_no_errors_in_headless_chromium() {
        let (tx, rx) = watch::channel(LiveEyeState::default());
        let hub = Hub::new("pupil://127.0.0.1:50020", rx);
        // A real glare kernel (001 §4.2) for the PSF image.
        let kernel = tokio::task::spawn_blocking(|| {
            gazelight_vision::psf::build_kernel(&gazelight_vision::psf::PsfParams {
                pupil_mm: 5.0,
                ..Default::default()
            })
        })
        .await
        .unwrap()
        .unwrap();
        let lum: Vec<f32> = kernel
            .rgb
            .iter()
            .map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2])
            .collect();
        hub.publish_psf(1, kernel.pupil_mm, kernel.size, &lum);
        let server = spawn(hub.clone(), "127.0.0.1:0".parse().unwrap())
            .await
            .unwrap();
        let url = format!("http://{}/", server.local_addr());

        // A session at 90 Hz: the pupil constricts after a light step and
        // the adaptation luminance follows it.
        let feeder_hub = hub.clone();
        let feeder = tokio::spawn(async move {
            let (w, h) = (320usize, 180usize);
            let mut rgba = vec![0u8; w * h * 4];
            let mut tick = tokio::time::interval(Duration::from_millis(11));
            for k in 1u64.. {
                tick.tick().await;
                if feeder_hub.shutting_down() {
                    break;
                }
                let t = k as f64 / 90.0;
                let step = (-(t - 0.5).max(0.0) / 1.5).exp();
                let pupil = [3.0 + 3.0 * step as f32, 3.1 + 3.0 * step as f32];
                let adaptation = 10f64.powf(2.0 - 2.0 * step);
                let mut state = EyeState {
                    t_secs: host_now_secs(),
                    gaze_uv: [0.5 + 0.2 * (t.sin() as f32), 0.5],
                    gaze_valid: true,
                    ..EyeState::default()
                };
                for (e, ch) in state.eyes.iter_mut().enumerate() {
                    ch.pupil_mm = pupil[e];
                    ch.measured = Some(pupil[e]);
                    ch.measured_unit = Some(PupilUnit::Mm);
                    ch.present = true;
                    ch.pupil_origin = PupilOrigin::Measured;
                    ch.confidence = 0.95;
                }
                tx.send_replace(LiveEyeState {
                    state,
                    updated_host_secs: state.t_secs,
                    updates: k,
                });
                feeder_hub.update_source(|s| {
                    s.health = gazelight_tracker::live::SourceHealth::Live;
                    s.sample_rate_hz = 600.0;
                    s.confidence = 0.95;
                    s.samples_total = k * 7;
                });
                feeder_hub.publish_frame(FrameStatus {
                    frames: k,
                    t_secs: t,
                    pupil_mm: pupil,
                    frame_pupil_mm: 0.5 * (pupil[0] + pupil[1]),
                    adaptation_cd_m2: adaptation,
                    target_cd_m2: 100.0,
                    eye_state_age_ms: 1.2,
                    frame_ms: 7.5,
                    psf_rebuilds: 1,
                    ..FrameStatus::default()
                });
                for (i, px) in rgba.chunks_exact_mut(4).enumerate() {
                    let (x, y) = (i % w, i / w);
                    let v = ((x + k as usize) % w * 255 / w) as u8;
                    px.copy_from_slice(&[v, (y * 255 / h) as u8, 255 - v, 255]);
                }
                feeder_hub.publish_display(k, w, h, &rgba);
            }
        });

        // Virtual time runs out as soon as the page is idle, so on a loaded
        // machine (a cold Chromium start beside a build) it can end before
        // the socket's first real-time message: up to 4 loads, the first
        // with an update kept.
        let dump = |url: String| tokio::task::spawn_blocking(move || dump_with_updates(&url));
        let first = dump(url.clone()).await.unwrap();
        tokio::time::sleep(Duration::from_millis(500)).await;
        let second = dump(url.clone()).await.unwrap();
        let (u1, e1, s1, err1) = page_state(&first);
        let (u2, e2, s2, err2) = page_state(&second);
        // The mirrored #state as JSON (null before the first update).
        let state_json = |text: &str| -> serde_json::Value {
            if text.is_empty() {
                serde_json::Value::Null
            } else {
                serde_json::from_str(text).unwrap()
            }
        };
        let (s1, s2) = (state_json(&s1), state_json(&s2));
        eprintln!("first load: {u1} updates {s1}; second: {u2} updates {s2}");
        assert_eq!((e1, e2), (0, 0), "script errors: {err1} {err2}");
        assert!(err1.trim().is_empty() && err2.trim().is_empty());
        assert!(u1 >= 1 && u2 >= 1, "the page got WebSocket updates");
        let f1 = s1["frames"].as_u64().unwrap();
        let f2 = s2["frames"].as_u64().unwrap();
        assert!(f2 > f1, "frames move: {f1} → {f2}");
        assert_ne!(s1["adaptation_cd_m2"], s2["adaptation_cd_m2"]);
        assert_ne!(s1["pupil_mm"], s2["pupil_mm"]);
        assert_eq!(s2["health"], "live");
        assert_eq!(s2["psf_rebuild"], 1);

        // (docs/status_page.png comes from a live session: tests/status_page.rs.)
        let shot =
            std::env::temp_dir().join(format!("gazelight-status-{}.png", std::process::id()));
        let shot_arg = format!("--screenshot={}", shot.display());
        let u = url.clone();
        tokio::task::spawn_blocking(move || {
            chromium::run(&[
                "--virtual-time-budget=4000".into(),
                "--window-size=1280,820".into(),
                shot_arg,
                u,
            ])
        })
        .await
        .unwrap();
        let img = image::open(&shot).expect("the screenshot");
        assert_eq!((img.width(), img.height()), (1280, 820));
        let _ = std::fs::remove_file(&shot);

        hub.request_shutdown();
        let _ = feeder.await;
        server.join().await;
    }
}
