#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The Neon Real-time API client against `neon_peer.py`, a Neon-like peer
//! that serves the Neon demo recording (`eye/neon-demo` of
//! the shared test data, MIT, © Pupil Labs) over HTTP status + RTSP/TCP interleaved + RTP/RTCP.
//! The expected values are read here straight from the recording's files,
//! not from the code under test. 127.0.0.1 only; every wait is bounded.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use gazelight_eye::sample::{GazeEyes, Sample};
use gazelight_eye::source::{SampleSource, SourceError};
use gazelight_neon::http::{direct_sensor, get_status, parse_status};
use gazelight_neon::payload::decode_gaze;
use gazelight_neon::{NeonConfig, NeonError, NeonSource, RtpStream};
use gazelight_test_support::{data_dir, skip_or_fail, try_data_dir};

/// The recording: per record (unix ns, [x, y], 20 eye-state floats).
struct Recording {
    times_ns: Vec<u64>,
    gaze: Vec<[f32; 2]>,
    state: Vec<[f32; 20]>,
    /// (start, end) ns.
    blinks: Vec<(i64, i64)>,
}

fn read_recording() -> Recording {
    let d = data_dir().join("eye/neon-demo");
    let read = |n: &str| std::fs::read(d.join(n)).expect(n);
    let le32 = |b: &[u8], i: usize| f32::from_le_bytes([b[i], b[i + 1], b[i + 2], b[i + 3]]);
    let le64 = |b: &[u8], i: usize| {
        let mut a = [0u8; 8];
        a.copy_from_slice(&b[i..i + 8]);
        a
    };
    let t = read("eye_state ps1.time");
    let g = read("gaze ps1.raw");
    let s = read("eye_state ps1.raw");
    let b = read("blinks ps1.raw");
    let n = t.len() / 8;
    Recording {
        times_ns: (0..n)
            .map(|i| u64::from_le_bytes(le64(&t, 8 * i)))
            .collect(),
        gaze: (0..n)
            .map(|i| [le32(&g, 8 * i), le32(&g, 8 * i + 4)])
            .collect(),
        state: (0..n)
            .map(|i| std::array::from_fn(|k| le32(&s, 80 * i + 4 * k)))
            .collect(),
        blinks: (0..b.len() / 20)
            .map(|i| {
                (
                    i64::from_le_bytes(le64(&b, 20 * i + 4)),
                    i64::from_le_bytes(le64(&b, 20 * i + 12)),
                )
            })
            .collect(),
    }
}

/// A running peer; killed (by its own pid) on drop.
struct Peer {
    child: Child,
    http_port: u16,
    start_unix_ns: u64,
}

impl Drop for Peer {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// Starts the peer, or `None` (SKIP) without python3 or the data outside CI.
fn peer(args: &[&str]) -> Option<Peer> {
    let python = Command::new("python3")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    let missing = match try_data_dir() {
        _ if !python => Some("python3".to_owned()),
        Err(e) => Some(e.to_string()),
        Ok(d) => {
            let raw = d.join("eye/neon-demo/eye_state ps1.raw");
            (!raw.exists()).then(|| format!("the Neon demo recording ({})", raw.display()))
        }
    };
    if let Some(what) = missing {
        skip_or_fail(&format!("missing {what}"));
        return None;
    }
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/neon_peer.py");
    let mut child = Command::new("python3")
        .arg(script)
        .arg("--data")
        .arg(data_dir())
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .expect("start neon_peer.py");
    let stdout = child.stdout.take().expect("stdout");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let mut line = String::new();
        let _ = BufReader::new(stdout).read_line(&mut line);
        let _ = tx.send(line);
    });
    let line = rx
        .recv_timeout(Duration::from_secs(20))
        .expect("peer READY within 20 s");
    let field = |k: &str| {
        line.split_whitespace()
            .find_map(|f| f.strip_prefix(k))
            .unwrap_or_else(|| panic!("no {k} in `{line}`"))
            .parse::<u64>()
            .expect("number")
    };
    let _ = child.stdin.as_mut().map(|s| s.flush());
    Some(Peer {
        http_port: field("http=") as u16,
        start_unix_ns: field("start_unix_ns="),
        child,
    })
}

async fn gaze_url(port: u16) -> String {
    let body = get_status("127.0.0.1", port, Duration::from_secs(3))
        .await
        .expect("status");
    let sensors = parse_status(&body).expect("sensors");
    direct_sensor(&sensors, "gaze")
        .and_then(|s| s.url())
        .expect("gaze url")
}

fn cfg(port: u16) -> NeonConfig {
    NeonConfig {
        host: "127.0.0.1".to_owned(),
        port,
        io_timeout: Duration::from_secs(2),
        gaze_timeout: Duration::from_millis(800),
        backoff_initial: Duration::from_millis(100),
        backoff_max: Duration::from_millis(400),
        ..NeonConfig::default()
    }
}

/// Every packet of the 89-byte stream decodes to the recording's values,
/// and its RTCP-anchored time equals the recording's `.time` within two RTP
/// ticks, across a 32-bit RTP timestamp wrap.
#[tokio::test]
async fn eye_state_values_and_rtcp_times_follow_the_recording_across_a_wrap() {
    let rec = read_recording();
    // 90 kHz clock starting 0.5 s before the 2^32 wrap; a sender report
    // every 400 packets (2 s), so the wrap falls between two reports.
    let Some(p) = peer(&[
        "--time",
        "recording",
        "--no-pace",
        "--loops",
        "1",
        "--layout",
        "89",
        "--clock",
        "90000",
        "--rtp-start",
        "0xFFFF5000",
        "--sr-every",
        "400",
    ]) else {
        return;
    };
    assert_eq!(p.start_unix_ns, rec.times_ns[0]);
    let url = gaze_url(p.http_port).await;
    assert!(url.contains("camera=gaze"), "{url}");
    let mut s = RtpStream::open(&url, Duration::from_secs(2), Duration::from_secs(2))
        .await
        .expect("play");
    assert_eq!(s.clock_rate_hz(), 90_000);
    assert_eq!(s.encoding(), Some("com.pupillabs.gaze1"));
    let tol_secs = 2.0 / 90_000.0;
    let mut wrapped = false;
    let mut last_ts = None;
    let mut worst = 0f64;
    for i in 0..rec.times_ns.len() {
        let pkt = tokio::time::timeout(Duration::from_secs(5), s.next_packet())
            .await
            .expect("packet in time")
            .expect("packet");
        if let Some(prev) = last_ts
            && pkt.rtp_timestamp < prev
        {
            wrapped = true;
        }
        last_ts = Some(pkt.rtp_timestamp);
        let want = rec.times_ns[i] as f64 * 1e-9;
        worst = worst.max((pkt.unix_secs - want).abs());
        assert!(
            (pkt.unix_secs - want).abs() < tol_secs,
            "record {i}: {} vs {want}",
            pkt.unix_secs
        );
        let d = decode_gaze(pkt.payload).expect("89-byte payload");
        assert_eq!(d.gaze_px, Some(rec.gaze[i]), "record {i}");
        assert!(d.worn());
        let es = d.eye_state.expect("eye state");
        let lids = d.eyelid.expect("eyelids");
        let st = &rec.state[i];
        assert_eq!(es[0].pupil_diameter_mm, st[0], "left pupil, record {i}");
        assert_eq!(es[0].eyeball_center_mm, [st[1], st[2], st[3]]);
        assert_eq!(es[0].optical_axis, [st[4], st[5], st[6]]);
        assert_eq!(es[1].pupil_diameter_mm, st[7], "right pupil, record {i}");
        assert_eq!(lids[0].aperture_mm, st[16], "left aperture, record {i}");
        assert_eq!(lids[1].aperture_mm, st[19], "right aperture, record {i}");
        assert_eq!(lids[1].angle_top_rad, st[17]);
    }
    assert!(wrapped, "the RTP timestamp should have wrapped");
    let c = s.counters();
    assert_eq!(c.before_first_report, 0);
    assert!(c.sender_reports >= 4, "{c:?}");
    eprintln!(
        "worst time error {:.2} µs over {} packets",
        worst * 1e6,
        rec.times_ns.len()
    );
}

/// Each layout decodes with the recording's gaze (and pupils where the
/// layout has them).
#[tokio::test]
async fn every_layout_decodes() {
    let rec = read_recording();
    for layout in ["9", "17", "25", "65", "89", "105"] {
        let Some(p) = peer(&["--no-pace", "--loops", "1", "--layout", layout]) else {
            return;
        };
        let url = gaze_url(p.http_port).await;
        let mut s = RtpStream::open(&url, Duration::from_secs(2), Duration::from_secs(2))
            .await
            .expect("play");
        for i in 0..50 {
            let pkt = s.next_packet().await.expect("packet");
            assert_eq!(pkt.payload.len().to_string(), layout);
            let d = decode_gaze(pkt.payload).expect("decode");
            match layout {
                "17" => assert_eq!(d.monocular_px, Some([rec.gaze[i], rec.gaze[i]])),
                _ => assert_eq!(d.gaze_px, Some(rec.gaze[i]), "layout {layout}"),
            }
            let pupils = d
                .eye_state
                .map(|e| [e[0].pupil_diameter_mm, e[1].pupil_diameter_mm]);
            match layout {
                "65" | "89" | "105" => {
                    assert_eq!(pupils, Some([rec.state[i][0], rec.state[i][7]]))
                }
                _ => assert_eq!(pupils, None),
            }
        }
    }
}

/// Malformed packets (a 7-byte gaze payload, a 3-byte RTP packet) are
/// errors naming what is wrong; the good packets between them all arrive.
#[tokio::test]
async fn malformed_packets_are_named_and_skipped() {
    let rec = read_recording();
    let Some(p) = peer(&["--no-pace", "--loops", "1", "--malformed-every", "100"]) else {
        return;
    };
    let url = gaze_url(p.http_port).await;
    let mut s = RtpStream::open(&url, Duration::from_secs(2), Duration::from_secs(2))
        .await
        .expect("play");
    let (mut good, mut short_rtp, mut bad_len) = (0usize, 0, 0);
    while good < rec.times_ns.len() {
        match tokio::time::timeout(Duration::from_secs(5), s.next_packet())
            .await
            .expect("in time")
        {
            Ok(pkt) => match decode_gaze(pkt.payload) {
                Ok(d) => {
                    assert_eq!(d.gaze_px, Some(rec.gaze[good]));
                    good += 1;
                }
                Err(e) => {
                    let m = e.to_string();
                    assert!(m.contains("gaze payload") && m.contains("7 bytes"), "{m}");
                    bad_len += 1;
                }
            },
            Err(e @ NeonError::Packet { .. }) => {
                let m = e.to_string();
                assert!(m.contains("RTP packet") && m.contains("3 bytes"), "{m}");
                short_rtp += 1;
            }
            Err(e) => panic!("stream lost: {e}"),
        }
    }
    assert_eq!(
        (bad_len, short_rtp),
        (17, 17),
        "1788 packets, one bad pair per 100"
    );
    assert_eq!(s.counters().malformed, 17);
}

/// Reads the source until `pred` holds or `secs` pass; returns what came.
async fn collect(
    src: &mut NeonSource,
    secs: f64,
    mut stop: impl FnMut(&[Result<Sample, String>]) -> bool,
) -> Vec<Result<Sample, String>> {
    let mut got = Vec::new();
    let deadline = tokio::time::Instant::now() + Duration::from_secs_f64(secs);
    while tokio::time::Instant::now() < deadline && !stop(&got) {
        match tokio::time::timeout_at(deadline, src.next()).await {
            Err(_) => break,
            Ok(Ok(Some(s))) => got.push(Ok(s)),
            Ok(Ok(None)) => break,
            Ok(Err(SourceError::Disconnected { reason, .. })) => {
                got.push(Err(format!("lost: {reason}")))
            }
            Ok(Err(SourceError::Item { error, .. })) => got.push(Err(format!("item: {error}"))),
            Ok(Err(SourceError::Fatal { reason, .. })) => panic!("fatal: {reason}"),
        }
    }
    got
}

fn pupils(got: &[Result<Sample, String>], eye: u8) -> Vec<f32> {
    got.iter()
        .filter_map(|r| match r {
            Ok(Sample::Pupil(p)) if p.eye == eye => p.diameter_mm,
            _ => None,
        })
        .collect()
}

/// The source delivers the recording's pupils in mm on the host clock;
/// when the peer drops the connection and refuses for a second, the
/// source reports the loss and is live again when the peer comes back.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn source_is_lost_then_live_again() {
    let rec = read_recording();
    let Some(p) = peer(&["--drop-after", "300", "--down-secs", "1"]) else {
        return;
    };
    let mut src = NeonSource::new(cfg(p.http_port));
    let got = collect(&mut src, 15.0, |g| {
        g.iter().any(|r| r.is_err()) && pupils(g, 1).len() >= 600
    })
    .await;
    let lost_at = got
        .iter()
        .position(|r| r.as_ref().is_err_and(|e| e.starts_with("lost")))
        .unwrap_or_else(|| panic!("no loss reported: {:?}", got.last()));
    let before = pupils(&got[..lost_at], 1);
    let after = pupils(&got[lost_at..], 1);
    // 300 packets before the drop: left pupils = the recording's first 300.
    let want: Vec<f32> = rec.state[..300].iter().map(|s| s[0]).collect();
    assert_eq!(before, want);
    assert!(after.len() >= 300, "{} pupils after the loss", after.len());
    // After the reconnect the peer plays from the start again.
    assert_eq!(after[..300], want[..]);
    let reasons: Vec<&String> = got.iter().filter_map(|r| r.as_ref().err()).collect();
    assert!(
        reasons[0].contains("closed") || reasons[0].contains("RTSP"),
        "{reasons:?}"
    );
    let stats = src.stats().snapshot();
    assert!(stats.connections >= 2 && stats.losses >= 1, "{stats:?}");
    assert!(stats.connected);
    // Host-clock times: the newest sample is recent (age < 1 s).
    let newest = got
        .iter()
        .rev()
        .find_map(|r| r.as_ref().ok().map(Sample::t_secs))
        .expect("a sample");
    let age = gazelight_eye::clock::host_now_secs() - newest;
    assert!((-0.5..1.0).contains(&age), "age {age}");
}

/// A peer that goes silent (the recording played once, then nothing) is
/// lost after the gaze timeout, with a message saying so.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn silent_peer_is_lost_with_a_timeout() {
    let Some(p) = peer(&["--no-pace", "--loops", "1", "--no-events"]) else {
        return;
    };
    let mut src = NeonSource::new(cfg(p.http_port));
    let got = collect(&mut src, 10.0, |g| g.iter().any(|r| r.is_err())).await;
    let e = got
        .iter()
        .find_map(|r| r.as_ref().err())
        .expect("a loss within 10 s");
    assert!(
        e.contains("RTP data from rtsp://127.0.0.1") && e.contains("nothing within 0.8 s"),
        "{e}"
    );
}

/// Nothing listening: a clear error naming the status URL.
#[tokio::test]
async fn refused_connection_names_the_status_url() {
    let port = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let mut src = NeonSource::new(cfg(port));
    let r = tokio::time::timeout(Duration::from_secs(5), src.next())
        .await
        .expect("answers in time");
    let Err(SourceError::Disconnected { reason, .. }) = r else {
        panic!("expected a loss, got {r:?}");
    };
    assert!(
        reason.contains(&format!("GET http://127.0.0.1:{port}/api/status"))
            && reason.to_lowercase().contains("refused"),
        "{reason}"
    );
}

/// Eye state off in the Companion app (9-byte packets): gaze arrives, and
/// the source says to turn on "Compute eye state".
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn eye_state_off_is_reported() {
    let Some(p) = peer(&["--layout", "9", "--speed", "4"]) else {
        return;
    };
    let mut src = NeonSource::new(cfg(p.http_port));
    let got = collect(&mut src, 10.0, |g| g.iter().any(|r| r.is_err())).await;
    let e = got.iter().find_map(|r| r.as_ref().err()).expect("a report");
    assert!(
        e.contains("Compute eye state") && e.contains("9 bytes"),
        "{e}"
    );
    assert!(
        got.iter()
            .any(|r| matches!(r, Ok(Sample::Gaze(g)) if g.eyes == GazeEyes::Binocular))
    );
    assert!(pupils(&got, 0).is_empty());
}

/// The recording's two blinks arrive from `eye_events` with their
/// durations, and closed-lid packets have pupil confidence 0.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn blinks_arrive_from_eye_events() {
    let rec = read_recording();
    let Some(p) = peer(&["--speed", "4"]) else {
        return;
    };
    let mut src = NeonSource::new(cfg(p.http_port));
    let blinks = |g: &[Result<Sample, String>]| {
        g.iter()
            .filter_map(|r| match r {
                Ok(Sample::Blink(b)) => Some(*b),
                _ => None,
            })
            .collect::<Vec<_>>()
    };
    let got = collect(&mut src, 12.0, |g| blinks(g).len() >= 2).await;
    let b = blinks(&got);
    assert_eq!(b.len(), 2, "blinks: {b:?}");
    for (got, want) in b.iter().zip(&rec.blinks) {
        let want_secs = (want.1 - want.0) as f64 * 1e-9;
        assert!(((got.end_t_secs - got.start_t_secs) - want_secs).abs() < 1e-6);
        assert_eq!(got.eye, None);
    }
    // Packets whose recorded aperture is ≤ 1 mm carry confidence 0.
    let closed = got
        .iter()
        .filter(|r| matches!(r, Ok(Sample::Pupil(p)) if p.eye == 1 && p.confidence == 0.0))
        .count();
    let want_closed = rec.state.iter().filter(|s| s[16] <= 1.0).count();
    assert!(want_closed > 0);
    assert!(closed >= want_closed.min(1), "{closed} closed-lid pupils");
}

/// The peer itself against Pupil Labs' official Python client
/// (`pupil-labs-realtime-api`): its status parses with the official models,
/// and the official decoder reads the 65/89/105-byte layouts, the pupils,
/// the sender-report timestamps and the blinks as the recording has them
/// (`neon_official_client.py` prints a PASS/FAIL line per check). Without
/// the client: SKIP, except in CI.
#[test]
fn the_peer_is_what_the_official_client_decodes() {
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/neon_official_client.py");
    let data = match try_data_dir() {
        Ok(d) => d,
        Err(e) => return skip_or_fail(&e.to_string()),
    };
    let out = match std::process::Command::new("python3")
        .arg(&script)
        .arg(data)
        .output()
    {
        Ok(o) => o,
        Err(e) => {
            assert!(
                std::env::var_os("CI").is_none(),
                "python3 missing in CI: {e}"
            );
            eprintln!("SKIP: python3 missing ({e})");
            return;
        }
    };
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    eprintln!("{stdout}");
    if out.status.code() == Some(2) {
        assert!(
            std::env::var_os("CI").is_none(),
            "the official client is missing in CI: {stdout}{stderr}"
        );
        return;
    }
    assert!(
        out.status.success() && !stdout.contains("FAIL"),
        "{stdout}\n{stderr}"
    );
    assert_eq!(stdout.matches("PASS").count(), 17, "{stdout}");
}
