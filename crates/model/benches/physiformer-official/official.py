#!/usr/bin/env python3
"""The official PhysiFormer code's side of the published-size benchmark (run.sh beside this).

  official.py make OFFICIAL_CHECKOUT OUT_DIR
      writes OUT_DIR/checkpoint-b.pt (the official B configuration with the published demo's
      conditioning: 16 registers, scene tokens, (softness, friction) materials, 10 object
      slots; every parameter randomised, seeded) and OUT_DIR/scene.json (a 10-object,
      356-vertex scene of 49 frames, positions in metres, velocities in m/s).
  official.py time OFFICIAL_CHECKOUT OUT_DIR WHAT AMP THREADS
      times the official code on that scene: WHAT is `call` (one denoiser call, repeated) or
      `sample:STEPS` (one whole Heun sample); AMP `none` (float32) or `bf16` (the official
      inference's default autocast). Prints one JSON line: seconds per repetition and the
      process's peak resident memory.

Nothing of the official code is copied; it is imported from OFFICIAL_CHECKOUT/src.
"""

from __future__ import annotations

import json
import os
import resource
import sys
import time

import numpy as np
import torch

FRAMES = 49
COUNTS = [86, 36, 36, 32, 30, 30, 30, 24, 24, 28]
SCENE_TOKENS = 4
MAX_OBJECTS = 10
CALL_REPEATS = 3


def build(root: str):
    sys.path.insert(0, os.path.join(root, "src"))
    from physiformer.diffusion.denoiser import DiffusionConfig
    from physiformer.diffusion.physiformer_denoiser import PhysiFormerDenoiser

    return PhysiFormerDenoiser(
        model_name="PhysiFormer-B",
        num_frames=FRAMES,
        num_vertices=sum(COUNTS),
        num_classes=1,
        model_kwargs={
            "max_num_objects": MAX_OBJECTS,
            "num_scene_tokens": SCENE_TOKENS,
            "scene_cond_dim": 9,
            "scene_cond_embed_out_tokens": SCENE_TOKENS,
            "object_material_dim": 2,
            "max_vertices": 8192,
        },
        diffusion=DiffusionConfig(),
    )


def scene() -> dict:
    rng = np.random.default_rng(7)
    pos, vel = [], []
    for o, n in enumerate(COUNTS):
        centre = np.array([-0.7 + 0.15 * o, 0.3 * np.sin(o), -0.5 + 0.1 * o])
        pos.append(centre + 0.08 * rng.standard_normal((n, 3)))
        vel.append(np.tile(rng.uniform(-1, 1, 3), (n, 1)))
    return {
        "counts": COUNTS,
        "frames": FRAMES,
        "positions": np.concatenate(pos).astype(np.float32).tolist(),
        "velocities": np.concatenate(vel).astype(np.float32).tolist(),
        "kinds": ["rigid"] * 5 + ["elastic"] * 5,
    }


def make(root: str, out: str) -> None:
    torch.manual_seed(0)
    model = build(root)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if name.endswith("object_id_embed.weight"):
                continue
            if p.ndim == 1 and "norm" in name:
                p.copy_(1.0 + 0.1 * torch.randn_like(p))
            else:
                p.add_(0.02 * torch.randn_like(p))
    args = {
        "model": "PhysiFormer-B",
        "num_frames": FRAMES,
        "num_vertices": sum(COUNTS),
        "max_num_objects": MAX_OBJECTS,
        "num_register_tokens": 16,
        "num_scene_tokens": SCENE_TOKENS,
        "noise_scale": 0.1,
        "num_sampling_steps": 50,
    }
    os.makedirs(out, exist_ok=True)
    torch.save({"model": model.state_dict(), "args": args}, os.path.join(out, "checkpoint-b.pt"))
    with open(os.path.join(out, "scene.json"), "w", encoding="utf-8") as f:
        json.dump(scene(), f)
    n = sum(p.numel() for p in model.parameters())
    print(f"wrote {out}: PhysiFormer-B, {n / 1e6:.1f} M parameters")


def inputs(sc: dict):
    v = sum(sc["counts"])
    pos = torch.tensor(sc["positions"]).reshape(1, v, 3)
    vel = torch.tensor(sc["velocities"]).reshape(1, v, 3)
    cond = torch.cat([pos, vel], dim=-1)
    ids = torch.cat([torch.full((n,), i) for i, n in enumerate(sc["counts"])])[None]
    scene_cond = torch.tensor([[0.0, 0.0, 0.0, 2.0, 2.0, 2.0, -9.81, 0.0, 1.0]])
    mats = torch.zeros(1, MAX_OBJECTS + 1, 2)
    for i, k in enumerate(sc["kinds"]):
        mats[0, i] = torch.tensor([0.0, 0.01] if k == "rigid" else [1.0, 0.15])
    return v, cond, ids, scene_cond, mats


def timed(root: str, out: str, what: str, amp: str, threads: int) -> None:
    torch.set_num_threads(threads)
    torch.set_grad_enabled(False)
    model = build(root)
    state = torch.load(os.path.join(out, "checkpoint-b.pt"), map_location="cpu", weights_only=False)
    model.load_state_dict(state["model"])
    model.eval()
    with open(os.path.join(out, "scene.json"), encoding="utf-8") as f:
        sc = json.load(f)
    v, cond, ids, scene_cond, mats = inputs(sc)
    labels = torch.zeros(1, dtype=torch.long)
    mask = torch.ones(1, FRAMES, v)
    ctx = torch.autocast("cpu", dtype=torch.bfloat16, enabled=amp == "bf16")
    seconds = []
    with ctx:
        if what == "call":
            z = 0.1 * torch.randn(1, FRAMES, v, 3)
            t = torch.full((1,), 0.5)
            for _ in range(CALL_REPEATS):
                t0 = time.perf_counter()
                model.net(z, t, labels, cond=cond, mask=mask, object_ids=ids, scene_cond=scene_cond, object_materials=mats)
                seconds.append(time.perf_counter() - t0)
        else:
            model.diff = type(model.diff)(num_sampling_steps=int(what.split(":")[1]))
            t0 = time.perf_counter()
            model.generate(
                labels,
                num_frames=FRAMES,
                num_vertices=v,
                cond_first_frame=cond,
                mask=mask,
                object_ids=ids,
                scene_cond=scene_cond,
                object_materials=mats,
            )
            seconds.append(time.perf_counter() - t0)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    print(json.dumps({"impl": "official", "what": what, "amp": amp, "threads": threads, "seconds": seconds, "peak_rss_mib": round(peak)}))


def main() -> None:
    if len(sys.argv) >= 4 and sys.argv[1] == "make":
        make(sys.argv[2], sys.argv[3])
    elif len(sys.argv) == 7 and sys.argv[1] == "time":
        timed(sys.argv[2], sys.argv[3], sys.argv[4], sys.argv[5], int(sys.argv[6]))
    else:
        sys.exit(__doc__)


if __name__ == "__main__":
    main()
