"""A sampling planner that pushes a box to a goal with a kinematic pusher.

Model-predictive control with the cross-entropy method: every planning round scores all
candidate pusher paths in ONE server call (Predict from a session: the geometry was sent once,
each candidate carries only its pusher path), executes the first steps of the best mean path
on the session, and plans again from the new state. A random pusher path of the same length,
run from a fork of the same start, is the baseline.

Distances are measured twice: in the learned model's own rollout (the session's state), and in
the ground truth, where both executed pusher paths are replayed in rapier by
``dynaserve sim replay`` (the binary given by ``--dynaserve``, else found in the repository's
``target/release`` or ``target/debug``, else on ``PATH``).

    python examples/push_planner.py --server http://127.0.0.1:8080
    python examples/push_planner.py --grpc 127.0.0.1:50051     # the same over gRPC
    python examples/push_planner.py --seeds 0-199   # one plan per seed, then a summary line
    python examples/push_planner.py --seeds 0-199 --json planner.json   # ... and every seed's distances
    python examples/push_planner.py --model rapier   # plan in the simulator itself (served beside)
    python examples/push_planner.py --model rigidformer-small-ensemble --risk-weight 1   # avoid what it is unsure of
    python examples/push_planner.py --refine 4   # and move the best paths down the cost's gradient

Planning in the model's own rollout makes the rapier distance a measure of the model: over many
seeds, a model whose pushes are forecast better ends closer to the goal more often.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import tempfile
import time
from typing import Any, Optional

import numpy as np

from dynaserve import Body, Client, box_points
from dynaserve.scene import scene_doc

BOX, PUSHER = 0, 1
HALF = 0.1  # box half extent, m
PUSHER_HALF = 0.06  # pusher half extent, m


def scene(seed: int):
    """A box resting on the floor at the origin and a kinematic pusher behind it."""
    box = Body(box_points([HALF] * 3, 128, seed), pose=[0, 0, HALF, 0, 0, 0, 1], mass=1.0, friction=0.5)
    pusher = Body(
        box_points([PUSHER_HALF] * 3, 96, seed + 1),
        pose=[-HALF - PUSHER_HALF - 0.02, 0, PUSHER_HALF, 0, 0, 0, 1],
        mass=5.0,
        friction=0.5,
    )
    return [box, pusher]


def path_from(start_xy: np.ndarray, velocities: np.ndarray, dt: float) -> np.ndarray:
    """Pusher poses ``[steps, 7]`` from planar velocities ``[steps, 2]`` (m/s)."""
    xy = start_xy + np.cumsum(velocities * dt, axis=0)
    poses = np.zeros((len(velocities), 7))
    poses[:, :2] = xy
    poses[:, 2] = PUSHER_HALF
    poses[:, 6] = 1.0
    return poses


def side_cost(traj: np.ndarray, paths: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """How close each candidate's pusher comes to the box's pushing side ``[candidates]``, m:
    the smallest distance over the horizon between the pusher (``paths``: ``[candidates,
    steps, 7]``) and the point just behind the predicted box (``traj``: ``[candidates, steps,
    objects, 7]``) on the side away from the goal, from where a push moves it towards the goal.
    It rewards making contact from the right side before the model's rollout can show the box
    moving."""
    box = traj[:, :, BOX, :2]
    away = box - goal
    away /= np.linalg.norm(away, axis=-1, keepdims=True) + 1e-9
    behind = box + away * (HALF + PUSHER_HALF)
    return np.linalg.norm(paths[:, :, :2] - behind, axis=-1).min(axis=1)


def risk(spread: np.ndarray) -> np.ndarray:
    """How unsure the model is of each candidate's outcome ``[candidates]``, m: the box's
    position spread of every step (``spread``: ``[candidates, steps, objects, 2]``, position
    m and orientation deg), summed in quadrature over the horizon as independent errors would
    add up by its end."""
    return np.sqrt((spread[:, :, BOX, 0] ** 2).sum(axis=1))


def velocity_gradient(grad_xy: np.ndarray, dt: float) -> np.ndarray:
    """The gradient of a cost with respect to the planar velocities ``[candidates, steps, 2]``
    (per m/s) from its gradient with respect to the pusher's positions ``grad_xy`` (same
    shape, per m): a velocity moves every later position by ``dt`` times it."""
    return dt * np.flip(np.cumsum(np.flip(grad_xy, axis=1), axis=1), axis=1)


def refine(session: Any, here: np.ndarray, v: np.ndarray, goal: np.ndarray, args: argparse.Namespace, dt: float) -> np.ndarray:
    """The candidates ``v`` (``[k, steps, 2]`` planar velocities, m/s) moved down the gradient
    of the box's final distance to the goal (a Gradient call on ``session``, whose pusher is at
    ``here``): each by ``args.refine_step`` m/s in root-mean-square over its steps, within the
    speed limit. A candidate whose gradient is zero (the pusher never reaches the box) stays."""
    paths = [path_from(here[PUSHER, :2], v[i], dt) for i in range(len(v))]
    cost = {"targets": [{"object": BOX, "position": [goal[0], goal[1], HALF], "position_weight": 1.0}]}
    g = session.gradient(args.horizon, kinematic=[{PUSHER: p} for p in paths], cost=cost)
    gv = velocity_gradient(np.asarray(g.translation)[:, :, 0, :2], dt)
    rms = np.sqrt((gv**2).sum(axis=2).mean(axis=1))[:, None, None]
    step = np.where(rms > 0, gv / np.maximum(rms, 1e-12), 0.0) * args.refine_step
    return np.clip(v - step, -args.speed, args.speed)


def find_dynaserve(given: Optional[str]) -> Optional[str]:
    """The ``dynaserve`` binary: ``given``, else the repository's release or debug build, else
    the one on ``PATH``; ``None`` when there is none."""
    if given:
        return given
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))))
    for profile in ("release", "debug"):
        path = os.path.join(root, "target", profile, "dynaserve")
        if os.access(path, os.X_OK):
            return path
    return shutil.which("dynaserve")


def replay(binary: str, bodies, path: np.ndarray, dt_frame: float) -> np.ndarray:
    """The rapier trajectory ``[steps + 1, objects, 7]`` of ``bodies`` with the pusher driven
    along ``path`` (``[steps, 7]``), from ``dynaserve sim replay``."""
    with tempfile.TemporaryDirectory() as tmp:
        scene_file = os.path.join(tmp, "scene.json")
        paths_file = os.path.join(tmp, "paths.json")
        with open(scene_file, "w") as f:
            json.dump({"scene": scene_doc(bodies), "kinematic": [PUSHER]}, f)
        with open(paths_file, "w") as f:
            json.dump({"paths": [{"object": PUSHER, "poses": np.asarray(path).tolist()}]}, f)
        out = subprocess.run(
            [binary, "sim", "replay", scene_file, "--paths", paths_file, "--dt-frame", repr(dt_frame)],
            check=True,
            capture_output=True,
            text=True,
        )
    return np.array(json.loads(out.stdout)["poses"])


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"7"``, ``"0-199"`` (inclusive) or ``"1,4,9-11"``."""
    seeds: list[int] = []
    for part in text.split(","):
        lo, sep, hi = part.strip().partition("-")
        if not lo:
            raise ValueError(f"not a seed or a range of seeds: {part!r}")
        first = int(lo)
        last = int(hi) if sep else first
        if last < first:
            raise ValueError(f"empty range of seeds: {part!r}")
        seeds.extend(range(first, last + 1))
    return seeds


def summary(results: list[tuple[float, ...]]) -> str:
    """Two lines over per-seed ``(planned, random, planned_off, random_off[, seconds])``: the
    rapier-replayed final distances to the goal (m; their means, medians and on how many seeds
    the plan ended closer than the random path), then how far the model's forecast of the box's
    final position was from rapier's (m; means and medians), for the executed plans and for
    the random paths. Planning exploits forecast errors, so the first of those is usually the
    larger."""
    r = np.array([d[:4] for d in results], dtype=float)
    planned, random_d, planned_off, random_off = r.T
    seconds = [d[4] for d in results if len(d) > 4]
    wins = int((planned < random_d).sum())
    return (
        f"over {len(results)} seeds (rapier replay): planned mean {planned.mean():.3f} m, "
        f"median {np.median(planned):.3f} m; random plan mean {random_d.mean():.3f} m, "
        f"median {np.median(random_d):.3f} m; planned closer than random on {wins} of {len(results)}\n"
        f"the model's final box position against rapier's: planned paths off by mean "
        f"{planned_off.mean():.3f} m (median {np.median(planned_off):.3f}), random paths by mean "
        f"{random_off.mean():.3f} m (median {np.median(random_off):.3f})"
        + (f"; planning took {np.median(seconds):.1f} s a seed (median)" if seconds else "")
    )


SETTINGS = ("goal", "rounds", "horizon", "execute", "samples", "iterations", "speed", "side_weight")
"""The options that change what a plan does: two records are paired seed by seed only when these
agree (``dynaserve train compare`` refuses them otherwise)."""


def record(model: dict, args: argparse.Namespace, results: list[tuple[int, tuple[float, ...]]]) -> dict:
    """The JSON record of a planner run: the model planned with, the settings that shape a plan
    and, per seed, the rapier-replayed final distances to the goal of the executed plan and of
    the random path and how far the model's final box position was from rapier's on each, in m.
    ``dynaserve train compare`` reads it as a scorecard's ``planner.json`` (the ship rule's
    planner clause pairs two such records seed by seed)."""
    return {
        "planner": "push",
        "model": {"name": model.get("name"), "architecture": model.get("architecture")},
        # The risk weight is recorded only when used, so records without it still compare.
        "settings": {
            name: getattr(args, name)
            for name in SETTINGS
            + (("risk_weight",) if getattr(args, "risk_weight", 0.0) else ())
            + (("refine", "refine_step", "grad_model") if getattr(args, "refine", 0) else ())
        },
        "seeds": [
            {"seed": seed, "planned": d[0], "random": d[1], "planned_off": d[2], "random_off": d[3]}
            | ({"seconds": d[4]} if len(d) > 4 else {})
            for seed, d in results
        ],
    }


def paired(reference: dict, candidate: dict) -> str:
    """One line comparing two planner records (``--json``) seed by seed over the seeds both
    hold: the candidate's mean rapier-replayed distance to the goal against the reference's,
    the mean paired difference (negative: the candidate ends closer) with its standard error,
    on how many seeds the candidate is closer, both records' forecast errors on the planned
    paths and their median planning times (when recorded)."""
    a = {s["seed"]: s for s in reference["seeds"]}
    b = {s["seed"]: s for s in candidate["seeds"]}
    seeds = sorted(set(a) & set(b))
    if len(seeds) < 2:
        raise ValueError(f"the records share {len(seeds)} seeds; two or more are needed")
    ra = np.array([a[k]["planned"] for k in seeds])
    rb = np.array([b[k]["planned"] for k in seeds])
    d = rb - ra
    se = d.std(ddof=1) / np.sqrt(len(d))
    off = [np.mean([r[k]["planned_off"] for k in seeds]) for r in (a, b)]
    secs = [[r[k]["seconds"] for k in seeds if "seconds" in r[k]] for r in (a, b)]
    timing = (
        f"; planning {np.median(secs[1]):.1f} s a seed against {np.median(secs[0]):.1f} s (medians)"
        if all(secs)
        else ""
    )
    return (
        f"over {len(seeds)} paired seeds: {rb.mean():.3f} m against {ra.mean():.3f} m, difference "
        f"{d.mean():+.4f} m (paired s.e. {se:.4f} m, {abs(d.mean()) / se if se > 0 else float('inf'):.1f} s.e.), "
        f"closer on {int((d < 0).sum())} of {len(seeds)}; planned-path forecast off by "
        f"{off[1]:.3f} m against {off[0]:.3f} m{timing}"
    )


def write_record(path: str, doc: dict) -> None:
    """Writes ``doc`` to ``path`` through a temporary file and a rename, so that a run stopped
    part-way leaves the seeds done so far, never a torn file."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=1)
        f.write("\n")
    os.replace(tmp, path)


def plan(client: Any, args: argparse.Namespace, seed: int, dt_frame: float, binary: Optional[str]):
    """Plans one push (scene and sampling from ``seed``) and prints the distances; returns the
    rapier-replayed final distances ``(planned, random)`` and how far the model's final box
    position was from rapier's on each path ``(planned_off, random_off)``, in m, or ``None``
    without a binary."""
    rng = np.random.default_rng(seed)
    goal = np.array(args.goal)
    bodies = scene(seed)
    session = client.create_session(bodies, kinematic=[PUSHER], model=args.model)
    # Gradients from another model (an ensemble computes none): a session of its own, driven
    # along the same executed path.
    differentiated = session
    if args.refine > 0 and args.grad_model and args.grad_model != args.model:
        differentiated = client.create_session(bodies, kinematic=[PUSHER], model=args.grad_model)
    baseline = session.fork()
    start = session.state()["poses"]
    d0 = float(np.linalg.norm(start[BOX, :2] - goal))

    t0 = time.time()
    calls, sent, gradient_calls = 0, 0, 0
    mean = np.zeros((args.horizon, 2))
    std = np.full((args.horizon, 2), args.speed / 2)
    executed = []
    for _ in range(args.rounds):
        here = session.state()["poses"]
        refined = np.zeros((0, args.horizon, 2))
        for iteration in range(args.iterations):
            v = np.clip(mean + std * rng.standard_normal((args.samples, args.horizon, 2)), -args.speed, args.speed)
            # The paths refined by the gradient last iteration take the place of samples.
            v[: len(refined)] = refined
            paths = [path_from(here[PUSHER, :2], v[i], dt_frame) for i in range(args.samples)]
            candidates = [{PUSHER: p} for p in paths]
            if args.risk_weight > 0:
                traj, spread = session.predict(args.horizon, kinematic=candidates, with_spread=True)
            else:
                traj, spread = session.predict(args.horizon, kinematic=candidates), None
            calls += 1
            sent += client.last_request_bytes
            cost = np.linalg.norm(traj[:, -1, BOX, :2] - goal, axis=1)
            if args.side_weight > 0:
                cost += args.side_weight * side_cost(traj, np.array(paths), goal)
            if args.risk_weight > 0:
                if spread is None:
                    raise SystemExit("--risk-weight needs a model that reports a spread (an ensemble)")
                cost += args.risk_weight * risk(spread)
            order = np.argsort(cost)
            elite = v[order[: max(2, args.samples // 8)]]
            mean, std = elite.mean(axis=0), elite.std(axis=0) + 0.05
            if args.refine > 0 and iteration + 1 < args.iterations:
                refined = refine(differentiated, here, v[order[: args.refine]], goal, args, dt_frame)
                gradient_calls += 1
        best = path_from(here[PUSHER, :2], mean, dt_frame)
        session.step(args.execute, kinematic={PUSHER: best[: args.execute]})
        if differentiated is not session:
            differentiated.step(args.execute, kinematic={PUSHER: best[: args.execute]})
        executed.append(best[: args.execute])
        # Warm start: shift the plan by the executed steps.
        mean = np.concatenate([mean[args.execute :], np.zeros((args.execute, 2))])
        std = np.full((args.horizon, 2), args.speed / 2)
    planning_seconds = time.time() - t0
    model_end = session.state()["poses"][BOX, :2]
    planned = float(np.linalg.norm(model_end - goal))

    steps = args.rounds * args.execute
    v = rng.uniform(-args.speed, args.speed, size=(steps, 2))
    random_path = path_from(start[PUSHER, :2], v, dt_frame)
    baseline.step(steps, kinematic={PUSHER: random_path})
    random_end = baseline.state()["poses"][BOX, :2]
    random_d = float(np.linalg.norm(random_end - goal))
    session.delete()
    baseline.delete()
    if differentiated is not session:
        differentiated.delete()

    print(f"seed {seed}: goal {goal.tolist()} m; box starts {d0:.3f} m away")
    print(
        f"planner: {calls} Predict calls of {args.samples} paths x {args.horizon} steps "
        f"({sent / max(calls, 1) / 1024:.1f} KiB each), {gradient_calls} Gradient calls of "
        f"{args.refine} paths, {time.time() - t0:.1f} s"
    )
    print(f"final distance to the goal (learned model): planned {planned:.3f} m, random plan {random_d:.3f} m")
    if binary is None:
        print("rapier replay skipped: no dynaserve binary (build it or give --dynaserve)")
        return None
    truth = [replay(binary, bodies, p, dt_frame)[-1, BOX, :2] for p in (np.concatenate(executed), random_path)]
    rapier = [float(np.linalg.norm(t - goal)) for t in truth]
    off = [float(np.linalg.norm(t - m)) for t, m in zip(truth, (model_end, random_end))]
    print(f"final distance to the goal (rapier replay): planned {rapier[0]:.3f} m, random plan {rapier[1]:.3f} m")
    print(f"the model's final box position against rapier's: planned {off[0]:.3f} m off, random plan {off[1]:.3f} m off")
    return rapier[0], rapier[1], off[0], off[1], planning_seconds


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--server", default="http://127.0.0.1:8080", help="the server's HTTP address")
    ap.add_argument("--grpc", help="plan over gRPC at this host:port instead (needs the grpc extra)")
    ap.add_argument("--goal", type=float, nargs=2, default=[0.35, 0.15], help="goal of the box, m")
    ap.add_argument("--rounds", type=int, default=8, help="planning rounds")
    ap.add_argument("--horizon", type=int, default=10, help="steps looked ahead")
    ap.add_argument("--execute", type=int, default=4, help="steps executed per round")
    ap.add_argument("--samples", type=int, default=48, help="candidate paths per call")
    ap.add_argument("--iterations", type=int, default=2, help="CEM iterations per round")
    ap.add_argument("--speed", type=float, default=0.8, help="largest pusher speed, m/s")
    ap.add_argument(
        "--side-weight",
        "--approach-weight",
        dest="side_weight",
        type=float,
        default=0.5,
        help="weight of the pusher's distance to the box's pushing side in the cost (0: goal distance "
        "only; --approach-weight is its former name)",
    )
    ap.add_argument(
        "--risk-weight",
        type=float,
        default=0.0,
        help="weight of the model's uncertainty about the box's final position in the cost (m per m; "
        "needs a model that reports a spread, an ensemble; 0: none)",
    )
    ap.add_argument(
        "--refine",
        type=int,
        default=0,
        help="per round, move this many of the best paths down the gradient of the box's final distance "
        "to the goal (one Gradient call) and try them in the next iteration (needs --iterations >= 2 "
        "and a model that computes gradients; 0: none)",
    )
    ap.add_argument(
        "--grad-model",
        help="the model the gradients are asked of (default: the one planned with); with an ensemble, "
        "one of its members, stepped along the same executed path in a session of its own",
    )
    ap.add_argument(
        "--refine-step",
        type=float,
        default=0.1,
        help="how far a refined path moves down the gradient, m/s in root-mean-square over its steps",
    )
    ap.add_argument(
        "--model",
        help="the model to plan with (default: the one RigidFormer); `rapier` plans in the simulator "
        "itself, the ceiling a perfect forecast would reach",
    )
    ap.add_argument("--seed", type=int, default=0, help="the scene's and the sampler's seed")
    ap.add_argument(
        "--seeds",
        help="plan once per seed (\"0-199\", \"1,4,9-11\") and end with a summary over them; overrides --seed",
    )
    ap.add_argument("--dynaserve", help="dynaserve binary for the rapier replay (default: found)")
    ap.add_argument(
        "--json",
        metavar="FILE",
        help="write every seed's rapier-replayed distances (and the model and settings) to FILE, "
        "rewritten after each seed; needs the rapier replay",
    )
    ap.add_argument(
        "--compare",
        nargs=2,
        metavar=("REFERENCE", "CANDIDATE"),
        help="compare two records written by --json seed by seed and exit (no server needed)",
    )
    args = ap.parse_args()
    if args.compare:
        with open(args.compare[0]) as f, open(args.compare[1]) as g:
            print(paired(json.load(f), json.load(g)))
        return
    try:
        seeds = parse_seeds(args.seeds) if args.seeds is not None else [args.seed]
    except ValueError as e:
        ap.error(f"--seeds: {e}")
    binary = find_dynaserve(args.dynaserve)
    if args.json and binary is None:
        ap.error("--json records rapier-replayed distances: build dynaserve or give --dynaserve")
    client: Any
    if args.grpc:
        from dynaserve.grpc import GrpcClient

        client = GrpcClient(args.grpc)
    else:
        client = Client(args.server)
    # The session's model: the one named, else the one RigidFormer (others may be resident).
    models = client.list_models()
    wanted = [m for m in models if (m["name"] == args.model if args.model else m["architecture"] == "rigidformer")]
    if len(wanted) != 1:
        ap.error(f"--model: name one of {[m['name'] for m in models]}")
    model = wanted[0]
    args.model = model["name"]
    dt_frame = model["dt_frame"]
    results = []
    for seed in seeds:
        distances = plan(client, args, seed, dt_frame, binary)
        if distances is not None:
            results.append((seed, distances))
            if args.json:
                write_record(args.json, record(model, args, results))
    if len(seeds) > 1 and results:
        print(summary([d for _, d in results]))


if __name__ == "__main__":
    main()
