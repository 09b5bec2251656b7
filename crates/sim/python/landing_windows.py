"""How predictable is a landing? Scores two simple predictors on the one-step windows (k = 1) of
a single-object dataset (`dynaserve sim drop`) in which the object first touches the floor
inside the predicted frame, with numpy and safetensors.

    python3 crates/sim/python/landing_windows.py data/diag/drop-test

Landing windows and the clamp are those of `landings.py`.

- clamp: constant linear and angular velocity plus free fall, raised so no reference point
  is below the floor (ballistic-with-floor);
- rebound: the clamp, plus the rebound of the lowest point treated as a point mass that hits
  the floor at the time its free fall predicts and leaves it with the restitution averaged
  with the floor's.

Prints the centre RMSE of both, per shape, and how the truth departs from the clamp.
"""

import sys

import numpy as np

from landings import landings


def landing_rows(split):
    rows = []
    for manifest, w in landings(split):
        dt = manifest["dt_frame"]
        g = np.array(manifest["gravity"], dtype=np.float64)
        floor_e = manifest["generator_parameters"]["floor"]["restitution"]
        e = 0.5 * (float(w.shard["restitution"][w.j]) + floor_e)
        p, t = w.p, w.t
        rebound = w.clamp.copy()
        v = (p[t, 2] - p[t - 1, 2]) / dt + g[2] * dt / 2  # vertical speed at t
        disc = v * v - 2 * g[2] * w.low[t]
        if disc >= 0:
            tau = (-v - np.sqrt(disc)) / g[2]  # time of impact in the frame
            if 0 < tau <= dt:
                r = dt - tau
                up = -e * (v + g[2] * tau) * r + 0.5 * g[2] * r * r
                rebound[2] = w.base[2] + w.lift + max(0.0, up)
        truth = p[t + 1]
        rows.append((
            np.linalg.norm(w.clamp - truth), np.linalg.norm(rebound - truth),
            truth[2] - w.clamp[2], np.linalg.norm((truth - w.clamp)[:2]),
            rebound[2] - w.clamp[2], int(w.shard["shape_id"][w.j]),
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
