"""The one agent loop — observe -> render memory maps -> act -> update memory -> step — shared by
demonstration collection, DAgger, evaluation and the demo, so they cannot drift apart.

Order within a step t matters: the memory renders its maps for the current pose *before* frame t
is added to it, so a region seen for the first time shows as uncertain.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Protocol

import numpy as np

from nue.sim.env import ImageNavEnv
from nue.sim.record import EpisodeRecord


class Agent(Protocol):
    """Anything that picks actions: the expert, a trained policy, a mix of both."""

    def reset(self, env: ImageNavEnv, obs: dict[str, np.ndarray], seed: int) -> None: ...

    def act(self, obs: dict[str, np.ndarray], maps: Any) -> int: ...


class Memory(Protocol):
    """The robot's memory (the online NeRF): rendered before it learns from the current frame."""

    def reset(self, seed: int, start_pose: np.ndarray, floor_z: float) -> None: ...

    def render_maps(self, pose: np.ndarray, depth: np.ndarray, floor_z: float) -> Any: ...

    def step(self, rgb: np.ndarray, depth: np.ndarray, pose: np.ndarray, floor_z: float) -> Any: ...


@dataclass
class StepData:
    """What the loop saw and did at step t (handed to ``on_step`` callbacks)."""

    t: int
    obs: dict[str, np.ndarray]
    maps: Any
    action: int
    info: dict[str, Any]
    env: ImageNavEnv


def run_episode(
    env: ImageNavEnv,
    agent: Agent,
    *,
    episode_index: int | None = None,
    episode=None,
    memory: Memory | None = None,
    seed: int = 0,
    on_step: Callable[[StepData], None] | None = None,
    method: str = "",
    reset_options: dict[str, Any] | None = None,
) -> EpisodeRecord:
    """Run one episode to its end and return its record.

    ``seed`` seeds the env's reset (when it draws the episode), the memory's ray sampling and the
    agent's action sampling; ``reset_options`` are further options of the env's reset (e.g. ``goal_image``,
    ``explore_only``).
    """
    options: dict[str, Any] = dict(reset_options or {})
    if episode is not None:
        options["episode"] = episode
    elif episode_index is not None:
        options["episode_index"] = episode_index
    obs, info = env.reset(seed=seed, options=options)
    if memory is not None:
        memory.reset(seed, start_pose=obs["pose"], floor_z=env.floor_z)
    agent.reset(env, obs, seed)
    t = 0
    while True:
        maps = memory.render_maps(obs["pose"], obs["depth"], floor_z=env.floor_z) if memory is not None else None
        action = int(agent.act(obs, maps))
        if on_step is not None:
            on_step(StepData(t, obs, maps, action, info, env))
        if memory is not None:
            memory.step(obs["rgb"], obs["depth"], obs["pose"], floor_z=env.floor_z)
        obs, _, terminated, truncated, info = env.step(action)
        t += 1
        if terminated or truncated:
            break
    return env.episode_record(method=method, seed=seed)
