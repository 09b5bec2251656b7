from google.protobuf.internal import containers as _containers
from google.protobuf.internal import enum_type_wrapper as _enum_type_wrapper
from google.protobuf import descriptor as _descriptor
from google.protobuf import message as _message
from collections.abc import Iterable as _Iterable, Mapping as _Mapping
from typing import ClassVar as _ClassVar, Optional as _Optional, Union as _Union

DESCRIPTOR: _descriptor.FileDescriptor

class Material(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    MATERIAL_UNSPECIFIED: _ClassVar[Material]
    MATERIAL_RIGID: _ClassVar[Material]
    MATERIAL_ELASTIC: _ClassVar[Material]

class Sampler(int, metaclass=_enum_type_wrapper.EnumTypeWrapper):
    __slots__ = ()
    SAMPLER_UNSPECIFIED: _ClassVar[Sampler]
    SAMPLER_HEUN: _ClassVar[Sampler]
    SAMPLER_EULER: _ClassVar[Sampler]
MATERIAL_UNSPECIFIED: Material
MATERIAL_RIGID: Material
MATERIAL_ELASTIC: Material
SAMPLER_UNSPECIFIED: Sampler
SAMPLER_HEUN: Sampler
SAMPLER_EULER: Sampler

class Vec3(_message.Message):
    __slots__ = ("x", "y", "z")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ...) -> None: ...

class Quaternion(_message.Message):
    __slots__ = ("x", "y", "z", "w")
    X_FIELD_NUMBER: _ClassVar[int]
    Y_FIELD_NUMBER: _ClassVar[int]
    Z_FIELD_NUMBER: _ClassVar[int]
    W_FIELD_NUMBER: _ClassVar[int]
    x: float
    y: float
    z: float
    w: float
    def __init__(self, x: _Optional[float] = ..., y: _Optional[float] = ..., z: _Optional[float] = ..., w: _Optional[float] = ...) -> None: ...

class Pose(_message.Message):
    __slots__ = ("translation", "rotation")
    TRANSLATION_FIELD_NUMBER: _ClassVar[int]
    ROTATION_FIELD_NUMBER: _ClassVar[int]
    translation: Vec3
    rotation: Quaternion
    def __init__(self, translation: _Optional[_Union[Vec3, _Mapping]] = ..., rotation: _Optional[_Union[Quaternion, _Mapping]] = ...) -> None: ...

class PointCloud(_message.Message):
    __slots__ = ("xyz",)
    XYZ_FIELD_NUMBER: _ClassVar[int]
    xyz: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, xyz: _Optional[_Iterable[float]] = ...) -> None: ...

class TriangleMesh(_message.Message):
    __slots__ = ("vertices", "faces", "samples", "seed")
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    FACES_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    vertices: _containers.RepeatedScalarFieldContainer[float]
    faces: _containers.RepeatedScalarFieldContainer[int]
    samples: int
    seed: int
    def __init__(self, vertices: _Optional[_Iterable[float]] = ..., faces: _Optional[_Iterable[int]] = ..., samples: _Optional[int] = ..., seed: _Optional[int] = ...) -> None: ...

class Velocity(_message.Message):
    __slots__ = ("linear", "angular")
    LINEAR_FIELD_NUMBER: _ClassVar[int]
    ANGULAR_FIELD_NUMBER: _ClassVar[int]
    linear: Vec3
    angular: Vec3
    def __init__(self, linear: _Optional[_Union[Vec3, _Mapping]] = ..., angular: _Optional[_Union[Vec3, _Mapping]] = ...) -> None: ...

class ObjectSpec(_message.Message):
    __slots__ = ("points", "mesh", "pose", "previous_pose", "velocity", "mass", "friction", "restitution")
    POINTS_FIELD_NUMBER: _ClassVar[int]
    MESH_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    PREVIOUS_POSE_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FIELD_NUMBER: _ClassVar[int]
    MASS_FIELD_NUMBER: _ClassVar[int]
    FRICTION_FIELD_NUMBER: _ClassVar[int]
    RESTITUTION_FIELD_NUMBER: _ClassVar[int]
    points: PointCloud
    mesh: TriangleMesh
    pose: Pose
    previous_pose: Pose
    velocity: Velocity
    mass: float
    friction: float
    restitution: float
    def __init__(self, points: _Optional[_Union[PointCloud, _Mapping]] = ..., mesh: _Optional[_Union[TriangleMesh, _Mapping]] = ..., pose: _Optional[_Union[Pose, _Mapping]] = ..., previous_pose: _Optional[_Union[Pose, _Mapping]] = ..., velocity: _Optional[_Union[Velocity, _Mapping]] = ..., mass: _Optional[float] = ..., friction: _Optional[float] = ..., restitution: _Optional[float] = ...) -> None: ...

class Scene(_message.Message):
    __slots__ = ("objects",)
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    objects: _containers.RepeatedCompositeFieldContainer[ObjectSpec]
    def __init__(self, objects: _Optional[_Iterable[_Union[ObjectSpec, _Mapping]]] = ...) -> None: ...

class RolloutRequest(_message.Message):
    __slots__ = ("model", "scene", "steps", "dt_steps", "timeout_ms")
    MODEL_FIELD_NUMBER: _ClassVar[int]
    SCENE_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    DT_STEPS_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    model: str
    scene: Scene
    steps: int
    dt_steps: int
    timeout_ms: int
    def __init__(self, model: _Optional[str] = ..., scene: _Optional[_Union[Scene, _Mapping]] = ..., steps: _Optional[int] = ..., dt_steps: _Optional[int] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class StepTiming(_message.Message):
    __slots__ = ("queue_ms", "forward_ms", "batch_scenes")
    QUEUE_MS_FIELD_NUMBER: _ClassVar[int]
    FORWARD_MS_FIELD_NUMBER: _ClassVar[int]
    BATCH_SCENES_FIELD_NUMBER: _ClassVar[int]
    queue_ms: float
    forward_ms: float
    batch_scenes: int
    def __init__(self, queue_ms: _Optional[float] = ..., forward_ms: _Optional[float] = ..., batch_scenes: _Optional[int] = ...) -> None: ...

class StepFrame(_message.Message):
    __slots__ = ("step", "time", "poses", "timing", "spread")
    STEP_FIELD_NUMBER: _ClassVar[int]
    TIME_FIELD_NUMBER: _ClassVar[int]
    POSES_FIELD_NUMBER: _ClassVar[int]
    TIMING_FIELD_NUMBER: _ClassVar[int]
    SPREAD_FIELD_NUMBER: _ClassVar[int]
    step: int
    time: float
    poses: _containers.RepeatedCompositeFieldContainer[Pose]
    timing: StepTiming
    spread: _containers.RepeatedCompositeFieldContainer[ObjectSpread]
    def __init__(self, step: _Optional[int] = ..., time: _Optional[float] = ..., poses: _Optional[_Iterable[_Union[Pose, _Mapping]]] = ..., timing: _Optional[_Union[StepTiming, _Mapping]] = ..., spread: _Optional[_Iterable[_Union[ObjectSpread, _Mapping]]] = ...) -> None: ...

class ObjectSpread(_message.Message):
    __slots__ = ("position_m", "orientation_deg")
    POSITION_M_FIELD_NUMBER: _ClassVar[int]
    ORIENTATION_DEG_FIELD_NUMBER: _ClassVar[int]
    position_m: float
    orientation_deg: float
    def __init__(self, position_m: _Optional[float] = ..., orientation_deg: _Optional[float] = ...) -> None: ...

class PredictRequest(_message.Message):
    __slots__ = ("model", "variants", "steps", "dt_steps", "every", "timeout_ms")
    MODEL_FIELD_NUMBER: _ClassVar[int]
    VARIANTS_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    DT_STEPS_FIELD_NUMBER: _ClassVar[int]
    EVERY_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    model: str
    variants: _containers.RepeatedCompositeFieldContainer[Scene]
    steps: int
    dt_steps: int
    every: int
    timeout_ms: int
    def __init__(self, model: _Optional[str] = ..., variants: _Optional[_Iterable[_Union[Scene, _Mapping]]] = ..., steps: _Optional[int] = ..., dt_steps: _Optional[int] = ..., every: _Optional[int] = ..., timeout_ms: _Optional[int] = ...) -> None: ...

class Trajectory(_message.Message):
    __slots__ = ("frames",)
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    frames: _containers.RepeatedCompositeFieldContainer[StepFrame]
    def __init__(self, frames: _Optional[_Iterable[_Union[StepFrame, _Mapping]]] = ...) -> None: ...

class PredictResponse(_message.Message):
    __slots__ = ("trajectories", "model")
    TRAJECTORIES_FIELD_NUMBER: _ClassVar[int]
    MODEL_FIELD_NUMBER: _ClassVar[int]
    trajectories: _containers.RepeatedCompositeFieldContainer[Trajectory]
    model: str
    def __init__(self, trajectories: _Optional[_Iterable[_Union[Trajectory, _Mapping]]] = ..., model: _Optional[str] = ...) -> None: ...

class ListModelsRequest(_message.Message):
    __slots__ = ()
    def __init__(self) -> None: ...

class ModelInfo(_message.Message):
    __slots__ = ("name", "architecture", "dt_frame", "default_points", "max_objects", "max_points_per_object", "max_steps", "max_dt_steps", "max_variants", "gravity", "config_json", "max_vertices", "max_frames", "max_denoise_steps", "default_denoise_steps", "max_samples", "box_half_extent", "members", "max_request_cost", "gradients", "max_gradient_work")
    NAME_FIELD_NUMBER: _ClassVar[int]
    ARCHITECTURE_FIELD_NUMBER: _ClassVar[int]
    DT_FRAME_FIELD_NUMBER: _ClassVar[int]
    DEFAULT_POINTS_FIELD_NUMBER: _ClassVar[int]
    MAX_OBJECTS_FIELD_NUMBER: _ClassVar[int]
    MAX_POINTS_PER_OBJECT_FIELD_NUMBER: _ClassVar[int]
    MAX_STEPS_FIELD_NUMBER: _ClassVar[int]
    MAX_DT_STEPS_FIELD_NUMBER: _ClassVar[int]
    MAX_VARIANTS_FIELD_NUMBER: _ClassVar[int]
    GRAVITY_FIELD_NUMBER: _ClassVar[int]
    CONFIG_JSON_FIELD_NUMBER: _ClassVar[int]
    MAX_VERTICES_FIELD_NUMBER: _ClassVar[int]
    MAX_FRAMES_FIELD_NUMBER: _ClassVar[int]
    MAX_DENOISE_STEPS_FIELD_NUMBER: _ClassVar[int]
    DEFAULT_DENOISE_STEPS_FIELD_NUMBER: _ClassVar[int]
    MAX_SAMPLES_FIELD_NUMBER: _ClassVar[int]
    BOX_HALF_EXTENT_FIELD_NUMBER: _ClassVar[int]
    MEMBERS_FIELD_NUMBER: _ClassVar[int]
    MAX_REQUEST_COST_FIELD_NUMBER: _ClassVar[int]
    GRADIENTS_FIELD_NUMBER: _ClassVar[int]
    MAX_GRADIENT_WORK_FIELD_NUMBER: _ClassVar[int]
    name: str
    architecture: str
    dt_frame: float
    default_points: int
    max_objects: int
    max_points_per_object: int
    max_steps: int
    max_dt_steps: int
    max_variants: int
    gravity: Vec3
    config_json: str
    max_vertices: int
    max_frames: int
    max_denoise_steps: int
    default_denoise_steps: int
    max_samples: int
    box_half_extent: float
    members: _containers.RepeatedScalarFieldContainer[str]
    max_request_cost: int
    gradients: bool
    max_gradient_work: int
    def __init__(self, name: _Optional[str] = ..., architecture: _Optional[str] = ..., dt_frame: _Optional[float] = ..., default_points: _Optional[int] = ..., max_objects: _Optional[int] = ..., max_points_per_object: _Optional[int] = ..., max_steps: _Optional[int] = ..., max_dt_steps: _Optional[int] = ..., max_variants: _Optional[int] = ..., gravity: _Optional[_Union[Vec3, _Mapping]] = ..., config_json: _Optional[str] = ..., max_vertices: _Optional[int] = ..., max_frames: _Optional[int] = ..., max_denoise_steps: _Optional[int] = ..., default_denoise_steps: _Optional[int] = ..., max_samples: _Optional[int] = ..., box_half_extent: _Optional[float] = ..., members: _Optional[_Iterable[str]] = ..., max_request_cost: _Optional[int] = ..., gradients: _Optional[bool] = ..., max_gradient_work: _Optional[int] = ...) -> None: ...

class ListModelsResponse(_message.Message):
    __slots__ = ("models",)
    MODELS_FIELD_NUMBER: _ClassVar[int]
    models: _containers.RepeatedCompositeFieldContainer[ModelInfo]
    def __init__(self, models: _Optional[_Iterable[_Union[ModelInfo, _Mapping]]] = ...) -> None: ...

class MeshObject(_message.Message):
    __slots__ = ("vertices", "faces", "material", "velocity", "vertex_velocities")
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    FACES_FIELD_NUMBER: _ClassVar[int]
    MATERIAL_FIELD_NUMBER: _ClassVar[int]
    VELOCITY_FIELD_NUMBER: _ClassVar[int]
    VERTEX_VELOCITIES_FIELD_NUMBER: _ClassVar[int]
    vertices: _containers.RepeatedScalarFieldContainer[float]
    faces: _containers.RepeatedScalarFieldContainer[int]
    material: Material
    velocity: Velocity
    vertex_velocities: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, vertices: _Optional[_Iterable[float]] = ..., faces: _Optional[_Iterable[int]] = ..., material: _Optional[_Union[Material, str]] = ..., velocity: _Optional[_Union[Velocity, _Mapping]] = ..., vertex_velocities: _Optional[_Iterable[float]] = ...) -> None: ...

class MeshScene(_message.Message):
    __slots__ = ("objects",)
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    objects: _containers.RepeatedCompositeFieldContainer[MeshObject]
    def __init__(self, objects: _Optional[_Iterable[_Union[MeshObject, _Mapping]]] = ...) -> None: ...

class GenerateRequest(_message.Message):
    __slots__ = ("model", "scene", "frames", "denoise_steps", "sampler", "samples", "seed", "timeout_ms", "raw_vertices", "noise")
    MODEL_FIELD_NUMBER: _ClassVar[int]
    SCENE_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    DENOISE_STEPS_FIELD_NUMBER: _ClassVar[int]
    SAMPLER_FIELD_NUMBER: _ClassVar[int]
    SAMPLES_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    TIMEOUT_MS_FIELD_NUMBER: _ClassVar[int]
    RAW_VERTICES_FIELD_NUMBER: _ClassVar[int]
    NOISE_FIELD_NUMBER: _ClassVar[int]
    model: str
    scene: MeshScene
    frames: int
    denoise_steps: int
    sampler: Sampler
    samples: int
    seed: int
    timeout_ms: int
    raw_vertices: bool
    noise: _containers.RepeatedScalarFieldContainer[float]
    def __init__(self, model: _Optional[str] = ..., scene: _Optional[_Union[MeshScene, _Mapping]] = ..., frames: _Optional[int] = ..., denoise_steps: _Optional[int] = ..., sampler: _Optional[_Union[Sampler, str]] = ..., samples: _Optional[int] = ..., seed: _Optional[int] = ..., timeout_ms: _Optional[int] = ..., raw_vertices: _Optional[bool] = ..., noise: _Optional[_Iterable[float]] = ...) -> None: ...

class GenerateProgress(_message.Message):
    __slots__ = ("step", "steps", "t", "timing")
    STEP_FIELD_NUMBER: _ClassVar[int]
    STEPS_FIELD_NUMBER: _ClassVar[int]
    T_FIELD_NUMBER: _ClassVar[int]
    TIMING_FIELD_NUMBER: _ClassVar[int]
    step: int
    steps: int
    t: float
    timing: StepTiming
    def __init__(self, step: _Optional[int] = ..., steps: _Optional[int] = ..., t: _Optional[float] = ..., timing: _Optional[_Union[StepTiming, _Mapping]] = ...) -> None: ...

class ObjectFrame(_message.Message):
    __slots__ = ("vertices", "pose", "fit_rms")
    VERTICES_FIELD_NUMBER: _ClassVar[int]
    POSE_FIELD_NUMBER: _ClassVar[int]
    FIT_RMS_FIELD_NUMBER: _ClassVar[int]
    vertices: _containers.RepeatedScalarFieldContainer[float]
    pose: Pose
    fit_rms: float
    def __init__(self, vertices: _Optional[_Iterable[float]] = ..., pose: _Optional[_Union[Pose, _Mapping]] = ..., fit_rms: _Optional[float] = ...) -> None: ...

class MeshFrame(_message.Message):
    __slots__ = ("frame", "time", "objects")
    FRAME_FIELD_NUMBER: _ClassVar[int]
    TIME_FIELD_NUMBER: _ClassVar[int]
    OBJECTS_FIELD_NUMBER: _ClassVar[int]
    frame: int
    time: float
    objects: _containers.RepeatedCompositeFieldContainer[ObjectFrame]
    def __init__(self, frame: _Optional[int] = ..., time: _Optional[float] = ..., objects: _Optional[_Iterable[_Union[ObjectFrame, _Mapping]]] = ...) -> None: ...

class GeneratedSample(_message.Message):
    __slots__ = ("sample", "seed", "frames")
    SAMPLE_FIELD_NUMBER: _ClassVar[int]
    SEED_FIELD_NUMBER: _ClassVar[int]
    FRAMES_FIELD_NUMBER: _ClassVar[int]
    sample: int
    seed: int
    frames: _containers.RepeatedCompositeFieldContainer[MeshFrame]
    def __init__(self, sample: _Optional[int] = ..., seed: _Optional[int] = ..., frames: _Optional[_Iterable[_Union[MeshFrame, _Mapping]]] = ...) -> None: ...

class GenerateEvent(_message.Message):
    __slots__ = ("progress", "sample")
    PROGRESS_FIELD_NUMBER: _ClassVar[int]
    SAMPLE_FIELD_NUMBER: _ClassVar[int]
    progress: GenerateProgress
    sample: GeneratedSample
    def __init__(self, progress: _Optional[_Union[GenerateProgress, _Mapping]] = ..., sample: _Optional[_Union[GeneratedSample, _Mapping]] = ...) -> None: ...
