//! A listener for the status server that holds at most
//! [`MAX_CONNECTIONS`] connections open at once.
//!
//! Each accepted connection holds a semaphore permit for as long as its
//! socket lives (an HTTP keep-alive or a WebSocket included). At the cap
//! the server stops accepting: further clients wait in the kernel's listen
//! backlog and cost the process no descriptor, so idle or hostile clients
//! can never take the descriptors the session's writers need (frames,
//! `timeline.csv`, `psf.csv`). With `ulimit -n 1024` that leaves more than
//! 700 descriptors to the rest of the process. Accept errors (a descriptor
//! limit reached elsewhere, an aborted handshake) are logged once per
//! episode and retried after a short pause, never ended on.

use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};
use tokio::net::{TcpListener, TcpStream};
use tokio::sync::{OwnedSemaphorePermit, Semaphore};

/// Most connections the status server holds open at once.
pub const MAX_CONNECTIONS: usize = 256;

/// Pause after an accept error before trying again.
const ACCEPT_RETRY: Duration = Duration::from_millis(50);

/// [`TcpListener`] with a cap on open connections.
pub struct CappedListener {
    inner: TcpListener,
    permits: Arc<Semaphore>,
    at_cap_logged: bool,
    error_logged: bool,
}

impl CappedListener {
    /// Wraps `inner` with a cap of `max` open connections.
    pub fn new(inner: TcpListener, max: usize) -> Self {
        Self {
            inner,
            permits: Arc::new(Semaphore::new(max.max(1))),
            at_cap_logged: false,
            error_logged: false,
        }
    }
}

/// An accepted connection; its permit is released when it is dropped.
pub struct CappedStream {
    stream: TcpStream,
    _permit: OwnedSemaphorePermit,
}

impl axum::serve::Listener for CappedListener {
    type Io = CappedStream;
    type Addr = std::net::SocketAddr;

    async fn accept(&mut self) -> (Self::Io, Self::Addr) {
        loop {
            let permit = match self.permits.clone().try_acquire_owned() {
                Ok(p) => {
                    self.at_cap_logged = false;
                    p
                }
                Err(_) => {
                    if !self.at_cap_logged {
                        self.at_cap_logged = true;
                        tracing::warn!(
                            max = MAX_CONNECTIONS,
                            "status server: connection cap reached; new clients wait"
                        );
                    }
                    match self.permits.clone().acquire_owned().await {
                        Ok(p) => p,
                        // The semaphore is never closed; do not spin if it were.
                        Err(_) => std::future::pending().await,
                    }
                }
            };
            match self.inner.accept().await {
                Ok((stream, addr)) => {
                    self.error_logged = false;
                    let _ = stream.set_nodelay(true);
                    return (
                        CappedStream {
                            stream,
                            _permit: permit,
                        },
                        addr,
                    );
                }
                Err(e) => {
                    if !self.error_logged {
                        self.error_logged = true;
                        tracing::warn!(error = %e, "status server: accept failed; retrying");
                    }
                    drop(permit);
                    tokio::time::sleep(ACCEPT_RETRY).await;
                }
            }
        }
    }

    fn local_addr(&self) -> std::io::Result<Self::Addr> {
        self.inner.local_addr()
    }
}

impl AsyncRead for CappedStream {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_read(cx, buf)
    }
}

impl AsyncWrite for CappedStream {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write(cx, buf)
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<std::io::Result<()>> {
        Pin::new(&mut self.stream).poll_shutdown(cx)
    }

    fn poll_write_vectored(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        bufs: &[std::io::IoSlice<'_>],
    ) -> Poll<std::io::Result<usize>> {
        Pin::new(&mut self.stream).poll_write_vectored(cx, bufs)
    }

    fn is_write_vectored(&self) -> bool {
        self.stream.is_write_vectored()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use axum::serve::Listener;

    #[tokio::test]
    async fn holds_at_most_the_cap_then_accepts_when_one_closes() {
        let inner = TcpListener::bind("127.0.0.1:0").await.unwrap();
        let addr = inner.local_addr().unwrap();
        let mut l = CappedListener::new(inner, 2);
        let c1 = TcpStream::connect(addr).await.unwrap();
        let _c2 = TcpStream::connect(addr).await.unwrap();
        let _c3 = TcpStream::connect(addr).await.unwrap();
        let a1 = l.accept().await;
        let _a2 = l.accept().await;
        // The third waits in the backlog while two are open.
        assert!(
            tokio::time::timeout(Duration::from_millis(300), l.accept())
                .await
                .is_err(),
            "a third connection was accepted over a cap of 2"
        );
        drop(a1);
        drop(c1);
        let third = tokio::time::timeout(Duration::from_secs(5), l.accept()).await;
        assert!(third.is_ok(), "a freed permit lets the next client in");
    }
}
