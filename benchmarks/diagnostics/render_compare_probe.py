"""Issue 37, a last metre only a NeRF memory can give: can the robot find where the goal photo was taken by rendering
its own memory from candidate poses and comparing the renders with the photo?

SLING's keypoint matching needs the robot to look where the goal photo looks; in the shipped NUE's found-then-lost
runs it mostly never matched (``results/sling``). The memory, though, can render any view of what the robot has
seen. For val252 episodes, the exploring expert drives with the online memory (preset ``fast``, as in collection)
until the robot first comes within ``--near`` metres geodesic of the goal. There, candidate poses (navigable cells
within ``--radius`` m of the robot, every ``--spacing`` m, ``--headings`` headings) are rendered at low resolution
from the memory (no depth guides them) and scored against the goal photo, downsampled to the same size, by zero-mean
normalised cross-correlation of the RGB. Reported per episode: the position error of the best candidate, the rank of
the candidate nearest the true goal pose, the score there, and the seconds the search took. The candidate set reads
the house's navigation grid, which the robot does not have: an agent would take its own seen floor instead.

    python benchmarks/diagnostics/render_compare_probe.py --episodes 12 --out results/diagnostics/render_compare.json
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch

from nue.nerf.config import get_memory
from nue.nerf.online import OnlineNeRF
from nue.policy.agent import ExpertAgent
from nue.rollout import StepData, run_episode
from nue.scene.generator import ensure_house
from nue.sim.env import make_env
from nue.sim.episodes import load_episodes


def downsample(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """(H, W, 3) uint8 -> (h, w, 3) float in [0, 1] by block means (H, W multiples of h, w)."""
    H, W = img.shape[:2]
    x = img.astype(np.float64).reshape(h, H // h, w, W // w, 3).mean(axis=(1, 3)) / 255.0
    return x


def ncc(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Zero-mean normalised cross-correlation of ``a (N, P)`` rows with ``b (P,)``."""
    a = a - a.mean(axis=1, keepdims=True)
    b = b - b.mean()
    return (a @ b) / (np.linalg.norm(a, axis=1) * np.linalg.norm(b) + 1e-9)


def search(memory: OnlineNeRF, env, robot_xy: np.ndarray, args) -> dict:
    """Render every candidate pose and score it against the goal photo."""
    grid = env.navgrid
    xs = np.arange(-args.radius, args.radius + 1e-9, args.spacing)
    cand = [robot_xy + np.array([dx, dy]) for dx in xs for dy in xs if dx * dx + dy * dy <= args.radius ** 2]
    cand = [c for c in cand if grid.is_free(c)]
    yaws = [2 * math.pi * k / args.headings for k in range(args.headings)]
    H, W = env.task.camera.height, env.task.camera.width
    nan_depth = np.full((H, W), np.nan, dtype=np.float32)
    goal = downsample(env.goal_image, args.h, args.w).reshape(-1)
    t0 = time.perf_counter()
    poses, renders = [], []
    kept = memory.config
    memory.config = kept.replace(render_samples=args.search_samples)  # unguided rays need more samples than 8
    try:
        for c in cand:
            for y in yaws:
                m = memory.render_view(np.array([c[0], c[1], y]), nan_depth, args.h, args.w, env.floor_z)
                renders.append(m.rgb.permute(1, 2, 0).reshape(-1).float().cpu().numpy())
                poses.append((c[0], c[1], y))
    finally:
        memory.config = kept
    seconds = time.perf_counter() - t0
    scores = ncc(np.asarray(renders), goal)
    poses_a = np.asarray(poses)
    best = int(scores.argmax())
    gp = np.asarray(env.episode.goal_pose, dtype=np.float64)
    goal_yaw = float(gp[2]) if gp.shape[0] >= 3 else float("nan")
    d_pos = np.linalg.norm(poses_a[:, :2] - env.goal_xy, axis=1)
    d_yaw = np.abs((poses_a[:, 2] - goal_yaw + np.pi) % (2 * np.pi) - np.pi)
    true_idx = int(np.lexsort((d_yaw, np.round(d_pos / args.spacing)))[0])
    order = np.argsort(-scores)
    top5 = poses_a[order[:5], :2]
    return {"candidates": len(poses), "seconds": round(seconds, 2),
            "best_error_m": round(float(d_pos[best]), 3),
            "top5_min_error_m": round(float(np.linalg.norm(top5 - env.goal_xy, axis=1).min()), 3),
            "true_pose_rank": int(np.where(order == true_idx)[0][0]) + 1,
            "true_pose_distance_m": round(float(d_pos[true_idx]), 3), "true_pose_score": round(float(scores[true_idx]), 4),
            "best_score": round(float(scores[best]), 4), "median_score": round(float(np.median(scores)), 4),
            "robot_to_goal_m": round(float(np.linalg.norm(robot_xy - env.goal_xy)), 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes-dir", default="episodes/val252")
    ap.add_argument("--scenes-root", default="data/scenes")
    ap.add_argument("--episodes", type=int, default=12, help="episodes in all, spread over the houses")
    ap.add_argument("--difficulty", default="hard", help="episodes of this bin (easy ones often start near the goal)")
    ap.add_argument("--near", type=float, default=2.0)
    ap.add_argument("--radius", type=float, default=3.0)
    ap.add_argument("--spacing", type=float, default=0.35)
    ap.add_argument("--headings", type=int, default=12)
    ap.add_argument("--h", type=int, default=12)
    ap.add_argument("--w", type=int, default=16)
    ap.add_argument("--memory", default="fast")
    ap.add_argument("--search-samples", type=int, default=48, help="samples per ray of the candidate renders")
    ap.add_argument("--min-step", type=int, default=20, help="search no earlier than this step")
    ap.add_argument("--out", default="results/diagnostics/render_compare.json")
    args = ap.parse_args()
    torch.set_num_threads(1)
    files = sorted(Path(args.episodes_dir).glob("*.json"))
    per_house = max(1, math.ceil(args.episodes / len(files)))
    rows = []
    for f in files:
        if len(rows) >= args.episodes:
            break
        scene_name = f.stem
        split, _, idx = scene_name.rpartition("_")
        env = make_env(ensure_house(split, int(idx), Path(args.scenes_root)))
        episodes = load_episodes(f, env.scene, env.task)
        memory = OnlineNeRF(get_memory(args.memory), env.task.camera)
        for ep in [e for e in episodes if e.difficulty == args.difficulty][:per_house]:
            hit: dict = {}

            def on_step(s: StepData, hit=hit) -> None:
                if not hit and s.env.geodesic_distance <= args.near and s.t >= args.min_step:
                    hit.update(search(memory, s.env, s.env.pose[:2].copy(), args), step=s.t)

            rec = run_episode(env, ExpertAgent(kind="explore"), episode=ep, memory=memory, seed=0, on_step=on_step)
            row = {"scene": scene_name, "episode_id": ep.episode_id, "expert_steps": rec.steps, **hit}
            print(json.dumps(row), flush=True)
            if hit:
                rows.append(row)
    errs = np.array([r["best_error_m"] for r in rows])
    out = {"settings": vars(args), "episodes": rows,
           "median_best_error_m": round(float(np.median(errs)), 3) if len(errs) else None,
           "best_within_0.8m": round(float((errs <= 0.8).mean()), 4) if len(errs) else None,
           "median_true_pose_rank": float(np.median([r["true_pose_rank"] for r in rows])) if rows else None,
           "median_candidates": float(np.median([r["candidates"] for r in rows])) if rows else None}
    print(json.dumps({k: v for k, v in out.items() if k != "episodes"}, indent=1))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
