#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Pupil Core message decoding throughput and socket-to-sample latency.
//!
//! 1. `decode/*`: decoding realistic msgpack datums as Pupil Capture v3
//!    publishes them (a 2D pupil datum, a pye3d 3D datum with every field,
//!    a binocular 3D gaze datum carrying two 3D base datums) into samples,
//!    one core. Throughput is reported in elements (= samples) per second.
//! 2. `latency`: a Pupil-Remote-like REP + PUB pair in this process
//!    (zeromq over 127.0.0.1 TCP) publishes 2D pupil datums at 1 kHz, each
//!    stamped with the host clock at send; the [`PupilClient`] decodes and
//!    delivers them; the time from send to the sample coming out of the
//!    client's channel is collected and its p50/p99/max printed.

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, Throughput};
use gazelight_eye::clock::host_now_secs;
use gazelight_eye::filter::FilterChain;
use gazelight_pupil::msg::decode;
use gazelight_pupil::{PupilClient, PupilConfig};
use rmpv::Value as V;
use std::io::{Read, Write};
use std::net::TcpListener;

use zeromq::{RepSocket, Socket, SocketRecv, SocketSend, ZmqMessage};

fn arr(v: &[f64]) -> V {
    V::Array(v.iter().map(|x| V::from(*x)).collect())
}

fn map(e: Vec<(&str, V)>) -> V {
    V::Map(e.into_iter().map(|(k, v)| (V::from(k), v)).collect())
}

fn pupil_2d(eye: u8, t: f64) -> V {
    map(vec![
        ("topic", V::from(format!("pupil.{eye}.2d"))),
        ("id", V::from(eye)),
        ("method", V::from("2d c++")),
        ("timestamp", V::from(t)),
        ("confidence", V::from(0.9731)),
        ("diameter", V::from(38.412)),
        ("norm_pos", arr(&[0.4513, 0.5277])),
        (
            "ellipse",
            map(vec![
                ("center", arr(&[86.65, 90.67])),
                ("axes", arr(&[34.21, 38.41])),
                ("angle", V::from(-21.7)),
            ]),
        ),
    ])
}

fn pupil_3d(eye: u8, t: f64) -> V {
    let V::Map(mut m) = pupil_2d(eye, t) else {
        unreachable!()
    };
    m[0].1 = V::from(format!("pupil.{eye}.3d"));
    m[2].1 = V::from("pye3d 0.3.0 real-time");
    let extra = map(vec![
        (
            "sphere",
            map(vec![
                ("center", arr(&[1.2, 0.7, 41.3])),
                ("radius", V::from(10.39)),
            ]),
        ),
        (
            "projected_sphere",
            map(vec![
                ("center", arr(&[99.1, 94.2])),
                ("axes", arr(&[121.3, 121.3])),
                ("angle", V::from(0.0)),
            ]),
        ),
        (
            "circle_3d",
            map(vec![
                ("center", arr(&[1.52, -0.48, 31.02])),
                ("normal", arr(&[0.051, -0.102, -0.993])),
                ("radius", V::from(1.93)),
            ]),
        ),
        ("diameter_3d", V::from(3.86)),
        ("location", arr(&[86.65, 90.67])),
        ("model_confidence", V::from(1.0)),
        ("model_id", V::from(3)),
        ("theta", V::from(1.673)),
        ("phi", V::from(-1.518)),
    ]);
    let V::Map(e) = extra else { unreachable!() };
    m.extend(e);
    V::Map(m)
}

fn gaze_3d(t: f64) -> V {
    map(vec![
        ("topic", V::from("gaze.3d.01.")),
        (
            "eye_centers_3d",
            V::Map(vec![
                (V::from(0), arr(&[20.1, 15.2, -20.3])),
                (V::from(1), arr(&[-40.2, 15.1, -20.5])),
            ]),
        ),
        (
            "gaze_normals_3d",
            V::Map(vec![
                (V::from(0), arr(&[-0.1, 0.05, 0.99])),
                (V::from(1), arr(&[0.02, 0.05, 0.99])),
            ]),
        ),
        ("gaze_point_3d", arr(&[12.3, -40.1, 497.0])),
        ("confidence", V::from(0.95)),
        ("timestamp", V::from(t)),
        ("base_data", V::Array(vec![pupil_3d(0, t), pupil_3d(1, t)])),
        ("norm_pos", arr(&[0.512, 0.433])),
    ])
}

fn enc(v: &V) -> Vec<u8> {
    let mut b = Vec::new();
    rmpv::encode::write_value(&mut b, v).expect("encode");
    b
}

fn decode_benches(c: &mut Criterion) {
    let cases = [
        ("pupil_2d", "pupil.0.2d", enc(&pupil_2d(0, 12345.678))),
        ("pupil_3d", "pupil.1.3d", enc(&pupil_3d(1, 12345.678))),
        ("gaze_3d_binocular", "gaze.3d.01.", enc(&gaze_3d(12345.678))),
    ];
    let mut g = c.benchmark_group("decode");
    g.throughput(Throughput::Elements(1));
    for (name, topic, bytes) in &cases {
        eprintln!("{name}: {} bytes", bytes.len());
        g.bench_function(*name, |b| {
            b.iter(|| decode(black_box(topic), black_box(bytes)).expect("decodes"))
        });
    }
    g.finish();
}

/// A ZMTP 3.0 PUB peer written on blocking std TCP, run on its own OS
/// thread like a separate Pupil Capture process would be: it accepts one
/// subscriber, does the NULL-mechanism handshake, then sends `n` messages
/// `[topic, datum]` at 1 kHz, stamping each datum's `timestamp` with
/// the host clock immediately before the `write`. (The zeromq crate's own
/// PUB socket hands every message to a fan-out task first, which would add
/// the publisher's task wake-ups to the measured path.)
fn raw_zmtp_publisher(listener: TcpListener, n: usize) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let (mut s, _) = listener.accept().expect("subscriber connects");
        s.set_nodelay(true).expect("nodelay");
        let mut greeting = [0u8; 64];
        greeting[0] = 0xff;
        greeting[9] = 0x7f;
        greeting[10] = 3; // version 3.0
        greeting[12..16].copy_from_slice(b"NULL");
        s.write_all(&greeting).expect("greeting");
        let mut peer = [0u8; 64];
        s.read_exact(&mut peer).expect("peer greeting");
        // READY with Socket-Type = PUB.
        let mut body = vec![5u8];
        body.extend_from_slice(b"READY");
        body.push(11);
        body.extend_from_slice(b"Socket-Type");
        body.extend_from_slice(&3u32.to_be_bytes());
        body.extend_from_slice(b"PUB");
        let mut cmd = vec![0x04, body.len() as u8];
        cmd.extend_from_slice(&body);
        s.write_all(&cmd).expect("READY");
        // The subscriber's READY command (short or long).
        let mut hdr = [0u8; 2];
        s.read_exact(&mut hdr).expect("peer READY");
        let len = if hdr[0] & 0x02 != 0 {
            let mut rest = [0u8; 7];
            s.read_exact(&mut rest).expect("peer READY size");
            let mut b = [0u8; 8];
            b[0] = hdr[1];
            b[1..].copy_from_slice(&rest);
            u64::from_be_bytes(b) as usize
        } else {
            hdr[1] as usize
        };
        let mut skip = vec![0u8; len];
        s.read_exact(&mut skip).expect("peer READY body");
        // Subscriptions arrive next; they are not needed (only subscribed
        // topics are sent) and stay in the socket buffer.
        std::thread::sleep(Duration::from_millis(200));
        let (datum, slot) = datum_with_time_slot();
        let topic = b"pupil.0.2d";
        let mut frame = vec![0x01, topic.len() as u8];
        frame.extend_from_slice(topic);
        assert!(datum.len() < 256);
        frame.extend_from_slice(&[0x00, datum.len() as u8]);
        let slot = frame.len() + slot;
        frame.extend_from_slice(&datum);
        let start = std::time::Instant::now();
        for i in 0..n {
            let due = start + Duration::from_micros(1000 * i as u64);
            let now = std::time::Instant::now();
            if due > now {
                std::thread::sleep(due - now);
            }
            frame[slot..slot + 8].copy_from_slice(&host_now_secs().to_be_bytes());
            if s.write_all(&frame).is_err() {
                return;
            }
        }
        // Keep the connection until the consumer is done.
        std::thread::sleep(Duration::from_millis(500));
    })
}

/// Runtime flavours the latency is measured on.
#[derive(Clone, Copy, Debug)]
enum Flavor {
    /// Multi-thread runtime, 2 workers: the client task and the consumer
    /// task may run on different threads (cross-thread wake-ups).
    MultiThread,
    /// Current-thread runtime: every task on the bench thread.
    CurrentThread,
}

/// Encodes a 2D datum once and returns it with the byte offset of its
/// `timestamp` float64, so the send time can be patched in just before
/// each send (no encoding between the time stamp and the send).
fn datum_with_time_slot() -> (Vec<u8>, usize) {
    let sentinel = 1234.5678125f64;
    let bytes = enc(&pupil_2d(0, sentinel));
    let mut pat = vec![0xcb];
    pat.extend_from_slice(&sentinel.to_be_bytes());
    let at = bytes
        .windows(9)
        .position(|w| w == pat.as_slice())
        .expect("timestamp float64 in the datum")
        + 1;
    (bytes, at)
}

/// A minimal Pupil Remote (REP, the zeromq crate) + bus (a raw ZMTP PUB
/// thread, [`raw_zmtp_publisher`]) in this process publishing 2D datums at
/// 1 kHz, each stamped with the host clock just before the send (offset
/// ≈ 0); a consumer task feeds every sample out of the client's
/// channel into a [`FilterChain`] and takes the time after the chain has
/// updated the [`gazelight_eye::EyeState`]. Returns the latencies
/// (s), the number sent and the clock offset the client used.
async fn latency_run(n: usize) -> (Vec<f64>, Vec<f64>, usize) {
    let mut rep = RepSocket::new();
    let rep_ep = rep.bind("tcp://127.0.0.1:0").await.expect("bind REP");
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind bus");
    let pub_port = listener.local_addr().expect("bus address").port();
    let rep_port = match &rep_ep {
        zeromq::Endpoint::Tcp(_, p) => *p,
        other => panic!("{other:?}"),
    };
    let publisher = raw_zmtp_publisher(listener, n);
    let remote = tokio::spawn(async move {
        loop {
            let Ok(m) = rep.recv().await else { return };
            let cmd = String::from_utf8_lossy(m.get(0).expect("frame")).into_owned();
            let reply = match cmd.as_str() {
                "SUB_PORT" => pub_port.to_string(),
                "v" => "bench".to_owned(),
                "t" => format!("{}", host_now_secs()),
                _ => "Message forwarded.".to_owned(),
            };
            if rep.send(ZmqMessage::from(reply)).await.is_err() {
                return;
            }
        }
    });
    let config = PupilConfig {
        remote_port: rep_port,
        channel_capacity: 2 * n,
        // One clock estimate for the whole run (at connection).
        clock_interval: Duration::from_secs(3600),
        idle_timeout: Duration::from_secs(3600),
        ..PupilConfig::default()
    };
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5 + n as u64 / 1000);
    let (client, receiver) = {
        // The client task decodes; a consumer task filters (as the live
        // eye task of gazelight-tracker does).
        let (client, streams) = PupilClient::spawn(config);
        client
            .wait_connected(Duration::from_secs(5))
            .await
            .expect("client connects");
        let offset = client.stats().clock.expect("clock estimate").offset_secs;
        let mut samples = streams.samples;
        let receiver = tokio::spawn(async move {
            let mut chain = FilterChain::with_defaults();
            let mut latencies = Vec::with_capacity(n);
            while latencies.len() < n {
                match tokio::time::timeout_at(deadline, samples.recv()).await {
                    Ok(Some(s)) => {
                        let state = chain.push(&s).state;
                        latencies.push(host_now_secs() - (state.t_secs + offset));
                    }
                    _ => break,
                }
            }
            (latencies, Vec::new())
        });
        (client, receiver)
    };
    let (updated, observed) = receiver.await.expect("receiver task");
    let _ = tokio::task::spawn_blocking(move || publisher.join()).await;
    client.shutdown().await;
    remote.abort();
    (updated, observed, n)
}

/// The floor of the machine: the same publisher thread and loopback TCP,
/// read by a plain blocking thread (no ZeroMQ library, no async runtime,
/// no decoding): what the kernel and the (virtual) CPU's wake-up cost
/// alone.
fn latency_floor(n: usize) -> Vec<f64> {
    let listener = TcpListener::bind("127.0.0.1:0").expect("bind");
    let addr = listener.local_addr().expect("address");
    let publisher = raw_zmtp_publisher(listener, n);
    let mut s = std::net::TcpStream::connect(addr).expect("connect");
    s.set_nodelay(true).expect("nodelay");
    let mut greeting = [0u8; 64];
    greeting[0] = 0xff;
    greeting[9] = 0x7f;
    greeting[10] = 3;
    greeting[12..16].copy_from_slice(b"NULL");
    s.write_all(&greeting).expect("greeting");
    let mut peer = [0u8; 64];
    s.read_exact(&mut peer).expect("peer greeting");
    let mut body = vec![5u8];
    body.extend_from_slice(b"READY");
    body.push(11);
    body.extend_from_slice(b"Socket-Type");
    body.extend_from_slice(&3u32.to_be_bytes());
    body.extend_from_slice(b"SUB");
    let mut cmd = vec![0x04, body.len() as u8];
    cmd.extend_from_slice(&body);
    s.write_all(&cmd).expect("READY");
    let mut hdr = [0u8; 2];
    s.read_exact(&mut hdr).expect("peer READY");
    let mut skip = vec![0u8; hdr[1] as usize];
    s.read_exact(&mut skip).expect("peer READY body");
    let (datum, slot) = datum_with_time_slot();
    let frame_len = 2 + 10 + 2 + datum.len();
    let slot = 2 + 10 + 2 + slot;
    let mut frame = vec![0u8; frame_len];
    let mut l = Vec::with_capacity(n);
    for _ in 0..n {
        if s.read_exact(&mut frame).is_err() {
            break;
        }
        let now = host_now_secs();
        let mut b = [0u8; 8];
        b.copy_from_slice(&frame[slot..slot + 8]);
        l.push(now - f64::from_be_bytes(b));
    }
    let _ = publisher.join();
    l
}

fn percentiles(l: &mut [f64]) -> String {
    l.sort_by(f64::total_cmp);
    let q = |p: f64| l[((l.len() - 1) as f64 * p).round() as usize] * 1e6;
    format!(
        "p50 {:.1} us, p99 {:.1} us, max {:.1} us",
        q(0.5),
        q(0.99),
        l[l.len() - 1] * 1e6
    )
}

fn latency_bench(flavor: Flavor) {
    let rt = match flavor {
        Flavor::MultiThread => tokio::runtime::Builder::new_multi_thread()
            .worker_threads(2)
            .enable_all()
            .build(),
        Flavor::CurrentThread => tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build(),
    }
    .expect("runtime");
    let n = 3000;
    let (mut updated, mut observed, sent) = rt.block_on(latency_run(n));
    if updated.is_empty() {
        println!("latency ({flavor:?}): no samples delivered");
        return;
    }
    let mode = "client task -> channel -> consumer task with the filter";
    println!(
        "latency {flavor:?}, {mode}: socket send -> EyeState updated, 1 kHz, {} of {sent} measured: {}",
        updated.len(),
        percentiles(&mut updated)
    );
    if !observed.is_empty() {
        println!(
            "    ... -> observed by a task waiting on the watch ({} of {sent}): {}",
            observed.len(),
            percentiles(&mut observed)
        );
    }
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    decode_benches(&mut c);
    c.final_summary();
    let mut floor = latency_floor(3000);
    println!(
        "latency floor (same publisher, blocking std thread read, no zmq/tokio/decode), {} of 3000: {}",
        floor.len(),
        percentiles(&mut floor)
    );
    latency_bench(Flavor::MultiThread);
    latency_bench(Flavor::CurrentThread);
}
