"""Agent-loop benchmark: ms per step of each part of the shared loop for NUE, NUE on the lean memory (``nue_lean``, when
``results/lean/nue_lean.pt`` exists), FR, the memory baselines VGM and NRNS (when ``results/memory_baselines/`` holds
their checkpoints) and the expert.

Writes ``benchmarks/results/loop.json``. The loop timed is :func:`nue.rollout.run_episode` itself (the
one shared by collection, DAgger, evaluation and the demo) with the evaluation's coverage tracker as its
``on_step``; each part is timed through a thin wrapper around the memory, the agent, the env and the
tracker, so nothing is reimplemented. Per part: the median over every step of the run (NRNS decides at some steps
and drives at the others, so its median ``act`` hides its decisions: compare methods by the wall time per step,
given as a ratio to FR's, ``ratio_to_fr``). The methods run
the same validation episodes (``episodes/val/val_00.json``, in order, until ``--steps`` steps; an episode
is cut at ``--steps``), interleaved ``--repeats`` times, and each method's total is also given as a ratio
to the bare ``env.step`` (the expert run's, which has no memory) measured in the same run, so the ratios
hold on a noisy machine. One torch thread, llvmpipe on one thread.

    python benchmarks/loop.py [--steps 280] [--repeats 2]
"""

from __future__ import annotations

import os

os.environ.setdefault("LP_NUM_THREADS", "1")  # llvmpipe on one core; set before the GL context exists
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402

from nue.evaluate.coverage import CoverageTracker  # noqa: E402
from nue.jobs import episode_seed  # noqa: E402
from nue.policy.agent import ExpertAgent  # noqa: E402
from nue.policy.checkpoint import load_agent  # noqa: E402
from nue.rollout import run_episode  # noqa: E402
from nue.scene.generator import ensure_house  # noqa: E402
from nue.scene.scene import Scene  # noqa: E402
from nue.sim.env import make_env  # noqa: E402
from nue.sim.episodes import load_episodes  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
CHECKPOINTS = {"nue_lean": ROOT / "results" / "lean" / "nue_lean.pt",
               "vgm": ROOT / "results" / "memory_baselines" / "vgm.pt",
               "nrns": ROOT / "results" / "memory_baselines" / "nrns.pt"}
"""Methods whose checkpoint is not ``checkpoints/<name>.pt``: ``nue_lean`` (NUE on the lean memory's 30 x 40 maps,
issue 38; its checkpoint carries the ``lean`` memory preset) and the memory baselines (issue 39)."""
PARTS = ("render_maps", "memory_step", "prepare_input", "policy_forward", "act", "env_step", "coverage")
"""``act`` is the agent's whole decision (``prepare_input`` + forward + sampling for a policy, the
expert's decision for the expert); ``policy_forward`` = ``act`` - ``prepare_input``."""


class Clock:
    """Per-step durations of the loop's parts, seconds."""

    def __init__(self):
        self.times: dict[str, list[float]] = {p: [] for p in PARTS}

    def wrap(self, part: str, fn):
        times = self.times[part]

        def timed(*args, **kwargs):
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            times.append(time.perf_counter() - t)
            return out
        return timed


class TimedMemory:
    """The memory with ``render_maps`` and ``step`` timed (``reset`` is per episode and not timed)."""

    def __init__(self, memory, clock: Clock):
        self.reset = memory.reset
        self.render_maps = clock.wrap("render_maps", memory.render_maps)
        self.step = clock.wrap("memory_step", memory.step)


class TimedAgent:
    """The agent with ``act`` timed (and, for a policy, its ``prepare_input`` inside ``act``)."""

    def __init__(self, agent, clock: Clock):
        self.reset = agent.reset
        self.act = clock.wrap("act", agent.act)
        if hasattr(agent, "policy_input"):
            agent.policy_input = clock.wrap("prepare_input", agent.policy_input)


def run_method(name: str, env, episodes, steps: int, clock: Clock) -> dict:
    """Episodes in order until ``steps`` steps; returns counts and the loop's wall time."""
    if name == "expert":
        agent, memory = ExpertAgent(), None
    else:
        agent, memory = load_agent(CHECKPOINTS.get(name, ROOT / "checkpoints" / f"{name}.pt"), env.task)
    agent_t = TimedAgent(agent, clock)
    memory_t = TimedMemory(memory, clock) if memory is not None else None
    env_step = env.step
    env.step = clock.wrap("env_step", env_step)  # the instance attribute shadows the method for the loop
    done = eps = 0
    wall = 0.0
    try:
        for ep in episodes:
            tracker = CoverageTracker(env.task.camera, env.navgrid, env.floor_z)
            t0 = time.perf_counter()
            run_episode(env, agent_t, episode=ep, memory=memory_t, seed=episode_seed(0, env.scene.name, ep.episode_id),
                        on_step=clock.wrap("coverage", tracker), method=name)
            wall += time.perf_counter() - t0
            done += env.steps
            eps += 1
            if done >= steps:
                break
    finally:
        del env.step
    return {"steps": done, "episodes": eps, "wall_s": wall}


def summarise(clock: Clock, runs: list[dict]) -> dict:
    t = {p: np.asarray(v) * 1000.0 for p, v in clock.times.items()}
    if len(t["prepare_input"]):
        t["policy_forward"] = t["act"] - t["prepare_input"]
    med = {p: float(np.median(v)) for p, v in t.items() if len(v)}
    steps = sum(r["steps"] for r in runs)
    loop_parts = ("render_maps", "memory_step", "act", "env_step", "coverage")
    return {
        "ms_median": med,
        "ms_mean": {p: float(np.mean(v)) for p, v in t.items() if len(v)},
        "sum_of_medians_ms": sum(med.get(p, 0.0) for p in loop_parts),
        "wall_ms_per_step": 1000.0 * sum(r["wall_s"] for r in runs) / steps,
        "steps": steps,
        "episodes": sum(r["episodes"] for r in runs),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=280, help="steps per method and repeat")
    ap.add_argument("--repeats", type=int, default=2, help="interleaved repeats of the three methods")
    default = ["nue", "nue_lean", "fr", "vgm", "nrns", "expert"]
    ap.add_argument("--methods", default=",".join(m for m in default if m not in CHECKPOINTS or CHECKPOINTS[m].exists()))
    args = ap.parse_args()
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    scene = Scene.load(ensure_house("val", 0, ROOT / "data" / "scenes"))
    env = make_env(scene, "paper", args.steps)  # an episode ends after --steps steps at the latest
    warm_env = make_env(scene, "paper", 20)
    episodes = load_episodes(ROOT / "episodes" / "val" / f"{scene.name}.json", scene, env.task)
    methods = args.methods.split(",")
    clocks = {m: Clock() for m in methods}
    runs: dict[str, list[dict]] = {m: [] for m in methods}
    for m in methods:  # warm-up: caches, lazy buffers, first GL frames
        run_method(m, warm_env, episodes[:1], 20, Clock())
    t_start = time.perf_counter()
    for _ in range(args.repeats):
        for m in methods:
            runs[m].append(run_method(m, env, episodes, args.steps, clocks[m]))
    elapsed = time.perf_counter() - t_start
    result = {m: summarise(clocks[m], runs[m]) for m in methods}
    bare = result["expert"]["ms_median"]["env_step"] if "expert" in result else None
    fr_wall = result["fr"]["wall_ms_per_step"] if "fr" in result else None
    for r in result.values():
        r["steps_per_s"] = 1000.0 / r["sum_of_medians_ms"]
        if bare:
            r["ratio_to_bare_env_step"] = r["sum_of_medians_ms"] / bare
        if fr_wall:
            r["ratio_to_fr"] = r["wall_ms_per_step"] / fr_wall
    path = write_result("loop", {
        "scene": scene.name,
        "episodes_file": f"episodes/val/{scene.name}.json",
        "torch_threads": torch.get_num_threads(),
        "loadavg_before": load_before,
        "bare_env_step_ms": bare,
        "targets_ms": {"nue": 16.0, "nue_lean": 12.5, "fr": 8.0},
        "elapsed_s": elapsed,
        "methods": result,
    })
    cols = ("render_maps", "memory_step", "prepare_input", "policy_forward", "act", "env_step", "coverage")
    print("| method | " + " | ".join(cols) + " | total (sum of medians) | steps/s | x bare env.step | wall ms/step "
          "| x FR (wall) |")
    print("|---" * (len(cols) + 6) + "|")
    for m, r in result.items():
        cells = [f"{r['ms_median'][c]:.2f}" if c in r["ms_median"] else "–" for c in cols]
        print(f"| {m} | " + " | ".join(cells) + f" | {r['sum_of_medians_ms']:.2f} | {r['steps_per_s']:.1f} | "
              f"{r.get('ratio_to_bare_env_step', float('nan')):.1f} | {r['wall_ms_per_step']:.2f} | "
              f"{r.get('ratio_to_fr', float('nan')):.2f} |")
    print(f"load average {load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after; {elapsed:.0f} s -> {path}")


if __name__ == "__main__":
    main()
