"""How predictable is a landing? Scores two simple predictors on the one-step windows (k = 1) of
a single-object dataset (`dynaserve sim drop`) in which the object first touches the floor
inside the predicted frame, with numpy and safetensors.

    python3 crates/sim/python/landing_windows.py data/diag/drop-test

A window t -> t+1 counts as a landing when the object is off the floor at t-1 and t (its lowest
posed reference point above 1 cm plus half the cloud's sampling spacing), no impulse is seen
at t-1 (centre acceleration within 1 m/s^2 of gravity), and an impulse at t or floor contact
at t+1 is (the floor and impulse tests of the evaluation's regimes, docs/evaluation.md).

- clamp: constant linear and angular velocity plus free fall, raised so no reference point
  is below the floor (ballistic-with-floor);
- rebound: the clamp, plus the rebound of the lowest point treated as a point mass that hits
  the floor at the time its free fall predicts and leaves it with the restitution averaged
  with the floor's.

Prints the centre RMSE of both, per shape, and how the truth departs from the clamp.
"""

import glob
import json
import sys

import numpy as np
from safetensors.numpy import load_file


def rotation_matrix(q):
    """Rotation matrix of a unit quaternion [x, y, z, w]."""
    x, y, z, w = q
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def spacing(cloud):
    """Median nearest-neighbour distance over the first 128 points, metres."""
    sub = cloud[:128]
    d = np.sqrt(((sub[:, None, :] - cloud[None, :, :]) ** 2).sum(-1))
    d[d == 0] = np.inf
    return float(np.median(d.min(1)))


def landing_rows(split):
    manifest = json.load(open(f"{split}/manifest.json"))
    dt = manifest["dt_frame"]
    g = np.array(manifest["gravity"], dtype=np.float64)
    floor_e = manifest["generator_parameters"]["floor"]["restitution"]
    rows = []
    for path in sorted(glob.glob(f"{split}/shard-*.safetensors")):
        shard = load_file(path)
        offsets = shard["scene_object_offsets"]
        for s in range(len(offsets) - 1):
            if offsets[s + 1] - offsets[s] != 1:
                continue  # single-object scenes only
            j = offsets[s]
            p = shard["positions"][j].astype(np.float64)
            rot = [rotation_matrix(q) for q in shard["rotations"][j].astype(np.float64)]
            cloud = shard["reference_points"][j].astype(np.float64)
            frames = len(p)
            low = np.array([(cloud @ rot[f].T)[:, 2].min() + p[f, 2] for f in range(frames)])
            floor = low < 0.01 + 0.5 * spacing(cloud)
            impulse = np.zeros(frames, bool)
            acc = (p[2:] - 2 * p[1:-1] + p[:-2]) / dt ** 2
            impulse[1:-1] = np.linalg.norm(acc - g, axis=1) > 1.0
            e = 0.5 * (float(shard["restitution"][j]) + floor_e)
            for t in range(1, frames - 1):
                if floor[t - 1] or floor[t] or impulse[t - 1] or not (impulse[t] or floor[t + 1]):
                    continue
                base_rot = rot[t] @ rot[t - 1].T @ rot[t]
                base = 2 * p[t] - p[t - 1] + g * dt * dt
                lift = max(0.0, -(base[2] + (cloud @ base_rot.T)[:, 2].min()))
                clamp = base + np.array([0.0, 0.0, lift])
                rebound = clamp.copy()
                v = (p[t, 2] - p[t - 1, 2]) / dt + g[2] * dt / 2  # vertical speed at t
                disc = v * v - 2 * g[2] * low[t]
                if disc >= 0:
                    tau = (-v - np.sqrt(disc)) / g[2]  # time of impact in the frame
                    if 0 < tau <= dt:
                        r = dt - tau
                        up = -e * (v + g[2] * tau) * r + 0.5 * g[2] * r * r
                        rebound[2] = base[2] + lift + max(0.0, up)
                truth = p[t + 1]
                rows.append((
                    np.linalg.norm(clamp - truth), np.linalg.norm(rebound - truth),
                    truth[2] - clamp[2], np.linalg.norm((truth - clamp)[:2]),
                    rebound[2] - clamp[2], int(shard["shape_id"][j]),
                ))
    return np.array(rows)


def rms_mm(x):
    return 1000 * float(np.sqrt((x ** 2).mean()))


def main():
    rows = landing_rows(sys.argv[1])
    if len(rows) == 0:
        print("no landing windows")
        return
    print(f"{len(rows)} landing windows (k = 1)")
    print(f"centre RMSE: clamp {rms_mm(rows[:, 0]):.1f} mm, rebound {rms_mm(rows[:, 1]):.1f} mm")
    for shape in np.unique(rows[:, 5]):
        m = rows[:, 5] == shape
        print(f"  shape {int(shape)}: {int(m.sum())} windows, clamp {rms_mm(rows[m, 0]):.1f} mm, "
              f"rebound {rms_mm(rows[m, 1]):.1f} mm")
    dz, dxy, up = rows[:, 2], rows[:, 3], rows[:, 4]
    print(f"truth - clamp: height mean {1000 * dz.mean():.1f} mm, RMS {rms_mm(dz):.1f} mm, "
          f"horizontal RMS {rms_mm(dxy):.1f} mm; {int((dz < 0).sum())} of {len(rows)} end "
          f"lower than the clamp")
    print(f"correlation of the rebound's height with the truth's: {np.corrcoef(dz, up)[0, 1]:.2f}")


if __name__ == "__main__":
    main()
