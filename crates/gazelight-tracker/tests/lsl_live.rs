#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The LSL wrappers against the real liblsl and pylsl, each test in its own
//! network namespace (`unshare -n`, loopback up) with the machine-only
//! configuration, so no discovery packet can leave the machine.
//!
//! Outside CI a missing `unshare`/`ip`/pylsl prints a SKIP line; with `CI`
//! set it fails.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use gazelight_test_support::netns;
use gazelight_tracker::lsl::{
    ChannelDesc, ChannelFormat, LslConfig, LslQuery, LslSource, Outlet, StreamDesc, local_clock,
};
use gazelight_tracker::{PupilUnit, Sample, SampleSource, SourceError};

fn peer_script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../gazelight/tests/lsl_peer.py")
}

/// Runs test `name` of this binary again inside a fresh network namespace
/// (loopback up, the machine-only LSL configuration); returns true when
/// the caller is already inside.
fn in_netns(name: &str) -> bool {
    if netns::inside() {
        return true;
    }
    if !netns::ready(&["pylsl"]) {
        return false;
    }
    let dir = std::env::temp_dir().join(format!("gazelight-lsl-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let cfg = dir.join("lsl_api.cfg");
    std::fs::write(&cfg, LslConfig::default().generated()).unwrap();
    netns::rerun_test(name, &[("LSLAPICFG", cfg.as_os_str())]);
    false
}

struct Kill(Child);
impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[test]
fn pylsl_reads_what_the_outlet_published() {
    if !in_netns("pylsl_reads_what_the_outlet_published") {
        return;
    }
    let config = LslConfig::default();
    let reader = Command::new("python3")
        .arg(peer_script())
        .args([
            "read",
            "--names",
            "t-num,t-mark",
            "--secs",
            "15",
            "--until-quiet",
            "1.0",
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let mut reader = Kill(reader);
    let mut num = Outlet::new(
        &config,
        &StreamDesc {
            name: "t-num".into(),
            kind: "Gaze".into(),
            nominal_srate_hz: 500.0,
            format: ChannelFormat::Double64,
            source_id: "t-num-src".into(),
            channels: vec![
                ChannelDesc::new("a", "mm", "Diameter", Some("right")),
                ChannelDesc::new("b", "normalized", "ScreenX", Some("both")),
            ],
            meta: vec![("source".into(), "unit test".into())],
        },
        10,
    )
    .unwrap();
    let mut mark = Outlet::new(
        &config,
        &StreamDesc {
            name: "t-mark".into(),
            kind: "Markers".into(),
            nominal_srate_hz: 0.0,
            format: ChannelFormat::String,
            source_id: "t-mark-src".into(),
            channels: Vec::new(),
            meta: Vec::new(),
        },
        10,
    )
    .unwrap();
    let start = Instant::now();
    while !(num.have_consumers() && mark.have_consumers()) {
        assert!(
            start.elapsed() < Duration::from_secs(12),
            "pylsl never connected"
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let t0 = local_clock(&config).unwrap();
    for i in 0..300 {
        num.push(
            &[f64::from(i) * 0.5, 1.0 / (1.0 + f64::from(i))],
            t0 + f64::from(i) * 0.002,
        )
        .unwrap();
        if i % 100 == 0 {
            mark.push_marker(&format!("m{i}"), t0 + f64::from(i) * 0.002)
                .unwrap();
        }
        std::thread::sleep(Duration::from_micros(500));
    }
    assert!(
        num.push(&[1.0], t0).is_err(),
        "a sample of the wrong size is refused"
    );
    let out = reader.0.stdout.take().unwrap();
    let mut line = String::new();
    BufReader::new(out).read_line(&mut line).unwrap();
    let _ = reader.0.wait();
    let v: serde_json::Value =
        serde_json::from_str(&line).unwrap_or_else(|e| panic!("{e}: {line}"));
    let s = &v["streams"]["t-num"];
    let vals = s["values"].as_array().unwrap();
    let ts = s["t"].as_array().unwrap();
    assert_eq!(vals.len(), 300, "every sample arrives");
    for (i, (x, t)) in vals.iter().zip(ts).enumerate() {
        // Exact in double64; the JSON text round trip may cost one ulp.
        assert!((x[0].as_f64().unwrap() - i as f64 * 0.5).abs() <= 1e-12 * (1.0 + i as f64));
        assert!((x[1].as_f64().unwrap() - 1.0 / (1.0 + i as f64)).abs() <= 1e-15);
        // pylsl's timestamp is the one we pushed (same machine: the time
        // correction is 0 and pylsl does not post-process by default).
        assert!((t.as_f64().unwrap() - (t0 + i as f64 * 0.002)).abs() < 1e-9);
    }
    let labels: Vec<&str> = s["info"]["channels"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["label"].as_str().unwrap())
        .collect();
    assert_eq!(labels, ["a", "b"]);
    assert_eq!(s["info"]["channels"][0]["unit"], "mm");
    assert_eq!(s["info"]["channels"][0]["eye"], "right");
    assert_eq!(s["info"]["source"], "unit test");
    let m = &v["streams"]["t-mark"]["values"];
    assert_eq!(m, &serde_json::json!([["m0"], ["m100"], ["m200"]]));
}

#[test]
fn a_relay_layout_stream_is_read_lost_and_resumed() {
    if !in_netns("a_relay_layout_stream_is_read_lost_and_resumed") {
        return;
    }
    // The tracker app streams for 2.5 s, is gone for 1 s, then a new one
    // (a restarted app: a new process, same stream name) streams for 8 s
    // (long enough for a re-resolve on a loaded 2-core machine).
    let relay = |secs: &str| {
        Command::new("python3")
            .arg(peer_script())
            .args([
                "relay", "--name", "t-relay", "--rate", "100", "--secs", secs,
            ])
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .status()
            .unwrap()
    };
    // The read ends on an event, not a clock: half a second after the
    // second peer's process has exited (its last sample sent), so a slow
    // start of either Python peer on a loaded machine cannot cut it short.
    let done = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
    let peers_done = done.clone();
    let peers = std::thread::spawn(move || {
        let first = relay("2.5").success();
        std::thread::sleep(Duration::from_secs(1));
        let second = relay("8").success();
        peers_done.store(true, std::sync::atomic::Ordering::SeqCst);
        assert!(first && second, "a relay peer failed");
    });
    let rt = tokio::runtime::Builder::new_current_thread()
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        let mut src = LslSource::new(
            LslQuery::parse("lsl://?name=t-relay").unwrap(),
            LslConfig::default(),
        )
        .unwrap();
        // A bound only against a hang: the peers take 11.5 s and their
        // start-ups.
        let hang = tokio::time::Instant::now() + Duration::from_secs(120);
        let mut drained_at: Option<tokio::time::Instant> = None;
        let (mut before, mut after, mut lost) = (0u32, 0u32, 0u32);
        let mut lags = Vec::new();
        loop {
            let now = tokio::time::Instant::now();
            assert!(now < hang, "the peers never finished");
            if done.load(std::sync::atomic::Ordering::SeqCst) {
                let at = *drained_at.get_or_insert(now + Duration::from_millis(500));
                if now >= at {
                    break;
                }
            }
            let Ok(r) = tokio::time::timeout(Duration::from_millis(100), src.next()).await else {
                continue;
            };
            match r {
                Ok(Some(Sample::Pupil(p))) => {
                    // Published: diameter0_3d 3.75 mm (right), diameter1_3d 4.25 mm.
                    let want = if p.eye == 0 { 3.75 } else { 4.25 };
                    assert_eq!((p.unit, p.diameter_mm), (PupilUnit::Mm, Some(want)));
                    assert!((p.confidence - 0.93).abs() < 1e-6);
                    let lag = gazelight_tracker::pupil::clock::host_now_secs() - p.t_secs;
                    lags.push(lag);
                    if lost == 0 { before += 1 } else { after += 1 }
                }
                Ok(Some(Sample::Gaze(g))) => {
                    // norm_pos (0.3, 0.8), origin bottom-left → uv (0.3, 0.2).
                    assert!((g.gaze_uv[0] - 0.3).abs() < 1e-6 && (g.gaze_uv[1] - 0.2).abs() < 1e-6);
                }
                Ok(Some(_)) => {}
                Ok(None) => break,
                Err(SourceError::Disconnected { .. }) => lost += 1,
                Err(e) => panic!("{e}"),
            }
        }
        lags.sort_by(f64::total_cmp);
        let median_lag = lags.get(lags.len() / 2).copied().unwrap_or(f64::NAN);
        eprintln!(
            "before {before}, after {after}, lost {lost}, median host receipt - sample time {:.2} ms, {}",
            median_lag * 1e3,
            src.describe()
        );
        assert!(before > 250, "pupil samples before the loss: {before}");
        assert!(lost >= 1, "the vanished stream is reported lost");
        assert!(after > 100, "the stream resumes: {after}");
        // Sample times are the sender's stamps on the host clock: the
        // typical receipt is a few ms after them, never before.
        assert!((0.0..0.05).contains(&median_lag), "{median_lag}");
        assert!(lags[0] > -0.001, "a sample time after its receipt: {}", lags[0]);
    });
    peers.join().unwrap();
}

#[test]
fn a_missing_library_says_how_to_get_it() {
    // A child process: the library is loaded once per process.
    if std::env::var_os("GAZELIGHT_LSL_MISSING").is_some() {
        let e = LslSource::new(
            LslQuery::parse("lsl://?type=Gaze").unwrap(),
            LslConfig::default(),
        )
        .err()
        .expect("no library");
        let msg = e.to_string();
        assert!(
            msg.contains("pip install pylsl") && msg.contains("/nonexistent/liblsl.so"),
            "{msg}"
        );
        return;
    }
    let out = Command::new(std::env::current_exe().unwrap())
        .args([
            "a_missing_library_says_how_to_get_it",
            "--exact",
            "--nocapture",
        ])
        .env("GAZELIGHT_LSL_MISSING", "1")
        .env("GAZELIGHT_LIBLSL", "/nonexistent/liblsl.so")
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
}

/// Issue 37: one LSL sample stamped +1e5 s froze the published pupil for
/// the rest of the session (the state's time stayed at the outlier's),
/// with the source still live. Now the stream's clock mapping drops that
/// one sample and counts it; when the sender's pupils change 0.5 s later
/// the published pupil follows them within 1 s.
#[test]
fn one_sample_stamped_1e5_s_ahead_does_not_freeze_the_pupil() {
    if !in_netns("one_sample_stamped_1e5_s_ahead_does_not_freeze_the_pupil") {
        return;
    }
    // 100 Hz for 6 s; one sample stamped +1e5 s at 1.5 s; every diameter
    // ×1.3 from 2.0 s (3.75 → 4.875 mm right, 4.25 → 5.525 mm left).
    let peer = Command::new("python3")
        .arg(peer_script())
        .args([
            "relay",
            "--name",
            "t-outlier",
            "--rate",
            "100",
            "--secs",
            "6",
            "--outlier-at",
            "1.5",
            "--outlier-secs",
            "1e5",
            "--scale-at",
            "2.0",
            "--scale",
            "1.3",
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::inherit())
        .spawn()
        .unwrap();
    let _peer = Kill(peer);
    let rt = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap();
    rt.block_on(async {
        use gazelight_tracker::live::{self, AgeClock, LiveConfig, SourceHealth, lock_status};
        let src = LslSource::new(
            LslQuery::parse("lsl://?name=t-outlier").unwrap(),
            LslConfig::default(),
        )
        .unwrap();
        let (stop, shutdown) = tokio::sync::watch::channel(false);
        let live = live::spawn(
            "lsl://?name=t-outlier",
            src,
            gazelight_tracker::filter::FilterChain::with_defaults(),
            AgeClock::SampleTime,
            shutdown,
            LiveConfig::default(),
        );
        let mut samples = live.samples.subscribe();
        let mut rx = live.eye.clone();
        let want = [3.75f32 * 1.3, 4.25 * 1.3];
        // Host time of the first sample with the new pupils, and of the
        // first published state showing them.
        let (mut changed_at, mut followed_at) = (None, None);
        let deadline = tokio::time::Instant::now() + Duration::from_secs(14);
        while followed_at.is_none() && tokio::time::Instant::now() < deadline {
            let wait = tokio::time::Instant::now() + Duration::from_millis(20);
            let _ = tokio::time::timeout_at(wait, rx.changed()).await;
            while let Ok(s) = samples.try_recv() {
                if let Sample::Pupil(p) = s
                    && changed_at.is_none()
                    && p.diameter_mm.is_some_and(|d| (d - want[0]).abs() < 1e-3)
                {
                    changed_at = Some(p.t_secs);
                }
            }
            let s = *rx.borrow_and_update();
            if changed_at.is_some()
                && (0..2).all(|e| {
                    let ch = s.state.eyes[e];
                    (ch.pupil_mm - want[e]).abs() < 0.05
                        && ch.pupil_origin == gazelight_tracker::PupilOrigin::Measured
                })
            {
                followed_at = Some(s.state.t_secs);
            }
        }
        let status = lock_status(&live.status).clone();
        let last = *rx.borrow();
        eprintln!("changed at {changed_at:?}, followed at {followed_at:?}; {status:?}");
        let changed_at = changed_at.expect("the sender's pupils changed");
        let followed_at =
            followed_at.unwrap_or_else(|| panic!("the pupil never followed: {last:?}"));
        assert!(
            followed_at - changed_at < 1.0,
            "followed {:.3} s after the change",
            followed_at - changed_at
        );
        assert_eq!(status.health, SourceHealth::Live);
        let clock = status
            .clock
            .expect("the LSL source reports its clock mapping");
        assert_eq!((clock.rejected, clock.jumps), (1, 0), "{clock:?}");
        stop.send_replace(true);
        let _ = tokio::time::timeout(Duration::from_secs(5), live.task).await;
    });
}
