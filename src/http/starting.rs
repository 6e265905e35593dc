//! The HTTP port before the service runs (a client waiting for its Zenoh router): every
//! request gets `503 Service Unavailable` with the reason, so a browser, a load balancer
//! or a container's HEALTHCHECK learns "starting", not "dead".
//!
//! It runs on a thread of its own with its own single-threaded runtime, never on a
//! worker of the service's runtime: whatever holds those workers while the service
//! starts (Zenoh's open blocks the thread it runs on) cannot starve it. Each connection
//! is answered in full: the request is read to its blank line before the answer is
//! written, the write side is shut, and what the client still sends is drained until it
//! closes, so the kernel never resets a connection whose answer the client has not read
//! ("Broken pipe" / "Connection reset" on the client's side).

use std::time::Duration;
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// How long a client may take to send its request head.
const READ_REQUEST_TIMEOUT: Duration = Duration::from_secs(5);
/// How long a client may keep the connection after its answer was written.
const DRAIN_TIMEOUT: Duration = Duration::from_secs(2);
/// How long connections being answered may delay the service's start or stop.
const FINISH_TIMEOUT: Duration = Duration::from_secs(1);
/// A request head larger than this is answered without reading the rest.
const MAX_REQUEST_HEAD: usize = 16 * 1024;

/// The responder while it runs; [`StartingResponder::finish`] gives the listener back.
pub struct StartingResponder {
    stop: Option<tokio::sync::oneshot::Sender<()>>,
    thread: std::thread::JoinHandle<std::io::Result<std::net::TcpListener>>,
}

impl StartingResponder {
    /// Answers every request on `listener` with 503 and `reason` until `finish`.
    pub fn start(
        listener: tokio::net::TcpListener,
        reason: String,
    ) -> std::io::Result<StartingResponder> {
        let listener = listener.into_std()?;
        let (stop, stopped) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name("http-starting".into())
            .spawn(move || {
                let rt = tokio::runtime::Builder::new_current_thread()
                    .enable_io()
                    .enable_time()
                    .build()?;
                rt.block_on(answer_until(listener, reason, stopped))
            })?;
        Ok(StartingResponder {
            stop: Some(stop),
            thread,
        })
    }

    /// Stops answering (connections being answered are finished first) and returns the
    /// listener, registered with the caller's runtime.
    pub async fn finish(mut self) -> std::io::Result<tokio::net::TcpListener> {
        if let Some(stop) = self.stop.take() {
            let _ = stop.send(());
        }
        let thread = self.thread;
        let listener = tokio::task::spawn_blocking(move || thread.join())
            .await
            .map_err(std::io::Error::other)?
            .map_err(|_| std::io::Error::other("the starting HTTP responder panicked"))??;
        tokio::net::TcpListener::from_std(listener)
    }
}

/// The answer to every request: 503 and why.
fn answer_text(reason: &str) -> String {
    format!(
        "HTTP/1.1 503 Service Unavailable\r\nContent-Type: text/plain; charset=utf-8\r\nContent-Length: {}\r\nConnection: close\r\nRetry-After: 1\r\n\r\n{reason}",
        reason.len()
    )
}

async fn answer_until(
    listener: std::net::TcpListener,
    reason: String,
    mut stop: tokio::sync::oneshot::Receiver<()>,
) -> std::io::Result<std::net::TcpListener> {
    listener.set_nonblocking(true)?;
    let listener = tokio::net::TcpListener::from_std(listener)?;
    let answer: std::sync::Arc<[u8]> = answer_text(&reason).into_bytes().into();
    let mut answering = tokio::task::JoinSet::new();
    loop {
        tokio::select! {
            _ = &mut stop => break,
            accepted = listener.accept() => {
                // A failed accept (a connection reset before it was taken, no file
                // descriptors for a moment) costs that connection only.
                let Ok((conn, _)) = accepted else { continue };
                answering.spawn(answer_one(conn, answer.clone()));
            }
            // Reap finished connections as they go.
            Some(_) = answering.join_next(), if !answering.is_empty() => {}
        }
    }
    // Connections already taken get their answer before the service takes over (or
    // the process stops), within a bound: a client that sends nothing holds no one up.
    let _ = tokio::time::timeout(FINISH_TIMEOUT, async {
        while answering.join_next().await.is_some() {}
    })
    .await;
    listener.into_std()
}

/// Read the request head, answer, shut the write side, drain until the client closes.
async fn answer_one(mut conn: tokio::net::TcpStream, answer: std::sync::Arc<[u8]>) {
    let mut head = Vec::with_capacity(1024);
    let mut buf = [0u8; 2048];
    let _ = tokio::time::timeout(READ_REQUEST_TIMEOUT, async {
        loop {
            match conn.read(&mut buf).await {
                Ok(0) | Err(_) => break,
                Ok(n) => {
                    head.extend_from_slice(&buf[..n]);
                    if head_complete(&head) || head.len() >= MAX_REQUEST_HEAD {
                        break;
                    }
                }
            }
        }
    })
    .await;
    if conn.write_all(&answer).await.is_err() {
        return;
    }
    let _ = conn.shutdown().await;
    let _ = tokio::time::timeout(DRAIN_TIMEOUT, async {
        while let Ok(n) = conn.read(&mut buf).await {
            if n == 0 {
                break;
            }
        }
    })
    .await;
}

/// The request head has ended (a blank line).
fn head_complete(head: &[u8]) -> bool {
    head.windows(4).any(|w| w == b"\r\n\r\n") || head.windows(2).any(|w| w == b"\n\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::{Read, Write};

    #[test]
    fn the_head_ends_at_a_blank_line() {
        assert!(!head_complete(b"GET / HTTP/1.1\r\nHost: x\r\n"));
        assert!(head_complete(b"GET / HTTP/1.1\r\nHost: x\r\n\r\n"));
        assert!(head_complete(b"GET / HTTP/1.0\n\n"));
    }

    /// Every request is answered in full, including one sent in pieces after a pause
    /// and while the runtime that started the responder has every worker blocked.
    #[test]
    fn answers_every_request_while_the_runtime_is_blocked() {
        let rt = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(1)
            .enable_all()
            .build()
            .expect("runtime");
        let listener = rt
            .block_on(tokio::net::TcpListener::bind("127.0.0.1:0"))
            .expect("bind");
        let addr = listener.local_addr().expect("addr");
        let _guard = rt.enter();
        let responder =
            StartingResponder::start(listener, "starting: waiting\n".into()).expect("start");
        // The only worker is held, as a blocking open would hold it.
        let (release, held) = std::sync::mpsc::channel::<()>();
        rt.spawn(async move {
            let _ = held.recv();
        });
        for slow in [false, true, false] {
            let mut c = std::net::TcpStream::connect(addr).expect("connect");
            c.set_read_timeout(Some(Duration::from_secs(10))).ok();
            if slow {
                c.write_all(b"GET /healthz HTTP/1.1\r\n").expect("write");
                std::thread::sleep(Duration::from_millis(400));
                c.write_all(b"Host: x\r\n\r\n").expect("write the rest");
            } else {
                c.write_all(b"GET /healthz HTTP/1.0\r\nHost: x\r\n\r\n")
                    .expect("write");
            }
            let mut answer = String::new();
            c.read_to_string(&mut answer).expect("read the answer");
            assert!(answer.starts_with("HTTP/1.1 503 "), "{answer}");
            assert!(answer.ends_with("starting: waiting\n"), "{answer}");
        }
        release.send(()).ok();
        let listener = rt.block_on(responder.finish()).expect("listener back");
        assert_eq!(listener.local_addr().expect("addr"), addr);
    }
}
