//! Scheduling classes: which requests run as bulk work and how much of the machine bulk work
//! gets while interactive work waits too (`crate::scheduler`, docs/architecture.md).
//!
//! A request's class follows from its cost, the same cost admission checks against the caps:
//! a Predict call (plain or on a session) in object-steps, a Generate call in vertex-frame
//! evaluations. Streamed work (Rollout, a session's Step and Interact) is always interactive:
//! it puts one scene in a pass at a time.

/// Flags of `dynaserve serve` that set the scheduling classes.
#[derive(Clone, Debug, clap::Args)]
pub struct SchedulingConfig {
    /// Predict calls (plain or on a session) costing more than this many object-steps
    /// (objects x steps summed over the variants) run as bulk work; cheaper ones are
    /// interactive. The default is about one second of a 2-core machine (5,000-6,000
    /// object-steps/s on 10-object scenes): a 16-variant x 30-step planning round of
    /// 10-object scenes stays interactive, a 64 x 50 one is bulk.
    #[arg(long, env = "DYNASERVE_BULK_COST", default_value_t = 5_000)]
    pub bulk_cost: u64,
    /// Generate calls costing more than this many vertex-frame evaluations (the unit of
    /// --max-generate-cost) run as bulk work. The default is about one second of the bundled
    /// PhysiFormer on a 2-core machine (~61,000 vertex-frame evaluations/s): one or two
    /// samples of the example scene at 16 denoising steps stay interactive.
    #[arg(long, env = "DYNASERVE_BULK_GENERATE_COST", default_value_t = 60_000)]
    pub bulk_generate_cost: u64,
    /// Share of the model passes' work that bulk requests get while interactive work waits
    /// too, above 0 and below 1. Interactive work goes first, so a pass holding interactive
    /// steps grows by at most bulk-share / (1 - bulk-share) with bulk steps (a third at the
    /// default 0.25); alone, bulk work runs in passes of at most this share of the pass
    /// budget, so an arriving interactive step waits for one short pass at most.
    #[arg(long, env = "DYNASERVE_BULK_SHARE", default_value_t = 0.25)]
    pub bulk_share: f64,
}

impl Default for SchedulingConfig {
    fn default() -> SchedulingConfig {
        SchedulingConfig {
            bulk_cost: 5_000,
            bulk_generate_cost: 60_000,
            bulk_share: 0.25,
        }
    }
}

impl SchedulingConfig {
    /// True when a Predict call of `object_steps` runs as bulk work.
    pub fn predict_is_bulk(&self, object_steps: u64) -> bool {
        object_steps > self.bulk_cost
    }

    /// True when a Generate call of `vertex_frame_evaluations` runs as bulk work.
    pub fn generate_is_bulk(&self, vertex_frame_evaluations: u64) -> bool {
        vertex_frame_evaluations > self.bulk_generate_cost
    }

    /// Checks the flags.
    pub fn validate(&self) -> Result<(), String> {
        if !(self.bulk_share.is_finite() && self.bulk_share > 0.0 && self.bulk_share < 1.0) {
            return Err("--bulk-share must be above 0 and below 1".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_class_follows_the_cost_and_the_share_must_be_a_fraction() {
        let c = SchedulingConfig::default();
        assert!(c.validate().is_ok());
        assert!(!c.predict_is_bulk(16 * 30 * 10));
        assert!(c.predict_is_bulk(64 * 50 * 10));
        assert!(!c.generate_is_bulk(16 * 49 * 31));
        assert!(c.generate_is_bulk(4 * 16 * 49 * 31));
        for bad in [0.0, 1.0, -0.5, f64::NAN] {
            let c = SchedulingConfig {
                bulk_share: bad,
                ..SchedulingConfig::default()
            };
            assert!(c.validate().unwrap_err().contains("--bulk-share"));
        }
    }

    #[test]
    fn the_default_is_the_flag_default() {
        use clap::Parser;
        #[derive(clap::Parser)]
        struct Wrapper {
            #[command(flatten)]
            config: SchedulingConfig,
        }
        let parsed = Wrapper::parse_from(["serve"]).config;
        let d = SchedulingConfig::default();
        assert_eq!(
            (
                parsed.bulk_cost,
                parsed.bulk_generate_cost,
                parsed.bulk_share
            ),
            (d.bulk_cost, d.bulk_generate_cost, d.bulk_share)
        );
    }
}
