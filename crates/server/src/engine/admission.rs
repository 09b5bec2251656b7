//! A stepping request's admission rules beyond its scene (which its family validates:
//! [`crate::families::built_scene`]): its steps and step size, and its cost against the server's
//! `--max-request-cost`, checked before any scene is prepared. Errors name the field.
//!
//! - steps in 1..=`max_steps`, dt_steps in 1..=`max_dt_steps` (0 means 1);
//! - objects x steps, summed over a Predict call's variants, at most `max_request_cost`
//!   object-steps ([`check_request_cost`], named `steps`).

use dynaserve_api::FieldError;
use dynaserve_api::limits::{Limits, object_steps};

use crate::error::count;

/// Checks `steps` and `dt_steps` (0 means 1); returns the effective `dt_steps`.
pub fn check_steps(steps: u32, dt_steps: u32, limits: &Limits) -> Result<u32, FieldError> {
    if steps == 0 || steps > limits.caps.max_steps {
        return Err(FieldError::new(
            "steps",
            format!("{steps} is outside 1..={}", limits.caps.max_steps),
        ));
    }
    let dt = dt_steps.max(1);
    if dt > limits.caps.max_dt_steps {
        return Err(FieldError::new(
            "dt_steps",
            format!(
                "{dt_steps} is outside 1..={} frames",
                limits.caps.max_dt_steps
            ),
        ));
    }
    Ok(dt)
}

/// Checks the cost of a stepping request against the server's `--max-request-cost`: `steps`
/// steps of scenes with `objects[i]` objects each ([`object_steps`]). `variants`: the scenes
/// are a Predict call's variants (one count per variant); otherwise `objects` holds the one
/// scene of a Rollout or a session's Step. Above the limit: an error naming `steps` whose
/// message names every factor and the flag. Returns the cost.
pub fn check_request_cost(
    objects: &[usize],
    steps: u32,
    variants: bool,
    limits: &Limits,
) -> Result<u64, FieldError> {
    let cost = object_steps(objects.iter().copied(), steps);
    let max = limits.caps.max_request_cost;
    if cost <= max {
        return Ok(cost);
    }
    let total = object_steps(objects.iter().copied(), 1);
    let steps_x = count(u64::from(steps), "step", "steps");
    let (factors, lower) = if !variants {
        (
            format!("{} x {steps_x}", count(total, "object", "objects")),
            "steps or objects",
        )
    } else {
        let n = count(objects.len() as u64, "variant", "variants");
        let first = objects.first().copied().unwrap_or(0);
        let factors = if objects.iter().all(|&o| o == first) {
            format!(
                "{} x {steps_x} x {n}",
                count(first as u64, "object", "objects")
            )
        } else {
            format!(
                "{} (summed over {n}) x {steps_x}",
                count(total, "object", "objects")
            )
        };
        (factors, "steps, variants or objects")
    };
    Err(FieldError::new(
        "steps",
        format!(
            "{factors} = {cost} object-steps exceeds the server's limit of {max} \
             (--max-request-cost); lower {lower}"
        ),
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::families::built_scene::tests::limits;

    #[test]
    fn steps_and_step_size_name_their_field() {
        assert_eq!(check_steps(0, 1, &limits()).unwrap_err().field, "steps");
        assert_eq!(check_steps(5, 5, &limits()).unwrap_err().field, "dt_steps");
        assert_eq!(check_steps(5, 0, &limits()).unwrap(), 1);
    }

    #[test]
    fn request_cost_names_every_factor_and_the_flag() {
        let l = limits();
        assert_eq!(check_request_cost(&[10], 100, false, &l), Ok(1000));
        let e = check_request_cost(&[10], 101, false, &l).unwrap_err();
        assert_eq!(e.field, "steps");
        assert_eq!(
            e.message,
            "10 objects x 101 steps = 1010 object-steps exceeds the server's limit of 1000 \
             (--max-request-cost); lower steps or objects"
        );
        let e = check_request_cost(&[4; 3], 100, true, &l).unwrap_err();
        assert_eq!(
            e.message,
            "4 objects x 100 steps x 3 variants = 1200 object-steps exceeds the server's limit \
             of 1000 (--max-request-cost); lower steps, variants or objects"
        );
        let e = check_request_cost(&[1, 4, 6], 100, true, &l).unwrap_err();
        assert_eq!(
            e.message,
            "11 objects (summed over 3 variants) x 100 steps = 1100 object-steps exceeds the \
             server's limit of 1000 (--max-request-cost); lower steps, variants or objects"
        );
        let e = check_request_cost(&[1001], 1, true, &l).unwrap_err();
        assert!(
            e.message
                .starts_with("1001 objects x 1 step x 1 variant = 1001 object-steps"),
            "{}",
            e.message
        );
        assert_eq!(check_request_cost(&[2, 3], 200, true, &l), Ok(1000));
    }
}
