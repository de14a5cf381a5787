"""Issue 37: can a classic matcher locate the goal on the frames where SLING's did not? Screens matcher variants on the
frames of the found-then-lost failures of a ``sling+`` row (replayed from the recorded poses, no policy runs).

Every ``--stride``-th frame of each failure is rendered; its *overlap* with the goal photo's content is measured as in
``goal_visibility_probe.py`` (frames with overlap < 0.3 are kept only every 8th step, as negatives). Each variant
estimates the goal's position from the frame; an estimate within 0.5 m (SIFT) or 0.8 m (template) of the goal is right.

- SIFT variants (``--mode sift``): :class:`nue.policy.goal_pose.GoalPoseEstimator` with a lower contrast threshold, a
  looser ratio test, fewer inliers, or CLAHE on both images; the whole estimator (PnP, plausibility, photometric check).
- Template matching (``--mode template``): the goal photo in CIELAB resized to 0.25-0.85 of its size, matched over the
  frame by normalised cross-correlation (``cv2.matchTemplate``, ``TM_CCOEFF_NORMED``); the best scale and place give a
  ray and the frame's median depth there, and the goal camera is put along the ray at depth x (1 - scale) (the photo's
  content is ``scale`` times as far from the goal camera as from the robot). Accepted above a score threshold.
- Depth warping (``--mode warp``): the current RGB-D frame's points (every 2nd pixel) are projected into candidate
  goal cameras in front of the robot (0.4-4 m ahead every 0.25 m, within 45 deg of the heading, headings within 60 deg
  of the robot's every 15 deg: 2,430 candidates), z-buffered at 45 x 60, and compared with the goal photo at 45 x 60
  by colour normalised cross-correlation where at least half the view is covered; the best candidate is the estimate.
  Frames: up to 8 with at least 0.3 of the photo's content above the floor in view while facing within 45 deg of its
  heading (``goal_visibility_probe.py``'s aligned overlap), and 8 others, per failure.

    python benchmarks/diagnostics/goal_matcher_screen.py results/sling/records_val252_sling_nue.jsonl --mode template
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from goal_visibility_probe import goal_points, overlap  # noqa: E402

from nue.sim.camera import depth_to_points  # noqa: E402

from nue.policy.goal_pose import GoalPoseConfig, GoalPoseEstimator  # noqa: E402
from nue.scene.generator import ensure_house  # noqa: E402
from nue.sim.camera import world_from_camera  # noqa: E402
from nue.sim.env import make_env  # noqa: E402
from nue.sim.episodes import load_episodes  # noqa: E402
from nue.sim.record import Trajectory  # noqa: E402

SCALES = (0.25, 0.3, 0.36, 0.43, 0.5, 0.6, 0.7, 0.85)
THRESHOLDS = (0.5, 0.6, 0.7, 0.8, 0.85, 0.9)


class _Estimator(GoalPoseEstimator):
    """SLING's estimator with optional CLAHE on the lightness of both images."""

    def __init__(self, camera, floor_z, config: GoalPoseConfig, clahe: bool = False):
        super().__init__(camera, floor_z, config)
        self.clahe = clahe

    def features(self, rgb):
        if self.clahe:
            lab = cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2LAB)
            lab[..., 0] = cv2.createCLAHE(2.0, (4, 4)).apply(lab[..., 0])
            rgb = cv2.cvtColor(lab, cv2.COLOR_LAB2RGB)
        return super().features(rgb)


SIFT_VARIANTS = {
    "default": (GoalPoseConfig(), False),
    "contrast_0.01": (GoalPoseConfig(contrast_threshold=0.01), False),
    "contrast_0.005": (GoalPoseConfig(contrast_threshold=0.005), False),
    "ratio_0.9": (GoalPoseConfig(ratio=0.9), False),
    "contrast_0.01_ratio_0.9": (GoalPoseConfig(contrast_threshold=0.01, ratio=0.9), False),
    "contrast_0.01_inliers_8": (GoalPoseConfig(contrast_threshold=0.01, min_inliers=8), False),
    "clahe": (GoalPoseConfig(), True),
    "clahe_contrast_0.01": (GoalPoseConfig(contrast_threshold=0.01), True),
}


def template_estimate(frame: np.ndarray, goal: np.ndarray, depth: np.ndarray, pose, camera, floor_z: float):
    """(score, scale, goal xy) of the best multi-scale template match of the goal photo in the frame."""
    f = cv2.cvtColor(frame, cv2.COLOR_RGB2LAB).astype(np.float32)
    g = cv2.cvtColor(goal, cv2.COLOR_RGB2LAB).astype(np.float32)
    best = None
    for s in SCALES:
        tw, th = int(round(goal.shape[1] * s)), int(round(goal.shape[0] * s))
        _, score, _, loc = cv2.minMaxLoc(cv2.matchTemplate(f, cv2.resize(g, (tw, th), interpolation=cv2.INTER_AREA),
                                                           cv2.TM_CCOEFF_NORMED))
        if best is None or score > best[0]:
            best = (score, s, loc, tw, th)
    score, s, (x0, y0), tw, th = best
    box = np.asarray(depth).reshape(camera.height, camera.width)[y0:y0 + th, x0:x0 + tw]
    dz = float(np.median(box[box > 0])) if (box > 0).any() else 0.0
    m = world_from_camera(pose, camera, floor_z)
    ray = m[:3, :3] @ np.array([(x0 + tw / 2 - camera.cx) / camera.fx, 0.0, 1.0])
    ray = ray[:2] / np.linalg.norm(ray[:2])
    return float(score), s, np.asarray(pose[:2], dtype=np.float64) + ray * dz * (1 - s)


WARP_H, WARP_W = 45, 60


def warp_estimate(rgb: np.ndarray, depth: np.ndarray, pose, goal: np.ndarray, camera, floor_z: float):
    """(score, candidate (x, y, yaw)) of the best goal camera found by warping the frame's points into candidates."""
    z_img = np.asarray(depth, dtype=np.float64).reshape(camera.height, camera.width)
    pts = depth_to_points(z_img, pose, camera, floor_z)[::2, ::2].reshape(-1, 3)
    col = rgb[::2, ::2].reshape(-1, 3).astype(np.float64)
    ok = z_img[::2, ::2].reshape(-1) > 0
    pts, col = pts[ok], col[ok]
    g = cv2.resize(goal, (WARP_W, WARP_H), interpolation=cv2.INTER_AREA).reshape(-1, 3).astype(np.float64)
    sx, sy = WARP_W / camera.width, WARP_H / camera.height
    x0, y0, yaw0 = (float(v) for v in pose[:3])
    best: tuple[float, tuple[float, float, float]] = (-2.0, (x0, y0, yaw0))
    for d in np.arange(0.4, 4.0 + 1e-9, 0.25):
        for lat in np.arange(-d, d + 1e-9, 0.25):
            if abs(np.arctan2(lat, d)) > np.radians(45):
                continue
            cx = x0 + d * np.cos(yaw0) - lat * np.sin(yaw0)
            cy = y0 + d * np.sin(yaw0) + lat * np.cos(yaw0)
            for dyaw in np.radians(np.arange(-60, 61, 15)):
                cand = (float(cx), float(cy), yaw0 + float(dyaw))
                m = world_from_camera(cand, camera, floor_z)
                pc = (pts - m[:3, 3]) @ m[:3, :3]
                f = pc[:, 2] > 0.1
                u = (camera.fx * pc[f, 0] / pc[f, 2] + camera.cx) * sx
                v = (camera.fy * pc[f, 1] / pc[f, 2] + camera.cy) * sy
                ins = (u >= 0) & (u < WARP_W) & (v >= 0) & (v < WARP_H)
                idx = v[ins].astype(np.int64) * WARP_W + u[ins].astype(np.int64)
                if len(idx) < 10:
                    continue
                order = np.lexsort((pc[f, 2][ins], idx))
                first = order[np.r_[True, idx[order][1:] != idx[order][:-1]]]
                if len(first) < 0.5 * WARP_H * WARP_W:
                    continue
                a = col[f][ins][first]
                b = g[idx[first]]
                a, b = a - a.mean(axis=0), b - b.mean(axis=0)
                score = float((a * b).sum() / (np.sqrt(float((a * a).sum() * (b * b).sum())) + 1e-9))
                if score > best[0]:
                    best = (score, cand)
    return best


def warp_rows(env, poses) -> list[tuple]:
    """``warp`` mode's rows of one failure: up to 8 frames with the photo's content in view (aligned overlap >= 0.3)
    and 8 drawn from the whole run (fixed draw), each (aligned overlap, 0, score, error m, cpu s)."""
    walls = goal_points(env, 6, floor=False)
    goal_yaw = float(env.episode.goal_pose[2])
    rng = np.random.default_rng(0)

    def aligned_overlap(pose, depth) -> float:
        facing = abs((pose[2] - goal_yaw + np.pi) % (2 * np.pi) - np.pi) <= np.pi / 4
        return overlap(walls, pose, depth, env) if facing and len(walls) else 0.0

    in_view = [t for t, pose in enumerate(poses) if aligned_overlap(pose, env.renderer.render(pose, env.floor_z)[1]) >= 0.3]
    chosen = list(rng.choice(in_view, min(8, len(in_view)), replace=False)) if in_view else []
    chosen += list(rng.choice(len(poses), 8, replace=False))
    out = []
    for t in chosen:
        pose = poses[int(t)]
        rgb, depth = env.renderer.render(pose, env.floor_z)
        t0 = time.process_time()
        score, cand = warp_estimate(rgb, depth, pose, env.goal_image, env.task.camera, env.floor_z)
        out.append((aligned_overlap(pose, depth), 0, score, float(np.hypot(cand[0] - env.goal_xy[0], cand[1] - env.goal_xy[1])),
                    time.process_time() - t0))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("records", help="records of a sling+ row (JSON lines)")
    ap.add_argument("--mode", choices=("sift", "template", "warp"), default="template")
    ap.add_argument("--episodes-dir", default="episodes/val252")
    ap.add_argument("--scenes-root", default="data/scenes")
    ap.add_argument("--max-episodes", type=int, default=0, help="only the first N failures (0 = all)")
    ap.add_argument("--stride", type=int, default=0, help="frame stride (default 2 for sift, 3 for template)")
    ap.add_argument("--out", default="")
    args = ap.parse_args()
    stride = args.stride or (2 if args.mode == "sift" else 3)
    recs = [json.loads(line) for line in open(args.records)]
    fails = [r for r in recs if not r["success"] and r["extra"].get("handoff", {}).get("outcome") == "found_then_lost"]
    if args.max_episodes:
        fails = fails[:args.max_episodes]
    rows = []  # (overlap, variant index, score or -1, error m or nan, cpu s)
    names = list(SIFT_VARIANTS) if args.mode == "sift" else [args.mode]
    for r in fails:
        scene = r["scene"]
        split, _, idx = scene.rpartition("_")
        env = make_env(ensure_house(split, int(idx), Path(args.scenes_root)))
        ep = {e.episode_id: e for e in load_episodes(Path(args.episodes_dir) / f"{scene}.json", env.scene, env.task)}[r["episode_id"]]
        env.reset(options={"episode": ep})
        pts = goal_points(env, 6)
        ests = [_Estimator(env.task.camera, env.floor_z, cfg, clahe) for cfg, clahe in SIFT_VARIANTS.values()] \
            if args.mode == "sift" else []
        for e in ests:
            e.set_goal(env.goal_image)
        poses = Trajectory.decode(r["extra"]["trajectory"]).poses
        if args.mode == "warp":
            rows += warp_rows(env, poses)
            print(scene, r["episode_id"], len(rows), flush=True)
            continue
        for t in range(0, len(poses), stride):
            pose = poses[t]
            rgb, depth = env.renderer.render(pose, env.floor_z)
            o = overlap(pts, pose, depth, env)
            if args.mode == "sift":
                if o < 0.3 and t % 8:
                    continue
                for i, e in enumerate(ests):
                    t0 = time.process_time()
                    m = e.estimate(rgb, depth, pose)
                    err = float(np.linalg.norm(m.xy - env.goal_xy)) if m is not None else float("nan")
                    rows.append((o, i, 1.0 if m is not None else -1.0, err, time.process_time() - t0))
            else:
                t0 = time.process_time()
                score, _, xy = template_estimate(rgb, env.goal_image, depth, pose, env.task.camera, env.floor_z)
                rows.append((o, 0, score, float(np.linalg.norm(xy - env.goal_xy)), time.process_time() - t0))
        print(scene, r["episode_id"], len(rows), flush=True)
    a = np.asarray(rows, dtype=np.float64).reshape(-1, 5)
    out: dict = {"settings": {**vars(args), "stride": stride}, "episodes": len(fails), "variants": {}}
    for i, name in enumerate(names):
        v = a[a[:, 1] == i]
        o, score, err = v[:, 0], v[:, 2], v[:, 3]
        res = {"frames": int(len(v)), "frames_in_view": int((o >= 0.3).sum()),
               "cpu_ms_per_call": round(1000 * float(v[:, 4].mean()), 2) if len(v) else None}
        if args.mode == "sift":
            acc = score > 0
            res.update(measured=int(acc.sum()), right_0_5m=int((acc & (err <= 0.5)).sum()),
                       wrong=int((acc & ~(err <= 0.5)).sum()), wrong_photo_not_in_view=int((acc & (o < 0.05)).sum()))
        elif args.mode == "warp":
            res["frames_in_view"] = int((o >= 0.3).sum())
            res["in_view_best_within_0_8m"] = int(((o >= 0.3) & (err <= 0.8)).sum())
            res["in_view_median_error_m"] = round(float(np.median(err[o >= 0.3])), 2) if (o >= 0.3).any() else None
            res["median_score_in_view"] = round(float(np.median(score[o >= 0.3])), 3) if (o >= 0.3).any() else None
            res["median_score_not_in_view"] = round(float(np.median(score[o < 0.05])), 3) if (o < 0.05).any() else None
            res["thresholds"] = {str(th): {"accepted": int((score >= th).sum()), "right_0_8m": int(((score >= th) & (err <= 0.8)).sum()),
                                           "wrong": int(((score >= th) & (err > 0.8)).sum())} for th in THRESHOLDS}
        else:
            res["thresholds"] = {str(th): {"accepted": int((score >= th).sum()),
                                           "accepted_in_view": int(((score >= th) & (o >= 0.3)).sum()),
                                           "right_0_8m": int(((score >= th) & (err <= 0.8)).sum()),
                                           "wrong": int(((score >= th) & (err > 0.8)).sum()),
                                           "wrong_photo_not_in_view": int(((score >= th) & (o < 0.05)).sum())}
                                 for th in THRESHOLDS}
        out["variants"][name] = res
    print(json.dumps(out["variants"], indent=1))
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(json.dumps(out, indent=1) + "\n")


if __name__ == "__main__":
    main()
