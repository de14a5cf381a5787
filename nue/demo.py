"""The demo job: one episode per difficulty in a generated validation house, with figures and a table.

Until a trained policy ships, the agent is the geodesic expert; the loop is the shared one
(:func:`nue.rollout.run_episode`), so swapping in NUE changes only the agent and memory.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from nue.evaluate.metrics import aggregate, format_table
from nue.rollout import ExpertAgent, StepData, run_episode
from nue.scene.generator import ensure_house
from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene
from nue.sim.env import ImageNavEnv
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import save_episodes
from nue.sim.renderer import Renderer
from nue.sim.task import get_task
from nue.viz.topdown import save_frames, save_topdown


def run_demo(out: Path, house: int = 0, task_name: str = "paper", seed: int = 0, scenes_root: Path | None = None,
             frames_per_episode: int = 4) -> str:
    """Run the demo; write figures, episodes, records and a metrics table under ``out``; return the table."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scenes_root = Path(scenes_root) if scenes_root else out.parent / "scenes"
    scene = Scene.load(ensure_house("val", house, scenes_root))
    task = get_task(task_name)
    nav = NavGrid.from_scene(scene)
    renderer = Renderer(scene, task.camera)
    episodes = generate_episodes(scene, task, EpisodeGenConfig(per_bin=1), seed=seed, navgrid=nav, renderer=renderer)
    save_episodes(out / "episodes.json", episodes, task)
    env = ImageNavEnv(scene, task, episodes, navgrid=nav, renderer=renderer)
    agent = ExpertAgent()
    records, runs = [], []
    for i, ep in enumerate(episodes):
        frames: list[dict] = []

        def keep(s: StepData) -> None:
            frames.append({"rgb": s.obs["rgb"], "depth": s.obs["depth"], "t": s.t})

        rec = run_episode(env, agent, episode_index=i, seed=seed, on_step=keep, method="expert")
        records.append(rec)
        runs.append({"trajectory": np.array(env.trajectory), "goal": env.goal_xy, "radius": task.success_radius,
                     "label": f"{ep.difficulty}: {'success' if rec.success else 'failure'} in {rec.steps} steps"})
        picks = np.linspace(0, len(frames) - 1, frames_per_episode).round().astype(int)
        save_frames(out / f"frames_{ep.difficulty}.png",
                    [dict(frames[k], title=f"t = {frames[k]['t']}") for k in picks], env.goal_image)
    save_topdown(out / "topdown.png", scene, runs, title=f"{scene.name}: geodesic expert, task '{task.name}'")
    with open(out / "records.jsonl", "w") as f:
        for r in records:
            f.write(json.dumps(r.to_dict()) + "\n")
    table = format_table(aggregate(records))
    (out / "metrics.md").write_text(f"# Demo: {scene.name} ({scene.content_hash}), expert, task {task.name}\n\n{table}\n")
    return table
