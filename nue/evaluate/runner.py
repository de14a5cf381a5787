"""``nue eval``: run policies (or the expert) on the fixed validation episodes, one JSON line per episode.

Every method runs the same episodes with the same per-episode seeds, through the shared agent loop,
with its checkpoint's online NeRF memory (fixed initial weights from the checkpoint). Records are
appended one line at a time (a single ``write`` + ``fsync``) by the one process holding the file's lock;
rerunning the command skips the episodes already recorded, so a killed evaluation resumes. Local worker processes or Ray tasks, as
in ``nue collect``. ``swap_maps`` feeds a policy the memory maps recorded in a *different* episode of
the same house (a control that shows whether the memory is used). Each episode of each method travels
to its worker as an :class:`~nue.evaluate.eval_job.EvalJob`.
"""

from __future__ import annotations

import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path


from nue.errors import CheckpointError, ConfigError, DataError
from nue.evaluate.eval_job import EvalJob, RunSettings
from nue.evaluate.eval_worker import batch_jobs, eval_batch, eval_episode  # noqa: F401  (eval_episode: also the explore benchmark's worker)
from nue.jobs import Job, episode_seed, run_jobs
from nue.output_lock import hold_output
from nue.policy.checkpoint import PolicyHeader, check_compatible, load_header
from nue.policy.commit import COMMIT_PREFIX
from nue.policy.last_mile import COMMIT_LAST_MILE, SLING_PREFIX, LastMileConfig
from nue.scene.generator import SPLITS, ensure_house
from nue.scene.navgrid import NavGrid
from nue.scene.scene import Scene
from nue.sim.episodes import Episode, read_episodes
from nue.sim.task import get_task

EXPERT_METHODS = {"expert": "geodesic", "expert-explore": "explore", "expert-uncertainty": "uncertainty", "random": "random"}
"""Method specs that run an expert (or the random walk) instead of a checkpoint -> ``ExpertAgent(kind=...)``
(``random``: :class:`~nue.policy.agent.RandomAgent`)."""


@dataclass(frozen=True)
class EvalConfig:
    """An evaluation run."""

    episodes_dir: str = "episodes/val"
    """Folder of episode files, one per house (``<house>.json``)."""
    scenes_root: str = "data/scenes"
    """Where the houses are (generated from their fixed seeds if missing)."""
    split: str = "val"
    """House split of episode files whose name does not say it (a file ``<split>_<NN>.json`` of a known split
    is that split's house NN); houses are regenerated from their split's seeds."""
    task: str = "paper"
    """Task preset; a checkpoint trained for another preset is refused."""
    seed: int = 0
    """Base seed; each episode's seed is derived from it and the episode's key."""
    device: str = "cpu"
    """Device of policy and memory in the workers."""
    coverage: bool = True
    """Record the seen floor area after every step (``extra['coverage']``)."""
    swap_maps: bool = False
    """Feed the policy the maps of another episode of the same house (control experiment)."""
    max_episodes: int = 0
    """Use only the first N episodes of each house (0 = all)."""
    per_bin: int = 0
    """Use only the first N episodes of each difficulty bin of each house (0 = all); applied before ``max_episodes``."""
    max_steps: int = 0
    """Override the preset's step limit (0 = keep it); for smoke runs only — records are not comparable."""
    skip_invalid: bool = False
    """Leave out episodes that cannot run (listed by :func:`plan_eval`) instead of refusing their file."""
    last_mile: LastMileConfig = LastMileConfig()
    """Settings of the last-mile wrapper of ``sling+<name>`` methods (stored in their records' settings)."""
    commit: LastMileConfig = COMMIT_LAST_MILE
    """Settings of the wrapper of ``commit+<name>`` methods: the last mile driven on the policy's own goal head
    (:mod:`nue.policy.commit`; stored in their records' settings)."""
    temperature: float = 1.0
    """Sampling temperature of the policies' actions: softmax(logits / temperature) (1 = the paper's eq. 14; 0 =
    argmax; experts are unaffected). Stored in the policies' records' settings when not 1."""
    batch: int = 1
    """Episodes a worker runs side by side in lock step (one batched policy forward per step, a finished episode's
    slot refilled by the next); stored in the records' settings when > 1 (the forward's rounding depends on it)."""


def parse_method(spec: str) -> tuple[str, str | None]:
    """``name=path``, ``path`` (name from the checkpoint's model config), ``expert`` (the geodesic expert)
    or ``expert-explore`` (the exploring expert, ``nue.sim.explorer``). ``sling+name=path`` or ``sling+path``:
    the checkpoint wrapped in the last-mile agent (:class:`~nue.policy.last_mile.LastMileAgent`), named
    ``sling+<name>``; ``commit+name=path`` / ``commit+path`` likewise with the learned locator
    (:mod:`nue.policy.commit`, a model with ``goal_head``)."""
    if spec in EXPERT_METHODS:
        return spec, None
    for prefix in (SLING_PREFIX, COMMIT_PREFIX):
        if spec.startswith(prefix) and "=" not in spec:
            path = spec[len(prefix):]
            if not path.strip():
                raise ConfigError("--checkpoint", f"{spec!r}: expected {prefix}name=path or {prefix}path")
            return prefix + load_header(path).name, path
    if "=" in spec:
        name, path = spec.split("=", 1)
        if not name.strip() or not path.strip():
            raise ConfigError("--checkpoint", f"{spec!r}: expected name=path with a non-empty name and path")
        return name, path
    return load_header(spec).name, spec


def episode_files(folder) -> list[Path]:
    """The episode files of a folder (``*.json``, habitat's ``*.json.gz``), sorted; DataError if none."""
    files = sorted([*Path(folder).glob("*.json"), *Path(folder).glob("*.json.gz")])
    if not files:
        raise DataError(folder, "no episode files (*.json, *.json.gz)")
    return files


def plan_eval(methods: list[str], cfg: EvalConfig, skipped: list | None = None) -> list[Job]:
    """One job per (episode, method). Every episode is validated on its house's navigation grid; with
    ``cfg.skip_invalid`` invalid ones are left out and appended to ``skipped``
    (:class:`~nue.sim.episodes.InvalidEpisode`), else all of a file are named in one error."""
    parsed, checked = parse_methods(methods, cfg.task)
    digests = {ckpt: sha for ckpt, (_, sha) in checked.items()}
    swap = "+swap" if cfg.swap_maps else ""
    files = episode_files(cfg.episodes_dir)
    jobs = []
    for f in files:
        folder = house_folder(f.name.removesuffix(".gz").removesuffix(".json"), cfg.scenes_root, cfg.split)
        scene = Scene.load(folder)
        for ckpt, (header, _) in checked.items():  # a house whose content changed since training is refused here
            check_compatible(header, ckpt, scenes={scene.name: scene.content_hash})
        loaded = read_episodes(f, scene, cfg.task, navgrid=NavGrid.from_scene(scene), skip_invalid=cfg.skip_invalid)
        if skipped is not None:
            skipped.extend(loaded.skipped)
        eps = loaded.episodes
        if cfg.per_bin:
            eps = [eps[i] for i in first_per_bin(eps, cfg.per_bin)]
        if cfg.max_episodes:
            eps = eps[: cfg.max_episodes]
        for i, ep in enumerate(eps):
            other = eps[(i + 1) % len(eps)] if cfg.swap_maps else None
            for method, ckpt in parsed:
                last_mile = None
                if ckpt is not None and method.startswith(SLING_PREFIX):
                    last_mile = cfg.last_mile
                elif ckpt is not None and method.startswith(COMMIT_PREFIX):
                    last_mile = cfg.commit
                settings = run_settings(cfg, digests.get(ckpt, method), ep, scene.content_hash, last_mile,
                                        temperature=cfg.temperature if ckpt is not None else 1.0)
                jobs.append(Job(f"{method}{swap}/{scene.name}/{ep.episode_id}", EvalJob(
                    method=method + swap, checkpoint=ckpt, expert=EXPERT_METHODS.get(method, "") if ckpt is None else "",
                    scene=str(folder), episode=ep, other=other, task=cfg.task,
                    seed=episode_seed(cfg.seed, scene.name, ep.episode_id), device=cfg.device, coverage=cfg.coverage,
                    max_steps=cfg.max_steps, settings=settings, last_mile=last_mile, temperature=settings.temperature)))
    return jobs


def first_per_bin(episodes, per_bin: int) -> list[int]:
    """Indices of the first ``per_bin`` episodes of each difficulty bin (all for 0), in file order."""
    taken: dict[str, int] = {}
    out = []
    for i, ep in enumerate(episodes):
        if not per_bin or taken.get(ep.difficulty, 0) < per_bin:
            taken[ep.difficulty] = taken.get(ep.difficulty, 0) + 1
            out.append(i)
    return out


def house_folder(name: str, scenes_root, split: str = "val") -> Path:
    """The scene folder of an episode file's or record's house ``name``: ``<split>_<NN>`` of a known split (else of
    ``split``) is that split's generated house NN (generated under ``scenes_root`` if missing); any other name is
    the folder ``scenes_root/name``."""
    try:
        prefix, index = name.rsplit("_", 1)  # <split>_<NN>: a generated house of that split
        return ensure_house(prefix if prefix in SPLITS else split, int(index), scenes_root)
    except (ValueError, IndexError):
        return Path(scenes_root) / name


def parse_methods(methods: list[str], task: str) -> tuple[list[tuple[str, str | None]], dict[str, tuple[PolicyHeader, str]]]:
    """``(name, checkpoint or None)`` per method spec (:func:`parse_method`; a name given twice is refused) and
    :func:`checked_checkpoint` of each checkpoint."""
    parsed = [parse_method(m) for m in methods]
    names = [name for name, _ in parsed]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError("--checkpoint", f"method name {twice[0]!r} given twice; name them apart with name=path")
    checked = {ckpt: checked_checkpoint(ckpt, task) for _, ckpt in parsed if ckpt is not None}
    for name, ckpt in parsed:
        if ckpt is not None and name.startswith(COMMIT_PREFIX) and not checked[ckpt][0].model.goal_head:
            raise ConfigError(ckpt, f"{name!r} needs a model with a goal head (e.g. preset nue_goal); "
                                    f"{checked[ckpt][0].model.name!r} has none")
    return parsed, checked


def checked_checkpoint(path: str, task: str) -> tuple[PolicyHeader, str]:
    """Check a checkpoint once in the driver (readable, finite weights, trained for ``task``) before any
    episode runs (:func:`plan_eval` then checks each house against it); returns its header and
    :func:`file_sha256`."""
    header = load_header(path)
    check_compatible(header, path, task=get_task(task))
    return header, file_sha256(path)


def file_sha256(path: str) -> str:
    """sha256 (16 hex digits) of a file's bytes; a checkpoint's identity for resuming."""
    h = hashlib.sha256()
    try:
        with open(path, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    except OSError as e:
        raise CheckpointError(path, f"cannot read ({e.strerror or e})") from None
    return h.hexdigest()[:16]


def run_settings(cfg: EvalConfig, agent: str, episode: Episode, scene_hash: str,
                 last_mile: LastMileConfig | None = None, temperature: float = 1.0) -> RunSettings:
    """The :class:`RunSettings` of one episode of a run: the checkpoint's content hash (or the expert's
    name), task preset, step limit, seed, maps swap, coverage, the episode itself, the scene's content hash,
    the last-mile wrapper's settings (``sling+`` methods), the policy's action temperature and the lock-step batch
    size."""
    return RunSettings(agent=agent, task=cfg.task, max_steps=cfg.max_steps, seed=cfg.seed, swap_maps=cfg.swap_maps,
                       coverage=cfg.coverage, episode=RunSettings.episode_digest(episode), scene=scene_hash,
                       last_mile=None if last_mile is None else last_mile.to_dict(), temperature=temperature,
                       batch=cfg.batch)


def recorded_settings(path: Path) -> dict[str, dict | None]:
    """Record key -> its stored run settings (None for records made before settings were stored)."""
    return {r["extra"]["key"]: r["extra"].get("settings") for r in _read_records(path)}


def check_resumable(path: Path, jobs: list[Job]) -> set[str]:
    """Keys of ``jobs`` already recorded in ``path`` with the same settings; raises :class:`DataError`
    if any of them was recorded with different settings (never silently reused)."""
    old = recorded_settings(path)
    clash: dict[str, list[str]] = {}
    for job in jobs:
        if job.key not in old:
            continue
        diff = job.payload.settings.differences(old[job.key])
        if diff:
            clash.setdefault(", ".join(diff), []).append(job.key)
    if clash:
        why, keys = next(iter(clash.items()))
        n = sum(len(v) for v in clash.values())
        raise DataError(path, f"{n} recorded episode(s) were run with other settings ({why} differ, e.g. "
                              f"{keys[0]}); use another --out or another method name")
    return {job.key for job in jobs if job.key in old}


def _read_records(path: Path) -> list[dict]:
    if not path.is_file():
        return []
    done_keys(path)  # cut a torn last line
    out = []
    for i, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            rec = json.loads(line)
            rec["extra"]["key"]
        except (ValueError, KeyError, TypeError):
            raise DataError(path, f"line {i} is not an evaluation record") from None
        out.append(rec)
    return out


def done_keys(path: Path) -> set[str]:
    """Keys of the records in a JSONL file; a torn last line (killed mid-write) is cut off."""
    if not path.is_file():
        return set()
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        data = data[: data.rfind(b"\n") + 1]
        with open(path, "r+b") as f:
            f.truncate(len(data))
    keys = set()
    for line in data.decode().splitlines():
        if line.strip():
            keys.add(json.loads(line)["extra"]["key"])
    return keys


def append_record(path: Path, record: dict) -> None:
    """Append one JSON line with a single write and fsync it."""
    append_lines(path, [record])


def append_lines(path: Path, dicts: list[dict]) -> None:
    """Append one JSON line per dict with a single write and fsync them (all or, killed mid-write, a torn last line)."""
    line = "".join(json.dumps(d, sort_keys=True) + "\n" for d in dicts).encode()
    fd = os.open(path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
    try:
        os.write(fd, line)
        os.fsync(fd)
    finally:
        os.close(fd)


def run_eval(methods: list[str], out, cfg: EvalConfig, workers: int = 1, ray_address: str | None = None,
             progress: bool = True, skipped: list | None = None) -> Path:
    """Evaluate ``methods`` (checkpoint paths, ``name=path`` or ``expert``); records appended to ``out``, which
    this process holds for the whole run (:func:`~nue.output_lock.hold_output`: a second writer stops at once).
    Episodes left out by ``cfg.skip_invalid`` are appended to ``skipped``."""
    if cfg.batch < 1:
        raise ConfigError("--batch", f"must be >= 1, got {cfg.batch}")
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with hold_output(out):
        jobs = plan_eval(methods, cfg, skipped)
        done = check_resumable(out, jobs)
        if cfg.batch == 1:
            run_jobs(jobs, eval_episode, on_result=lambda job, rec: append_record(out, rec),
                     is_done=lambda job: job.key in done, workers=workers, ray_address=ray_address, desc="eval",
                     progress=progress)
        else:
            todo = [j for j in jobs if j.key not in done]
            run_jobs(batch_jobs(todo, cfg.batch), eval_batch, on_result=lambda job, rec: append_record(out, rec),
                     workers=workers, ray_address=ray_address, desc="eval", progress=progress, stream=True,
                     total=len(todo))
    return out
