//! The experiment ledger (`docs/experiments.jsonl`): one JSON object per training run (id,
//! parent, config, data, iterations, wall time, key figures, verdict, why), printed as a
//! table by `dynaserve train ledger`. The reading of the runs is `docs/experiments.md`.

use std::path::Path;

use anyhow::Context;
use serde::Deserialize;
use serde_json::{Map, Value};

/// Where the ledger lives, relative to the repository root.
pub const DEFAULT_LEDGER: &str = "docs/experiments.jsonl";

/// One run of the ledger.
#[derive(Clone, Debug, Deserialize)]
pub struct Run {
    /// Run id (`r87`) or release name.
    pub id: String,
    /// The run or release it started from.
    pub parent: Option<String>,
    /// Its configuration file.
    pub config: Option<String>,
    /// Training data.
    pub data: Option<String>,
    /// Training iterations.
    pub iterations: Option<u64>,
    /// Wall time as recorded.
    pub wall_time: Option<String>,
    /// Key figures by name.
    #[serde(default)]
    pub figures: Map<String, Value>,
    /// `shipped`, `not shipped`, `abandoned`, `baseline` or `ensemble member`.
    pub verdict: String,
    /// One line: why that verdict.
    pub why: String,
}

/// Reads every run of the ledger at `path`; an error names the line.
pub fn read(path: &Path) -> anyhow::Result<Vec<Run>> {
    let text = std::fs::read_to_string(path)
        .with_context(|| format!("cannot read the ledger {}", path.display()))?;
    text.lines()
        .enumerate()
        .filter(|(_, l)| !l.trim().is_empty())
        .map(|(i, l)| {
            serde_json::from_str(l)
                .with_context(|| format!("{}:{}: not a ledger record", path.display(), i + 1))
        })
        .collect()
}

fn cut(s: &str, n: usize) -> String {
    if s.chars().count() <= n {
        s.to_string()
    } else {
        let mut t: String = s.chars().take(n - 1).collect();
        t.push('~');
        t
    }
}

/// The ledger as a table, one run per line (figures and why shortened to fit `width`).
pub fn table(runs: &[Run], width: usize) -> String {
    let mut out = format!(
        "{:<10} {:<10} {:>9} {:<14} {}\n",
        "run", "parent", "iters", "verdict", "figures | why"
    );
    for r in runs {
        let figures: Vec<String> = r
            .figures
            .iter()
            .map(|(k, v)| match v {
                Value::String(s) => format!("{k} {s}"),
                other => format!("{k} {other}"),
            })
            .collect();
        let rest = format!("{} | {}", figures.join(", "), r.why);
        let head = format!(
            "{:<10} {:<10} {:>9} {:<14} ",
            cut(&r.id, 10),
            cut(r.parent.as_deref().unwrap_or("-"), 10),
            r.iterations.map_or("-".into(), |i| i.to_string()),
            cut(&r.verdict, 14)
        );
        let room = width.saturating_sub(head.chars().count()).max(20);
        out.push_str(&head);
        out.push_str(&cut(&rest, room));
        out.push('\n');
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_committed_ledger_reads_and_prints_every_run() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../..")
            .join(DEFAULT_LEDGER);
        let runs = read(&path).unwrap();
        assert!(runs.len() >= 20, "{} runs", runs.len());
        let shipped = runs.iter().filter(|r| r.verdict == "shipped").count();
        assert!(shipped >= 1, "no shipped release in the ledger");
        for r in &runs {
            assert!(!r.id.is_empty() && !r.why.is_empty(), "{r:?}");
        }
        let t = table(&runs, 120);
        assert_eq!(t.lines().count(), runs.len() + 1);
        assert!(t.lines().all(|l| l.chars().count() <= 120), "{t}");
    }
}
