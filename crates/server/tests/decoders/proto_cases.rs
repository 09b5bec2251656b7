//! The protobuf side: the gRPC calls, a valid message of each, every number of a message
//! reachable for hostile values, and structural damage (missing or extra parts).

use dynaserve_api::spec::session::{
    CreateSessionSpec, InteractOpen, InteractStep, SessionPredictSpec, SetStateSpec, StepSpec,
};
use dynaserve_api::spec::{PredictSpec, RolloutSpec};
use dynaserve_api::{FieldError, json, v1};
use dynaserve_server::engine::sessions::input::{apply_states, check_action};
use proptest::prelude::*;
use prost::Message;

use crate::checks::*;
use crate::json_cases::*;

/// Request kinds of the gRPC API.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Rpc {
    Rollout,
    Predict,
    CreateSession,
    Step,
    SetState,
    SessionPredict,
    InteractOpen,
    InteractStep,
}

pub(crate) const RPCS: [Rpc; 8] = [
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
pub(crate) fn proto_message(rpc: Rpc, m: &Msg) -> Result<(), FieldError> {
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
pub(crate) fn proto_request(rpc: Rpc, bytes: &[u8]) -> Result<(), FieldError> {
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
pub(crate) enum Msg {
    Rollout(v1::RolloutRequest),
    Predict(v1::PredictRequest),
    Create(v1::CreateSessionRequest),
    Step(v1::StepRequest),
    SetState(v1::SetStateRequest),
    SessionPredict(v1::SessionPredictRequest),
    Interact(v1::InteractRequest),
}

impl Msg {
    pub(crate) fn encode(&self) -> Vec<u8> {
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
pub(crate) fn valid_proto(rpc: Rpc) -> Msg {
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

pub(crate) fn all_valid_messages_are_accepted() {
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
pub(crate) fn numbers(m: &mut Msg) -> (Vec<&mut f32>, Vec<&mut u32>) {
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
pub(crate) enum Damage {
    None,
    NoPose(usize),
    NoShape(usize),
    RaggedCloud(usize),
    NoObjects,
    ManyObjects(usize),
    ManyPoints(usize),
    NoSessionPose(usize),
}

pub(crate) fn damage() -> impl Strategy<Value = Damage> {
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

pub(crate) fn harm(m: &mut Msg, d: Damage) {
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

pub(crate) fn hostile_f32() -> impl Strategy<Value = f32> {
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

pub(crate) fn hostile_u32() -> impl Strategy<Value = u32> {
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

pub(crate) fn rpc() -> impl Strategy<Value = Rpc> {
    proptest::sample::select(RPCS.to_vec())
}
