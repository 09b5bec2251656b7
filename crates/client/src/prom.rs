//! The one reader of the Prometheus text format (what the server's `/metrics` answers):
//! samples ([`parse`], [`value`]), a strict check of the exposition ([`check_exposition`]),
//! and histogram arithmetic (a load run scrapes before and after; the difference of the
//! cumulative buckets is what the run contributed).

use std::collections::BTreeMap;

use serde::Serialize;

/// One sample line: metric name, labels in file order, value.
#[derive(Clone, Debug, PartialEq)]
pub struct Sample {
    /// Series name, e.g. `dynaserve_batch_scenes_bucket`.
    pub name: String,
    /// `(label, value)` pairs, unescaped.
    pub labels: Vec<(String, String)>,
    /// Sample value (`+Inf`, `-Inf` and `NaN` are accepted).
    pub value: f64,
}

impl Sample {
    /// Value of label `key`, if present.
    pub fn label(&self, key: &str) -> Option<&str> {
        self.labels
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }
}

fn parse_value(s: &str) -> Option<f64> {
    match s {
        "+Inf" | "Inf" => Some(f64::INFINITY),
        "-Inf" => Some(f64::NEG_INFINITY),
        "NaN" => Some(f64::NAN),
        _ => s.parse().ok(),
    }
}

/// Parses `key="value",...` (the inside of the braces); `None` on malformed input.
fn parse_labels(s: &str) -> Option<Vec<(String, String)>> {
    let mut out = Vec::new();
    let mut rest = s.trim();
    while !rest.is_empty() {
        let eq = rest.find('=')?;
        let key = rest[..eq].trim().to_string();
        rest = rest[eq + 1..].trim_start();
        let mut chars = rest.char_indices();
        if chars.next()?.1 != '"' {
            return None;
        }
        let mut value = String::new();
        let mut end = None;
        let mut escaped = false;
        for (i, c) in chars {
            if escaped {
                value.push(match c {
                    'n' => '\n',
                    other => other,
                });
                escaped = false;
            } else if c == '\\' {
                escaped = true;
            } else if c == '"' {
                end = Some(i);
                break;
            } else {
                value.push(c);
            }
        }
        let end = end?;
        out.push((key, value));
        rest = rest[end + 1..].trim_start();
        rest = rest.strip_prefix(',').unwrap_or(rest).trim_start();
    }
    Some(out)
}

/// Parses the Prometheus text exposition format; comments and malformed lines are skipped.
pub fn parse(text: &str) -> Vec<Sample> {
    let mut out = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (name, labels, rest) = match line.find('{') {
            Some(open) => {
                let Some(close) = line.rfind('}') else {
                    continue;
                };
                let Some(labels) = parse_labels(&line[open + 1..close]) else {
                    continue;
                };
                (&line[..open], labels, &line[close + 1..])
            }
            None => match line.split_once(char::is_whitespace) {
                Some((n, r)) => (n, Vec::new(), r),
                None => continue,
            },
        };
        // The value may be followed by a timestamp.
        let Some(value) = rest.split_whitespace().next().and_then(parse_value) else {
            continue;
        };
        out.push(Sample {
            name: name.trim().to_string(),
            labels,
            value,
        });
    }
    out
}

/// Value of one series, given as it is written in the text (`dynaserve_ready`,
/// `dynaserve_batch_scenes_bucket{model="m",le="1"}`); label order does not matter.
pub fn value(text: &str, series: &str) -> Option<f64> {
    let (name, labels) = match series.find('{') {
        Some(open) => (
            &series[..open],
            parse_labels(series[open + 1..].strip_suffix('}')?)?,
        ),
        None => (series, Vec::new()),
    };
    let mut wanted = labels;
    wanted.sort();
    parse(text).into_iter().find_map(|s| {
        let mut have = s.labels.clone();
        have.sort();
        (s.name == name && have == wanted).then_some(s.value)
    })
}

fn valid_name(n: &str) -> bool {
    let mut chars = n.chars();
    chars
        .next()
        .is_some_and(|c| c.is_ascii_alphabetic() || c == '_' || c == ':')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_' || c == ':')
}

/// Checks a whole exposition strictly (format 0.0.4): every line well formed, every family with
/// one `# HELP` and one `# TYPE`, every sample of a declared family, every histogram with its
/// `_bucket`, `_sum` and `_count` series. Returns family name -> type (`counter`, `gauge`,
/// `histogram`, ...) or the first problem found.
pub fn check_exposition(text: &str) -> Result<BTreeMap<String, String>, String> {
    let mut types: BTreeMap<String, String> = BTreeMap::new();
    let mut helps = 0;
    let mut seen: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for line in text.lines().filter(|l| !l.is_empty()) {
        if let Some(rest) = line.strip_prefix("# HELP ") {
            let (name, _) = rest
                .split_once(' ')
                .ok_or(format!("HELP without text: {line}"))?;
            if !valid_name(name) {
                return Err(format!("bad name {name}"));
            }
            helps += 1;
            continue;
        }
        if let Some(rest) = line.strip_prefix("# TYPE ") {
            let (name, kind) = rest
                .split_once(' ')
                .ok_or(format!("TYPE without kind: {line}"))?;
            if !["counter", "gauge", "histogram", "summary", "untyped"].contains(&kind) {
                return Err(format!("bad type {kind}"));
            }
            if types.insert(name.to_string(), kind.to_string()).is_some() {
                return Err(format!("duplicate TYPE {name}"));
            }
            continue;
        }
        if line.starts_with('#') {
            return Err(format!("unexpected comment {line}"));
        }
        let (series, v) = line.rsplit_once(' ').ok_or(format!("no value: {line}"))?;
        if parse_value(v).is_none() {
            return Err(format!("bad value in {line}"));
        }
        let name = match series.split_once('{') {
            Some((n, l)) => {
                let l = l
                    .strip_suffix('}')
                    .ok_or(format!("no closing brace: {line}"))?;
                let labels = parse_labels(l).ok_or(format!("malformed labels: {line}"))?;
                if let Some((k, _)) = labels.iter().find(|(k, _)| !valid_name(k)) {
                    return Err(format!("bad label {k}"));
                }
                n
            }
            None => series,
        };
        if !valid_name(name) {
            return Err(format!("bad metric name {name}"));
        }
        let family = ["_bucket", "_sum", "_count"]
            .iter()
            .find_map(|s| {
                name.strip_suffix(s)
                    .filter(|f| types.get(*f).is_some_and(|t| t == "histogram"))
            })
            .unwrap_or(name);
        if !types.contains_key(family) {
            return Err(format!("sample {name} without TYPE"));
        }
        seen.entry(family.to_string())
            .or_default()
            .push(name.to_string());
    }
    if helps != types.len() {
        return Err(format!("{helps} HELP lines for {} families", types.len()));
    }
    for (f, t) in &types {
        if t == "histogram" {
            let names = seen.get(f).map(Vec::as_slice).unwrap_or_default();
            for s in ["_bucket", "_sum", "_count"] {
                if !names.iter().any(|n| *n == format!("{f}{s}")) {
                    return Err(format!("{f} lacks {s}"));
                }
            }
        }
    }
    Ok(types)
}

/// Sum of the values of every series named `name` whose labels pass `filter`.
pub fn sum(samples: &[Sample], name: &str, filter: impl Fn(&Sample) -> bool) -> f64 {
    samples
        .iter()
        .filter(|s| s.name == name && filter(s))
        .map(|s| s.value)
        .sum()
}

/// A cumulative histogram: `buckets[i] = (upper bound, observations <= bound)`, ascending by
/// bound, the last bound `+Inf`; plus the sum and count of the observations.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct Histogram {
    /// `(le, cumulative count)` pairs, ascending.
    pub buckets: Vec<(f64, f64)>,
    /// Sum of the observed values.
    pub sum: f64,
    /// Number of observations.
    pub count: f64,
}

impl Histogram {
    /// Histogram `name` (without the `_bucket` suffix) summed over every label set that
    /// passes `filter` (the `le` label is ignored by the filter's caller). `None` when the
    /// metric is absent.
    pub fn from_samples(
        samples: &[Sample],
        name: &str,
        filter: impl Fn(&Sample) -> bool,
    ) -> Option<Histogram> {
        let bucket_name = format!("{name}_bucket");
        let mut buckets: Vec<(f64, f64)> = Vec::new();
        let mut found = false;
        for s in samples
            .iter()
            .filter(|s| s.name == bucket_name && filter(s))
        {
            let Some(le) = s.label("le").and_then(parse_value) else {
                continue;
            };
            found = true;
            match buckets.iter_mut().find(|(b, _)| *b == le) {
                Some(b) => b.1 += s.value,
                None => buckets.push((le, s.value)),
            }
        }
        if !found {
            return None;
        }
        buckets.sort_by(|a, b| a.0.total_cmp(&b.0));
        Some(Histogram {
            buckets,
            sum: sum(samples, &format!("{name}_sum"), &filter),
            count: sum(samples, &format!("{name}_count"), &filter),
        })
    }

    /// `self - before`: the observations made between two scrapes. Buckets missing from
    /// `before` count as zero there.
    pub fn diff(&self, before: &Histogram) -> Histogram {
        let buckets = self
            .buckets
            .iter()
            .map(|&(le, c)| {
                let b = before
                    .buckets
                    .iter()
                    .find(|(l, _)| *l == le)
                    .map_or(0.0, |x| x.1);
                (le, (c - b).max(0.0))
            })
            .collect();
        Histogram {
            buckets,
            sum: self.sum - before.sum,
            count: (self.count - before.count).max(0.0),
        }
    }

    /// Exact mean of the observations (`sum / count`); 0 when empty.
    pub fn mean(&self) -> f64 {
        if self.count > 0.0 {
            self.sum / self.count
        } else {
            0.0
        }
    }

    /// Upper bound of the bucket holding quantile `q` (in `[0, 1]`): at least a fraction `q`
    /// of the observations are `<=` it. For the `+Inf` bucket the largest finite bound is
    /// returned. 0 when empty.
    pub fn quantile_upper(&self, q: f64) -> f64 {
        let total = self.buckets.last().map_or(0.0, |b| b.1);
        if total <= 0.0 {
            return 0.0;
        }
        let rank = (q.clamp(0.0, 1.0) * total).max(f64::MIN_POSITIVE);
        let mut last_finite = 0.0;
        for &(le, c) in &self.buckets {
            if le.is_finite() {
                last_finite = le;
            }
            if c >= rank {
                return if le.is_finite() { le } else { last_finite };
            }
        }
        last_finite
    }

    /// Quantile `q` estimated like PromQL's `histogram_quantile`: linear interpolation inside
    /// the bucket that holds the rank, the first bucket starting at 0, the `+Inf` bucket
    /// answered with the largest finite bound. 0 when empty.
    pub fn quantile_interpolated(&self, q: f64) -> f64 {
        let total = self.buckets.last().map_or(0.0, |b| b.1);
        if total <= 0.0 {
            return 0.0;
        }
        let rank = q.clamp(0.0, 1.0) * total;
        let mut prev_le = 0.0;
        let mut prev_c = 0.0;
        for &(le, c) in &self.buckets {
            if c >= rank && c > prev_c {
                if !le.is_finite() {
                    return prev_le;
                }
                return prev_le + (le - prev_le) * (rank - prev_c) / (c - prev_c);
            }
            if le.is_finite() {
                prev_le = le;
            }
            prev_c = c;
        }
        prev_le
    }

    /// Observations per bucket (not cumulative): `(lower bound, upper bound, count)` for every
    /// non-empty bucket.
    pub fn nonempty_buckets(&self) -> Vec<(f64, f64, f64)> {
        let mut out = Vec::new();
        let mut prev_le = 0.0;
        let mut prev_c = 0.0;
        for &(le, c) in &self.buckets {
            if c - prev_c > 0.0 {
                out.push((prev_le, le, c - prev_c));
            }
            prev_le = le;
            prev_c = c;
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const BEFORE: &str = r#"# HELP dynaserve_batch_scenes Scenes per batched forward pass.
# TYPE dynaserve_batch_scenes histogram
dynaserve_batch_scenes_bucket{model="m",le="1"} 5
dynaserve_batch_scenes_bucket{model="m",le="2"} 5
dynaserve_batch_scenes_bucket{model="m",le="4"} 6
dynaserve_batch_scenes_bucket{model="m",le="8"} 6
dynaserve_batch_scenes_bucket{model="m",le="+Inf"} 6
dynaserve_batch_scenes_sum{model="m"} 8
dynaserve_batch_scenes_count{model="m"} 6
dynaserve_queue_wait_seconds_bucket{model="m",priority="interactive",le="0.001"} 1
dynaserve_queue_wait_seconds_bucket{model="m",priority="interactive",le="+Inf"} 1
dynaserve_queue_wait_seconds_sum{model="m",priority="interactive"} 0.0005
dynaserve_queue_wait_seconds_count{model="m",priority="interactive"} 1
dynaserve_queue_wait_seconds_bucket{model="m",priority="bulk",le="0.001"} 0
dynaserve_queue_wait_seconds_bucket{model="m",priority="bulk",le="+Inf"} 3
dynaserve_queue_wait_seconds_sum{model="m",priority="bulk"} 6
dynaserve_queue_wait_seconds_count{model="m",priority="bulk"} 3
dynaserve_scene_steps_total{model="m"} 11
dynaserve_build_info{version="0.1.0"} 1
weird{a="x\"y,z",b="c"} 2.5 1700000000
"#;

    fn after() -> String {
        BEFORE
            .replace("le=\"4\"} 6", "le=\"4\"} 16")
            .replace("le=\"8\"} 6", "le=\"8\"} 26")
            .replace("le=\"+Inf\"} 6", "le=\"+Inf\"} 26")
            .replace("_sum{model=\"m\"} 8", "_sum{model=\"m\"} 148")
            .replace("_count{model=\"m\"} 6", "_count{model=\"m\"} 26")
            .replace("total{model=\"m\"} 11", "total{model=\"m\"} 151")
    }

    #[test]
    fn parses_labels_escapes_and_timestamps() {
        let s = parse(BEFORE);
        let w = s.iter().find(|s| s.name == "weird").unwrap();
        assert_eq!(w.label("a"), Some("x\"y,z"));
        assert_eq!(w.label("b"), Some("c"));
        assert_eq!(w.value, 2.5);
        assert_eq!(sum(&s, "dynaserve_scene_steps_total", |_| true), 11.0);
        let inf = s
            .iter()
            .find(|s| s.label("le") == Some("+Inf"))
            .map(|s| s.label("le").and_then(parse_value));
        assert_eq!(inf, Some(Some(f64::INFINITY)));
    }

    #[test]
    fn values_are_found_by_series_and_expositions_are_checked() {
        assert_eq!(
            value(BEFORE, r#"dynaserve_batch_scenes_bucket{le="4",model="m"}"#),
            Some(6.0)
        );
        assert_eq!(
            value(BEFORE, r#"dynaserve_scene_steps_total{model="m"}"#),
            Some(11.0)
        );
        assert_eq!(value(BEFORE, "dynaserve_scene_steps_total"), None);
        let good = "# HELP a_total A.\n# TYPE a_total counter\na_total{x=\"1\"} 3\n\
                    # HELP h H.\n# TYPE h histogram\nh_bucket{le=\"+Inf\"} 1\nh_sum 2\nh_count 1\n";
        let families = check_exposition(good).unwrap();
        assert_eq!(families["a_total"], "counter");
        assert_eq!(families["h"], "histogram");
        assert!(
            check_exposition("a 1\n")
                .unwrap_err()
                .contains("without TYPE")
        );
        let no_sum = good.replace("h_sum 2\n", "");
        assert!(
            check_exposition(&no_sum)
                .unwrap_err()
                .contains("lacks _sum")
        );
        assert!(check_exposition(&good.replace("=\"1\"", "=1")).is_err());
    }

    #[test]
    fn diff_keeps_only_the_runs_observations() {
        let b =
            Histogram::from_samples(&parse(BEFORE), "dynaserve_batch_scenes", |_| true).unwrap();
        let a =
            Histogram::from_samples(&parse(&after()), "dynaserve_batch_scenes", |_| true).unwrap();
        let d = a.diff(&b);
        // 10 batches of 4 scenes and 10 of 8 were added.
        assert_eq!(d.count, 20.0);
        assert_eq!(d.sum, 140.0);
        assert_eq!(d.mean(), 7.0);
        assert_eq!(
            d.nonempty_buckets(),
            vec![(2.0, 4.0, 10.0), (4.0, 8.0, 10.0)]
        );
        assert_eq!(d.quantile_upper(0.5), 4.0);
        assert_eq!(d.quantile_upper(0.51), 8.0);
        assert_eq!(d.quantile_upper(0.99), 8.0);
        // Interpolated: the median sits at the top of the (2, 4] bucket.
        assert!((d.quantile_interpolated(0.5) - 4.0).abs() < 1e-12);
        assert!((d.quantile_interpolated(0.75) - 6.0).abs() < 1e-12);
        let empty = b.diff(&b);
        assert_eq!(
            (empty.count, empty.mean(), empty.quantile_upper(0.99)),
            (0.0, 0.0, 0.0)
        );
    }

    #[test]
    fn label_filters_select_series_and_inf_bucket_is_bounded() {
        let s = parse(BEFORE);
        let bulk = Histogram::from_samples(&s, "dynaserve_queue_wait_seconds", |x| {
            x.label("priority") == Some("bulk")
        })
        .unwrap();
        assert_eq!(bulk.count, 3.0);
        // Every bulk observation is above the last finite bound: answered with that bound.
        assert_eq!(bulk.quantile_upper(0.5), 0.001);
        assert_eq!(bulk.quantile_interpolated(0.5), 0.001);
        let all = Histogram::from_samples(&s, "dynaserve_queue_wait_seconds", |_| true).unwrap();
        assert_eq!(all.count, 4.0);
        assert_eq!(all.buckets, vec![(0.001, 1.0), (f64::INFINITY, 4.0)]);
        assert!(Histogram::from_samples(&s, "missing", |_| true).is_none());
    }
}
