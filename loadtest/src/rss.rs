//! The server's resident memory during a soak: read from `/proc/PID/status` (`VmRSS`) when
//! the server's process id is known (`--spawn` or `--pid`), else from the standard
//! `process_resident_memory_bytes` gauge of its `/metrics`, when it exports one.

use std::time::Instant;

use serde::Serialize;

/// Where resident memory is read from.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum RssSource {
    /// `/proc/PID/status` of a local process.
    Proc(u32),
    /// The `process_resident_memory_bytes` gauge of a Prometheus endpoint (URL).
    Metrics(String),
}

impl RssSource {
    /// Short description for reports (`/proc/1234/status`, or the metrics URL).
    pub fn describe(&self) -> String {
        match self {
            RssSource::Proc(pid) => format!("/proc/{pid}/status VmRSS"),
            RssSource::Metrics(url) => format!("{url} process_resident_memory_bytes"),
        }
    }

    /// Reads the resident set size now, bytes.
    pub async fn read(&self) -> Result<u64, String> {
        match self {
            RssSource::Proc(pid) => {
                let path = format!("/proc/{pid}/status");
                let text = tokio::fs::read_to_string(&path)
                    .await
                    .map_err(|e| format!("{path}: {e}"))?;
                vm_rss_bytes(&text).ok_or_else(|| format!("{path}: no VmRSS line"))
            }
            RssSource::Metrics(url) => {
                let text = crate::transport::http_get(url).await?;
                metrics_rss_bytes(&text)
                    .ok_or_else(|| format!("{url}: no process_resident_memory_bytes"))
            }
        }
    }
}

/// The `VmRSS:  1234 kB` line of a `/proc/PID/status` text, in bytes.
pub fn vm_rss_bytes(status: &str) -> Option<u64> {
    let line = status.lines().find(|l| l.starts_with("VmRSS:"))?;
    let mut parts = line["VmRSS:".len()..].split_whitespace();
    let value: u64 = parts.next()?.parse().ok()?;
    match parts.next() {
        Some("kB") | None => Some(value * 1024),
        Some(_) => None,
    }
}

/// The `process_resident_memory_bytes` gauge of a Prometheus text, in bytes.
pub fn metrics_rss_bytes(text: &str) -> Option<u64> {
    let samples = dynaserve_client::prom::parse(text);
    let s = samples
        .iter()
        .find(|s| s.name == "process_resident_memory_bytes")?;
    (s.value.is_finite() && s.value >= 0.0).then_some(s.value as u64)
}

/// One reading: seconds since the soak started and resident bytes.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct RssSample {
    /// Seconds since the start of the soak.
    pub at_s: f64,
    /// Resident set size, bytes.
    pub bytes: u64,
}

/// Resident memory over a soak: every sample, and the start, peak and end readings.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct RssRecord {
    /// Where the figures were read.
    pub source: String,
    /// Every reading, in time order.
    pub samples: Vec<RssSample>,
    /// Readings that failed (the first few messages).
    pub errors: Vec<String>,
}

impl RssRecord {
    /// An empty record for `source`.
    pub fn new(source: &RssSource) -> RssRecord {
        RssRecord {
            source: source.describe(),
            ..RssRecord::default()
        }
    }

    /// Takes one reading from `source`, `since` being the soak's start.
    pub async fn sample(&mut self, source: &RssSource, since: Instant) {
        match source.read().await {
            Ok(bytes) => self.samples.push(RssSample {
                at_s: since.elapsed().as_secs_f64(),
                bytes,
            }),
            Err(e) if self.errors.len() < 3 => self.errors.push(e),
            Err(_) => {}
        }
    }

    /// First reading, bytes.
    pub fn start(&self) -> Option<u64> {
        self.samples.first().map(|s| s.bytes)
    }

    /// Largest reading, bytes.
    pub fn peak(&self) -> Option<u64> {
        self.samples.iter().map(|s| s.bytes).max()
    }

    /// Last reading, bytes.
    pub fn end(&self) -> Option<u64> {
        self.samples.last().map(|s| s.bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn proc_status_and_metrics_are_parsed() {
        let status = "Name:\tdynaserve\nVmPeak:\t  900 kB\nVmRSS:\t  123456 kB\nThreads:\t9\n";
        assert_eq!(vm_rss_bytes(status), Some(123456 * 1024));
        assert_eq!(vm_rss_bytes("Name:\tx\n"), None);
        assert_eq!(vm_rss_bytes("VmRSS:\t12 MB\n"), None);
        let metrics = "# TYPE process_resident_memory_bytes gauge\n\
            process_resident_memory_bytes 5.24288e+07\nother 1\n";
        assert_eq!(metrics_rss_bytes(metrics), Some(52_428_800));
        assert_eq!(metrics_rss_bytes("other 1\n"), None);
    }

    #[tokio::test]
    async fn own_process_is_sampled() {
        let src = RssSource::Proc(std::process::id());
        let mut rec = RssRecord::new(&src);
        let t0 = Instant::now();
        rec.sample(&src, t0).await;
        rec.sample(&RssSource::Proc(u32::MAX), t0).await;
        assert_eq!(rec.samples.len(), 1, "{:?}", rec.errors);
        assert!(rec.start().unwrap() > 0);
        assert_eq!(rec.errors.len(), 1);
        assert!(
            rec.errors[0].contains("/proc/4294967295/status"),
            "{:?}",
            rec.errors
        );
    }
}
