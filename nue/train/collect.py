"""``nue collect``: expert (or DAgger) episodes in the training houses with the online NeRF memory
running exactly as at test time; one checksummed, memory-mappable file per episode plus a manifest.

Per step an episode file holds what the policy consumes: ``rgbd`` (T, 4, fh, fw) (already normalised by
``prepare_input``; 8-bit codes), ``i_u`` (T, 1, h, w) float16 and ``i_cog`` (T, 64, h, w) (4-bit codes) —
the compact storage of :class:`~nue.train.compact.StepStorage`, older collections hold float16 — the
expert's ``action`` label and the ``executed`` action (T,) int8, ``goal_angle`` (T,) float32,
``pose`` (T, 3) float32 and ``geodesic`` (T,) float32 (the geodesic distance to the goal, NRNS's training label;
collections made before it existed lack it); per episode the goal photo at map and frame size (3, ., .) float16.
Episodes are written by the driver as they finish (temporary file + rename); rerunning the same
command skips finished episodes, so a killed collection resumes without duplicates. What the folder
holds is described by its manifest (:mod:`nue.train.manifest`); each episode travels to its worker as
a :class:`~nue.train.collect_job.CollectJob`.
"""

from __future__ import annotations

import dataclasses
import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from nue.errors import ConfigError, DataError
from nue.jobs import Job, episode_seed, run_jobs, worker_cached
from nue.nerf.config import MemoryConfig, get_memory
from nue.nerf.online import OnlineNeRF
from nue.output_lock import hold_output
from nue.policy.agent import EXPERT_KINDS, ExpertAgent, MixedAgent, NoisyAgent
from nue.policy.checkpoint import load_agent
from nue.policy.config import get_model_config
from nue.policy.inputs import prepare_input, resize_area
from nue.policy.protocols import expert_label
from nue.rollout import run_episode
from nue.scene.generator import SPLITS, TRAINING_SPLITS, ensure_house
from nue.scene.scene import Scene
from nue.sim.env import make_env
from nue.sim.seen import goal_in_view
from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
from nue.sim.episodes import Episode, load_episodes, save_episodes
from nue.sim.task import get_task
from nue.train.collect_job import AgentSpec, CollectJob
from nue.train.compact import QuantizedArray, StepStorage
from nue.train.episode_file import read_header, write_episode_file
from nue.train.manifest import CollectionManifest, DataLayout, read_manifest, write_manifest


@dataclass(frozen=True)
class CollectConfig:
    """What a demonstration collection contains."""

    task: str = "paper"
    """Task preset."""
    memory: str | MemoryConfig = "fast"
    """Memory (NeRF) preset name, or a full config (e.g. a manifest's), run online exactly as at test time."""
    model: str = "nue"
    """Model preset whose input layout (frame size, map size, depth scale) the data is stored in."""
    split: str = "train"
    """Generated house split to collect in: ``train`` (21 houses of the ``gibson`` style) or ``train_diverse`` (42
    houses, a style drawn per house, docs/styles.md); the validation splits are for evaluation only."""
    houses: tuple[int, ...] = ()
    """Indices of the houses of the split to use; empty = all."""
    scene_dirs: tuple[str, ...] = ()
    """Explicit scene folders (e.g. your own Gibson scans) instead of the generated split."""
    episodes_per_bin: int = 16
    """Training episodes per difficulty bin per house."""
    heldout_per_bin: int = 2
    """Held-out episodes per bin per house, for model selection (never the validation houses)."""
    subsample_per_bin: int = 0
    """Use only the first k of the ``episodes_per_bin`` training episodes of each bin (0 = all); DAgger
    rounds revisit a subset of the expert collection's episodes this way."""
    seed: int = 0
    """Seed of episode sampling and of each episode's memory / action sampling."""
    device: str = "cpu"
    """Device of the NeRF memory in the workers."""
    agent: AgentSpec = AgentSpec()
    """Who drives: the expert, or DAgger's mix (``AgentSpec.dagger``: a checkpoint, ``beta`` and the expert
    collection whose step counts cap policy control at ``max_factor`` x; the expert finishes)."""
    memory_lag: int = 0
    """Override the memory's ``lag`` (frames join the NeRF this many steps late); 0 = keep the preset's."""
    expert: str = "geodesic"
    """Which expert drives (``expert``) or labels (``dagger``): ``geodesic`` (shortest path to the goal it
    knows) or ``explore`` (frontiers of its own seen map until the goal is in view, then geodesic)."""
    noise: float = 0.0
    """DART-style noise injection: probability that the executed action is replaced by a random move; the
    label stays the expert's (0 = none)."""

    def __post_init__(self) -> None:
        if self.expert not in EXPERT_KINDS:
            raise DataError(None, f"unknown expert {self.expert!r}; known: {', '.join(EXPERT_KINDS)}")
        if not 0.0 <= self.noise < 1.0:
            raise DataError(None, f"noise must be in [0, 1), got {self.noise}")


def plan_collection(cfg: CollectConfig, scenes_root: Path) -> tuple[list[Job], CollectionManifest]:
    """Houses, episodes (generated once, stored under ``episodes/``) and the manifest of a collection;
    each job's payload is a :class:`CollectJob`."""
    task = get_task(cfg.task)
    model_cfg = get_model_config(cfg.model).for_task(task)
    memory = get_memory(cfg.memory)
    if cfg.memory_lag:
        memory = memory.replace(lag=cfg.memory_lag)
    if tuple(memory_map := (memory.map_height, memory.map_width)) != tuple(model_cfg.map_size):
        raise DataError(None, f"memory preset {memory.name!r} renders maps at {memory_map}, model {model_cfg.name!r} "
                              f"expects {model_cfg.map_size}")
    if not cfg.scene_dirs and cfg.split not in TRAINING_SPLITS:
        raise ConfigError("split", f"{cfg.split!r} is not a training split; one of {', '.join(TRAINING_SPLITS)}")
    if cfg.scene_dirs:
        scenes = [Scene.load(d) for d in cfg.scene_dirs]
    else:
        indices = cfg.houses or tuple(range(len(SPLITS[cfg.split])))
        scenes = [Scene.load(ensure_house(cfg.split, i, scenes_root)) for i in indices]
    manifest = CollectionManifest(
        task=task.name, memory=memory, model_layout=DataLayout.of(model_cfg), split=cfg.split,
        scenes={s.name: s.content_hash for s in scenes}, episodes_per_bin=cfg.episodes_per_bin,
        heldout_per_bin=cfg.heldout_per_bin, seed=cfg.seed, subsample_per_bin=cfg.subsample_per_bin, agent=cfg.agent,
        expert=cfg.expert, noise=cfg.noise)
    jobs = []
    for s in scenes:
        for part, per_bin, seed in (("train", cfg.episodes_per_bin, cfg.seed), ("heldout", cfg.heldout_per_bin, cfg.seed + 7919)):
            if per_bin <= 0:
                continue
            episodes = _episodes_for(s, task, per_bin, seed, scenes_root)
            if part == "train" and cfg.subsample_per_bin:
                episodes = _first_per_bin(episodes, cfg.subsample_per_bin)
            for ep in episodes:
                key = f"{part}/{s.name}/{ep.episode_id}"
                expert_steps = 0
                if cfg.agent.kind == "dagger":
                    expert_file = episode_path(Path(cfg.agent.expert_steps_from), key)
                    expert_steps = read_header(expert_file)[0]["meta"]["steps"] if expert_file.is_file() else 0
                jobs.append(Job(key, CollectJob(
                    scene=str(s.path), episode=ep, task=task.name, memory=memory, model=cfg.model,
                    seed=episode_seed(cfg.seed, s.name, key), device=cfg.device, agent=cfg.agent, expert=cfg.expert,
                    noise=cfg.noise, expert_steps=expert_steps)))
    return jobs, manifest


def _first_per_bin(episodes: list[Episode], k: int) -> list[Episode]:
    """The first ``k`` episodes of each difficulty bin, in the original order."""
    seen: dict[str, int] = {}
    kept = []
    for ep in episodes:
        seen[ep.difficulty] = seen.get(ep.difficulty, 0) + 1
        if seen[ep.difficulty] <= k:
            kept.append(ep)
    return kept


def _episodes_for(scene, task, per_bin: int, seed: int, scenes_root: Path) -> list[Episode]:
    path = scenes_root / "episodes" / f"{scene.name}_{task.name}_s{seed}_n{per_bin}.json"
    if path.is_file():
        eps = load_episodes(path, scene, task)
    else:
        eps = generate_episodes(scene, task, EpisodeGenConfig(per_bin=per_bin), seed=seed)
        save_episodes(path, eps, task)
    return list(eps)


def episode_path(out: Path, key: str) -> Path:
    return out / f"{key}.nue"


def is_complete(path: Path) -> bool:
    """A finished episode file (complete header and size; a damaged one is redone)."""
    if not path.is_file():
        return False
    try:
        read_header(path)
        return True
    except DataError:
        return False


def collect(out, cfg: CollectConfig, scenes_root, workers: int = 1, ray_address: str | None = None,
            progress: bool = True, storage: StepStorage = StepStorage()) -> CollectSummary:
    """Run (or resume) a collection into ``out``; returns its :class:`CollectSummary` (episodes, steps, bytes per
    step), also written to ``out/summary.json``.

    ``storage`` says how the step arrays are encoded (compact by default; all bits 0 = float16). It is not
    part of the manifest — the content is the same whatever the encoding, as after ``nue convert`` — but
    ``out/storage.json`` records it and a resumed collection refuses another one (DataError)."""
    out, scenes_root = Path(out), Path(scenes_root)
    with hold_output(out):  # one writer per collection folder
        jobs, manifest = plan_collection(cfg, scenes_root)
        write_manifest(out, manifest)
        _check_storage(out, storage)
        jobs = [Job(j.key, dataclasses.replace(j.payload, storage=storage)) for j in jobs]
        run_jobs(jobs, collect_episode, on_result=lambda job, res: _write(out, job, res),
                 is_done=lambda job: is_complete(episode_path(out, job.key)), workers=workers,
                 ray_address=ray_address, desc="collect", progress=progress)
        return summarize_collection(out, jobs)


def _check_storage(out: Path, storage: StepStorage) -> None:
    """Record ``storage`` in ``out/storage.json``, or refuse one that differs from the recorded encoding."""
    path = out / "storage.json"
    want = dataclasses.asdict(storage)
    if path.is_file():
        try:
            have = json.loads(path.read_text())
        except ValueError as exc:
            raise DataError(path, f"unreadable ({exc})") from None
        if have != want:
            raise DataError(path, f"the collection was started with storage {have}; this run asks for {want} "
                                  "(use another --out, or `nue convert` afterwards)")
        return
    path.write_text(json.dumps(want) + "\n")


def _write(out: Path, job: Job, result) -> None:
    arrays, meta = result
    write_episode_file(episode_path(out, job.key), arrays, meta)


@dataclass(frozen=True)
class CollectSummary:
    """What a collection holds when :func:`collect` returns; ``summary.json`` in the folder is its :meth:`to_dict`."""

    episodes: int
    """Episode files of the collection."""
    steps: int
    """Steps over all of them."""
    bytes: int
    """Size of the episode files."""
    bytes_per_step: float
    expert_success_rate: float
    """Share of the episodes that ended in success (the agent that drove them: expert, or DAgger's mix)."""
    manifest_hash: str
    """:meth:`~nue.train.manifest.CollectionManifest.hash` of the folder's manifest."""
    storage: dict | None = None
    """The step arrays' encoding as ``storage.json`` records it (``StepStorage`` fields), None if it has none."""

    def to_dict(self) -> dict:
        """The JSON form (``summary.json``, a reproduce stage's summary): ``storage`` only when recorded."""
        d = {"episodes": self.episodes, "steps": self.steps, "bytes": self.bytes, "bytes_per_step": self.bytes_per_step,
             "expert_success_rate": self.expert_success_rate, "manifest_hash": self.manifest_hash}
        if self.storage is not None:
            d["storage"] = dict(self.storage)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "CollectSummary":
        """The summary of its JSON form."""
        storage = d.get("storage")
        return cls(episodes=d["episodes"], steps=d["steps"], bytes=d["bytes"], bytes_per_step=d["bytes_per_step"],
                   expert_success_rate=d["expert_success_rate"], manifest_hash=d["manifest_hash"],
                   storage=dict(storage) if storage is not None else None)


def summarize_collection(out: Path, jobs) -> CollectSummary:
    """Count the episode files of ``jobs`` in ``out`` and write ``out/summary.json``."""
    steps = total = 0
    succ = 0
    for job in jobs:
        header, _ = read_header(episode_path(out, job.key))
        steps += header["meta"]["steps"]
        succ += bool(header["meta"]["success"])
        total += episode_path(out, job.key).stat().st_size
    storage = json.loads((out / "storage.json").read_text()) if (out / "storage.json").is_file() else None
    summary = CollectSummary(episodes=len(jobs), steps=steps, bytes=total, bytes_per_step=total / max(steps, 1),
                             expert_success_rate=succ / max(len(jobs), 1), manifest_hash=read_manifest(out).hash(),
                             storage=storage)
    (out / "summary.json").write_text(json.dumps(summary.to_dict(), indent=1) + "\n")
    return summary


# ------------------------------------------------------------------------------------------- worker
def _worker_objects(job: CollectJob):
    """The job's env and memory (the manifest's config, its own initial weights), built once per worker."""
    env = worker_cached(("env", job.scene, job.task), lambda: make_env(job.scene, job.task))
    memory = worker_cached(("memory", job.memory, job.device),
                           lambda: OnlineNeRF(job.memory, env.task.camera, device=job.device))
    return env, memory


def collect_episode(job: Job):
    """Worker: run one episode with the memory online; return (arrays, meta) for its file."""
    p: CollectJob = job.payload
    env, memory = _worker_objects(p)
    episode = p.episode
    model_cfg = get_model_config(p.model).for_task(env.task)
    agent = make_agent(p, env)
    rec = DemoRecorder(model_cfg, agent, storage=p.storage)
    record = run_episode(env, agent, episode=episode, memory=memory, seed=p.seed, on_step=rec, method=p.agent.kind)
    meta = {"key": job.key, "scene": env.scene.name, "scene_hash": env.scene.content_hash,
            "episode_id": episode.episode_id, "difficulty": episode.difficulty, "success": record.success,
            "steps": record.steps, "seed": p.seed, "agent": p.agent_meta(), "record": record.to_dict()}
    return rec.arrays(), meta


def make_agent(job: CollectJob, env):
    """The driving agent of a collection job: the expert or DAgger's mix, wrapped in noise injection."""
    expert = ExpertAgent(kind=job.expert)
    spec = job.agent
    if spec.kind == "expert":
        agent = expert
    else:
        policy, _ = worker_cached(("policy", spec.checkpoint, env.task.name),
                                  lambda: load_agent(spec.checkpoint, env.task, memory=False, greedy=False))
        limit = int(spec.max_factor * job.expert_steps) if job.expert_steps else None
        agent = MixedAgent(policy, expert, spec.beta, policy_steps=limit)
    return NoisyAgent(agent, job.noise, env.task.actions) if job.noise else agent


@dataclass
class DemoRecorder:
    """``on_step`` callback that stores, per step, exactly what the policy consumes plus the labels."""

    config: object
    agent: object
    storage: StepStorage = StepStorage()
    """How the per-step arrays are stored (compact by default)."""
    steps: list = field(default_factory=list)
    goal: dict | None = None
    panorama: list = field(default_factory=list)
    """Per step the memory's I_u panorama (K, hp, wp) float16, if its preset renders one."""
    view_range: float = 3.0
    """Range of the ``goal_in_view`` label, metres (the exploring expert's switch: ``ExplorerConfig.view_range``)."""
    _goal_cell: tuple[int, int] | None = None

    def __call__(self, s) -> None:
        cfg = self.config
        maps = s.maps
        panorama = getattr(maps, "panorama", None)
        inp = prepare_input(s.obs["rgb"], s.obs["depth"], s.obs["goal"], maps.i_u, maps.i_cog, cfg, panorama=panorama)
        label = expert_label(self.agent)
        if panorama is not None:  # memory presets with a panorama: kept for the models that read it
            self.panorama.append(panorama.detach().cpu().numpy().astype(np.float16))
        self.steps.append({
            "rgbd": self.storage.encode("rgbd", inp.rgbd.numpy()),
            "i_u": self.storage.encode("i_u", maps.i_u.detach().cpu().numpy()[None]),
            "i_cog": self.storage.encode("i_cog", maps.i_cog.detach().cpu().numpy()[None]),
            "action": s.action if label is None else label,
            "executed": s.action,
            "goal_angle": float(s.info["goal_angle"]),
            "goal_distance": float(s.info["euclidean_distance"]),
            "goal_in_view": self._goal_in_view(s),
            "pose": np.asarray(s.obs["pose"], dtype=np.float32),
            "geodesic": float(s.info["geodesic_distance"]),
        })
        if self.goal is None:  # the goal photo as the map-size (NUE) and frame-size (baselines) inputs see it
            frame_cfg = get_model_config("fr").replace(num_actions=cfg.num_actions, frame_height=cfg.frame_height,
                                                       frame_width=cfg.frame_width, max_depth=cfg.max_depth)
            frame_goal = prepare_input(s.obs["rgb"], s.obs["depth"], s.obs["goal"], None, None, frame_cfg).goal
            goal_map = resize_area(inp.goal, tuple(cfg.map_size))  # at map size whatever the model's goal size
            self.goal = {"goal_map": goal_map[0].numpy().astype(np.float16),
                         "goal_frame": frame_goal[0].numpy().astype(np.float16)}

    def _goal_in_view(self, s) -> bool:
        """The exploring expert's switch test at this step (:func:`nue.sim.seen.goal_in_view`): the label of the
        exploitation heads (the robot sees the goal's floor within ``view_range``)."""
        env = s.env
        goal = np.asarray(env.nav_goal_xy, dtype=np.float64)
        if self._goal_cell is None:
            self._goal_cell = tuple(int(v) for v in env.navgrid.cell_of(goal))
        return goal_in_view(s.obs["depth"], s.obs["pose"], self._goal_cell, goal, env.task.camera, env.navgrid,
                            env.floor_z, self.view_range)

    def arrays(self) -> dict[str, np.ndarray]:
        st = self.steps
        return {
            **{k: _join([x[k] for x in st]) for k in ("rgbd", "i_u", "i_cog")},
            "action": np.array([x["action"] for x in st], dtype=np.int8),
            "executed": np.array([x["executed"] for x in st], dtype=np.int8),
            "goal_angle": np.array([x["goal_angle"] for x in st], dtype=np.float32),
            "goal_distance": np.array([x["goal_distance"] for x in st], dtype=np.float32),
            "goal_in_view": np.array([x["goal_in_view"] for x in st], dtype=np.int8),
            "pose": np.stack([x["pose"] for x in st]),
            "geodesic": np.array([x["geodesic"] for x in st], dtype=np.float32),
            **({"panorama": np.stack(self.panorama)} if self.panorama else {}),
            **self.goal,
        }


def _join(steps: list) -> np.ndarray | QuantizedArray:
    """Per-step (1, ...) arrays, plain or compact, joined along the step axis."""
    return QuantizedArray.concatenate(steps) if isinstance(steps[0], QuantizedArray) else np.concatenate(steps)
