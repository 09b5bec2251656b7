"""RigidFormer-small in PyTorch with random weights, timed on the CPU next to our candle step.

The network has the same layers and tensor shapes as `crates/model` (encoder with two
set-abstraction levels, 6 decoder blocks with gated attention, ARoPE and FiLM, the anchor head
with AVP pooling and multi-depth cross-attention) on MOVi-like batches of 10 objects x 512
points and on the 217-object wrecking ball (216 cubes of 128 points and a ball of 512). Inputs
are random tensors of the right shapes: contact features, grouping and anchors are computed
by our step but not here, so the comparison favours PyTorch by our features phase (printed).

Run (in a virtualenv outside the repository; PyPI's Linux wheel carries the CUDA libraries
and runs on the CPU, the smaller CPU-only wheel is on https://download.pytorch.org/whl/cpu):

    python3 -m venv /tmp/torchenv && /tmp/torchenv/bin/pip install torch
    /tmp/torchenv/bin/python crates/model/benches/torch_reference.py --threads 2

It times eager mode and `torch.compile`, then runs our criterion bench for the same cases
(`cargo bench -p dynaserve-model --bench step`, or parses a saved output with `--ours FILE`)
and prints our time over PyTorch's for each case.
"""

import argparse
import math
import re
import statistics
import subprocess
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

# The small configuration (crates/model/src/config.rs, ModelConfig::small).
C1, S, G, C2, D, H, L, R, FFN, FILM, ROPE, K, TAPS = 32, 32, 8, 64, 128, 4, 6, 8, 512, 32, 24, 8, [1, 3, 5]
P = ROPE // 2


def rms_norm(x, w, eps=1e-6):
    return x * torch.rsqrt(x.pow(2).mean(-1, keepdim=True) + eps) * w


def rotate(x, cos, sin):
    """Rotates channel pairs (2i, 2i+1), i < P, of x [B, H, T, dh] by cos/sin [B, 1, T, P]."""
    e, o = x[..., 0 : 2 * P : 2], x[..., 1 : 2 * P : 2]
    rot = torch.stack([e * cos - o * sin, e * sin + o * cos], -1).flatten(-2)
    return torch.cat([rot, x[..., 2 * P :]], -1)


def attention(q, k, v, mask, qr, kr):
    b, tq, _ = q.shape
    tk = k.shape[1]
    dh = D // H
    q = rotate(q.view(b, tq, H, dh).transpose(1, 2), *qr)
    k = rotate(k.view(b, tk, H, dh).transpose(1, 2), *kr)
    v = v.view(b, tk, H, dh).transpose(1, 2)
    att = torch.softmax(q @ k.transpose(-1, -2) / math.sqrt(dh) + mask, -1)
    return att @ v  # [B, H, Tq, dh]


class Mlp(nn.Module):
    def __init__(self, i, h, o):
        super().__init__()
        self.a, self.b = nn.Linear(i, h), nn.Linear(h, o)

    def forward(self, x):
        return self.b(F.silu(self.a(x)))


class Block(nn.Module):
    def __init__(self):
        super().__init__()
        self.n1, self.n2 = nn.Parameter(torch.ones(D)), nn.Parameter(torch.ones(D))
        self.qkv = nn.Linear(D, 3 * D, bias=False)
        self.gate = nn.Linear(D, H)
        self.out = nn.Linear(D, D, bias=False)
        self.film = Mlp(1, FILM, 2 * D)
        self.up = nn.Linear(D, 2 * FFN, bias=False)
        self.down = nn.Linear(FFN, D, bias=False)

    def forward(self, x, mask, rope, tau):
        b, t, _ = x.shape
        xn = rms_norm(x, self.n1)
        q, k, v = self.qkv(xn).split(D, -1)
        o = attention(q, k, v, mask, rope, rope)
        gate = torch.sigmoid(self.gate(xn)).transpose(1, 2).unsqueeze(3)
        x = x + self.out((o * gate).transpose(1, 2).reshape(b, t, D))
        gb = self.film(tau)
        x = x * (1 + gb[:, :D]).unsqueeze(1) + gb[:, D:].unsqueeze(1)
        u = self.up(rms_norm(x, self.n2))
        return x + self.down(F.silu(u[..., :FFN]) * u[..., FFN:])


class RigidFormer(nn.Module):
    def __init__(self):
        super().__init__()
        self.point, self.sa1, self.sa2 = Mlp(12, C1, C1), Mlp(C1 + 3, C2, C2), Mlp(C2 + 3, D, D)
        self.token = nn.Linear(D, D)
        self.registers = nn.Parameter(torch.rand(R, D) - 0.5)
        self.blocks = nn.ModuleList(Block() for _ in range(L))
        self.query_in = nn.Linear(C1 + 3 + C1 + ROPE, D)
        self.own_token = nn.Linear(D, D, bias=False)
        self.norms = nn.Parameter(torch.ones(4 + len(TAPS), D))
        self.depth = nn.Parameter(torch.rand(len(TAPS), D) * 0.2 - 0.1)
        self.log_sigma = nn.Parameter(torch.tensor(math.log(0.2)))
        self.q, self.kv = nn.Linear(D, D, bias=False), nn.Linear(D, 2 * D, bias=False)
        self.out = nn.Linear(D, D, bias=False)
        self.head = Mlp(D, D, 3)

    def forward(self, x):
        b, m = x["b"], x["m"]
        o, n = b * m, x["feats"].shape[1]
        t = m + R
        h = self.point(x["feats"])  # [O, N, C1]
        flat = h.reshape(o * n, C1)
        grouped = flat[x["group_idx"]]  # [O*S*G, C1]
        y = self.sa1(torch.cat([x["group_rel"], grouped], -1)).view(o * S, G, C2).amax(1)
        y = self.sa2(torch.cat([x["centre_rel"], y], -1)).view(o, S, D).amax(1)
        tokens = self.token(F.silu(y)).view(b, m, D)
        z = torch.cat([tokens, self.registers.expand(b, R, D)], 1)
        taps = []
        for i, blk in enumerate(self.blocks):
            z = blk(z, x["mask"], x["rope"], x["tau"])
            if i in TAPS:
                taps.append(z)
        # Anchor head.
        w = torch.exp(-x["avp_d2"] * torch.exp(-2 * self.log_sigma))  # [O, K, N]
        avp = (w @ h) / w.sum(-1, keepdim=True)
        own = flat[x["anchor_idx"]].view(o, K, C1)
        q_in = torch.cat([own, x["anchor_rel"], avp, x["anchor_rope"]], -1)
        own_tok = self.own_token(rms_norm(z[:, :m].reshape(o, D), self.norms[0]))
        query = (self.query_in(q_in) + own_tok.unsqueeze(1)).view(b, m * K, D)
        kv_in = torch.cat([rms_norm(tp, self.norms[4 + i]) + self.depth[i] for i, tp in enumerate(taps)], 1)
        kk, vv = self.kv(kv_in).split(D, -1)
        nt = len(TAPS)
        kmask = x["mask"].repeat(1, 1, 1, nt)
        krope = tuple(c.repeat(1, 1, nt, 1) for c in x["rope"])
        att = attention(self.q(rms_norm(query, self.norms[1])), kk, vv, kmask, x["qrope"], krope)
        yq = query + self.out(att.transpose(1, 2).reshape(b, m * K, D))
        return self.head(rms_norm(yq, self.norms[2]))


def inputs(b, m, n):
    o, t = b * m, m + R
    ang = torch.rand(b, 1, t, P) * 6
    qang = torch.rand(b, 1, m * K, P) * 6
    return {
        "b": b,
        "m": m,
        "feats": torch.randn(o, n, 12),
        "group_idx": torch.randint(0, o * n, (o * S * G,)),
        "group_rel": torch.randn(o * S * G, 3),
        "centre_rel": torch.randn(o * S, 3),
        "mask": torch.zeros(b, 1, 1, t),
        "rope": (ang.cos(), ang.sin()),
        "qrope": (qang.cos(), qang.sin()),
        "tau": torch.zeros(b, 1),
        "avp_d2": torch.rand(o, K, n),
        "anchor_idx": torch.randint(0, o * n, (o * K,)),
        "anchor_rel": torch.randn(o, K, 3),
        "anchor_rope": torch.randn(o, K, ROPE),
    }


def median_ms(f, x, runs):
    with torch.inference_mode():
        for _ in range(3):
            f(x)
        times = []
        for _ in range(runs):
            t0 = time.perf_counter()
            f(x)
            times.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(times)


# Our criterion cases: (label, batch, objects per scene, points per object, criterion id).
CASES = [
    ("10x512 batch 1", 1, 10, 512, "step_small_10x512/batch_1"),
    ("10x512 batch 8", 8, 10, 512, "step_small_10x512/batch_8"),
    ("10x512 batch 32", 32, 10, 512, "step_small_10x512/batch_32"),
    # The wrecking ball pads every object to the ball's 512 points, as our encoder input does.
    ("wrecking ball", 1, 217, 512, "wrecking_ball/216_cubes_128pts_small"),
]


def ours(path):
    """Criterion median (ms) per bench id, from a saved output or a fresh run."""
    if path:
        text = open(path).read()
    else:
        filt = "step_small_10x512/batch_(1|8|32)$|216_cubes_128pts_small"
        text = subprocess.run(
            ["cargo", "bench", "-p", "dynaserve-model", "--bench", "step", "--", filt],
            capture_output=True, text=True, check=True,
        ).stdout
    unit = {"ns": 1e-6, "µs": 1e-3, "us": 1e-3, "ms": 1.0, "s": 1e3}
    found = {}
    for m in re.finditer(r"^(\S+)\s*\n?\s*time:\s+\[\S+ \S+ (\S+) (\S+)", text, re.M):
        found[m.group(1)] = float(m.group(2)) * unit[m.group(3)]
    return found


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--runs", type=int, default=15)
    ap.add_argument("--no-compile", action="store_true")
    ap.add_argument("--ours", help="saved output of the criterion step bench instead of running it")
    ap.add_argument("--skip-ours", action="store_true")
    a = ap.parse_args()
    torch.set_num_threads(a.threads)
    torch.manual_seed(0)
    model = RigidFormer().eval()
    compiled = None if a.no_compile else torch.compile(model)
    print(f"torch {torch.__version__}, {a.threads} threads, medians of {a.runs} runs")
    rows = []
    for label, b, m, n, key in CASES:
        x = inputs(b, m, n)
        eager = median_ms(model, x, a.runs)
        comp = median_ms(compiled, x, a.runs) if compiled is not None else float("nan")
        print(f"{label}: eager {eager:.2f} ms ({eager / b:.2f} per scene), compiled {comp:.2f} ms ({comp / b:.2f} per scene)")
        rows.append((label, b, key, eager, comp))
    if a.skip_ours:
        return
    mine = ours(a.ours)
    print("ours / torch (per pass; ours includes contact features):")
    for label, b, key, eager, comp in rows:
        if key in mine:
            t = mine[key]
            print(f"  {label}: ours {t:.2f} ms ({t / b:.2f} per scene) = {t / eager:.2f}x eager, {t / comp:.2f}x compiled")


if __name__ == "__main__":
    main()
