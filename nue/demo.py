"""The demo job: a trained agent (or the expert) in a validation house, one episode per difficulty.

With a checkpoint (default ``checkpoints/nue.pt`` when it exists) the agent is that policy with its
online NeRF memory; without one it is the geodesic expert, with the memory running alongside for
the figures. The loop is the shared one (:func:`nue.rollout.run_episode`). Writes under ``out``:
``topdown.png``, per difficulty ``frames_*.png`` (RGB / depth), ``fig6_*.png`` (uncertainty over
time), ``fig7_*.png`` (predicted vs true goal direction) and ``episode_*.gif``, plus
``fig8_gradcam.png`` (Grad-CAM of the uncertainty branch), ``records.jsonl`` and ``metrics.md``.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np

from nue.evaluate.coverage import CoverageTracker
from nue.evaluate.metrics import aggregate, format_table
from nue.nerf.online import OnlineNeRF
from nue.policy.agent import ExpertAgent
from nue.policy.checkpoint import load_agent
from nue.rollout import StepData, run_episode
from nue.scene.generator import ensure_house
from nue.scene.scene import Scene
from nue.sim.env import ImageNavEnv, make_env
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import Episode, load_episodes, save_episodes
from nue.sim.task import get_task
from nue.viz.figures import (fig6_uncertainty_timeline, fig7_goal_direction, fig8_gradcam, gradcam_uncertainty,
                             save_episode_gif, save_figure)
from nue.viz.topdown import save_frames, save_topdown
from nue.viz.trace import TraceRecorder

DEFAULT_CHECKPOINT = Path("checkpoints/nue.pt")


def _episodes(env: ImageNavEnv, task, seed: int, episodes_dir: Path):
    """One episode per difficulty: the first of each bin in the committed validation file, if any."""
    scene = env.scene
    path = episodes_dir / f"{scene.name}.json"
    if path.is_file():
        eps = load_episodes(path, scene, task)
    else:
        eps = generate_episodes(scene, task, EpisodeGenConfig(per_bin=1), seed=seed, navgrid=env.navgrid,
                                renderer=env.renderer)
    first: dict[str, Episode] = {}
    for e in eps:
        first.setdefault(e.difficulty, e)
    return [first[b] for b in task.bins.names if b in first]


def run_demo(out: Path, house: int = 0, task_name: str = "paper", seed: int = 0, scenes_root: Path | None = None,
             checkpoint: Path | None = None, max_steps: int = 0, episodes_dir: Path = Path("episodes/val"),
             frames_per_episode: int = 4, use_default_checkpoint: bool = True) -> str:
    """Run the demo; write figures, records and a metrics table under ``out``; return the table."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    scenes_root = Path(scenes_root) if scenes_root else out.parent / "scenes"
    if checkpoint is None and use_default_checkpoint and DEFAULT_CHECKPOINT.is_file():
        checkpoint = DEFAULT_CHECKPOINT
    scene = Scene.load(ensure_house("val", house, scenes_root))
    env = make_env(scene, task_name, max_steps)
    task = env.task
    episodes = _episodes(env, get_task(task_name), seed, Path(episodes_dir))
    save_episodes(out / "episodes.json", episodes, task)

    model = None
    if checkpoint is not None:
        agent, memory = load_agent(checkpoint, task, scenes={scene.name: scene.content_hash}, memory=True)
        model, method = agent.model, agent.model.config.name
    else:
        memory, agent, method = OnlineNeRF("fast", task.camera), ExpertAgent(), "expert"

    records, runs = [], []
    cams: list = []
    for ep in episodes:
        frames: list[dict] = []
        inputs: dict[int, object] = {}
        recorder = TraceRecorder(aux_source=(lambda s: agent.last_aux) if model is not None else None)
        coverage = CoverageTracker(task.camera, env.navgrid, env.floor_z)

        def on_step(s: StepData) -> None:
            recorder(s)
            coverage(s)
            frames.append({"rgb": s.obs["rgb"], "depth": s.obs["depth"], "t": s.t})
            if model is not None and s.t % 10 == 0:
                inputs[s.t] = agent.last_input

        rec = run_episode(env, agent, episode=ep, memory=memory, seed=seed, on_step=on_step, method=method)
        rec = dataclasses.replace(rec, extra={**rec.extra, "coverage": coverage.areas})
        records.append(rec)
        trace = recorder.finish(env)
        d = ep.difficulty
        runs.append({"trajectory": trace.trajectory(), "goal": env.goal_xy, "radius": task.success_radius,
                     "label": f"{d}: {'success' if rec.success else 'failure'} in {rec.steps} steps"})
        picks = np.linspace(0, len(frames) - 1, frames_per_episode).round().astype(int)
        save_frames(out / f"frames_{d}.png", [dict(frames[k], title=f"t = {frames[k]['t']}") for k in picks],
                    env.goal_image)
        save_figure(fig6_uncertainty_timeline(scene, trace.trajectory(), trace.i_u + [None], env.goal_xy,
                                              task.success_radius), out / f"fig6_{d}.png")
        if model is not None and model.config.use_aux:
            fig = fig7_goal_direction(trace.pose_array(), trace.aux_array(), trace.goal_angle_array(), scene=scene,
                                      goal_xy=env.goal_xy, success_radius=task.success_radius)
            save_figure(fig, out / f"fig7_{d}.png")
        save_episode_gif(out / f"episode_{d}.gif", trace, scene)
        if model is not None and model.config.uses_i_u and not cams:
            cams = _gradcams(model, inputs)
    if cams:
        save_figure(fig8_gradcam([c[0] for c in cams], [c[1] for c in cams], [c[2] for c in cams]), out / "fig8_gradcam.png")
    save_topdown(out / "topdown.png", scene, runs, title=f"{scene.name}: {method}, task '{task.name}'")
    with open(out / "records.jsonl", "w") as f:
        for r in records:
            f.write(json.dumps(r.to_dict()) + "\n")
    table = format_table(aggregate(records))
    (out / "metrics.md").write_text(f"# Demo: {scene.name} ({scene.content_hash}), {method}, task {task.name}\n\n{table}\n")
    return table


def _gradcams(model, inputs: dict) -> list:
    """(I_u, Grad-CAM, title) at up to three recorded steps of an episode."""
    steps = sorted(inputs)
    picks = [steps[i] for i in sorted({0, len(steps) // 2, len(steps) - 1})] if steps else []
    out = []
    for t in picks:
        inp = inputs[t]
        out.append((np.log1p(inp.i_u[0, 0].cpu().numpy()), gradcam_uncertainty(model, inp), f"t = {t}"))
    return out
