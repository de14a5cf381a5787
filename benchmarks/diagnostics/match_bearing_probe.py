"""Issue 37, the goal's position for ``commit+``: does the matching branch's map say *where* the goal is better than
the auxiliary angle head?

On held-out steps with the goal in view (the exploring expert's switch test), a trained ``nue_match`` checkpoint's
matching branch gives m_frame, each frame cell's best cosine among the goal photo's cells. The frame cell with the
highest m_frame gives a bearing (and the softmax-weighted mean of the columns' best cosines a soft one; 90 deg
horizontal field of view, positive = left, as ``goal_angle``) and the depth under it a range; this probe compares
that bearing with the true goal angle, next to the auxiliary head's angle and to "straight ahead", and the range with
the true distance, next to the exploitation head's distance. Nothing is trained.

    python benchmarks/diagnostics/match_bearing_probe.py --checkpoint results/candidates/nue_match_s0.pt \
        --data data/demos_v8 --out results/diagnostics/match_bearing_nue_match_s0.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch

from nue.policy.checkpoint import load_policy
from nue.train.dataset import DemoSet


TEMPERATURES = (0.02, 0.05, 0.1, 0.2)
"""Softmax temperatures (on cosines) of the soft bearing: the column profile's weighted mean column."""


def wrap(a: np.ndarray) -> np.ndarray:
    return (a + np.pi) % (2 * np.pi) - np.pi


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", default="results/candidates/nue_match_s0.pt")
    ap.add_argument("--data", default="data/demos_v8")
    ap.add_argument("--out", default="results/diagnostics/match_bearing_nue_match_s0.json")
    ap.add_argument("--heldout-steps", type=int, default=6000)
    args = ap.parse_args()
    torch.set_num_threads(1)
    model, header = load_policy(args.checkpoint)
    model.eval()
    cfg = header.model
    held = DemoSet(args.data, "heldout")
    ep, st = held.sample_steps(args.heldout_steps, 1)
    rows: dict[str, list[np.ndarray]] = {k: [] for k in ("view", "true_angle", "true_d", "aux_angle", "head_p",
                                                          "head_d", "map_angle", "map_range", "map_peak", "zero_angle",
                                                          *(f"w{t}_angle" for t in TEMPERATURES))}
    with torch.no_grad():
        for i in range(0, len(ep), 256):
            b = held.batch(ep[i:i + 256], st[i:i + 256], cfg)
            out = model(b.inp)
            _, m_frame = model.f_match.correlation(b.inp.rgbd[:, :3], b.inp.goal)
            n, h, w = m_frame.shape
            flat = m_frame.reshape(n, -1)
            peak, j = flat.max(dim=1)
            col = (j % w).numpy()
            x = ((col + 0.5) / w - 0.5) * 2.0  # tan(45 deg) = 1
            rows["map_angle"].append(-np.arctan(x))
            # soft bearing: the column profile's softmax-weighted mean (temperature 0.05 on cosines)
            prof = m_frame.max(dim=1).values  # (n, w)
            xs = ((np.arange(w) + 0.5) / w - 0.5) * 2.0
            for t in TEMPERATURES:
                rows[f"w{t}_angle"].append(-np.arctan(torch.softmax(prof / t, dim=1).numpy() @ xs))
            rows["zero_angle"].append(np.zeros(n))
            depth = b.inp.rgbd[:, 3].numpy() * 5.0  # clip(depth, 0, 5) / 5
            H, W = depth.shape[1:]
            r = (j // w).numpy()
            cell = [depth[k, r[k] * H // h:(r[k] + 1) * H // h, col[k] * W // w:(col[k] + 1) * W // w] for k in range(n)]
            rows["map_range"].append(np.array([float(np.median(c)) for c in cell]))
            rows["map_peak"].append(peak.numpy())
            rows["view"].append(b.goal_in_view.numpy() > 0.5)
            rows["true_angle"].append(b.goal_angle.numpy())
            rows["true_d"].append(b.goal_distance.numpy())
            rows["aux_angle"].append(out.aux_angle.numpy())
            rows["head_p"].append(torch.sigmoid(out.goal_view).numpy())
            rows["head_d"].append(np.exp(out.goal_log_distance.numpy()))
    a = {k: np.concatenate(v) for k, v in rows.items()}
    v = a["view"]
    res: dict = {"checkpoint": args.checkpoint, "data": args.data, "heldout_scored": int(len(v)), "in_view": int(v.sum())}
    for name in ("zero_angle", "aux_angle", "map_angle", *(f"w{t}_angle" for t in TEMPERATURES)):
        e = np.degrees(np.abs(wrap(a[name] - a["true_angle"])))
        res[f"{name}_error_deg_median_in_view"] = round(float(np.median(e[v])), 2)
        res[f"{name}_within_15deg_in_view"] = round(float((e[v] <= 15).mean()), 4)
        conf = v & (a["head_p"] >= 0.9)
        res[f"{name}_error_deg_median_p09"] = round(float(np.median(e[conf])), 2) if conf.any() else None
    for name in ("head_d", "map_range"):
        e = np.abs(a[name] - a["true_d"])
        res[f"{name}_error_m_median_in_view"] = round(float(np.median(e[v])), 3)
    # the position each would give, relative to the robot: d (cos, sin)(angle); error to the true goal offset
    true = a["true_d"][:, None] * np.stack([np.cos(a["true_angle"]), np.sin(a["true_angle"])], 1)
    for ang, rng in (("zero_angle", "head_d"), ("aux_angle", "head_d"), ("map_angle", "head_d"),
                     *((f"w{t}_angle", "head_d") for t in TEMPERATURES), ("map_angle", "map_range")):
        pos = a[rng][:, None] * np.stack([np.cos(a[ang]), np.sin(a[ang])], 1)
        e = np.linalg.norm(pos - true, axis=1)
        conf = v & (a["head_p"] >= 0.9)
        res[f"position_{ang}+{rng}_error_m_median_in_view"] = round(float(np.median(e[v])), 3)
        res[f"position_{ang}+{rng}_error_m_median_p09_in_view"] = round(float(np.median(e[conf])), 3) if conf.any() else None
        res[f"position_{ang}+{rng}_within_0.8m_in_view"] = round(float((e[v] <= 0.8).mean()), 4)
    res["steps_p09"] = int((a["head_p"] >= 0.9).sum())
    res["steps_p09_in_view"] = int((v & (a["head_p"] >= 0.9)).sum())
    print(json.dumps(res, indent=1))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
