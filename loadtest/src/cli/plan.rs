//! The parsed command line turned into a run: the load ([`build_load`], with every flag
//! checked) and the one or two sides it goes to ([`plan_sides`]).

use std::time::Duration;

use super::args::{Cli, Common, ModeCmd};
use crate::run::{Load, Mode, SoakPlan, Target, Transport};
use crate::scenes::SceneSource;

/// Parses a duration: a number of seconds, or a number followed by `ms`, `s`, `m` or `h`.
pub fn parse_duration(text: &str) -> anyhow::Result<Duration> {
    let t = text.trim();
    let split = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (number, unit) = t.split_at(split);
    let value: f64 = number
        .parse()
        .map_err(|_| anyhow::anyhow!("{text:?} is not a duration (e.g. 600, 90s, 10m, 1h)"))?;
    let scale = match unit.trim() {
        "" | "s" => 1.0,
        "ms" => 1e-3,
        "m" | "min" => 60.0,
        "h" => 3600.0,
        u => anyhow::bail!("{text:?}: unknown unit {u:?} (use ms, s, m or h)"),
    };
    seconds("--duration", value * scale)
}

/// `s` seconds as a duration; `name` is the flag named when it is negative or not finite.
pub(super) fn seconds(name: &str, s: f64) -> anyhow::Result<Duration> {
    anyhow::ensure!(
        s.is_finite() && s >= 0.0,
        "{name} must be a number of seconds >= 0"
    );
    Ok(Duration::from_secs_f64(s))
}

fn pick<T: Clone>(list: &[T], i: usize) -> Option<T> {
    list.get(i).or(list.first()).cloned()
}

/// A side before its server is (optionally) launched.
#[derive(Clone, Debug)]
pub struct SidePlan {
    /// Target template (URL filled in from the spawned server when `spawn` is set).
    pub target: Target,
    /// Command to launch, for remote sides.
    pub spawn: Option<String>,
}

/// Default metrics URL of a target: HTTP targets' own `/metrics`, gRPC targets' host on 8080.
pub fn default_metrics_url(transport: Transport, url: &str) -> Option<String> {
    match transport {
        Transport::Http => Some(format!("{}/metrics", url.trim_end_matches('/'))),
        Transport::Grpc => {
            let base = dynaserve_client::http::HttpBase::parse(url).ok()?;
            let host = dynaserve_client::http::HttpBase {
                host: base.host,
                port: 8080,
            };
            Some(format!("http://{}/metrics", host.authority()))
        }
        Transport::Inprocess => None,
    }
}

/// Splits the per-side flags into one or two side plans.
pub fn plan_sides(c: &Common) -> anyhow::Result<Vec<SidePlan>> {
    let most = [
        c.transport.len(),
        c.target.len(),
        c.metrics_url.len(),
        c.spawn.len(),
        c.label.len(),
    ]
    .into_iter()
    .max()
    .unwrap_or(0);
    anyhow::ensure!(
        most <= 2,
        "per-side flags (--transport, --target, --metrics-url, --spawn, --label) may be given at most twice"
    );
    let n = if c.compare { 2 } else { 1 };
    anyhow::ensure!(
        c.compare || most <= 1,
        "a per-side flag was given twice: add --compare to run two sides"
    );
    anyhow::ensure!(
        !c.compare || most == 2 || c.transport.len() == 1 || !c.spawn.is_empty(),
        "--compare needs two sides: give --target, --transport or --spawn twice"
    );
    anyhow::ensure!(c.connections >= 1, "--connections must be at least 1");
    let mut out = Vec::new();
    for i in 0..n {
        let transport = pick(&c.transport, i).unwrap_or(Transport::Grpc);
        let spawn = match transport {
            Transport::Inprocess => None,
            _ => pick(&c.spawn, i),
        };
        let url = pick(&c.target, i).unwrap_or_else(|| match transport {
            Transport::Http => "http://127.0.0.1:8080".into(),
            _ => "http://127.0.0.1:50051".into(),
        });
        let metrics_url = if c.no_metrics {
            None
        } else {
            pick(&c.metrics_url, i).or_else(|| default_metrics_url(transport, &url))
        };
        out.push(SidePlan {
            target: Target {
                label: c
                    .label
                    .get(i)
                    .cloned()
                    .unwrap_or_else(|| ["A", "B"][i].to_string()),
                transport,
                url,
                metrics_url,
                connections: c.connections,
                model_dir: c.model_dir.clone(),
                max_batch_scenes: c.max_batch_scenes,
                max_batch_objects: c.max_batch_objects,
                spawned: None,
                pid: None,
            },
            spawn,
        });
    }
    if n == 2 {
        let (a, b) = (&out[0], &out[1]);
        anyhow::ensure!(
            a.target.transport != b.target.transport
                || a.target.url != b.target.url
                || a.spawn != b.spawn
                || a.spawn.is_some(),
            "--compare: both sides are the same; give two targets, transports or spawn commands"
        );
    }
    Ok(out)
}

/// Builds the load description from the parsed command line.
pub fn build_load(cli: &Cli) -> anyhow::Result<(Load, Common)> {
    let (mode, common) = match &cli.mode {
        ModeCmd::Generate(_) => anyhow::bail!("generate runs on its own (generate_mode::run)"),
        ModeCmd::Fairness(_) => anyhow::bail!("fairness runs on its own (fairness::run)"),
        ModeCmd::Streams(a) => {
            anyhow::ensure!(
                !a.streams.is_empty() && a.streams.iter().all(|&s| s >= 1),
                "--streams must list counts >= 1"
            );
            (
                Mode::Streams {
                    levels: a.streams.clone(),
                    duration: a
                        .duration_s
                        .map(|d| seconds("--duration-s", d))
                        .transpose()?,
                },
                a.common.clone(),
            )
        }
        ModeCmd::Predict(a) => {
            anyhow::ensure!(
                a.variants >= 1 && a.calls >= 1 && a.concurrency >= 1,
                "--variants, --calls and --concurrency must be at least 1"
            );
            (
                Mode::Predict {
                    variants: a.variants,
                    calls: a.calls,
                    concurrency: a.concurrency,
                    every: a.every,
                },
                a.common.clone(),
            )
        }
        ModeCmd::Poisson(a) => {
            anyhow::ensure!(
                a.rate.is_finite() && a.rate > 0.0,
                "--rate must be a positive number of arrivals per second"
            );
            (
                Mode::Poisson {
                    rate: a.rate,
                    duration: seconds("--duration-s", a.duration_s)?,
                    seed: a.common.seed,
                    max_in_flight: a.max_in_flight.max(1),
                },
                a.common.clone(),
            )
        }
        ModeCmd::Ramp(a) => {
            anyhow::ensure!(
                a.start >= 1 && a.max_concurrency >= a.start && a.factor >= 2,
                "ramp needs 1 <= --start <= --max-concurrency and --factor >= 2"
            );
            (
                Mode::Ramp {
                    start: a.start,
                    factor: a.factor,
                    max: a.max_concurrency,
                    p99_bound_ms: a.p99_bound_ms,
                    level_duration: seconds("--level-duration-s", a.level_duration_s)?,
                },
                a.common.clone(),
            )
        }
        ModeCmd::Soak(a) => {
            anyhow::ensure!(a.streams >= 1, "--streams must be at least 1");
            anyhow::ensure!(
                (0.0..=1.0).contains(&a.drop_probability),
                "--drop-probability must be in [0, 1]"
            );
            let rss_interval = seconds("--rss-interval-s", a.rss_interval_s)?;
            anyhow::ensure!(
                rss_interval >= Duration::from_millis(100),
                "--rss-interval-s must be at least 0.1"
            );
            (
                Mode::Soak(SoakPlan {
                    streams: a.streams,
                    duration: parse_duration(&a.duration)?,
                    drop_probability: a.drop_probability,
                    rss_interval,
                    seed: a.common.seed,
                }),
                a.common.clone(),
            )
        }
    };
    if let Mode::Soak(_) = mode {
        anyhow::ensure!(
            !common.compare,
            "soak runs against one server: --compare does not apply"
        );
        anyhow::ensure!(
            !common.transport.contains(&Transport::Inprocess),
            "the soak checks a server's streams: use --transport grpc or http"
        );
    }
    let scenes = if common.scene.is_empty() {
        anyhow::ensure!(
            common.objects >= 1 && common.points >= 1,
            "--objects and --points must be at least 1"
        );
        SceneSource::Generated {
            objects: common.objects,
            points: common.points,
            seed: common.seed,
        }
    } else {
        SceneSource::from_files(&common.scene)?
    };
    let file = scenes.file_steps();
    let steps = common.steps.or(file.map(|f| f.0)).unwrap_or(50);
    let dt_steps = common.dt_steps.or(file.map(|f| f.1)).unwrap_or(1);
    anyhow::ensure!(steps >= 1, "--steps must be at least 1");
    Ok((
        Load {
            mode,
            scenes,
            steps,
            dt_steps: dt_steps.max(1),
            model: common.model.clone(),
            timeout_ms: common.timeout_ms,
            warmup: seconds("--warmup-s", common.warmup_s)?,
        },
        common,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    fn parse(args: &[&str]) -> anyhow::Result<(Load, Vec<SidePlan>)> {
        let mut v = vec!["dynaserve-loadtest"];
        v.extend_from_slice(args);
        let cli = Cli::try_parse_from(v)?;
        let (load, common) = build_load(&cli)?;
        Ok((load, plan_sides(&common)?))
    }

    #[test]
    fn defaults_and_sides() {
        let (load, sides) = parse(&["streams", "--streams", "1,8", "--steps", "5"]).unwrap();
        assert_eq!(
            load.mode,
            Mode::Streams {
                levels: vec![1, 8],
                duration: None
            }
        );
        assert_eq!(load.steps, 5);
        assert_eq!(sides.len(), 1);
        assert_eq!(sides[0].target.url, "http://127.0.0.1:50051");
        assert_eq!(
            sides[0].target.metrics_url.as_deref(),
            Some("http://127.0.0.1:8080/metrics")
        );
        let (_, sides) = parse(&[
            "predict",
            "--compare",
            "--transport",
            "inprocess",
            "--transport",
            "grpc",
            "--spawn",
            "dynaserve serve",
        ])
        .unwrap();
        assert_eq!(sides[0].target.transport, Transport::Inprocess);
        assert!(sides[0].spawn.is_none());
        assert_eq!(sides[1].spawn.as_deref(), Some("dynaserve serve"));
        assert_eq!(sides[1].target.label, "B");
        let (_, sides) = parse(&["ramp", "--transport", "http", "--target", "http://h:9"]).unwrap();
        assert_eq!(
            sides[0].target.metrics_url.as_deref(),
            Some("http://h:9/metrics")
        );
    }

    #[test]
    fn soak_flags_and_durations() {
        let (load, sides) = parse(&["soak", "--duration", "90s", "--steps", "120"]).unwrap();
        let Mode::Soak(p) = &load.mode else {
            panic!("{:?}", load.mode)
        };
        assert_eq!(p.streams, 64);
        assert_eq!(p.duration, Duration::from_secs(90));
        assert_eq!(p.drop_probability, 0.3);
        assert_eq!(load.steps, 120);
        assert_eq!(sides.len(), 1);
        assert_eq!(parse_duration("10m").unwrap(), Duration::from_secs(600));
        assert_eq!(parse_duration("600").unwrap(), Duration::from_secs(600));
        assert_eq!(parse_duration("1.5h").unwrap(), Duration::from_secs(5400));
        assert_eq!(parse_duration("250ms").unwrap(), Duration::from_millis(250));
        assert!(parse_duration("m").is_err());
        assert!(parse_duration("-5s").is_err());
    }

    #[test]
    fn bad_flag_combinations_are_errors() {
        assert!(
            parse(&[
                "streams",
                "--target",
                "http://a:1",
                "--target",
                "http://b:1"
            ])
            .is_err()
        );
        assert!(parse(&["streams", "--compare"]).is_err());
        assert!(parse(&["streams", "--streams", "0"]).is_err());
        assert!(parse(&["poisson", "--rate", "-1"]).is_err());
        assert!(parse(&["ramp", "--start", "8", "--max-concurrency", "4"]).is_err());
        assert!(parse(&["streams", "--scene", "does-not-exist.json"]).is_err());
        assert!(parse(&["streams", "--warmup-s", "-2"]).is_err());
        assert!(parse(&["soak", "--drop-probability", "1.5"]).is_err());
        assert!(parse(&["soak", "--duration", "10 parsecs"]).is_err());
        assert!(parse(&["soak", "--transport", "inprocess"]).is_err());
        assert!(
            parse(&[
                "soak",
                "--compare",
                "--target",
                "http://a:1",
                "--target",
                "http://b:1"
            ])
            .is_err()
        );
    }
}
