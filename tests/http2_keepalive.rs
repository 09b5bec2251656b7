//! Idle HTTP/2 (gRPC) connections against a real server on 127.0.0.1: the server pings them
//! every `--http2-keepalive-interval-s`; a client that answers keeps its connection however long
//! it idles, a peer that does not answer is closed after `--http2-keepalive-timeout-s`, and
//! without pings such a peer stays connected.

mod common;

use std::time::{Duration, Instant};

use common::*;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// A bound for waits that must end; reaching it is a hang, not a slow machine.
const HANG: Duration = Duration::from_secs(60);

/// The HTTP/2 client preface, an empty SETTINGS frame, and `GET /` on stream 1 (HPACK:
/// `:method GET`, `:scheme http`, `:path /` from the static table, `:authority x` literal).
fn preface_and_one_request() -> Vec<u8> {
    let mut b = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n".to_vec();
    b.extend_from_slice(&[0, 0, 0, 4, 0, 0, 0, 0, 0]);
    let block = [0x82, 0x86, 0x84, 0x41, 0x01, b'x'];
    // HEADERS, END_STREAM | END_HEADERS, stream 1.
    b.extend_from_slice(&[0, 0, block.len() as u8, 1, 0x05, 0, 0, 0, 1]);
    b.extend_from_slice(&block);
    b
}

/// Frame types of a byte stream of HTTP/2 frames (with their flags), as far as it parses.
fn frames(bytes: &[u8]) -> Vec<(u8, u8)> {
    let mut out = Vec::new();
    let mut at = 0;
    while at + 9 <= bytes.len() {
        let len = (usize::from(bytes[at]) << 16)
            | (usize::from(bytes[at + 1]) << 8)
            | usize::from(bytes[at + 2]);
        out.push((bytes[at + 3], bytes[at + 4]));
        at += 9 + len;
    }
    out
}

const PING: u8 = 6;
const GOAWAY: u8 = 7;

/// Reads what the server sends until it closes the connection (`Ok`) or `within` passes
/// (`Err` with what was read).
async fn read_until_closed(s: &mut TcpStream, within: Duration) -> Result<Vec<u8>, Vec<u8>> {
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    let end = Instant::now() + within;
    loop {
        let left = end.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, s.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return Ok(out),
            Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
            Err(_) => return Err(out),
        }
    }
}

fn open_grpc(text: &str) -> f64 {
    sample(text, "dynaserve_open_connections{listener=\"grpc\"}").unwrap_or(f64::NAN)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn idle_http2_connections_are_kept_by_answered_pings_and_closed_without_answers() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.connections.http2_keepalive_interval_s = 0.3;
        c.connections.http2_keepalive_timeout_s = 0.5;
    })
    .await;

    // A gRPC client answers pings (its HTTP/2 stack does): after idling for many ping
    // intervals its connection is still the one open connection and serves again.
    let mut c = client(&server).await;
    c.list_models().await.unwrap();
    assert_eq!(open_grpc(&metrics(&server).await), 1.0);
    tokio::time::sleep(Duration::from_secs(3)).await;
    assert_eq!(open_grpc(&metrics(&server).await), 1.0);
    c.list_models().await.unwrap();
    assert_eq!(open_grpc(&metrics(&server).await), 1.0);

    // A peer that sends one request and then never answers: pinged, then closed.
    let mut s = TcpStream::connect(server.grpc_addr).await.unwrap();
    s.write_all(&preface_and_one_request()).await.unwrap();
    let got = read_until_closed(&mut s, HANG)
        .await
        .unwrap_or_else(|b| panic!("still open after {HANG:?}: frames {:?}", frames(&b)));
    let f = frames(&got);
    assert!(
        f.iter().any(|&(t, flags)| t == PING && flags & 1 == 0),
        "no ping before the close: {f:?}"
    );
    assert!(
        f.iter().any(|&(t, _)| t == GOAWAY),
        "closed without GOAWAY: {f:?}"
    );
    // The answering client was not affected.
    c.list_models().await.unwrap();
    server.shutdown();
    server.wait().await.unwrap();

    // Without pings the same silent peer stays connected (until the server stops).
    let server = start(&m.dir, |c| c.connections.http2_keepalive_interval_s = 0.0).await;
    let mut s = TcpStream::connect(server.grpc_addr).await.unwrap();
    s.write_all(&preface_and_one_request()).await.unwrap();
    let got = read_until_closed(&mut s, Duration::from_secs(3))
        .await
        .expect_err("closed though no ping is sent");
    let f = frames(&got);
    assert!(
        !f.iter().any(|&(t, _)| t == PING),
        "a ping though disabled: {f:?}"
    );
    drop(s);
    server.shutdown();
    server.wait().await.unwrap();
}
