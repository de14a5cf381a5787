"""How well the last mile locates the goal, and what it costs per step, on val252 episodes.

A diagnostic, not part of ``make bench``. For the first ``--per-house`` episodes of every house in
``--episodes-dir`` (houses regenerated under ``--scenes-root`` from their split's seeds):

* **offset views**: the goal photo against views rendered 0.5-3 m behind the goal (0.3 m to either side, the
  heading jittered by up to +-20 deg, only where the robot may stand): per-frame estimates, their position
  error (m) and heading error (deg) against the match count (PnP inliers);
* **expert path**: the same for every frame of the geodesic expert's path within 3 m of the goal (it
  approaches from wherever the start is, often facing away from what the goal photo shows);
* **another house**: the previous house's goal photo against this house's offset views: every acceptance
  is a false one;
* **wrapper cost**: :class:`LastMileAgent` around an agent that only turns (costs nothing) for 60 steps from
  1 m behind the goal: CPU ms per step of the wrapper by part (process time, so other jobs on the machine
  inflate it less than wall time).

    python benchmarks/diagnostics/last_mile.py --per-house 6 --cost-episodes 2 --out outputs/last_mile_diag.json
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("LP_NUM_THREADS", "1")  # one llvmpipe thread: the process time is then ours

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from nue.policy.agent import ExpertAgent  # noqa: E402
from nue.policy.goal_pose import GoalPoseConfig, GoalPoseEstimator  # noqa: E402
from nue.policy.last_mile import LastMileAgent, LastMileConfig  # noqa: E402
from nue.rollout import run_episode  # noqa: E402
from nue.scene.generator import ensure_house  # noqa: E402
from nue.scene.scene import Scene  # noqa: E402
from nue.sim.camera import quat_from_yaw  # noqa: E402
from nue.sim.env import make_env  # noqa: E402
from nue.sim.episodes import read_episodes  # noqa: E402


POSE = GoalPoseConfig()
"""The per-frame settings measured (``--pose`` overrides fields)."""


def _offset_poses(goal: np.ndarray, env, rng: np.random.Generator) -> list[np.ndarray]:
    """Poses behind the goal (0.5-3 m, 0.3 m to either side, heading jittered) where the robot may stand."""
    c, s = math.cos(goal[2]), math.sin(goal[2])
    out = []
    for back in (0.5, 1.0, 1.5, 2.0, 3.0):
        for side in (-0.3, 0.3):
            p = np.array([goal[0] - back * c + side * s, goal[1] - back * s - side * c,
                          goal[2] + rng.uniform(-math.radians(20), math.radians(20))])
            if env.navgrid.is_free(p[:2]):
                out.append(p)
    return out


def _row(est: GoalPoseEstimator, env, pose, goal) -> dict:
    """One frame's estimate against the true goal pose (x, y, yaw)."""
    rgb, depth = env.renderer.render(pose, env.floor_z)
    t = time.process_time()
    m = est.estimate(rgb, depth, pose)
    row = {"ms": 1000 * (time.process_time() - t), "dist": float(np.linalg.norm(pose[:2] - goal[:2])),
           "matches": est.report.matches, "inliers": est.report.inliers, "reason": est.report.reason}
    if m is not None:
        row["err_m"] = float(np.linalg.norm(m.xy - goal[:2]))
        row["err_deg"] = abs(math.degrees(math.remainder(m.yaw - goal[2], 2 * math.pi)))
    return row


class _Turn:
    """A wrapped agent that costs nothing: it always turns left."""

    def reset(self, env, obs, seed=0):
        pass

    def act(self, obs, maps):
        return 1


class _Timed:
    """Process time spent in a :class:`LastMileAgent`'s ``reset`` and in each ``act``, split by who acted."""

    def __init__(self, agent: LastMileAgent):
        self.agent, self.reset_cpu, self.cpu = agent, 0.0, {"inner": [], "controller": []}

    def reset(self, env, obs, seed=0):
        t = time.process_time()
        self.agent.reset(env, obs, seed)
        self.reset_cpu += time.process_time() - t

    def act(self, obs, maps):
        before = self.agent.control_steps
        t = time.process_time()
        a = self.agent.act(obs, maps)
        self.cpu["controller" if self.agent.control_steps > before else "inner"].append(time.process_time() - t)
        return a


def _wrapper_cost(scene, ep, start: np.ndarray) -> dict:
    """:class:`LastMileAgent` around :class:`_Turn` for up to 60 steps from ``start`` (x, y, yaw) behind the goal."""
    env = make_env(scene, "paper", max_steps=60)
    agent = LastMileAgent(_Turn(), LastMileConfig(pose=POSE))
    timed = _Timed(agent)
    moved = dataclasses.replace(ep, start_position=(float(start[0]), float(start[1]), 0.0),
                                start_rotation=tuple(float(v) for v in quat_from_yaw(float(start[2]))))
    rec = run_episode(env, timed, episode=moved)
    s = agent.summary(env.goal_xy)
    return {"steps": rec.steps, "success": rec.success, "reset_cpu": timed.reset_cpu, "cpu": timed.cpu,
            "control_steps": s["control_steps"], "accepted_errors": s["accepted_errors"]}


def _summary(rows: list[dict]) -> dict:
    acc = [r for r in rows if "err_m" in r]
    out = {"frames": len(rows), "accepted": len(acc), "ms_per_estimate": round(float(np.mean([r["ms"] for r in rows])), 2)
           if rows else None}
    if acc:
        err = np.array([r["err_m"] for r in acc])
        out.update(within_0_5m=round(float((err <= 0.5).mean()), 3), median_err_m=round(float(np.median(err)), 3),
                   median_err_deg=round(float(np.median([r["err_deg"] for r in acc])), 2))
        bins = [(0, 12), (12, 20), (20, 40), (40, 80), (80, 10_000)]
        out["by_inliers"] = {f"{lo}-{hi - 1 if hi < 10_000 else ''}": {
            "n": int(sum(lo <= r["inliers"] < hi for r in acc)),
            "within_0_5m": round(float(np.mean([r["err_m"] <= 0.5 for r in acc if lo <= r["inliers"] < hi])), 3)
            if any(lo <= r["inliers"] < hi for r in acc) else None,
            "median_err_m": round(float(np.median([r["err_m"] for r in acc if lo <= r["inliers"] < hi])), 3)
            if any(lo <= r["inliers"] < hi for r in acc) else None} for lo, hi in bins}
        out["by_distance"] = {f"{lo}-{hi}m": {"frames": int(sum(lo <= r["dist"] < hi for r in rows)),
                                              "accepted": int(sum(lo <= r["dist"] < hi for r in acc))}
                              for lo, hi in ((0, 1), (1, 2), (2, 3), (3, 10))}
    reasons: dict[str, int] = {}
    for r in rows:
        reasons[r["reason"] or "accepted"] = reasons.get(r["reason"] or "accepted", 0) + 1
    out["reasons"] = reasons
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--episodes-dir", default="episodes/val252")
    ap.add_argument("--scenes-root", default="data/scenes")
    ap.add_argument("--per-house", type=int, default=6)
    ap.add_argument("--cost-episodes", type=int, default=1, help="Wrapper-cost runs per house.")
    ap.add_argument("--pose", action="append", default=[], metavar="FIELD=VALUE",
                    help="Override a GoalPoseConfig field (e.g. min_inliers=8); repeatable.")
    ap.add_argument("--out", default="")
    args = ap.parse_args()
    global POSE
    POSE = dataclasses.replace(POSE, **{k: type(getattr(POSE, k))(v) for k, v in (o.split("=", 1) for o in args.pose)})
    cv2.setNumThreads(1)
    rng = np.random.default_rng(0)
    rows: dict[str, list[dict]] = {"offset": [], "expert_path": [], "other_house": []}
    cost: list[dict] = []
    prev_goal_photo = None
    t0 = time.time()
    for f in sorted(Path(args.episodes_dir).glob("*.json")):
        split, index = f.stem.rsplit("_", 1)
        scene = Scene.load(ensure_house(split, int(index), args.scenes_root))
        eps = read_episodes(f, scene, "paper").episodes[: args.per_house]
        env = make_env(scene, "paper", episodes=eps)
        for i, ep in enumerate(eps):
            obs, _ = env.reset(options={"episode_index": i})
            goal = np.asarray(ep.goal_pose, dtype=np.float64)
            est = GoalPoseEstimator(env.task.camera, env.floor_z, POSE)
            est.set_goal(obs["goal"])
            offsets = _offset_poses(goal, env, rng)
            rows["offset"] += [_row(est, env, p, goal) for p in offsets]
            path: list[np.ndarray] = []
            run_episode(env, ExpertAgent(), episode=ep, on_step=lambda s: path.append(np.asarray(s.obs["pose"], float)))
            rows["expert_path"] += [_row(est, env, p, goal) for p in path if np.linalg.norm(p[:2] - goal[:2]) <= 3.0]
            if prev_goal_photo is not None:
                other = GoalPoseEstimator(env.task.camera, env.floor_z, POSE)
                other.set_goal(prev_goal_photo)
                rows["other_house"] += [_row(other, env, p, goal) for p in offsets]
            if i < args.cost_episodes and offsets:
                cost.append(_wrapper_cost(scene, ep, offsets[min(2, len(offsets) - 1)]))
        prev_goal_photo = obs["goal"]
        print(f"{f.stem}: {sum(len(v) for v in rows.values())} frames, {time.time() - t0:.0f} s", flush=True)
    result = {k: _summary(v) for k, v in rows.items()}
    if cost:
        per = {k: [x for c in cost for x in c["cpu"][k]] for k in ("inner", "controller")}
        steps = sum(c["steps"] for c in cost)
        result["wrapper_cost"] = {
            "episodes": len(cost), "steps": steps, "success": round(float(np.mean([c["success"] for c in cost])), 3),
            "cpu_ms_per_step_pooled": round(1000 * (sum(map(sum, per.values())) + sum(c["reset_cpu"] for c in cost)) / steps, 2),
            "cpu_ms_per_step_wrapped_agent_acting": round(1000 * float(np.mean(per["inner"])), 2) if per["inner"] else None,
            "cpu_ms_per_step_controller_driving": round(1000 * float(np.mean(per["controller"])), 2) if per["controller"] else None,
            "cpu_ms_per_reset": round(1000 * float(np.mean([c["reset_cpu"] for c in cost])), 2),
            "control_share": round(len(per["controller"]) / steps, 3),
        }
    result["pose_config"] = dataclasses.asdict(POSE)
    result["load_average"] = os.getloadavg()
    text = json.dumps(result, indent=1)
    print(text)
    if args.out:
        Path(args.out).parent.mkdir(parents=True, exist_ok=True)
        Path(args.out).write_text(text + "\n")


if __name__ == "__main__":
    main()
