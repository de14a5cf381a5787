"""Issue 37: does a policy imitate the exploitation phase as well as the search? Held-out action accuracy by phase.

On held-out steps of a collection with the exploitation labels (``goal_in_view``, ``goal_distance``), each
checkpoint's greedy action is compared with the expert's label, split by whether the goal is in view (the exploring
expert's switch test: from there it follows the geodesic path) and by the distance to the goal. A policy that
imitates the last metres well offline but loses the goal in closed loop suffers covariate shift (states the expert
never visits); one that imitates them poorly offline has not learned the phase at all.

    python benchmarks/diagnostics/phase_accuracy.py -c nue=checkpoints/nue.pt \
        -c nue_match=results/candidates/nue_match_s0.pt --data data/demos_v8 \
        --out results/diagnostics/phase_accuracy.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from nue.policy.checkpoint import load_policy
from nue.train.dataset import DemoSet

DISTANCE_BINS = ((0.0, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 1e9))
"""Straight-line distance to the goal (metres) of the split."""


def score(checkpoint: str, held: DemoSet, ep: np.ndarray, st: np.ndarray) -> dict:
    model, header = load_policy(checkpoint)
    model.eval()
    # the labels ride on a goal-head config's batches; the model reads only its own inputs
    cfg = header.model
    label_cfg = cfg if cfg.goal_head else cfg.replace(goal_head=True)
    hit, view, dist, label = [], [], [], []
    with torch.no_grad():
        for i in range(0, len(ep), 256):
            b = held.batch(ep[i:i + 256], st[i:i + 256], label_cfg)
            out = model(b.inp)
            hit.append((out.logits.argmax(dim=-1) == b.action).numpy())
            view.append(b.goal_in_view.numpy() > 0.5)
            dist.append(b.goal_distance.numpy())
            label.append(b.action.numpy())
    h, v, d, a = (np.concatenate(x) for x in (hit, view, dist, label))
    res: dict = {"checkpoint": checkpoint, "steps": int(len(h)), "accuracy": round(float(h.mean()), 4),
                 "in_view": {"steps": int(v.sum()), "accuracy": round(float(h[v].mean()), 4)},
                 "not_in_view": {"steps": int((~v).sum()), "accuracy": round(float(h[~v].mean()), 4)}}
    for lo, hi in DISTANCE_BINS:
        m = (d >= lo) & (d < hi)
        key = f"distance_{lo:g}-{hi:g}m" if hi < 1e8 else f"distance_over_{lo:g}m"
        res[key] = {"steps": int(m.sum()), "accuracy": round(float(h[m].mean()), 4) if m.any() else None,
                    "in_view_accuracy": round(float(h[m & v].mean()), 4) if (m & v).any() else None}
    res["in_view_label_share"] = {str(k): round(float((a[v] == k).mean()), 4) for k in np.unique(a)}
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-c", "--checkpoint", action="append", required=True, help="name=path, repeatable")
    ap.add_argument("--data", default="data/demos_v8")
    ap.add_argument("--out", default="results/diagnostics/phase_accuracy.json")
    ap.add_argument("--heldout-steps", type=int, default=6000)
    args = ap.parse_args()
    torch.set_num_threads(1)
    held = DemoSet(args.data, "heldout")
    ep, st = held.sample_steps(args.heldout_steps, 1)
    out = {"data": args.data, "heldout_steps": int(len(ep))}
    for spec in args.checkpoint:
        name, _, path = spec.partition("=")
        out[name] = score(path or name, held, ep, st)
        print(json.dumps({name: out[name]}, indent=1), flush=True)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
