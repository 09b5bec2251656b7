//! Fair and bounded under abuse, against a real server on loopback: slow bodies on both
//! protocols, per-peer connection caps, the probe listener, session ownership and per-caller
//! quotas, and the smaller refusals (implied speeds, request ids, pipelined Interact actions).

mod common;

use std::convert::Infallible;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use common::*;
use futures::SinkExt;
use http_body_util::{BodyExt, StreamBody};
use hyper::body::{Bytes, Frame};
use prost::Message;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::{TcpSocket, TcpStream};

/// A bound for waits that must end; reaching it is a hang, not a slow machine.
const HANG: Duration = Duration::from_secs(60);

/// A TCP connection to `to` from the loopback address `from` (127.0.0.x: another peer).
async fn connect_from(from: [u8; 4], to: SocketAddr) -> TcpStream {
    let s = TcpSocket::new_v4().unwrap();
    s.bind(SocketAddr::from((from, 0))).unwrap();
    s.connect(to).await.unwrap()
}

/// Reads until the peer closes (or resets) the connection; `Err` if it is still open after
/// `within`.
async fn read_to_close(s: &mut TcpStream, within: Duration) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    let end = Instant::now() + within;
    loop {
        let left = end.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, s.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return Ok(out),
            Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
            Err(_) => return Err(format!("still open; read {} bytes", out.len())),
        }
    }
}

/// `GET path` from the loopback address `from`, the whole answer (empty when the server
/// closed the connection without one).
async fn get_from(from: [u8; 4], to: SocketAddr, path: &str) -> String {
    let mut s = connect_from(from, to).await;
    let req = format!("GET {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n");
    // A connection closed on accept may refuse the write too.
    let _ = s.write_all(req.as_bytes()).await;
    String::from_utf8_lossy(&read_to_close(&mut s, HANG).await.unwrap()).into_owned()
}

/// A POST whose body declares 100 000 bytes and sends one every 100 ms for as long as the
/// server reads; returns what the server answered and when.
async fn trickle(from: [u8; 4], to: SocketAddr) -> (String, Duration) {
    let mut s = connect_from(from, to).await;
    let start = Instant::now();
    s.write_all(
        b"POST /v1/rollout HTTP/1.1\r\nHost: x\r\ncontent-type: application/json\r\n\
          content-length: 100000\r\n\r\n{",
    )
    .await
    .unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 4096];
    loop {
        tokio::select! {
            r = s.read(&mut buf) => match r {
                Ok(0) | Err(_) => break,
                Ok(n) => got.extend_from_slice(&buf[..n]),
            },
            _ = tokio::time::sleep(Duration::from_millis(100)) => {
                if s.write_all(b" ").await.is_err() {
                    // Closed: read what came before the close.
                    let _ = tokio::time::timeout(Duration::from_secs(5), s.read_to_end(&mut got)).await;
                    break;
                }
            }
        }
        assert!(
            start.elapsed() < HANG,
            "the trickling body was never cut off"
        );
    }
    (String::from_utf8_lossy(&got).into_owned(), start.elapsed())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_loopback_slowloris_is_cut_off_while_probes_answer() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.connections.max_connections = 6;
        c.connections.max_connections_per_peer = 4;
        c.connections.body_deadline_s = 1.5;
        // The trickle never pauses long enough for the timeout between chunks.
        c.connections.body_read_timeout_s = 30.0;
        c.connections.health_addr = Some(SocketAddr::from(([127, 0, 0, 1], 0)));
    })
    .await;
    let http_addr = server.http_addr;
    let health = server.health_addr.expect("the probe listener is bound");

    // Four trickling bodies from 127.0.0.1, the per-peer cap.
    let tricklers: Vec<_> = (0..4)
        .map(|_| tokio::spawn(trickle([127, 0, 0, 1], http_addr)))
        .collect();
    tokio::time::sleep(Duration::from_millis(300)).await;
    // A fifth connection from the same peer is closed on accept, with no answer.
    let over = get_from([127, 0, 0, 1], http_addr, "/ready").await;
    assert!(over.is_empty(), "over the per-peer cap: {over}");
    // Another peer is served on the same listener.
    let ready = get_from([127, 0, 0, 2], http_addr, "/ready").await;
    assert!(ready.starts_with("HTTP/1.1 200"), "{ready}");
    // Two idle connections from a third peer fill the listener's global cap (6).
    let mut idle = Vec::new();
    for _ in 0..2 {
        let mut s = connect_from([127, 0, 0, 3], http_addr).await;
        s.write_all(b"GET /health HTTP/1.1\r\nHost: x\r\n")
            .await
            .unwrap();
        idle.push(s);
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let locked_out = get_from([127, 0, 0, 4], http_addr, "/ready").await;
    assert!(locked_out.is_empty(), "over the global cap: {locked_out}");
    // The probe listener answers whatever the API listener holds.
    for path in ["/ready", "/health", "/metrics"] {
        let probe = get_from([127, 0, 0, 4], health, path).await;
        assert!(probe.starts_with("HTTP/1.1 200"), "{path}: {probe}");
    }
    let not_api = get_from([127, 0, 0, 4], health, "/v1/models").await;
    assert!(not_api.starts_with("HTTP/1.1 404"), "{not_api}");

    // Every trickling body is cut off at the body deadline with 408 naming the flag.
    for t in tricklers {
        let (answer, after) = t.await.unwrap();
        assert!(answer.starts_with("HTTP/1.1 408"), "{answer}");
        assert!(answer.contains("--body-deadline-s"), "{answer}");
        assert!(after >= Duration::from_millis(1400), "cut after {after:?}");
    }
    drop(idle);
    // With the trickles gone, their peer is served again.
    let t = Instant::now();
    loop {
        let again = get_from([127, 0, 0, 1], http_addr, "/ready").await;
        if again.starts_with("HTTP/1.1 200") {
            break;
        }
        assert!(t.elapsed() < HANG, "the peer's slots never came back");
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    server.shutdown();
    server.wait().await.unwrap();
}

/// One gRPC message frame (uncompressed) of `payload`.
fn grpc_frame(payload: &[u8]) -> Vec<u8> {
    let mut b = vec![0u8];
    b.extend_from_slice(&(payload.len() as u32).to_be_bytes());
    b.extend_from_slice(payload);
    b
}

type BodyTx = futures::channel::mpsc::Sender<Result<Frame<Bytes>, Infallible>>;

/// A raw HTTP/2 gRPC call to `path` whose request body the test writes through the returned
/// sender, byte by byte if it likes; the response comes back on the handle.
async fn raw_grpc_call(
    addr: SocketAddr,
    path: &str,
) -> (
    BodyTx,
    tokio::task::JoinHandle<hyper::Result<hyper::Response<hyper::body::Incoming>>>,
) {
    let tcp = TcpStream::connect(addr).await.unwrap();
    let (mut send, conn) = hyper::client::conn::http2::handshake(
        hyper_util::rt::TokioExecutor::new(),
        hyper_util::rt::TokioIo::new(tcp),
    )
    .await
    .unwrap();
    tokio::spawn(conn);
    let (tx, rx) = futures::channel::mpsc::channel(64);
    let req = hyper::Request::post(format!("http://{addr}{path}"))
        .header("content-type", "application/grpc")
        .header("te", "trailers")
        .body(StreamBody::new(rx))
        .unwrap();
    let call = tokio::spawn(async move { send.send_request(req).await });
    (tx, call)
}

/// The grpc-status and grpc-message of a response: from its headers (trailers-only) or its
/// trailers, reading (and counting) the data frames before them.
async fn grpc_outcome(
    resp: hyper::Response<hyper::body::Incoming>,
) -> (Option<String>, String, usize) {
    let get = |h: &hyper::HeaderMap, k: &str| {
        h.get(k)
            .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
    };
    if let Some(code) = get(resp.headers(), "grpc-status") {
        let msg = get(resp.headers(), "grpc-message").unwrap_or_default();
        return (Some(code), msg, 0);
    }
    let mut body = resp.into_body();
    let mut data = 0;
    while let Some(f) = tokio::time::timeout(HANG, body.frame())
        .await
        .expect("the call never ended")
    {
        let f = f.unwrap();
        if let Some(d) = f.data_ref() {
            data += d.len();
        }
        if let Some(t) = f.trailers_ref() {
            let code = get(t, "grpc-status");
            let msg = get(t, "grpc-message").unwrap_or_default();
            return (code, msg, data);
        }
    }
    (None, String::new(), data)
}

fn percent_decoded(s: &str) -> String {
    s.replace("%20", " ")
        .replace("%2D", "-")
        .replace("%3A", ":")
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn grpc_messages_that_trickle_are_cut_off_but_interact_may_wait_between_messages() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.connections.body_deadline_s = 1.0;
        c.connections.body_read_timeout_s = 30.0;
    })
    .await;
    let addr = server.grpc_addr;

    // A unary call whose one message trickles in a byte every 100 ms.
    let (mut tx, call) = raw_grpc_call(addr, "/dynaserve.v1.WorldModel/Predict").await;
    let mut prefix = vec![0u8];
    prefix.extend_from_slice(&1000u32.to_be_bytes());
    tx.send(Ok(Frame::data(Bytes::from(prefix)))).await.unwrap();
    let start = Instant::now();
    let trickler = tokio::spawn(async move {
        while tx
            .send(Ok(Frame::data(Bytes::from_static(b"\x0a"))))
            .await
            .is_ok()
        {
            tokio::time::sleep(Duration::from_millis(100)).await;
            if start.elapsed() > HANG {
                break;
            }
        }
    });
    let resp = tokio::time::timeout(HANG, call)
        .await
        .expect("no answer")
        .unwrap()
        .unwrap();
    let (code, msg, _) = grpc_outcome(resp).await;
    assert_eq!(code.as_deref(), Some("3"), "INVALID_ARGUMENT: {msg}");
    let msg = percent_decoded(&msg);
    assert!(
        msg.starts_with("request: ") && msg.contains("--body-deadline-s"),
        "{msg}"
    );
    assert!(start.elapsed() >= Duration::from_millis(900));
    trickler.abort();

    // Interact: the wait between messages is the client's (twice the deadline here), but a
    // message that starts must be complete within the deadline.
    let scene = scene(61, 2, 32);
    let open = dynaserve_api::v1::InteractRequest {
        create: Some(dynaserve_api::v1::CreateSessionRequest {
            model: m.name.clone(),
            scene: Some(scene.to_proto()),
            dt_steps: 1,
            kinematic: vec![],
        }),
        ..Default::default()
    };
    let step = grpc_frame(&dynaserve_api::v1::InteractRequest::default().encode_to_vec());
    let (mut tx, call) = raw_grpc_call(addr, "/dynaserve.v1.Sessions/Interact").await;
    tx.send(Ok(Frame::data(Bytes::from(grpc_frame(
        &open.encode_to_vec(),
    )))))
    .await
    .unwrap();
    tx.send(Ok(Frame::data(Bytes::from(step.clone()))))
        .await
        .unwrap();
    let resp = tokio::time::timeout(HANG, call)
        .await
        .expect("no answer")
        .unwrap()
        .unwrap();
    assert_eq!(resp.status(), 200);
    assert!(resp.headers().get("grpc-status").is_none());
    let mut body = resp.into_body();
    let mut data = Vec::new();
    // The first frame.
    while data.len() < 5 {
        let f = tokio::time::timeout(HANG, body.frame())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        data.extend_from_slice(f.data_ref().expect("a frame, not the end"));
    }
    tokio::time::sleep(Duration::from_millis(2000)).await;
    // After the pause, a whole message is stepped as usual: its frame arrives.
    let before = data.len();
    tx.send(Ok(Frame::data(Bytes::from(step.clone()))))
        .await
        .unwrap();
    while data.len() < before + 5 {
        let f = tokio::time::timeout(HANG, body.frame())
            .await
            .unwrap()
            .unwrap()
            .unwrap();
        data.extend_from_slice(f.data_ref().expect("a second frame, not the end"));
    }
    // A message cut in half and left so: the stream ends with INVALID_ARGUMENT.
    tx.send(Ok(Frame::data(Bytes::from(step[..3].to_vec()))))
        .await
        .unwrap();
    let started = Instant::now();
    let (code, msg) = loop {
        let f = tokio::time::timeout(HANG, body.frame())
            .await
            .expect("the half message was never cut off")
            .expect("the stream ended without trailers")
            .unwrap();
        if let Some(t) = f.trailers_ref() {
            let get = |k| {
                t.get(k)
                    .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
                    .unwrap_or_default()
            };
            break (get("grpc-status"), percent_decoded(&get("grpc-message")));
        }
    };
    assert_eq!(code, "3", "INVALID_ARGUMENT: {msg}");
    assert!(msg.contains("--body-deadline-s"), "{msg}");
    assert!(started.elapsed() >= Duration::from_millis(900));
    drop(tx);
    server.shutdown();
    server.wait().await.unwrap();
}
