from dynaserve.v1 import world_model_pb2 as _world_model_pb2
from google.protobuf.internal import containers as _containers
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class ObjectPose(_message.Message):
    __slots__ = ("object", "pose")
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    object: int
    pose: _world_model_pb2.Pose
    def __init__(self, object: _Optional[int] = ..., pose: _Optional[_Union[_world_model_pb2.Pose, _Mapping]] = ...) -> None: ...

class Action(_message.Message):
    __slots__ = ("kinematic",)
    KINEMATIC_FIELD_NUMBER: _ClassVar[int]
    kinematic: _containers.RepeatedCompositeFieldContainer[ObjectPose]
    def __init__(self, kinematic: _Optional[_Iterable[_Union[ObjectPose, _Mapping]]] = ...) -> None: ...

class ObjectState(_message.Message):
    __slots__ = ("object", "pose", "previous_pose", "velocity")
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    PREVIOUS_POSE_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FIELD_NUMBER: _ClassVar[int]
    object: int
    pose: _world_model_pb2.Pose
    previous_pose: _world_model_pb2.Pose
    velocity: _world_model_pb2.Velocity
    def __init__(self, object: _Optional[int] = ..., pose: _Optional[_Union[_world_model_pb2.Pose, _Mapping]] = ..., previous_pose: _Optional[_Union[_world_model_pb2.Pose, _Mapping]] = ..., velocity: _Optional[_Union[_world_model_pb2.Velocity, _Mapping]] = ...) -> None: ...

class CreateSessionRequest(_message.Message):
    __slots__ = ("model", "scene", "dt_steps", "kinematic", "shared")
    MODEL_FIELD_NUMBER: _ClassVar[int]
    SCENE_FIELD_NUMBER: _ClassVar[int]
    DT_STEPS_FIELD_NUMBER: _ClassVar[int]
    KINEMATIC_FIELD_NUMBER: _ClassVar[int]
    SHARED_FIELD_NUMBER: _ClassVar[int]
    model: str
    scene: _world_model_pb2.Scene
    dt_steps: int
    kinematic: _containers.RepeatedScalarFieldContainer[int]
    shared: bool
    def __init__(self, model: _Optional[str] = ..., scene: _Optional[_Union[_world_model_pb2.Scene, _Mapping]] = ..., dt_steps: _Optional[int] = ..., kinematic: _Optional[_Iterable[int]] = ..., shared: _Optional[bool] = ...) -> None: ...

class SessionInfo(_message.Message):
    __slots__ = ("session_id", "model", "expires_at_unix_ms", "objects", "dt_steps", "kinematic", "shared")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    MODEL_FIELD_NUMBER: _ClassVar[int]
    EXPIRES_AT_UNIX_MS_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    DT_STEPS_FIELD_NUMBER: _ClassVar[int]
    KINEMATIC_FIELD_NUMBER: _ClassVar[int]
    SHARED_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    model: str
    expires_at_unix_ms: int
    objects: int
    dt_steps: int
    kinematic: _containers.RepeatedScalarFieldContainer[int]
    shared: bool
    def __init__(self, session_id: _Optional[str] = ..., model: _Optional[str] = ..., expires_at_unix_ms: _Optional[int] = ..., objects: _Optional[int] = ..., dt_steps: _Optional[int] = ..., kinematic: _Optional[_Iterable[int]] = ..., shared: _Optional[bool] = ...) -> None: ...

class StepRequest(_message.Message):
    __slots__ = ("session_id", "steps", "actions", "timeout_ms")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    ACTIONS_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    steps: int
    actions: _containers.RepeatedCompositeFieldContainer[Action]
    timeout_ms: int
    def __init__(self, session_id: _Optional[str] = ..., steps: _Optional[int] = ..., actions: _Optional[_Iterable[_Union[Action, _Mapping]]] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class SetStateRequest(_message.Message):
    __slots__ = ("session_id", "objects")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    objects: _containers.RepeatedCompositeFieldContainer[ObjectState]
    def __init__(self, session_id: _Optional[str] = ..., objects: _Optional[_Iterable[_Union[ObjectState, _Mapping]]] = ...) -> None: ...

class GetStateRequest(_message.Message):
    __slots__ = ("session_id",)
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    def __init__(self, session_id: _Optional[str] = ...) -> None: ...

class SessionState(_message.Message):
    __slots__ = ("session_id", "step", "time", "poses", "previous_poses", "expires_at_unix_ms")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    STEP_FIELD_NUMBER: _ClassVar[int]
    TIME_FIELD_NUMBER: _ClassVar[int]
    POSES_FIELD_NUMBER: _ClassVar[int]
    PREVIOUS_POSES_FIELD_NUMBER: _ClassVar[int]
    EXPIRES_AT_UNIX_MS_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    step: int
    time: float
    poses: _containers.RepeatedCompositeFieldContainer[_world_model_pb2.Pose]
    previous_poses: _containers.RepeatedCompositeFieldContainer[_world_model_pb2.Pose]
    expires_at_unix_ms: int
    def __init__(self, session_id: _Optional[str] = ..., step: _Optional[int] = ..., time: _Optional[float] = ..., poses: _Optional[_Iterable[_Union[_world_model_pb2.Pose, _Mapping]]] = ..., previous_poses: _Optional[_Iterable[_Union[_world_model_pb2.Pose, _Mapping]]] = ..., expires_at_unix_ms: _Optional[int] = ...) -> None: ...

class ForkRequest(_message.Message):
    __slots__ = ("session_id",)
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    def __init__(self, session_id: _Optional[str] = ...) -> None: ...

class DeleteSessionRequest(_message.Message):
    __slots__ = ("session_id",)
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    def __init__(self, session_id: _Optional[str] = ...) -> None: ...

class DeleteSessionResponse(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class SessionVariant(_message.Message):
    __slots__ = ("state", "actions")
    STATE_FIELD_NUMBER: _ClassVar[int]
    ACTIONS_FIELD_NUMBER: _ClassVar[int]
    state: _containers.RepeatedCompositeFieldContainer[ObjectState]
    actions: _containers.RepeatedCompositeFieldContainer[Action]
    def __init__(self, state: _Optional[_Iterable[_Union[ObjectState, _Mapping]]] = ..., actions: _Optional[_Iterable[_Union[Action, _Mapping]]] = ...) -> None: ...

class SessionPredictRequest(_message.Message):
    __slots__ = ("session_id", "variants", "steps", "every", "timeout_ms")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    VARIANTS_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    EVERY_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    variants: _containers.RepeatedCompositeFieldContainer[SessionVariant]
    steps: int
    every: int
    timeout_ms: int
    def __init__(self, session_id: _Optional[str] = ..., variants: _Optional[_Iterable[_Union[SessionVariant, _Mapping]]] = ..., steps: _Optional[int] = ..., every: _Optional[int] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class InteractRequest(_message.Message):
    __slots__ = ("session_id", "create", "action", "correct")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    CREATE_FIELD_NUMBER: _ClassVar[int]
    ACTION_FIELD_NUMBER: _ClassVar[int]
    CORRECT_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    create: CreateSessionRequest
    action: Action
    correct: _containers.RepeatedCompositeFieldContainer[ObjectState]
    def __init__(self, session_id: _Optional[str] = ..., create: _Optional[_Union[CreateSessionRequest, _Mapping]] = ..., action: _Optional[_Union[Action, _Mapping]] = ..., correct: _Optional[_Iterable[_Union[ObjectState, _Mapping]]] = ...) -> None: ...

class GradientCandidate(_message.Message):
    __slots__ = ("actions",)
    ACTIONS_FIELD_NUMBER: _ClassVar[int]
    actions: _containers.RepeatedCompositeFieldContainer[Action]
    def __init__(self, actions: _Optional[_Iterable[_Union[Action, _Mapping]]] = ...) -> None: ...

class CostTarget(_message.Message):
    __slots__ = ("object", "step", "position", "position_weight", "rotation", "rotation_weight")
    OBJECT_FIELD_NUMBER: _ClassVar[int]
    STEP_FIELD_NUMBER: _ClassVar[int]
    POSITION_FIELD_NUMBER: _ClassVar[int]
    POSITION_WEIGHT_FIELD_NUMBER: _ClassVar[int]
    ROTATION_FIELD_NUMBER: _ClassVar[int]
    ROTATION_WEIGHT_FIELD_NUMBER: _ClassVar[int]
    object: int
    step: int
    position: _world_model_pb2.Vec3
    position_weight: float
    rotation: _world_model_pb2.Quaternion
    rotation_weight: float
    def __init__(self, object: _Optional[int] = ..., step: _Optional[int] = ..., position: _Optional[_Union[_world_model_pb2.Vec3, _Mapping]] = ..., position_weight: _Optional[float] = ..., rotation: _Optional[_Union[_world_model_pb2.Quaternion, _Mapping]] = ..., rotation_weight: _Optional[float] = ...) -> None: ...

class GradientCost(_message.Message):
    __slots__ = ("targets", "smoothness")
    TARGETS_FIELD_NUMBER: _ClassVar[int]
    SMOOTHNESS_FIELD_NUMBER: _ClassVar[int]
    targets: _containers.RepeatedCompositeFieldContainer[CostTarget]
    smoothness: float
    def __init__(self, targets: _Optional[_Iterable[_Union[CostTarget, _Mapping]]] = ..., smoothness: _Optional[float] = ...) -> None: ...

class SessionGradientRequest(_message.Message):
    __slots__ = ("session_id", "candidates", "steps", "cost", "every", "timeout_ms")
    SESSION_ID_FIELD_NUMBER: _ClassVar[int]
    CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    COST_FIELD_NUMBER: _ClassVar[int]
    EVERY_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    session_id: str
    candidates: _containers.RepeatedCompositeFieldContainer[GradientCandidate]
    steps: int
    cost: GradientCost
    every: int
    timeout_ms: int
    def __init__(self, session_id: _Optional[str] = ..., candidates: _Optional[_Iterable[_Union[GradientCandidate, _Mapping]]] = ..., steps: _Optional[int] = ..., cost: _Optional[_Union[GradientCost, _Mapping]] = ..., every: _Optional[int] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class PoseGradient(_message.Message):
    __slots__ = ("translation", "rotation")
    TRANSLATION_FIELD_NUMBER: _ClassVar[int]
    ROTATION_FIELD_NUMBER: _ClassVar[int]
    translation: _world_model_pb2.Vec3
    rotation: _world_model_pb2.Vec3
    def __init__(self, translation: _Optional[_Union[_world_model_pb2.Vec3, _Mapping]] = ..., rotation: _Optional[_Union[_world_model_pb2.Vec3, _Mapping]] = ...) -> None: ...

class StepGradient(_message.Message):
    __slots__ = ("kinematic",)
    KINEMATIC_FIELD_NUMBER: _ClassVar[int]
    kinematic: _containers.RepeatedCompositeFieldContainer[PoseGradient]
    def __init__(self, kinematic: _Optional[_Iterable[_Union[PoseGradient, _Mapping]]] = ...) -> None: ...

class CandidateGradient(_message.Message):
    __slots__ = ("cost", "steps", "frames")
    COST_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    cost: float
    steps: _containers.RepeatedCompositeFieldContainer[StepGradient]
    frames: _containers.RepeatedCompositeFieldContainer[_world_model_pb2.StepFrame]
    def __init__(self, cost: _Optional[float] = ..., steps: _Optional[_Iterable[_Union[StepGradient, _Mapping]]] = ..., frames: _Optional[_Iterable[_Union[_world_model_pb2.StepFrame, _Mapping]]] = ...) -> None: ...

class GradientResponse(_message.Message):
    __slots__ = ("candidates", "model")
    CANDIDATES_FIELD_NUMBER: _ClassVar[int]
    MODEL_FIELD_NUMBER: _ClassVar[int]
    candidates: _containers.RepeatedCompositeFieldContainer[CandidateGradient]
    model: str
    def __init__(self, candidates: _Optional[_Iterable[_Union[CandidateGradient, _Mapping]]] = ..., model: _Optional[str] = ...) -> None: ...
