"""Simulator benchmark: env steps/s with rendering at 180 x 240 on one core, expert planning time.

Writes ``benchmarks/results/sim.json``. Variants run side by side in the same process, so their
ratios hold even on a noisy machine: bare render at 180 x 240 vs 90 x 120, and env.step vs render.
"""

from __future__ import annotations

import os

os.environ.setdefault("LP_NUM_THREADS", "1")  # llvmpipe on one core; set before the GL context exists

import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, median_ms, write_result  # noqa: E402

from nue.policy.agent import ExpertAgent  # noqa: E402
from nue.scene.generator import ensure_house  # noqa: E402
from nue.scene.navgrid import NavGrid  # noqa: E402
from nue.scene.scene import Scene  # noqa: E402
from nue.sim.env import ImageNavEnv  # noqa: E402
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes  # noqa: E402
from nue.sim.renderer import Renderer  # noqa: E402
from nue.sim.task import get_task  # noqa: E402

HOUSES = (0, 1, 2)
EPISODES_PER_BIN = 4


def main() -> None:
    task = get_task("paper")
    per_house = []
    step_times, act_times, plan_times, steps_total = [], [], [], 0
    render_full, render_half = [], []
    for h in HOUSES:
        scene = Scene.load(ensure_house("val", h, CACHE))
        nav = NavGrid.from_scene(scene)
        renderer = Renderer(scene, task.camera)
        small = Renderer(scene, task.camera.scaled(120, 90))
        eps = generate_episodes(scene, task, EpisodeGenConfig(per_bin=EPISODES_PER_BIN), seed=0, navgrid=nav, renderer=renderer)
        pose = eps[0].start_pose
        render_full.append(median_ms(lambda: renderer.render(pose), 100))
        render_half.append(median_ms(lambda: small.render(pose), 100))
        env = ImageNavEnv(scene, task, eps, navgrid=nav, renderer=renderer)
        # Episode: time env.step (render included) apart from the expert's decisions.
        for i, ep in enumerate(eps):
            fresh = NavGrid.from_scene(scene)  # cold caches: planning time includes the geodesic fields
            t0 = time.perf_counter()
            fresh.distance_field(ep.goal_position[:2], comfort=True)
            fresh.distance_field(ep.goal_position[:2])
            field_s = time.perf_counter() - t0
            env.navgrid = fresh
            agent = ExpertAgent()
            obs, _ = env.reset(options={"episode_index": i})
            agent.reset(env, obs)
            act_s = 0.0
            while True:
                t = time.perf_counter()
                a = agent.act(obs, None)
                act_s += time.perf_counter() - t
                t = time.perf_counter()
                obs, _, term, trunc, _ = env.step(a)
                step_times.append(time.perf_counter() - t)
                steps_total += 1
                if term or trunc:
                    break
            plan_times.append(field_s + act_s)
            act_times.append(act_s / env.steps)
        per_house.append({"scene": scene.name, "triangles": renderer.n_triangles})
    step_ms = 1000 * float(np.median(step_times))
    result = {
        "task": task.name,
        "resolution": [task.camera.height, task.camera.width],
        "episodes": len(plan_times),
        "steps": steps_total,
        "env_step_ms_median": step_ms,
        "env_steps_per_s": 1000.0 / step_ms,
        "env_steps_per_s_target": 200,
        "render_ms_180x240": float(np.median(render_full)),
        "render_ms_90x120": float(np.median(render_half)),
        "ratio_render_180x240_over_90x120": float(np.median(render_full) / np.median(render_half)),
        "ratio_env_step_over_render": step_ms / float(np.median(render_full)),
        "expert_act_ms_median": 1000 * float(np.median(act_times)),
        "expert_planning_s_per_episode_median": float(np.median(plan_times)),
        "expert_planning_s_per_episode_max": float(np.max(plan_times)),
        "houses": per_house,
    }
    path = write_result("sim", result)
    print(f"env.step {step_ms:.2f} ms ({1000 / step_ms:.0f} steps/s, target >= 200), render {result['render_ms_180x240']:.2f} ms "
          f"at 180x240 vs {result['render_ms_90x120']:.2f} ms at 90x120; expert planning "
          f"{result['expert_planning_s_per_episode_median'] * 1000:.0f} ms/episode -> {path}")


if __name__ == "__main__":
    main()
