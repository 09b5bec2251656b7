"""Is a landing predictable from the state a one-step model sees? Fits a small MLP (PyTorch) on
the landing windows (k = 1) of a training split of `dynaserve sim drop` scenes and scores it on
those of a test split, next to the clamp of ballistic-with-floor.

    python3 crates/sim/python/landing_regressor.py data/diag/drop-train-20k data/diag/drop-test

Landing windows and the clamp are those of `landings.py`. The inputs are what frames t-1 and t show
(no later frame): the attitude at t (rotation matrix, 9), the rotation over the last frame
(scaled axis, 3), the centre's increment (3), the height of the lowest reference point and the
clamp's lift (2), that point in the body frame (3), the cloud's extents (3), restitution,
friction and log mass (3), the shape (one-hot of 10), and with `--lever` the lowest point's
offset from the centre in the world frame (3). The target is the true next centre minus the
clamp's. `--drop a,b,...` removes input columns (in the order above) to see what matters.
Prints the held-out RMSE at the epoch with the best validation error (10% of the training
windows held out).
"""

import argparse
import argparse

import numpy as np
import torch

from landings import landings


def rotation_vector(r):
    """Scaled axis of a rotation matrix."""
    angle = np.arccos(np.clip((np.trace(r) - 1) / 2, -1, 1))
    axis = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])
    return axis / (2 * np.sin(angle)) * angle if angle > 1e-6 else axis / 2


def landing_data(split, lever):
    """Inputs `[n, F]`, targets `[n, 3]` (m) and the clamp's error `[n]` (m) of a split."""
    xs, ys, clamp_err = [], [], []
    for _, w in landings(split):
        shard, j, t, p, rot, posed = w.shard, w.j, w.t, w.p, w.rot, w.posed
        extents = w.cloud.max(0) - w.cloud.min(0)
        material = [shard["restitution"][j], shard["friction"][j], np.log(shard["mass"][j])]
        shape = np.eye(10)[shard["shape_id"][j]]
        lowest = posed[t, :, 2].argmin()
        x = [rot[t].ravel(), rotation_vector(rot[t] @ rot[t - 1].T), p[t] - p[t - 1],
             [w.low[t], w.lift], w.cloud[lowest], extents, material, shape]
        if lever:
            x.append(posed[t, lowest])
        xs.append(np.concatenate(x))
        ys.append(p[t + 1] - w.clamp)
        clamp_err.append(np.linalg.norm(p[t + 1] - w.clamp))
    return np.array(xs, np.float32), np.array(ys, np.float32), np.array(clamp_err)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("train")
    ap.add_argument("test")
    ap.add_argument("--lever", action="store_true", help="add the lowest point's offset")
    ap.add_argument("--drop", default="", help="input columns to remove, comma-separated")
    ap.add_argument("--epochs", type=int, default=60)
    args = ap.parse_args()
    xtr, ytr, _ = landing_data(args.train, args.lever)
    xte, yte, clamp = landing_data(args.test, args.lever)
    keep = [i for i in range(xtr.shape[1])
            if str(i) not in args.drop.split(",")]
    xtr, xte = xtr[:, keep], xte[:, keep]
    print(f"{len(xtr)} training and {len(xte)} test landing windows, {len(keep)} inputs")
    mu, sd = xtr.mean(0), xtr.std(0) + 1e-6
    x, y = torch.tensor((xtr - mu) / sd), torch.tensor(ytr * 10)  # targets in decimetres
    xe = torch.tensor((xte - mu) / sd)
    torch.manual_seed(0)
    net = torch.nn.Sequential(
        torch.nn.Linear(x.shape[1], 256), torch.nn.SiLU(),
        torch.nn.Linear(256, 256), torch.nn.SiLU(),
        torch.nn.Linear(256, 256), torch.nn.SiLU(),
        torch.nn.Linear(256, 3))
    opt = torch.optim.AdamW(net.parameters(), 1e-3, weight_decay=1e-4)
    order = torch.randperm(len(x))
    val, train = order[: len(x) // 10], order[len(x) // 10:]
    best = (float("inf"), float("nan"))
    for epoch in range(args.epochs):
        net.train()
        for b in torch.split(train[torch.randperm(len(train))], 256):
            loss = ((net(x[b]) - y[b]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        net.eval()
        with torch.no_grad():
            v = ((net(x[val]) - y[val]) ** 2).sum(1).mean().sqrt().item() / 10
            t = float(np.sqrt(((net(xe).numpy() / 10 - yte) ** 2).sum(1).mean()))
        if v < best[0]:
            best = (v, t)
        if (epoch + 1) % 10 == 0:
            print(f"epoch {epoch + 1}: validation {1000 * v:.1f} mm, test {1000 * t:.1f} mm")
    print(f"held-out landing RMSE {1000 * best[1]:.1f} mm (best validation epoch); "
          f"clamp {1000 * float(np.sqrt((clamp ** 2).mean())):.1f} mm")


if __name__ == "__main__":
    main()
