"""Training recipes of ``nue reproduce`` as data: one frozen ``Recipe`` per way of building Table I, the named
presets ``RECIPES``, and the training runs a recipe implies (every seed of every model, ``Recipe.training_runs``).
The time estimate of a recipe, stage by stage (``estimate``), is :mod:`nue.recipe_estimate`'s (re-exported here).

A recipe fixes everything that changes the results: the demonstrations (expert, DART noise, episodes per
bin), the models and their training (budget in wall-clock minutes on one core or in samples, batch,
precision, map dropout, closed-loop selection, optional DAgger), and the evaluation sets. How the run is
executed (worker processes, a Ray cluster, folders) is not part of it. ``v10``, the default (``DEFAULT_RECIPE``), is
the recipe chosen in issue 37: a recurrent NUE and its ablations on the ``lean`` memory, 3 training seeds for the
compared rows, the memory baselines and the SLING rows. ``v6`` is the recipe of the shipped ``checkpoints/*.pt``
(``checkpoints/README.md``) and of today's RESULTS.md: ``v5`` with a budget of 256,000 samples per model, the same on
any machine. ``v7`` is ``v6`` with 3 training seeds for NUE, the no-f_u and all-off ablations and FR
(``Recipe.train_seeds``: a row of Table I is then the seeds' runs). ``v5`` trains each model for 50 minutes on one
core (its models are ``results/v5/checkpoints/``), ``v3`` for 34 minutes with three snapshots competing in the
selection; ``v8`` is ``v7`` with the SLING rows (NUE, FR and Nav-A3C wrapped in the last-mile module); ``v9`` is
``v8`` on the ``lean`` memory with VGM and NRNS; ``quick`` is tiny everything, for CI (with 2 training seeds of NUE
and its SLING row, so CI runs those paths end to end).
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
    CostModel, StageEstimate, collection_episodes, episode_counts, estimate, format_duration, format_estimate,
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
        if (sel := get_episode_set(self.select_set)).split != self.train_split or not sel.bin_per_house:
            raise ConfigError("recipe", f"select_set {self.select_set!r} is not a selection set of the "
                                        f"{self.train_split!r} houses")
        if self.train_minutes <= 0 and self.train_samples <= 0 and not self.steps:
            raise ConfigError("recipe", "needs a training budget: train_minutes, train_samples or steps")
        if set(self.swap_maps) - set(self.models):
            raise ConfigError("recipe", "swap_maps names a model the recipe does not train")
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
        houses = len(self.train_houses) or len(SPLITS[self.train_split])
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
        select = (f"best.pt by closed-loop selection among the last {self.select_candidates} snapshots on episodes/select"
                  if self.select == "closed_loop" else "best.pt by held-out action accuracy")
        return (f"{self.name}: demonstrations from the {self.expert} expert with DART noise {self.noise:g}, "
                f"{self.episodes_per_bin} + {self.heldout_per_bin} held-out episodes per bin in {houses} training houses "
                f"(memory preset {self.memory}); {len(self.models)} models ({', '.join(self.models)}){rows} trained for "
                f"{budget}, batch {self.batch_size} samples, {self.precision}, map dropout {self.map_dropout:g} for the "
                f"models that read maps{dagger}{seeds}; {select}; evaluated on {', '.join(self.eval_sets)} "
                f"(+ {', '.join(self.experts) or 'no experts'}; swapped maps: {', '.join(self.swap_maps) or 'none'}"
                f"{last_mile})")

    def to_dict(self) -> dict:
        """Plain JSON data (stored in the run folder; a resumed run must match it exactly). ``train_split`` and
        ``select_set`` only when they are not ``train`` / ``select``, and ``last_mile`` and ``rows`` only when they name a model, so runs started before they existed resume."""
        d = _jsonable(dataclasses.asdict(self))
        if d["train_split"] == "train":
            del d["train_split"]
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


V3 = Recipe(name="v3")
V5 = V3.replace(name="v5", train_minutes=50.0, select_candidates=2,
                steps=(("nue", StepPlan(30_000, 1_500)), ("fr", StepPlan(80_000, 3_000)),
                       ("nav_a3c", StepPlan(30_000, 1_000))))

V6 = V5.replace(name="v6", train_minutes=0.0, train_samples=256_000)
"""v5 with a budget in samples seen instead of minutes: the same for every model whatever the machine, its load or
how many sessions a run spans (a time budget gives a slower machine's models fewer samples). 256,000 samples are
4,000 optimiser steps of 64 samples (Nav-A3C: 8 sequences of 8); why that many: docs/history/checkpoints.md."""

V7 = V6.replace(name="v7", train_seeds=(("nue", 3), ("abl_at_cbam", 3), ("abl_none", 3), ("fr", 3)))
"""v6 with 3 training seeds for NUE, the no-f_u ablation (``abl_at_cbam``: f_u off, AT and CBAM on — NUE without
f_u; ``abl_fu`` is the other way round, f_u alone), the all-off ablation (``abl_none``) and FR, so their rows and the
comparisons between them pool seeds x episodes (issue 37, item 6); the other models train once. Only the training
seed differs between a model's seeds."""

V8 = V7.replace(name="v8", last_mile=("nue", "fr", "nav_a3c"))
"""v7 with the SLING rows of Table I (issue 40): NUE (every seed), FR (every seed) and Nav-A3C also run wrapped in the
last-mile module on every evaluation set."""

TABLE_I_MODELS_LEAN: tuple[str, ...] = (tuple(f"{m}_lean" for m in ("nue", *ABLATION_PRESETS))
                                        + ("fr", "nav_a3c", "vgm", "nrns"))
"""Table I's trained rows on the ``lean`` memory: the ``_lean`` twins of NUE and its ablations (30 x 40 maps), FR,
Nav-A3C and the memory baselines VGM and NRNS (which read no maps; MSM could not be identified, docs/msm.md)."""

MEMORY_BASELINE_STEPS: tuple[tuple[str, StepPlan], ...] = (("vgm", StepPlan(30_000, 1_500)),
                                                           ("nrns", StepPlan(30_000, 1_500)))
"""Step plans of the memory baselines' kinds (under a samples budget only ``eval_every`` is read): VGM's held-out
accuracy, NRNS's held-out distance error every 1,500 steps, as NUE's."""

V9 = V8.replace(name="v9", memory="lean", models=TABLE_I_MODELS_LEAN, steps=V8.steps + MEMORY_BASELINE_STEPS,
                rows=tuple((f"{m}_lean", m) for m in ("nue", *ABLATION_PRESETS)),
                train_seeds=(("nue_lean", 3), ("abl_at_cbam_lean", 3), ("abl_none_lean", 3), ("fr", 3), ("nav_a3c", 3),
                             ("vgm", 3), ("nrns", 3)),
                swap_maps=("nue_lean",), last_mile=("nue_lean", "fr", "nav_a3c"))
"""v8 on the ``lean`` memory (issue 38: 1.7x less per NUE episode step, 1.4x faster NUE training), with the memory
baselines VGM and NRNS (issue 39) and 3 training seeds for NUE, the no-f_u and all-off ablations, FR, Nav-A3C, VGM
and NRNS. A candidate, not the default: its ``_lean`` models fill NUE's and the ablations' rows (``rows``: run ``nue``
trains ``nue_lean``) (results/lean/README.md has the
comparison with ``fast`` that decides it)."""

TABLE_I_MODELS_GRU_LEAN: tuple[str, ...] = (("nue_gru_lean",) + tuple(f"{m}_gru_lean" for m in ABLATION_PRESETS)
                                            + ("fr", "nav_a3c", "vgm", "nrns"))
"""Table I's trained rows with a recurrent NUE: ``nue_gru_lean`` and its ablations with the same 256-unit GRU after
the fusion (``abl_*_gru_lean``), on the ``lean`` memory; the baselines as in v9."""

V10 = V9.replace(name="v10", models=TABLE_I_MODELS_GRU_LEAN,
                 rows=tuple((f"{m}_gru_lean", m) for m in ("nue", *ABLATION_PRESETS)),
                 train_seeds=(("nue_gru_lean", 3), ("abl_at_cbam_gru_lean", 3), ("abl_none_gru_lean", 3), ("fr", 3),
                              ("nav_a3c", 3), ("vgm", 3), ("nrns", 3)),
                 swap_maps=("nue_gru_lean",), last_mile=("nue_gru_lean", "fr", "nav_a3c"))
"""v9 with a recurrent NUE and its ablations carrying the same state, so an ablation row differs from NUE only by the
components the paper switches off; the default (``DEFAULT_RECIPE``). Why it was chosen (issue 37): ``nue_gru_lean``
reached 83.3% on val252 in each of 3 training seeds against reactive ``nue_lean``'s 77.8 / 78.2 / 79.0%, +5.0 points
[+0.4, +9.8] pooled over seeds x episodes (results/gru/README.md); no other change to the hand-off measured better.
Recurrent models train on ``batch_size // seq_len`` sequences, the same samples per step."""

V11 = V10.replace(name="v11", train_split="train_diverse", episodes_per_bin=3, heldout_per_bin=1,
                 select_set="select_diverse", eval_sets=("val252", "val_plain", "val_pale"))
"""v10 trained in the 42 style-diverse ``train_diverse`` houses (issue 43, docs/styles.md), on both held-out families:
3 + 1 held-out episodes per bin per house (v10's 378 training episodes), 256k samples per model, ``select_diverse``.
Not the default: its NUE-GRU lost 5.2 SR points on val252 against v10's (2 x 3 seeds, [-10.8, +0.2]); FR did not."""

RECIPES: dict[str, Recipe] = {
    "v6": V6,
    "v7": V7,
    "v8": V8,
    "v9": V9,
    "v10": V10,
    "v11": V11,
    "v5": V5,
    "v3": V3,
    "quick": V3.replace(
        name="quick", expert="geodesic", episodes_per_bin=1, heldout_per_bin=0, train_houses=(0,), train_minutes=0.0,
        steps=(("nue", StepPlan(2, 2)), ("fr", StepPlan(2, 2)), ("nav_a3c", StepPlan(2, 2))), batch_size=4,
        seq_len=2, warmup=1, precision="fp32", select="accuracy", eval_houses=(0,), eval_max_episodes=1,
        eval_max_steps=5, experts=("expert",), train_seeds=(("nue", 2),), last_mile=("nue",)),
}
"""Named recipes: ``v10`` (the default: v9 with a recurrent NUE and ablations), ``v6`` (the shipped checkpoints' and
RESULTS.md's: v5 with 256k samples per model instead of 50 minutes), ``v7`` (v6 with 3 training seeds for NUE,
abl_at_cbam, abl_none and FR), ``v8`` (v7 with the SLING rows of NUE, FR and Nav-A3C), ``v9`` (v8 on the lean memory
with VGM and NRNS, 3 seeds for 7 rows), ``v11`` (v10 trained in the style-diverse houses), ``v5``, ``v3`` (docs/history/checkpoints.md) and ``quick`` (CI; 2 training
seeds of NUE, and its SLING row)."""

DEFAULT_RECIPE = "v10"
"""What ``nue reproduce`` runs without ``--recipe``."""


def get_recipe(name: str) -> Recipe:
    """A recipe preset by name; unknown -> ConfigError."""
    try:
        return RECIPES[name]
    except KeyError:
        raise ConfigError("--recipe", f"unknown recipe {name!r}; known: {', '.join(RECIPES)}") from None
