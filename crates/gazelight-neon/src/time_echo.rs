//! The Time Echo protocol of the Neon Real-time API: the offset between
//! the phone's clock and this host's, measured directly instead of trusting
//! both to follow NTP.
//!
//! The Companion app serves it on the TCP port its `/api/status` names
//! (`Phone.time_echo_port`). The client sends its time `t1` (ms since the
//! Unix epoch, u64, network byte order); the phone answers `t1` and its own
//! time `tH` (two u64); the client notes `t2` on receipt. Assuming the
//! transport is symmetric, `offset_ms = (t1 + t2) / 2 − tH`: phone time +
//! offset = host time. [`estimate_offset`] takes the median of several
//! echoes.

use std::time::{Duration, SystemTime, UNIX_EPOCH};

use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

use crate::NeonError;

/// The median of a run of echoes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TimeEchoEstimate {
    /// Host clock − phone clock, ms (median): phone time + this = host time.
    pub offset_ms: f64,
    /// Round trip, ms (median).
    pub roundtrip_ms: f64,
    /// Echoes measured.
    pub echoes: usize,
}

fn unix_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| d.as_millis() as u64)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    match v.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => v[n / 2],
        n => 0.5 * (v[n / 2 - 1] + v[n / 2]),
    }
}

/// Measures `echoes` time echoes against `host:port` (each within
/// `io_timeout`) and returns their medians. An echo that does not return
/// `t1` is a protocol error naming the address.
pub async fn estimate_offset(
    host: &str,
    port: u16,
    echoes: usize,
    io_timeout: Duration,
) -> Result<TimeEchoEstimate, NeonError> {
    let addr = if host.contains(':') {
        format!("[{host}]:{port}")
    } else {
        format!("{host}:{port}")
    };
    let what = format!("Time Echo at {addr}");
    let io = |e: std::io::Error| NeonError::Io {
        what: what.clone(),
        error: e.to_string(),
    };
    let timed_out = || NeonError::Io {
        what: what.clone(),
        error: format!("no answer within {io_timeout:?}"),
    };
    let mut s = tokio::time::timeout(io_timeout, TcpStream::connect(&addr))
        .await
        .map_err(|_| timed_out())?
        .map_err(io)?;
    let _ = s.set_nodelay(true);
    let mut offsets = Vec::with_capacity(echoes);
    let mut roundtrips = Vec::with_capacity(echoes);
    for _ in 0..echoes.max(1) {
        let t1 = unix_ms();
        let mut reply = [0u8; 16];
        let exchange = async {
            s.write_all(&t1.to_be_bytes()).await?;
            s.read_exact(&mut reply).await?;
            Ok::<(), std::io::Error>(())
        };
        tokio::time::timeout(io_timeout, exchange)
            .await
            .map_err(|_| timed_out())?
            .map_err(io)?;
        let t2 = unix_ms();
        let (echo, th) = reply.split_at(8);
        let echo = u64::from_be_bytes(echo.try_into().unwrap_or([0; 8]));
        let th = u64::from_be_bytes(th.try_into().unwrap_or([0; 8]));
        if echo != t1 {
            return Err(NeonError::Status {
                reason: format!("{what}: the echo carries {echo}, not the {t1} sent"),
            });
        }
        offsets.push((t1 as f64 + t2 as f64) / 2.0 - th as f64);
        roundtrips.push(t2.saturating_sub(t1) as f64);
    }
    Ok(TimeEchoEstimate {
        offset_ms: median(&mut offsets),
        roundtrip_ms: median(&mut roundtrips),
        echoes: offsets.len(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::net::TcpListener;

    /// A Time Echo server on 127.0.0.1 answering each 8-byte request with
    /// `answer(request)`; returns its port.
    async fn phone(answer: fn([u8; 8]) -> [u8; 16]) -> u16 {
        let listener = TcpListener::bind("127.0.0.1:0")
            .await
            .unwrap_or_else(|e| panic!("{e}"));
        let port = listener.local_addr().map(|a| a.port()).unwrap_or(0);
        tokio::spawn(async move {
            let Ok((mut c, _)) = listener.accept().await else {
                return;
            };
            let mut t1 = [0u8; 8];
            while c.read_exact(&mut t1).await.is_ok() {
                if c.write_all(&answer(t1)).await.is_err() {
                    return;
                }
            }
        });
        port
    }

    /// A phone whose clock runs 1500 ms behind this host's: the estimate
    /// says +1500 ms (within the protocol's 1 ms resolution and the round
    /// trip); a wrong echo is an error.
    #[tokio::test]
    async fn offset_of_a_phone_behind_by_1500_ms() {
        let port = phone(|t1| {
            let mut out = [0u8; 16];
            out[..8].copy_from_slice(&t1);
            out[8..].copy_from_slice(&(unix_ms() - 1500).to_be_bytes());
            out
        })
        .await;
        let e = estimate_offset("127.0.0.1", port, 10, Duration::from_secs(2))
            .await
            .unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(e.echoes, 10);
        assert!(
            (e.offset_ms - 1500.0).abs() <= 1.0 + e.roundtrip_ms,
            "{e:?}"
        );

        let port = phone(|_| [7u8; 16]).await;
        let err = estimate_offset("127.0.0.1", port, 3, Duration::from_secs(2))
            .await
            .expect_err("a wrong echo");
        assert!(err.to_string().contains("Time Echo"), "{err}");
    }
}
