"""Landing windows of single-object splits (`dynaserve sim drop`), shared by
`landing_windows.py` and `landing_regressor.py`.

A window t -> t+1 (k = 1) counts as a landing when the object is off the floor at t-1 and t
(its lowest posed reference point above 1 cm plus half the cloud's sampling spacing), no
impulse is seen at t-1 (centre acceleration within 1 m/s^2 of gravity), and an impulse at t or
floor contact at t+1 is (the floor and impulse tests of the evaluation's regimes,
docs/evaluation.md). The clamp is ballistic-with-floor: constant linear and angular velocity
plus free fall, raised so no reference point is below the floor.
"""

import glob
import json
from dataclasses import dataclass

import numpy as np
from safetensors.numpy import load_file


def rotation_matrices(q):
    """Rotation matrices `[..., 3, 3]` of unit quaternions `[..., 4]` ([x, y, z, w])."""
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    r = np.stack([
        1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
        2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
        2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
    ], -1)
    return r.reshape(q.shape[:-1] + (3, 3))


def spacing(cloud):
    """Median nearest-neighbour distance over the first 128 points, metres."""
    sub = cloud[:128]
    d = np.sqrt(((sub[:, None, :] - cloud[None, :, :]) ** 2).sum(-1))
    d[d == 0] = np.inf
    return float(np.median(d.min(1)))


@dataclass
class Landing:
    """One landing window: the object's track and the clamp's prediction for frame t+1."""

    shard: dict  # the shard's arrays
    j: int  # the object's row in the shard
    t: int  # the window's current frame
    p: np.ndarray  # centres `[frames, 3]`, metres
    rot: np.ndarray  # rotation matrices `[frames, 3, 3]`
    cloud: np.ndarray  # reference points `[n, 3]`, body frame, metres
    posed: np.ndarray  # reference points rotated into the world frame `[frames, n, 3]`
    low: np.ndarray  # height of the lowest posed point `[frames]`, metres
    base: np.ndarray  # constant-velocity free-fall centre at t+1 `[3]`, metres
    lift: float  # how far the clamp raises `base` out of the floor, metres
    clamp: np.ndarray  # ballistic-with-floor's centre at t+1 `[3]`, metres


def landings(split):
    """Yields `(manifest, Landing)` for every landing window of `split`'s single-object scenes."""
    manifest = json.load(open(f"{split}/manifest.json"))
    dt = manifest["dt_frame"]
    g = np.array(manifest["gravity"], dtype=np.float64)
    for path in sorted(glob.glob(f"{split}/shard-*.safetensors")):
        shard = load_file(path)
        offsets = shard["scene_object_offsets"]
        for s in range(len(offsets) - 1):
            if offsets[s + 1] - offsets[s] != 1:
                continue  # single-object scenes only
            j = int(offsets[s])
            p = shard["positions"][j].astype(np.float64)
            rot = rotation_matrices(shard["rotations"][j].astype(np.float64))
            cloud = shard["reference_points"][j].astype(np.float64)
            posed = np.einsum("fij,nj->fni", rot, cloud)
            low = posed[:, :, 2].min(1) + p[:, 2]
            floor = low < 0.01 + 0.5 * spacing(cloud)
            frames = len(p)
            impulse = np.zeros(frames, bool)
            acc = (p[2:] - 2 * p[1:-1] + p[:-2]) / dt ** 2
            impulse[1:-1] = np.linalg.norm(acc - g, axis=1) > 1.0
            for t in range(1, frames - 1):
                if floor[t - 1] or floor[t] or impulse[t - 1] or not (impulse[t] or floor[t + 1]):
                    continue
                base_rot = rot[t] @ rot[t - 1].T @ rot[t]
                base = 2 * p[t] - p[t - 1] + g * dt * dt
                lift = max(0.0, -(base[2] + (cloud @ base_rot.T)[:, 2].min()))
                clamp = base + np.array([0.0, 0.0, lift])
                yield manifest, Landing(shard, j, t, p, rot, cloud, posed, low, base, lift, clamp)
