//! Property tests of the request decoders: hostile bytes and hostile values go through the
//! same steps the server takes before any model work, for both wire forms, and must come out
//! as a valid request or a [`FieldError`] naming a field, never a panic.
//!
//! - JSON (`POST /v1/rollout`, `/v1/predict`, `/v1/sessions`, `.../step`, `.../state`,
//!   `.../predict`): the server's body reader (`json_body::decode`: a JSON object, errors naming
//!   the field), the conversion to the neutral request, then its checks: steps and step size,
//!   the variant count, every scene through `build_scene`, session states, kinematic sets and
//!   actions through the sessions' input checks (against a three-object session, object 0
//!   kinematic).
//! - Protobuf (`Rollout`, `Predict`, `CreateSession`, `Step`, `SetState`, session `Predict`,
//!   `Interact`): `prost` decoding, the conversion from the gRPC form, then the same checks.
//!
//! Limits are those of the shipped `models/rigidformer-small` under the server's default caps.
//! Each property prints its case count and what the cases came to (accepted, or rejected
//! naming a field, indices left out), the figures of the reliability record. The number of
//! cases per property is `PROPTEST_CASES` when set.
//!
//! The properties are below; [`checks`] holds the server's checks, [`json_cases`] and
//! [`proto_cases`] the valid requests and their hostile variants of each wire form, [`runner`]
//! the tally.

mod checks;
mod json_cases;
mod proto_cases;
mod runner;

use proptest::prelude::*;

use json_cases::*;
use proto_cases::*;
use runner::*;

#[test]
fn valid_requests_of_every_kind_are_accepted() {
    all_valid_json_bodies_are_accepted();
    all_valid_messages_are_accepted();
}

#[test]
fn arbitrary_bytes_never_panic() {
    run(
        "arbitrary_bytes_never_panic",
        cases(300),
        (
            proptest::collection::vec(any::<u8>(), 0..512),
            any::<bool>(),
        ),
        |(mut bytes, brace), tally| {
            for rpc in RPCS {
                record(tally, proto_request(rpc, &bytes))?;
            }
            // Half the cases open with a brace to get past the object check.
            if brace {
                bytes.insert(0, b'{');
            }
            for kind in KINDS {
                record(tally, json_request(kind, &bytes))?;
            }
            Ok(())
        },
    );
}

#[test]
fn mutated_valid_requests_never_panic() {
    run(
        "mutated_valid_requests_never_panic",
        cases(300),
        (kind(), rpc(), byte_ops()),
        |(kind, rpc, ops), tally| {
            let body = valid_json(kind).to_string().into_bytes();
            record(tally, json_request(kind, &mutate(body, &ops)))?;
            let bytes = valid_proto(rpc).encode();
            record(tally, proto_request(rpc, &mutate(bytes, &ops)))
        },
    );
}

#[test]
fn hostile_json_values_are_refused_or_valid_never_a_panic() {
    run(
        "hostile_json_values_are_refused_or_valid_never_a_panic",
        cases(300),
        (kind(), proptest::collection::vec(edit(), 1..=3)),
        |(kind, edits), tally| {
            let mut v = valid_json(kind);
            for e in &edits {
                apply(&mut v, e);
            }
            record(tally, json_request(kind, v.to_string().as_bytes()))
        },
    );
}

#[test]
fn hostile_protobuf_values_are_refused_or_valid_never_a_panic() {
    run(
        "hostile_protobuf_values_are_refused_or_valid_never_a_panic",
        cases(300),
        (
            rpc(),
            damage(),
            proptest::collection::vec((any::<usize>(), hostile_f32()), 0..=4),
            proptest::collection::vec((any::<usize>(), hostile_u32()), 0..=2),
        ),
        |(rpc, damage, floats, ints), tally| {
            let mut m = valid_proto(rpc);
            harm(&mut m, damage);
            {
                let (mut f, mut i) = numbers(&mut m);
                for (k, x) in floats {
                    if !f.is_empty() {
                        let n = f.len();
                        *f[k % n] = x;
                    }
                }
                for (k, x) in ints {
                    if !i.is_empty() {
                        let n = i.len();
                        *i[k % n] = x;
                    }
                }
            }
            record(tally, proto_message(rpc, &m))?;
            record(tally, proto_request(rpc, &m.encode()))
        },
    );
}
