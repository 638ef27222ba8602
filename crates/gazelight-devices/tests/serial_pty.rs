#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Serial sources over a pseudo-terminal pair (the kernel's pty driver in
//! raw mode, as `serialport::TTYPort::pair()` sets it up): all three
//! encodings, a corrupt frame, a garbled line, and a hang-up.

use std::io::Write;
use std::path::Path;
use std::time::Duration;

use gazelight_devices::SerialFormat;
use gazelight_devices::framing;
use gazelight_devices::serial::SerialSource;
use gazelight_eye::{
    DetectorMethod, GazeEyes, GazeSample, PupilSample, PupilUnit, Sample, SampleSource, SourceError,
};
use serialport::{SerialPort, TTYPort};

/// Bounded wait for the next item.
async fn next(src: &mut SerialSource) -> Result<Option<Sample>, SourceError> {
    tokio::time::timeout(Duration::from_secs(5), src.next())
        .await
        .expect("the serial source answered within 5 s")
}

#[tokio::test]
async fn csv_lines_including_a_garbled_one() {
    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    let mut src = SerialSource::from_port(slave, "pty-csv", SerialFormat::Csv).unwrap();
    master
        .write_all(
            b"# kind,t_secs,...\nG,10.000,0.25,0.75,1\nP,10.000,1,4.20,mm,0.9\nG,10.0\x0e7,0.@,\xff\n",
        )
        .unwrap();
    // The next sample 100 ms later (device time says 8 ms: the first burst
    // was late, so the clock offset stays the one of the first sample).
    tokio::time::sleep(Duration::from_millis(100)).await;
    master.write_all(b"P,10.008,0,310.5,px,1\n").unwrap();
    let Some(Sample::Gaze(g)) = next(&mut src).await.unwrap() else {
        panic!("gaze first")
    };
    assert_eq!((g.gaze_uv, g.confidence), ([0.25, 0.75], 1.0));
    let Some(Sample::Pupil(p)) = next(&mut src).await.unwrap() else {
        panic!("pupil second")
    };
    assert_eq!((p.eye, p.diameter_mm, p.confidence), (1, Some(4.2), 0.9));
    // Both samples carry the same device time, so the same host time.
    assert_eq!(p.t_secs, g.t_secs);
    // Line 4 is garbled (a stray control byte, a non-UTF-8 byte).
    match next(&mut src).await {
        Err(SourceError::Item { index, error, .. }) => {
            assert_eq!(index, 4);
            assert!(error.to_string().starts_with("line 4:"), "{error}");
        }
        other => panic!("expected an item error, got {other:?}"),
    }
    let Some(Sample::Pupil(p)) = next(&mut src).await.unwrap() else {
        panic!("pupil after the garbled line")
    };
    assert_eq!((p.eye, p.unit, p.diameter_raw), (0, PupilUnit::Px, 310.5));
    // 8 ms later by the device clock.
    assert!((p.t_secs - g.t_secs - 0.008).abs() < 1e-9);

    // Hang-up: the pty master goes away.
    drop(master);
    assert!(matches!(
        next(&mut src).await,
        Err(SourceError::Disconnected { .. })
    ));
    // A source made from a port cannot reopen it: end of stream.
    assert!(next(&mut src).await.unwrap().is_none());
}

#[tokio::test]
async fn framed_samples_with_a_corrupt_frame() {
    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    let mut src = SerialSource::from_port(slave, "pty-framed", SerialFormat::Framed).unwrap();
    let gaze = Sample::Gaze(GazeSample {
        t_secs: 0.0,
        gaze_uv: [0.5, 0.5],
        confidence: 1.0,
        eyes: GazeEyes::Binocular,
    });
    let pupil = |d: f32| {
        Sample::Pupil(PupilSample {
            t_secs: 0.0,
            eye: 0,
            diameter_raw: d,
            unit: PupilUnit::Mm,
            diameter_mm: Some(d),
            confidence: 1.0,
            norm_pos: [f32::NAN, f32::NAN],
            method: DetectorMethod::Other,
        })
    };
    let mut bytes = b"boot noise\r\n".to_vec();
    framing::encode(&gaze, 5_000_000, &mut bytes);
    let bad = bytes.len();
    framing::encode(&pupil(3.5), 5_004_000, &mut bytes);
    bytes[bad + 15] ^= 0x01; // flip a bit of the diameter: CRC no longer matches
    framing::encode(&pupil(3.75), 5_008_000, &mut bytes);
    // Write in two pieces, splitting a frame.
    master.write_all(&bytes[..bad + 7]).unwrap();
    master.flush().unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    master.write_all(&bytes[bad + 7..]).unwrap();

    let Some(Sample::Gaze(g)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!(g.gaze_uv, [0.5, 0.5]);
    match next(&mut src).await {
        Err(SourceError::Item { error, .. }) => {
            let msg = error.to_string();
            assert!(msg.contains(&format!("frame at byte {bad}")), "{msg}");
            assert!(msg.contains("CRC mismatch"), "{msg}");
        }
        other => panic!("expected a CRC error, got {other:?}"),
    }
    let Some(Sample::Pupil(p)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!(p.diameter_mm, Some(3.75));
    assert!((p.t_secs - g.t_secs - 0.008).abs() < 1e-9);
}

#[tokio::test]
async fn gazepoint_records_over_a_path_opened_line_and_a_hangup() {
    let (mut master, slave) = TTYPort::pair().expect("pty pair");
    let path = slave.name().expect("the pty slave has a path");
    // Open the device node by path, as a CDC-ACM gadget would be.
    let mut src = SerialSource::open(Path::new(&path), 115_200, SerialFormat::Gazepoint).unwrap();
    drop(slave);
    assert!(src.describe().contains(&path));
    master
        .write_all(
            b"<ACK ID=\"ENABLE_SEND_DATA\" STATE=\"1\" />\r\n\
              <REC TIME=\"4.99716\" FPOGX=\"0.48439\" FPOGY=\"0.50313\" FPOGV=\"1\" LPMM=\"3.91\" LPMMV=\"1\" RPMM=\"3.87\" RPMMV=\"1\" />\r\n\
              <REC TIME=\"5.01366\" FPOGX=\"0.49\" FPOGY=0.5 />\r\n",
        )
        .unwrap();
    tokio::time::sleep(Duration::from_millis(100)).await;
    master
        .write_all(b"<REC TIME=\"5.02991\" FPOGX=\"0.50\" FPOGY=\"0.51\" FPOGV=\"0\" />\r\n")
        .unwrap();
    let Some(Sample::Gaze(g)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!(g.gaze_uv, [0.48439, 0.50313]);
    assert_eq!(g.confidence, 1.0);
    let Some(Sample::Pupil(r)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    let Some(Sample::Pupil(l)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!(
        (r.eye, r.diameter_mm, l.eye, l.diameter_mm),
        (0, Some(3.87), 1, Some(3.91))
    );
    assert_eq!(r.unit, PupilUnit::Mm);
    match next(&mut src).await {
        Err(SourceError::Item { index, error, .. }) => {
            assert_eq!(index, 3);
            // `FPOGY=0.5`: the value has no opening quote at byte 39.
            assert!(error.to_string().contains("byte 39"), "{error}");
        }
        other => panic!("expected a malformed record, got {other:?}"),
    }
    let Some(Sample::Gaze(g2)) = next(&mut src).await.unwrap() else {
        panic!()
    };
    assert_eq!(g2.confidence, 0.0);
    assert!((g2.t_secs - g.t_secs - (5.02991 - 4.99716)).abs() < 1e-9);

    // Hang-up, then a reopen attempt on the next call: the pty is gone.
    drop(master);
    assert!(matches!(
        next(&mut src).await,
        Err(SourceError::Disconnected { .. })
    ));
    match next(&mut src).await {
        Err(SourceError::Disconnected { reason, .. }) => {
            assert!(
                reason.contains(&path) || reason.contains("open"),
                "{reason}"
            )
        }
        other => panic!("expected a failed reopen, got {other:?}"),
    }
}

#[test]
fn a_missing_device_is_a_clear_error() {
    let Err(SourceError::Fatal { reason, .. }) = SerialSource::open(
        Path::new("/dev/ttyACM-gazelight-missing"),
        115_200,
        SerialFormat::Csv,
    ) else {
        panic!("opening a missing device must fail");
    };
    assert!(reason.contains("/dev/ttyACM-gazelight-missing"), "{reason}");
}
