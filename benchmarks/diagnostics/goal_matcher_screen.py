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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("records", help="records of a sling+ row (JSON lines)")
    ap.add_argument("--mode", choices=("sift", "template"), default="template")
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
    names = list(SIFT_VARIANTS) if args.mode == "sift" else ["template"]
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
