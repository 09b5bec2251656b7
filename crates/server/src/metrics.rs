//! Prometheus metrics: every series the server exports, registered, described and initialised
//! at start-up, so a scrape before the first request already lists them all.
//!
//! [`METRICS`] is the single list of metric names, types, labels and help texts; dashboards and
//! alerts are checked against it (`dynaserve serve --print-metrics` prints it). Durations are in
//! seconds (Prometheus convention) with bucket boundaries chosen at millisecond resolution.

use std::time::Duration;

use prometheus::{
    Encoder, GaugeVec, HistogramOpts, HistogramVec, IntCounterVec, IntGauge, IntGaugeVec, Opts,
    Registry, TextEncoder,
};

/// Kind of a Prometheus metric.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MetricKind {
    /// Monotonic counter (`_total`).
    Counter,
    /// Value that goes up and down.
    Gauge,
    /// Bucketed distribution (`_bucket`, `_sum`, `_count`).
    Histogram,
}

impl MetricKind {
    /// The Prometheus `# TYPE` word.
    pub fn as_str(self) -> &'static str {
        match self {
            MetricKind::Counter => "counter",
            MetricKind::Gauge => "gauge",
            MetricKind::Histogram => "histogram",
        }
    }
}

/// Description of one exported metric.
#[derive(Clone, Copy, Debug)]
pub struct MetricSpec {
    /// Full metric name (with the `dynaserve_` prefix).
    pub name: &'static str,
    /// Counter, gauge or histogram.
    pub kind: MetricKind,
    /// Label names.
    pub labels: &'static [&'static str],
    /// Help text (also the `# HELP` line).
    pub help: &'static str,
}

const fn spec(
    name: &'static str,
    kind: MetricKind,
    labels: &'static [&'static str],
    help: &'static str,
) -> MetricSpec {
    MetricSpec {
        name,
        kind,
        labels,
        help,
    }
}

use MetricKind::{Counter, Gauge as G, Histogram as H};

/// Every metric the server exports. Label values: `protocol` in {grpc, http}; `method` in
/// [`METHODS`]; `reason` in [`FAILURE_REASONS`]; `priority` in
/// {interactive, bulk}; `model` is a resident model's name.
pub const METRICS: &[MetricSpec] = &[
    spec(
        "dynaserve_build_info",
        G,
        &["version"],
        "Always 1; the label carries the server version.",
    ),
    spec(
        "dynaserve_ready",
        G,
        &[],
        "1 once every model is loaded and warmed up and the server is not draining, else 0.",
    ),
    spec(
        "dynaserve_models_loaded",
        G,
        &[],
        "Number of resident models.",
    ),
    spec(
        "dynaserve_requests_total",
        Counter,
        &["protocol", "method"],
        "Requests received (counted on arrival).",
    ),
    spec(
        "dynaserve_request_failures_total",
        Counter,
        &["protocol", "method", "reason"],
        "Requests that ended with an error, by reason (gRPC code name in snake case).",
    ),
    spec(
        "dynaserve_request_duration_seconds",
        H,
        &["protocol", "method"],
        "Wall time from arrival to the last response byte or frame, seconds.",
    ),
    spec(
        "dynaserve_queue_wait_seconds",
        H,
        &["model", "priority"],
        "Time a step request waited in the scheduler queue before its batch started, seconds.",
    ),
    spec(
        "dynaserve_queue_depth",
        G,
        &["model", "priority"],
        "Step requests waiting in the scheduler queue.",
    ),
    spec(
        "dynaserve_class_work_total",
        Counter,
        &["model", "priority"],
        "Work run in forward passes by scheduling class: objects (rigid models) or vertices \
         (PhysiFormer) of every step, summed.",
    ),
    spec(
        "dynaserve_batch_scenes",
        H,
        &["model"],
        "Scenes per batched forward pass.",
    ),
    spec(
        "dynaserve_batch_objects",
        H,
        &["model"],
        "Objects per batched forward pass.",
    ),
    spec(
        "dynaserve_forward_duration_seconds",
        H,
        &["model"],
        "Duration of one batched model step, seconds.",
    ),
    spec(
        "dynaserve_scene_steps_total",
        Counter,
        &["model"],
        "Scene-steps computed (one scene advanced by one step); FPS is its rate.",
    ),
    spec(
        "dynaserve_object_steps_total",
        Counter,
        &["model"],
        "Object-steps computed (one object advanced by one step).",
    ),
    spec(
        "dynaserve_scene_steps_per_second",
        G,
        &["model"],
        "Scene-steps computed over the last second (current FPS).",
    ),
    spec(
        "dynaserve_dropped_steps_total",
        Counter,
        &["model", "reason"],
        "Queued step requests dropped before computing them (reason: cancelled, deadline_exceeded).",
    ),
    spec(
        "dynaserve_active_rollouts",
        G,
        &["model"],
        "Rollout streams admitted and not yet finished.",
    ),
    spec(
        "dynaserve_active_predict_variants",
        G,
        &["model"],
        "Scene variants of admitted Predict calls (and candidates of Gradient calls) not yet \
         finished.",
    ),
    spec(
        "dynaserve_sessions_open",
        G,
        &["model"],
        "Sessions held (created or forked, not yet deleted or expired).",
    ),
    spec(
        "dynaserve_sessions_created_total",
        Counter,
        &["model"],
        "Sessions created (CreateSession and Interact streams that create their own).",
    ),
    spec(
        "dynaserve_out_of_range_scenes_total",
        Counter,
        &["model", "parameter"],
        "Request scenes holding objects whose parameter (mass, friction, restitution) is \
         outside the range the model was trained on; each is answered with a warning.",
    ),
    spec(
        "dynaserve_session_forks_total",
        Counter,
        &["model"],
        "Sessions created by Fork.",
    ),
    spec(
        "dynaserve_sessions_reaped_total",
        Counter,
        &["model"],
        "Sessions deleted because they were idle for longer than --session-ttl-s.",
    ),
    spec(
        "dynaserve_stalled_streams_total",
        Counter,
        &["model"],
        "Rollout streams ended because their client read nothing for --stream-stall-timeout-s.",
    ),
    spec(
        "dynaserve_scene_step_failures_total",
        Counter,
        &["model"],
        "Scene-steps that failed (a state outside the model's domain, a non-finite output, a \
         model error or panic); a failure in a shared pass reaches only its own scene.",
    ),
    spec(
        "dynaserve_denoise_steps_total",
        Counter,
        &["model"],
        "Denoising steps completed by Generate samples (one sample advanced by one step); \
         denoising steps per second is its rate. Batch sizes of these passes are \
         dynaserve_batch_scenes of the same model.",
    ),
    spec(
        "dynaserve_generate_sample_seconds",
        H,
        &["model"],
        "Wall time of one Generate sample, from admission to its finished trajectory, seconds.",
    ),
    spec(
        "dynaserve_active_generate_samples",
        G,
        &["model"],
        "Samples of admitted Generate calls not yet finished.",
    ),
    spec(
        "dynaserve_open_connections",
        G,
        &["listener"],
        "Open client connections (listener: grpc, http).",
    ),
    spec(
        "dynaserve_closed_connections_total",
        Counter,
        &["listener", "reason"],
        "Connections the server closed itself, by reason (limit: over --max-connections; \
         timeout: no request in time; tls: failed handshake).",
    ),
];

/// Values of the `listener` label.
pub const LISTENERS: &[&str] = &["grpc", "http"];
/// Values of the `reason` label of `dynaserve_closed_connections_total`.
pub const CLOSE_REASONS: &[&str] = &["limit", "timeout", "tls"];

/// Values of the `reason` label of `dynaserve_request_failures_total`.
pub const FAILURE_REASONS: &[&str] = &[
    "invalid_argument",
    "resource_exhausted",
    "deadline_exceeded",
    "cancelled",
    "unavailable",
    "internal",
];

/// Values of the `protocol` label.
pub const PROTOCOLS: &[&str] = &["grpc", "http"];
/// Values of the `method` label.
pub const METHODS: &[&str] = &[
    "rollout",
    "predict",
    "list_models",
    "create_session",
    "session_step",
    "set_state",
    "get_state",
    "fork_session",
    "delete_session",
    "session_predict",
    "session_gradient",
    "interact",
    "generate",
];
/// Values of the `priority` label.
pub const PRIORITIES: &[&str] = &["interactive", "bulk"];

const DURATION_BUCKETS: &[f64] = &[
    0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 300.0,
];
const QUEUE_BUCKETS: &[f64] = &[
    0.0001, 0.00025, 0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.05, 0.1, 0.25, 0.5, 1.0, 5.0,
];
const FORWARD_BUCKETS: &[f64] = &[
    0.0005, 0.001, 0.002, 0.004, 0.006, 0.008, 0.01, 0.015, 0.02, 0.03, 0.05, 0.075, 0.1, 0.15,
    0.2, 0.3, 0.5, 1.0, 2.0,
];
const COUNT_BUCKETS: &[f64] = &[
    1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0, 512.0, 1024.0, 2048.0, 4096.0,
];

fn find(name: &str) -> &'static MetricSpec {
    METRICS
        .iter()
        .find(|m| m.name == name)
        .unwrap_or_else(|| panic!("metric {name} is missing from METRICS"))
}

fn counter(registry: &Registry, name: &str) -> IntCounterVec {
    let s = find(name);
    let c = IntCounterVec::new(Opts::new(s.name, s.help), s.labels).expect("valid counter");
    registry.register(Box::new(c.clone())).expect("unique");
    c
}

fn gauge(registry: &Registry, name: &str) -> IntGaugeVec {
    let s = find(name);
    let g = IntGaugeVec::new(Opts::new(s.name, s.help), s.labels).expect("valid gauge");
    registry.register(Box::new(g.clone())).expect("unique");
    g
}

fn histogram(registry: &Registry, name: &str, buckets: &[f64]) -> HistogramVec {
    let s = find(name);
    let h = HistogramVec::new(
        HistogramOpts::new(s.name, s.help).buckets(buckets.to_vec()),
        s.labels,
    )
    .expect("valid histogram");
    registry.register(Box::new(h.clone())).expect("unique");
    h
}

/// All metric handles, sharing one registry.
#[derive(Clone)]
pub struct Metrics {
    registry: Registry,
    /// `dynaserve_ready`.
    pub ready: IntGauge,
    /// `dynaserve_models_loaded`.
    pub models_loaded: IntGauge,
    /// `dynaserve_requests_total`.
    pub requests: IntCounterVec,
    /// `dynaserve_request_failures_total`.
    pub failures: IntCounterVec,
    /// `dynaserve_request_duration_seconds`.
    pub request_duration: HistogramVec,
    /// `dynaserve_queue_wait_seconds`.
    pub queue_wait: HistogramVec,
    /// `dynaserve_queue_depth`.
    pub queue_depth: IntGaugeVec,
    /// `dynaserve_class_work_total`.
    pub class_work: IntCounterVec,
    /// `dynaserve_batch_scenes`.
    pub batch_scenes: HistogramVec,
    /// `dynaserve_batch_objects`.
    pub batch_objects: HistogramVec,
    /// `dynaserve_forward_duration_seconds`.
    pub forward_duration: HistogramVec,
    /// `dynaserve_scene_steps_total`.
    pub scene_steps: IntCounterVec,
    /// `dynaserve_object_steps_total`.
    pub object_steps: IntCounterVec,
    /// `dynaserve_scene_steps_per_second`.
    pub fps: GaugeVec,
    /// `dynaserve_dropped_steps_total`.
    pub dropped: IntCounterVec,
    /// `dynaserve_active_rollouts`.
    pub active_rollouts: IntGaugeVec,
    /// `dynaserve_active_predict_variants`.
    pub active_predict: IntGaugeVec,
    /// `dynaserve_sessions_open`.
    pub sessions_open: IntGaugeVec,
    /// `dynaserve_sessions_created_total`.
    pub sessions_created: IntCounterVec,
    /// `dynaserve_out_of_range_scenes_total`.
    pub out_of_range_scenes: IntCounterVec,
    /// `dynaserve_session_forks_total`.
    pub session_forks: IntCounterVec,
    /// `dynaserve_sessions_reaped_total`.
    pub sessions_reaped: IntCounterVec,
    /// `dynaserve_stalled_streams_total`.
    pub stalled_streams: IntCounterVec,
    /// `dynaserve_scene_step_failures_total`.
    pub scene_step_failures: IntCounterVec,
    /// `dynaserve_denoise_steps_total`.
    pub denoise_steps: IntCounterVec,
    /// `dynaserve_generate_sample_seconds`.
    pub generate_sample_seconds: HistogramVec,
    /// `dynaserve_active_generate_samples`.
    pub active_generate_samples: IntGaugeVec,
    /// `dynaserve_open_connections`.
    pub open_connections: IntGaugeVec,
    /// `dynaserve_closed_connections_total`.
    pub closed_connections: IntCounterVec,
}

impl Metrics {
    /// Registers every metric of [`METRICS`] and creates the series of every known label
    /// combination for `models`, so all of them are listed (at zero) before the first request.
    pub fn new(models: &[String]) -> Metrics {
        let registry = Registry::new();
        let build = gauge(&registry, "dynaserve_build_info");
        build.with_label_values(&[env!("CARGO_PKG_VERSION")]).set(1);
        let ready = gauge(&registry, "dynaserve_ready").with_label_values(&[] as &[&str]);
        let models_loaded =
            gauge(&registry, "dynaserve_models_loaded").with_label_values(&[] as &[&str]);
        let fps_spec = find("dynaserve_scene_steps_per_second");
        let fps = GaugeVec::new(Opts::new(fps_spec.name, fps_spec.help), fps_spec.labels)
            .expect("valid gauge");
        let m = Metrics {
            ready,
            models_loaded,
            requests: counter(&registry, "dynaserve_requests_total"),
            failures: counter(&registry, "dynaserve_request_failures_total"),
            request_duration: histogram(
                &registry,
                "dynaserve_request_duration_seconds",
                DURATION_BUCKETS,
            ),
            queue_wait: histogram(&registry, "dynaserve_queue_wait_seconds", QUEUE_BUCKETS),
            queue_depth: gauge(&registry, "dynaserve_queue_depth"),
            class_work: counter(&registry, "dynaserve_class_work_total"),
            batch_scenes: histogram(&registry, "dynaserve_batch_scenes", COUNT_BUCKETS),
            batch_objects: histogram(&registry, "dynaserve_batch_objects", COUNT_BUCKETS),
            forward_duration: histogram(
                &registry,
                "dynaserve_forward_duration_seconds",
                FORWARD_BUCKETS,
            ),
            scene_steps: counter(&registry, "dynaserve_scene_steps_total"),
            object_steps: counter(&registry, "dynaserve_object_steps_total"),
            fps: fps.clone(),
            dropped: counter(&registry, "dynaserve_dropped_steps_total"),
            active_rollouts: gauge(&registry, "dynaserve_active_rollouts"),
            active_predict: gauge(&registry, "dynaserve_active_predict_variants"),
            sessions_open: gauge(&registry, "dynaserve_sessions_open"),
            sessions_created: counter(&registry, "dynaserve_sessions_created_total"),
            out_of_range_scenes: counter(&registry, "dynaserve_out_of_range_scenes_total"),
            session_forks: counter(&registry, "dynaserve_session_forks_total"),
            sessions_reaped: counter(&registry, "dynaserve_sessions_reaped_total"),
            stalled_streams: counter(&registry, "dynaserve_stalled_streams_total"),
            scene_step_failures: counter(&registry, "dynaserve_scene_step_failures_total"),
            denoise_steps: counter(&registry, "dynaserve_denoise_steps_total"),
            generate_sample_seconds: histogram(
                &registry,
                "dynaserve_generate_sample_seconds",
                DURATION_BUCKETS,
            ),
            active_generate_samples: gauge(&registry, "dynaserve_active_generate_samples"),
            open_connections: gauge(&registry, "dynaserve_open_connections"),
            closed_connections: counter(&registry, "dynaserve_closed_connections_total"),
            registry,
        };
        m.registry
            .register(Box::new(fps))
            .expect("unique metric name");
        m.models_loaded.set(models.len() as i64);
        for p in PROTOCOLS {
            for meth in METHODS {
                m.requests.with_label_values(&[p, meth]);
                m.request_duration.with_label_values(&[p, meth]);
                for r in FAILURE_REASONS {
                    m.failures.with_label_values(&[p, meth, r]);
                }
            }
        }
        for l in LISTENERS {
            m.open_connections.with_label_values(&[l]);
            for r in CLOSE_REASONS {
                m.closed_connections.with_label_values(&[l, r]);
            }
        }
        for model in models {
            let model = model.as_str();
            m.stalled_streams.with_label_values(&[model]);
            m.scene_step_failures.with_label_values(&[model]);
            for pr in PRIORITIES {
                m.queue_wait.with_label_values(&[model, pr]);
                m.queue_depth.with_label_values(&[model, pr]);
                m.class_work.with_label_values(&[model, pr]);
            }
            m.batch_scenes.with_label_values(&[model]);
            m.batch_objects.with_label_values(&[model]);
            m.forward_duration.with_label_values(&[model]);
            m.scene_steps.with_label_values(&[model]);
            m.object_steps.with_label_values(&[model]);
            m.fps.with_label_values(&[model]);
            m.active_rollouts.with_label_values(&[model]);
            m.active_predict.with_label_values(&[model]);
            m.sessions_open.with_label_values(&[model]);
            m.sessions_created.with_label_values(&[model]);
            m.session_forks.with_label_values(&[model]);
            for parameter in ["mass", "friction", "restitution"] {
                m.out_of_range_scenes.with_label_values(&[model, parameter]);
            }
            m.sessions_reaped.with_label_values(&[model]);
            m.denoise_steps.with_label_values(&[model]);
            m.generate_sample_seconds.with_label_values(&[model]);
            m.active_generate_samples.with_label_values(&[model]);
            for r in ["cancelled", "deadline_exceeded"] {
                m.dropped.with_label_values(&[model, r]);
            }
        }
        m
    }

    /// The registry (for tests and custom exporters).
    pub fn registry(&self) -> &Registry {
        &self.registry
    }

    /// Renders every metric in the Prometheus text exposition format (version 0.0.4).
    pub fn render(&self) -> String {
        let mut buf = Vec::new();
        let encoder = TextEncoder::new();
        // Encoding into a Vec cannot fail for well-formed families.
        if let Err(e) = encoder.encode(&self.registry.gather(), &mut buf) {
            tracing::error!(error = %e, "cannot encode metrics");
        }
        String::from_utf8(buf).unwrap_or_default()
    }

    /// Records the outcome of one request.
    pub fn finish_request(
        &self,
        protocol: &str,
        method: &str,
        elapsed: Duration,
        failure: Option<&str>,
    ) {
        self.request_duration
            .with_label_values(&[protocol, method])
            .observe(elapsed.as_secs_f64());
        if let Some(reason) = failure {
            self.failures
                .with_label_values(&[protocol, method, reason])
                .inc();
        }
    }
}

/// The metric list as a table (name, type, labels, help), one metric per line.
pub fn metrics_table() -> String {
    let mut out = String::new();
    for m in METRICS {
        out.push_str(&format!(
            "{}\t{}\t{}\t{}\n",
            m.name,
            m.kind.as_str(),
            m.labels.join(","),
            m.help
        ));
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_listed_metric_is_exported_before_any_request() {
        let m = Metrics::new(&["a".to_string()]);
        let text = m.render();
        for spec in METRICS {
            assert!(
                text.contains(&format!("# TYPE {} {}", spec.name, spec.kind.as_str())),
                "{} missing from\n{text}",
                spec.name
            );
            assert!(text.contains(&format!("# HELP {} ", spec.name)));
        }
        // And nothing is exported that the list does not name.
        for fam in m.registry().gather() {
            assert!(
                METRICS.iter().any(|s| s.name == fam.name()),
                "{}",
                fam.name()
            );
            assert!(fam.name().starts_with("dynaserve_"));
        }
    }
}
