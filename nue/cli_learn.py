"""The ``nue collect``, ``nue train``, ``nue dagger`` and ``nue select`` commands (demonstrations, behaviour
cloning, DAgger, closed-loop selection); registered on the app in :mod:`nue.cli`, which handles errors."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer

from nue import cli_args as A
from nue.cli_config import RAY_ADDRESS, WORKERS, ConfigOptions, Opt, config_command
from nue.errors import ConfigError
from nue.outputs import check_output_dir, check_output_file

if TYPE_CHECKING:
    from nue.selection import SelectConfig
    from nue.train.bc import TrainConfig
    from nue.train.collect import CollectConfig
    from nue.train.compact import StepStorage
    from nue.train.dagger import DaggerConfig


def _bits(option: str, bits: int) -> None:
    """Bits of a stored array: 0 (float16) or one :func:`~nue.train.compact.quantize` supports."""
    from nue.train.compact import BITS

    if bits not in (0, *BITS):
        raise ConfigError(option, f"must be 0 or one of {BITS}, got {bits}")




# --- the configs' options: defaults and help are the dataclass fields' (nue.cli_config) ----------------
COLLECT = ConfigOptions(
    "nue.train.collect:CollectConfig", Opt("scene_dirs", flag="--scene", path=True),
    Opt("split", check=A.one_of("nue.scene.generator:TRAINING_SPLITS")), "houses", "task", "memory",
    "model", Opt("episodes_per_bin", check=A.positive), Opt("heldout_per_bin", check=A.non_negative), "seed",
    Opt("device", check=A.device), Opt("expert", check=A.one_of("nue.policy.agent:EXPERT_KINDS")),
    Opt("noise", check=A.probability), Opt("memory_lag", check=A.non_negative))
STORAGE = ConfigOptions("nue.train.compact:StepStorage", *(Opt(f, check=_bits) for f in ("rgbd_bits", "i_cog_bits",
                                                                                          "i_u_bits")))
TRAIN = ConfigOptions(
    "nue.train.bc:TrainConfig", Opt("data", path=True), Opt("out", path=True), "model",
    Opt("steps", check=A.positive), Opt("batch_size", check=A.positive), "lr", "aux_weight", "goal_weight",
    Opt("time_budget_s", flag="--time-budget", minutes=True, check=A.non_negative,
        help="Stop (and checkpoint) after this many minutes of training (0 = no limit)."),
    Opt("budget_clock", check=A.one_of("nue.train.bc:BUDGET_CLOCKS")),
    Opt("eval_every", check=A.positive), "seed", Opt("device", check=A.device),
    Opt("precision", check=A.one_of("nue.train.bc:PRECISIONS")), "compile", Opt("map_dropout", check=A.probability),
    Opt("select", check=A.one_of("nue.train.bc:SELECTIONS")), Opt("select_episodes", path=True),
    Opt("select_candidates", check=A.positive), Opt("select_workers", check=A.positive),
    Opt("init_from", path=True), Opt("warmup", check=A.non_negative), Opt("exploit_weight", check=A.above_zero))
DAGGER = ConfigOptions(
    "nue.train.dagger:DaggerConfig", Opt("rounds", check=A.non_negative), Opt("start_from", flag="--start", path=True),
    Opt("beta0", flag="--beta", check=A.probability), Opt("max_factor", check=A.positive),
    Opt("episodes_per_bin", check=A.non_negative), Opt("steps_per_round", flag="--round-steps", check=A.non_negative),
    Opt("round_budget_s", flag="--time-budget", minutes=True, check=A.non_negative,
        help="Minutes per round, rollouts included; retraining gets what the rollouts leave (0 = no limit). "
             "Round 0 stops after this too."))
SELECT = ConfigOptions(
    "nue.selection:SelectConfig", Opt("episodes_dir", path=True), Opt("scenes_root", path=True),
    Opt("candidates", check=A.positive), Opt("max_episodes", check=A.non_negative),
    Opt("max_steps", check=A.non_negative), Opt("workers", check=A.positive), Opt("device", check=A.device))

@config_command
def collect_cmd(
    out: Path = typer.Option(Path("data/demos"), help="Collection folder (episode files + manifest)."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the generated houses live (made if missing)."),
    cfg: CollectConfig = COLLECT,
    storage: StepStorage = STORAGE,
    workers: int = WORKERS,
    ray_address: Optional[str] = RAY_ADDRESS,
):
    """Collect expert demonstrations with the online NeRF memory (resumes if rerun); stored compactly by
    default, `--rgbd-bits 0 --i-cog-bits 0` for float16."""
    from nue.train.collect import collect

    A.positive("--workers", workers)
    check_output_dir(out, "the collection folder")
    check_output_dir(scenes_root, "the scenes folder")
    summary = collect(out, cfg, scenes_root, workers=workers, ray_address=ray_address, storage=storage)
    typer.echo(f"{summary.episodes} episodes, {summary.steps} steps, "
               f"{summary.bytes_per_step / 1024:.0f} KiB/step, expert SR {100 * summary.expert_success_rate:.1f}% -> {out}")


@config_command
def convert_cmd(
    source: Path = typer.Argument(..., help="Collection folder to re-encode (e.g. one written before the compact format)."),
    out: Path = typer.Option(..., help="New collection folder (resumes if rerun)."),
    storage: StepStorage = STORAGE,
):
    """Copy a demonstration collection with its frames and maps stored compactly (~140 KiB a step)."""
    from nue.train.convert import convert_collection

    check_output_dir(out, "the output collection folder")
    s = convert_collection(source, out, storage, progress=True)
    typer.echo(f"{s.episodes} episodes ({s.converted} converted now), {s.steps} steps, "
               f"{s.kib_per_step_before:.0f} -> {s.kib_per_step_after:.0f} KiB/step -> {out}")


def _run_dagger(cfg: TrainConfig, dagger: DaggerConfig, scene: list[Path], scenes_root: Path, workers: int,
                ray_address: Optional[str]) -> None:
    """Run DAgger on ``cfg.data``'s collection (its manifest says which episodes to revisit); write ``dagger.json``."""
    import json

    from nue.output_lock import hold_output
    from nue.selection import select_run
    from nue.train.dagger import collect_config_from_manifest, run_dagger
    from nue.train.manifest import manifest_path, read_manifest

    expert_data = cfg.data.split(",")[0]
    with hold_output(cfg.out):  # the run folder, until dagger.json is written
        collect_cfg = collect_config_from_manifest(read_manifest(expert_data), scene, cfg.device,
                                                   manifest_path(expert_data), model=cfg.model)
        rounds = run_dagger(cfg, collect_cfg, dagger, scenes_root, workers=workers, ray_address=ray_address,
                            select=select_run)
        (Path(cfg.out) / "dagger.json").write_text(json.dumps([r.to_dict() for r in rounds], indent=1, default=str)
                                                   + "\n")
    typer.echo(f"DAgger: {len(rounds) - 1} rounds; final checkpoint {rounds[-1].best}")


@config_command
def train_cmd(
    cfg: TrainConfig = TRAIN,
    resume: bool = typer.Option(False, help="Continue from OUT/last.pt."),
):
    """Behaviour cloning (+ auxiliary goal-angle loss) on collected demonstrations (DAgger: `nue dagger`)."""
    from nue.selection import select_run
    from nue.train.bc import train

    check_output_dir(cfg.out, "the run folder")
    res = train(cfg, resume=resume, select=select_run)
    typer.echo(f"{res.step} steps ({res.steps_this_call} in this call, {res.elapsed_s / 60:.1f} min); "
               f"best checkpoint: {res.best}")


@config_command
def dagger_cmd(
    cfg: TrainConfig = TRAIN.but(  # noqa: B008  (an option declaration, like typer.Option)
        "time_budget_s",
        data={"help": "The expert collection (`nue collect --out`); its manifest says which training episodes the "
                      "rounds revisit."},
        out={"default": "runs/nue_dagger", "help": "Run folder: round_<r>/ runs, data_r<r>/ rollouts, dagger.json."},
        steps={"help": "Optimiser steps of round 0 (behaviour cloning)."}),
    dagger: DaggerConfig = DAGGER,
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the training houses are (made if missing)."),
    scene: list[Path] = typer.Option([], help="The collection's scene folders, if not generated houses."),
    workers: int = typer.Option(1, help="Parallel rollout worker processes."),
    ray_address: Optional[str] = typer.Option(None, help="Run the rollouts as tasks on this Ray cluster."),
):
    """DAgger (beyond the paper): behaviour cloning, then rounds of policy rollouts labelled by the expert,
    aggregated and retrained on; resumes if rerun."""
    A.positive("--workers", workers)
    check_output_dir(cfg.out, "the run folder")
    _run_dagger(cfg.replace(time_budget_s=dagger.round_budget_s), dagger, scene, scenes_root, workers, ray_address)


@config_command
def select_cmd(
    run: Path = typer.Argument(..., help="Run folder of `nue train --select closed_loop` (with snapshots/)."),
    cfg: SelectConfig = SELECT,
):
    """Closed-loop model selection: run a run's last snapshots on training-house episodes, copy the best to best.pt."""
    from nue.selection import select_checkpoint

    check_output_file(run / "best.pt", "the selected checkpoint")
    ranked = select_checkpoint(run, cfg)
    for c in ranked:
        typer.echo(f"{c.name}: SR {100 * c.sr:.1f}% SPL {c.spl:.3f} collisions/ep {c.collisions:.1f} (n={c.n})")
    typer.echo(f"selected {ranked[0].name} -> {run / 'best.pt'}")
