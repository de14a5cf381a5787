"""What the agent loop and the agent wrappers may ask of an agent, as protocols.

Every agent is an :class:`Agent` (``reset`` + ``act``). Some offer more, and callers ask with ``isinstance``
against a runtime-checkable protocol (never by probing attribute names):

* :class:`ToldExecuted` — ``executed(action)``: told which action was really executed this step (a wrapper may
  replace the agent's action: noise injection, DAgger's mix, the last-mile controller). The experts' and the
  controllers' blocked-move checks compare against it.
* :class:`Labelling` — ``last_expert_action``: the expert's label for the current state (DAgger's mix, noise
  injection); demonstrations store it as the step's action.
* :class:`BatchedAgent` — ``batch_key()`` and the static ``act_batch(...)``: agents with equal keys act in one
  forward of the lock-step loop (:func:`nue.rollout.run_episodes`).
* :class:`Twinnable` — ``twin()``: another agent on the same model (own recurrent state and sampling), one per
  lock-step slot.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from nue.nerf.online import MemoryMaps
    from nue.sim.env import ImageNavEnv


class Agent(Protocol):
    """Anything that picks actions: an expert, a trained policy, a wrapper around another agent. ``maps``: what the
    memory shows for the current pose (None when the episode runs without a memory)."""

    def reset(self, env: ImageNavEnv, obs: dict[str, np.ndarray], seed: int) -> None: ...

    def act(self, obs: dict[str, np.ndarray], maps: MemoryMaps | None) -> int: ...


@runtime_checkable
class ToldExecuted(Protocol):
    """An agent that wants to know the action executed in its place (its blocked-move check compares with it)."""

    def executed(self, action: int) -> None: ...


@runtime_checkable
class Labelling(Protocol):
    """An agent that holds the expert's label for the current state (set by its last ``act``; None before)."""

    last_expert_action: int | None


@runtime_checkable
class BatchedAgent(Protocol):
    """An agent with a batched forward for the lock-step loop.

    ``act_batch(agents, obs_list, maps_list, rows, positions) -> list[int]`` is a static method: the actions of
    ``agents`` (equal ``batch_key()``) for their observations, in one forward of ``rows`` rows, agent k in row
    ``positions[k]``."""

    def batch_key(self) -> tuple: ...

    @staticmethod
    def act_batch(agents: list[Any], obs_list: list, maps_list: list, rows: int = 0,
                  positions: list[int] | None = None) -> list[int]: ...


@runtime_checkable
class Twinnable(Protocol):
    """An agent that can make another one on the same model (weights shared; own recurrent state and sampling)."""

    def twin(self) -> Agent: ...


def tell_executed(agent: object, action: int) -> None:
    """Tell ``agent`` the executed action if it wants to know (:class:`ToldExecuted`); nothing otherwise."""
    if isinstance(agent, ToldExecuted):
        agent.executed(action)


def expert_label(agent: object) -> int | None:
    """``agent``'s expert label for the current state (:class:`Labelling`), or None if it keeps none."""
    return agent.last_expert_action if isinstance(agent, Labelling) else None
