#![allow(clippy::unwrap_used, clippy::expect_used)] // test and bench code may panic on a failed setup
//! Property suite (issue 14): every importer, the msgpack datum decoder and
//! the HID descriptor/report parsers, on random bytes and on mutations of
//! the real files in shared/data. The invariant: any input gives `Ok` or a
//! clear error, never a panic; importers end (no endless loop) and yield at
//! most one sample per few input bytes (memory bounded by the input).
//!
//! Case counts are fixed (`CASES` per property, set by `GAZELIGHT_FUZZ_CASES`
//! for longer local runs) so the whole suite stays well under a minute.

use std::path::{Path, PathBuf};

use gazelight_tracker::import::csv::CsvPupilImporter;
use gazelight_tracker::import::eyelink::AscImporter;
use gazelight_tracker::import::time_guard::TimeGuard;
use gazelight_tracker::import::{self, Importer};
use gazelight_tracker::pupil::msg;
use gazelight_tracker::transport::hid::descriptor::Descriptor;
use gazelight_tracker::transport::hid::page12::Page12Layout;
use gazelight_tracker::transport::hid::{livetrack, testdata};
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

fn cases() -> u32 {
    std::env::var("GAZELIGHT_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(256)
}

fn config() -> Config {
    Config {
        cases: cases(),
        failure_persistence: None,
        ..Config::default()
    }
}

fn shared(rel: &str) -> PathBuf {
    gazelight_test_support::data_path(rel)
}

/// The first `n` bytes of a real file (mutations stay fast).
fn head(rel: &str, n: usize) -> Vec<u8> {
    let mut b = std::fs::read(shared(rel)).expect("shared data");
    b.truncate(n);
    b
}

/// A mutation of `seed`: byte flips, overwrites, deletions, insertions and
/// splices of absurd numbers.
fn mutated(seed: Vec<u8>) -> impl Strategy<Value = Vec<u8>> {
    let len = seed.len().max(1);
    let edit = prop_oneof![
        (0..len, any::<u8>()).prop_map(|(i, b)| (0u8, i, vec![b])),
        (0..len, 0u8..8).prop_map(|(i, bit)| (1u8, i, vec![bit])),
        (0..len, 1usize..64).prop_map(|(i, n)| (2u8, i, vec![n as u8])),
        (
            0..len,
            prop::sample::select(vec![
                "1e308",
                "-1e308",
                "nan",
                "inf",
                "99999999999999",
                "-0",
                "\r",
                "\t",
                "\0",
                ",,,,",
                "\u{feff}",
                "18446744073709551615",
            ])
        )
            .prop_map(|(i, s)| (3u8, i, s.as_bytes().to_vec())),
    ];
    prop::collection::vec(edit, 1..16).prop_map(move |edits| {
        let mut b = seed.clone();
        for (kind, i, v) in edits {
            if b.is_empty() {
                break;
            }
            let i = i % b.len();
            match kind {
                0 => b[i] = v[0],
                1 => b[i] ^= 1 << v[0],
                2 => {
                    let end = (i + v[0] as usize).min(b.len());
                    b.drain(i..end);
                }
                _ => {
                    b.splice(i..i, v);
                }
            }
        }
        b
    })
}

/// Drains an importer, checking that it ends and stays bounded by its input.
fn drain(imp: &mut dyn Importer, input_len: usize) -> Result<(), TestCaseError> {
    let mut n = 0usize;
    for item in &mut *imp {
        n += 1;
        if let Err(e) = item {
            // A clear error names something.
            prop_assert!(!e.to_string().is_empty());
        }
        // Each CSV/ASC line yields at most 3 samples and is at least 2 bytes.
        prop_assert!(n <= input_len * 2 + 16, "{n} items from {input_len} bytes");
    }
    Ok(())
}

fn csv_bytes(b: &[u8]) -> Result<(), TestCaseError> {
    let p = Path::new("fuzz.csv");
    let mut imp = TimeGuard::new(CsvPupilImporter::from_reader(b, p), p);
    drain(&mut imp, b.len())
}

fn asc_bytes(b: &[u8]) -> Result<(), TestCaseError> {
    let p = Path::new("fuzz.asc");
    let mut imp = TimeGuard::new(AscImporter::from_reader(b, p), p);
    drain(&mut imp, b.len())
}

#[test]
fn csv_importer_never_panics() {
    let mut r = TestRunner::new(config());
    r.run(&prop::collection::vec(any::<u8>(), 0..2048), |b| {
        csv_bytes(&b)
    })
    .unwrap();
    let seed = head("eye/piprkit-plr/pupil_trace.csv", 4096);
    r.run(&mutated(seed), |b| csv_bytes(&b)).unwrap();
}

#[test]
fn asc_importer_never_panics() {
    let mut r = TestRunner::new(config());
    r.run(&prop::collection::vec(any::<u8>(), 0..2048), |b| {
        asc_bytes(&b)
    })
    .unwrap();
    // Past the header, into the sample and event lines.
    let asc = std::fs::read(shared("eye/eyelink-psa/both_eyes.asc")).unwrap();
    let start = asc.len() / 3;
    let seed = asc[start..start + 6000].to_vec();
    r.run(&mutated(seed), |b| asc_bytes(&b)).unwrap();
}

/// A copy of a recording directory in a per-test temp dir.
fn copy_dir(src: &Path, name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("gazelight-fuzz-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    for e in std::fs::read_dir(src).unwrap() {
        let e = e.unwrap();
        if e.path().is_file() {
            std::fs::copy(e.path(), d.join(e.file_name())).unwrap();
        }
    }
    d
}

fn import_dir(dir: &Path) -> Result<(), TestCaseError> {
    match import::open(dir) {
        Err(e) => prop_assert!(!e.to_string().is_empty()),
        Ok(mut imp) => drain(imp.as_mut(), 1 << 24)?,
    }
    Ok(())
}

#[test]
fn neon_importer_never_panics_on_mutated_files() {
    let dir = copy_dir(&shared("eye/neon-demo"), "neon");
    let mut r = TestRunner::new(Config {
        cases: cases() / 4,
        ..config()
    });
    // Mutate one file of the recording per case (the small ones whole, the
    // binary streams in their first 4 KiB), then import the directory.
    let files = [
        "info.json",
        "eye_state.dtype",
        "gaze.dtype",
        "blinks.dtype",
        "eye_state ps1.time",
        "eye_state ps1.raw",
        "gaze ps1.time",
        "blinks ps1.raw",
    ];
    for f in files {
        let orig = std::fs::read(shared("eye/neon-demo").join(f)).unwrap();
        let n = orig.len().min(4096);
        let seed = orig[..n].to_vec();
        r.run(&mutated(seed), |b| {
            let mut whole = orig.clone();
            whole.splice(..n, b);
            std::fs::write(dir.join(f), &whole).unwrap();
            let res = import_dir(&dir);
            std::fs::write(dir.join(f), &orig).unwrap();
            res
        })
        .unwrap();
    }
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn pupil_core_importer_never_panics_on_random_pldata() {
    let dir = std::env::temp_dir().join(format!("gazelight-fuzz-{}-pcore", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    // A real datum as Pupil writes it, then random and mutated records.
    let datum = {
        use gazelight_tracker::sample::{DetectorMethod, PupilSample, PupilUnit, Sample};
        let s = Sample::Pupil(PupilSample {
            t_secs: 12.5,
            eye: 0,
            diameter_raw: 40.0,
            unit: PupilUnit::Px,
            diameter_mm: None,
            confidence: 0.9,
            norm_pos: [0.5, 0.5],
            method: DetectorMethod::Pupil2d,
        });
        let (topic, payload) = msg::encode_sample(&s).unwrap().unwrap();
        let mut rec = vec![0x92, 0xa0 | topic.len() as u8];
        rec.extend_from_slice(topic.as_bytes());
        rec.push(0xc5);
        rec.extend_from_slice(&(payload.len() as u16).to_be_bytes());
        rec.extend_from_slice(&payload);
        rec.repeat(8)
    };
    let mut r = TestRunner::new(Config {
        cases: cases() / 2,
        ..config()
    });
    let strat = prop_oneof![
        prop::collection::vec(any::<u8>(), 0..4096).boxed(),
        mutated(datum).boxed()
    ];
    r.run(&strat, |b| {
        std::fs::write(dir.join("pupil.pldata"), &b).unwrap();
        import_dir(&dir)
    })
    .unwrap();
    std::fs::remove_dir_all(&dir).ok();
}

#[test]
fn msgpack_decoder_never_panics() {
    let topics = prop::sample::select(vec![
        "pupil.0.2d",
        "pupil.1.3d",
        "gaze.3d.01.",
        "gaze.2d.0.",
        "blinks",
        "notify.x",
        "",
        "pupil",
    ]);
    let mut r = TestRunner::new(config());
    r.run(
        &(topics, prop::collection::vec(any::<u8>(), 0..512)),
        |(t, b)| {
            if let Err(e) = msg::decode(t, &b) {
                prop_assert!(!e.to_string().is_empty());
            }
            let _ = msg::decode_message(t.as_bytes(), &b);
            Ok(())
        },
    )
    .unwrap();
    // Mutations of a valid 2D pupil datum.
    use gazelight_tracker::sample::{DetectorMethod, PupilSample, PupilUnit, Sample};
    let s = Sample::Pupil(PupilSample {
        t_secs: 1.0,
        eye: 1,
        diameter_raw: 30.0,
        unit: PupilUnit::Px,
        diameter_mm: None,
        confidence: 1.0,
        norm_pos: [0.4, 0.6],
        method: DetectorMethod::Pupil2d,
    });
    let (topic, payload) = msg::encode_sample(&s).unwrap().unwrap();
    r.run(&mutated(payload.to_vec()), |b| {
        let _ = msg::decode(&topic, &b);
        Ok(())
    })
    .unwrap();
}

#[test]
fn hid_descriptor_and_report_parsers_never_panic() {
    let mut r = TestRunner::new(config());
    let seed = testdata::PAGE12_EYE_TRACKER.to_vec();
    let strat = prop_oneof![
        prop::collection::vec(any::<u8>(), 0..512).boxed(),
        mutated(seed).boxed()
    ];
    r.run(
        &(strat, prop::collection::vec(any::<u8>(), 0..128)),
        |(d, report)| {
            if let Ok(desc) = Descriptor::parse(&d)
                && let Ok(layout) = Page12Layout::from_descriptor(&desc)
            {
                let _ = layout.decode_tracking(&report);
                let _ = layout.decode_screen(&report);
                let _ = layout.decode_status(&report);
            }
            let _ = livetrack::decode(&report);
            Ok(())
        },
    )
    .unwrap();
    // Random reports against the real layout.
    let desc = Descriptor::parse(testdata::PAGE12_EYE_TRACKER).unwrap();
    let layout = Page12Layout::from_descriptor(&desc).unwrap();
    r.run(&prop::collection::vec(any::<u8>(), 0..256), |report| {
        let _ = layout.decode_tracking(&report);
        let _ = layout.decode_screen(&report);
        let _ = layout.decode_status(&report);
        Ok(())
    })
    .unwrap();
}

/// The live Neon decoders (issue 16): gaze and eye-event payloads, RTP
/// packets, RTCP sender reports, the SDP and `/api/status`, on random
/// bytes and on mutations of valid packets. Any input is `Ok` or an error
/// that says something; the RTP clock stays finite for any timestamps.
#[test]
fn neon_packet_decoders_never_panic() {
    use gazelight_neon::payload::{decode_eye_event, decode_gaze};
    use gazelight_neon::rtp::{RtpClock, RtpPacket, sender_reports};
    use gazelight_neon::{http, sdp};
    let mut r = TestRunner::new(config());
    r.run(&prop::collection::vec(any::<u8>(), 0..160), |b| {
        for e in [
            decode_gaze(&b).err(),
            decode_eye_event(&b).err(),
            RtpPacket::parse(&b).err(),
            sender_reports(&b).err(),
            http::parse_status(&b).err(),
            sdp::parse(&String::from_utf8_lossy(&b)).err(),
        ]
        .into_iter()
        .flatten()
        {
            prop_assert!(!e.to_string().is_empty());
        }
        Ok(())
    })
    .unwrap();
    // Mutations (flips, truncations, extensions) of an RTP packet carrying
    // an 89-byte eye-state gaze payload, and of a sender report.
    let mut rtp = vec![0x80, 99, 0, 1, 0, 0, 0x10, 0, 0, 0, 0, 7];
    rtp.extend((0..89u8).map(|i| i.wrapping_mul(37)));
    r.run(&mutated(rtp), |b| {
        if let Ok(p) = RtpPacket::parse(&b) {
            let _ = decode_gaze(p.payload);
        }
        Ok(())
    })
    .unwrap();
    let mut sr = vec![0x80, 200, 0, 6, 0, 0, 0, 7];
    sr.extend_from_slice(&[0xe9, 0x00, 0x00, 0x00, 0x80, 0, 0, 0]);
    sr.extend_from_slice(&[0, 0, 0x10, 0, 0, 0, 0, 1, 0, 0, 0, 89]);
    r.run(&mutated(sr), |b| {
        let _ = sender_reports(&b);
        Ok(())
    })
    .unwrap();
    r.run(
        &(
            1u32..200_000,
            prop::collection::vec(any::<u32>(), 1..64),
            any::<u32>(),
        ),
        |(rate, stamps, anchor)| {
            let mut clock = RtpClock::new(rate);
            for (i, ts) in stamps.iter().enumerate() {
                if i == 0 {
                    let reports = {
                        let mut p = vec![0x80, 200, 0, 6, 0, 0, 0, 7];
                        p.extend_from_slice(&0xe900_0000u32.to_be_bytes());
                        p.extend_from_slice(&0u32.to_be_bytes());
                        p.extend_from_slice(&anchor.to_be_bytes());
                        p.extend_from_slice(&[0; 8]);
                        sender_reports(&p).unwrap()
                    };
                    clock.apply(&reports[0]);
                }
                let t = clock.unix_secs(*ts).unwrap();
                prop_assert!(t.is_finite());
            }
            Ok(())
        },
    )
    .unwrap();
}
