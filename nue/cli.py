"""The ``nue`` command line: scenes, episodes, the expert and the demo.

Bad input (a malformed scene folder, episode file, ...) prints ``error: <file>: <problem>`` and exits
with status 2, without a traceback.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Optional

import typer

from nue import cli_args as A
from nue.errors import NueError
from nue.outputs import check_output_dir, check_output_file

app = typer.Typer(add_completion=False, pretty_exceptions_enable=False, no_args_is_help=True,
                  help="Image-goal navigation with an uncertainty-aware NeRF memory.")
scenes_app = typer.Typer(no_args_is_help=True, help="Generate and inspect Gibson-layout scenes.")
episodes_app = typer.Typer(no_args_is_help=True, help="Generate and convert navigation episodes.")
app.add_typer(scenes_app, name="scenes")
app.add_typer(episodes_app, name="episodes")


@scenes_app.command("generate")
def scenes_generate(
    split: str = typer.Option(..., help="train (21 houses) or val (14 houses)."),
    out: Path = typer.Option(..., help="Folder to write <split>_<NN>/ scene folders into."),
    force: bool = typer.Option(False, help="Regenerate generated houses that are corrupt, incomplete or another house."),
):
    """Write the fixed-seed houses of a split in the Gibson layout (intact houses are kept)."""
    from nue.scene.generator import generate_split

    check_output_dir(out)
    paths = generate_split(split, out, force=force)
    typer.echo(f"{len(paths)} scenes in {out}")


@scenes_app.command("info")
def scenes_info(folders: list[Path] = typer.Argument(..., help="Scene folders.")):
    """Load scene folders and print their floors, free area and content hash."""
    from nue.scene.scene import Scene

    for folder in folders:
        s = Scene.load(folder)
        area = [float(m.sum()) * s.resolution**2 for m in s.trav_maps]
        s.load_mesh()
        typer.echo(f"{s.name}: hash {s.content_hash}, floors {list(s.floor_heights)}, "
                   f"free area {', '.join(f'{a:.1f}' for a in area)} m^2")


@episodes_app.command("generate")
def episodes_generate(
    scene: Path = typer.Option(..., help="Scene folder (Gibson layout)."),
    out: Path = typer.Option(..., help="Episode file to write."),
    per_bin: int = typer.Option(10, help="Episodes per difficulty bin."),
    seed: int = typer.Option(0, help="Random seed."),
    task: str = typer.Option("paper", help="Task preset: paper, official or habitat."),
    fmt: str = typer.Option("nue", "--format", help="nue (ours), authors, or habitat (habitat-lab's PointNav/ImageNav "
                            "dataset; gzip when OUT ends in .gz)."),
):
    """Sample episodes into the task's difficulty bins."""
    from nue.scene.scene import Scene
    from nue.sim.episode_gen import EpisodeGenConfig, generate_episodes
    from nue.sim.episodes import save_episodes

    A.positive("--per-bin", per_bin)
    A.choice("--format", fmt, EPISODE_FORMATS)
    check_output_file(out, "the episode file")
    s = Scene.load(scene)
    eps = generate_episodes(s, task, EpisodeGenConfig(per_bin=per_bin), seed=seed)
    save_episodes(out, eps, task, fmt=fmt)
    typer.echo(f"{len(eps)} episodes -> {out}")


@episodes_app.command("convert")
def episodes_convert(
    source: Path = typer.Argument(..., help="Episode file in any format (ours, the authors', habitat's .json[.gz])."),
    out: Path = typer.Option(..., help="Episode file to write."),
    fmt: str = typer.Option("nue", "--format", help="nue, authors or habitat (gzip when OUT ends in .gz)."),
    scene: Optional[Path] = typer.Option(None, help="Scene folder: checks content hashes, names the episodes' scene "
                                         "and picks its episodes from a many-scene habitat file."),
    task: str = typer.Option("paper", help="Task preset whose bins label episodes that carry no labels."),
):
    """Convert an episode file between formats (habitat's y-up frame <-> our z-up frame)."""
    from nue.scene.scene import Scene
    from nue.sim.episodes import load_episodes, save_episodes

    A.choice("--format", fmt, EPISODE_FORMATS)
    check_output_file(out, "the episode file")
    s = Scene.load(scene) if scene is not None else None
    eps = load_episodes(source, s, task)
    save_episodes(out, eps, task, fmt=fmt)
    typer.echo(f"{len(eps)} episodes -> {out}")


EPISODE_FORMATS = ("nue", "authors", "habitat")


def _echo_episode_checks(skipped, snapped: dict | None = None, source=None) -> None:
    """Print the episodes left out by --skip-invalid, and those whose start or goal was snapped."""
    if skipped:
        typer.echo(f"skipped {len(skipped)} invalid episode(s) (--skip-invalid):")
        for e in skipped:
            typer.echo(f"  {e}")
    if snapped:
        parts = [f"{eid} (start {s.start:.3f} m, goal {s.goal:.3f} m)" for eid, s in snapped.items()]
        typer.echo(f"{source}: snapped to navigable cells: {', '.join(parts)}")


@app.command("expert")
def expert(
    scene: Path = typer.Option(..., help="Scene folder."),
    episodes: Path = typer.Option(..., help="Episode file (ours or the authors' format)."),
    task: str = typer.Option("paper", help="Task preset."),
    records: Optional[Path] = typer.Option(None, help="Write one JSON record per episode here."),
    kind: str = typer.Option("geodesic", help="geodesic (shortest path) or explore (frontier exploration until "
                             "the goal is in view, then geodesic)."),
    skip_invalid: bool = typer.Option(False, help="Run the valid episodes and list the invalid ones instead of refusing the file."),
):
    """Run the geodesic (or exploring) expert on an episode file and print SR / SPL / DTS."""
    import json

    from nue.evaluate.metrics import aggregate, format_table
    from nue.rollout import EXPERT_KINDS, ExpertAgent, run_episode
    from nue.scene.navgrid import NavGrid
    from nue.scene.scene import Scene
    from nue.sim.env import ImageNavEnv
    from nue.errors import EpisodeError
    from nue.sim.episodes import read_episodes

    A.choice("--kind", kind, EXPERT_KINDS)
    if records:
        check_output_file(records, "the records file")
    s = Scene.load(scene)
    nav = NavGrid.from_scene(s)
    loaded = read_episodes(episodes, s, task, navgrid=nav, skip_invalid=skip_invalid)
    _echo_episode_checks(loaded.skipped, loaded.snapped, episodes)
    eps = loaded.episodes
    if not eps:
        raise EpisodeError(episodes, "no valid episodes to run")
    env = ImageNavEnv(s, task, eps, navgrid=nav)
    agent = ExpertAgent(kind=kind)
    method = "expert" if kind == "geodesic" else f"expert-{kind}"
    recs = [run_episode(env, agent, episode_index=i, method=method) for i in range(len(eps))]
    if records:
        records.parent.mkdir(parents=True, exist_ok=True)
        records.write_text("".join(json.dumps(r.to_dict()) + "\n" for r in recs))
    typer.echo(format_table(aggregate(recs)))


def _ints(text: str) -> tuple[int, ...]:
    return tuple(int(v) for v in text.split(",") if v.strip()) if text else ()


@app.command("collect")
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
    cfg = CollectConfig(task=task, memory=memory, model=model, houses=_ints(houses),
                        scene_dirs=tuple(str(p) for p in scene), episodes_per_bin=episodes_per_bin,
                        heldout_per_bin=heldout_per_bin, seed=seed, device=device, expert=expert_kind, noise=noise,
                        memory_lag=memory_lag)
    summary = collect(out, cfg, scenes_root, workers=workers, ray_address=ray_address)
    typer.echo(f"{summary['episodes']} episodes, {summary['steps']} steps, "
               f"{summary['bytes_per_step'] / 1024:.0f} KiB/step, expert SR {100 * summary['expert_success_rate']:.1f}% -> {out}")


@app.command("train")
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


@app.command("select")
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


@app.command("eval")
def eval_cmd(
    method: list[str] = typer.Option(..., "--checkpoint", "-c", help="Checkpoint path, name=path, or 'expert'; repeatable."),
    out: Path = typer.Option(Path("results/records.jsonl"), help="JSON-lines file the records are appended to."),
    episodes_dir: Path = typer.Option(Path("episodes/val"), help="Folder with one episode file per house."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the houses are (generated if missing)."),
    task: str = typer.Option("paper", help="Task preset."),
    seed: int = typer.Option(0, help="Base seed."),
    workers: int = typer.Option(1, help="Parallel local worker processes."),
    ray_address: Optional[str] = typer.Option(None, help="Run episodes as tasks on this Ray cluster."),
    device: str = typer.Option("cpu", help="cpu or cuda."),
    swap_maps: bool = typer.Option(False, help="Feed the maps of another episode (control)."),
    max_episodes: int = typer.Option(0, help="First N episodes per house only (0 = all)."),
    max_steps: int = typer.Option(0, help="Override the step limit (smoke runs only; 0 = the preset's)."),
    skip_invalid: bool = typer.Option(False, help="Run the valid episodes and list the invalid ones instead of refusing their file."),
):
    """Evaluate checkpoints on the fixed validation episodes (resumes if rerun)."""
    from nue.evaluate.metrics import aggregate, format_table
    from nue.evaluate.report import load_records
    from nue.evaluate.runner import EvalConfig, run_eval

    A.positive("--workers", workers)
    A.non_negative("--max-episodes", max_episodes)
    A.non_negative("--max-steps", max_steps)
    A.device("--device", device)
    check_output_file(out, "the records file")
    cfg = EvalConfig(episodes_dir=str(episodes_dir), scenes_root=str(scenes_root), task=task, seed=seed,
                     device=device, swap_maps=swap_maps, max_episodes=max_episodes, max_steps=max_steps,
                     skip_invalid=skip_invalid)
    skipped: list = []
    run_eval(method, out, cfg, workers=workers, ray_address=ray_address, skipped=skipped)
    _echo_episode_checks(skipped)
    records = load_records(out)
    for name in sorted({r.method for r in records}):
        typer.echo(f"## {name}\n" + format_table(aggregate([r for r in records if r.method == name])))


@app.command("report")
def report_cmd(
    records: list[Path] = typer.Argument(..., help="Record files (JSON lines) from `nue eval`."),
    out: Path = typer.Option(Path("results/report"), help="Folder for table.md/.csv/.tex and coverage.png."),
    results_md: Optional[Path] = typer.Option(None, help="Also write this RESULTS.md."),
    command: str = typer.Option("", help="The evaluation command, recorded in RESULTS.md."),
    task: str = typer.Option("paper", help="Task preset of the records (its action ids, for the closed-loop diagnostics)."),
):
    """Table I (SR / SPL / DTS per difficulty, CIs, paired differences to NUE) and coverage."""
    import json
    import platform

    from nue.evaluate.report import load_records, render_results_md, write_report

    check_output_dir(out, "the report folder")
    if results_md:
        check_output_file(results_md)
    recs = load_records(*records)
    paths = write_report(recs, out, task=task)
    typer.echo((out / "table.md").read_text() if (out / "table.md").is_file() else "")
    if results_md:
        meta_path = results_md.parent / f"{results_md.stem}.meta.json"
        meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {
            "command": command, "date": "", "commit": "", "machine": f"{platform.machine()}, {os.cpu_count()} CPUs"}
        results_md.write_text(render_results_md(recs, meta, task))
        typer.echo(f"wrote {results_md}")
    typer.echo(f"wrote {', '.join(str(p) for p in paths.values())}")


@app.command("diagnose")
def diagnose_cmd(
    records: list[Path] = typer.Option([], "--records", help="Record files (JSON lines) from `nue eval`; repeatable."),
    method: list[str] = typer.Option([], help="Only these methods (repeatable; default: all)."),
    checkpoint: Optional[Path] = typer.Option(None, help="With --data: held-out accuracy with intact, mirrored and other-step maps."),
    data: Optional[Path] = typer.Option(None, help="Collection folder: previous-action probe on its maps (and the map controls)."),
    part: str = typer.Option("heldout", help="Part of the collection to use (heldout or train)."),
    task: str = typer.Option("paper", help="Task preset the records' action ids belong to."),
    max_episodes: int = typer.Option(200, help="Map controls: at most this many episodes."),
    probe_steps: int = typer.Option(20_000, help="Probe: subsample at most this many steps."),
    probe_cog: bool = typer.Option(False, help="Probe: add the mean norm of I_cog to the features."),
    seed: int = typer.Option(0, help="Seed of the other-step maps, the probe's subsample and its shuffled control."),
    out: Optional[Path] = typer.Option(None, help="Also write everything as JSON here."),
):
    """Closed-loop diagnostics from records; map controls and a previous-action probe from demonstrations."""
    import json

    from nue.errors import ConfigError
    from nue.evaluate import diagnose as D

    if not records and data is None:
        raise ConfigError(None, "nothing to diagnose: give --records and/or --data")
    if checkpoint is not None and data is None:
        raise ConfigError(checkpoint, "--checkpoint needs --data (the demonstrations to evaluate it on)")
    A.positive("--max-episodes", max_episodes)
    A.positive("--probe-steps", probe_steps)
    if out:
        check_output_file(out)
    result: dict = {}
    if records:
        diags = D.record_diagnostics(D.read_records(*records), task, method)
        result["records"] = diags
        typer.echo("## Closed-loop diagnostics\n\n" + D.format_record_diagnostics(diags))
    if data is not None:
        from nue.evaluate import diagnose_maps as M
        from nue.train.dataset import DemoSet

        demos = DemoSet(data, part, verify=False)
        if checkpoint is not None:
            result["map_controls"] = M.map_controls(checkpoint, demos, seed=seed, max_episodes=max_episodes)
            typer.echo("## Map controls\n\n" + M.format_map_controls(result["map_controls"]))
        try:
            result["probe"] = M.previous_action_probe(demos, seed=seed, max_steps=probe_steps, with_cog=probe_cog)
            typer.echo("## Previous-action probe\n\n" + M.format_probe(result["probe"], D.action_short_names(task)))
        except M.ProbeUnavailable as exc:
            result["probe"] = None
            typer.echo(f"## Previous-action probe\n\nn/a: {exc}\n")
    if out:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(D.to_jsonable(result), indent=1) + "\n")
        typer.echo(f"wrote {out}")


@app.command("demo")
def demo(
    out: Path = typer.Option(Path("outputs/demo"), help="Output folder for figures and tables."),
    house: int = typer.Option(0, help="Validation house index (0-13)."),
    task: str = typer.Option("paper", help="Task preset."),
    seed: int = typer.Option(0, help="Episode seed."),
    checkpoint: Optional[Path] = typer.Option(None, help="Policy checkpoint (default: checkpoints/nue.pt if present, else the expert)."),
    expert: bool = typer.Option(False, help="Run the geodesic expert even if a checkpoint exists."),
    max_steps: int = typer.Option(0, help="Override the step limit (quick runs; 0 = the preset's)."),
):
    """Run the agent on one episode per difficulty in a validation house; write figures and a table."""
    from nue.demo import run_demo

    A.non_negative("--max-steps", max_steps)
    check_output_dir(out)
    table = run_demo(out, house=house, task_name=task, seed=seed, checkpoint=checkpoint, max_steps=max_steps,
                     use_default_checkpoint=not expert)
    typer.echo(table)
    typer.echo(f"figures and records in {out}/")


def main() -> None:
    from nue.jobs import InjectedFailure

    try:
        app()
    except NueError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)
    except InjectedFailure as exc:
        typer.echo(f"stopped: {exc}", err=True)
        sys.exit(3)


if __name__ == "__main__":
    main()
