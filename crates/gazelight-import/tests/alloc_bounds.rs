#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! Issue 48, class 2 (input size × amplification), counted: a global
//! allocator that keeps the peak of live heap bytes, and hostile inputs
//! written here, each read to its end (or its refusal) with the peak
//! checked against the bound its limits promise (docs/robustness.md). One
//! test in this binary, its cases in turn, so no other test's allocations
//! are counted.

use std::alloc::{GlobalAlloc, Layout, System};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

/// The system allocator, counting live bytes and their peak.
struct Peak;

static LIVE: AtomicUsize = AtomicUsize::new(0);
static PEAK: AtomicUsize = AtomicUsize::new(0);

// SAFETY: every call is forwarded unchanged to `System`; the counters are
// only read.
unsafe impl GlobalAlloc for Peak {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        // SAFETY: the caller's contract is `System`'s.
        let p = unsafe { System.alloc(layout) };
        if !p.is_null() {
            let now = LIVE.fetch_add(layout.size(), Ordering::Relaxed) + layout.size();
            PEAK.fetch_max(now, Ordering::Relaxed);
        }
        p
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: as above.
        unsafe { System.dealloc(ptr, layout) };
        LIVE.fetch_sub(layout.size(), Ordering::Relaxed);
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        // SAFETY: as above.
        let p = unsafe { System.realloc(ptr, layout, new_size) };
        if !p.is_null() {
            if new_size >= layout.size() {
                let grow = new_size - layout.size();
                let now = LIVE.fetch_add(grow, Ordering::Relaxed) + grow;
                PEAK.fetch_max(now, Ordering::Relaxed);
            } else {
                LIVE.fetch_sub(layout.size() - new_size, Ordering::Relaxed);
            }
        }
        p
    }
}

#[global_allocator]
static ALLOC: Peak = Peak;

const MIB: usize = 1 << 20;

/// The peak of live heap bytes above the start while `f` runs.
fn peak_of(f: impl FnOnce()) -> usize {
    let start = LIVE.load(Ordering::Relaxed);
    PEAK.store(start, Ordering::Relaxed);
    f();
    PEAK.load(Ordering::Relaxed).saturating_sub(start)
}

/// Reads a recording to its end (or its first error), counting samples.
fn read_all(path: &Path) -> (usize, Option<String>) {
    match gazelight_import::open(path) {
        Err(e) => (0, Some(e.to_string())),
        Ok(imp) => {
            let mut n = 0;
            for s in imp {
                match s {
                    Ok(_) => n += 1,
                    Err(e) => return (n, Some(e.to_string())),
                }
            }
            (n, None)
        }
    }
}

/// An XDF chunk: `[4][u32 length][tag u16][content]`.
fn chunk(out: &mut Vec<u8>, tag: u16, content: &[u8]) {
    out.push(4);
    out.extend_from_slice(&((content.len() + 2) as u32).to_le_bytes());
    out.extend_from_slice(&tag.to_le_bytes());
    out.extend_from_slice(content);
}

/// A stream header: stream id 1, `channels` channel entries listed in
/// `<desc>` (whatever `channel_count` says).
fn stream_header(channel_count: usize, listed: usize) -> Vec<u8> {
    let mut xml = format!(
        "<?xml version=\"1.0\"?><info><name>pupil</name><type>Gaze</type>\
         <channel_count>{channel_count}</channel_count><nominal_srate>100</nominal_srate>\
         <channel_format>double64</channel_format><desc><channels>"
    );
    for i in 0..listed {
        xml.push_str(&format!(
            "<channel><label>diameter{i}</label><unit>mm</unit></channel>"
        ));
    }
    xml.push_str("</channels></desc></info>");
    let mut c = 1u32.to_le_bytes().to_vec();
    c.extend_from_slice(xml.as_bytes());
    c
}

fn xdf_file(dir: &Path, name: &str, body: impl FnOnce(&mut Vec<u8>)) -> PathBuf {
    let mut out = b"XDF:".to_vec();
    chunk(
        &mut out,
        1,
        b"<?xml version=\"1.0\"?><info><version>1.0</version></info>",
    );
    body(&mut out);
    let p = dir.join(name);
    std::fs::write(&p, out).unwrap();
    p
}

#[test]
fn no_hostile_input_allocates_beyond_its_bound() {
    let dir = std::env::temp_dir().join(format!("gazelight-alloc-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut report = Vec::new();

    // 1. A stream header whose channel list (≈ 15 MiB, 250 000 entries,
    // inside MAX_XML_BYTES) is not capped by its own channel_count of 1:
    // its parsed form was ~26× its text. Bound: the text twice over and
    // the one declared channel (32 MiB).
    let listed = xdf_file(&dir, "channel_list.xdf", |out| {
        let h = stream_header(1, 250_000);
        assert!(
            h.len() > 14 * MIB && (h.len() as u64) < gazelight_import::xdf::reader::MAX_XML_BYTES
        );
        chunk(out, 2, &h);
    });
    let mut outcome = (0, None);
    let peak = peak_of(|| outcome = read_all(&listed));
    println!("channel list: {outcome:?}");
    report.push(("XDF channel list ≫ channel_count", peak, 32 * MIB));

    // 2. A samples chunk claiming 2^62 samples in 20 bytes. Bound: 1 MiB
    // (refused before anything is sized from the count).
    let claims = xdf_file(&dir, "claims.xdf", |out| {
        chunk(out, 2, &stream_header(1, 1));
        let mut c = 1u32.to_le_bytes().to_vec();
        c.push(8);
        c.extend_from_slice(&(1u64 << 62).to_le_bytes());
        c.extend_from_slice(&[0u8; 8]);
        chunk(out, 3, &c);
    });
    let mut claims_error = None;
    let peak = peak_of(|| claims_error = read_all(&claims).1);
    assert!(
        claims_error.is_some(),
        "a 2^62-sample chunk was read as valid"
    );
    report.push(("XDF sample count 2^62", peak, MIB));

    // 3. A gzip bomb of valid BIDS rows (≈ 200 MiB from a few hundred
    // KiB): refused at MAX_EXPANSION_RATIO × its size, streamed. Bound:
    // 16 MiB (buffers and the samples in flight, never the rows).
    let stem = "sub-01_task-x_recording-eye1";
    std::fs::write(
        dir.join(format!("{stem}_physio.json")),
        r#"{"PhysioType": "eyetrack", "RecordedEye": "right", "SamplingFrequency": 1000,
            "StartTime": 0, "Columns": ["timestamp", "x_coordinate", "y_coordinate", "pupil_size"],
            "timestamp": {"Units": "s"}, "pupil_size": {"Units": "mm"}}"#,
    )
    .unwrap();
    let row = b"1.0\t0.5\t0.5\t4.0\n";
    let mut rows = Vec::new();
    while rows.len() < MIB {
        rows.extend_from_slice(row);
    }
    let mut enc = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::best());
    enc.write_all(&rows).unwrap();
    let member = enc.finish().unwrap();
    let bomb = dir.join(format!("{stem}_physio.tsv.gz"));
    let mut f = std::fs::File::create(&bomb).unwrap();
    for _ in 0..200 {
        f.write_all(&member).unwrap();
    }
    drop(f);
    let mut outcome = (0, None);
    let peak = peak_of(|| outcome = read_all(&bomb));
    println!("gzip bomb: {outcome:?}");
    assert!(
        outcome.1.as_deref().is_some_and(|e| e.contains("expan")),
        "the bomb was not refused at its expansion cap: {outcome:?}"
    );
    report.push(("BIDS .tsv.gz bomb", peak, 16 * MIB));

    // 4. An EyeLink file whose one line is 32 MiB (a sample line
    // without a newline). Bound: 4 × MAX_LINE_BYTES plus buffers (2 MiB).
    let asc = dir.join("long_line.asc");
    let mut text = b"** CONVERTED FROM x.edf\nSAMPLES\tGAZE\tRIGHT\tRATE\t500.00\n1000\t".to_vec();
    text.resize(text.len() + 32 * MIB, b'7');
    std::fs::write(&asc, &text).unwrap();
    drop(text);
    let mut outcome = (0, None);
    let peak = peak_of(|| outcome = read_all(&asc));
    println!("long line: {outcome:?}");
    report.push(("EyeLink 32 MiB line", peak, 2 * MIB));

    // 5. A config of 900 KiB holding a 300 000-element array (within
    // MAX_CONFIG_BYTES, past MAX_CONFIG_VALUES): refused before a parser
    // builds it. Bound: the text and a copy (2 × 1 MiB).
    let toml = dir.join("big.toml");
    let mut t = String::from("x = [");
    while t.len() < 900 << 10 {
        t.push_str("1,");
    }
    t.push_str("1]\n");
    std::fs::write(&toml, t).unwrap();
    let mut refused = false;
    let peak = peak_of(|| {
        refused = gazelight_input::read_config(&toml, gazelight_input::ConfigSyntax::Toml).is_err();
    });
    assert!(refused, "a 300 000-value config was read");
    report.push(("config of 300 000 values", peak, 2 * MIB));

    for (case, peak, bound) in &report {
        println!(
            "{case}: peak {:.2} MiB (bound {:.0} MiB)",
            *peak as f64 / MIB as f64,
            *bound as f64 / MIB as f64
        );
    }
    for (case, peak, bound) in &report {
        assert!(
            peak <= bound,
            "{case}: {:.2} MiB live at its peak, over its bound of {:.0} MiB",
            *peak as f64 / MIB as f64,
            *bound as f64 / MIB as f64
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
