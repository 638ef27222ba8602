#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Hostile ZMTP peers, written byte by byte (ZMTP 3.0, RFC 23: 64-byte
//! greeting, NULL mechanism, READY command), against the relay's three
//! sockets and the `pupil://` client:
//!
//! - a long frame header announcing 2^62 or 2^40 bytes (the unpatched
//!   `zeromq` 0.7.0 reserves the announced length and the process aborts);
//! - a multipart message that never ends, 1-byte "more" frames (the
//!   unpatched crate buffers all of them: hundreds of MB for tens of MB
//!   sent).
//!
//! Each attack must end with the offending peer disconnected, the reason
//! counted, the session still serving, and the process's resident memory
//! (VmRSS, sampled every 2 ms during the attack) less than
//! [`RSS_BOUND_BYTES`] above where it started.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use bytes::Bytes;
use gazelight_eye::LiveEyeState;
use gazelight_eye::clock::host_now_secs;
use gazelight_eye::{DetectorMethod, PupilSample, PupilUnit, Sample};
use gazelight_pupil::msg;
use gazelight_pupil::relay::{self, FrameFigures, RelayFeed, RelayHandle};
use gazelight_pupil::{PupilClient, PupilConfig};
use tokio::sync::{broadcast, watch};
use zeromq::{PubSocket, ReqSocket, Socket, SocketRecv, SocketSend, SubSocket, ZmqMessage};

/// Growth of the resident set allowed during one attack: the read chunk
/// and frame headers of one peer are kilobytes; the unpatched crate grows
/// by hundreds of MB on the multipart attack and aborts on the headers.
const RSS_BOUND_BYTES: u64 = 32 << 20;
/// Bytes of 1-byte "more" frames the multipart attack sends at most (3
/// bytes each on the wire: 16 M frames).
const MULTIPART_ATTACK_BYTES: usize = 48 << 20;

/// One attack at a time: the resident set is the process's.
static SERIAL: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

fn vm_rss_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let line = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .expect("VmRSS in /proc/self/status");
    let kib: u64 = line
        .split_whitespace()
        .nth(1)
        .and_then(|v| v.parse().ok())
        .unwrap();
    kib * 1024
}

/// Samples VmRSS every 2 ms until dropped; `peak()` is the highest seen.
struct RssWatch {
    start: u64,
    peak: Arc<AtomicU64>,
    stop: Arc<AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl RssWatch {
    fn start() -> Self {
        let start = vm_rss_bytes();
        let peak = Arc::new(AtomicU64::new(start));
        let stop = Arc::new(AtomicBool::new(false));
        let (p, s) = (peak.clone(), stop.clone());
        let thread = std::thread::spawn(move || {
            while !s.load(Ordering::Relaxed) {
                p.fetch_max(vm_rss_bytes(), Ordering::Relaxed);
                std::thread::sleep(Duration::from_millis(2));
            }
        });
        Self {
            start,
            peak,
            stop,
            thread: Some(thread),
        }
    }

    /// Stops sampling; the growth of the peak over the start, bytes.
    fn finish(mut self) -> u64 {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            t.join().unwrap();
        }
        self.peak
            .load(Ordering::Relaxed)
            .max(vm_rss_bytes())
            .saturating_sub(self.start)
    }
}

/// ZMTP 3.0 by hand.
mod zmtp {
    use super::*;

    /// The 64-byte greeting: signature, version 3.0, mechanism NULL.
    pub fn greeting() -> [u8; 64] {
        let mut g = [0u8; 64];
        g[0] = 0xff;
        g[9] = 0x7f;
        g[10] = 3;
        g[11] = 0;
        g[12..16].copy_from_slice(b"NULL");
        g
    }

    /// A READY command frame with the socket type.
    pub fn ready(socket_type: &str) -> Vec<u8> {
        let mut body = vec![5u8];
        body.extend_from_slice(b"READY");
        body.push(11);
        body.extend_from_slice(b"Socket-Type");
        body.extend_from_slice(&(socket_type.len() as u32).to_be_bytes());
        body.extend_from_slice(socket_type.as_bytes());
        let mut f = vec![0x04, body.len() as u8];
        f.extend_from_slice(&body);
        f
    }

    /// One frame with its header (short or long form).
    pub fn frame(more: bool, body: &[u8]) -> Vec<u8> {
        let more_bit = u8::from(more);
        let mut f = Vec::with_capacity(body.len() + 9);
        if body.len() > 255 {
            f.push(0x02 | more_bit);
            f.extend_from_slice(&(body.len() as u64).to_be_bytes());
        } else {
            f.push(more_bit);
            f.push(body.len() as u8);
        }
        f.extend_from_slice(body);
        f
    }

    /// A long frame header announcing `len` bytes, with no body.
    pub fn long_header(len: u64) -> Vec<u8> {
        let mut f = vec![0x02];
        f.extend_from_slice(&len.to_be_bytes());
        f
    }

    /// Reads one frame: (flags, body).
    pub fn read_frame(s: &mut TcpStream) -> std::io::Result<(u8, Vec<u8>)> {
        let mut flags = [0u8; 1];
        s.read_exact(&mut flags)?;
        let len = if flags[0] & 0x02 != 0 {
            let mut l = [0u8; 8];
            s.read_exact(&mut l)?;
            u64::from_be_bytes(l)
        } else {
            let mut l = [0u8; 1];
            s.read_exact(&mut l)?;
            u64::from(l[0])
        };
        assert!(len < 1 << 20, "the peer under test sent a {len}-byte frame");
        let mut body = vec![0u8; len as usize];
        s.read_exact(&mut body)?;
        Ok((flags[0], body))
    }

    /// Reads one whole message (command frames skipped).
    pub fn read_message(s: &mut TcpStream) -> std::io::Result<Vec<Vec<u8>>> {
        let mut frames = Vec::new();
        loop {
            let (flags, body) = read_frame(s)?;
            if flags & 0x04 != 0 {
                continue;
            }
            frames.push(body);
            if flags & 0x01 == 0 {
                return Ok(frames);
            }
        }
    }

    /// Greeting and READY both ways, as a `socket_type` peer.
    pub fn handshake(s: &mut TcpStream, socket_type: &str) -> std::io::Result<()> {
        s.set_read_timeout(Some(Duration::from_secs(5)))?;
        s.set_write_timeout(Some(Duration::from_secs(5)))?;
        s.write_all(&greeting())?;
        let mut theirs = [0u8; 64];
        s.read_exact(&mut theirs)?;
        assert_eq!(theirs[0], 0xff, "a ZMTP greeting");
        assert_eq!(theirs[10], 3, "ZMTP 3");
        s.write_all(&ready(socket_type))?;
        let (flags, body) = read_frame(s)?;
        assert!(
            flags & 0x04 != 0 && body.get(1..6) == Some(b"READY"),
            "READY"
        );
        Ok(())
    }
}

#[derive(Clone, Copy, Debug)]
enum Attack {
    /// A long frame header announcing this many bytes.
    Header(u64),
    /// Endless 1-byte "more" frames.
    EndlessMultipart,
}

impl Attack {
    const ALL: [Attack; 3] = [
        Attack::Header(1 << 62),
        Attack::Header(1 << 40),
        Attack::EndlessMultipart,
    ];
}

/// What the attacker saw.
#[derive(Debug)]
struct Outcome {
    /// Bytes of the attack written before the peer closed.
    sent: usize,
    /// The peer closed the connection (EOF or reset) within the wait.
    closed: bool,
}

/// Runs `attack` on an established connection and waits (≤ 10 s) for the
/// peer to close it.
fn run_attack(s: &mut TcpStream, attack: Attack) -> Outcome {
    let mut sent = 0usize;
    let mut write_failed = false;
    match attack {
        Attack::Header(len) => {
            let h = zmtp::long_header(len);
            write_failed = s.write_all(&h).is_err();
            sent += h.len();
        }
        Attack::EndlessMultipart => {
            let chunk: Vec<u8> = std::iter::repeat_n([0x01u8, 0x01, b'x'], 64 << 10)
                .flatten()
                .collect();
            while sent < MULTIPART_ATTACK_BYTES {
                match s.write(&chunk) {
                    Ok(0) | Err(_) => {
                        write_failed = true;
                        break;
                    }
                    Ok(n) => sent += n,
                }
            }
        }
    }
    // Closed: a read ends (EOF) or fails with a reset; a timeout is not.
    s.set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let deadline = Instant::now() + Duration::from_secs(10);
    let mut buf = [0u8; 4096];
    let mut closed = write_failed;
    while !closed && Instant::now() < deadline {
        match s.read(&mut buf) {
            Ok(0) => closed = true,
            Ok(_) => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) => {}
            Err(_) => closed = true,
        }
    }
    Outcome { sent, closed }
}

// ---------------------------------------------------------------- relay

struct Hub {
    eye: watch::Receiver<LiveEyeState>,
    samples: broadcast::Sender<Sample>,
    shutdown: watch::Sender<bool>,
}

impl RelayFeed for Hub {
    fn eye(&self) -> watch::Receiver<LiveEyeState> {
        self.eye.clone()
    }
    fn subscribe_samples(&self) -> broadcast::Receiver<Sample> {
        self.samples.subscribe()
    }
    fn frame(&self) -> FrameFigures {
        FrameFigures::default()
    }
    fn shutdown_signal(&self) -> watch::Receiver<bool> {
        self.shutdown.subscribe()
    }
}

async fn start_relay() -> (Arc<Hub>, RelayHandle, watch::Sender<LiveEyeState>) {
    let (tx, eye) = watch::channel(LiveEyeState::default());
    let (shutdown, _) = watch::channel(false);
    let hub = Arc::new(Hub {
        eye,
        samples: broadcast::channel(16).0,
        shutdown,
    });
    let relay = relay::spawn(hub.clone(), "127.0.0.1:0".parse().unwrap())
        .await
        .unwrap();
    (hub, relay, tx)
}

/// The relay still serves: Remote forwards a notification, the bus
/// delivers it to a new subscriber, and a message published on PUB_PORT
/// reaches the bus too.
async fn relay_still_serves(relay: &RelayHandle) {
    let mut bus = SubSocket::new();
    bus.connect(&format!("tcp://127.0.0.1:{}", relay.sub_port()))
        .await
        .unwrap();
    bus.subscribe("notify.").await.unwrap();
    bus.subscribe("still.").await.unwrap();
    let mut req = ReqSocket::new();
    req.connect(&format!("tcp://{}", relay.local_addr()))
        .await
        .unwrap();
    let mut publisher = PubSocket::new();
    publisher
        .connect(&format!("tcp://127.0.0.1:{}", relay.pub_port()))
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_millis(200)).await;

    let (topic, payload) =
        msg::encode_notification("still.serving", &[("n", rmpv::Value::from(1))]).unwrap();
    let mut m = ZmqMessage::from(topic.clone());
    m.push_back(Bytes::from(payload));
    req.send(m).await.unwrap();
    let reply = tokio::time::timeout(Duration::from_secs(2), req.recv())
        .await
        .expect("Remote answers after the attack")
        .unwrap();
    assert_eq!(reply.get(0).unwrap().as_ref(), b"Message forwarded.");
    let got = tokio::time::timeout(Duration::from_secs(2), bus.recv())
        .await
        .expect("the bus delivers after the attack")
        .unwrap();
    assert_eq!(got.get(0).unwrap().as_ref(), topic.as_bytes());

    let mut m = ZmqMessage::from("still.pub_port");
    m.push_back(Bytes::from_static(b"\x80"));
    let deadline = Instant::now() + Duration::from_secs(3);
    loop {
        publisher.send(m.clone()).await.unwrap();
        if let Ok(Ok(got)) = tokio::time::timeout(Duration::from_millis(100), bus.recv()).await
            && got.get(0).unwrap().as_ref() == b"still.pub_port"
        {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "PUB_PORT input reaches the bus after the attack"
        );
    }
}

/// Runs every attack against one relay socket.
async fn attack_relay_socket(which: &str, port_of: fn(&RelayHandle) -> u16, claim: &str) {
    let _guard = SERIAL.lock().await;
    let (hub, relay, _eye) = start_relay().await;
    for (k, attack) in Attack::ALL.into_iter().enumerate() {
        let port = port_of(&relay);
        let claim = claim.to_owned();
        let rss = RssWatch::start();
        let outcome = tokio::task::spawn_blocking(move || {
            let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
            zmtp::handshake(&mut s, &claim).unwrap();
            run_attack(&mut s, attack)
        })
        .await
        .unwrap();
        let grew = rss.finish();
        eprintln!("relay {which}, {attack:?}: {outcome:?}, VmRSS peak +{grew} bytes");
        assert!(
            outcome.closed,
            "relay {which}, {attack:?}: the peer is disconnected"
        );
        if matches!(attack, Attack::EndlessMultipart) {
            assert!(
                outcome.sent < MULTIPART_ATTACK_BYTES,
                "relay {which}: dropped before {MULTIPART_ATTACK_BYTES} bytes, sent {}",
                outcome.sent
            );
        }
        assert!(
            grew < RSS_BOUND_BYTES,
            "relay {which}, {attack:?}: VmRSS grew {grew} bytes"
        );
        // Counted (the bus counts through its monitor, asynchronously).
        let deadline = Instant::now() + Duration::from_secs(2);
        while relay.stats().peers_dropped < k as u64 + 1 && Instant::now() < deadline {
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        assert_eq!(
            relay.stats().peers_dropped,
            k as u64 + 1,
            "relay {which}, {attack:?}: counted"
        );
        relay_still_serves(&relay).await;
    }
    hub.shutdown.send_replace(true);
    tokio::time::timeout(Duration::from_secs(3), relay.join())
        .await
        .expect("the relay stops on shutdown");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn relay_remote_drops_oversized_and_endless_requests() {
    attack_relay_socket("Pupil Remote (REP)", |r| r.local_addr().port(), "REQ").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn relay_pub_port_drops_oversized_and_endless_messages() {
    attack_relay_socket("PUB_PORT (SUB)", |r| r.pub_port(), "PUB").await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn relay_bus_drops_oversized_and_endless_subscriptions() {
    attack_relay_socket("bus (PUB)", |r| r.sub_port(), "SUB").await;
}

// ---------------------------------------------------------------- client

/// Which socket of the fake Capture misbehaves, and how.
#[derive(Clone, Copy, Debug)]
enum Target {
    Remote(Attack),
    Bus(Attack),
}

/// A Pupil Capture written by hand: Pupil Remote (REP) and the bus (PUB).
/// The first connection of the targeted socket gets the attack; the
/// others are served properly, and the bus publishes a valid `pupil.0.3d`
/// datum every 5 ms.
struct FakeCapture {
    remote_port: u16,
    /// Bytes of the attack written, and whether the client closed.
    outcome: Arc<Mutex<Option<Outcome>>>,
    stop: Arc<AtomicBool>,
}

impl FakeCapture {
    fn start(target: Target) -> Self {
        let remote = TcpListener::bind("127.0.0.1:0").unwrap();
        let bus = TcpListener::bind("127.0.0.1:0").unwrap();
        let remote_port = remote.local_addr().unwrap().port();
        let bus_port = bus.local_addr().unwrap().port();
        let outcome = Arc::new(Mutex::new(None));
        let stop = Arc::new(AtomicBool::new(false));
        remote.set_nonblocking(true).unwrap();
        bus.set_nonblocking(true).unwrap();
        {
            let (outcome, stop) = (outcome.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut first = true;
                while !stop.load(Ordering::Relaxed) {
                    let Ok((s, _)) = remote.accept() else {
                        std::thread::sleep(Duration::from_millis(5));
                        continue;
                    };
                    s.set_nonblocking(false).unwrap();
                    let attack = match target {
                        Target::Remote(a) if first => Some(a),
                        _ => None,
                    };
                    first = false;
                    let (outcome, stop) = (outcome.clone(), stop.clone());
                    std::thread::spawn(move || serve_remote(s, bus_port, attack, &outcome, &stop));
                }
            });
        }
        {
            let (outcome, stop) = (outcome.clone(), stop.clone());
            std::thread::spawn(move || {
                let mut first = true;
                while !stop.load(Ordering::Relaxed) {
                    let Ok((s, _)) = bus.accept() else {
                        std::thread::sleep(Duration::from_millis(5));
                        continue;
                    };
                    s.set_nonblocking(false).unwrap();
                    let attack = match target {
                        Target::Bus(a) if first => Some(a),
                        _ => None,
                    };
                    first = false;
                    let (outcome, stop) = (outcome.clone(), stop.clone());
                    std::thread::spawn(move || serve_bus(s, attack, &outcome, &stop));
                }
            });
        }
        Self {
            remote_port,
            outcome,
            stop,
        }
    }
}

impl Drop for FakeCapture {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
    }
}

fn serve_remote(
    mut s: TcpStream,
    bus_port: u16,
    attack: Option<Attack>,
    outcome: &Mutex<Option<Outcome>>,
    stop: &AtomicBool,
) {
    if zmtp::handshake(&mut s, "REP").is_err() {
        return;
    }
    let _ = s.set_read_timeout(Some(Duration::from_millis(500)));
    while !stop.load(Ordering::Relaxed) {
        let request = match zmtp::read_message(&mut s) {
            Ok(r) => r,
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                continue;
            }
            Err(_) => return,
        };
        if let Some(a) = attack {
            // The reply's envelope, then the attack in place of the text.
            let _ = s.write_all(&zmtp::frame(true, b""));
            let o = run_attack(&mut s, a);
            *outcome.lock().unwrap() = Some(o);
            return;
        }
        let command = request.last().cloned().unwrap_or_default();
        let text = match command.as_slice() {
            b"SUB_PORT" => bus_port.to_string(),
            b"PUB_PORT" => "1".to_owned(),
            b"v" => "3.5.0".to_owned(),
            b"t" => format!("{:?}", host_now_secs()),
            _ => "Unknown command.".to_owned(),
        };
        let mut reply = zmtp::frame(true, b"");
        reply.extend(zmtp::frame(false, text.as_bytes()));
        if s.write_all(&reply).is_err() {
            return;
        }
    }
}

fn serve_bus(
    mut s: TcpStream,
    attack: Option<Attack>,
    outcome: &Mutex<Option<Outcome>>,
    stop: &AtomicBool,
) {
    if zmtp::handshake(&mut s, "PUB").is_err() {
        return;
    }
    if let Some(a) = attack {
        let o = run_attack(&mut s, a);
        *outcome.lock().unwrap() = Some(o);
        return;
    }
    // Subscriptions are not read: a few bytes stay in the socket buffer.
    while !stop.load(Ordering::Relaxed) {
        let sample = Sample::Pupil(PupilSample {
            t_secs: host_now_secs(),
            eye: 0,
            diameter_raw: 3.5,
            unit: PupilUnit::Mm,
            diameter_mm: Some(3.5),
            confidence: 0.95,
            norm_pos: [0.5, 0.5],
            method: DetectorMethod::Pupil3d,
        });
        let (topic, payload) = msg::encode_sample(&sample).unwrap().unwrap();
        let mut m = zmtp::frame(true, topic.as_bytes());
        m.extend(zmtp::frame(false, &payload));
        if s.write_all(&m).is_err() {
            return;
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

async fn attack_client(target: Target) {
    let _guard = SERIAL.lock().await;
    let capture = FakeCapture::start(target);
    let rss = RssWatch::start();
    let (client, mut streams) = PupilClient::spawn(PupilConfig {
        remote_port: capture.remote_port,
        request_timeout: Duration::from_millis(500),
        connect_timeout: Duration::from_millis(500),
        backoff_initial: Duration::from_millis(50),
        backoff_max: Duration::from_millis(200),
        ..PupilConfig::default()
    });
    // The attacker's thread records its outcome once the client closed.
    let deadline = Instant::now() + Duration::from_secs(20);
    let outcome = loop {
        if let Some(o) = capture.outcome.lock().unwrap().take() {
            break o;
        }
        assert!(Instant::now() < deadline, "{target:?}: the attack ran");
        tokio::time::sleep(Duration::from_millis(10)).await;
    };
    let grew = rss.finish();
    let stats = client.stats();
    eprintln!(
        "client, {target:?}: {outcome:?}, VmRSS peak +{grew} bytes, last error {:?}",
        stats.last_error
    );
    assert!(
        outcome.closed,
        "{target:?}: the client closed the connection"
    );
    if matches!(
        target,
        Target::Remote(Attack::EndlessMultipart) | Target::Bus(Attack::EndlessMultipart)
    ) {
        assert!(
            outcome.sent < MULTIPART_ATTACK_BYTES,
            "{target:?}: {outcome:?}"
        );
    }
    assert!(
        grew < RSS_BOUND_BYTES,
        "{target:?}: VmRSS grew {grew} bytes"
    );
    assert_eq!(stats.too_large, 1, "{target:?}: counted");
    assert!(
        stats
            .last_error
            .as_deref()
            .is_some_and(|e| e.contains("limit")),
        "{target:?}: the reason is kept: {:?}",
        stats.last_error
    );
    // The session goes on: a reconnect, and a datum decoded from it.
    let sample = tokio::time::timeout(Duration::from_secs(10), streams.samples.recv())
        .await
        .expect("a sample after the attack")
        .expect("the client is running");
    assert!(matches!(sample, Sample::Pupil(p) if p.eye == 0 && p.diameter_raw == 3.5));
    assert!(client.stats().connected);
    client.shutdown().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn client_drops_capture_sending_oversized_or_endless_bus_messages() {
    for attack in Attack::ALL {
        attack_client(Target::Bus(attack)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn client_drops_capture_sending_oversized_or_endless_remote_replies() {
    for attack in Attack::ALL {
        attack_client(Target::Remote(attack)).await;
    }
}
