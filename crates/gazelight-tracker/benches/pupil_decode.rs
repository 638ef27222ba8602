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
use gazelight_tracker::pupil::clock::host_now_secs;
use gazelight_tracker::pupil::msg::decode;
use gazelight_tracker::pupil::{PupilClient, PupilConfig};
use rmpv::Value as V;
use zeromq::{PubSocket, RepSocket, Socket, SocketRecv, SocketSend, ZmqMessage};

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

/// A minimal Pupil Remote (REP) + bus (PUB) publishing 2D datums at 1 kHz
/// stamped with host time (offset 0); returns the send→delivery latencies.
async fn latency_run(n: usize) -> Vec<f64> {
    let mut rep = RepSocket::new();
    let rep_ep = rep.bind("tcp://127.0.0.1:0").await.expect("bind REP");
    let mut publ = PubSocket::new();
    let pub_ep = publ.bind("tcp://127.0.0.1:0").await.expect("bind PUB");
    let port = |ep: &zeromq::Endpoint| match ep {
        zeromq::Endpoint::Tcp(_, p) => *p,
        other => panic!("{other:?}"),
    };
    let (rep_port, pub_port) = (port(&rep_ep), port(&pub_ep));
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
        ..PupilConfig::default()
    };
    let (client, streams) = PupilClient::spawn(config);
    client
        .wait_connected(Duration::from_secs(5))
        .await
        .expect("client connects");
    // Let the subscription reach the publisher.
    tokio::time::sleep(Duration::from_millis(200)).await;
    let mut template = match pupil_2d(0, 0.0) {
        V::Map(m) => m,
        _ => unreachable!(),
    };
    let mut samples = streams.samples;
    let receiver = tokio::spawn(async move {
        let mut latencies = Vec::with_capacity(n);
        let deadline = tokio::time::Instant::now() + Duration::from_secs(10);
        while latencies.len() < n {
            match tokio::time::timeout_at(deadline, samples.recv()).await {
                Ok(Some(s)) => latencies.push(host_now_secs() - s.t_secs()),
                _ => break,
            }
        }
        latencies
    });
    let mut tick = tokio::time::interval(Duration::from_millis(1));
    for _ in 0..n {
        tick.tick().await;
        template[3].1 = V::from(host_now_secs());
        let mut m = ZmqMessage::from("pupil.0.2d");
        m.push_back(enc(&V::Map(template.clone())).into());
        publ.send(m).await.expect("publish");
    }
    let latencies = receiver.await.expect("receiver task");
    client.shutdown().await;
    remote.abort();
    latencies
}

fn latency_bench() {
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .expect("runtime");
    let n = 3000;
    let mut l = rt.block_on(latency_run(n));
    if l.is_empty() {
        eprintln!("latency: no samples delivered");
        return;
    }
    l.sort_by(f64::total_cmp);
    let q = |p: f64| l[((l.len() - 1) as f64 * p).round() as usize] * 1e6;
    println!(
        "latency (PUB send -> sample out of the client channel, 1 kHz, {} of {n} delivered): p50 {:.1} us, p99 {:.1} us, max {:.1} us",
        l.len(),
        q(0.5),
        q(0.99),
        l[l.len() - 1] * 1e6
    );
}

fn main() {
    let mut c = Criterion::default().configure_from_args();
    decode_benches(&mut c);
    c.final_summary();
    latency_bench();
}
