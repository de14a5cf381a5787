"""Training recipes of ``nue reproduce`` as data: the frozen ``Recipe`` (everything that decides the results of a run,
a docstring per field), its demonstration collections (``Recipe.collections``) and the training runs it implies
(every seed of every model, ``Recipe.training_runs``). The named presets (``v3`` ... ``v12``, ``quick``) are
:mod:`nue.recipes`'; the time estimate of a recipe, stage by stage (``estimate``), is :mod:`nue.recipe_estimate`'s
(re-exported here).

A recipe fixes everything that changes the results: the demonstrations (expert, DART noise, episodes per bin, the
training houses), the models and their training (budget in wall-clock minutes on one core or in samples, batch,
precision, map dropout, closed-loop selection, optional DAgger), and the evaluation sets. How the run is executed
(worker processes, a Ray cluster, folders) is not part of it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from nue.errors import ConfigError
from nue.evaluate.table import METHODS, canonical_method, seed_run_name
from nue.policy.config import ABLATION_PRESETS, get_model_config
from nue.recipe_estimate import (  # noqa: F401  (re-exported: the time estimate of a recipe)
    CostModel, StageEstimate, collection_episodes, episode_counts, estimate, explore_counts, format_duration,
    format_estimate,
)
from nue.sim.episode_sets import get_episode_set
from nue.scene.generator import SPLITS, TRAINING_SPLITS

TABLE_I_KEYS: frozenset[str] = frozenset(m.key for m in METHODS if "+" not in m.key)
"""Table I's trained rows (``Recipe.rows`` maps a model preset onto one of them)."""
TABLE_I_MODELS: tuple[str, ...] = ("nue", *ABLATION_PRESETS, "fr", "nav_a3c")
"""Every trained row of the paper's Table I: NUE, the five ablations, FR and Nav-A3C."""


@dataclass(frozen=True)
class StepPlan:
    """Optimiser steps of one model family."""

    steps: int
    """Step cap; also the length of the cosine schedule, which with a time budget follows whichever of
    steps and time is further along."""
    eval_every: int
    """Held-out evaluation / snapshot interval, steps (closed-loop selection picks among the last snapshots)."""


def training_seed(seed: int, k: int) -> int:
    """The training seed (``TrainConfig.seed``) of training seed index ``k`` under a recipe's ``seed``: ``seed``
    itself for k = 0 (a single-seed recipe trains as before), else the first 32-bit word of
    ``numpy.random.SeedSequence([seed, k])`` modulo 2**31 (stable across processes and machines; never Python's
    salted ``hash()``). Example: seed 0 -> 0 for k = 0."""
    if k < 0:
        raise ConfigError("recipe", f"training seed index {k} < 0")
    return seed if k == 0 else int(np.random.SeedSequence([seed, k]).generate_state(1)[0]) % 2**31


@dataclass(frozen=True)
class Collection:
    """One demonstration collection of a recipe (:meth:`Recipe.collections`)."""

    split: str
    """Training house split (``nue.scene.generator.TRAINING_SPLITS``)."""
    episodes_per_bin: int
    """Training episodes per difficulty bin per house."""
    heldout_per_bin: int
    """Held-out episodes per bin per house."""
    houses: tuple[int, ...] = ()
    """Indices of its houses (empty = all of ``split``)."""

    @property
    def houses_count(self) -> int:
        return len(self.houses) or len(SPLITS[self.split])


@dataclass(frozen=True)
class TrainingRun:
    """One training run of a recipe: a model trained with one of its seeds (what a ``train/<name>`` stage trains)."""

    model: str
    """Model preset."""
    seed_index: int
    """k, from 0 to the model's ``train_seeds`` - 1."""
    name: str
    """Run folder ``runs/<name>`` and the method name of its records: ``<row>`` for k = 0, ``<row>@s<k>`` else
    (:func:`nue.evaluate.table.seed_run_name`), where ``<row>`` is the model's Table I row (``Recipe.row_of``)."""
    seed: int
    """Its training seed (:func:`training_seed` of the recipe's seed and k)."""


@dataclass(frozen=True)
class Recipe:
    """Everything that decides the results of a ``nue reproduce`` run."""

    name: str
    """Preset name."""
    task: str = "paper"
    """Task preset."""
    seed: int = 0
    """Seed of collection, training and evaluation."""
    # -- demonstrations --------------------------------------------------------------------------
    expert: str = "explore"
    """Demonstrating expert: ``geodesic`` or ``explore`` (``nue collect --expert``)."""
    noise: float = 0.3
    """DART noise: probability that a random move is executed instead of the expert's (the label stays)."""
    episodes_per_bin: int = 6
    """Training episodes per difficulty bin per training house."""
    heldout_per_bin: int = 1
    """Held-out episodes per bin per training house (held-out action accuracy)."""
    train_split: str = "train"
    """House split the demonstrations are collected in: ``train`` (the 21 houses every shipped model learned from) or
    ``train_diverse`` (42 houses drawn from the ``diverse`` style distribution, docs/styles.md)."""
    train_houses: tuple[int, ...] = ()
    """Indices of the training houses to collect in (empty = all of ``train_split``)."""
    also_train: tuple[Collection, ...] = ()
    """Further demonstrations every model trains on with ``train_split``'s, one per other training split (stage
    ``collect/<split>``, folder ``demos_<split>``; same expert, noise and seed)."""
    memory: str = "fast"
    """Memory (NeRF) preset run online during collection (and stored in every checkpoint)."""
    # -- training --------------------------------------------------------------------------------
    models: tuple[str, ...] = TABLE_I_MODELS
    """Model presets to train, each on the same demonstrations with the same budget."""
    rows: tuple[tuple[str, str], ...] = ()
    """``(model, row)`` pairs: the Table I row (the method name of its runs and records, a key of
    :data:`nue.evaluate.table.METHODS`) that a model preset fills when it is not its own name's row, e.g. v10's
    ``("nue_gru_lean", "nue")``; a model not named fills the row of its own name (a named model the recipe does
    not train is ignored, as in ``train_seeds``). So the report compares a recipe's
    NUE and ablations with the paper's rows, whatever their variant; the checkpoints name the preset."""
    train_seeds: tuple[tuple[str, int], ...] = ()
    """Training seeds per model, ``(model, count)`` pairs; a model not named trains once. Seed k of a model is the run
    ``<model>@s<k>`` (k = 0: ``<model>``, trained with ``seed`` as before; k >= 1: with :func:`training_seed`); the
    demonstrations, the selection and evaluation episodes and their per-episode seeds are the same for every seed, so
    the seeds' records pair episode by episode. The swapped-maps control runs every seed of a ``swap_maps`` model. A
    named model the recipe does not train (not in ``models``) is ignored."""
    train_minutes: float = 34.0
    """Per-model budget on one core (one torch thread), minutes of ``budget_clock``; 0 = none."""
    budget_clock: str = "cpu"
    """What ``train_minutes`` counts (``nue train --budget-clock``): ``cpu``, each training process's CPU time, so a
    model gets its minutes of one core even when other work shares the machine; ``wall``, wall-clock (the two agree
    on a machine kept otherwise quiet)."""
    train_samples: int = 0
    """Per-model budget in samples seen (steps x samples per step); 0 = none (then ``steps`` caps)."""
    steps: tuple[tuple[str, StepPlan], ...] = (("nue", StepPlan(12_000, 750)), ("fr", StepPlan(30_000, 1_500)),
                                               ("nav_a3c", StepPlan(30_000, 1_500)))
    """Step plan per model kind (``ModelConfig.kind``: ``nue`` covers NUE and its ablations)."""
    batch_size: int = 64
    """Samples per optimiser step; recurrent models (Nav-A3C) get ``batch_size // seq_len`` sequences."""
    seq_len: int = 8
    """Recurrent models: steps per training sequence."""
    lr: float = 1e-3
    """Peak learning rate."""
    warmup: int = 100
    """Linear warm-up steps."""
    precision: str = "auto"
    """``auto`` (bf16 autocast where the device runs bfloat16 natively, else fp32), ``fp32`` or ``bf16``. Forced
    bf16 on a CPU without AVX512-BF16 is emulated and ~7x slower (benchmarks/results/train_no_native_bf16.json),
    which under a time budget cuts the samples seen 7-fold; held-out accuracy of bf16 and fp32 is the same step for
    step."""
    map_dropout: float = 0.2
    """Probability of replacing a sample's memory maps by another sample's; models that read maps only."""
    select: str = "closed_loop"
    """How ``best.pt`` is chosen: ``closed_loop`` (snapshots run on ``episodes/<select_set>``) or ``accuracy``."""
    select_set: str = "select"
    """Closed-loop selection's episode set (:data:`nue.sim.episode_sets.EPISODE_SETS`), in the houses of
    ``train_split``: ``select`` (21 ``train`` houses) or ``select_diverse`` (21 of the 42 ``train_diverse``)."""
    select_candidates: int = 3
    """Closed-loop selection: how many of the last snapshots compete."""
    dagger_rounds: int = 0
    """DAgger rounds after behaviour cloning (0 = none)."""
    dagger_beta: float = 0.5
    """DAgger: expert-action probability in round r is beta ** r."""
    dagger_steps: int = 1_000
    """DAgger: optimiser-step cap per round (the round's wall-clock budget is ``train_minutes``)."""
    dagger_episodes_per_bin: int = 0
    """DAgger: roll out the first k training episodes per bin per house (0 = all)."""
    # -- evaluation ------------------------------------------------------------------------------
    eval_sets: tuple[str, ...] = ("val252", "val_plain")
    """Episode sets (``nue.sim.episode_sets``) every model runs; a set that extends another also reports it."""
    eval_houses: tuple[int, ...] = ()
    """Only these houses of each set (empty = all 14)."""
    eval_max_episodes: int = 0
    """Only the first N episodes per house (0 = all); smoke runs."""
    eval_max_steps: int = 0
    """Override the task's step limit (0 = keep it); smoke runs only."""
    explore_sets: tuple[str, ...] = ()
    """Episode sets from whose starts the exploration benchmark runs (stage ``explore/<set>``,
    :mod:`nue.evaluate.exploration`: ``explore_steps`` steps with another house's goal photo, the seen floor area at 100
    / 200 / 500 / 800 steps, RESULTS.md's ratios to the no-f_u ablation's row); none by default."""
    explore_models: tuple[str, ...] = ()
    """Models (every seed) the exploration benchmark runs, beside ``expert-explore`` and ``random``."""
    explore_houses: tuple[int, ...] = ()
    """Only these houses of each explore set (empty = all; at least two: a start's goal photo is the next house's)."""
    explore_per_bin: int = 1
    """Starts per difficulty bin per house: the first k episodes of each bin (0 = all)."""
    explore_steps: int = 800
    """Steps of every exploration run."""
    experts: tuple[str, ...] = ("expert", "expert-explore")
    """Reference rows run on every set: ``expert`` (geodesic), ``expert-explore``."""
    swap_maps: tuple[str, ...] = ("nue",)
    """Models also run with another episode's maps (the swapped-maps control) on every evaluation set."""
    last_mile: tuple[str, ...] = ()
    """Models also run wrapped in SLING's last-mile module (``sling+<run>`` rows, :mod:`nue.policy.last_mile`) on
    every evaluation set, every seed of each."""

    def __post_init__(self) -> None:
        for m in self.models:
            get_model_config(m)
        if self.train_split not in TRAINING_SPLITS:
            raise ConfigError("recipe", f"train_split {self.train_split!r} is not a training split; one of "
                                        f"{', '.join(TRAINING_SPLITS)}")
        for s in self.eval_sets:
            if get_episode_set(s).split in TRAINING_SPLITS:
                raise ConfigError("recipe", f"eval_sets: {s!r} is in training houses, not an evaluation set")
        splits = [c.split for c in self.collections()]
        if (len(set(splits)) < len(splits) or not set(splits) <= set(TRAINING_SPLITS)
                or any(c.episodes_per_bin < 1 or c.heldout_per_bin < 0 for c in self.also_train)):
            raise ConfigError("recipe", "also_train: one collection (episodes_per_bin >= 1, heldout_per_bin >= 0) "
                                        "per training split other than train_split")
        if (sel := get_episode_set(self.select_set)).split not in splits or not sel.bin_per_house:
            raise ConfigError("recipe", f"select_set {self.select_set!r} is not a selection set of the "
                                        f"{' + '.join(map(repr, splits))} houses")
        if self.train_minutes <= 0 and self.train_samples <= 0 and not self.steps:
            raise ConfigError("recipe", "needs a training budget: train_minutes, train_samples or steps")
        if set(self.swap_maps) - set(self.models):
            raise ConfigError("recipe", "swap_maps names a model the recipe does not train")
        if set(self.explore_models) - set(self.models) or (self.explore_models and not self.explore_sets):
            raise ConfigError("recipe", "explore_models names a model the recipe does not train, or no explore_sets")
        for s in self.explore_sets:
            if get_episode_set(s).split in TRAINING_SPLITS:
                raise ConfigError("recipe", f"explore_sets: {s!r} is in training houses")
        if self.explore_steps < 1 or self.explore_per_bin < 0 or len(self.explore_houses) == 1:
            raise ConfigError("recipe", "explore: steps >= 1, per_bin >= 0 and not exactly one house")
        if set(self.last_mile) - set(self.models):
            raise ConfigError("recipe", "last_mile names a model the recipe does not train")
        unknown = [r for _, r in self.rows if canonical_method(r) != r or r not in TABLE_I_KEYS]
        if unknown:
            raise ConfigError("recipe", f"rows: {', '.join(unknown)} is not a Table I row key")
        filled = [self.row_of(m) for m in self.models]
        if len(set(filled)) < len(filled):
            raise ConfigError("recipe", "rows: two models fill the same Table I row")
        named = [m for m, _ in self.train_seeds]
        for m in named:
            get_model_config(m)
        if len(set(named)) < len(named):
            raise ConfigError("recipe", "train_seeds names a model twice")
        if any(not isinstance(n, int) or n < 1 for _, n in self.train_seeds):
            raise ConfigError("recipe", "train_seeds: a model's number of seeds must be an integer >= 1")

    def collections(self) -> tuple[Collection, ...]:
        """Every demonstration collection the models train on, ``train_split``'s first."""
        return (Collection(self.train_split, self.episodes_per_bin, self.heldout_per_bin, self.train_houses),
                *self.also_train)

    def row_of(self, model: str) -> str:
        """The Table I row (run and record name) ``model`` fills (``rows``; else its own name)."""
        return dict(self.rows).get(model, model)

    def seeds_of(self, model: str) -> int:
        """Training seeds of ``model`` (1 unless ``train_seeds`` names it)."""
        return dict(self.train_seeds).get(model, 1)

    def training_runs(self, models: Sequence[str] | None = None) -> tuple[TrainingRun, ...]:
        """Every training run of the recipe (of ``models``, default all), seed by seed: each model's seed 0 in the
        order of ``models`` (the single-seed recipe's runs), then each seed 1, and so on, so a run cut short has
        whole seeds of every model first."""
        models = self.models if models is None else tuple(models)
        most = max((self.seeds_of(m) for m in models), default=0)
        return tuple(TrainingRun(m, k, seed_run_name(self.row_of(m), k), training_seed(self.seed, k))
                     for k in range(most) for m in models if k < self.seeds_of(m))

    def training_run(self, name: str) -> TrainingRun:
        """The training run named ``name`` (``nue``, ``nue@s1``); ConfigError if the recipe has none so named."""
        for run in self.training_runs():
            if run.name == name:
                return run
        raise ConfigError("recipe", f"{self.name!r} has no training run {name!r}")

    def step_plan(self, model: str) -> StepPlan:
        """The step plan of a model preset (by its kind)."""
        kind = get_model_config(model).kind
        plans = dict(self.steps)
        if kind not in plans:
            raise ConfigError("recipe", f"no step plan for model kind {kind!r}")
        return plans[kind]

    def batch_for(self, model: str) -> int:
        """``nue train --batch-size`` of a model: samples, or sequences for a recurrent model."""
        return max(1, self.batch_size // self.seq_len) if get_model_config(model).recurrent else self.batch_size

    def samples_per_step(self, model: str) -> int:
        """Samples one optimiser step of ``model`` sees."""
        return self.batch_for(model) * (self.seq_len if get_model_config(model).recurrent else 1)

    def train_steps(self, model: str) -> int:
        """Optimiser steps of ``model``: the samples budget divided by its samples per step, else its plan's cap."""
        if self.train_samples > 0:
            return math.ceil(self.train_samples / self.samples_per_step(model))
        return self.step_plan(model).steps

    def summary(self) -> str:
        """One paragraph for RESULTS.md (the full recipe is the run's ``recipe.json``)."""
        houses = " and ".join(f"{c.episodes_per_bin} + {c.heldout_per_bin} held-out episodes per bin in {c.houses_count} "
                              f"{'training' if c.split == 'train' else c.split} houses" for c in self.collections())
        if self.train_samples > 0:
            budget = f"{self.train_samples:,} samples each"
        elif self.train_minutes > 0:
            budget = f"{self.train_minutes:g} min each on one core (one torch thread)"
        else:
            budget = "a fixed number of steps each"
        dagger = f", then {self.dagger_rounds} DAgger round(s) (beta {self.dagger_beta})" if self.dagger_rounds else ""
        rows = (f" (Table I rows: {', '.join(f'{m} as {r}' for m, r in self.rows)})" if self.rows else "")
        seeds = (f"; training seeds: {', '.join(f'{m} x{n}' for m, n in self.train_seeds)} "
                 f"({len(self.training_runs())} runs; the others once)" if self.train_seeds else "")
        last_mile = f"; SLING last mile: {', '.join(self.last_mile)}" if self.last_mile else ""
        explore = (f"; exploration benchmark from {', '.join(self.explore_sets)}'s starts: "
                   f"{', '.join(self.explore_models)}, {self.explore_steps} steps" if self.explore_sets else "")
        select = (f"best.pt by closed-loop selection among the last {self.select_candidates} snapshots on "
                  f"episodes/{self.select_set}"
                  if self.select == "closed_loop" else "best.pt by held-out action accuracy")
        return (f"{self.name}: demonstrations from the {self.expert} expert with DART noise {self.noise:g}, "
                f"{houses} "
                f"(memory preset {self.memory}); {len(self.models)} models ({', '.join(self.models)}){rows} trained for "
                f"{budget}, batch {self.batch_size} samples, {self.precision}, map dropout {self.map_dropout:g} for the "
                f"models that read maps{dagger}{seeds}; {select}; evaluated on {', '.join(self.eval_sets)} "
                f"(+ {', '.join(self.experts) or 'no experts'}; swapped maps: {', '.join(self.swap_maps) or 'none'}"
                f"{last_mile}{explore})")

    def to_dict(self) -> dict:
        """Plain JSON data (stored in the run folder; a resumed run must match it exactly). ``train_split`` and
        ``select_set`` only when they are not ``train`` / ``select``, and ``also_train``, ``last_mile``, ``rows`` and the
        ``explore_*`` fields only when they name something, so runs started before they existed resume."""
        d = _jsonable(dataclasses.asdict(self))
        if d["train_split"] == "train":
            del d["train_split"]
        if not d["also_train"]:
            del d["also_train"]
        if not d["explore_sets"]:
            for k in ("explore_sets", "explore_models", "explore_houses", "explore_per_bin", "explore_steps"):
                del d[k]
        if d["select_set"] == "select":
            del d["select_set"]
        if not d["last_mile"]:
            del d["last_mile"]
        if not d["rows"]:
            del d["rows"]
        return d

    def replace(self, **changes) -> "Recipe":
        return dataclasses.replace(self, **changes)


def _jsonable(x):
    if isinstance(x, dict):
        return {k: _jsonable(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_jsonable(v) for v in x]
    return x
