"""Issue 37: in the runs that came near the goal and left, did the robot ever *look at what the goal photo shows*, and
when it did, could the last-mile matcher see it?

The hand-off split (``nue.evaluate.handoff``) calls the goal "seen" when the goal's *position* is in the frame; the
goal photo, though, shows what lies in front of that position, and SLING's keypoint matcher needs that content in the
frame. For every failure of ``--method`` in the records (by default those that saw the goal or came within 2 m), this
replays the recorded trajectory pose by pose (no policy runs) and measures at each step:

- ``overlap``: the fraction of the goal photo's content in the current view: every ``--stride``-th pixel of the goal
  photo, back-projected by its depth to the world, projected into the current camera, inside the frame and within
  10% of the current depth there (not hidden);
- ``aligned overlap``: the same for the photo's content above the floor (the floor is seen from anywhere), counted
  only while the robot faces within 45 degrees of the photo's heading (SIFT is not invariant to larger changes of
  viewpoint), else 0;
- what :class:`nue.policy.goal_pose.GoalPoseEstimator` (SLING's matcher, default settings) makes of the frame:
  a measurement, or why none (few matches, ambiguous, ...), with its matches.

Reported per episode: the largest overlap and its step, steps with overlap >= 0.3 / 0.5, the steps at which the
estimator gave a measurement on any frame (SLING only tries every ``match_every``-th) and the SLING run's own first
match. Pooled: how many failures never had >= 0.3 of the photo in view (the policy never looked: exploration's
fault), how many had it but the estimator never measured on any such frame (the matcher's fault), and how many had a
measuring frame that the wrapper did not act on.

    python benchmarks/diagnostics/goal_visibility_probe.py results/sling/records_val252_sling_nue.jsonl \\
        --episodes-dir episodes/val252 --out results/diagnostics/goal_visibility.json
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

from nue.policy.goal_pose import GoalPoseEstimator
from nue.scene.generator import ensure_house
from nue.sim.camera import depth_to_points, world_from_camera
from nue.sim.env import make_env
from nue.sim.episodes import load_episodes
from nue.sim.record import Trajectory


def goal_points(env, stride: int, floor: bool = True) -> np.ndarray:
    """World points (N, 3) of every ``stride``-th pixel of the goal photo that has a surface (without the floor's,
    those within 5 cm of the floor height, when ``floor`` is False)."""
    _, depth = env.renderer.render(env.episode.goal_pose, env.floor_z)
    pts = depth_to_points(depth, env.episode.goal_pose, env.task.camera, env.floor_z)[stride // 2::stride, stride // 2::stride]
    d = np.asarray(depth, dtype=np.float64).reshape(env.task.camera.height, env.task.camera.width)
    valid = d[stride // 2::stride, stride // 2::stride] > 0
    if not floor:
        valid &= pts[..., 2] > env.floor_z + 0.05
    return pts[valid]


def overlap(points: np.ndarray, pose, depth: np.ndarray, env, tolerance: float = 0.1) -> float:
    """Fraction of ``points`` visible from ``pose`` given that view's z-depth ``depth``."""
    cam = env.task.camera
    m = world_from_camera(pose, cam, env.floor_z)
    pc = (points - m[:3, 3]) @ m[:3, :3]  # world -> camera frame
    z = pc[:, 2]
    front = z > cam.near
    u = np.full(len(z), -1.0)
    v = np.full(len(z), -1.0)
    u[front] = cam.fx * pc[front, 0] / z[front] + cam.cx
    v[front] = cam.fy * pc[front, 1] / z[front] + cam.cy
    inside = front & (u >= 0) & (u < cam.width) & (v >= 0) & (v < cam.height)
    d = np.asarray(depth, dtype=np.float64).reshape(cam.height, cam.width)
    seen = np.zeros(len(z), dtype=bool)
    di = d[v[inside].astype(np.int64), u[inside].astype(np.int64)]
    seen[inside] = (di > 0) & (np.abs(di - z[inside]) <= tolerance * z[inside])
    return float(seen.mean()) if len(z) else 0.0


def probe_episode(env, ep, record: dict, stride: int) -> dict:
    traj = Trajectory.decode(record["extra"]["trajectory"])
    env.reset(options={"episode": ep})
    pts = goal_points(env, stride)
    walls = goal_points(env, stride, floor=False)
    goal_yaw = float(env.episode.goal_pose[2])
    est = GoalPoseEstimator(env.task.camera, env.floor_z)
    est.set_goal(env.goal_image)
    ov, ov_aligned, measured, reasons, matches, errors = [], [], [], {}, [], []
    for t, pose in enumerate(traj.poses):
        rgb, depth = env.renderer.render(pose, env.floor_z)
        o = overlap(pts, pose, depth, env)
        ov.append(o)
        # the photo's content above the floor, seen within 45 degrees of the photo's own heading
        aligned = abs((pose[2] - goal_yaw + np.pi) % (2 * np.pi) - np.pi) <= np.pi / 4
        ov_aligned.append(overlap(walls, pose, depth, env) if aligned and len(walls) else 0.0)
        if o < 0.05:  # nothing of the photo in view: the matcher would have nothing to find (not run, for speed)
            continue
        m = est.estimate(rgb, depth, pose)
        matches.append((t, est.report.matches))
        if m is None:
            reasons[est.report.reason] = reasons.get(est.report.reason, 0) + 1
        else:
            measured.append(t)
            errors.append(float(np.linalg.norm(m.xy - env.goal_xy)))
    ov_a = np.asarray(ov)
    al = np.asarray(ov_aligned)
    lm = record["extra"].get("last_mile", {})
    return {
        "scene": record["scene"], "episode_id": record["episode_id"],
        "outcome": record["extra"].get("handoff", {}).get("outcome"),
        "closest_geodesic": record["extra"].get("handoff", {}).get("closest_geodesic"),
        "goal_points": int(len(pts)),
        "max_overlap": round(float(ov_a.max()), 3), "max_overlap_step": int(ov_a.argmax()),
        "steps_overlap_0.3": int((ov_a >= 0.3).sum()), "steps_overlap_0.5": int((ov_a >= 0.5).sum()),
        "max_aligned_overlap": round(float(al.max()), 3), "steps_aligned_0.3": int((al >= 0.3).sum()),
        "steps_aligned_0.5": int((al >= 0.5).sum()),
        "distance_at_max_aligned": round(float(np.linalg.norm(traj.poses[int(al.argmax())][:2] - env.goal_xy)), 2),
        "measured_steps": measured[:50], "measured": len(measured),
        "measured_within_0.5m": int(sum(e <= 0.5 for e in errors)),
        "no_measurement_reasons": reasons,
        "max_matches": max((c for _, c in matches), default=0),
        "sling_first_match": lm.get("first_match_step"), "sling_first_accept": lm.get("first_accept_step"),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("records", help="records of one method (JSON lines)")
    ap.add_argument("--method", default="", help="only this method's records (default: every record in the file)")
    ap.add_argument("--episodes-dir", default="episodes/val252")
    ap.add_argument("--scenes-root", default="data/scenes")
    ap.add_argument("--outcomes", default="found_then_lost",
                    help="comma-separated hand-off outcomes of the failures to probe (found_then_lost, near_unseen, never_near)")
    ap.add_argument("--stride", type=int, default=6, help="goal-photo pixel stride of the overlap")
    ap.add_argument("--out", default="results/diagnostics/goal_visibility.json")
    args = ap.parse_args()
    wanted = set(args.outcomes.split(","))
    recs = [json.loads(line) for line in open(args.records)]
    recs = [r for r in recs if (not args.method or r["method"] == args.method) and not r["success"]
            and r["extra"].get("handoff", {}).get("outcome") in wanted]
    rows = []
    for scene in sorted({r["scene"] for r in recs}):
        split, _, idx = scene.rpartition("_")
        env = make_env(ensure_house(split, int(idx), Path(args.scenes_root)))
        eps = {e.episode_id: e for e in load_episodes(Path(args.episodes_dir) / f"{scene}.json", env.scene, env.task)}
        for r in [r for r in recs if r["scene"] == scene]:
            row = probe_episode(env, eps[r["episode_id"]], r, args.stride)
            print(json.dumps(row), flush=True)
            rows.append(row)
    never = [r for r in rows if r["steps_overlap_0.3"] == 0]
    never_aligned = [r for r in rows if r["steps_aligned_0.3"] == 0]
    looked_unmeasured = [r for r in rows if r["steps_overlap_0.3"] > 0 and r["measured"] == 0]
    measurable = [r for r in rows if r["measured"] > 0]
    summary = {
        "episodes": len(rows),
        "never_0.3_of_photo_in_view": len(never),
        "never_0.3_of_photo_above_floor_in_view_within_45deg": len(never_aligned),
        "median_max_aligned_overlap": round(float(np.median([r["max_aligned_overlap"] for r in rows])), 3) if rows else None,
        "in_view_but_no_measurement_on_any_frame": len(looked_unmeasured),
        "a_frame_gave_a_measurement": len(measurable),
        "of_which_sling_never_matched": sum(r["sling_first_match"] is None for r in measurable),
        "median_max_overlap": round(float(np.median([r["max_overlap"] for r in rows])), 3) if rows else None,
    }
    print(json.dumps(summary, indent=1))
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps({"settings": vars(args), "summary": summary, "episodes": rows}, indent=1) + "\n")


if __name__ == "__main__":
    main()
