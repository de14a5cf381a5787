"""Issue 37, exploitation signal, offline probe: can a trained NUE's f_cog tell that the goal is in view and how far?

Freezes a trained NUE checkpoint, adds the exploitation head (``ModelConfig.goal_head``: goal-in-view logit and log
distance from f_cog) and trains only that head on a collection with the labels (``goal_in_view``, ``goal_distance``;
collections made after they were added), then scores it on the collection's held-out part:

- AUROC of the in-view probability against the label; precision / recall at 0.5;
- on the in-view held-out steps: median |log d_pred - log d| and the median error of the goal position the
  ``commit+`` locator would measure, ``|xy + d_pred (cos, sin)(yaw + a_pred) - xy_goal|`` (a_pred: the checkpoint's
  own auxiliary angle head), against the same with the true distance (angle error alone);
- with ``--features cat``: the same head on [f_cog, f_u, f_p] instead (what a head on the whole input could do).

A checkpoint whose model already has the head (``nue_goal`` trained end to end) is scored as it is with ``--steps 0``.

Writes the probe's checkpoint (the trunk's weights unchanged, the new head trained; an ordinary ``nue_goal``
checkpoint that ``nue eval -c commit+name=path`` runs) and a JSON of the scores.

    python benchmarks/diagnostics/goal_head_probe.py --checkpoint checkpoints/nue.pt --data data/demos_v8 \
        --out results/diagnostics/goal_head_probe_nue_v6.pt --steps 1500
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from nue.policy.accuracy import auroc
from nue.policy.blocks import mlp
from nue.policy.checkpoint import load_checkpoint, save_checkpoint
from nue.policy.config import ModelConfig
from nue.policy import build_model
from nue.train.dataset import BufferSampler, DemoSet


def features(model, inp, which: str) -> torch.Tensor:
    f_cog, f_u, f_p = model.features(inp)
    if which == "cog":
        return f_cog
    return torch.cat([f_cog, f_p] if f_u is None else [f_cog, f_u, f_p], dim=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default="checkpoints/nue.pt")
    ap.add_argument("--data", default="data/demos_v8")
    ap.add_argument("--out", default="results/diagnostics/goal_head_probe_nue_v6.pt")
    ap.add_argument("--features", choices=("cog", "cat"), default="cog")
    ap.add_argument("--steps", type=int, default=1500)
    ap.add_argument("--batch", type=int, default=64)
    ap.add_argument("--lr", type=float, default=2e-3)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-heldout-steps", type=int, default=6000)
    args = ap.parse_args()
    torch.set_num_threads(1)
    torch.manual_seed(args.seed)

    ckpt = load_checkpoint(args.checkpoint)
    base_cfg = ModelConfig.from_dict(ckpt["model_config"])
    trained = base_cfg.goal_head  # a model trained with its head: scored as it is (``--steps 0``)
    cfg = base_cfg if trained else base_cfg.replace(name=f"{base_cfg.name}_goal", goal_head=True)
    model = build_model(cfg)
    missing, unexpected = model.load_state_dict(ckpt["model_state"], strict=False)
    assert not unexpected and all(k.startswith("goal_head.") for k in missing), (missing, unexpected)
    assert not (trained and missing), missing
    model.eval()
    for p in model.parameters():
        p.requires_grad_(False)
    if args.features == "cog":
        head = model.goal_head
    else:  # a probe on the whole input: not part of the model, scored only
        dim = cfg.branch_dim * (2 if cfg.use_uncertainty else 1) + cfg.perception_dim
        head = mlp([dim, cfg.aux_hidden, 2], cfg.negative_slope, final_activation=False)
    for p in head.parameters():
        p.requires_grad_(True)
    opt = torch.optim.Adam(head.parameters(), lr=args.lr)

    train, held = DemoSet(args.data, "train"), DemoSet(args.data, "heldout")
    train.check_layout(cfg)
    sampler = BufferSampler(train, args.batch, np.random.default_rng(args.seed))
    pos_rate = float(np.mean(np.concatenate([np.asarray(e["goal_in_view"]) for e in train.episodes])))
    print(f"train {len(train)} steps ({train.n_episodes} episodes), in view {pos_rate:.3f}; held-out {len(held)} steps")
    t0 = time.time()
    for step in range(args.steps):
        ep, st = next(sampler)
        batch = train.batch(ep, st, cfg)
        with torch.no_grad():
            f = features(model, batch.inp, args.features)
        out = head(f)
        view, logd = out[:, 0], out[:, 1]
        label = batch.goal_in_view.float()
        loss = F.binary_cross_entropy_with_logits(view, label)
        mask = label > 0.5
        if mask.any():
            loss = loss + (logd[mask] - torch.log(batch.goal_distance[mask].clamp_min(0.1))).abs().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        for g in opt.param_groups:
            g["lr"] = args.lr * 0.5 * (1 + math.cos(math.pi * (step + 1) / args.steps))
        if step % 250 == 0:
            print(f"step {step} loss {loss.item():.4f} ({time.time() - t0:.0f} s)", flush=True)

    # held-out scores
    ep_of, st_of = held.sample_steps(args.max_heldout_steps, 1)
    probs, logds, angles, labels, dists, true_angles = [], [], [], [], [], []
    with torch.no_grad():
        for i in range(0, len(ep_of), 256):
            b = held.batch(ep_of[i:i + 256], st_of[i:i + 256], cfg)
            full = model(b.inp)
            if trained:  # the model's own head (with its inputs, e.g. f_match)
                out = torch.stack([full.goal_view, full.goal_log_distance], dim=1)
            else:
                out = head(features(model, b.inp, args.features))
            probs.append(torch.sigmoid(out[:, 0]).numpy())
            logds.append(out[:, 1].numpy())
            angles.append(full.aux_angle.numpy())
            labels.append(b.goal_in_view.numpy())
            dists.append(b.goal_distance.numpy())
            true_angles.append(b.goal_angle.numpy())
    p, logd, a = np.concatenate(probs), np.concatenate(logds), np.concatenate(angles)
    y, d, ta = np.concatenate(labels) > 0.5, np.concatenate(dists), np.concatenate(true_angles)
    pred = p >= 0.5
    dp = np.exp(logd)

    def pos_err(dist, ang):  # robot at the origin facing +x: error of the goal position from (dist, ang)
        return np.hypot(dist * np.cos(ang) - d * np.cos(ta), dist * np.sin(ang) - d * np.sin(ta))

    e_full, e_angle = pos_err(dp, a), pos_err(d, a)
    scores = {
        "checkpoint": args.checkpoint, "data": args.data, "features": args.features, "steps": args.steps,
        "train_steps": len(train), "heldout_scored": int(len(ep_of)), "heldout_in_view": int(y.sum()),
        "auroc": round(auroc(p, y), 4),
        "precision_at_0.5": round(float((pred & y).sum() / max(pred.sum(), 1)), 4),
        "recall_at_0.5": round(float((pred & y).sum() / max(y.sum(), 1)), 4),
        "median_abs_log_distance_error_in_view": round(float(np.median(np.abs(logd[y] - np.log(np.maximum(d[y], 0.1))))), 4),
        "median_angle_error_deg_in_view": round(float(np.degrees(np.median(np.abs(np.angle(np.exp(1j * (a[y] - ta[y]))))))), 2),
        "median_position_error_m_in_view": round(float(np.median(e_full[y])), 3),
        "share_position_error_below_0.75m_in_view": round(float(np.mean(e_full[y] < 0.75)), 4),
        "median_position_error_true_distance_m_in_view": round(float(np.median(e_angle[y])), 3),
        "median_position_error_m_predicted_in_view": round(float(np.median(e_full[pred])), 3) if pred.any() else None,
        "train_seconds": round(time.time() - t0, 1),
        "by_threshold": {f"{q:g}": {"precision": round(float(((p >= q) & y).sum() / max(int((p >= q).sum()), 1)), 4),
                                    "recall": round(float(((p >= q) & y).sum() / max(int(y.sum()), 1)), 4),
                                    "median_position_error_m": (round(float(np.median(e_full[p >= q])), 3)
                                                                if (p >= q).any() else None)}
                         for q in (0.5, 0.7, 0.8, 0.9, 0.95)},
    }
    print(json.dumps(scores, indent=1))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.with_suffix(f".{args.features}.json").write_text(json.dumps(scores, indent=1) + "\n")
    if args.features == "cog" and not trained:
        payload = {k: v for k, v in ckpt.items() if k != "format"}
        payload["model_config"] = cfg.to_dict()
        payload["model_state"] = model.state_dict()
        payload["probe"] = {"from": args.checkpoint, "data": args.data, "steps": args.steps, "lr": args.lr,
                            "seed": args.seed, "trained": "goal_head only (trunk frozen)"}
        save_checkpoint(out, payload)
        print(f"wrote {out}")


if __name__ == "__main__":
    main()
