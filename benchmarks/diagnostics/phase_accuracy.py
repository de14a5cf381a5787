"""Issue 37: does a policy imitate the exploitation phase as well as the search? Held-out action accuracy by phase.

On held-out steps of a collection with the exploitation labels (``goal_in_view``, ``goal_distance``), each
checkpoint's greedy action is compared with the expert's label, split by whether the goal is in view (the exploring
expert's switch test: from there it follows the geodesic path) and by the distance to the goal. A policy that
imitates the last metres well offline but loses the goal in closed loop suffers covariate shift (states the expert
never visits); one that imitates them poorly offline has not learned the phase at all.

    python benchmarks/diagnostics/phase_accuracy.py -c nue=checkpoints/nue.pt \
        -c nue_match=results/candidates/nue_match_s0.pt --data data/demos_v8 \
        --out results/diagnostics/phase_accuracy.json
    # a recurrent model (nue_gru) needs its episodes in order, its state carried: --episodes scores every held-out step
    python benchmarks/diagnostics/phase_accuracy.py --episodes -c nue_lean=results/lean/nue_lean.pt \
        -c nue_gru_lean=runs/nue_gru_lean_s0/best.pt --data data/demos_v9_lean --out results/gru/phase_accuracy.json
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


def _steps_of_every_episode(held: DemoSet, chunk: int = 200):
    """(episode, steps) chunks of every held-out episode in order, so a recurrent model carries its state."""
    for e in range(held.n_episodes):
        n = int(held.lengths[e])
        for t0 in range(0, n, chunk):
            yield e, np.arange(t0, min(n, t0 + chunk))


def score(checkpoint: str, held: DemoSet, ep: np.ndarray | None, st: np.ndarray | None) -> dict:
    """Greedy-action accuracy on the held-out steps by phase. ``ep`` / ``st``: sampled steps, each scored alone (a
    reactive model); None: every held-out episode from its first step in order, the recurrent state carried (what
    a recurrent model needs, and the same numbers for a reactive one up to the sample)."""
    model, header = load_policy(checkpoint)
    model.eval()
    # the labels ride on a goal-head config's batches; the model reads only its own inputs
    cfg = header.model
    label_cfg = cfg if cfg.goal_head else cfg.replace(goal_head=True)
    hit, view, dist, label = [], [], [], []

    def keep(logits, b):
        hit.append((logits.argmax(dim=-1) == b.action).reshape(-1).numpy())
        view.append(b.goal_in_view.reshape(-1).numpy() > 0.5)
        dist.append(b.goal_distance.reshape(-1).numpy())
        label.append(b.action.reshape(-1).numpy())

    with torch.no_grad():
        if ep is not None and st is not None:
            for i in range(0, len(ep), 256):
                b = held.batch(ep[i:i + 256], st[i:i + 256], label_cfg)
                keep(model(b.inp).logits, b)
        else:
            state = None
            for e, steps in _steps_of_every_episode(held):
                b = held.batch(np.full((len(steps), 1), e), steps[:, None], label_cfg)
                reset = torch.zeros((len(steps), 1), dtype=torch.bool)
                reset[0, 0] = bool(steps[0] == 0)
                out = model.forward_sequence(b.inp, state, reset)
                state = out.state
                keep(out.logits, b)
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
    ap.add_argument("--episodes", action="store_true", help="every held-out step, episode by episode in order with "
                    "the recurrent state carried (needed for recurrent models such as nue_gru)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    held = DemoSet(args.data, "heldout")
    if args.episodes:
        ep = st = None
        out = {"data": args.data, "heldout_steps": int(sum(held.lengths)), "episodes_in_order": True}
    else:
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
