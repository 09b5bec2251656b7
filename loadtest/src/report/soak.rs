//! The soak's section of a level report: its outcome counts, the server's memory record, and
//! its block of the text report.

use serde::Serialize;

use crate::rss::RssRecord;

/// Soak outcome counts.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct SoakCounts {
    /// Rollouts the client kept that brought every frame and ended cleanly.
    pub kept_complete: u64,
    /// Rollouts the client dropped on purpose (each followed by a new connection).
    pub dropped: u64,
    /// Kept rollouts that ended with an error or too few frames (frames lost).
    pub failed: u64,
    /// Rollouts refused at admission (RESOURCE_EXHAUSTED / 429) before any frame, retried.
    pub refused: u64,
    /// Rollouts still running when the run stopped (Ctrl-C, or the drain limit after the
    /// duration: then they are counted as stalled too).
    pub cut: u64,
    /// Rollouts still running the drain limit (`run::DRAIN_LIMIT`) after the duration ended.
    pub stalled: u64,
    /// New connections opened after a drop or a failure.
    pub reconnects: u64,
    /// Connection attempts that failed.
    pub connect_errors: u64,
    /// Frames received and checked.
    pub frames: u64,
    /// Frames a kept rollout never brought, and steps skipped before a drop.
    pub lost_frames: u64,
    /// Frames with another pose count or a pose outside the stream's region.
    pub misrouted_frames: u64,
    /// Frames whose step was not above the previous frame's.
    pub out_of_order_frames: u64,
}

/// The soak's section of a level report.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct SoakReport {
    /// Concurrent streams.
    pub streams: usize,
    /// Time new rollouts were started, seconds.
    pub duration_s: f64,
    /// Time until every stream had finished its last rollout, seconds.
    pub elapsed_s: f64,
    /// Chance that a rollout is dropped by its client at a random frame.
    pub drop_probability: f64,
    /// Steps per rollout.
    pub steps: u32,
    /// Outcomes.
    pub counts: SoakCounts,
    /// Checked frames per second over `elapsed_s`.
    pub frames_per_s: f64,
    /// The server's resident memory, when it could be read.
    pub rss: Option<RssRecord>,
    /// A few violations or failures, described.
    pub examples: Vec<String>,
}

fn mib(bytes: u64) -> String {
    format!("{:.1} MiB", bytes as f64 / (1024.0 * 1024.0))
}

impl SoakReport {
    /// The soak's block of the text report.
    pub fn to_text(&self) -> String {
        let c = &self.counts;
        let mut o = format!(
            "  soak: {} streams, new rollouts for {:.0} s (all done after {:.0} s), {} steps each, \
             drop probability {}\n",
            self.streams, self.duration_s, self.elapsed_s, self.steps, self.drop_probability
        );
        o += &format!(
            "    rollouts: {} kept to the end, {} dropped by their client ({} new connections), \
             {} failed, {} refused at admission, {} cut, {} stalled, {} failed connection attempts\n",
            c.kept_complete,
            c.dropped,
            c.reconnects,
            c.failed,
            c.refused,
            c.cut,
            c.stalled,
            c.connect_errors
        );
        o += &format!(
            "    frames checked {} ({:.1} frames/s): {} lost, {} misrouted, {} out of order\n",
            c.frames, self.frames_per_s, c.lost_frames, c.misrouted_frames, c.out_of_order_frames
        );
        match &self.rss {
            Some(r) => match (r.start(), r.peak(), r.end()) {
                (Some(a), Some(p), Some(e)) => {
                    o += &format!(
                        "    server RSS ({}): start {}, peak {}, end {} ({} readings)\n",
                        r.source,
                        mib(a),
                        mib(p),
                        mib(e),
                        r.samples.len()
                    )
                }
                _ => {
                    o += &format!(
                        "    server RSS: not read ({})\n",
                        r.errors.first().map_or("no reading", String::as_str)
                    )
                }
            },
            None => o += "    server RSS: not read (no --pid, no spawned server, no /metrics)\n",
        }
        for e in &self.examples {
            o += &format!("    e.g. {e}\n");
        }
        o += if self.passed() {
            "    result: PASS, every frame came in order in its own stream, every kept rollout complete\n"
        } else {
            "    result: FAIL (see the counts above)\n"
        };
        o
    }

    /// True when no frame was lost, misrouted or out of order, no kept rollout failed or
    /// stalled and every connection attempt succeeded.
    pub fn passed(&self) -> bool {
        let c = &self.counts;
        c.lost_frames == 0
            && c.misrouted_frames == 0
            && c.out_of_order_frames == 0
            && c.failed == 0
            && c.stalled == 0
            && c.connect_errors == 0
    }
}
