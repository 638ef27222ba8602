#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! The Gazepoint Open Gaze API client against the simulator on 127.0.0.1:
//! handshake (every ENABLE_SEND field acknowledged), records → samples with
//! the right gaze and pupil values, a malformed record, a dropped
//! connection and the reconnection. Every wait is bounded.

use std::time::Duration;

use gazelight_devices::gazepoint::sim::{self, Session};
use gazelight_devices::gazepoint::{ENABLE_FIELDS, GazepointSource, GazepointTimeouts};
use gazelight_eye::{PupilUnit, Sample, SampleSource, SourceError};

fn timeouts() -> GazepointTimeouts {
    GazepointTimeouts {
        connect: Duration::from_secs(2),
        ack: Duration::from_secs(2),
        idle: Duration::from_secs(2),
    }
}

async fn next(src: &mut GazepointSource) -> Result<Option<Sample>, SourceError> {
    tokio::time::timeout(Duration::from_secs(5), src.next())
        .await
        .expect("the Gazepoint source answered within 5 s")
}

/// A record with every field the client enables, values as a GP3 sends
/// them (the §5.4 / §5.9 / §5.10 examples of the Open Gaze API v2.0 for
/// gaze and pupil pixels, mm pupils of an adult in room light).
fn full_record(cnt: u32, time: f64, fpog: (f64, f64, u8), lmm: f64, rmm: f64) -> String {
    sim::rec(&[
        ("CNT", cnt.to_string()),
        ("TIME", format!("{time:.5}")),
        ("FPOGX", format!("{:.5}", fpog.0)),
        ("FPOGY", format!("{:.5}", fpog.1)),
        ("FPOGS", "1891.86768".into()),
        ("FPOGD", "0.49280".into()),
        ("FPOGID", "1599".into()),
        ("FPOGV", fpog.2.to_string()),
        ("LPCX", "0.40525".into()),
        ("LPCY", "0.32822".into()),
        ("LPD", "15.23866".into()),
        ("LPS", "1.04834".into()),
        ("LPV", "1".into()),
        ("RPCX", "0.79375".into()),
        ("RPCY", "0.54131".into()),
        ("RPD", "12.69461".into()),
        ("RPS", "1.12750".into()),
        ("RPV", "1".into()),
        ("LPMM", format!("{lmm:.5}")),
        ("LPMMV", "1".into()),
        ("RPMM", format!("{rmm:.5}")),
        ("RPMMV", u8::from(rmm > 0.0).to_string()),
    ])
}

#[tokio::test]
async fn handshake_records_malformed_record_drop_and_reconnect() {
    let session1 = Session {
        lines: vec![
            full_record(1, 4.99716, (0.48439, 0.50313, 1), 3.91, 3.87),
            // Truncated mid-attribute (a cut line).
            "<REC CNT=\"2\" TIME=\"5.01366\" FPOGX=\"0.4".to_owned(),
            full_record(3, 5.02991, (0.1, 0.9, 0), 3.95, 0.0),
        ],
        drop_after: true,
        line_interval: None,
    };
    let session2 = Session {
        lines: vec![full_record(1, 0.01667, (0.75, 0.25, 1), 5.5, 5.4)],
        drop_after: false,
        line_interval: None,
    };
    let simulator = sim::start(vec![session1, session2]).await.unwrap();
    let mut src = GazepointSource::with_timeouts("127.0.0.1", simulator.addr.port(), timeouts());
    assert!(src.describe().contains("Gazepoint"));

    // Record 1: gaze + right + left pupil.
    let Some(Sample::Gaze(g)) = next(&mut src).await.unwrap() else {
        panic!("gaze first")
    };
    assert_eq!(g.gaze_uv, [0.48439, 0.50313]);
    assert_eq!(g.confidence, 1.0);
    let Some(Sample::Pupil(r)) = next(&mut src).await.unwrap() else {
        panic!("right pupil")
    };
    assert_eq!(r.eye, 0);
    assert_eq!(r.unit, PupilUnit::Px);
    assert!((r.diameter_raw - 12.69461).abs() < 1e-5);
    assert_eq!(r.diameter_mm, Some(3.87));
    // Camera-image centre (top-left origin) → Pupil's bottom-left origin.
    assert!(
        (r.norm_pos[0] - 0.79375).abs() < 1e-6 && (r.norm_pos[1] - (1.0 - 0.54131)).abs() < 1e-6
    );
    let Some(Sample::Pupil(l)) = next(&mut src).await.unwrap() else {
        panic!("left pupil")
    };
    assert_eq!((l.eye, l.diameter_mm, l.confidence), (1, Some(3.91), 1.0));

    // The handshake enabled every field, each acknowledged, DATA last.
    {
        let got = simulator.received.lock().unwrap().clone();
        let ids: Vec<&str> = got.iter().map(|(id, _)| id.as_str()).collect();
        assert_eq!(ids, ENABLE_FIELDS.to_vec());
        assert!(got.iter().all(|(_, state)| state == "1"));
    }

    // Record 2 is malformed: an item error naming the record and offset.
    match next(&mut src).await {
        Err(SourceError::Item { index, error, .. }) => {
            assert_eq!(index, 1);
            assert_eq!(
                error.to_string(),
                "byte 38: expected the record to end with `/>`"
            );
        }
        other => panic!("expected a malformed record, got {other:?}"),
    }
    // Record 3: FPOGV=0 → confidence 0; right pupil mm invalid.
    let Some(Sample::Gaze(g3)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!((g3.gaze_uv, g3.confidence), ([0.1, 0.9], 0.0));
    let Some(Sample::Pupil(r3)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!(r3.diameter_mm, None);
    let Some(Sample::Pupil(_)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!((src.records(), src.errors(), src.connects()), (3, 1, 1));

    // The server drops the connection.
    match next(&mut src).await {
        Err(SourceError::Disconnected { reason, .. }) => {
            assert!(reason.contains("closed"), "{reason}")
        }
        other => panic!("expected a disconnection, got {other:?}"),
    }
    // The next call reconnects, repeats the handshake and reads on.
    let Some(Sample::Gaze(g4)) = next(&mut src).await.unwrap() else {
        panic!("gaze after reconnecting")
    };
    assert_eq!(g4.gaze_uv, [0.75, 0.25]);
    assert_eq!(src.connects(), 2);
    let Some(Sample::Pupil(r4)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!(r4.diameter_mm, Some(5.4));
    assert_eq!(
        simulator.received.lock().unwrap().len(),
        2 * ENABLE_FIELDS.len()
    );
}

#[tokio::test]
async fn no_server_is_a_disconnection_not_a_hang() {
    // Bind and close a listener to get a port nobody listens on.
    let port = {
        let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
        l.local_addr().unwrap().port()
    };
    let mut src = GazepointSource::with_timeouts("127.0.0.1", port, timeouts());
    match next(&mut src).await {
        Err(SourceError::Disconnected { reason, .. }) => {
            assert!(reason.starts_with("connect:"), "{reason}")
        }
        other => panic!("expected a failed connect, got {other:?}"),
    }
}

#[tokio::test]
async fn a_silent_server_times_out_the_handshake() {
    // Accepts but never answers.
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = l.local_addr().unwrap().port();
    let server = tokio::spawn(async move {
        let (s, _) = l.accept().await.unwrap();
        tokio::time::sleep(Duration::from_secs(10)).await;
        drop(s);
    });
    let mut src = GazepointSource::with_timeouts(
        "127.0.0.1",
        port,
        GazepointTimeouts {
            ack: Duration::from_millis(200),
            ..timeouts()
        },
    );
    match next(&mut src).await {
        Err(SourceError::Disconnected { reason, .. }) => {
            assert!(reason.contains("no ACK for ENABLE_SEND_TIME"), "{reason}")
        }
        other => panic!("expected a handshake timeout, got {other:?}"),
    }
    server.abort();
}
