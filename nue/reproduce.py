"""``nue reproduce``: Table I from nothing in one resumable command — houses, demonstrations, every model of
the recipe, evaluation on the fixed episode sets, the report and RESULTS.md.

Stages, in order (each one calls the library function of its command, and each is resumable by itself):

==================  ==========================================================================================
``scenes``          the training houses and the houses of every evaluation set (kept when intact)
``collect``         ``nue collect`` into ``OUT/demos``; ``collect/<split>``, each of ``Recipe.also_train`` into
                    ``OUT/demos_<split>``
``train/<run>``     ``nue train --resume`` into ``OUT/runs/<run>`` (closed-loop selection included), one per training
                    run: ``<model>``, and ``<model>@s<k>`` for a model's further training seeds (``Recipe.train_seeds``);
                    the runs go side by side on ``--workers`` processes (one torch thread each) or Ray tasks
                    (:mod:`nue.reproduce_train`)
``eval/<set>``      ``nue eval`` of every training run and expert on the set into ``OUT/records/<set>.jsonl`` (a
                    run's records are named after it, so the report pools a model's seeds into one row)
``eval/<set>+swap`` the swapped-maps control on each set (every seed of the ``swap_maps`` models); then
                    ``eval/<set>+sling``, the ``last_mile`` models (every seed) wrapped in SLING's last-mile module
``explore/<set>``   ``nue explore``: the exploration benchmark from the set's starts (``Recipe.explore_sets``) into
                    ``OUT/records/explore/<set>.jsonl`` (:mod:`nue.reproduce_eval` runs the ``eval`` and ``explore``
                    stages)
``report``          ``nue report`` per set (``OUT/report/<set>/``: tables and coverage.png; a set that extends
                    another also reports the smaller one from the same records), the exploration benchmark's
                    figure per set of starts (``OUT/report/explore_<set>.png``) and ``OUT/RESULTS.md`` (with each
                    stage's wall-clock in the call that finished it, and an evaluation's summed episode time)
==================  ==========================================================================================

The recipe is stored in ``OUT/recipe.json`` when a run starts; a rerun with another recipe is refused (a field added to
``Recipe`` since the file was written counts at its default, which keeps the results of before).
A finished stage leaves ``OUT/stages/<stage>.json`` (its wall-clock and summary) and is skipped by a
rerun, so a killed run picks up at the stage it was in, and that stage continues from its own files.
Test hook: ``NUE_FAIL_AFTER_STAGE=k`` stops the run after k stages finished in this call.
"""

from __future__ import annotations

import json
import platform
import time
from collections import Counter
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Sequence

from nue.errors import ConfigError, DataError
from nue.evaluate.report import load_records, write_report
from nue.evaluate.results_md import render_results_md
from nue.jobs import fail_point
from nue.output_lock import hold_output
from nue.policy.checkpoint import git_commit
from nue.recipe import Recipe, StageEstimate, episode_counts, estimate, explore_counts, format_duration, format_estimate
from nue.recipe_estimate import CostModel, collection_sizes
from nue.reproduce_adopt import Adoption, collection_index, finished_runs, trained_shares
from nue.reproduce_adopt import adopt as adopt_into_run
from nue.reproduce_calibrate import calibration
from nue.reproduce_eval import (EXPLORE_REFERENCES, EXTRA_ROWS, eval_episodes_dir, explore_records,  # noqa: F401
                                report_tables, run_eval_stage, run_explore_stage, run_methods as _methods)
from nue.reproduce_marker import (HousesSummary, ReportSummary, RunFolders, StageMarker, StageSummary,  # noqa: F401
                                  stage_done)
from nue.reproduce_train import TrainJob, collect_config, collect_configs, run_training, train_config, train_model  # noqa: F401
from nue.scene.generator import SPLITS, ensure_house
from nue.sim.episode_sets import get_episode_set, held_out_sets
from nue.train.collect import CollectSummary, collect
from nue.train.hardware import machine_summary
from nue.viz.coverage import write_coverage_figure

FORMAT = "nue-reproduce/1"
FAIL_AFTER_STAGE_ENV = "NUE_FAIL_AFTER_STAGE"


@dataclass
class ReproduceResult:
    """What a call did."""

    ran: list[str]
    """Stages run (to completion) in this call."""
    kept: list[str]
    """Stages finished by an earlier call, skipped."""
    results_md: Path
    """The RESULTS.md written."""


# --- the recipe and the stage markers -----------------------------------------------------------------
def check_recipe(out: Path, recipe: Recipe) -> None:
    """Store ``recipe`` in ``out/recipe.json``, or refuse a run folder that was started with another one."""
    path = out / "recipe.json"
    mine = recipe.to_dict()
    if path.is_file():
        try:
            stored = json.loads(path.read_text())["recipe"]
            stored = {**_defaults(), **stored}  # fields added since it was written: at their defaults
        except (ValueError, KeyError, TypeError):
            raise DataError(path, "is not a reproduce recipe file") from None
        if stored != mine:
            diff = sorted(k for k in set(stored) | set(mine) if stored.get(k) != mine.get(k))
            raise ConfigError(path, f"this run was started with recipe {stored.get('name')!r}, which differs in "
                                    f"{', '.join(diff)}; rerun with that recipe or use another --out")
        return
    out.mkdir(parents=True, exist_ok=True)
    _write_json(path, {"format": FORMAT, "recipe": mine, "commit": git_commit(), "started": _now()})


def _defaults() -> dict:
    """Every ``Recipe`` field with a default (all but ``name``), at it, as ``to_dict`` writes it."""
    return {k: v for k, v in Recipe(name="").to_dict().items() if k != "name"}


def _write_json(path: Path, data) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(data, indent=1, default=str) + "\n")
    tmp.replace(path)


def _now() -> str:
    return time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())


# --- stages ---------------------------------------------------------------------------------------------
def _houses(recipe: Recipe) -> list[tuple[str, int]]:
    out = [(c.split, i) for c in recipe.collections() for i in (c.houses or range(len(SPLITS[c.split])))]
    for name, houses in [(n, recipe.eval_houses) for n in recipe.eval_sets] + [(n, recipe.explore_houses)
                                                                             for n in recipe.explore_sets]:
        split = get_episode_set(name).split
        out += [(split, i) for i in (houses or range(len(SPLITS[split]))) if (split, i) not in out]
    return out


# --- the run --------------------------------------------------------------------------------------------
def _lines(path: Path) -> int:
    if not path.is_file():
        return 0
    with path.open("rb") as f:
        return sum(1 for line in f if line.strip())


def remaining_estimate(recipe: Recipe, folders: RunFolders, workers: int = 1, compiled: bool = False,
                       cost: CostModel = CostModel()) -> list[StageEstimate]:
    """:func:`~nue.recipe.estimate` of what is left of a (resumed) run: stages finished earlier are marked done,
    the training stage counts only the training runs not trained yet (a run folder at its last step counts as trained;
    one part-way through, the share of its training left),
    a collection stage is scaled by the share of its episodes not collected yet, and an evaluation stage by the share
    of its (episode, method) runs its records file does not hold yet (the runs go episode by episode, every method
    of an episode together, so that share is also a share of the cost). ``cost``: the cost model (a run's own
    measured rates: :func:`nue.reproduce_calibrate.calibration`)."""
    trained = [r.name for r in recipe.training_runs()]
    pending = [r for r in trained if stage_done(folders, f"train/{r}") is None]
    pending = [r for r in pending if r not in finished_runs(recipe, folders, pending)]  # adopted: only a selection left
    counts = episode_counts(recipe)
    out = []
    for s in estimate(recipe, workers, cost=cost, compiled=compiled, runs=pending,
                      trained=trained_shares(recipe, folders, pending)):
        done = not pending if s.stage == "train" else stage_done(folders, s.stage) is not None
        if done:
            out.append(replace(s, seconds=0.0, done=True, detail="finished in an earlier call"))
        elif s.stage == "collect" or s.stage.startswith("collect/"):
            k = collection_index(recipe, s.stage)
            c = recipe.collections()[k]
            want = collection_sizes(recipe)[k]
            have = min(sum(1 for _ in folders.demos_of(c.split, k == 0).glob("*/*/*.nue")), want)
            out.append(replace(s, seconds=s.seconds * (1 - have / max(want, 1)),
                               detail=s.detail + (f"; {have:,} of {want:,} episodes collected" if have else "")))
        elif s.stage == "train" and len(pending) < len(trained):
            out.append(replace(s, detail=f"{s.detail}; {len(trained) - len(pending)} trained earlier"))
        elif s.stage.startswith("eval/"):
            name = s.stage.removeprefix("eval/")
            extra = EXTRA_ROWS.get(name.rpartition("+")[2]) if "+" in name else None
            methods = (len(recipe.training_runs(extra(recipe))) if extra is not None
                       else len(trained) + len(recipe.experts))
            runs = counts[name.partition("+")[0]] * methods
            have = min(_lines(folders.records(s.stage)), runs)
            out.append(replace(s, seconds=s.seconds * (1 - have / max(runs, 1)),
                               detail=s.detail + (f"; {have:,} of {runs:,} runs recorded" if have else "")))
        elif s.stage.startswith("explore/"):
            runs = (explore_counts(recipe)[s.stage.removeprefix("explore/")]
                    * (len(recipe.training_runs(recipe.explore_models)) + len(EXPLORE_REFERENCES)))
            have = min(_lines(folders.records(s.stage)), runs)
            out.append(replace(s, seconds=s.seconds * (1 - have / max(runs, 1)),
                               detail=s.detail + (f"; {have:,} of {runs:,} runs recorded" if have else "")))
        else:
            out.append(s)
    return out


def plan_stages(recipe: Recipe) -> list[str]:
    """Stage names of a recipe, in order."""
    stages = ["scenes", "collect", *[f"collect/{c.split}" for c in recipe.collections()[1:]],
              *[f"train/{r.name}" for r in recipe.training_runs()]]
    for name in recipe.eval_sets:
        stages.append(f"eval/{name}")
        for suffix, models in EXTRA_ROWS.items():
            if models(recipe):
                stages.append(f"eval/{name}+{suffix}")
    return stages + [f"explore/{name}" for name in recipe.explore_sets] + ["report"]


def reproduce(recipe: Recipe, out, scenes_root="data/scenes", episodes_root="episodes", workers: int = 1,
              ray_address: str | None = None, device: str = "cpu", results_md=None,
              echo: Callable[[str], None] = print, progress: bool = True, compile: bool = False,
              adopt: Sequence[Adoption] = ()) -> ReproduceResult:
    """Run (or resume) ``recipe`` into ``out``, which this process holds meanwhile (one writer per output); see the
    module docstring. ``compile``: train with ``torch.compile`` (``TrainConfig.compile``: the same arithmetic,
    rounded differently; a run may switch it between calls). ``adopt``: collections and training runs made outside
    the run with the stage's exact settings, checked and put into the run folder first (:mod:`nue.reproduce_adopt`)."""
    with hold_output(out):
        folders = RunFolders(Path(out), Path(scenes_root), Path(episodes_root))
        check_recipe(folders.out, recipe)
        for line in adopt_into_run(recipe, folders, list(adopt), device):
            echo(line)
        return _reproduce(recipe, folders, workers, ray_address, device, results_md, echo, progress, compile)


def _reproduce(recipe: Recipe, folders: RunFolders, workers, ray_address, device, results_md, echo, progress,
               compile) -> ReproduceResult:
    measured = calibration(recipe, folders, compile)
    est = {s.stage: s for s in remaining_estimate(recipe, folders, workers, compile, measured.cost_model())}
    note = measured.describe()
    echo(f"nue reproduce: recipe {recipe.name!r} -> {folders.out}; estimated wall-clock with {workers} worker(s):\n"
         f"{format_estimate(list(est.values()))}" + (f"\n{note}" if note else ""))
    stages = plan_stages(recipe)
    ran: list[str] = []
    done = {s: stage_done(folders, s) for s in stages}
    kept = [s for s in stages if done[s] is not None]

    def finish(stage: str, seconds: float, summary: StageSummary) -> None:
        _write_json(folders.marker(stage), StageMarker(stage, seconds, _now(), summary, machine_summary()).to_dict())
        ran.append(stage)
        echo(f"  {stage}: done in {format_duration(seconds)}")
        fail_point(FAIL_AFTER_STAGE_ENV, len(ran), f"stage {stage}")

    def header(i: int, stage: str, what: str) -> None:
        guess = est.get(stage.split("/")[0] if stage.startswith("train/") else stage)
        echo(f"[{i + 1}/{len(stages)}] {stage}: {what}" + (f" (estimate {format_duration(guess.seconds)})" if guess else ""))

    pending_train = [s for s in stages if s.startswith("train/") and s not in kept]
    for i, stage in enumerate(stages):
        marker = done[stage]
        if marker is not None:
            echo(f"[{i + 1}/{len(stages)}] {stage}: finished in an earlier call "
                 f"({format_duration(marker.seconds)}), kept")
            continue
        if stage.startswith("train/"):
            if stage == pending_train[0]:
                header(i, "train", f"{len(pending_train)} training run(s): {', '.join(s[6:] for s in pending_train)}")
                run_training(recipe, folders, pending_train, workers, ray_address, device, progress, finish, compile)
            continue
        t0 = time.perf_counter()
        if stage == "scenes":
            header(i, stage, "houses")
            houses = _houses(recipe)
            for split, index in houses:
                ensure_house(split, index, folders.scenes_root)
            finish(stage, time.perf_counter() - t0, HousesSummary([f"{s}_{k:02d}" for s, k in houses]))
        elif stage == "collect" or stage.startswith("collect/"):
            k = collection_index(recipe, stage)
            cfg = collect_configs(recipe, device)[k]
            demos = folders.demos_of(cfg.split, k == 0)
            header(i, stage, f"demonstrations in the {cfg.split} houses -> {demos}")
            collected = collect(demos, cfg, folders.scenes_root, workers=workers, ray_address=ray_address,
                                progress=progress)
            finish(stage, time.perf_counter() - t0, collected)
        elif stage.startswith("eval/"):
            header(i, stage, f"-> {folders.records(stage)}")
            summary = run_eval_stage(recipe, folders, stage, workers, ray_address, device, progress)
            finish(stage, time.perf_counter() - t0, summary)
        elif stage.startswith("explore/"):
            header(i, stage, f"exploration benchmark -> {folders.records(stage)}")
            summary = run_explore_stage(recipe, folders, stage, workers, ray_address, device, progress)
            finish(stage, time.perf_counter() - t0, summary)
        elif stage == "report":
            header(i, stage, f"-> {folders.out / 'report'}, RESULTS.md")
            md = write_results(recipe, folders)
            if results_md:
                Path(results_md).write_text(md.read_text())
            finish(stage, time.perf_counter() - t0, ReportSummary(str(md)))
    md = folders.out / "RESULTS.md"
    if results_md and "report" in kept:
        Path(results_md).write_text(md.read_text())
    return ReproduceResult(ran, kept, Path(results_md) if results_md else md)


def _episode_time(folders: RunFolders, stage: str) -> str:
    """For an evaluation stage, its runs and their summed episode time from its records (a stage's marker times
    only the call that finished it; a stage resumed across calls spent more)."""
    if not stage.startswith(("eval/", "explore/")):
        return ""
    recs = load_records(folders.records(stage))
    return f" ({len(recs)} run{'' if len(recs) == 1 else 's'}, {format_duration(sum(r.wall_time for r in recs))} of episode time summed over workers)"


def demonstrations_line(collected: list[CollectSummary]) -> str:
    """RESULTS.md's demonstrations line: episodes, steps and the expert's SR over every collection of a run."""
    if not collected:
        return "? episodes, ? steps, expert SR 0.0%"
    episodes = sum(c.episodes for c in collected)
    sr = sum(c.expert_success_rate * c.episodes for c in collected) / max(episodes, 1)
    return f"{episodes} episodes, {sum(c.steps for c in collected)} steps, expert SR {100 * sr:.1f}%"


def run_meta(recipe: Recipe, folders: RunFolders) -> dict[str, str]:
    """RESULTS.md's facts about a run, from its files: command, dates (started; the last stage marker's finish, or
    now), commits (where it started; now), machine, recipe, main set, demonstrations, each finished stage's
    wall-clock and where the stages ran (``scripts/reproduce_publish.py`` copies the last three into the repository's
    RESULTS.meta.json)."""
    walls = {s: stage_done(folders, s) for s in plan_stages(recipe) if s != "report"}
    done = [m for m in walls.values() if m is not None]
    collected = [m.summary for m in done if isinstance(m.summary, CollectSummary)]
    stored = json.loads((folders.out / "recipe.json").read_text())
    finished = max((m.finished for m in done), default=_now())  # "YYYY-MM-DD HH:MM UTC" sorts as text
    main = recipe.eval_sets[0]
    commit = git_commit()
    return {
        "command": f"nue reproduce --recipe {recipe.name} --out {folders.out}",
        "date": f"{stored.get('started', '?')} - {finished}",
        "commit": commit if stored.get("commit") in (None, commit) else f"started at {stored['commit']}, now {commit}",
        "machine": f"{machine_summary()}, Python {platform.python_version()} (the call that wrote this)",
        "stage machines": "where the call that finished each stage ran, stages: " + "; ".join(
            f"{where or 'not recorded (markers written before the field)'} {n}"
            for where, n in Counter(d.machine for d in done).most_common()),
        "recipe": f"{recipe.summary()} (all values: {folders.out / 'recipe.json'})",
        "episodes": f"`{main}`: {get_episode_set(main).description}",
        "demonstrations": demonstrations_line(collected),
        "stage wall-clock": "each stage's wall-clock in the call that finished it (a stage resumed across calls "
                            "spent more; an evaluation's summed episode time follows it): "
                            + "; ".join(f"{s} {format_duration(m.seconds)}{_episode_time(folders, s)}"
                                        for s, m in walls.items() if m),
    }


def write_results(recipe: Recipe, folders: RunFolders) -> Path:
    """``OUT/report/<table>/`` for every table and ``OUT/RESULTS.md`` (the first set in full, then the others)."""
    tables = report_tables(recipe, folders)
    for name, recs in tables.items():
        write_report(recs, folders.out / "report" / name, task=recipe.task)
        write_coverage_figure(recs, folders.out / "report" / name)
    explored = explore_records(recipe, folders)
    for name, recs in explored.items():
        write_coverage_figure(recs, folders.out / "report", f"explore_{name}.png",
                              f"Exploration benchmark from {name}'s starts")
    main = recipe.eval_sets[0]
    meta = run_meta(recipe, folders)
    held_out = [s for s in held_out_sets() if s in tables]
    text = render_results_md(tables[main], meta, recipe.task, sets={k: v for k, v in tables.items() if k != main},
                             main_name=main, explore=explored, generalisation=main if held_out else "")
    path = folders.out / "RESULTS.md"
    path.write_text(text)
    return path
