"""Where a model's one-step error at contacts lies, measured against rapier restarted from the
same two frames. Reads the window CSV of a suite run that scored the model, ballistic and the
restart together (standard library only):

    dynaserve eval --model models/rigidformer-small --rapier --suite physics \
        --data data/movi-b/test --max-scenes 60 --step-sizes 1 --windows windows.csv
    python3 crates/sim/python/restart_bins.py windows.csv

For the floor- and object-contact windows at k = 1, bins them by the restart's own error (how
well the two frames and the exact physics determine the step) and prints per bin the windows,
the three centre RMSEs (m) and the bin's share of the model's squared error.
"""

import collections
import csv
import math
import sys

BINS = [(0.0, 0.002), (0.002, 0.01), (0.01, 0.03), (0.03, math.inf)]
PREDICTORS = ("model", "rapier-restart", "ballistic")


def err(window, predictor):
    """The centre error (m) of `predictor` in one window."""
    return float(window[predictor]["translation_m"])


def main(path):
    windows = collections.defaultdict(dict)
    with open(path, newline="") as f:
        for r in csv.DictReader(f):
            if r["k"] == "1":
                windows[(r["scene"], r["object"], r["t"])][r["predictor"]] = r
    for regime in ("object contact", "floor contact"):
        sel = [
            w
            for w in windows.values()
            if all(p in w for p in PREDICTORS) and w["model"]["regime"] == regime
        ]
        if not sel:
            print(f"{regime}: no windows with all of {', '.join(PREDICTORS)}")
            continue
        total = sum(err(w, "model") ** 2 for w in sel)
        print(f"\n{regime}, k = 1: {len(sel)} windows")
        print("| restart error, m | windows | model | rapier restart | ballistic | share of the model's squared error |")
        print("| --- | --- | --- | --- | --- | --- |")
        for lo, hi in BINS:
            b = [w for w in sel if lo <= err(w, "rapier-restart") < hi]
            if not b:
                continue
            rmse = {p: math.sqrt(sum(err(w, p) ** 2 for w in b) / len(b)) for p in PREDICTORS}
            share = sum(err(w, "model") ** 2 for w in b) / total
            top = "" if math.isinf(hi) else f"{hi}"
            print(
                f"| [{lo}, {top or 'inf'}) | {len(b)} | {rmse['model']:.4f} | "
                f"{rmse['rapier-restart']:.4f} | {rmse['ballistic']:.4f} | {share:.2f} |"
            )


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    main(sys.argv[1])
