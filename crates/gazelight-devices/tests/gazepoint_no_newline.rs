#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup
//! A Gazepoint-like server on 127.0.0.1 that sends 100 MB without a
//! newline, once in place of the handshake's ACK and once after it in
//! place of the records. The client must stop at its 8 KiB line limit
//! while reading: a clear error (the connection dropped, the reason
//! naming the missing newline), within the time limits, with the
//! process's resident memory (VmRSS, sampled every 2 ms) less than
//! [`RSS_BOUND_BYTES`] above where it started. The unbounded
//! `read_line` this replaces kept the whole line: +100 MB or more.

use std::io::{BufRead, BufReader, Write};
use std::net::TcpListener;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use gazelight_devices::gazepoint::{GazepointSource, GazepointTimeouts, MAX_LINE_BYTES};
use gazelight_eye::{SampleSource, SourceError};

/// What the server sends without a newline.
const FLOOD_BYTES: usize = 100 << 20;
/// Allowed growth of the resident set: the line limit is 8 KiB; the
/// socket's and the reader's buffers are tens of KiB.
const RSS_BOUND_BYTES: u64 = 16 << 20;

fn vm_rss_bytes() -> u64 {
    let status = std::fs::read_to_string("/proc/self/status").unwrap();
    let kib: u64 = status
        .lines()
        .find(|l| l.starts_with("VmRSS:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .expect("VmRSS in /proc/self/status");
    kib * 1024
}

/// When the flood starts.
#[derive(Clone, Copy, Debug, PartialEq)]
enum When {
    /// The first SET gets no ACK, only the flood.
    InsteadOfAck,
    /// Every SET is acknowledged, then the flood comes instead of records.
    AfterHandshake,
}

/// Serves one connection; returns the bytes of the flood written before
/// the client closed.
fn flood_server(when: When) -> (u16, std::thread::JoinHandle<usize>) {
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let t = std::thread::spawn(move || {
        let (s, _) = listener.accept().unwrap();
        s.set_write_timeout(Some(Duration::from_secs(10))).unwrap();
        let mut reader = BufReader::new(s.try_clone().unwrap());
        let mut w = s;
        if when == When::AfterHandshake {
            loop {
                let mut line = String::new();
                if reader.read_line(&mut line).unwrap() == 0 {
                    return 0;
                }
                let id = line.split('"').nth(1).unwrap_or("").to_owned();
                write!(w, "<ACK ID=\"{id}\" STATE=\"1\" />\r\n").unwrap();
                if id == "ENABLE_SEND_DATA" {
                    break;
                }
            }
        }
        let chunk = vec![b'x'; 64 << 10];
        let mut sent = 0;
        while sent < FLOOD_BYTES {
            match w.write(&chunk) {
                Ok(0) | Err(_) => break,
                Ok(n) => sent += n,
            }
        }
        // Keep the connection open: the client must not wait for an end.
        std::thread::sleep(Duration::from_secs(3));
        sent
    });
    (port, t)
}

async fn flood(when: When) {
    let (port, server) = flood_server(when);
    let start = vm_rss_bytes();
    let peak = Arc::new(AtomicU64::new(start));
    let stop = Arc::new(AtomicBool::new(false));
    let sampler = {
        let (peak, stop) = (peak.clone(), stop.clone());
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                peak.fetch_max(vm_rss_bytes(), Ordering::Relaxed);
                std::thread::sleep(Duration::from_millis(2));
            }
        })
    };
    let mut src = GazepointSource::with_timeouts(
        "127.0.0.1",
        port,
        GazepointTimeouts {
            connect: Duration::from_secs(2),
            ack: Duration::from_secs(2),
            idle: Duration::from_secs(2),
        },
    );
    let t0 = Instant::now();
    let r = tokio::time::timeout(Duration::from_secs(10), src.next())
        .await
        .expect("the source answers within 10 s");
    let took = t0.elapsed();
    drop(src);
    stop.store(true, Ordering::Relaxed);
    sampler.join().unwrap();
    let grew = peak.load(Ordering::Relaxed).saturating_sub(start);
    let sent = server.join().unwrap();
    eprintln!(
        "{when:?}: {r:?} after {took:?}; server wrote {sent} bytes; VmRSS peak +{grew} bytes"
    );
    match r {
        Err(SourceError::Disconnected { reason, .. }) => {
            assert!(
                reason.contains("without a newline")
                    && reason.contains(&MAX_LINE_BYTES.to_string()),
                "{when:?}: a clear reason: {reason}"
            );
        }
        other => panic!("{when:?}: expected the connection dropped, got {other:?}"),
    }
    // Before the idle and ACK limits (2 s, set above) could have ended the
    // read: the line limit did. The bound is those configured timeouts,
    // not a guess at how fast a loaded machine reads the flood.
    assert!(took < Duration::from_secs(2), "{when:?}: took {took:?}");
    assert!(grew < RSS_BOUND_BYTES, "{when:?}: VmRSS grew {grew} bytes");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_server_without_newlines_is_dropped_at_the_line_limit() {
    // One after the other: the resident set is the process's.
    flood(When::InsteadOfAck).await;
    flood(When::AfterHandshake).await;
}
