"""The one agent loop — observe -> render memory maps -> act -> update memory -> step — shared by
demonstration collection, DAgger, evaluation and the demo, so they cannot drift apart.

Order within a step t matters: the memory renders its maps for the current pose *before* frame t
is added to it, so a region seen for the first time shows as uncertain.

:func:`run_episodes` runs B episodes side by side in lock step (B "slots"): each step renders the maps of
all running episodes (one call of a slot memory, :class:`nue.nerf.slots.SlotMemory`), asks their agents for
actions (one batched forward for the agents that are :class:`~nue.policy.protocols.BatchedAgent`, the others one
by one), updates the memory (one call) and steps the envs in turn; an episode that ends frees its slot for the next
job of the queue. :func:`run_episode` is its B = 1 case and makes exactly the calls of the plain loop.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator, Protocol

import numpy as np

from nue.policy.protocols import Agent, BatchedAgent
from nue.sim.env import ImageNavEnv
from nue.sim.record import EpisodeRecord

if TYPE_CHECKING:
    from nue.nerf.online import MemoryMaps


class Memory(Protocol):
    """The robot's memory (the online NeRF): rendered before it learns from the current frame."""

    def reset(self, seed: int, start_pose: np.ndarray, floor_z: float) -> None: ...

    def render_maps(self, pose: np.ndarray, depth: np.ndarray, floor_z: float) -> MemoryMaps: ...

    def step(self, rgb: np.ndarray, depth: np.ndarray, pose: np.ndarray, floor_z: float) -> Any: ...


class SlotMemory(Protocol):
    """The memories of B slots behind one interface (:class:`nue.nerf.slots.MemoryList`, the stacked memory):
    each call covers the listed slots at once."""

    slots: int

    def reset_slot(self, i: int, seed: int, start_pose: np.ndarray, floor_z: float) -> None: ...

    def render_maps(self, slots: list[int], poses: list[np.ndarray], depths: list[np.ndarray],
                    floor_zs: list[float]) -> list[MemoryMaps]: ...

    def step(self, slots: list[int], rgbs, depths, poses, floor_zs) -> None: ...


@dataclass
class StepData:
    """What the loop saw and did at step t (handed to ``on_step`` callbacks)."""

    t: int
    obs: dict[str, np.ndarray]
    maps: MemoryMaps | None
    action: int
    info: dict[str, Any]
    env: ImageNavEnv


@dataclass
class EpisodeJob:
    """One episode for :func:`run_episodes`: its env and agent (owned by the episode while it runs: a slot's
    env and agent must not serve two running episodes), what to reset to, and its callbacks."""

    env: ImageNavEnv
    agent: Agent
    seed: int = 0
    """Seeds the env's reset (when it draws the episode), the memory's ray sampling and the agent's actions."""
    episode: Any = None
    """The episode to run (else ``episode_index`` of the env's episodes, else one the env draws)."""
    episode_index: int | None = None
    method: str = ""
    """Written to the record."""
    reset_options: dict[str, Any] | None = None
    """Further options of the env's reset (e.g. ``goal_image``, ``explore_only``)."""
    on_step: Callable[[StepData], None] | None = None
    """Called after the action is chosen, before the memory learns the frame and the env steps."""
    memory: Memory | None = None
    """A memory of this episode alone (used as in the plain loop); None: the loop's slot memory if
    ``slot_memory``, else no memory."""
    slot_memory: bool = False
    """Use the slot memory of :func:`run_episodes` (the slot's part of it) for this episode."""


class _Running:
    """A slot's episode in progress."""

    def __init__(self, index: int, job: EpisodeJob, slot: int, memory: SlotMemory | None):
        self.index, self.job, self.slot, self.t = index, job, slot, 0
        if job.slot_memory and memory is None:
            raise ValueError("an episode asks for the slot memory but run_episodes was given none")
        options: dict[str, Any] = dict(job.reset_options or {})
        if job.episode is not None:
            options["episode"] = job.episode
        elif job.episode_index is not None:
            options["episode_index"] = job.episode_index
        env = job.env
        self.obs, self.info = env.reset(seed=job.seed, options=options)
        if job.memory is not None:
            job.memory.reset(job.seed, start_pose=self.obs["pose"], floor_z=env.floor_z)
        elif job.slot_memory:
            assert memory is not None
            memory.reset_slot(slot, job.seed, self.obs["pose"], env.floor_z)
        job.agent.reset(env, self.obs, job.seed)


def run_episodes(
    jobs: Iterable[EpisodeJob | Callable[[int], EpisodeJob]],
    slots: int = 1,
    memory: SlotMemory | None = None,
    on_done: Callable[[int, EpisodeRecord], None] | None = None,
) -> list[EpisodeRecord]:
    """Run the ``jobs`` on ``slots`` lock-step slots (:func:`lockstep`); returns their records in job order.
    ``on_done(job index, record)`` runs as each episode ends (e.g. to append its record at once)."""
    records: dict[int, EpisodeRecord] = {}
    for index, record in lockstep(jobs, slots, memory):
        records[index] = record
        if on_done is not None:
            on_done(index, record)
    return [records[i] for i in sorted(records)]


def lockstep(
    jobs: Iterable[EpisodeJob | Callable[[int], EpisodeJob]],
    slots: int = 1,
    memory: SlotMemory | None = None,
) -> Iterator[tuple[int, EpisodeRecord]]:
    """Run the ``jobs`` on ``slots`` lock-step slots, yielding ``(job index, record)`` as each episode ends.

    A job is an :class:`EpisodeJob` or a function of the slot index giving one (called when a slot takes the
    job: per-slot envs, agents, trackers). Jobs start in order, each in the lowest free slot, as soon as a
    slot is free. ``memory``: the slots' memory for jobs with ``slot_memory`` (``memory.slots >= slots``).

    With ``slots > 1`` agents that are :class:`~nue.policy.protocols.BatchedAgent` run in one forward per step and group of equal
    ``batch_key()``, always of ``slots`` rows (padded), each in the row of its slot: an episode's numbers depend
    on its own inputs, ``slots`` and (on some CPUs, in the last bit) its slot index, never on the contents of
    the other rows. With ``slots == 1`` every agent's ``act`` is called (the plain loop's arithmetic).
    """
    if slots < 1:
        raise ValueError(f"slots must be >= 1, got {slots}")
    if memory is not None and memory.slots < slots:
        raise ValueError(f"the slot memory has {memory.slots} slots, the loop {slots}")
    queue = iter(enumerate(jobs))
    running: list[_Running | None] = [None] * slots

    def start(slot: int) -> _Running | None:
        nxt = next(queue, None)
        if nxt is None:
            return None
        index, job = nxt
        return _Running(index, job if isinstance(job, EpisodeJob) else job(slot), slot, memory)

    for slot in range(slots):
        running[slot] = start(slot)
    while any(r is not None for r in running):
        active = [r for r in running if r is not None]
        maps = _render(active, memory)
        actions = _act(active, maps, slots)
        for r, m, a in zip(active, maps, actions):
            if r.job.on_step is not None:
                r.job.on_step(StepData(r.t, r.obs, m, a, r.info, r.job.env))
        _learn(active, memory)
        for r, a in zip(active, actions):
            r.obs, _, terminated, truncated, r.info = r.job.env.step(a)
            r.t += 1
            if terminated or truncated:
                record = r.job.env.episode_record(method=r.job.method, seed=r.job.seed)
                running[r.slot] = None
                yield r.index, record
                running[r.slot] = start(r.slot)


def _render(active: list[_Running], memory: SlotMemory | None) -> list[MemoryMaps | None]:
    maps: list[MemoryMaps | None] = [None] * len(active)
    shared = [k for k, r in enumerate(active) if r.job.memory is None and r.job.slot_memory]
    for k, r in enumerate(active):
        if r.job.memory is not None:
            maps[k] = r.job.memory.render_maps(r.obs["pose"], r.obs["depth"], floor_z=r.job.env.floor_z)
    if shared:
        assert memory is not None
        out = memory.render_maps([active[k].slot for k in shared], [active[k].obs["pose"] for k in shared],
                                 [active[k].obs["depth"] for k in shared], [active[k].job.env.floor_z for k in shared])
        for k, m in zip(shared, out):
            maps[k] = m
    return maps


def _act(active: list[_Running], maps: list[MemoryMaps | None], slots: int) -> list[int]:
    actions: list[int | None] = [None] * len(active)
    if slots > 1:
        groups: dict[Any, list[int]] = {}
        for k, r in enumerate(active):
            agent = r.job.agent
            if isinstance(agent, BatchedAgent):
                groups.setdefault((type(agent), agent.batch_key()), []).append(k)
        for (kind, _), ks in groups.items():
            out = kind.act_batch([active[k].job.agent for k in ks], [active[k].obs for k in ks], [maps[k] for k in ks],
                                 rows=slots, positions=[active[k].slot for k in ks])
            for k, a in zip(ks, out):
                actions[k] = int(a)
    for k, r in enumerate(active):
        if actions[k] is None:
            actions[k] = int(r.job.agent.act(r.obs, maps[k]))
    return [int(a) for a in actions]  # type: ignore[arg-type]


def _learn(active: list[_Running], memory: SlotMemory | None) -> None:
    shared = [r for r in active if r.job.memory is None and r.job.slot_memory]
    for r in active:
        if r.job.memory is not None:
            r.job.memory.step(r.obs["rgb"], r.obs["depth"], r.obs["pose"], floor_z=r.job.env.floor_z)
    if shared:
        assert memory is not None
        memory.step([r.slot for r in shared], [r.obs["rgb"] for r in shared], [r.obs["depth"] for r in shared],
                    [r.obs["pose"] for r in shared], [r.job.env.floor_z for r in shared])


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
    """Run one episode to its end and return its record (:func:`run_episodes` with one slot).

    ``seed`` seeds the env's reset (when it draws the episode), the memory's ray sampling and the
    agent's action sampling; ``reset_options`` are further options of the env's reset (e.g. ``goal_image``,
    ``explore_only``).
    """
    job = EpisodeJob(env, agent, seed=seed, episode=episode, episode_index=episode_index, method=method,
                     reset_options=reset_options, on_step=on_step, memory=memory)
    return run_episodes([job], slots=1)[0]

