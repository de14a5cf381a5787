"""The worker side of ``nue eval``: one evaluation episode (:func:`eval_episode`) or a queue of them on lock-step
slots (:func:`eval_batch`), with the method's agent and memory built once per worker and the record's extras
(hand-off, coverage, last-mile and NRNS decisions). :mod:`nue.evaluate.runner` plans the jobs and appends the
records.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from nue.errors import CheckpointError
from nue.evaluate.coverage import CoverageTracker, cell_area, explorable_cells
from nue.evaluate.eval_job import EvalJob
from nue.evaluate.handoff import HANDOFF_KEY, GoalSightTracker, geodesic_along, handoff
from nue.jobs import Job, worker_cached
from nue.nerf.config import get_memory
from nue.nerf.online import MemoryMaps, OnlineNeRF
from nue.nerf.slots import slot_memory
from nue.policy.agent import ExpertAgent, RandomAgent
from nue.policy.checkpoint import load_agent
from nue.policy.last_mile import LastMileAgent
from nue.policy.nrns_agent import NRNSAgent
from nue.policy.protocols import Twinnable
from nue.rollout import EpisodeJob, lockstep, run_episode
from nue.sim.env import ImageNavEnv, make_env
from nue.sim.explorer import ExplorerConfig, ExploringExpert

BATCH_EPISODES_PER_SLOT = 8
"""``--batch B``: a worker's lock-step batch is a queue of up to B x this many episodes of one method (fewer: less
idle padding at the batch's end, more: less spread over workers)."""


@dataclass(frozen=True)
class EvalBatch:
    """A queue of episodes of one method that one worker runs on ``slots`` lock-step slots."""

    jobs: tuple[Job, ...]
    """Episode jobs (payload :class:`EvalJob`), in the order the slots take them."""
    slots: int
    """Lock-step slots (``--batch``)."""


def batch_jobs(todo: list[Job], slots: int) -> list[Job]:
    """The episode jobs grouped into :class:`EvalBatch` jobs: per method (in order of first appearance), runs of up
    to ``slots * BATCH_EPISODES_PER_SLOT`` episodes in plan order."""
    by_method: dict[str, list[Job]] = {}
    for job in todo:
        by_method.setdefault(job.payload.method, []).append(job)
    size = slots * BATCH_EPISODES_PER_SLOT
    out = []
    for group in by_method.values():
        for i in range(0, len(group), size):
            part = tuple(group[i:i + size])
            out.append(Job(f"batch/{part[0].key}", EvalBatch(part, slots)))
    return out


class MapReplay:
    """A memory that ignores the current episode and replays maps recorded in another one."""

    def __init__(self, maps: list[MemoryMaps]):
        self.maps = maps

    def reset(self, seed, start_pose, floor_z) -> None:
        self.t = 0

    def render_maps(self, pose, depth, floor_z) -> MemoryMaps:
        m = self.maps[min(self.t, len(self.maps) - 1)]
        self.t += 1
        return m

    def step(self, rgb, depth, pose, floor_z) -> None:
        pass


def _env(job: EvalJob):
    return worker_cached(("env", job.scene, job.task, job.max_steps), lambda: make_env(job.scene, job.task, job.max_steps))


def _policy(job: EvalJob, env):
    """The checkpoint's agent and memory, loaded once per worker (:func:`plan_eval` checked the houses)."""
    return worker_cached(("policy", job.checkpoint, job.device, env.task.name, job.temperature),
                         lambda: load_agent(job.checkpoint, env.task, job.device, temperature=job.temperature))


def eval_episode(job: Job) -> dict:
    """Worker: one episode of one method; returns its record as a dict."""
    p: EvalJob = job.payload
    run = _EpisodeRun(job, slot=0, slots=1)
    t0 = time.perf_counter()
    record = run_episode(run.job.env, run.job.agent, episode=p.episode, memory=run.job.memory, seed=p.seed,
                         method=p.method, on_step=run.job.on_step, reset_options=run.job.reset_options)
    return run.finish(record, time.perf_counter() - t0)


def eval_batch(job: Job):
    """Worker: the episodes of an :class:`EvalBatch` on its lock-step slots; yields each record (a dict) as its
    episode ends (:func:`~nue.rollout.lockstep`)."""
    batch: EvalBatch = job.payload
    runs: dict[int, _EpisodeRun] = {}

    def start(index: int):
        def take(slot: int) -> EpisodeJob:
            run = runs[index] = _EpisodeRun(batch.jobs[index], slot, batch.slots)
            return run.job
        return take

    first: EvalJob = batch.jobs[0].payload
    memory = _batch_memory(first, _env(first), batch.slots)
    for index, record in lockstep([start(i) for i in range(len(batch.jobs))], batch.slots, memory):
        run = runs.pop(index)
        yield run.finish(record, time.perf_counter() - run.t0)


def _slot_env(job: EvalJob, slot: int):
    """The env of lock-step slot ``slot`` for the job's house: slot 0 is the worker's env of the house, the others
    share its scene, navigation grid and renderer (an env holds one episode's state)."""
    base = _env(job)
    if slot == 0:
        return base
    return worker_cached(("env", job.scene, job.task, job.max_steps, slot),
                         lambda: ImageNavEnv(base.scene, base.task, renderer=base.renderer, navgrid=base.navgrid))


def _memory(job: EvalJob, env) -> OnlineNeRF | None:
    """The method's memory in this worker: the checkpoint's (None if its model reads no maps), the uncertainty
    expert's own (default initial weights), else None."""
    if job.checkpoint is not None:
        return _policy(job, env)[1]
    if job.expert == "uncertainty":  # it reads its own memory's panorama (default initial weights)
        return worker_cached(("memory", "fast_pano", job.device, env.task.name), lambda: OnlineNeRF(
            get_memory("fast_pano"), env.task.camera, device=job.device))
    return None


def _batch_memory(job: EvalJob, env, slots: int):
    """The slot memory (:func:`~nue.nerf.slots.slot_memory`) of the job's method for ``slots`` lock-step slots;
    None when it has no memory or replays another episode's maps (``swap_maps``)."""
    base = _memory(job, env)
    if base is None or job.other is not None:
        return None
    return worker_cached(("slot-memory", id(base), slots), lambda: slot_memory(base, slots))


class _EpisodeRun:
    """One evaluation episode's setup (env, agent, memory, trackers: ``job``, an :class:`~nue.rollout.EpisodeJob`)
    and its record's extras (:meth:`finish`), in lock-step slot ``slot`` of ``slots`` (1: the plain loop)."""

    def __init__(self, job: Job, slot: int, slots: int):
        p: EvalJob = job.payload
        self.p, self.slot, self.slots = p, slot, slots
        env = self.env = _env(p) if slots == 1 else _slot_env(p, slot)
        self.extra: dict = {"key": job.key, "seed": p.seed, "checkpoint": p.checkpoint, "settings": p.settings.to_dict()}
        memory: OnlineNeRF | MapReplay | None = _memory(p, env)
        if p.checkpoint is None:
            agent = _expert_agent(p)
        else:
            agent = _policy(p, env)[0]
            self.extra["git_commit"] = agent.git_commit
            if slots > 1:  # one agent per slot on the shared model (own recurrent state and action sampling)
                base = agent
                make = (base.twin if isinstance(base, Twinnable)
                        else lambda: load_agent(p.checkpoint, env.task, p.device, temperature=p.temperature)[0])
                agent = worker_cached(("policy", p.checkpoint, p.device, env.task.name, p.temperature, slot, slots), make)
            if p.other is not None and isinstance(memory, OnlineNeRF):
                recorder = memory
                if slots > 1:  # the slot memory may be in use: record the other episode's maps on a memory of its own
                    recorder = worker_cached(("swap-memory", id(memory)), lambda: _twin_memory(recorder))
                memory = MapReplay(_record_maps(env, recorder, p))
            if p.last_mile is not None:
                agent = LastMileAgent(agent, p.last_mile)
        use_slot_memory = slots > 1 and isinstance(memory, OnlineNeRF)
        self.agent = agent
        self.tracker = CoverageTracker(env.task.camera, env.navgrid, env.floor_z) if p.coverage else None
        self.sight = GoalSightTracker()
        options: dict = {"explore_only": True} if p.explore_only else {}
        if p.goal_episode is not None:
            other = _env(dataclasses.replace(p, scene=p.goal_scene))
            options["goal_image"], _ = other.renderer.render(p.goal_episode.goal_pose, other.floor_z)
        if p.explore_only and self.tracker is not None:
            self.tracker.region = explorable_cells(env.navgrid, p.episode.start_pose[:2])
            self.extra["explorable_area"] = round(cell_area(env.navgrid) * float(np.count_nonzero(self.tracker.region)), 3)
        tracker, sight = self.tracker, self.sight

        def on_step(step) -> None:
            sight(step)
            if tracker is not None:
                tracker(step)

        self.job = EpisodeJob(env, agent, seed=p.seed, episode=p.episode, method=p.method, reset_options=options,
                              on_step=on_step,
                              memory=None if use_slot_memory else memory, slot_memory=use_slot_memory)
        self.t0 = time.perf_counter()

    def finish(self, record, wall_time: float) -> dict:
        """The record as a dict with the evaluation's extras (wall time, hand-off, coverage, ...)."""
        p, env, agent, extra = self.p, self.env, self.agent, self.extra
        extra["wall_time"] = wall_time
        if self.slots > 1:
            extra["slot"] = self.slot
        if not p.explore_only:
            extra[HANDOFF_KEY] = handoff(geodesic_along(record.trajectory().poses, env.navgrid, env.goal_field),
                                         self.sight.first_seen_step, record.success).to_dict()
        if isinstance(getattr(agent, "expert", None), ExploringExpert):
            extra["explorer"] = dict(agent.expert.stats)
        if isinstance(agent, LastMileAgent):
            extra["last_mile"] = agent.summary(goal_xy=env.goal_xy)  # the true goal: for the record's analysis only
        if isinstance(agent, NRNSAgent):
            extra["nrns"] = agent.summary()  # its graph and decisions
        if self.tracker is not None:
            extra["coverage"] = [round(float(a), 3) for a in self.tracker.areas]
            if self.tracker.region is not None:
                extra["coverage_explorable"] = [round(float(a), 3) for a in self.tracker.region_areas]
        d = record.to_dict()
        d["extra"] = {**d["extra"], **extra}
        d["wall_time"] = extra["wall_time"]
        return d


def _twin_memory(memory: OnlineNeRF) -> OnlineNeRF:
    """Another memory like ``memory`` (same config, camera, initial weights, device)."""
    return OnlineNeRF(memory.config, memory.camera, init_state=memory.initial_state(), device=memory.device)


def _expert_agent(job: EvalJob):
    """The expert (or random walk) of an expert method; in the exploration benchmark the exploring expert never
    sees the goal (it is in another house) and explores for the whole run."""
    if job.expert == "random":
        return RandomAgent()
    if job.explore_only and job.expert == "explore":
        return ExpertAgent(kind="explore", explorer=ExplorerConfig(view_range=-1.0, max_explore_steps=10**9))
    return ExpertAgent(kind=job.expert or "geodesic")


def _record_maps(env, memory, job: EvalJob) -> list:
    """Maps the memory renders along the expert's run of the *other* episode (for ``swap_maps``)."""
    maps: list = []
    run_episode(env, ExpertAgent(), episode=job.other, memory=memory, seed=job.seed, on_step=lambda s: maps.append(s.maps))
    if not maps:
        raise CheckpointError(job.checkpoint, "swap_maps: the other episode produced no maps")
    return maps
