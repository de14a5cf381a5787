"""Hand-off files: the :class:`~nue.evaluate.handoff.Handoff` of records made before the evaluation measured it,
recomputed from their trajectories and kept beside the records (the records themselves stay as they were run).

The hand-off file of ``records_<set>.jsonl`` is ``records_<set>.handoff.jsonl`` (:func:`handoff_path`): JSON lines
``{"key": <record key>, "method": ..., "trajectory": <digest>, "handoff": {...}}``, one per record, written one
(scene, method) job at a time with a single ``write`` + ``fsync``; rerunning resumes. :func:`load_records_with_handoff`
merges it into the records (a record's own ``extra['handoff']`` wins); a line whose trajectory digest differs
from its record's (the records were rerun) is refused.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from nue.errors import DataError
from nue.evaluate.handoff import HANDOFF_KEY, handoff_of_record, record_handoff
from nue.jobs import Job, run_jobs, worker_cached
from nue.output_lock import hold_output
from nue.sim.record import EpisodeRecord


@dataclass(frozen=True)
class HandoffJob:
    """The records of one method in one house, to recompute (``jobs.Job.payload``)."""

    scene: str
    """Scene folder."""
    episodes: str
    """The house's episode file."""
    task: str
    """Task preset name."""
    records: tuple
    """The records' dicts (:meth:`EpisodeRecord.to_dict`)."""


def record_key(r: EpisodeRecord) -> str:
    """A record's key (``extra['key']``, else ``method/scene/episode_id``)."""
    return str(r.extra.get("key") or f"{r.method}/{r.scene}/{r.episode_id}")


def handoff_path(records_path) -> Path:
    """The hand-off file beside a records file: ``results/records_val252.jsonl`` -> ``results/records_val252.handoff.jsonl``."""
    p = Path(records_path)
    return p.with_name(p.name.removesuffix(".jsonl") + ".handoff.jsonl")


def trajectory_digest(r: EpisodeRecord) -> str:
    """sha256 (16 hex digits) of a record's stored trajectory (what its hand-off is computed from)."""
    return hashlib.sha256(json.dumps(r.extra.get("trajectory"), sort_keys=True).encode()).hexdigest()[:16]


def read_handoff_file(path) -> dict[str, dict]:
    """Record key -> line of a hand-off file ({} if it does not exist); a torn last line is cut off."""
    path = Path(path)
    if not path.is_file():
        return {}
    data = path.read_bytes()
    if data and not data.endswith(b"\n"):
        data = data[: data.rfind(b"\n") + 1]
        with open(path, "r+b") as f:
            f.truncate(len(data))
    out = {}
    for i, line in enumerate(data.decode().splitlines(), 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
            out[str(d["key"])] = {"trajectory": str(d["trajectory"]), HANDOFF_KEY: dict(d[HANDOFF_KEY])}
        except (ValueError, KeyError, TypeError):
            raise DataError(path, f"line {i} is not a hand-off line") from None
    return out


def attach_handoff(records: Sequence[EpisodeRecord], path) -> list[EpisodeRecord]:
    """``records`` with ``extra['handoff']`` taken from the hand-off file ``path`` where they do not carry one;
    :class:`DataError` for a line computed from another trajectory than its record's."""
    table = read_handoff_file(path)
    out = []
    for r in records:
        line = table.get(record_key(r))
        if line is not None and record_handoff(r) is None:
            if line["trajectory"] != trajectory_digest(r):
                raise DataError(path, f"{record_key(r)}: computed from another run of the episode than its record's "
                                      "(recompute it with nue diagnose --handoff)")
            r = dataclasses.replace(r, extra={**r.extra, HANDOFF_KEY: line[HANDOFF_KEY]})
        out.append(r)
    return out


def load_records_with_handoff(*paths, drop_duplicates: bool = False, on_dropped=None) -> list[EpisodeRecord]:
    """Records of JSON-lines files with their hand-off files (:func:`handoff_path`, where they exist) attached;
    ``drop_duplicates`` and ``on_dropped`` as for :func:`nue.evaluate.diagnose.read_records`."""
    from nue.evaluate.diagnose import read_records

    out: list[EpisodeRecord] = []
    for p in paths:
        recs = read_records(p, drop_duplicates=drop_duplicates, on_dropped=on_dropped)
        out += attach_handoff(recs, handoff_path(p)) if handoff_path(p).is_file() else recs
    return out


def plan_handoff(records: Sequence[EpisodeRecord], episodes_dir, scenes_root, task: str = "paper",
                 split: str = "val") -> list[Job]:
    """One job per (house, method) of the records that carry no hand-off but a trajectory (records made before
    trajectories were stored are left out: nothing to recompute from); their houses' episode files are
    ``episodes_dir/<scene>.json``."""
    from nue.evaluate.runner import house_folder

    groups: dict[tuple[str, str], list[dict]] = {}
    for r in records:
        if record_handoff(r) is None and r.extra.get("trajectory") is not None:  # older records have no trajectory
            groups.setdefault((r.scene, r.method), []).append(r.to_dict())
    jobs = []
    for (scene, method), recs in sorted(groups.items()):
        file = Path(episodes_dir) / f"{scene}.json"
        if not file.is_file():
            raise DataError(file, f"no episode file for the records of house {scene!r} (--episodes-dir)")
        folder = house_folder(scene, scenes_root, split)
        jobs.append(Job(f"{method}/{scene}", HandoffJob(str(folder), str(file), task, tuple(recs))))
    return jobs


def handoff_job(job: Job) -> list[dict]:
    """Worker: the hand-off lines of one job's records."""
    from nue.scene.scene import Scene
    from nue.sim.env import make_env
    from nue.sim.episodes import read_episodes

    p: HandoffJob = job.payload

    def build():
        scene = Scene.load(p.scene)
        env = make_env(scene, p.task)
        return env, {e.episode_id: e for e in read_episodes(p.episodes, scene, p.task, navgrid=env.navgrid).episodes}

    env, episodes = worker_cached(("handoff", p.scene, p.episodes, p.task), build)
    lines = []
    for d in p.records:
        r = EpisodeRecord.from_dict(d)
        if r.episode_id not in episodes:
            raise DataError(p.episodes, f"no episode {r.episode_id!r} (record {record_key(r)})")
        env.reset(seed=0, options={"episode": episodes[r.episode_id]})
        lines.append({"key": record_key(r), "method": r.method, "trajectory": trajectory_digest(r),
                      HANDOFF_KEY: handoff_of_record(r, env).to_dict()})
    return lines


def run_handoff(records: Sequence[EpisodeRecord], out, episodes_dir, scenes_root="data/scenes", task: str = "paper",
                workers: int = 1, progress: bool = True) -> Path:
    """Recompute the hand-off of every record without one into the hand-off file ``out`` (resumes), which this
    process holds meanwhile (:func:`~nue.output_lock.hold_output`)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with hold_output(out):
        return _run_handoff(records, out, episodes_dir, scenes_root, task, workers, progress)


def _run_handoff(records: Sequence[EpisodeRecord], out: Path, episodes_dir, scenes_root, task: str, workers: int,
                 progress: bool) -> Path:
    have = read_handoff_file(out)
    jobs = plan_handoff([r for r in records if record_key(r) not in have], episodes_dir, scenes_root, task)

    from nue.evaluate.runner import append_lines

    run_jobs(jobs, handoff_job, on_result=lambda job, lines: append_lines(out, lines), workers=workers,
             desc="hand-off", progress=progress)
    return out
