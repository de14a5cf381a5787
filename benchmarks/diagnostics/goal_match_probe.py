"""Issue 37, exploitation signal: does goal-view *matching* tell that the goal is in view, where NUE's features do not?

The goal-head probe (``goal_head_probe.py``) found that neither a frozen trained NUE's f_cog nor all its branch
vectors, nor a NUE trained end to end with the head, separate the steps with the goal in view (the exploring
expert's switch test) from the others well (held-out AUROC 0.55-0.66). This probe scores two matchers on the same
held-out steps of a collection (frames and goal photos as stored, 90 x 120):

- ``sift``: mutual ratio-test SIFT matches between the current RGB frame and the goal photo (OpenCV; the count is
  the score), no learning;
- ``siamese``: NUE's goal-view matching branch (:class:`nue.policy.goal_match.GoalMatch`: a shared CNN, best
  cosine match of every goal cell in the frame and back) and a linear layer to the in-view logit, trained alone with
  class-balanced BCE on the collection's training part.

    python benchmarks/diagnostics/goal_match_probe.py --data data/demos_v8 --out results/diagnostics/goal_match_probe.json
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import cv2
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from nue.policy.accuracy import auroc
from nue.policy.config import get_model_config
from nue.policy.goal_match import GoalMatch
from nue.train.dataset import BufferSampler, DemoSet


def to_u8(x: torch.Tensor) -> np.ndarray:
    """(3, h, w) float in [0, 1] -> (h, w, 3) uint8."""
    return np.ascontiguousarray((x.clamp(0, 1).permute(1, 2, 0).numpy() * 255).round().astype(np.uint8))


def sift_scores(data: DemoSet, ep: np.ndarray, st: np.ndarray, cfg) -> tuple[np.ndarray, np.ndarray]:
    sift = cv2.SIFT_create()
    bf = cv2.BFMatcher(cv2.NORM_L2)
    goal_cache: dict[int, np.ndarray | None] = {}
    scores, labels = [], []
    for i in range(0, len(ep), 256):
        b = data.batch(ep[i:i + 256], st[i:i + 256], cfg)
        for k in range(len(b.action)):
            e = int(ep[i + k])
            if e not in goal_cache:
                goal_cache[e] = sift.detectAndCompute(cv2.cvtColor(to_u8(b.inp.goal[k]), cv2.COLOR_RGB2GRAY), None)[1]
            gdes = goal_cache[e]
            des = sift.detectAndCompute(cv2.cvtColor(to_u8(b.inp.rgbd[k, :3]), cv2.COLOR_RGB2GRAY), None)[1]
            n = 0
            if des is not None and gdes is not None and len(des) >= 2 and len(gdes) >= 2:
                fwd = {a.queryIdx: a.trainIdx for a, c in (p for p in bf.knnMatch(des, gdes, k=2) if len(p) == 2)
                       if a.distance < 0.8 * c.distance}
                bwd = {a.queryIdx: a.trainIdx for a, c in (p for p in bf.knnMatch(gdes, des, k=2) if len(p) == 2)
                       if a.distance < 0.8 * c.distance}
                n = sum(1 for q, g in fwd.items() if bwd.get(g) == q)
            scores.append(n)
        labels.append(b.goal_in_view.numpy())
    return np.asarray(scores, dtype=np.float64), np.concatenate(labels) > 0.5


def train_siamese(train: DemoSet, held: DemoSet, cfg, steps: int, batch: int, seed: int, ep, st) -> dict:
    torch.manual_seed(seed)
    net = GoalMatch(32)
    clf = nn.Linear(32, 1)
    opt = torch.optim.Adam([*net.parameters(), *clf.parameters()], lr=2e-3)
    sampler = BufferSampler(train, batch, np.random.default_rng(seed))
    pos = float(np.mean(np.concatenate([np.asarray(e["goal_in_view"]) for e in train.episodes])))
    w_pos = (1 - pos) / max(pos, 1e-6)
    t0 = time.time()
    for step in range(steps):
        e, s = next(sampler)
        b = train.batch(e, s, cfg)
        logit = clf(net(b.inp.rgbd[:, :3], b.inp.goal))[:, 0]
        y = b.goal_in_view.float()
        loss = F.binary_cross_entropy_with_logits(logit, y, pos_weight=torch.tensor(w_pos))
        opt.zero_grad()
        loss.backward()
        opt.step()
        for g in opt.param_groups:
            g["lr"] = 2e-3 * 0.5 * (1 + math.cos(math.pi * (step + 1) / steps))
        if step % 250 == 0:
            print(f"siamese step {step} loss {loss.item():.4f} ({time.time() - t0:.0f} s)", flush=True)
    net.eval()
    scores, labels = [], []
    with torch.no_grad():
        for i in range(0, len(ep), 256):
            b = held.batch(ep[i:i + 256], st[i:i + 256], cfg)
            scores.append(torch.sigmoid(clf(net(b.inp.rgbd[:, :3], b.inp.goal))[:, 0]).numpy())
            labels.append(b.goal_in_view.numpy() > 0.5)
    p, y = np.concatenate(scores), np.concatenate(labels)
    return {"auroc": round(auroc(p, y), 4), "steps": steps, "batch": batch, "train_seconds": round(time.time() - t0, 1),
            "precision_at_0.5": round(float(((p >= 0.5) & y).sum() / max(int((p >= 0.5).sum()), 1)), 4),
            "recall_at_0.5": round(float(((p >= 0.5) & y).sum() / max(int(y.sum()), 1)), 4)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default="data/demos_v8")
    ap.add_argument("--out", default="results/diagnostics/goal_match_probe.json")
    ap.add_argument("--heldout-steps", type=int, default=6000)
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    torch.set_num_threads(1)
    cv2.setNumThreads(1)
    # the frame and goal photo at frame size, as the baselines read them (``goal_frame``)
    cfg = get_model_config("fr").replace(goal_head=False)
    cfg = dataclass_with_labels(cfg)
    train, held = DemoSet(args.data, "train"), DemoSet(args.data, "heldout")
    ep, st = held.sample_steps(args.heldout_steps, 1)
    t0 = time.time()
    s, y = sift_scores(held, ep, st, cfg)
    out: dict = {"data": args.data, "heldout_scored": int(len(ep)), "heldout_in_view": int(y.sum()),
                 "sift": {"auroc": round(auroc(s, y), 4), "seconds": round(time.time() - t0, 1),
                          "median_matches_in_view": float(np.median(s[y])), "median_matches_not": float(np.median(s[~y])),
                          **{f"recall_at_{k}": round(float((s[y] >= k).mean()), 4) for k in (4, 8, 12)},
                          **{f"false_positive_rate_at_{k}": round(float((s[~y] >= k).mean()), 4) for k in (4, 8, 12)}}}
    print(json.dumps(out, indent=1), flush=True)
    out["siamese"] = train_siamese(train, held, cfg, args.steps, args.batch, args.seed, ep, st)
    print(json.dumps(out, indent=1))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


def dataclass_with_labels(cfg):
    """A frame-size config whose batches carry the in-view labels (``goal_head`` reads them); the model is never built."""
    return cfg.replace(kind="nue", goal_head=True, use_uncertainty=False, use_aux=False, use_cbam=False,
                       goal_in_perception=True)


if __name__ == "__main__":
    main()
