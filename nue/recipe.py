"""Training recipes of ``nue reproduce`` as data: one frozen ``Recipe`` per way of building Table I, the named
presets ``RECIPES``, and the time estimate a recipe implies, stage by stage (``estimate``).

A recipe fixes everything that changes the results: the demonstrations (expert, DART noise, episodes per
bin), the models and their training (budget in wall-clock minutes on one core or in samples, batch,
precision, map dropout, closed-loop selection, optional DAgger), and the evaluation sets. How the run is
executed (worker processes, a Ray cluster, folders) is not part of it. ``v6``, the default, is the recipe of the
shipped ``checkpoints/*.pt`` (``checkpoints/README.md``): ``v5`` with a budget of 256,000 samples per model, the same
on any machine. ``v5`` trains each model for 50 minutes on one core (its models are ``results/v5/checkpoints/``),
``v3`` for 34 minutes with three snapshots competing in the selection; ``quick`` is tiny everything, for CI.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Sequence

from nue.errors import ConfigError
from nue.policy.config import ABLATION_PRESETS, get_model_config
from nue.sim.episode_sets import EPISODE_SETS, get_episode_set, per_house_bin
from nue.scene.generator import SPLITS

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
    train_houses: tuple[int, ...] = ()
    """Indices of the training houses to collect in (empty = all 21)."""
    memory: str = "fast"
    """Memory (NeRF) preset run online during collection (and stored in every checkpoint)."""
    # -- training --------------------------------------------------------------------------------
    models: tuple[str, ...] = TABLE_I_MODELS
    """Model presets to train, each on the same demonstrations with the same budget."""
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
    """How ``best.pt`` is chosen: ``closed_loop`` (snapshots run on ``episodes/select``) or ``accuracy``."""
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

    def __post_init__(self) -> None:
        for m in self.models:
            get_model_config(m)
        for s in self.eval_sets:
            get_episode_set(s)
        if self.train_minutes <= 0 and self.train_samples <= 0 and not self.steps:
            raise ConfigError("recipe", "needs a training budget: train_minutes, train_samples or steps")
        if set(self.swap_maps) - set(self.models):
            raise ConfigError("recipe", "swap_maps names a model the recipe does not train")

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
        houses = len(self.train_houses) or len(SPLITS["train"])
        if self.train_samples > 0:
            budget = f"{self.train_samples:,} samples each"
        elif self.train_minutes > 0:
            budget = f"{self.train_minutes:g} min each on one core (one torch thread)"
        else:
            budget = "a fixed number of steps each"
        dagger = f", then {self.dagger_rounds} DAgger round(s) (beta {self.dagger_beta})" if self.dagger_rounds else ""
        select = (f"best.pt by closed-loop selection among the last {self.select_candidates} snapshots on episodes/select"
                  if self.select == "closed_loop" else "best.pt by held-out action accuracy")
        return (f"{self.name}: demonstrations from the {self.expert} expert with DART noise {self.noise:g}, "
                f"{self.episodes_per_bin} + {self.heldout_per_bin} held-out episodes per bin in {houses} training houses "
                f"(memory preset {self.memory}); {len(self.models)} models ({', '.join(self.models)}) trained for "
                f"{budget}, batch {self.batch_size} samples, {self.precision}, map dropout {self.map_dropout:g} for the "
                f"models that read maps{dagger}; {select}; evaluated on {', '.join(self.eval_sets)} "
                f"(+ {', '.join(self.experts) or 'no experts'}; swapped maps: {', '.join(self.swap_maps) or 'none'})")

    def to_dict(self) -> dict:
        """Plain JSON data (stored in the run folder; a resumed run must match it exactly)."""
        return _jsonable(dataclasses.asdict(self))

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

RECIPES: dict[str, Recipe] = {
    "v6": V6,
    "v5": V5,
    "v3": V3,
    "quick": V3.replace(
        name="quick", expert="geodesic", episodes_per_bin=1, heldout_per_bin=0, train_houses=(0,), train_minutes=0.0,
        steps=(("nue", StepPlan(2, 2)), ("fr", StepPlan(2, 2)), ("nav_a3c", StepPlan(2, 2))), batch_size=4,
        seq_len=2, warmup=1, precision="fp32", select="accuracy", eval_houses=(0,), eval_max_episodes=1,
        eval_max_steps=5, experts=("expert",)),
}
"""Named recipes: ``v6`` (the default and the shipped checkpoints': v5 with 256k samples per model instead of 50
minutes), ``v5``, ``v3`` (docs/history/checkpoints.md) and ``quick`` (CI)."""


def get_recipe(name: str) -> Recipe:
    """A recipe preset by name; unknown -> ConfigError."""
    try:
        return RECIPES[name]
    except KeyError:
        raise ConfigError("--recipe", f"unknown recipe {name!r}; known: {', '.join(RECIPES)}") from None


# --- time estimate --------------------------------------------------------------------------------
@dataclass(frozen=True)
class CostModel:
    """Costs measured in earlier runs on 2-core x86 CPUs, which the estimate scales (each field says where its
    number comes from; docs/history/ has the runs)."""

    collect_s_per_step: float = 0.052
    """Collection, seconds per step per worker (the v5 / v6 collection: 63,999 steps in 27.7 min on 2 workers)."""
    steps_per_episode: tuple[tuple[str, float], ...] = (("geodesic", 36.8), ("explore", 102.0))
    """Noise-free episode length per expert, steps (v1: 41,756 / 1,134; explore: v3's 145 / 1.42)."""
    noise_length_factor: float = 1.4
    """Episodes grow by 1 + this x noise (v2: 52.3 steps at noise 0.3 vs 36.8 without)."""
    house_s: float = 3.0
    """Generating one house (and loading it), seconds."""
    samples_per_s: tuple[tuple[str, float], ...] = (("nue", 98.0), ("fr", 200.0), ("nav_a3c", 232.0))
    """Eager training throughput per model kind, two trainings side by side on a 2-core Xeon without native bf16
    (fp32): the compiled rates of the v6 run (``results/reproduce/run/stages``, 256,000 samples in ``train_seconds``:
    the six NUE-family models 136-163 samples/s, mean 147; FR 330; Nav-A3C 334) divided by ``compiled_speedup``."""
    compiled_speedup: tuple[tuple[str, float], ...] = (("nue", 1.5), ("fr", 1.65), ("nav_a3c", 1.44))
    """Training throughput with ``nue train --compile`` relative to eager, per model kind: eager and compiled steps
    interleaved in one process (batch 64 / 8 x 8 sequences, fp32, one thread, synthetic data, a 2-core Xeon without
    native bf16)."""
    select_s_per_episode: tuple[tuple[str, float], ...] = (("nue", 11.5), ("fr", 1.7), ("nav_a3c", 1.9))
    """Closed-loop selection, seconds per episode (400-step limit; the v6 run: 2 x 21 episodes in 7.2-8.6 min per
    NUE-family model, 73 s FR, 79 s Nav-A3C)."""
    eval_s_per_episode: tuple[tuple[str, float], ...] = (("nue", 13.3), ("fr", 3.4), ("nav_a3c", 3.9),
                                                         ("expert", 0.2), ("expert-explore", 1.7), ("swap", 4.3))
    """Evaluation, seconds per episode per worker, two workers: the mean ``wall_time`` of the v6 run's val252
    records (the six NUE-family models 12.5-14.1 s, 325-381 steps an episode at 36-40 ms a step). The swapped-maps
    control replays maps recorded along the expert's run of another episode, so its agent neither renders nor
    trains a memory."""
    train_overhead_s: float = 10.0
    """Per model: loading the demonstrations, building the model, checkpoints, seconds."""
    eval_overhead_s: float = 5.0
    """Per method and set: loading checkpoints and houses in the workers, seconds."""
    report_s: float = 30.0
    """Report and RESULTS.md, seconds."""


@dataclass(frozen=True)
class StageEstimate:
    """Estimated wall-clock of one stage."""

    stage: str
    """Stage name (``collect``, ``train``, ``eval/<set>``, ...)."""
    seconds: float
    """Estimated wall-clock, seconds."""
    detail: str
    """How it was computed."""
    done: bool = False
    """Finished by an earlier call of a resumed run (``seconds`` is then 0: nothing of it is left)."""


def _kind_cost(table: tuple[tuple[str, float], ...], model: str) -> float:
    costs = dict(table)
    return costs[model] if model in costs else costs[get_model_config(model).kind]


def _makespan(durations: list[float], slots: int) -> float:
    """Wall-clock of jobs started in order on ``slots`` parallel slots, each taking the next free one."""
    free = [0.0] * max(1, slots)
    for d in durations:
        i = free.index(min(free))
        free[i] += d
    return max(free) if durations else 0.0


def episode_counts(recipe: Recipe) -> dict[str, int]:
    """Evaluation episodes per set of a recipe (its houses and first-N limits applied)."""
    out = {}
    for name in recipe.eval_sets:
        spec = EPISODE_SETS[name]
        houses = len(recipe.eval_houses) or len(SPLITS[spec.split])
        per_house = 3 * per_house_bin(name)
        out[name] = houses * (min(per_house, recipe.eval_max_episodes) if recipe.eval_max_episodes else per_house)
    return out


def collection_episodes(recipe: Recipe) -> int:
    """Demonstration episodes of a recipe: houses x 3 bins x (train + held-out per bin)."""
    houses = len(recipe.train_houses) or len(SPLITS["train"])
    return houses * 3 * (recipe.episodes_per_bin + recipe.heldout_per_bin)


def estimate(recipe: Recipe, workers: int = 1, cost: CostModel = CostModel(), compiled: bool = False,
             models: Sequence[str] | None = None) -> list[StageEstimate]:
    """Wall-clock per stage of ``recipe`` with ``workers`` parallel processes (a Ray cluster: its CPUs); ``compiled``:
    training with ``torch.compile``; ``models``: the models the training stage still has to train (default: all)."""
    w = max(1, workers)
    out = []
    houses = (len(recipe.train_houses) or len(SPLITS["train"])) + sum(
        len(recipe.eval_houses) or len(SPLITS[EPISODE_SETS[s].split]) for s in recipe.eval_sets)
    out.append(StageEstimate("scenes", houses * cost.house_s, f"{houses} houses x {cost.house_s:.0f} s (kept if present)"))
    n_eps = collection_episodes(recipe)
    length = dict(cost.steps_per_episode)[recipe.expert] * (1 + cost.noise_length_factor * recipe.noise)
    out.append(StageEstimate("collect", n_eps * length * cost.collect_s_per_step / w,
                             f"{n_eps} episodes x ~{length:.0f} steps x {cost.collect_s_per_step} s / {w} worker(s)"))
    jobs = []
    select_eps = 21 if recipe.select == "closed_loop" else 0
    for m in (recipe.models if models is None else models):
        if recipe.train_minutes > 0:
            t = 60 * recipe.train_minutes
        else:
            rate = _kind_cost(cost.samples_per_s, m) * (_kind_cost(cost.compiled_speedup, m) if compiled else 1.0)
            t = recipe.train_steps(m) * recipe.samples_per_step(m) / rate
        rounds = 1 + recipe.dagger_rounds
        rollouts = recipe.dagger_rounds * n_eps * length * cost.collect_s_per_step * 1.2
        jobs.append(cost.train_overhead_s + rounds * t + rollouts + select_eps * recipe.select_candidates * _kind_cost(cost.select_s_per_episode, m))
    select = (f" + closed-loop selection ({recipe.select_candidates} x 21 episodes)" if select_eps else "")
    budget = (f"{recipe.train_minutes:g} min" if recipe.train_minutes > 0
              else f"{recipe.train_samples:,} samples" if recipe.train_samples > 0 else "its steps")
    side = f"{min(w, len(jobs))} side by side on one core each" if w > 1 else "one at a time on one core"
    out.append(StageEstimate("train", _makespan(jobs, w), f"{len(jobs)} models x {budget}{' (compiled)' if compiled else ''}{select}"
                             f"{f' x {1 + recipe.dagger_rounds} rounds' if recipe.dagger_rounds else ''}, {side}"))
    scale = min(1.0, recipe.eval_max_steps / 800) if recipe.eval_max_steps else 1.0
    for name, n in episode_counts(recipe).items():
        per_ep = sum(_kind_cost(cost.eval_s_per_episode, m) for m in (*recipe.models, *recipe.experts))
        methods = len(recipe.models) + len(recipe.experts)
        out.append(StageEstimate(f"eval/{name}", (n * per_ep * scale + methods * cost.eval_overhead_s) / w,
                                 f"{n} episodes x {methods} methods / {w} worker(s)"))
        if recipe.swap_maps:
            swap = len(recipe.swap_maps)
            out.append(StageEstimate(f"eval/{name}+swap", (n * swap * dict(cost.eval_s_per_episode)["swap"] * scale
                                                           + swap * cost.eval_overhead_s) / w,
                                     f"{n} episodes x {swap} model(s), swapped maps"))
    out.append(StageEstimate("report", cost.report_s, "tables, coverage plot, RESULTS.md"))
    return out


def format_duration(seconds: float) -> str:
    """``1 h 05 min``, ``12 min``, ``40 s``."""
    if seconds < 60:
        return f"{seconds:.0f} s"
    minutes = int(round(seconds / 60))
    return f"{minutes // 60} h {minutes % 60:02d} min" if minutes >= 60 else f"{minutes} min"


def format_estimate(stages: list[StageEstimate]) -> str:
    """The estimate as printed before a run: one line per stage, then the total."""
    width = max(len(s.stage) for s in stages)
    lines = [f"  {s.stage:<{width}}  {'done' if s.done else format_duration(s.seconds):>11}  {s.detail}" for s in stages]
    total = sum(s.seconds for s in stages)
    left = "  left to run" if any(s.done for s in stages) else ""
    return "\n".join(lines + [f"  {'total':<{width}}  {format_duration(total):>11}{left}"])
