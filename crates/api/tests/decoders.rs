//! Property tests of the request decoders: hostile bytes and hostile values go through the
//! same steps the server takes before any model work, for both wire forms, and must come out
//! as a valid request or a [`FieldError`] naming a field, never a panic.
//!
//! - JSON (`POST /v1/rollout`, `/v1/predict`, `/v1/sessions`, `.../step`, `.../state`,
//!   `.../predict`): the server's body reader (`json_body::decode`: a JSON object, errors naming
//!   the field), the conversion to the neutral request, then its checks: steps and step size,
//!   the variant count, every scene through `build_scene`, session states, kinematic sets and
//!   actions through `session_input` (against a three-object session, object 0 kinematic).
//! - Protobuf (`Rollout`, `Predict`, `CreateSession`, `Step`, `SetState`, session `Predict`,
//!   `Interact`): `prost` decoding, the conversion from the gRPC form, then the same checks.
//!
//! Limits are those of the shipped `models/rigidformer-small` under the server's default caps.
//! Each property prints its case count and what the cases came to (accepted, or rejected
//! naming a field, indices left out), the figures of the reliability record. The number of
//! cases per property is `PROPTEST_CASES` when set.

use std::cell::RefCell;
use std::collections::BTreeMap;
use std::path::Path;
use std::sync::OnceLock;

use dynaserve_api::build::{build_scene, check_steps};
use dynaserve_api::json_body::decode as read_json;
use dynaserve_api::limits::{Caps, Limits};
use dynaserve_api::session_input::{apply_states, check_action, check_actions, kinematic_mask};
use dynaserve_api::spec::session::{
    CreateSessionSpec, InteractOpen, InteractStep, SessionPredictSpec, SetStateSpec, StepSpec,
};
use dynaserve_api::spec::{Pose, PredictSpec, RolloutSpec};
use dynaserve_api::{FieldError, json, v1};
use dynaserve_model::SceneState;
use proptest::prelude::*;
use proptest::test_runner::{Config, TestRunner};
use prost::Message;
use serde_json::{Value, json};

/// Limits and frame duration of the shipped model.
struct Model {
    limits: Limits,
    dt_frame: f32,
}

fn model() -> &'static Model {
    static M: OnceLock<Model> = OnceLock::new();
    M.get_or_init(|| {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../models/rigidformer-small");
        let config = dynaserve_model::read_config(&dir).expect("the shipped model's config.json");
        Model {
            limits: Limits::new(&Caps::DEFAULT, &config),
            dt_frame: config.dt_frame,
        }
    })
}

/// Objects of the session that session requests are checked against; object 0 is kinematic.
const SESSION_OBJECTS: usize = 3;
const SESSION_KINEMATIC: [bool; SESSION_OBJECTS] = [true, false, false];

fn session_state() -> SceneState {
    let at = |x: f32| Pose {
        translation: [x, 0.0, 0.5],
        rotation: [0.0, 0.0, 0.0, 1.0],
    };
    SceneState {
        previous: (0..SESSION_OBJECTS).map(|i| at(i as f32)).collect(),
        current: (0..SESSION_OBJECTS).map(|i| at(i as f32)).collect(),
    }
}

// ---- the checks the server makes after decoding ----

fn dt_seconds(dt_steps: u32) -> f32 {
    dt_steps as f32 * model().dt_frame
}

fn variant_count(n: usize) -> Result<(), FieldError> {
    let max = model().limits.caps.max_variants;
    if n == 0 || n > max {
        return Err(FieldError::new(
            "variants",
            format!("{n} variants given; 1..={max} accepted"),
        ));
    }
    Ok(())
}

fn check_rollout(r: RolloutSpec) -> Result<(), FieldError> {
    let dt = check_steps(r.steps, r.dt_steps, &model().limits)?;
    build_scene(&r.scene, "scene", &model().limits, dt_seconds(dt)).map(drop)
}

fn check_predict(r: PredictSpec) -> Result<(), FieldError> {
    let dt = check_steps(r.steps, r.dt_steps, &model().limits)?;
    variant_count(r.variants.len())?;
    for (i, s) in r.variants.iter().enumerate() {
        build_scene(
            s,
            &format!("variants[{i}]"),
            &model().limits,
            dt_seconds(dt),
        )?;
    }
    Ok(())
}

fn check_create(r: CreateSessionSpec) -> Result<(), FieldError> {
    let dt = check_steps(1, r.dt_steps, &model().limits)?;
    kinematic_mask(&r.kinematic, r.scene.objects.len())?;
    build_scene(&r.scene, "scene", &model().limits, dt_seconds(dt)).map(drop)
}

fn check_step(r: StepSpec) -> Result<(), FieldError> {
    check_steps(r.steps, 1, &model().limits)?;
    check_actions(&r.actions, r.steps, &SESSION_KINEMATIC, "actions").map(drop)
}

fn check_set_state(r: SetStateSpec) -> Result<(), FieldError> {
    apply_states(&mut session_state(), &r.objects, dt_seconds(1), "objects")
}

fn check_session_predict(r: SessionPredictSpec) -> Result<(), FieldError> {
    check_steps(r.steps, 1, &model().limits)?;
    variant_count(r.variants.len())?;
    for (i, v) in r.variants.iter().enumerate() {
        apply_states(
            &mut session_state(),
            &v.state,
            dt_seconds(1),
            &format!("variants[{i}].state"),
        )?;
        check_actions(
            &v.actions,
            r.steps,
            &SESSION_KINEMATIC,
            &format!("variants[{i}].actions"),
        )?;
    }
    Ok(())
}

// ---- JSON ----

/// Request kinds of the HTTP API.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Rollout,
    Predict,
    CreateSession,
    Step,
    SetState,
    SessionPredict,
}

const KINDS: [Kind; 6] = [
    Kind::Rollout,
    Kind::Predict,
    Kind::CreateSession,
    Kind::Step,
    Kind::SetState,
    Kind::SessionPredict,
];

/// A JSON body of `kind` through decoding, conversion and the server's checks.
fn json_request(kind: Kind, bytes: &[u8]) -> Result<(), FieldError> {
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

fn scene() -> Value {
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

fn state(object: u32) -> Value {
    json!({ "object": object, "pose": { "translation": [0.5, 0.0, 0.3] },
            "velocity": { "linear": [0.1, 0.0, 0.0] } })
}

fn action() -> Value {
    json!({ "kinematic": [ { "object": 0, "pose": { "translation": [0.0, 0.1, 0.5] } } ] })
}

/// A valid JSON body of each kind.
fn valid_json(kind: Kind) -> Value {
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

fn all_valid_json_bodies_are_accepted() {
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
enum Edit {
    Replace(usize, Value),
    Remove(usize),
    UnknownKey(usize),
    Repeat(usize, usize),
}

fn edit() -> impl Strategy<Value = Edit> {
    prop_oneof![
        6 => (any::<usize>(), hostile_value()).prop_map(|(p, v)| Edit::Replace(p, v)),
        2 => any::<usize>().prop_map(Edit::Remove),
        1 => any::<usize>().prop_map(Edit::UnknownKey),
        1 => (any::<usize>(), prop_oneof![Just(1usize), Just(300), Just(5000)])
            .prop_map(|(p, n)| Edit::Repeat(p, n)),
    ]
}

fn apply(v: &mut Value, e: &Edit) {
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

fn kind() -> impl Strategy<Value = Kind> {
    proptest::sample::select(KINDS.to_vec())
}

/// Bytes with 1-5 random overwrites, deletions and insertions.
fn mutate(mut bytes: Vec<u8>, ops: &[(u8, usize, u8)]) -> Vec<u8> {
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

fn byte_ops() -> impl Strategy<Value = Vec<(u8, usize, u8)>> {
    proptest::collection::vec((any::<u8>(), any::<usize>(), any::<u8>()), 1..=5)
}

// ---- protobuf ----

/// Request kinds of the gRPC API.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Rpc {
    Rollout,
    Predict,
    CreateSession,
    Step,
    SetState,
    SessionPredict,
    InteractOpen,
    InteractStep,
}

const RPCS: [Rpc; 8] = [
    Rpc::Rollout,
    Rpc::Predict,
    Rpc::CreateSession,
    Rpc::Step,
    Rpc::SetState,
    Rpc::SessionPredict,
    Rpc::InteractOpen,
    Rpc::InteractStep,
];

fn decode<T: Message + Default>(bytes: &[u8]) -> Result<T, FieldError> {
    T::decode(bytes).map_err(|e| FieldError::new("request", e.to_string()))
}

fn check_interact(first: bool, r: &v1::InteractRequest) -> Result<(), FieldError> {
    if first {
        match InteractOpen::from_v1(r)? {
            InteractOpen::Create(c) => check_create(c),
            InteractOpen::Session(_) => Ok(()),
        }
    } else {
        let step = InteractStep::from_v1(r)?;
        apply_states(
            &mut session_state(),
            &step.correct,
            dt_seconds(1),
            "correct",
        )?;
        check_action(&step.action, &SESSION_KINEMATIC, "action").map(drop)
    }
}

/// A decoded gRPC message through conversion and the server's checks (an Interact message as
/// the opening one or as a later one).
fn proto_message(rpc: Rpc, m: &Msg) -> Result<(), FieldError> {
    match (rpc, m) {
        (Rpc::Rollout, Msg::Rollout(r)) => check_rollout(RolloutSpec::from_v1(r)?),
        (Rpc::Predict, Msg::Predict(r)) => check_predict(PredictSpec::from_v1(r)?),
        (Rpc::CreateSession, Msg::Create(r)) => check_create(CreateSessionSpec::from_v1(r, "")?),
        (Rpc::Step, Msg::Step(r)) => check_step(StepSpec::from_v1(r)?),
        (Rpc::SetState, Msg::SetState(r)) => check_set_state(SetStateSpec::from_v1(r)?),
        (Rpc::SessionPredict, Msg::SessionPredict(r)) => {
            check_session_predict(SessionPredictSpec::from_v1(r)?)
        }
        (Rpc::InteractOpen, Msg::Interact(r)) => check_interact(true, r),
        (Rpc::InteractStep, Msg::Interact(r)) => check_interact(false, r),
        _ => unreachable!("message of another call"),
    }
}

/// Bytes of `rpc` through `prost` decoding, conversion and the server's checks.
fn proto_request(rpc: Rpc, bytes: &[u8]) -> Result<(), FieldError> {
    let m = match rpc {
        Rpc::Rollout => Msg::Rollout(decode(bytes)?),
        Rpc::Predict => Msg::Predict(decode(bytes)?),
        Rpc::CreateSession => Msg::Create(decode(bytes)?),
        Rpc::Step => Msg::Step(decode(bytes)?),
        Rpc::SetState => Msg::SetState(decode(bytes)?),
        Rpc::SessionPredict => Msg::SessionPredict(decode(bytes)?),
        Rpc::InteractOpen | Rpc::InteractStep => Msg::Interact(decode(bytes)?),
    };
    proto_message(rpc, &m)
}

/// A gRPC request message of any call.
#[derive(Clone, Debug)]
enum Msg {
    Rollout(v1::RolloutRequest),
    Predict(v1::PredictRequest),
    Create(v1::CreateSessionRequest),
    Step(v1::StepRequest),
    SetState(v1::SetStateRequest),
    SessionPredict(v1::SessionPredictRequest),
    Interact(v1::InteractRequest),
}

impl Msg {
    fn encode(&self) -> Vec<u8> {
        match self {
            Msg::Rollout(m) => m.encode_to_vec(),
            Msg::Predict(m) => m.encode_to_vec(),
            Msg::Create(m) => m.encode_to_vec(),
            Msg::Step(m) => m.encode_to_vec(),
            Msg::SetState(m) => m.encode_to_vec(),
            Msg::SessionPredict(m) => m.encode_to_vec(),
            Msg::Interact(m) => m.encode_to_vec(),
        }
    }
}

fn v1_scene() -> v1::Scene {
    serde_json::from_value::<json::Scene>(scene())
        .expect("valid scene")
        .to_proto()
}

fn v1_pose(x: f32) -> v1::Pose {
    json::Pose {
        translation: [x, 0.0, 0.4],
        rotation: json::IDENTITY_ROTATION,
    }
    .to_proto()
}

fn v1_state(object: u32) -> v1::ObjectState {
    v1::ObjectState {
        object,
        pose: Some(v1_pose(0.5)),
        motion: Some(v1::object_state::Motion::Velocity(v1::Velocity {
            linear: Some(v1::Vec3 {
                x: 0.1,
                y: 0.0,
                z: 0.0,
            }),
            angular: None,
        })),
    }
}

fn v1_action() -> v1::Action {
    v1::Action {
        kinematic: vec![v1::ObjectPose {
            object: 0,
            pose: Some(v1_pose(0.1)),
        }],
    }
}

/// A valid message of each call.
fn valid_proto(rpc: Rpc) -> Msg {
    match rpc {
        Rpc::Rollout => Msg::Rollout(v1::RolloutRequest {
            scene: Some(v1_scene()),
            steps: 10,
            dt_steps: 2,
            ..Default::default()
        }),
        Rpc::Predict => Msg::Predict(v1::PredictRequest {
            variants: vec![v1_scene(), v1_scene()],
            steps: 5,
            every: 2,
            ..Default::default()
        }),
        Rpc::CreateSession => Msg::Create(v1::CreateSessionRequest {
            scene: Some(v1_scene()),
            dt_steps: 1,
            kinematic: vec![0],
            ..Default::default()
        }),
        Rpc::Step => Msg::Step(v1::StepRequest {
            session_id: "s1".into(),
            steps: 2,
            actions: vec![v1_action(), v1_action()],
            ..Default::default()
        }),
        Rpc::SetState => Msg::SetState(v1::SetStateRequest {
            session_id: "s1".into(),
            objects: vec![v1_state(1), v1_state(2)],
        }),
        Rpc::SessionPredict => Msg::SessionPredict(v1::SessionPredictRequest {
            session_id: "s1".into(),
            variants: vec![v1::SessionVariant {
                state: vec![v1_state(2)],
                actions: vec![v1_action(), v1_action(), v1_action()],
            }],
            steps: 3,
            every: 1,
            ..Default::default()
        }),
        Rpc::InteractOpen => Msg::Interact(v1::InteractRequest {
            create: Some(v1::CreateSessionRequest {
                scene: Some(v1_scene()),
                kinematic: vec![0],
                ..Default::default()
            }),
            ..Default::default()
        }),
        Rpc::InteractStep => Msg::Interact(v1::InteractRequest {
            action: Some(v1_action()),
            correct: vec![v1_state(1)],
            ..Default::default()
        }),
    }
}

fn all_valid_messages_are_accepted() {
    for rpc in RPCS {
        let m = valid_proto(rpc);
        proto_message(rpc, &m).unwrap_or_else(|e| panic!("{rpc:?}: {e}"));
        proto_request(rpc, &m.encode()).unwrap_or_else(|e| panic!("{rpc:?} encoded: {e}"));
    }
}

fn vec3<'a>(v: &'a mut Option<v1::Vec3>, out: &mut Vec<&'a mut f32>) {
    if let Some(v1::Vec3 { x, y, z }) = v {
        out.extend([x, y, z]);
    }
}

fn pose_floats<'a>(p: &'a mut Option<v1::Pose>, out: &mut Vec<&'a mut f32>) {
    if let Some(v1::Pose {
        translation,
        rotation,
    }) = p
    {
        vec3(translation, out);
        if let Some(v1::Quaternion { x, y, z, w }) = rotation {
            out.extend([x, y, z, w]);
        }
    }
}

fn scene_floats<'a>(s: &'a mut v1::Scene, out: &mut Vec<&'a mut f32>, ints: &mut Vec<&'a mut u32>) {
    for o in &mut s.objects {
        let v1::ObjectSpec {
            shape,
            pose,
            motion,
            mass,
            friction,
            restitution,
        } = o;
        match shape {
            Some(v1::object_spec::Shape::Points(c)) => out.extend(c.xyz.iter_mut()),
            Some(v1::object_spec::Shape::Mesh(m)) => {
                out.extend(m.vertices.iter_mut());
                ints.extend(m.faces.iter_mut());
                ints.push(&mut m.samples);
            }
            None => {}
        }
        pose_floats(pose, out);
        match motion {
            Some(v1::object_spec::Motion::PreviousPose(p)) => {
                let v1::Pose {
                    translation,
                    rotation,
                } = p;
                vec3(translation, out);
                if let Some(v1::Quaternion { x, y, z, w }) = rotation {
                    out.extend([x, y, z, w]);
                }
            }
            Some(v1::object_spec::Motion::Velocity(v)) => {
                vec3(&mut v.linear, out);
                vec3(&mut v.angular, out);
            }
            None => {}
        }
        out.extend([mass, friction, restitution]);
    }
}

fn state_floats<'a>(
    s: &'a mut v1::ObjectState,
    out: &mut Vec<&'a mut f32>,
    ints: &mut Vec<&'a mut u32>,
) {
    ints.push(&mut s.object);
    pose_floats(&mut s.pose, out);
    match &mut s.motion {
        Some(v1::object_state::Motion::PreviousPose(p)) => {
            let v1::Pose {
                translation,
                rotation,
            } = p;
            vec3(translation, out);
            if let Some(v1::Quaternion { x, y, z, w }) = rotation {
                out.extend([x, y, z, w]);
            }
        }
        Some(v1::object_state::Motion::Velocity(v)) => {
            vec3(&mut v.linear, out);
            vec3(&mut v.angular, out);
        }
        None => {}
    }
}

fn action_floats<'a>(
    a: &'a mut v1::Action,
    out: &mut Vec<&'a mut f32>,
    ints: &mut Vec<&'a mut u32>,
) {
    for k in &mut a.kinematic {
        ints.push(&mut k.object);
        pose_floats(&mut k.pose, out);
    }
}

/// Every float and every count or index of a message.
fn numbers(m: &mut Msg) -> (Vec<&mut f32>, Vec<&mut u32>) {
    let (mut f, mut i) = (Vec::new(), Vec::new());
    match m {
        Msg::Rollout(r) => {
            i.extend([&mut r.steps, &mut r.dt_steps]);
            if let Some(s) = &mut r.scene {
                scene_floats(s, &mut f, &mut i);
            }
        }
        Msg::Predict(r) => {
            i.extend([&mut r.steps, &mut r.dt_steps, &mut r.every]);
            for s in &mut r.variants {
                scene_floats(s, &mut f, &mut i);
            }
        }
        Msg::Create(r) => {
            i.push(&mut r.dt_steps);
            i.extend(r.kinematic.iter_mut());
            if let Some(s) = &mut r.scene {
                scene_floats(s, &mut f, &mut i);
            }
        }
        Msg::Step(r) => {
            i.push(&mut r.steps);
            for a in &mut r.actions {
                action_floats(a, &mut f, &mut i);
            }
        }
        Msg::SetState(r) => {
            for s in &mut r.objects {
                state_floats(s, &mut f, &mut i);
            }
        }
        Msg::SessionPredict(r) => {
            i.extend([&mut r.steps, &mut r.every]);
            for v in &mut r.variants {
                for s in &mut v.state {
                    state_floats(s, &mut f, &mut i);
                }
                for a in &mut v.actions {
                    action_floats(a, &mut f, &mut i);
                }
            }
        }
        Msg::Interact(r) => {
            if let Some(c) = &mut r.create {
                i.push(&mut c.dt_steps);
                i.extend(c.kinematic.iter_mut());
                if let Some(s) = &mut c.scene {
                    scene_floats(s, &mut f, &mut i);
                }
            }
            if let Some(a) = &mut r.action {
                action_floats(a, &mut f, &mut i);
            }
            for s in &mut r.correct {
                state_floats(s, &mut f, &mut i);
            }
        }
    }
    (f, i)
}

/// Structural damage to a message: a required pose or shape missing, a cloud whose length is
/// not a multiple of 3, every object gone, objects or points multiplied past the limits.
#[derive(Clone, Copy, Debug)]
enum Damage {
    None,
    NoPose(usize),
    NoShape(usize),
    RaggedCloud(usize),
    NoObjects,
    ManyObjects(usize),
    ManyPoints(usize),
    NoSessionPose(usize),
}

fn damage() -> impl Strategy<Value = Damage> {
    prop_oneof![
        4 => Just(Damage::None),
        1 => any::<usize>().prop_map(Damage::NoPose),
        1 => any::<usize>().prop_map(Damage::NoShape),
        1 => any::<usize>().prop_map(Damage::RaggedCloud),
        1 => Just(Damage::NoObjects),
        1 => prop_oneof![Just(257usize), Just(1100)].prop_map(Damage::ManyObjects),
        1 => prop_oneof![Just(4097usize), Just(9000)].prop_map(Damage::ManyPoints),
        1 => any::<usize>().prop_map(Damage::NoSessionPose),
    ]
}

fn scenes(m: &mut Msg) -> Vec<&mut v1::Scene> {
    match m {
        Msg::Rollout(r) => r.scene.iter_mut().collect(),
        Msg::Predict(r) => r.variants.iter_mut().collect(),
        Msg::Create(r) => r.scene.iter_mut().collect(),
        Msg::Interact(r) => r
            .create
            .iter_mut()
            .filter_map(|c| c.scene.as_mut())
            .collect(),
        _ => Vec::new(),
    }
}

fn harm(m: &mut Msg, d: Damage) {
    match d {
        Damage::NoSessionPose(k) => {
            let poses: Vec<&mut Option<v1::Pose>> = match m {
                Msg::SetState(r) => r.objects.iter_mut().map(|s| &mut s.pose).collect(),
                Msg::Step(r) => r
                    .actions
                    .iter_mut()
                    .flat_map(|a| a.kinematic.iter_mut().map(|k| &mut k.pose))
                    .collect(),
                Msg::Interact(r) => r.correct.iter_mut().map(|s| &mut s.pose).collect(),
                _ => Vec::new(),
            };
            let n = poses.len();
            if let Some(p) = poses.into_iter().nth(k % n.max(1)) {
                *p = None;
            }
        }
        _ => {
            for s in scenes(m) {
                let n = s.objects.len().max(1);
                match d {
                    Damage::NoPose(k) => {
                        if let Some(o) = s.objects.get_mut(k % n) {
                            o.pose = None;
                        }
                    }
                    Damage::NoShape(k) => {
                        if let Some(o) = s.objects.get_mut(k % n) {
                            o.shape = None;
                        }
                    }
                    Damage::RaggedCloud(k) => {
                        if let Some(v1::ObjectSpec {
                            shape: Some(v1::object_spec::Shape::Points(c)),
                            ..
                        }) = s.objects.get_mut(k % n)
                        {
                            c.xyz.pop();
                        }
                    }
                    Damage::NoObjects => s.objects.clear(),
                    Damage::ManyObjects(count) => {
                        if let Some(first) = s.objects.first().cloned() {
                            s.objects.resize(count, first);
                        }
                    }
                    Damage::ManyPoints(count) => {
                        if let Some(v1::ObjectSpec {
                            shape: Some(v1::object_spec::Shape::Points(c)),
                            ..
                        }) = s.objects.first_mut()
                        {
                            c.xyz.resize(count * 3, 0.05);
                        }
                    }
                    Damage::None | Damage::NoSessionPose(_) => {}
                }
            }
        }
    }
}

fn hostile_f32() -> impl Strategy<Value = f32> {
    prop_oneof![
        Just(f32::NAN),
        Just(f32::INFINITY),
        Just(f32::NEG_INFINITY),
        Just(f32::MAX),
        Just(f32::MIN),
        Just(f32::MIN_POSITIVE),
        Just(1e-45f32),
        Just(-0.0f32),
        Just(0.0f32),
        Just(1e5f32),
        Just(100_001.0f32),
        Just(1e-7f32),
        any::<f32>(),
    ]
}

fn hostile_u32() -> impl Strategy<Value = u32> {
    prop_oneof![
        Just(0u32),
        Just(1),
        Just(2),
        Just(u32::MAX),
        Just(u32::MAX - 1),
        Just(100_000),
        0u32..20,
        any::<u32>(),
    ]
}

fn rpc() -> impl Strategy<Value = Rpc> {
    proptest::sample::select(RPCS.to_vec())
}

// ---- the runner ----

/// What the cases of one property came to: `accepted`, or `rejected <field>` with indices
/// left out (`scene.objects[].mass`).
type Tally = BTreeMap<String, u64>;

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
fn record(tally: &RefCell<Tally>, outcome: Result<(), FieldError>) -> Result<(), TestCaseError> {
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

fn cases(default: u32) -> u32 {
    std::env::var("PROPTEST_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// Runs `test` on `cases` values of `strategy` (no regression files are written), then
/// prints what they came to.
fn run<S: Strategy>(
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
