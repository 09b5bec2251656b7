//! The JSON side: the HTTP request kinds, a valid body of each, hostile values and edits at
//! any JSON pointer, and byte mutations.

use dynaserve_api::json_body::decode as read_json;
use dynaserve_api::spec::session::{CreateSessionSpec, SessionPredictSpec, SetStateSpec, StepSpec};
use dynaserve_api::spec::{PredictSpec, RolloutSpec};
use dynaserve_api::{FieldError, json};
use proptest::prelude::*;
use serde_json::{Value, json};

use crate::checks::*;

/// Request kinds of the HTTP API.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    Rollout,
    Predict,
    CreateSession,
    Step,
    SetState,
    SessionPredict,
}

pub(crate) const KINDS: [Kind; 6] = [
    Kind::Rollout,
    Kind::Predict,
    Kind::CreateSession,
    Kind::Step,
    Kind::SetState,
    Kind::SessionPredict,
];

/// A JSON body of `kind` through decoding, conversion and the server's checks.
pub(crate) fn json_request(kind: Kind, bytes: &[u8]) -> Result<(), FieldError> {
    match kind {
        Kind::Rollout => check_rollout(RolloutSpec::from_json(
            &read_json::<json::RolloutRequest>(bytes)?,
        )?),
        Kind::Predict => check_predict(PredictSpec::from_json(
            &read_json::<json::PredictRequest>(bytes)?,
        )?),
        Kind::CreateSession => check_create(CreateSessionSpec::from_json(&read_json::<
            json::CreateSessionRequest,
        >(bytes)?)?),
        Kind::Step => check_step(StepSpec::from_json(
            "s1",
            &read_json::<json::StepRequest>(bytes)?,
        )),
        Kind::SetState => check_set_state(SetStateSpec::from_json(
            "s1",
            &read_json::<json::SetStateRequest>(bytes)?,
        )?),
        Kind::SessionPredict => check_session_predict(SessionPredictSpec::from_json(
            "s1",
            &read_json::<json::SessionPredictRequest>(bytes)?,
        )?),
    }
}

/// An 8-corner box cloud of half extent `h`, metres.
fn box_points(h: f32) -> Value {
    let mut v = Vec::new();
    for x in [-h, h] {
        for y in [-h, h] {
            for z in [-h, h] {
                v.push(json!([x, y, z]));
            }
        }
    }
    Value::Array(v)
}

fn cube_mesh() -> Value {
    let v: Vec<Value> = (0..8)
        .map(|i| {
            json!([
                if i & 1 == 0 { -0.1 } else { 0.1 },
                if i & 2 == 0 { -0.1 } else { 0.1 },
                if i & 4 == 0 { -0.1 } else { 0.1 }
            ])
        })
        .collect();
    let faces = json!([
        [0, 2, 1],
        [1, 2, 3],
        [4, 5, 6],
        [5, 7, 6],
        [0, 1, 4],
        [1, 5, 4],
        [2, 6, 3],
        [3, 6, 7],
        [0, 4, 2],
        [2, 4, 6],
        [1, 3, 5],
        [3, 7, 5]
    ]);
    json!({ "vertices": v, "faces": faces, "samples": 64, "seed": 7 })
}

pub(crate) fn scene() -> Value {
    json!({ "objects": [
        { "points": box_points(0.2), "pose": { "translation": [0.0, 0.0, 0.2] }, "mass": 1.0,
          "friction": 0.5, "restitution": 0.2 },
        { "mesh": cube_mesh(),
          "pose": { "translation": [1.0, 0.0, 0.6], "rotation": [0.0, 0.0, 0.38268343, 0.9238795] },
          "velocity": { "linear": [0.5, 0.0, -1.0], "angular": [0.0, 0.0, 2.0] }, "mass": 2.5 },
        { "points": box_points(0.1), "pose": { "translation": [-1.0, 0.5, 0.1] },
          "previous_pose": { "translation": [-1.01, 0.5, 0.1] }, "mass": 0.3 }
    ]})
}

pub(crate) fn state(object: u32) -> Value {
    json!({ "object": object, "pose": { "translation": [0.5, 0.0, 0.3] },
            "velocity": { "linear": [0.1, 0.0, 0.0] } })
}

pub(crate) fn action() -> Value {
    json!({ "kinematic": [ { "object": 0, "pose": { "translation": [0.0, 0.1, 0.5] } } ] })
}

/// A valid JSON body of each kind.
pub(crate) fn valid_json(kind: Kind) -> Value {
    match kind {
        Kind::Rollout => json!({ "scene": scene(), "steps": 10, "dt_steps": 2, "stream": true }),
        Kind::Predict => {
            json!({ "variants": [scene(), scene()], "steps": 5, "every": 2, "timeout_ms": 1000 })
        }
        Kind::CreateSession => json!({ "scene": scene(), "dt_steps": 1, "kinematic": [0] }),
        Kind::Step => json!({ "steps": 2, "actions": [action(), action()] }),
        Kind::SetState => json!({ "objects": [state(1), state(2)] }),
        Kind::SessionPredict => json!({
            "variants": [ { "state": [state(2)], "actions": [action(), action(), action()] },
                          { "state": [], "actions": [] } ],
            "steps": 3, "every": 1 }),
    }
}

pub(crate) fn all_valid_json_bodies_are_accepted() {
    for kind in KINDS {
        let body = valid_json(kind).to_string();
        json_request(kind, body.as_bytes()).unwrap_or_else(|e| panic!("{kind:?}: {e}"));
    }
}

/// Hostile JSON values: wrong types, numbers beyond `u32` and `f32` (1e39 reads as an
/// infinite `f32`), denormals, empty and oversized arrays, wrong arities.
fn hostile_value() -> impl Strategy<Value = Value> {
    prop_oneof![
        Just(Value::Null),
        Just(json!(true)),
        Just(json!("text")),
        Just(json!("NaN")),
        Just(json!(-1)),
        Just(json!(0)),
        Just(json!(u32::MAX)),
        Just(json!(u64::MAX)),
        Just(json!(i64::MIN)),
        Just(json!(1e39)),
        Just(json!(-1e39)),
        Just(json!(3.4028235e38)),
        Just(json!(1e-45)),
        Just(json!(5e-324)),
        Just(json!(1e5)),
        Just(json!(100001.0)),
        Just(json!([])),
        Just(json!({})),
        Just(json!([[]])),
        Just(json!([1, 2])),
        Just(json!([1, 2, 3, 4, 5])),
        Just(json!([0.0, 0.0, 0.0, 0.0])),
        Just(Value::Array(vec![json!([0.0, 0.0, 0.0]); 5000])),
        Just(json!([[0, 1, 99]])),
        (-1e6f64..1e6).prop_map(|x| json!(x)),
    ]
}

/// Every path of a JSON tree, as JSON pointers (the root is "").
fn pointers(v: &Value, at: String, out: &mut Vec<String>) {
    match v {
        Value::Object(m) => {
            for (k, c) in m {
                pointers(c, format!("{at}/{k}"), out);
            }
        }
        Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                pointers(c, format!("{at}/{i}"), out);
            }
        }
        _ => {}
    }
    out.push(at);
}

/// One edit of a JSON tree: at the `pick`-th path, replace the value, drop it, or add an
/// unknown key or a duplicate array element next to it.
#[derive(Clone, Debug)]
pub(crate) enum Edit {
    Replace(usize, Value),
    Remove(usize),
    UnknownKey(usize),
    Repeat(usize, usize),
}

pub(crate) fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        6 => (any::<usize>(), hostile_value()).prop_map(|(p, v)| Edit::Replace(p, v)),
        2 => any::<usize>().prop_map(Edit::Remove),
        1 => any::<usize>().prop_map(Edit::UnknownKey),
        1 => (any::<usize>(), prop_oneof![Just(1usize), Just(300), Just(5000)])
            .prop_map(|(p, n)| Edit::Repeat(p, n)),
    ]
}

pub(crate) fn apply(v: &mut Value, e: &Edit) {
    let mut paths = Vec::new();
    pointers(v, String::new(), &mut paths);
    let pick = |i: usize| paths[i % paths.len()].clone();
    match e {
        Edit::Replace(i, new) => {
            let p = pick(*i);
            if let Some(slot) = v.pointer_mut(&p) {
                *slot = new.clone();
            }
        }
        Edit::Remove(i) | Edit::UnknownKey(i) | Edit::Repeat(i, _) => {
            let p = pick(*i);
            let Some(cut) = p.rfind('/') else { return };
            let (parent, key) = (&p[..cut], &p[cut + 1..]);
            match (v.pointer_mut(parent), e) {
                (Some(Value::Object(m)), Edit::Remove(_)) => {
                    m.remove(key);
                }
                (Some(Value::Object(m)), Edit::UnknownKey(_)) => {
                    m.insert("unexpected".into(), json!(1));
                }
                (Some(Value::Array(a)), Edit::Remove(_)) => {
                    if let Ok(k) = key.parse::<usize>() {
                        a.remove(k);
                    }
                }
                (Some(Value::Array(a)), Edit::Repeat(_, n)) => {
                    if let Ok(k) = key.parse::<usize>() {
                        let item = a[k].clone();
                        a.extend(std::iter::repeat_n(item, *n));
                    }
                }
                _ => {}
            }
        }
    }
}

pub(crate) fn kind() -> impl Strategy<Value = Kind> {
    proptest::sample::select(KINDS.to_vec())
}

/// Bytes with 1-5 random overwrites, deletions and insertions.
pub(crate) fn mutate(mut bytes: Vec<u8>, ops: &[(u8, usize, u8)]) -> Vec<u8> {
    for &(op, at, b) in ops {
        if bytes.is_empty() {
            bytes.push(b);
            continue;
        }
        let i = at % bytes.len();
        match op % 3 {
            0 => bytes[i] = b,
            1 => {
                bytes.remove(i);
            }
            _ => bytes.insert(i, b),
        }
    }
    bytes
}

pub(crate) fn byte_ops() -> impl Strategy<Value = Vec<(u8, usize, u8)>> {
    proptest::collection::vec((any::<u8>(), any::<usize>(), any::<u8>()), 1..=5)
}
