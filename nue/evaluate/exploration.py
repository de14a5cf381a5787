"""``nue explore``: the exploration benchmark, after Active Neural SLAM's protocol (Chaplot et al., ICLR 2020), on
our houses: seen floor area over a fixed number of steps when there is nothing to find.

Each run starts from a goal episode's start pose (e.g. val252's), and the agent is given the goal photo of the
same-numbered episode of the *next* house of the set (house i gets house i + 1's, the last the first's): a real
goal photo that matches nothing in this house. Success never ends the run (``explore_only``), so every run lasts
``steps`` steps, and the seen floor area (:class:`~nue.evaluate.coverage.CoverageTracker`, m²) after every step
is recorded (``coverage``), and the seen area within the floor the robot could see at most (``coverage_explorable``;
that floor is the traversable region of the start, :func:`~nue.evaluate.coverage.explorable_cells`, of area
``explorable_area``). :func:`exploration_summary` reports the mean seen area and fraction at 100 / 200 / 500 / 800 steps and
the ratio of each method's mean to a reference method's, with a paired bootstrap over the starts. Runs go through
the evaluation's jobs and records (:mod:`nue.evaluate.runner`): resumable, refusing other settings. References:
``expert-explore`` (frontier exploration on its own seen map, never switching to a goal) and ``random``
(uniform random moves).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from nue.errors import ConfigError
from nue.evaluate.coverage import COVERAGE_KEY, pad_curves
from nue.evaluate.eval_job import EvalJob, RunSettings
from nue.jobs import Job, episode_seed, run_jobs
from nue.output_lock import hold_output
from nue.sim.episodes import read_episodes
from nue.sim.record import EpisodeRecord

REPORT_STEPS = (100, 200, 500, 800)
"""Steps at which the summary reports the seen area."""


@dataclass(frozen=True)
class ExploreConfig:
    """An exploration benchmark run."""

    episodes_dir: str = "episodes/val252"
    """Folder of episode files, one per house (``<house>.json``): their start poses are the runs' starts."""
    scenes_root: str = "data/scenes"
    """Where the houses are (generated from their fixed seeds if missing)."""
    split: str = "val"
    """House split of episode files whose name does not say it."""
    task: str = "paper"
    """Task preset (camera, actions); its step limit is replaced by ``steps``."""
    seed: int = 0
    """Base seed; each run's seed is derived from it and the episode's key."""
    device: str = "cpu"
    """Device of policy and memory in the workers."""
    steps: int = 800
    """Steps of every run."""
    per_bin: int = 0
    """Use only the first N episodes of each difficulty bin of each house (0 = all)."""


def plan_explore(methods: list[str], cfg: ExploreConfig) -> list[Job]:
    """One job per (start, method); keys ``<method>/<house>/<episode id>``."""
    from nue.evaluate.runner import EXPERT_METHODS, episode_files, first_per_bin, house_folder, parse_methods
    from nue.policy.checkpoint import check_compatible
    from nue.scene.scene import Scene

    if cfg.steps <= 0:
        raise ConfigError("--steps", "must be positive")
    parsed, checked = parse_methods(methods, cfg.task)
    houses = []
    for f in episode_files(cfg.episodes_dir):
        folder = house_folder(f.name.removesuffix(".gz").removesuffix(".json"), cfg.scenes_root, cfg.split)
        scene = Scene.load(folder)
        for ckpt, (header, _) in checked.items():
            check_compatible(header, ckpt, scenes={scene.name: scene.content_hash})
        houses.append((folder, scene, read_episodes(f, scene, cfg.task).episodes))
    if len(houses) < 2:
        raise ConfigError("--episodes-dir", f"{cfg.episodes_dir}: needs at least two houses (goal photos come from another one)")
    jobs = []
    for h, (folder, scene, episodes) in enumerate(houses):
        g_folder, g_scene, g_eps = houses[(h + 1) % len(houses)]
        for i in first_per_bin(episodes, cfg.per_bin):
            ep, goal = episodes[i], g_eps[i % len(g_eps)]
            goal_from = f"{g_scene.content_hash}/{RunSettings.episode_digest(goal)}"
            for method, ckpt in parsed:
                settings = RunSettings(agent=checked[ckpt][1] if ckpt else method, task=cfg.task, max_steps=cfg.steps,
                                       seed=cfg.seed, swap_maps=False, coverage=True,
                                       episode=RunSettings.episode_digest(ep), scene=scene.content_hash,
                                       goal_from=goal_from, explore_only=True)
                jobs.append(Job(f"{method}/{scene.name}/{ep.episode_id}", EvalJob(
                    method=method, checkpoint=ckpt, expert=EXPERT_METHODS.get(method, "") if ckpt is None else "",
                    scene=str(folder), episode=ep, other=None, task=cfg.task,
                    seed=episode_seed(cfg.seed, scene.name, ep.episode_id), device=cfg.device, coverage=True,
                    max_steps=cfg.steps, settings=settings, goal_scene=str(g_folder), goal_episode=goal,
                    explore_only=True)))
    return jobs


def run_explore(methods: list[str], out, cfg: ExploreConfig, workers: int = 1, ray_address: str | None = None,
                progress: bool = True) -> Path:
    """Run the benchmark for ``methods`` (checkpoints, ``name=path``, ``expert-explore``, ``random``); records
    appended to ``out`` (resumes; refuses records of other settings), which this process holds meanwhile
    (:func:`~nue.output_lock.hold_output`: a second writer stops at once)."""
    from nue.evaluate.runner import append_record, check_resumable, eval_episode

    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with hold_output(out):
        jobs = plan_explore(methods, cfg)
        done = check_resumable(out, jobs)
        run_jobs(jobs, eval_episode, on_result=lambda job, rec: append_record(out, rec),
                 is_done=lambda job: job.key in done, workers=workers, ray_address=ray_address, desc="explore",
                 progress=progress)
    return out


@dataclass(frozen=True)
class ExplorationRow:
    """One method's seen area at the report steps (with several training seeds: their runs pooled)."""

    method: str
    runs: int
    """Starts in the row (with several seeds: the starts every seed ran)."""
    area: dict
    """Step -> mean seen floor area, m² (with several seeds: the mean over starts of the seeds' mean)."""
    area_ci: dict
    """Step -> (lo, hi) 95% bootstrap interval of the mean, m² (several seeds: two-level, seeds then starts)."""
    fraction: dict
    """Step -> mean over the runs of (seen area within the explorable floor) / (explorable floor area)."""
    ratio: dict
    """Step -> (ratio of means to the reference, lo, hi) over the starts both ran (paired bootstrap; with several
    seeds on either side the two-level one, :func:`~nue.evaluate.stats.seed_episode_ratio`); {} for the reference
    itself or without one."""
    seeds: int = 1
    """Training seeds pooled in the row (runs ``<method>@s<k>``, :func:`~nue.evaluate.table.split_seed`)."""


def _curves(records: Sequence[EpisodeRecord], steps: int) -> dict[str, dict[int, dict[str, np.ndarray]]]:
    """Method key -> seed index -> start key -> (seen area, fraction of the explorable floor) curves, (2, steps)."""
    from nue.evaluate.table import canonical_method, split_seed

    by: dict[str, dict[int, dict[str, np.ndarray]]] = {}
    for r in records:
        cov = r.extra.get(COVERAGE_KEY)
        if cov is None:
            continue
        inside, total = r.extra.get("coverage_explorable"), r.extra.get("explorable_area")
        frac = pad_curves([inside], steps)[0] / total if inside is not None and total else np.full(steps, np.nan)
        base, k = split_seed(r.method)
        by.setdefault(canonical_method(base), {}).setdefault(k, {})[f"{r.scene}/{r.episode_id}"] = np.stack(
            [pad_curves([cov], steps)[0], frac])
    return by


def _stack(seeds: Mapping[int, Mapping[str, np.ndarray]], keys: Sequence[str]) -> np.ndarray:
    """(seeds, starts, 2, steps) curves of ``keys``."""
    return np.stack([np.stack([runs[k] for k in keys]) for runs in seeds.values()])


def _common(seeds: Mapping[int, Mapping[str, np.ndarray]]) -> set[str]:
    return set.intersection(*(set(runs) for runs in seeds.values()))


def exploration_summary(records: Sequence[EpisodeRecord], reference: str = "abl_at_cbam",
                        steps: Sequence[int] = REPORT_STEPS) -> list[ExplorationRow]:
    """Per method key (in table order, :func:`~nue.evaluate.table.order_methods`; a method's training seeds
    ``<method>@s<k>`` pooled in one row), the :class:`ExplorationRow` at ``steps`` within the runs' length, and at
    that length."""
    from nue.evaluate.stats import seed_episode_bootstrap, seed_episode_ratio
    from nue.evaluate.table import canonical_method, order_methods

    length = max((len(r.extra.get(COVERAGE_KEY) or []) for r in records), default=0)
    steps = sorted({s for s in (*steps, length) if 0 < s <= length})
    curves = _curves(records, length)
    ref = curves.get(canonical_method(reference))
    cols = [s - 1 for s in steps]
    rows = []
    for m in order_methods(curves):
        keys = sorted(_common(curves[m]))
        c = _stack(curves[m], keys)  # (S, n, 2, steps)
        area_runs = c[:, :, 0, cols]
        mean, lo, hi = seed_episode_bootstrap(area_runs, np.zeros((1, *area_runs.shape[1:])))
        with np.errstate(invalid="ignore"):
            frac = np.nanmean(c[:, :, 1, cols].mean(axis=0), axis=0) if np.isfinite(c[:, :, 1]).any() else \
                np.full(len(steps), np.nan)
        ratio = {}
        if ref is not None and curves[m] is not ref:
            both = sorted(set(keys) & _common(ref))
            if both:
                r, rlo, rhi = seed_episode_ratio(_stack(curves[m], both)[:, :, 0, cols], _stack(ref, both)[:, :, 0, cols])
                ratio = {s: (float(r[i]), float(rlo[i]), float(rhi[i])) for i, s in enumerate(steps)}
        rows.append(ExplorationRow(m, len(keys), {s: float(mean[i]) for i, s in enumerate(steps)},
                                   {s: (float(lo[i]), float(hi[i])) for i, s in enumerate(steps)},
                                   {s: float(frac[i]) for i, s in enumerate(steps)}, ratio, seeds=len(curves[m])))
    return rows


def format_exploration_markdown(rows: Sequence[ExplorationRow], reference: str = "abl_at_cbam",
                                labels: Mapping[str, str] | None = None) -> str:
    """Markdown table: per method and report step the mean seen area (95% interval), the mean fraction of the
    explorable area, and the ratio to ``reference`` (95% paired bootstrap)."""
    steps = sorted({s for r in rows for s in r.area})
    ref = (labels or {}).get(reference, reference)
    head = "| method | runs | " + " | ".join(f"step {s}: m² (95%), fraction, ratio to {ref}" for s in steps) + " |"
    lines = [head, "|" + "---|" * (len(steps) + 2)]
    for r in rows:
        cells = []
        for s in steps:
            lo, hi = r.area_ci[s]
            ratio = r.ratio.get(s)
            rt = "–" if ratio is None else f"{ratio[0]:.2f} [{ratio[1]:.2f}, {ratio[2]:.2f}]"
            cells.append(f"{r.area[s]:.1f} [{lo:.1f}, {hi:.1f}], {r.fraction[s]:.2f}, {rt}")
        runs = str(r.runs) if r.seeds == 1 else f"{r.runs} x {r.seeds} seeds"
        lines.append(f"| {(labels or {}).get(r.method, r.method)} | {runs} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
