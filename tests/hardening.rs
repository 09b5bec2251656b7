//! Hardening of `dynaserve serve` against a real server on 127.0.0.1 with a real RigidFormer:
//! a scene leaving the model's domain fails alone beside healthy streams; slow, idle and
//! half-sent connections are closed; a client that never reads loses its stream slot;
//! bearer-token authentication and TLS on both protocols; CORS and content-type policy; the
//! status codes of odd requests; readiness during the drain.

mod common;

use std::sync::Arc;
use std::time::{Duration, Instant};

use common::*;
use dynaserve_api::json;
use dynaserve_api::v1;
use dynaserve_server::ServeConfig;
use futures::StreamExt;
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;
use tonic::Code;

/// A bound for waits that must end; reaching it is a hang, not a slow machine.
const HANG: Duration = Duration::from_secs(60);

/// Reads until the peer closes (Ok(bytes read)) or `within` passes (Err).
async fn read_to_close(s: &mut TcpStream, within: Duration) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    let mut buf = [0u8; 4096];
    let end = Instant::now() + within;
    loop {
        let left = end.saturating_duration_since(Instant::now());
        match tokio::time::timeout(left, s.read(&mut buf)).await {
            Ok(Ok(0)) | Ok(Err(_)) => return Ok(out),
            Ok(Ok(n)) => out.extend_from_slice(&buf[..n]),
            Err(_) => return Err(format!("still open after {within:?}")),
        }
    }
}

/// Sends `body` by `method` to `path` with exactly the content type `ct` over raw HTTP/1.1
/// (the shared client always adds `application/json`) and reads the whole answer.
async fn send_typed(
    addr: std::net::SocketAddr,
    method: &str,
    path: &str,
    ct: &str,
    body: &[u8],
) -> String {
    let mut s = TcpStream::connect(addr).await.unwrap();
    let head = format!(
        "{method} {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\ncontent-type: {ct}\r\n\
         origin: https://evil.example\r\ncontent-length: {}\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).await.unwrap();
    s.write_all(body).await.unwrap();
    String::from_utf8(read_to_close(&mut s, HANG).await.unwrap()).unwrap()
}

/// One object at `x` metres moving at `vx` m/s along x.
fn fast_object(x: f32, vx: f32) -> json::Scene {
    let mut s = scene(5, 1, 32);
    s.objects[0].pose.translation = [x, 0.0, 0.5];
    s.objects[0].velocity = Some(json::Velocity {
        linear: [vx, 0.0, 0.0],
        angular: [0.0; 3],
    });
    s
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scene_leaving_the_domain_fails_alone_while_its_batch_mates_get_every_frame() {
    let m = test_model();
    let server = start(&m.dir, |c| c.max_queue_delay_ms = 5.0).await;
    let model = load(&m.dir);
    let steps = 40;
    let healthy: Vec<json::RolloutRequest> = (0..3)
        .map(|i| rollout_request(&m.name, scene(300 + i, 2, 32), steps))
        .collect();
    let c = client(&server).await;
    // Healthy streams first; once each has a frame, the poisoned scene joins their passes.
    let (first_tx, mut first_rx) = tokio::sync::mpsc::channel(3);
    let tasks: Vec<_> = healthy
        .iter()
        .cloned()
        .map(|r| {
            let mut c = c.clone();
            let first_tx = first_tx.clone();
            tokio::spawn(async move {
                let mut rollout = c.rollout(&r).await.unwrap();
                let mut frames = Vec::new();
                while let Some(f) = rollout.frames.next().await {
                    frames.push(f.expect("a healthy stream must not fail"));
                    if frames.len() == 1 {
                        let _ = first_tx.send(()).await;
                    }
                }
                frames
            })
        })
        .collect();
    for _ in 0..3 {
        first_rx.recv().await.unwrap();
    }
    // 99999.9 m at 1000 m/s: inside the accepted ranges, beyond 1e5 m after one step.
    let poisoned = rollout_request(&m.name, fast_object(99_999.9, 1000.0), steps);
    let mut pc = c.clone();
    let mut p = pc.rollout(&poisoned).await.unwrap();
    let end = p.frames.next().await.unwrap();
    let status = match end {
        Err(dynaserve_client::ClientError::Status(s)) => s,
        other => panic!("expected OUT_OF_RANGE, got {other:?}"),
    };
    assert_eq!(status.code(), Code::OutOfRange, "{status:?}");
    assert!(
        status
            .message()
            .starts_with("scene.objects[0]: left the model's domain at step 1"),
        "{}",
        status.message()
    );
    for (req, t) in healthy.iter().zip(tasks) {
        let frames = t.await.unwrap();
        let diff = max_diff(&frames, &in_process(&*model, req));
        assert!(diff <= 1e-5, "healthy stream differs by {diff}");
        // The error names nothing of the other streams.
        let x = format!("{}", req.scene.objects[0].pose.translation[0]);
        assert!(!status.message().contains(&x), "{}", status.message());
    }
    // A start whose previous pose (translation - velocity * dt) lies beyond the model's domain
    // is refused at admission, naming the velocity.
    let r = post_json(
        server.http_addr,
        "/v1/rollout",
        &rollout_request(&m.name, fast_object(-99_999.9, 1000.0), 3),
    )
    .await;
    assert_eq!(r.status, 422, "{}", r.text());
    let e: json::ErrorResponse = r.json();
    assert_eq!(
        e.error.field.as_deref(),
        Some("scene.objects[0].velocity.linear")
    );
    let text = metrics(&server).await;
    assert_eq!(
        sample(
            &text,
            "dynaserve_request_failures_total{protocol=\"grpc\",method=\"rollout\",reason=\"invalid_argument\"}"
        ),
        Some(1.0),
        "OUT_OF_RANGE is counted with invalid input"
    );
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn slow_idle_and_half_sent_connections_are_closed() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.connections.header_read_timeout_s = 0.5;
        c.connections.body_read_timeout_s = 0.5;
    })
    .await;
    let http_addr = server.http_addr;
    // Nothing sent, on both listeners.
    for addr in [http_addr, server.grpc_addr] {
        let mut s = TcpStream::connect(addr).await.unwrap();
        read_to_close(&mut s, HANG).await.unwrap();
    }
    // Headers that never end.
    let mut s = TcpStream::connect(http_addr).await.unwrap();
    s.write_all(b"POST /v1/rollout HTTP/1.1\r\nHost: x\r\nX-Slow: 1")
        .await
        .unwrap();
    read_to_close(&mut s, HANG).await.unwrap();
    // An idle keep-alive connection after a complete request.
    let mut s = TcpStream::connect(http_addr).await.unwrap();
    s.write_all(b"GET /health HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .unwrap();
    let got = String::from_utf8(read_to_close(&mut s, HANG).await.unwrap()).unwrap();
    assert!(got.starts_with("HTTP/1.1 200"), "{got}");
    // A body that stops half way: 408, then the connection closes.
    let mut s = TcpStream::connect(http_addr).await.unwrap();
    s.write_all(
        b"POST /v1/rollout HTTP/1.1\r\nHost: x\r\ncontent-type: application/json\r\n\
          content-length: 1000\r\n\r\n{\"steps\": 3,",
    )
    .await
    .unwrap();
    let got = String::from_utf8(read_to_close(&mut s, HANG).await.unwrap()).unwrap();
    assert!(got.starts_with("HTTP/1.1 408"), "{got}");
    let text = metrics(&server).await;
    for listener in ["http", "grpc"] {
        let closed = sample(
            &text,
            &format!(
                "dynaserve_closed_connections_total{{listener=\"{listener}\",reason=\"timeout\"}}"
            ),
        )
        .unwrap();
        assert!(closed >= 1.0, "{listener}: {closed}");
    }
    // The server still serves.
    assert_eq!(
        http(http_addr, "GET", "/ready", &[], None).await.status,
        200
    );
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn connections_over_the_cap_are_closed_and_the_server_recovers() {
    let m = test_model();
    let server = start(&m.dir, |c| c.connections.max_connections = 2).await;
    let a = TcpStream::connect(server.http_addr).await.unwrap();
    let b = TcpStream::connect(server.http_addr).await.unwrap();
    let mut over = TcpStream::connect(server.http_addr).await.unwrap();
    read_to_close(&mut over, HANG).await.unwrap();
    drop((a, b));
    let t = Instant::now();
    loop {
        // The slots come back as soon as the server sees the two connections close.
        let mut s = TcpStream::connect(server.http_addr).await.unwrap();
        s.write_all(b"GET /health HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n")
            .await
            .unwrap();
        let got = read_to_close(&mut s, HANG).await.unwrap();
        if got.starts_with(b"HTTP/1.1 200") {
            break;
        }
        assert!(t.elapsed() < HANG, "never recovered");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    let text = metrics(&server).await;
    let refused = sample(
        &text,
        "dynaserve_closed_connections_total{listener=\"http\",reason=\"limit\"}",
    )
    .unwrap();
    assert!(refused >= 1.0, "{refused}");
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_client_that_never_reads_loses_its_stream_and_slot() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.max_active_rollouts = 1;
        c.stream_buffer = 2;
        c.stream_stall_timeout_s = 1.0;
    })
    .await;
    // Many objects per frame fill the socket buffers quickly.
    let req = json::RolloutRequest {
        stream: true,
        ..rollout_request(&m.name, scene(41, 48, 16), 10_000)
    };
    let body = serde_json::to_vec(&req).unwrap();
    let sock = tokio::net::TcpSocket::new_v4().unwrap();
    sock.set_recv_buffer_size(4096).unwrap();
    let mut s = sock.connect(server.http_addr).await.unwrap();
    let head = format!(
        "POST /v1/rollout HTTP/1.1\r\nHost: x\r\ncontent-type: application/json\r\n\
         content-length: {}\r\n\r\n",
        body.len()
    );
    s.write_all(head.as_bytes()).await.unwrap();
    s.write_all(&body).await.unwrap();
    // The one slot is taken until the server gives up on the reader.
    let t = Instant::now();
    loop {
        let text = metrics(&server).await;
        let stalled = sample(
            &text,
            &format!("dynaserve_stalled_streams_total{{model=\"{}\"}}", m.name),
        );
        if stalled == Some(1.0) {
            break;
        }
        assert!(t.elapsed() < HANG, "the stream was never ended");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let small = rollout_request(&m.name, scene(42, 1, 16), 2);
    let r = post_json(server.http_addr, "/v1/rollout", &small).await;
    assert_eq!(r.status, 200, "slot not freed: {}", r.text());
    // Reading now shows the buffered frames, then the error that ended the stream.
    let mut got = Vec::new();
    let mut buf = vec![0u8; 1 << 16];
    while !String::from_utf8_lossy(&got).contains("event: error") {
        let n = tokio::time::timeout(HANG, s.read(&mut buf))
            .await
            .expect("stream never delivered its error")
            .unwrap();
        assert!(n > 0, "closed without the error event");
        got.extend_from_slice(&buf[..n]);
    }
    let text = String::from_utf8_lossy(&got);
    assert!(
        text.contains("the client read no frame for 1 s"),
        "{text:.300}"
    );
    assert!(!text.contains("event: done"));
    server.shutdown();
    server.wait().await.unwrap();
}

const TOKEN: &str = "test-token-0123456789abcdef";

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bearer_tokens_guard_both_protocols() {
    let m = test_model();
    let dir = TempDir::new("tokens");
    let file = dir.0.join("tokens");
    std::fs::write(&file, format!("# one per line\n{TOKEN}\n")).unwrap();
    let server = start(&m.dir, |c| c.security.auth_token_file = Some(file)).await;
    let req = rollout_request(&m.name, scene(51, 1, 16), 2);
    let body = serde_json::to_vec(&req).unwrap();
    let post = |headers: Vec<(&'static str, String)>| {
        let body = body.clone();
        let addr = server.http_addr;
        async move {
            let h: Vec<(&str, &str)> = headers.iter().map(|(k, v)| (*k, v.as_str())).collect();
            http(addr, "POST", "/v1/rollout", &h, Some(&body)).await
        }
    };
    let missing = post(vec![]).await;
    assert_eq!(missing.status, 401, "{}", missing.text());
    assert!(
        missing
            .header("www-authenticate")
            .unwrap()
            .starts_with("Bearer")
    );
    assert!(missing.text().contains("UNAUTHENTICATED"));
    let wrong = post(vec![(
        "authorization",
        "Bearer wrong-token-0123456789".into(),
    )])
    .await;
    assert_eq!(wrong.status, 401);
    let right = post(vec![("authorization", format!("Bearer {TOKEN}"))]).await;
    assert_eq!(right.status, 200, "{}", right.text());
    // Probes are open; metrics are not.
    assert_eq!(
        http(server.http_addr, "GET", "/ready", &[], None)
            .await
            .status,
        200
    );
    assert_eq!(
        http(server.http_addr, "GET", "/metrics", &[], None)
            .await
            .status,
        401
    );

    let mut g = client(&server).await;
    let e = grpc_error(g.list_models().await);
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let mut wrong = g.clone().with_bearer_token("nope-nope-nope-nope").unwrap();
    let e = grpc_error(wrong.list_models().await);
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let mut right = g.with_bearer_token(TOKEN).unwrap();
    let ok = right.list_models().await.unwrap();
    assert_eq!(ok[0].name, m.name);
    let channel = tonic::transport::Channel::from_shared(format!("http://{}", server.grpc_addr))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut health = tonic_health::pb::health_client::HealthClient::new(channel);
    let h = health
        .check(tonic_health::pb::HealthCheckRequest {
            service: String::new(),
        })
        .await
        .unwrap();
    assert_eq!(h.into_inner().status, 1, "SERVING without a token");
    server.shutdown();
    server.wait().await.unwrap();
}

/// A self-signed certificate for `localhost` written as PEM files into `dir`.
fn self_signed(dir: &std::path::Path) -> (std::path::PathBuf, std::path::PathBuf, String) {
    let cert = rcgen::generate_simple_self_signed(vec!["localhost".to_string()]).unwrap();
    let pem = cert.cert.pem();
    let (c, k) = (dir.join("cert.pem"), dir.join("key.pem"));
    std::fs::write(&c, &pem).unwrap();
    std::fs::write(&k, cert.signing_key.serialize_pem()).unwrap();
    (c, k, pem)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn tls_handshakes_on_both_listeners() {
    use tokio_rustls::rustls;
    let m = test_model();
    let dir = TempDir::new("tls");
    let (cert, key, pem) = self_signed(&dir.0);
    let server = start(&m.dir, |c| {
        c.security.tls_cert = Some(cert);
        c.security.tls_key = Some(key);
    })
    .await;
    // HTTP/1.1 over TLS.
    let mut roots = rustls::RootCertStore::empty();
    use rustls::pki_types::pem::PemObject;
    for c in rustls::pki_types::CertificateDer::pem_slice_iter(pem.as_bytes()) {
        roots.add(c.unwrap()).unwrap();
    }
    let config = rustls::ClientConfig::builder_with_provider(Arc::new(
        rustls::crypto::ring::default_provider(),
    ))
    .with_safe_default_protocol_versions()
    .unwrap()
    .with_root_certificates(roots)
    .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(Arc::new(config));
    let tcp = TcpStream::connect(server.http_addr).await.unwrap();
    let name = rustls::pki_types::ServerName::try_from("localhost").unwrap();
    let mut tls = connector.connect(name, tcp).await.unwrap();
    tls.write_all(b"GET /ready HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n\r\n")
        .await
        .unwrap();
    let mut got = Vec::new();
    let _ = tls.read_to_end(&mut got).await;
    let got = String::from_utf8_lossy(&got);
    assert!(got.starts_with("HTTP/1.1 200"), "{got}");
    // gRPC over TLS with tonic's own client.
    let tls = tonic::transport::ClientTlsConfig::new()
        .ca_certificate(tonic::transport::Certificate::from_pem(&pem))
        .domain_name("localhost");
    let channel = tonic::transport::Channel::from_shared(format!(
        "https://localhost:{}",
        server.grpc_addr.port()
    ))
    .unwrap()
    .tls_config(tls)
    .unwrap()
    .connect()
    .await
    .unwrap();
    let mut c = dynaserve_client::Client::from_channel(channel);
    let frames = c
        .rollout_collect(&rollout_request(&m.name, scene(61, 2, 16), 3))
        .await
        .unwrap();
    assert_eq!(frames.len(), 3);
    // Plain text to a TLS port is refused.
    let mut s = TcpStream::connect(server.http_addr).await.unwrap();
    s.write_all(b"GET /ready HTTP/1.1\r\nHost: x\r\n\r\n")
        .await
        .unwrap();
    let got = read_to_close(&mut s, HANG).await.unwrap();
    assert!(!got.starts_with(b"HTTP/1.1 200"));
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn cors_allow_list_and_json_only_bodies() {
    let m = test_model();
    let server = start(&m.dir, |c| {
        c.security.cors_origins = vec!["https://viewer.example".into()];
    })
    .await;
    let preflight = |origin: &'static str| {
        let addr = server.http_addr;
        async move {
            let headers = [
                ("origin", origin),
                ("access-control-request-method", "POST"),
                ("access-control-request-headers", "content-type"),
            ];
            http(addr, "OPTIONS", "/v1/rollout", &headers, None).await
        }
    };
    let allowed = preflight("https://viewer.example").await;
    assert_eq!(
        allowed.header("access-control-allow-origin"),
        Some("https://viewer.example")
    );
    let other = preflight("https://evil.example").await;
    assert_eq!(other.header("access-control-allow-origin"), None);
    // A browser app may also replace a session's state (PUT) and delete a session (DELETE):
    // their preflights allow exactly the methods the API serves.
    for (method, path) in [
        ("PUT", "/v1/sessions/0123456789abcdef/state"),
        ("DELETE", "/v1/sessions/0123456789abcdef"),
    ] {
        let headers = [
            ("origin", "https://viewer.example"),
            ("access-control-request-method", method),
            ("access-control-request-headers", "content-type"),
        ];
        let r = http(server.http_addr, "OPTIONS", path, &headers, None).await;
        assert_eq!(r.status, 200, "{method} {path}: {}", r.text());
        assert_eq!(
            r.header("access-control-allow-origin"),
            Some("https://viewer.example")
        );
        let mut allowed: Vec<&str> = r
            .header("access-control-allow-methods")
            .unwrap_or_default()
            .split(',')
            .map(str::trim)
            .collect();
        allowed.sort_unstable();
        assert_eq!(allowed, ["DELETE", "GET", "POST", "PUT"], "{method} {path}");
    }
    // A "simple" cross-origin post (text/plain, no preflight) is refused before any work.
    let body = serde_json::to_vec(&rollout_request(&m.name, scene(71, 1, 16), 2)).unwrap();
    for ct in ["text/plain", "application/x-www-form-urlencoded"] {
        let got = send_typed(server.http_addr, "POST", "/v1/rollout", ct, &body).await;
        assert!(got.starts_with("HTTP/1.1 415"), "{got}");
        assert!(got.contains("\"UNSUPPORTED_MEDIA_TYPE\""), "{got}");
        assert!(got.contains(ct), "{got}");
    }
    // So is a session state PUT in either type: the state stays as it was. As JSON it is
    // applied.
    let info = create_session_http(server.http_addr, &m.name, scene(72, 1, 16), vec![]).await;
    let path = format!("/v1/sessions/{}", info.session_id);
    let state_of = || async {
        let r = http(server.http_addr, "GET", &path, &[], None).await;
        assert_eq!(r.status, 200, "{}", r.text());
        r.json::<json::SessionState>()
    };
    let before = state_of().await;
    let moved = json::Pose {
        translation: [0.25, -0.125, 0.5],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };
    let put = serde_json::to_vec(&json::SetStateRequest {
        objects: vec![json::ObjectState {
            object: 0,
            pose: moved,
            previous_pose: None,
            velocity: None,
        }],
    })
    .unwrap();
    let state_path = format!("{path}/state");
    for ct in ["text/plain", "application/x-www-form-urlencoded"] {
        let got = send_typed(server.http_addr, "PUT", &state_path, ct, &put).await;
        assert!(got.starts_with("HTTP/1.1 415"), "{got}");
        assert!(got.contains("\"UNSUPPORTED_MEDIA_TYPE\""), "{got}");
        assert!(got.contains(ct), "{got}");
    }
    assert_eq!(state_of().await.poses, before.poses);
    let r = http(server.http_addr, "PUT", &state_path, &[], Some(&put)).await;
    assert_eq!(r.status, 200, "{}", r.text());
    assert_eq!(r.json::<json::SessionState>().poses[0], moved);
    assert_eq!(state_of().await.poses[0], moved);
    let text = metrics(&server).await;
    assert_eq!(
        sample(
            &text,
            "dynaserve_requests_total{protocol=\"http\",method=\"rollout\"}"
        ),
        Some(0.0)
    );
    server.shutdown();
    server.wait().await.unwrap();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn odd_requests_get_the_right_status() {
    let m = test_model();
    let server = start(&m.dir, |c: &mut ServeConfig| {
        c.max_predict_variants = 4;
        c.max_request_bytes = 8192;
    })
    .await;
    // Warm-up is not serving work.
    let text = metrics(&server).await;
    assert_eq!(
        sample(
            &text,
            &format!("dynaserve_scene_steps_total{{model=\"{}\"}}", m.name)
        ),
        Some(0.0)
    );
    // A Predict above the in-flight cap can never run: 422 naming `variants`, and ListModels
    // reports that cap.
    let predict = json::PredictRequest {
        model: m.name.clone(),
        variants: (0..5).map(|i| scene(80 + i, 1, 16)).collect(),
        steps: 2,
        dt_steps: 1,
        every: 0,
        timeout_ms: 0,
    };
    let r = post_json(server.http_addr, "/v1/predict", &predict).await;
    assert_eq!(r.status, 422, "{}", r.text());
    assert_eq!(
        r.json::<json::ErrorResponse>().error.field.as_deref(),
        Some("variants")
    );
    let models = http(server.http_addr, "GET", "/v1/models", &[], None).await;
    let models: json::ListModelsResponse = models.json();
    assert_eq!(models.models[0].max_variants, 4);
    // A JSON array is not a request.
    let r = http(
        server.http_addr,
        "POST",
        "/v1/rollout",
        &[],
        Some(b"[\"m\", {}, 3]"),
    )
    .await;
    assert_eq!(r.status, 422, "{}", r.text());
    assert!(r.text().contains("JSON object"), "{}", r.text());
    // GET on a POST route: 405 with a JSON error.
    let r = http(server.http_addr, "GET", "/v1/rollout", &[], None).await;
    assert_eq!(r.status, 405);
    assert_eq!(
        r.json::<json::ErrorResponse>().error.code,
        "METHOD_NOT_ALLOWED"
    );
    // Oversized gRPC messages (beyond the decoding cap of 4x the limit) are INVALID_ARGUMENT
    // naming `request`, with a google.rpc.BadRequest detail.
    let mut g = client(&server).await;
    let big = rollout_request(&m.name, scene(90, 64, 64), 2);
    let e = match g.rollout(&big).await {
        Ok(_) => panic!("oversized message accepted"),
        Err(e) => status_of(e),
    };
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    assert!(e.message().starts_with("request: "), "{}", e.message());
    use tonic_types::StatusExt;
    let details = e.get_error_details();
    assert_eq!(
        details.bad_request().unwrap().field_violations[0].field,
        "request"
    );
    server.shutdown();
    server.wait().await.unwrap();
}

/// A gRPC codec that sends and receives message bytes as they are, so that a test can frame
/// bytes that are no protobuf message.
#[derive(Clone, Copy, Default)]
struct RawCodec;

impl tonic::codec::Codec for RawCodec {
    type Encode = Vec<u8>;
    type Decode = Vec<u8>;
    type Encoder = RawCodec;
    type Decoder = RawCodec;
    fn encoder(&mut self) -> RawCodec {
        RawCodec
    }
    fn decoder(&mut self) -> RawCodec {
        RawCodec
    }
}

impl tonic::codec::Encoder for RawCodec {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn encode(
        &mut self,
        item: Vec<u8>,
        dst: &mut tonic::codec::EncodeBuf<'_>,
    ) -> Result<(), tonic::Status> {
        use prost::bytes::BufMut;
        dst.put_slice(&item);
        Ok(())
    }
}

impl tonic::codec::Decoder for RawCodec {
    type Item = Vec<u8>;
    type Error = tonic::Status;
    fn decode(
        &mut self,
        src: &mut tonic::codec::DecodeBuf<'_>,
    ) -> Result<Option<Vec<u8>>, tonic::Status> {
        use prost::bytes::Buf;
        Ok(Some(src.copy_to_bytes(src.remaining()).to_vec()))
    }
}

/// Asserts `e` is INVALID_ARGUMENT (grpc-status 3) naming `request`, with the
/// google.rpc.BadRequest detail, and not the INTERNAL tonic's codec answers.
fn assert_invalid_request(e: &tonic::Status, what: &str) {
    assert_eq!(e.code(), Code::InvalidArgument, "{what}: {e:?}");
    assert!(
        e.message().starts_with("request: ")
            && e.message().contains("failed to decode Protobuf message"),
        "{what}: {}",
        e.message()
    );
    use tonic_types::StatusExt;
    let details = e.get_error_details();
    assert_eq!(
        details.bad_request().unwrap().field_violations[0].field,
        "request",
        "{what}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn undecodable_grpc_messages_are_invalid_argument_naming_request() {
    let m = test_model();
    let server = start(&m.dir, |_| {}).await;
    let channel = tonic::transport::Endpoint::from_shared(format!("http://{}", server.grpc_addr))
        .unwrap()
        .connect()
        .await
        .unwrap();
    let mut g = tonic::client::Grpc::new(channel.clone());
    // Well-framed gRPC messages (flag 0, the right length) whose bytes are no protobuf: an
    // overlong varint, wire type 7, a length-delimited field longer than the message.
    let garbage: [&[u8]; 3] = [&[0xff; 16], &[0x0f, 0x01], &[0x0a, 0x05, 0x61]];
    for bytes in garbage {
        let what = format!("{bytes:02x?}");
        // Unary (Predict) and server-streaming (Rollout) calls.
        g.ready().await.unwrap();
        let e = g
            .unary(
                tonic::Request::new(bytes.to_vec()),
                "/dynaserve.v1.WorldModel/Predict".parse().unwrap(),
                RawCodec,
            )
            .await
            .map(|_| ())
            .expect_err("undecodable Predict answered");
        assert_invalid_request(&e, &format!("Predict {what}"));
        g.ready().await.unwrap();
        let e = g
            .server_streaming(
                tonic::Request::new(bytes.to_vec()),
                "/dynaserve.v1.WorldModel/Rollout".parse().unwrap(),
                RawCodec,
            )
            .await
            .map(|_| ())
            .expect_err("undecodable Rollout answered");
        assert_invalid_request(&e, &format!("Rollout {what}"));
        // The first message of a client stream (Sessions.Interact).
        g.ready().await.unwrap();
        let e = g
            .streaming(
                tonic::Request::new(futures::stream::iter(vec![bytes.to_vec()])),
                "/dynaserve.v1.Sessions/Interact".parse().unwrap(),
                RawCodec,
            )
            .await
            .map(|_| ())
            .expect_err("undecodable Interact opening answered");
        assert_invalid_request(&e, &format!("Interact opening {what}"));
    }
    // A later message of an Interact stream that does not decode ends the stream with the
    // same refusal (not CANCELLED).
    let mut c = dynaserve_client::Client::from_channel(channel);
    let info = c
        .create_session(v1::CreateSessionRequest {
            model: m.name.clone(),
            scene: Some(scene(73, 1, 16).to_proto()),
            dt_steps: 1,
            kinematic: vec![],
            shared: false,
        })
        .await
        .unwrap()
        .info;
    let open = prost::Message::encode_to_vec(&v1::InteractRequest {
        session_id: info.session_id.clone(),
        ..Default::default()
    });
    g.ready().await.unwrap();
    let mut frames = g
        .streaming(
            tonic::Request::new(futures::stream::iter(vec![open, vec![0xff; 16]])),
            "/dynaserve.v1.Sessions/Interact".parse().unwrap(),
            RawCodec,
        )
        .await
        .expect("a valid opening message is accepted")
        .into_inner();
    let e = loop {
        match tokio::time::timeout(HANG, frames.message()).await {
            Ok(Ok(Some(_))) => continue,
            Ok(Ok(None)) => panic!("the stream ended without refusing the undecodable step"),
            Ok(Err(e)) => break e,
            Err(_) => panic!("no answer within {HANG:?}"),
        }
    };
    assert_invalid_request(&e, "Interact step");
    // The server is unharmed: a well-formed call is served on the same connection.
    c.list_models().await.unwrap();
    server.shutdown();
    server.wait().await.unwrap();
}
