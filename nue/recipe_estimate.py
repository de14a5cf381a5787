"""The time estimate of a ``nue reproduce`` recipe (:class:`nue.recipe.Recipe`), stage by stage: measured costs
(:class:`CostModel`) scaled by the recipe's houses, demonstrations, training runs (every seed of every model) and
evaluation episodes, on ``workers`` parallel processes; printed before a run and by ``nue reproduce --estimate``."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Mapping, Sequence

from nue.policy.config import get_model_config
from nue.scene.generator import SPLITS
from nue.sim.episode_sets import EPISODE_SETS, per_house_bin

if TYPE_CHECKING:
    from nue.recipe import Recipe


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
    samples_per_s: tuple[tuple[str, float], ...] = (("nue", 98.0), ("fr", 200.0), ("nav_a3c", 232.0), ("nrns", 132.0),
                                                    ("vgm", 71.0))
    """Eager training throughput per model kind, two trainings side by side on a 2-core Xeon without native bf16
    (fp32): the compiled rates of the v6 run (``results/reproduce/run/stages``, 256,000 samples in ``train_seconds``:
    the six NUE-family models 136-163 samples/s, mean 147; FR 330; Nav-A3C 334) divided by ``compiled_speedup``.
    NRNS and VGM (issue 39) by their ratio to NUE on the lean memory (the rate ``nue`` x ``map_train_speedup``'s lean
    1.37), measured on the 2-core AMD EPYC of 2026-12-06 (results/memory_baselines/README.md): NRNS 938 s for 256,000
    samples beside ``nue_gru_lean``'s 923 s (two trainings, one core each); VGM 3,712 s beside 3 other jobs, 1.75x the
    923 s when scaled by ``nue_gru_lean``'s second seed run under the same load (1,956 s), plus its 300 contrastive
    embedding steps; approximate."""
    compiled_speedup: tuple[tuple[str, float], ...] = (("nue", 1.5), ("fr", 1.65), ("nav_a3c", 1.44), ("nrns", 1.0),
                                                       ("vgm", 1.0))
    """Training throughput with ``nue train --compile`` relative to eager, per model kind: eager and compiled steps
    interleaved in one process (batch 64 / 8 x 8 sequences, fp32, one thread, synthetic data, a 2-core Xeon without
    native bf16). NRNS and VGM: not measured (1.0)."""
    select_s_per_episode: tuple[tuple[str, float], ...] = (("nue", 11.5), ("fr", 1.7), ("nav_a3c", 1.9), ("nrns", 0.0),
                                                           ("vgm", 4.2))
    """Closed-loop selection, seconds per episode (400-step limit; the v6 run: 2 x 21 episodes in 7.2-8.6 min per
    NUE-family model, 73 s FR, 79 s Nav-A3C). NRNS has none (selected by held-out distance error); VGM: 8.4 s an
    episode with 4 jobs on the 2 cores (2026-12-06), halved."""
    eval_s_per_episode: tuple[tuple[str, float], ...] = (("nue", 13.3), ("fr", 3.4), ("nav_a3c", 3.9),
                                                         ("expert", 0.2), ("expert-explore", 1.7), ("swap", 4.3),
                                                         ("sling", 2.5), ("nrns", 6.8), ("vgm", 5.5))
    """Evaluation, seconds per episode per worker, two workers: the mean ``wall_time`` of the v6 run's val252
    records (the six NUE-family models 12.5-14.1 s, 325-381 steps an episode at 36-40 ms a step). The swapped-maps
    control replays maps recorded along the expert's run of another episode, so its agent neither renders nor
    trains a memory. ``sling`` is what SLING's last-mile wrapper adds to its model's episode (SIFT matching every 4th
    step at ~22 ms, the depth map every 2nd at ~2 ms: ~7 ms a step, ~300 steps). NRNS: ~15 ms a step (30 ms with 4
    jobs on the 2 cores, 2026-12-06; docs/nrns.md measured 14) x ~450 steps; VGM: its selection's cost per episode
    x 1.3 (evaluation episodes run up to 800 steps, not 400); both approximate."""
    eval_steps_per_episode: float = 350.0
    """Mean steps of an evaluation episode behind ``eval_s_per_episode`` (the v6 run's NUE family: 325-381), to cost
    the exploration benchmark's fixed-length runs (``random`` is costed as Nav-A3C, a light policy)."""
    memory_speedup: tuple[tuple[str, float], ...] = (("lean", 1.70),)
    """Per memory preset other than ``fast``: how much less an episode step of a model that reads the memory's maps
    costs (evaluation and closed-loop selection), a ratio to ``fast``. ``lean``: ``benchmarks/loop.py`` with
    ``results/lean/nue_lean.pt`` beside ``checkpoints/nue.pt``, interleaved in one run, sum of the per-part medians
    36.95 against 21.74 ms (2026-12-05, load average ~2.3 on 2 cores)."""
    map_train_speedup: tuple[tuple[str, float], ...] = (("lean", 1.37),)
    """Per memory preset other than ``fast``: training throughput of a model that reads its (smaller) maps, a ratio
    to ``fast``'s. ``lean``: ``benchmarks/train.py``, NUE on 30 x 40 against 45 x 60 maps, one thread, bf16 (308
    against 225 samples/s in one run, 2026-12-05, loaded)."""
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


def cost_key(table: tuple[tuple[str, float], ...], model: str) -> str:
    """The entry of a per-model-kind cost table that prices ``model``: the model's own, else its kind's."""
    return model if model in dict(table) else get_model_config(model).kind


def _kind_cost(table: tuple[tuple[str, float], ...], model: str) -> float:
    return dict(table)[cost_key(table, model)]


def _memory_factor(table: tuple[tuple[str, float], ...], model: str, memory: str) -> float:
    """The speed-up ``table`` gives ``model`` under the recipe's memory preset (1 for ``fast``, an unlisted preset or
    a model that reads no maps)."""
    return dict(table).get(memory, 1.0) if get_model_config(model).uses_memory_maps else 1.0


def train_rate(recipe: Recipe, model: str, cost: CostModel = CostModel(), compiled: bool = False) -> float:
    """Modelled training throughput of ``model`` under ``recipe`` (its memory preset), samples a second."""
    return (_kind_cost(cost.samples_per_s, model) * (_kind_cost(cost.compiled_speedup, model) if compiled else 1.0)
            * _memory_factor(cost.map_train_speedup, model, recipe.memory))


def episode_seconds(recipe: Recipe, model: str, cost: CostModel = CostModel()) -> float:
    """Modelled evaluation seconds per episode of ``model`` under ``recipe``'s memory preset."""
    return _kind_cost(cost.eval_s_per_episode, model) / _memory_factor(cost.memory_speedup, model, recipe.memory)


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


def explore_counts(recipe: Recipe) -> dict[str, int]:
    """Starts of the exploration benchmark per explore set: houses x 3 bins x ``explore_per_bin`` (all: the set's)."""
    out = {}
    for name in recipe.explore_sets:
        houses = len(recipe.explore_houses) or len(SPLITS[EPISODE_SETS[name].split])
        per_bin = per_house_bin(name)
        out[name] = houses * 3 * (min(per_bin, recipe.explore_per_bin) if recipe.explore_per_bin else per_bin)
    return out


def collection_episodes(recipe: Recipe) -> int:
    """Demonstration episodes of a recipe: over its collections, houses x 3 bins x (train + held-out per bin)."""
    return sum(collection_sizes(recipe))


def collection_sizes(recipe: Recipe) -> list[int]:
    """Demonstration episodes of each collection of a recipe (``train_split``'s first)."""
    return [c.houses_count * 3 * (c.episodes_per_bin + c.heldout_per_bin) for c in recipe.collections()]


def estimate(recipe: Recipe, workers: int = 1, cost: CostModel = CostModel(), compiled: bool = False,
             runs: Sequence[str] | None = None, trained: Mapping[str, float] | None = None) -> list[StageEstimate]:
    """Wall-clock per stage of ``recipe`` with ``workers`` parallel processes (a Ray cluster: its CPUs); ``compiled``:
    training with ``torch.compile``; ``runs``: the training runs (:meth:`Recipe.training_runs` names: every seed of a
    model is one) the training stage still has to train (default: all); ``trained``: the share of its training a run
    has done already (a resumed run's ``last.pt``; behaviour cloning only, DAgger's rounds are costed whole). Every
    seed's run is trained, selected and evaluated (the swapped-maps control too) as a model of its own."""
    w = max(1, workers)
    out = []
    houses = sum(c.houses_count for c in recipe.collections()) + sum(
        len(recipe.eval_houses) or len(SPLITS[EPISODE_SETS[s].split]) for s in recipe.eval_sets)
    out.append(StageEstimate("scenes", houses * cost.house_s, f"{houses} houses x {cost.house_s:.0f} s (kept if present)"))
    length = dict(cost.steps_per_episode)[recipe.expert] * (1 + cost.noise_length_factor * recipe.noise)
    for c, n_eps in zip(recipe.collections(), collection_sizes(recipe)):
        out.append(StageEstimate("collect" if c.split == recipe.train_split else f"collect/{c.split}",
                                 n_eps * length * cost.collect_s_per_step / w,
                                 f"{n_eps} episodes x ~{length:.0f} steps x {cost.collect_s_per_step} s / {w} worker(s)"))
    jobs = []
    select_eps = 21 if recipe.select == "closed_loop" else 0
    all_runs = recipe.training_runs()
    for name in ([r.name for r in all_runs] if runs is None else runs):
        m = recipe.training_run(name).model
        if recipe.train_minutes > 0:
            t = 60 * recipe.train_minutes
        else:
            t = recipe.train_steps(m) * recipe.samples_per_step(m) / train_rate(recipe, m, cost, compiled)
        if not recipe.dagger_rounds:
            t *= 1 - min(1.0, max(0.0, (trained or {}).get(name, 0.0)))
        rounds = 1 + recipe.dagger_rounds
        rollouts = recipe.dagger_rounds * n_eps * length * cost.collect_s_per_step * 1.2
        select_s = _kind_cost(cost.select_s_per_episode, m) / _memory_factor(cost.memory_speedup, m, recipe.memory)
        jobs.append(cost.train_overhead_s + rounds * t + rollouts + select_eps * recipe.select_candidates * select_s)
    select = (f" + closed-loop selection ({recipe.select_candidates} x 21 episodes)" if select_eps else "")
    budget = (f"{recipe.train_minutes:g} min" if recipe.train_minutes > 0
              else f"{recipe.train_samples:,} samples" if recipe.train_samples > 0 else "its steps")
    side = f"{min(w, len(jobs))} side by side on one core each" if w > 1 else "one at a time on one core"
    what = f"{len(jobs)} models" if len(all_runs) == len(recipe.models) else f"{len(jobs)} runs (models x seeds)"
    part = [f"{n} {100 * trained[n]:.0f}%" for n in (runs or ()) if trained and 0 < trained.get(n, 0) < 1
            and not recipe.dagger_rounds]
    out.append(StageEstimate("train", _makespan(jobs, w), f"{what} x {budget}{' (compiled)' if compiled else ''}{select}"
                             f"{f' x {1 + recipe.dagger_rounds} rounds' if recipe.dagger_rounds else ''}, {side}"
                             + (f"; trained already: {', '.join(part)}" if part else "")))
    scale = min(1.0, recipe.eval_max_steps / 800) if recipe.eval_max_steps else 1.0
    swap = len(recipe.training_runs(recipe.swap_maps))
    for name, n in episode_counts(recipe).items():
        per_ep = (sum(episode_seconds(recipe, r.model, cost) for r in all_runs)
                  + sum(_kind_cost(cost.eval_s_per_episode, m) for m in recipe.experts))
        methods = len(all_runs) + len(recipe.experts)
        out.append(StageEstimate(f"eval/{name}", (n * per_ep * scale + methods * cost.eval_overhead_s) / w,
                                 f"{n} episodes x {methods} methods / {w} worker(s)"))
        if recipe.swap_maps:
            out.append(StageEstimate(f"eval/{name}+swap", (n * swap * dict(cost.eval_s_per_episode)["swap"] * scale
                                                           + swap * cost.eval_overhead_s) / w,
                                     f"{n} episodes x {swap} {'model(s)' if swap == len(recipe.swap_maps) else 'runs'}, swapped maps"))
        if recipe.last_mile:
            wrapped = recipe.training_runs(recipe.last_mile)
            per_ep = sum(episode_seconds(recipe, r.model, cost) + dict(cost.eval_s_per_episode)["sling"] for r in wrapped)
            out.append(StageEstimate(f"eval/{name}+sling", (n * per_ep * scale + len(wrapped) * cost.eval_overhead_s) / w,
                                     f"{n} episodes x {len(wrapped)} runs with SLING's last mile / {w} worker(s)"))
    explorers = recipe.training_runs(recipe.explore_models)
    for name, n in explore_counts(recipe).items():
        steps = recipe.explore_steps / cost.eval_steps_per_episode  # episodes' worth of steps per run
        per_start = steps * (sum(episode_seconds(recipe, r.model, cost) for r in explorers)
                             + sum(_kind_cost(cost.eval_s_per_episode, m) for m in ("expert-explore", "nav_a3c")))
        methods = len(explorers) + 2
        out.append(StageEstimate(f"explore/{name}", (n * per_start + methods * cost.eval_overhead_s) / w,
                                 f"{n} starts x {methods} methods x {recipe.explore_steps} steps / {w} worker(s)"))
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
