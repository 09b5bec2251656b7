//! The property runner: what the cases of one property came to (accepted, or rejected naming a
//! field), the check that every rejection names a field briefly, and the case count.

use std::cell::RefCell;
use std::collections::BTreeMap;

use dynaserve_api::FieldError;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};

/// What the cases of one property came to: `accepted`, or `rejected <field>` with indices
/// left out (`scene.objects[].mass`).
pub(crate) type Tally = BTreeMap<String, u64>;

/// A field path with its indices left out, and a key that is no name (a mutated one) as `?`.
fn field_shape(field: &str) -> String {
    let named = |seg: &str| {
        seg.chars()
            .all(|c| c.is_ascii_alphanumeric() || "_[]?".contains(c))
    };
    let field = field
        .split('.')
        .map(|seg| if named(seg) { seg } else { "?" })
        .collect::<Vec<_>>()
        .join(".");
    let mut out = String::new();
    let mut in_index = false;
    for c in field.chars() {
        match c {
            '[' => {
                in_index = true;
                out.push('[');
            }
            ']' => {
                in_index = false;
                out.push(']');
            }
            _ if in_index => {}
            _ => out.push(c),
        }
    }
    out
}

/// Counts an outcome; a rejection must name a field (a path, or the unknown key the request
/// sent) and say briefly what is wrong.
pub(crate) fn record(
    tally: &RefCell<Tally>,
    outcome: Result<(), FieldError>,
) -> Result<(), TestCaseError> {
    let key = match outcome {
        Ok(()) => "accepted".to_string(),
        Err(e) => {
            prop_assert!(
                !e.field.trim().is_empty(),
                "the rejection names no field: {e:?}"
            );
            prop_assert!(!e.message.trim().is_empty(), "an empty message: {e:?}");
            let text = e.to_string();
            prop_assert!(
                text.len() < 1024,
                "a message of {} bytes: {}...",
                text.len(),
                text.chars().take(400).collect::<String>()
            );
            format!("rejected {}", field_shape(&e.field))
        }
    };
    *tally.borrow_mut().entry(key).or_insert(0) += 1;
    Ok(())
}

pub(crate) fn cases(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Runs `test` on `cases` values of `strategy` (no regression files are written), then
/// prints what they came to.
pub(crate) fn run<S: Strategy>(
    name: &str,
    cases: u32,
    strategy: S,
    test: impl Fn(S::Value, &RefCell<Tally>) -> Result<(), TestCaseError>,
) {
    let mut runner = TestRunner::new(Config {
        cases,
        failure_persistence: None,
        ..Config::default()
    });
    let tally = RefCell::new(Tally::new());
    let result = runner.run(&strategy, |v| test(v, &tally));
    if let Err(e) = result {
        panic!("{name}: {e}");
    }
    let t = tally.into_inner();
    let total: u64 = t.values().sum();
    eprintln!("{name}: {cases} cases, {total} requests decoded");
    for (k, v) in &t {
        eprintln!("  {v:>6}  {k}");
    }
}
