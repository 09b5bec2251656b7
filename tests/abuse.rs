//! Fair and bounded under abuse, against a real server on loopback: slow bodies on both
//! protocols, per-peer connection caps, the probe listener, session ownership and per-caller
//! quotas, and the smaller refusals (implied speeds, request ids, pipelined Interact actions).

mod common;

use std::convert::Infallible;
use std::net::SocketAddr;
use std::time::{Duration, Instant};

use common::*;
use futures::{SinkExt, StreamExt};
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

/// The grpc-status and grpc-message of the trailers ending `body`.
async fn grpc_outcome_of_body(mut body: hyper::body::Incoming) -> (Option<String>, String, usize) {
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
            let get = |k: &str| {
                t.get(k)
                    .map(|v| String::from_utf8_lossy(v.as_bytes()).into_owned())
            };
            return (
                get("grpc-status"),
                get("grpc-message").unwrap_or_default(),
                data,
            );
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
            shared: false,
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

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn thousands_of_pipelined_interact_actions_all_get_their_frame() {
    // A tiny random model: the point is the transport, not the physics.
    let m = random_model("rigidformer-pipeline", 3);
    let server = start(&m.dir, |_| {}).await;
    const N: usize = 5000;
    let open = dynaserve_api::v1::InteractRequest {
        create: Some(dynaserve_api::v1::CreateSessionRequest {
            model: m.name.clone(),
            scene: Some(scene(71, 1, 16).to_proto()),
            dt_steps: 1,
            // Held still (the random model would let a free object drift out of its domain
            // over thousands of steps); every step still runs through the model.
            kinematic: vec![0],
            shared: false,
        }),
        ..Default::default()
    };
    let (mut tx, call) = raw_grpc_call(server.grpc_addr, "/dynaserve.v1.Sessions/Interact").await;
    tx.send(Ok(Frame::data(Bytes::from(grpc_frame(
        &open.encode_to_vec(),
    )))))
    .await
    .unwrap();
    // Every action in a DATA frame of its own, all sent before the first frame is read: the
    // server must hold them back (flow control), not drop the connection.
    let step = Bytes::from(grpc_frame(
        &dynaserve_api::v1::InteractRequest::default().encode_to_vec(),
    ));
    let sender = tokio::spawn(async move {
        for _ in 0..N {
            tx.send(Ok(Frame::data(step.clone()))).await.unwrap();
        }
        tx
    });
    let resp = tokio::time::timeout(HANG, call)
        .await
        .expect("no answer")
        .unwrap()
        .unwrap();
    assert!(resp.headers().get("grpc-status").is_none());
    let mut body = resp.into_body();
    let mut bytes = Vec::new();
    let mut frames = 0;
    while frames < N {
        let f = tokio::time::timeout(HANG, body.frame())
            .await
            .expect("a frame never came")
            .unwrap_or_else(|| panic!("the stream ended after {frames} frames"))
            .unwrap_or_else(|e| panic!("after {frames} frames: {e:?}"));
        if let Some(t) = f.trailers_ref() {
            panic!("the stream ended after {frames} frames: {t:?}");
        }
        bytes.extend_from_slice(f.data_ref().unwrap());
        // Count whole gRPC messages.
        while bytes.len() >= 5 {
            let len = u32::from_be_bytes([bytes[1], bytes[2], bytes[3], bytes[4]]) as usize;
            if bytes.len() < 5 + len {
                break;
            }
            let msg = dynaserve_api::v1::StepFrame::decode(&bytes[5..5 + len]).unwrap();
            frames += 1;
            assert_eq!(msg.step as usize, frames);
            bytes.drain(..5 + len);
        }
    }
    drop(sender.await.unwrap());
    let (code, msg, _) = grpc_outcome_of_body(body).await;
    assert_eq!(code.as_deref(), Some("0"), "{msg}");
    server.shutdown();
    server.wait().await.unwrap();
}

const TOKEN_A: &str = "caller-a-token-0123456789";
const TOKEN_B: &str = "caller-b-token-0123456789";

fn bearer(token: &str) -> String {
    format!("Bearer {token}")
}

/// `method path` as the caller of `token` (JSON body when given).
async fn as_caller(
    addr: SocketAddr,
    token: &str,
    method: &str,
    path: &str,
    body: Option<serde_json::Value>,
) -> HttpResponse {
    let auth = bearer(token);
    let b = body.map(|v| serde_json::to_vec(&v).unwrap());
    http(
        addr,
        method,
        path,
        &[("authorization", &auth)],
        b.as_deref(),
    )
    .await
}

fn create_body(model: &str, seed: u64, shared: bool) -> serde_json::Value {
    serde_json::json!({
        "model": model,
        "scene": scene(seed, 2, 32),
        "shared": shared,
    })
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sessions_belong_to_their_caller_and_others_get_not_found() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.security.auth_tokens = vec![TOKEN_A.into(), TOKEN_B.into()];
    })
    .await;
    let addr = server.http_addr;
    let created = as_caller(
        addr,
        TOKEN_A,
        "POST",
        "/v1/sessions",
        Some(create_body(&m.name, 81, false)),
    )
    .await;
    assert_eq!(created.status, 201, "{}", created.text());
    let info: dynaserve_api::json::SessionInfo = created.json();
    assert!(!info.shared);
    let id = info.session_id;
    let base = format!("/v1/sessions/{id}");

    // Its owner uses it.
    let own = as_caller(addr, TOKEN_A, "GET", &base, None).await;
    assert_eq!(own.status, 200, "{}", own.text());
    // For the other caller it does not exist, whatever the call.
    let other_calls: Vec<(&str, String, Option<serde_json::Value>)> = vec![
        ("GET", base.clone(), None),
        (
            "PUT",
            format!("{base}/state"),
            Some(serde_json::json!({"objects": []})),
        ),
        (
            "POST",
            format!("{base}/step"),
            Some(serde_json::json!({"steps": 1})),
        ),
        ("POST", format!("{base}/fork"), None),
        (
            "POST",
            format!("{base}/predict"),
            Some(serde_json::json!({"variants": [{}], "steps": 1})),
        ),
        ("DELETE", base.clone(), None),
    ];
    for (method, path, body) in other_calls {
        let r = as_caller(addr, TOKEN_B, method, &path, body).await;
        assert_eq!(r.status, 404, "{method} {path}: {}", r.text());
        let e: dynaserve_api::json::ErrorResponse = r.json();
        assert_eq!(
            e.error.field.as_deref(),
            Some("session_id"),
            "{method} {path}"
        );
    }
    // The same over gRPC, Interact included.
    let mut c = client(&server).await.with_bearer_token(TOKEN_B).unwrap();
    let e = grpc_error(c.get_state(&id).await);
    assert_eq!(e.code(), tonic::Code::NotFound, "{}", e.message());
    let open = dynaserve_api::v1::InteractRequest {
        session_id: id.clone(),
        ..Default::default()
    };
    let e = grpc_error(c.interact(open).await);
    assert_eq!(e.code(), tonic::Code::NotFound, "{}", e.message());
    // Still there for its owner after all that.
    assert_eq!(
        as_caller(addr, TOKEN_A, "GET", &base, None).await.status,
        200
    );

    // A shared session: every caller uses it, only its owner deletes it.
    let created = as_caller(
        addr,
        TOKEN_A,
        "POST",
        "/v1/sessions",
        Some(create_body(&m.name, 82, true)),
    )
    .await;
    assert_eq!(created.status, 201, "{}", created.text());
    let shared: dynaserve_api::json::SessionInfo = created.json();
    assert!(shared.shared);
    let sbase = format!("/v1/sessions/{}", shared.session_id);
    assert_eq!(
        as_caller(addr, TOKEN_B, "GET", &sbase, None).await.status,
        200
    );
    let stepped = as_caller(
        addr,
        TOKEN_B,
        "POST",
        &format!("{sbase}/step"),
        Some(serde_json::json!({"steps": 1})),
    )
    .await;
    assert_eq!(stepped.status, 200, "{}", stepped.text());
    let fork = as_caller(addr, TOKEN_B, "POST", &format!("{sbase}/fork"), None).await;
    assert_eq!(fork.status, 201, "{}", fork.text());
    let fork: dynaserve_api::json::SessionInfo = fork.json();
    assert!(!fork.shared, "a fork is its forker's own");
    let fork_path = format!("/v1/sessions/{}", fork.session_id);
    assert_eq!(
        as_caller(addr, TOKEN_A, "GET", &fork_path, None)
            .await
            .status,
        404
    );
    let denied = as_caller(addr, TOKEN_B, "DELETE", &sbase, None).await;
    assert_eq!(denied.status, 403, "{}", denied.text());
    assert_eq!(
        as_caller(addr, TOKEN_A, "DELETE", &sbase, None)
            .await
            .status,
        204
    );
    assert_eq!(
        as_caller(addr, TOKEN_B, "DELETE", &fork_path, None)
            .await
            .status,
        204
    );
    server.shutdown();
    server.wait().await.unwrap();

    // Without authentication a session belongs to its creator's IP address.
    let server = start(&m.dir, |_| {}).await;
    let info = create_session_http(server.http_addr, &m.name, scene(83, 2, 32), vec![]).await;
    let path = format!("/v1/sessions/{}", info.session_id);
    let other = get_from([127, 0, 0, 2], server.http_addr, &path).await;
    assert!(other.starts_with("HTTP/1.1 404"), "{other}");
    let same = get_from([127, 0, 0, 1], server.http_addr, &path).await;
    assert!(same.starts_with("HTTP/1.1 200"), "{same}");
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn session_and_stream_quotas_are_per_caller() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.security.auth_tokens = vec![TOKEN_A.into(), TOKEN_B.into()];
        c.sessions.max_sessions_per_caller = 2;
        c.sessions.max_streams_per_caller = 1;
        c.stream_buffer = 1;
    })
    .await;
    let addr = server.http_addr;
    for seed in [91, 92] {
        let r = as_caller(
            addr,
            TOKEN_A,
            "POST",
            "/v1/sessions",
            Some(create_body(&m.name, seed, false)),
        )
        .await;
        assert_eq!(r.status, 201, "{}", r.text());
    }
    let full = as_caller(
        addr,
        TOKEN_A,
        "POST",
        "/v1/sessions",
        Some(create_body(&m.name, 93, false)),
    )
    .await;
    assert_eq!(full.status, 429, "{}", full.text());
    assert!(
        full.text().contains("--max-sessions-per-caller"),
        "{}",
        full.text()
    );
    // The other caller has a quota of its own.
    let r = as_caller(
        addr,
        TOKEN_B,
        "POST",
        "/v1/sessions",
        Some(create_body(&m.name, 94, false)),
    )
    .await;
    assert_eq!(r.status, 201, "{}", r.text());

    // Streams: the first of A's holds its one slot while nobody reads it.
    let mut a = client(&server).await.with_bearer_token(TOKEN_A).unwrap();
    let mut b = a.clone().with_bearer_token(TOKEN_B).unwrap();
    let long = rollout_request(&m.name, scene(95, 1, 16), 5000);
    let held = a.rollout(&long).await.unwrap();
    let e = grpc_error(a.rollout(&long).await);
    assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{}", e.message());
    assert!(
        e.message().contains("--max-streams-per-caller"),
        "{}",
        e.message()
    );
    let short = rollout_request(&m.name, scene(96, 1, 16), 2);
    let mut frames = b.rollout(&short).await.unwrap().frames;
    let mut n = 0;
    while let Some(f) = frames.next().await {
        n += 1;
        assert_eq!(f.unwrap().step, n);
    }
    assert_eq!(n, 2);
    // A's slot comes back when its stream goes.
    drop(held);
    let t = Instant::now();
    loop {
        match a.rollout(&short).await {
            Ok(_) => break,
            Err(e) => {
                let e = status_of(e);
                assert_eq!(e.code(), tonic::Code::ResourceExhausted, "{}", e.message());
                assert!(t.elapsed() < HANG, "the stream's quota never came back");
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
        }
    }
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_session_that_could_never_fit_is_invalid_not_a_retry() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.sessions.max_session_mib = 1;
    })
    .await;
    // Far more than a MiB of prepared points and anchors.
    let big = serde_json::json!({"model": m.name, "scene": scene(97, 64, 512)});
    let r = post_json(server.http_addr, "/v1/sessions", &big).await;
    assert_eq!(r.status, 422, "{}", r.text());
    let e: dynaserve_api::json::ErrorResponse = r.json();
    assert_eq!(e.error.field.as_deref(), Some("scene"));
    assert!(
        e.error.message.contains("--max-session-mib"),
        "{}",
        e.error.message
    );
    let mut c = client(&server).await;
    let e = grpc_error(
        c.create_session(dynaserve_api::v1::CreateSessionRequest {
            model: m.name.clone(),
            scene: Some(scene(97, 64, 512).to_proto()),
            dt_steps: 1,
            kinematic: vec![],
            shared: false,
        })
        .await,
    );
    assert_eq!(e.code(), tonic::Code::InvalidArgument, "{}", e.message());
    // A small one fits.
    create_session_http(server.http_addr, &m.name, scene(98, 2, 32), vec![]).await;
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn poses_implying_more_than_1000_m_per_s_are_refused_naming_the_object() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let addr = server.http_addr;
    // A previous pose 100 m from the pose: at the model's step of a few hundredths of a second
    // that is thousands of m/s.
    let mut s = scene(101, 2, 32);
    let at = s.objects[1].pose.translation;
    s.objects[1].velocity = None;
    s.objects[1].previous_pose = Some(dynaserve_api::json::Pose {
        translation: [at[0] - 100.0, at[1], at[2]],
        rotation: [0.0, 0.0, 0.0, 1.0],
    });
    let r = post_json(addr, "/v1/rollout", &rollout_request(&m.name, s.clone(), 2)).await;
    assert_eq!(r.status, 422, "{}", r.text());
    let e: dynaserve_api::json::ErrorResponse = r.json();
    assert_eq!(
        e.error.field.as_deref(),
        Some("scene.objects[1].previous_pose")
    );
    assert!(e.error.message.contains("1000 m/s"), "{}", e.error.message);
    let mut c = client(&server).await;
    let e = grpc_error(c.rollout(&rollout_request(&m.name, s, 2)).await);
    assert_eq!(e.code(), tonic::Code::InvalidArgument, "{}", e.message());
    assert!(
        e.message().starts_with("scene.objects[1].previous_pose"),
        "{}",
        e.message()
    );

    // A kinematic object's action 100 m from where it is.
    let info = create_session_http(addr, &m.name, scene(102, 2, 32), vec![0]).await;
    let path = format!("/v1/sessions/{}", info.session_id);
    let state: dynaserve_api::json::SessionState = http(addr, "GET", &path, &[], None).await.json();
    let p = state.poses[0].translation;
    let near = serde_json::json!({"translation": [p[0] + 0.01, p[1], p[2]]});
    let far = serde_json::json!({"translation": [p[0] + 100.0, p[1], p[2]]});
    let step = |poses: Vec<serde_json::Value>| {
        serde_json::json!({
            "steps": poses.len(),
            "actions": poses
                .into_iter()
                .map(|pose| serde_json::json!({"kinematic": [{"object": 0, "pose": pose}]}))
                .collect::<Vec<_>>(),
        })
    };
    let r = post_json(
        addr,
        &format!("{path}/step"),
        &step(vec![near.clone(), far.clone()]),
    )
    .await;
    assert_eq!(r.status, 422, "{}", r.text());
    let e: dynaserve_api::json::ErrorResponse = r.json();
    assert_eq!(
        e.error.field.as_deref(),
        Some("actions[1].kinematic[0].pose")
    );
    assert!(e.error.message.contains("object 0"), "{}", e.error.message);
    // Nothing was stepped; a slow action runs.
    let r = post_json(addr, &format!("{path}/step"), &step(vec![near])).await;
    assert_eq!(r.status, 200, "{}", r.text());
    let r: dynaserve_api::json::StepResponse = r.json();
    assert_eq!(r.frames[0].step, 1);
    // A session Predict variant's action, too.
    let body = serde_json::json!({"variants": [{}, {"actions": [{"kinematic": [{"object": 0, "pose": far}]}]}], "steps": 1});
    let r = post_json(addr, &format!("{path}/predict"), &body).await;
    assert_eq!(r.status, 422, "{}", r.text());
    let e: dynaserve_api::json::ErrorResponse = r.json();
    assert_eq!(
        e.error.field.as_deref(),
        Some("variants[1].actions[0].kinematic[0].pose")
    );
    server.shutdown();
    server.wait().await.unwrap();
}

/// One object at `x` metres moving at `vx` m/s along x.
fn fast_object(x: f32, vx: f32) -> dynaserve_api::json::Scene {
    let mut s = scene(5, 1, 32);
    s.objects[0].pose.translation = [x, 0.0, 0.5];
    s.objects[0].velocity = Some(dynaserve_api::json::Velocity {
        linear: [vx, 0.0, 0.0],
        angular: [0.0; 3],
    });
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_predict_variant_leaving_the_domain_is_named() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let req = dynaserve_api::json::PredictRequest {
        model: m.name.clone(),
        variants: vec![scene(111, 2, 32), fast_object(99_999.9, 1000.0)],
        steps: 5,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    let r = post_json(server.http_addr, "/v1/predict", &req).await;
    assert_eq!(r.status, 422, "{}", r.text());
    let e: dynaserve_api::json::ErrorResponse = r.json();
    assert_eq!(e.error.code, "OUT_OF_RANGE");
    assert_eq!(e.error.field.as_deref(), Some("variants[1].objects[0]"));
    assert!(
        e.error
            .message
            .starts_with("variants[1].objects[0]: left the model's domain"),
        "{}",
        e.error.message
    );
    let mut c = client(&server).await;
    let e = grpc_error(c.predict(&req).await);
    assert_eq!(e.code(), tonic::Code::OutOfRange);
    assert!(
        e.message().starts_with("variants[1].objects[0]"),
        "{}",
        e.message()
    );
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_grpc_client_that_never_reads_loses_its_slot_and_finds_the_status_after_its_frames() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.max_active_rollouts = 1;
        c.stream_buffer = 2;
        c.stream_stall_timeout_s = 1.0;
    })
    .await;
    // A client window of 1 KiB: the server can send next to nothing it does not read.
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
        .unwrap()
        .initial_stream_window_size(1024)
        .connect()
        .await
        .unwrap();
    let mut slow = dynaserve_client::Client::from_channel(channel);
    let long = rollout_request(&m.name, scene(121, 8, 16), 10_000);
    let mut unread = slow.rollout(&long).await.unwrap().frames;
    let t = Instant::now();
    loop {
        let stalled = sample(
            &metrics(&server).await,
            &format!("dynaserve_stalled_streams_total{{model=\"{}\"}}", m.name),
        );
        if stalled == Some(1.0) {
            break;
        }
        assert!(t.elapsed() < HANG, "the stream was never ended");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    // Its slot is free: another client's rollout runs.
    let mut c = client(&server).await;
    c.rollout_collect(&rollout_request(&m.name, scene(122, 1, 16), 2))
        .await
        .unwrap();
    // Reading at last: the frames the server had sent, then the status that ended the stream.
    let mut frames = 0;
    let status = loop {
        match tokio::time::timeout(HANG, unread.next()).await.unwrap() {
            Some(Ok(_)) => frames += 1,
            None => panic!("ended without a status after {frames} frames"),
            Some(Err(e)) => break status_of(e),
        }
    };
    assert!(frames < 10_000);
    assert_eq!(
        status.code(),
        tonic::Code::Cancelled,
        "{}",
        status.message()
    );
    assert!(
        status.message().contains("read no frame for 1 s"),
        "{}",
        status.message()
    );
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn request_ids_are_echoed_only_when_short_and_visible() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let ok = "a".repeat(128);
    let long = "b".repeat(129);
    let is_generated = |id: &str| id.len() == 16 && id.bytes().all(|b| b.is_ascii_hexdigit());
    for path in ["/v1/models", "/v1/sessions/no-such-session"] {
        let r = http(
            server.http_addr,
            "GET",
            path,
            &[("x-request-id", &ok)],
            None,
        )
        .await;
        assert_eq!(r.header("x-request-id"), Some(ok.as_str()), "{path}");
        for bad in [long.as_str(), "has space", "tab\there", "\u{e9}t\u{e9}"] {
            let r = http(
                server.http_addr,
                "GET",
                path,
                &[("x-request-id", bad)],
                None,
            )
            .await;
            let got = r.header("x-request-id").unwrap_or_default().to_string();
            assert!(is_generated(&got), "{path} {bad:?}: {got:?}");
        }
    }
    let mut c = grpc_world_model(&server).await;
    let mut s = grpc_sessions(&server).await;
    for (id, echoed) in [(ok.as_str(), true), (long.as_str(), false)] {
        let mut r = tonic::Request::new(dynaserve_api::v1::ListModelsRequest {});
        r.metadata_mut().insert("x-request-id", id.parse().unwrap());
        let resp = c.list_models(r).await.unwrap();
        let got = resp
            .metadata()
            .get("x-request-id")
            .unwrap()
            .to_str()
            .unwrap();
        assert_eq!(got == id, echoed, "{got}");
        assert!(echoed || is_generated(got), "{got}");
        // The error path carries it too.
        let mut r = tonic::Request::new(dynaserve_api::v1::GetStateRequest {
            session_id: "no-such-session".into(),
        });
        r.metadata_mut().insert("x-request-id", id.parse().unwrap());
        let e = s.get_state(r).await.unwrap_err();
        let got = e.metadata().get("x-request-id").unwrap().to_str().unwrap();
        assert_eq!(got == id, echoed, "{got}");
        assert!(echoed || is_generated(got), "{got}");
    }
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_grpc_message_that_pauses_is_cut_off_but_not_the_wait_between_messages() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.connections.body_read_timeout_s = 0.5;
        c.connections.body_deadline_s = 30.0;
    })
    .await;
    // A unary call whose message stops after a few bytes.
    let (mut tx, call) = raw_grpc_call(server.grpc_addr, "/dynaserve.v1.WorldModel/Predict").await;
    let mut start_of_message = vec![0u8];
    start_of_message.extend_from_slice(&1000u32.to_be_bytes());
    start_of_message.extend_from_slice(b"\x0a\x01");
    tx.send(Ok(Frame::data(Bytes::from(start_of_message))))
        .await
        .unwrap();
    let resp = tokio::time::timeout(HANG, call)
        .await
        .expect("no answer")
        .unwrap()
        .unwrap();
    let (code, msg, _) = grpc_outcome(resp).await;
    let msg = percent_decoded(&msg);
    assert_eq!(code.as_deref(), Some("3"), "INVALID_ARGUMENT: {msg}");
    assert!(msg.contains("--body-read-timeout-s"), "{msg}");
    drop(tx);

    // Interact: three times the pause between whole messages is fine.
    let open = dynaserve_api::v1::InteractRequest {
        create: Some(dynaserve_api::v1::CreateSessionRequest {
            model: m.name.clone(),
            scene: Some(scene(131, 1, 16).to_proto()),
            dt_steps: 1,
            kinematic: vec![],
            shared: false,
        }),
        ..Default::default()
    };
    let step = grpc_frame(&dynaserve_api::v1::InteractRequest::default().encode_to_vec());
    let (mut tx, call) = raw_grpc_call(server.grpc_addr, "/dynaserve.v1.Sessions/Interact").await;
    tx.send(Ok(Frame::data(Bytes::from(grpc_frame(
        &open.encode_to_vec(),
    )))))
    .await
    .unwrap();
    let resp = tokio::time::timeout(HANG, call)
        .await
        .expect("no answer")
        .unwrap()
        .unwrap();
    let mut body = resp.into_body();
    tokio::time::sleep(Duration::from_millis(1500)).await;
    tx.send(Ok(Frame::data(Bytes::from(step.clone()))))
        .await
        .unwrap();
    let f = tokio::time::timeout(HANG, body.frame())
        .await
        .unwrap()
        .unwrap()
        .unwrap();
    assert!(f.data_ref().is_some_and(|d| d.len() >= 5), "{f:?}");
    // A message that stops half way is cut after the pause allowed.
    tx.send(Ok(Frame::data(Bytes::from(step[..3].to_vec()))))
        .await
        .unwrap();
    let (code, msg, _) = grpc_outcome_of_body(body).await;
    let msg = percent_decoded(&msg);
    assert_eq!(code.as_deref(), Some("3"), "INVALID_ARGUMENT: {msg}");
    assert!(msg.contains("--body-read-timeout-s"), "{msg}");
    drop(tx);
    server.shutdown();
    server.wait().await.unwrap();
}
