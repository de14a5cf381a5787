"""The ``nue collect``, ``nue train``, ``nue dagger`` and ``nue select`` commands (demonstrations, behaviour
cloning, DAgger, closed-loop selection); registered on the app in :mod:`nue.cli`, which handles errors."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from nue import cli_args as A
from nue.errors import ConfigError
from nue.outputs import check_output_dir, check_output_file


def _ints(option: str, text: str) -> tuple[int, ...]:
    """Comma-separated integers (``"0,3,5"``); :class:`~nue.errors.ConfigError` naming ``option`` otherwise."""
    try:
        return tuple(int(v) for v in text.split(",") if v.strip()) if text else ()
    except ValueError:
        raise ConfigError(option, f"expected comma-separated integers, got {text!r}") from None


def collect_cmd(
    out: Path = typer.Option(Path("data/demos"), help="Collection folder (episode files + manifest)."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the generated houses live (made if missing)."),
    scene: list[Path] = typer.Option([], help="Explicit scene folder(s) instead of the generated training split."),
    houses: str = typer.Option("", help="Comma-separated indices of training houses (default: all 21)."),
    task: str = typer.Option("paper", help="Task preset."),
    memory: str = typer.Option("fast", help="Memory (NeRF) preset, run online as at test time."),
    model: str = typer.Option("nue", help="Model preset whose input layout the data use."),
    episodes_per_bin: int = typer.Option(16, help="Training episodes per difficulty bin per house."),
    heldout_per_bin: int = typer.Option(2, help="Held-out episodes per bin per house (model selection)."),
    seed: int = typer.Option(0, help="Seed."),
    workers: int = typer.Option(1, help="Parallel local worker processes."),
    ray_address: Optional[str] = typer.Option(None, help="Run episodes as tasks on this Ray cluster."),
    device: str = typer.Option("cpu", help="Device of the NeRF memory."),
    expert_kind: str = typer.Option("geodesic", "--expert", help="geodesic (knows the goal) or explore (frontiers "
                                    "of its own seen map until the goal is in view, then geodesic)."),
    noise: float = typer.Option(0.0, help="DART noise: probability that a random move is executed instead of the "
                                "expert's; the label stays the expert's."),
    memory_lag: int = typer.Option(0, help="Memory lag: frames join the NeRF this many steps late (0 = the preset's)."),
):
    """Collect expert demonstrations with the online NeRF memory (resumes if rerun)."""
    from nue.train.collect import CollectConfig, collect

    A.positive("--episodes-per-bin", episodes_per_bin)
    A.non_negative("--heldout-per-bin", heldout_per_bin)
    A.positive("--workers", workers)
    A.probability("--noise", noise)
    A.non_negative("--memory-lag", memory_lag)
    A.device("--device", device)
    check_output_dir(out, "the collection folder")
    check_output_dir(scenes_root, "the scenes folder")
    cfg = CollectConfig(task=task, memory=memory, model=model, houses=_ints("--houses", houses),
                        scene_dirs=tuple(str(p) for p in scene), episodes_per_bin=episodes_per_bin,
                        heldout_per_bin=heldout_per_bin, seed=seed, device=device, expert=expert_kind, noise=noise,
                        memory_lag=memory_lag)
    summary = collect(out, cfg, scenes_root, workers=workers, ray_address=ray_address)
    typer.echo(f"{summary['episodes']} episodes, {summary['steps']} steps, "
               f"{summary['bytes_per_step'] / 1024:.0f} KiB/step, expert SR {100 * summary['expert_success_rate']:.1f}% -> {out}")



def convert_cmd(
    source: Path = typer.Argument(..., help="Collection folder to re-encode (e.g. one written before the compact format)."),
    out: Path = typer.Option(..., help="New collection folder (resumes if rerun)."),
    rgbd_bits: int = typer.Option(8, help="Bits per RGB-D value (0 = float16)."),
    i_cog_bits: int = typer.Option(4, help="Bits per I_cog value (0 = float16)."),
):
    """Copy a demonstration collection with its frames and maps stored compactly (~140 KiB a step)."""
    from nue.train.compact import BITS, StepStorage
    from nue.train.convert import convert_collection

    for option, bits in (("--rgbd-bits", rgbd_bits), ("--i-cog-bits", i_cog_bits)):
        if bits not in (0, *BITS):
            raise ConfigError(option, f"must be 0 or one of {BITS}, got {bits}")
    check_output_dir(out, "the output collection folder")
    s = convert_collection(source, out, StepStorage(rgbd_bits=rgbd_bits, i_cog_bits=i_cog_bits), progress=True)
    typer.echo(f"{s.episodes} episodes ({s.converted} converted now), {s.steps} steps, "
               f"{s.kib_per_step_before:.0f} -> {s.kib_per_step_after:.0f} KiB/step -> {out}")

# --- options shared by `nue train` and `nue dagger` (declared once) ---------------------------------
_DATA = typer.Option(Path("data/demos"), help="Collection folder.")
_MODEL = typer.Option("nue", help="Model preset: nue, abl_*, fr, nav_a3c.")
_BATCH_SIZE = typer.Option(64, help="Batch size (sequences for recurrent models).")
_LR = typer.Option(1e-3, help="Peak learning rate.")
_AUX_WEIGHT = typer.Option(0.5, help="Weight of the goal-angle loss.")
_EVAL_EVERY = typer.Option(250, help="Held-out evaluation / checkpoint interval.")
_SEED = typer.Option(0, help="Seed.")
_DEVICE = typer.Option("cpu", help="cpu or cuda.")
_PRECISION = typer.Option("fp32", help="auto (bf16 where the CPU/GPU runs it natively, else fp32), fp32, or "
                          "bf16 (bfloat16 autocast: ~2x faster on CPUs with AVX512-BF16).")
_MAP_DROPOUT = typer.Option(0.0, help="Probability per sample of replacing its memory maps by another sample's.")
_SELECT = typer.Option("accuracy", help="How best.pt is chosen: accuracy (held-out action accuracy) or "
                       "closed_loop (the last snapshots run on --select-episodes; highest SR wins).")
_SELECT_EPISODES = typer.Option(Path("episodes/select"), help="Closed-loop selection episodes (training houses).")
_SELECT_CANDIDATES = typer.Option(3, help="Closed-loop selection: how many of the last snapshots compete.")
_SELECT_WORKERS = typer.Option(1, help="Closed-loop selection: worker processes.")
_INIT_FROM = typer.Option(None, help="Start from this checkpoint's weights (fine-tuning).")
_WARMUP = typer.Option(100, help="Linear learning-rate warm-up steps.")
_DAGGER_OLD = "Deprecated: DAgger options (use `nue dagger`)"


def _train_config(data: Path, out: Path, model: str, steps: int, batch_size: int, lr: float, aux_weight: float,
                  time_budget: float, eval_every: int, seed: int, device: str, precision: str, map_dropout: float,
                  select: str, select_episodes: Path, select_candidates: int, select_workers: int,
                  init_from: Optional[Path], warmup: int):
    """Check the training options and build the :class:`~nue.train.bc.TrainConfig` (the caller checks the run
    folder once all its options are checked)."""
    from nue.train.bc import TrainConfig

    for option, value in (("--steps", steps), ("--batch-size", batch_size), ("--eval-every", eval_every),
                          ("--select-candidates", select_candidates), ("--select-workers", select_workers)):
        A.positive(option, value)
    A.non_negative("--time-budget", time_budget)
    A.non_negative("--warmup", warmup)
    A.probability("--map-dropout", map_dropout)
    A.device("--device", device)
    return TrainConfig(data=str(data), out=str(out), model=model, steps=steps, batch_size=batch_size, lr=lr,
                       aux_weight=aux_weight, time_budget_s=60 * time_budget, eval_every=eval_every, seed=seed,
                       device=device, precision=precision, init_from=str(init_from or ""), warmup=warmup,
                       map_dropout=map_dropout, select=select, select_episodes=str(select_episodes),
                       select_candidates=select_candidates, select_workers=select_workers)


def _run_dagger(cfg, dagger, scene: list[Path], scenes_root: Path, workers: int, ray_address: Optional[str]) -> None:
    """Run DAgger on ``cfg.data``'s collection (its manifest says which episodes to revisit); write ``dagger.json``."""
    import json

    from nue.train.dagger import collect_config_from_manifest, run_dagger
    from nue.train.manifest import manifest_path, read_manifest

    expert_data = cfg.data.split(",")[0]
    collect_cfg = collect_config_from_manifest(read_manifest(expert_data), scene, cfg.device, manifest_path(expert_data))
    rounds = run_dagger(cfg, collect_cfg, dagger, scenes_root, workers=workers, ray_address=ray_address)
    (Path(cfg.out) / "dagger.json").write_text(json.dumps(rounds, indent=1, default=str) + "\n")
    typer.echo(f"DAgger: {len(rounds) - 1} rounds; final checkpoint {rounds[-1]['best']}")


def train_cmd(
    data: Path = _DATA,
    out: Path = typer.Option(Path("runs/nue"), help="Run folder (checkpoints, TensorBoard)."),
    model: str = _MODEL,
    steps: int = typer.Option(3000, help="Optimiser steps."),
    batch_size: int = _BATCH_SIZE,
    lr: float = _LR,
    aux_weight: float = _AUX_WEIGHT,
    time_budget: float = typer.Option(0.0, help="Stop after this many minutes (0 = no limit); with the deprecated "
                                      "--dagger-rounds, per round with its rollouts included."),
    eval_every: int = _EVAL_EVERY,
    seed: int = _SEED,
    device: str = _DEVICE,
    resume: bool = typer.Option(False, help="Continue from OUT/last.pt."),
    precision: str = _PRECISION,
    map_dropout: float = _MAP_DROPOUT,
    select: str = _SELECT,
    select_episodes: Path = _SELECT_EPISODES,
    select_candidates: int = _SELECT_CANDIDATES,
    select_workers: int = _SELECT_WORKERS,
    init_from: Optional[Path] = _INIT_FROM,
    warmup: int = _WARMUP,
    dagger_rounds: int = typer.Option(0, help="`nue dagger --rounds` (0 = plain BC).", rich_help_panel=_DAGGER_OLD),
    dagger_steps: int = typer.Option(1000, help="`nue dagger --round-steps`.", rich_help_panel=_DAGGER_OLD),
    dagger_beta: float = typer.Option(0.5, help="`nue dagger --beta`.", rich_help_panel=_DAGGER_OLD),
    dagger_episodes_per_bin: int = typer.Option(0, help="`nue dagger --episodes-per-bin`.", rich_help_panel=_DAGGER_OLD),
    dagger_start: Optional[Path] = typer.Option(None, help="`nue dagger --start`.", rich_help_panel=_DAGGER_OLD),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="`nue dagger --scenes-root`.", rich_help_panel=_DAGGER_OLD),
    scene: list[Path] = typer.Option([], help="`nue dagger --scene`.", rich_help_panel=_DAGGER_OLD),
    workers: int = typer.Option(1, help="`nue dagger --workers`.", rich_help_panel=_DAGGER_OLD),
    ray_address: Optional[str] = typer.Option(None, help="`nue dagger --ray-address`.", rich_help_panel=_DAGGER_OLD),
):
    """Behaviour cloning (+ auxiliary goal-angle loss) on collected demonstrations. (DAgger: `nue dagger`;
    the --dagger-* options here are deprecated and will be removed.)"""
    from nue.train.bc import train

    cfg = _train_config(data, out, model, steps, batch_size, lr, aux_weight, time_budget, eval_every, seed, device,
                        precision, map_dropout, select, select_episodes, select_candidates, select_workers, init_from,
                        warmup)
    for option, value in (("--dagger-rounds", dagger_rounds), ("--dagger-steps", dagger_steps),
                          ("--dagger-episodes-per-bin", dagger_episodes_per_bin)):
        A.non_negative(option, value)
    A.probability("--dagger-beta", dagger_beta)
    A.positive("--workers", workers)
    check_output_dir(out, "the run folder")
    if dagger_rounds > 0:
        from nue.train.dagger import DaggerConfig

        typer.echo("warning: `nue train --dagger-*` is deprecated; use `nue dagger` (--dagger-rounds -> --rounds, "
                   "--dagger-steps -> --round-steps, --dagger-beta -> --beta, --dagger-episodes-per-bin -> "
                   "--episodes-per-bin, --dagger-start -> --start)", err=True)
        dagger = DaggerConfig(rounds=dagger_rounds, beta0=dagger_beta, steps_per_round=dagger_steps,
                              episodes_per_bin=dagger_episodes_per_bin, round_budget_s=60 * time_budget,
                              start_from=str(dagger_start or ""))
        _run_dagger(cfg, dagger, scene, scenes_root, workers, ray_address)
        return
    res = train(cfg, resume=resume)
    typer.echo(f"{res.step} steps ({res.steps_this_call} in this call, {res.elapsed_s / 60:.1f} min); "
               f"best checkpoint: {res.best}")


def dagger_cmd(
    data: Path = typer.Option(Path("data/demos"), help="The expert collection (`nue collect --out`); its manifest "
                              "says which training episodes the rounds revisit."),
    out: Path = typer.Option(Path("runs/nue_dagger"), help="Run folder: round_<r>/ runs, data_r<r>/ rollouts, dagger.json."),
    rounds: int = typer.Option(2, help="DAgger rounds after the behaviour-cloning round 0."),
    start: Optional[Path] = typer.Option(None, help="Skip round 0 and start from this checkpoint (e.g. a BC run's best.pt)."),
    beta: float = typer.Option(0.5, help="Expert-action probability in round r is beta ** r."),
    max_factor: float = typer.Option(3.0, help="Policy control stops at this multiple of the expert's step count; "
                                     "the expert finishes the episode."),
    episodes_per_bin: int = typer.Option(0, help="Roll out the first k training episodes per bin per house (0 = all)."),
    round_steps: int = typer.Option(1000, help="Optimiser steps of each retraining round."),
    time_budget: float = typer.Option(0.0, help="Minutes per round, rollouts included; retraining gets what the "
                                      "rollouts leave (0 = no limit). Round 0 stops after this too."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the training houses are (made if missing)."),
    scene: list[Path] = typer.Option([], help="The collection's scene folders, if not generated houses."),
    workers: int = typer.Option(1, help="Parallel rollout worker processes."),
    ray_address: Optional[str] = typer.Option(None, help="Run the rollouts as tasks on this Ray cluster."),
    model: str = _MODEL,
    steps: int = typer.Option(3000, help="Optimiser steps of round 0 (behaviour cloning)."),
    batch_size: int = _BATCH_SIZE,
    lr: float = _LR,
    aux_weight: float = _AUX_WEIGHT,
    eval_every: int = _EVAL_EVERY,
    seed: int = _SEED,
    device: str = _DEVICE,
    precision: str = _PRECISION,
    map_dropout: float = _MAP_DROPOUT,
    select: str = _SELECT,
    select_episodes: Path = _SELECT_EPISODES,
    select_candidates: int = _SELECT_CANDIDATES,
    select_workers: int = _SELECT_WORKERS,
    init_from: Optional[Path] = _INIT_FROM,
    warmup: int = _WARMUP,
):
    """DAgger (beyond the paper): behaviour cloning, then rounds of policy rollouts labelled by the expert,
    aggregated and retrained on; resumes if rerun."""
    from nue.train.dagger import DaggerConfig

    cfg = _train_config(data, out, model, steps, batch_size, lr, aux_weight, time_budget, eval_every, seed, device,
                        precision, map_dropout, select, select_episodes, select_candidates, select_workers, init_from,
                        warmup)
    A.non_negative("--rounds", rounds)
    A.non_negative("--round-steps", round_steps)
    A.non_negative("--episodes-per-bin", episodes_per_bin)
    A.probability("--beta", beta)
    A.positive("--max-factor", max_factor)
    A.positive("--workers", workers)
    check_output_dir(out, "the run folder")
    dagger = DaggerConfig(rounds=rounds, beta0=beta, max_factor=max_factor, steps_per_round=round_steps,
                          episodes_per_bin=episodes_per_bin, round_budget_s=60 * time_budget,
                          start_from=str(start or ""))
    _run_dagger(cfg, dagger, scene, scenes_root, workers, ray_address)


def select_cmd(
    run: Path = typer.Argument(..., help="Run folder of `nue train --select closed_loop` (with snapshots/)."),
    episodes_dir: Path = typer.Option(Path("episodes/select"), help="Selection episodes (training houses only)."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the houses are (generated if missing)."),
    candidates: int = typer.Option(3, help="How many of the last snapshots compete."),
    max_episodes: int = typer.Option(0, help="First N episodes per house only (0 = all)."),
    workers: int = typer.Option(1, help="Parallel local worker processes."),
    device: str = typer.Option("cpu", help="cpu or cuda."),
):
    """Closed-loop model selection: run a run's last snapshots on training-house episodes, copy the best to best.pt."""
    from nue.train.select import SelectConfig, select_checkpoint

    A.positive("--candidates", candidates)
    A.positive("--workers", workers)
    A.non_negative("--max-episodes", max_episodes)
    A.device("--device", device)
    check_output_file(run / "best.pt", "the selected checkpoint")
    ranked = select_checkpoint(run, SelectConfig(episodes_dir=str(episodes_dir), scenes_root=str(scenes_root),
                                                 candidates=candidates, max_episodes=max_episodes, workers=workers,
                                                 device=device))
    for c in ranked:
        typer.echo(f"{c.name}: SR {100 * c.sr:.1f}% SPL {c.spl:.3f} collisions/ep {c.collisions:.1f} (n={c.n})")
    typer.echo(f"selected {ranked[0].name} -> {run / 'best.pt'}")
