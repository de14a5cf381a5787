"""The estimate of a resumed ``nue reproduce`` run, calibrated to the machine it runs on.

:class:`~nue.recipe_estimate.CostModel` holds costs measured on the CPUs of earlier runs; another machine trains and
steps episodes at its own rates. A run's finished work says how much: each finished training run's ``train_seconds``
(resume-proof: the trainer's clock survives a restart) against the samples it trained at the modelled rate, and the
episodes it has stepped (its closed-loop selection's ``selection.jsonl`` and the evaluation records written so far:
``wall_time`` and ``steps``) against the modelled seconds a step. :func:`calibration` turns them into factors per cost
entry (``nue``, ``fr``, ... as the cost tables name them: the median over the entry's runs, so a run slowed by other work
on the machine does not set the rate) and :meth:`Calibration.cost_model` into a cost model whose
estimate of what is left runs at this machine's measured rates; an entry with no measurement takes the factor pooled
over those that have one (the median of all their runs), and without any measurement nothing changes."""

from __future__ import annotations

import json
import statistics
from dataclasses import dataclass, replace
from pathlib import Path

from nue.recipe import Recipe
from nue.recipe_estimate import CostModel, cost_key, episode_seconds, train_rate
from nue.reproduce_marker import RunFolders, StageMarker, TrainRunSummary

MAX_RECORDS_PER_FILE = 5000
"""Evaluation records read per file for the step rate (the runs go episode by episode, every method together, so
the first records are a fair sample of the methods; the files grow to ~10,000 lines)."""


@dataclass(frozen=True)
class Factor:
    """Measured over modelled seconds for one cost entry, run by run."""

    key: str
    """The cost entry (``nue``, ``fr``, ``vgm``, ...; a model's own name where the cost tables list it)."""
    ratios: tuple[float, ...]
    """Per measured run (a training run; the episodes of one run in one records file): its measured seconds over
    the seconds the cost model gives the same work."""
    episodes: int = 0
    """Episodes behind the step ratios (0 for training)."""

    @property
    def ratio(self) -> float:
        """The median over the runs."""
        return statistics.median(self.ratios)


@dataclass(frozen=True)
class Calibration:
    """How a run's measured costs compare with the cost model's (empty: nothing measured yet)."""

    train: tuple[Factor, ...] = ()
    """Training throughput, per cost entry of ``samples_per_s``."""
    steps: tuple[Factor, ...] = ()
    """Seconds per episode step (closed-loop selection and evaluation), per cost entry of ``eval_s_per_episode``."""

    @staticmethod
    def _pooled(factors: tuple[Factor, ...]) -> float:
        return statistics.median([r for f in factors for r in f.ratios]) if factors else 1.0

    def cost_model(self, base: CostModel = CostModel()) -> CostModel:
        """``base`` at the measured rates: training rates divided by their factor, selection and evaluation seconds
        per episode multiplied by theirs (unmeasured entries, the experts', the swapped-maps control's and SLING's
        included, by the pooled factor)."""
        train, steps = {f.key: f.ratio for f in self.train}, {f.key: f.ratio for f in self.steps}
        pool_t, pool_s = self._pooled(self.train), self._pooled(self.steps)
        return replace(base,
                       samples_per_s=tuple((k, v / train.get(k, pool_t)) for k, v in base.samples_per_s),
                       select_s_per_episode=tuple((k, v * steps.get(k, pool_s)) for k, v in base.select_s_per_episode),
                       eval_s_per_episode=tuple((k, v * steps.get(k, pool_s)) for k, v in base.eval_s_per_episode))

    def describe(self) -> str:
        """One line for the printed estimate (empty when nothing was measured)."""
        if not (self.train or self.steps):
            return ""
        parts = []
        if self.train:
            parts.append("training time " + ", ".join(f"{f.key} x{f.ratio:.2f} ({_runs(f)})" for f in self.train))
        if self.steps:
            parts.append("episode steps " + ", ".join(f"{f.key} x{f.ratio:.2f} ({_runs(f)}, {f.episodes:,} episodes)"
                                                     for f in self.steps))
        return ("  calibrated to this run's measured costs (x: measured / the cost model's, median over runs): "
                + "; ".join(parts))


def _runs(f: Factor) -> str:
    return f"{len(f.ratios)} run{'s' * (len(f.ratios) != 1)}"


def _read_lines(path: Path, limit: int | None = None) -> list[dict]:
    out: list[dict] = []
    if not path.is_file():
        return out
    with path.open() as f:
        for line in f:
            if limit is not None and len(out) >= limit:
                break
            try:
                d = json.loads(line)
            except json.JSONDecodeError:
                continue  # a line being written; the estimate is no place to refuse a file
            if isinstance(d, dict):
                out.append(d)
    return out


def _factors(acc: dict[str, list[tuple[float, float, int]]]) -> tuple[Factor, ...]:
    """(measured s, modelled s, episodes) per run, grouped by cost entry -> one :class:`Factor` per entry."""
    out = []
    for key, runs in sorted(acc.items()):
        kept = [(m, e, n) for m, e, n in runs if m > 0 and e > 0]
        if kept:
            out.append(Factor(key, tuple(m / e for m, e, _ in kept), sum(n for _, _, n in kept)))
    return tuple(out)


def calibration(recipe: Recipe, folders: RunFolders, compiled: bool = False, base: CostModel = CostModel()) -> Calibration:
    """The factors measured by what ``folders`` holds of a run of ``recipe``: finished training runs (a stage
    marker with the trainer's time; a recipe with a time budget has no training factor, its budget fixes the
    time), their selection records, and the first :data:`MAX_RECORDS_PER_FILE` records of each goal-episode
    evaluation stage (records of training runs only: the experts and the extra rows are priced by the pooled factor)."""
    train: dict[str, list[tuple[float, float, int]]] = {}
    steps: dict[str, list[tuple[float, float, int]]] = {}

    def add_steps(model: str, records: list[dict]) -> None:
        per_step = episode_seconds(recipe, model, base) / base.eval_steps_per_episode
        timed = [r for r in records if isinstance(r.get("wall_time"), (int, float))
                 and isinstance(r.get("steps"), int) and r["steps"] > 0]
        if timed:
            steps.setdefault(cost_key(base.eval_s_per_episode, model), []).append(
                (sum(r["wall_time"] for r in timed), sum(r["steps"] for r in timed) * per_step, len(timed)))

    models = {r.name: r.model for r in recipe.training_runs()}
    for name, model in models.items():
        marker_path = folders.marker(f"train/{name}")
        if not marker_path.is_file():
            continue
        summary = StageMarker.read(marker_path).summary
        if not isinstance(summary, TrainRunSummary):
            continue
        if recipe.train_minutes <= 0 and summary.train_seconds and summary.steps:
            modelled = summary.steps * recipe.samples_per_step(model) / train_rate(recipe, model, base, compiled)
            train.setdefault(cost_key(base.samples_per_s, model), []).append((summary.train_seconds, modelled, 0))
        add_steps(model, _read_lines(folders.run(name) / "selection.jsonl"))
    for name in recipe.eval_sets:
        by_method: dict[str, list[dict]] = {}
        for r in _read_lines(folders.records(f"eval/{name}"), MAX_RECORDS_PER_FILE):
            if r.get("method") in models:
                by_method.setdefault(r["method"], []).append(r)
        for method, records in by_method.items():
            add_steps(models[method], records)
    return Calibration(_factors(train), _factors(steps))
