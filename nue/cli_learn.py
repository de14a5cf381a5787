"""The ``nue collect``, ``nue train`` and ``nue select`` commands (demonstrations, behaviour cloning +
DAgger, closed-loop selection); registered on the app in :mod:`nue.cli`, which handles errors."""

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


def train_cmd(
    data: Path = typer.Option(Path("data/demos"), help="Collection folder."),
    out: Path = typer.Option(Path("runs/nue"), help="Run folder (checkpoints, TensorBoard)."),
    model: str = typer.Option("nue", help="Model preset: nue, abl_*, fr, nav_a3c."),
    steps: int = typer.Option(3000, help="Optimiser steps."),
    batch_size: int = typer.Option(64, help="Batch size (sequences for recurrent models)."),
    lr: float = typer.Option(1e-3, help="Peak learning rate."),
    aux_weight: float = typer.Option(0.5, help="Weight of the goal-angle loss."),
    time_budget: float = typer.Option(0.0, help="Stop after this many minutes (0 = no limit); with DAgger, per round with its rollouts included."),
    eval_every: int = typer.Option(250, help="Held-out evaluation / checkpoint interval."),
    seed: int = typer.Option(0, help="Seed."),
    device: str = typer.Option("cpu", help="cpu or cuda."),
    resume: bool = typer.Option(False, help="Continue from OUT/last.pt."),
    precision: str = typer.Option("fp32", help="auto (bf16 where the CPU/GPU runs it natively, else fp32), fp32, or "
                                  "bf16 (bfloat16 autocast: ~2x faster on CPUs with AVX512-BF16)."),
    map_dropout: float = typer.Option(0.0, help="Probability per sample of replacing its memory maps by another sample's."),
    select: str = typer.Option("accuracy", help="How best.pt is chosen: accuracy (held-out action accuracy) or "
                               "closed_loop (the last snapshots run on --select-episodes; highest SR wins)."),
    select_episodes: Path = typer.Option(Path("episodes/select"), help="Closed-loop selection episodes (training houses)."),
    select_candidates: int = typer.Option(3, help="Closed-loop selection: how many of the last snapshots compete."),
    select_workers: int = typer.Option(1, help="Closed-loop selection: worker processes."),
    init_from: Optional[Path] = typer.Option(None, help="Start from this checkpoint's weights (fine-tuning)."),
    warmup: int = typer.Option(100, help="Linear learning-rate warm-up steps."),
    dagger_rounds: int = typer.Option(0, help="DAgger rounds after behaviour cloning (0 = plain BC)."),
    dagger_steps: int = typer.Option(1000, help="Optimiser steps per DAgger round."),
    dagger_beta: float = typer.Option(0.5, help="Expert-action probability in round r is beta ** r."),
    dagger_episodes_per_bin: int = typer.Option(0, help="DAgger: roll out the first k training episodes per bin per house (0 = all)."),
    dagger_start: Optional[Path] = typer.Option(None, help="DAgger: skip round 0 and start from this checkpoint."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="DAgger: where the training houses are."),
    scene: list[Path] = typer.Option([], help="DAgger: the collection's scene folders, if not generated houses."),
    workers: int = typer.Option(1, help="DAgger: parallel rollout workers."),
    ray_address: Optional[str] = typer.Option(None, help="DAgger: run rollouts on this Ray cluster."),
):
    """Behaviour cloning (+ auxiliary goal-angle loss) on collected demonstrations, optionally + DAgger."""
    import json

    from nue.train.bc import TrainConfig, train

    for option, value in (("--steps", steps), ("--batch-size", batch_size), ("--eval-every", eval_every),
                          ("--select-candidates", select_candidates), ("--select-workers", select_workers),
                          ("--workers", workers)):
        A.positive(option, value)
    for option, value in (("--time-budget", time_budget), ("--warmup", warmup), ("--dagger-rounds", dagger_rounds),
                          ("--dagger-steps", dagger_steps), ("--dagger-episodes-per-bin", dagger_episodes_per_bin)):
        A.non_negative(option, value)
    A.probability("--map-dropout", map_dropout)
    A.probability("--dagger-beta", dagger_beta)
    A.device("--device", device)
    check_output_dir(out, "the run folder")
    cfg = TrainConfig(data=str(data), out=str(out), model=model, steps=steps, batch_size=batch_size, lr=lr,
                      aux_weight=aux_weight, time_budget_s=60 * time_budget, eval_every=eval_every, seed=seed,
                      device=device, precision=precision, init_from=str(init_from or ""), warmup=warmup,
                      map_dropout=map_dropout, select=select, select_episodes=str(select_episodes),
                      select_candidates=select_candidates, select_workers=select_workers)
    if dagger_rounds > 0:
        from nue.train.dagger import DaggerConfig, collect_config_from_manifest, run_dagger

        manifest = json.loads((data / "manifest.json").read_text())
        rounds = run_dagger(cfg, collect_config_from_manifest(manifest, scene, device),
                            DaggerConfig(rounds=dagger_rounds, beta0=dagger_beta, steps_per_round=dagger_steps,
                                         episodes_per_bin=dagger_episodes_per_bin,
                                         round_budget_s=60 * time_budget, start_from=str(dagger_start or "")),
                            scenes_root, workers=workers, ray_address=ray_address)
        (out / "dagger.json").write_text(json.dumps(rounds, indent=1, default=str) + "\n")
        typer.echo(f"DAgger: {len(rounds) - 1} rounds; final checkpoint {rounds[-1]['best']}")
        return
    res = train(cfg, resume=resume)
    typer.echo(f"{res.step} steps ({res.steps_this_call} in this call, {res.elapsed_s / 60:.1f} min); "
               f"best checkpoint: {res.best}")


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
