"""The ``nue`` command line: scenes, episodes, the expert and the demo.

Bad input (a malformed scene folder, episode file, ...) prints ``error: <file>: <problem>`` and exits
with status 2, without a traceback.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer

from nue import cli_args as A
from nue.cli_config import ConfigOptions, Opt, config_command
from nue.cli_learn import collect_cmd, convert_cmd, dagger_cmd, select_cmd, train_cmd
from nue.cli_reproduce import make_set_cmd, reproduce_cmd
from nue.outputs import check_output_dir, check_output_file

if TYPE_CHECKING:
    from nue.evaluate.runner import EvalConfig
    from nue.sim.episode_gen import EpisodeGenConfig

app = typer.Typer(add_completion=False, pretty_exceptions_enable=False, no_args_is_help=True,
                  help="Image-goal navigation with an uncertainty-aware NeRF memory.")
scenes_app = typer.Typer(no_args_is_help=True, help="Generate and inspect Gibson-layout scenes.")
episodes_app = typer.Typer(no_args_is_help=True, help="Generate and convert navigation episodes.")
app.add_typer(scenes_app, name="scenes")
app.add_typer(episodes_app, name="episodes")


@scenes_app.command("generate")
def scenes_generate(
    split: str = typer.Option(..., help="train (21 houses), val (14 houses) or val_plain (14 houses of the held-out "
                              "plain scene style)."),
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
@config_command
def episodes_generate(
    scene: Path = typer.Option(..., help="Scene folder (Gibson layout)."),
    out: Path = typer.Option(..., help="Episode file to write."),
    gen: EpisodeGenConfig = ConfigOptions("nue.sim.episode_gen:EpisodeGenConfig", Opt("per_bin", check=A.positive)),
    seed: int = typer.Option(0, help="Random seed."),
    task: str = typer.Option("paper", help="Task preset: paper, official or habitat."),
    fmt: str = typer.Option("nue", "--format", help="nue (ours), authors, or habitat (habitat-lab's PointNav/ImageNav "
                            "dataset; gzip when OUT ends in .gz)."),
):
    """Sample episodes into the task's difficulty bins."""
    from nue.scene.scene import Scene
    from nue.sim.episode_gen import generate_episodes
    from nue.sim.episodes import save_episodes

    A.choice("--format", fmt, EPISODE_FORMATS)
    check_output_file(out, "the episode file")
    s = Scene.load(scene)
    eps = generate_episodes(s, task, gen, seed=seed)
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
episodes_app.command("make-set")(make_set_cmd)


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
    from nue.policy.agent import EXPERT_KINDS, ExpertAgent
    from nue.rollout import run_episode
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


app.command("collect")(collect_cmd)
app.command("convert")(convert_cmd)
app.command("train")(train_cmd)
app.command("dagger")(dagger_cmd)
app.command("select")(select_cmd)
app.command("reproduce")(reproduce_cmd)


EVAL = ConfigOptions(
    "nue.evaluate.runner:EvalConfig", Opt("episodes_dir", path=True), Opt("scenes_root", path=True), "task", "seed",
    Opt("device", check=A.device), "swap_maps", Opt("max_episodes", check=A.non_negative),
    Opt("max_steps", check=A.non_negative), "skip_invalid")


@app.command("eval")
@config_command
def eval_cmd(
    method: list[str] = typer.Option(..., "--checkpoint", "-c", help="Checkpoint path, name=path, or 'expert'; repeatable."),
    out: Path = typer.Option(Path("results/records.jsonl"), help="JSON-lines file the records are appended to."),
    cfg: EvalConfig = EVAL,
    workers: int = typer.Option(1, help="Parallel local worker processes."),
    ray_address: Optional[str] = typer.Option(None, help="Run episodes as tasks on this Ray cluster."),
):
    """Evaluate checkpoints on the fixed validation episodes (resumes if rerun)."""
    from nue.evaluate.metrics import aggregate, format_table
    from nue.evaluate.report import load_records
    from nue.evaluate.runner import run_eval

    A.positive("--workers", workers)
    check_output_file(out, "the records file")
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
    from nue.viz.coverage import write_coverage_figure

    check_output_dir(out, "the report folder")
    if results_md:
        check_output_file(results_md)
    recs = load_records(*records)
    paths = {**write_report(recs, out, task=task), **write_coverage_figure(recs, out)}
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


@app.command("view")
def view_cmd(
    scene: Optional[Path] = typer.Option(None, help="Live run: scene folder."),
    episodes: Optional[Path] = typer.Option(None, help="Live run: episode file; replay: the file holding the record's episode "
                                            "(default EPISODES_DIR/<scene>.json)."),
    episode: str = typer.Option("0", help="Live run: episode id or index in the file."),
    checkpoint: Optional[Path] = typer.Option(None, help="Live run: policy checkpoint (default: the geodesic expert). "
                                              "Replay with --maps: the memory's preset and initial weights."),
    records: list[Path] = typer.Option([], "--records", help="Replay: record files (JSON lines); repeatable."),
    key: Optional[str] = typer.Option(None, help="Replay: the record's key (method/scene/episode_id)."),
    maps: bool = typer.Option(False, help="Replay: re-run the memory along the recorded poses to show I_u / I_cog."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Replay: where the record's house is."),
    episodes_dir: Path = typer.Option(Path("episodes/val"), help="Replay: folder of per-house episode files."),
    task: str = typer.Option("paper", help="Task preset."),
    seed: int = typer.Option(0, help="Live run: episode seed."),
    max_steps: int = typer.Option(0, help="Live run: override the step limit (0 = the preset's)."),
    port: int = typer.Option(9090, help="Port of the web page."),
    grpc_port: int = typer.Option(9876, help="Port of the data stream the page reads."),
    save: Optional[Path] = typer.Option(None, help="Also write the recording here (.rrd; opens with `rerun FILE`)."),
    serve: bool = typer.Option(True, help="Serve the page (--no-serve: only --save)."),
    screenshot: Optional[Path] = typer.Option(None, help="Write a PNG of the page (headless chromium) after the episode, then exit."),
    serve_seconds: float = typer.Option(0.0, help="Serve this long after the episode (0 = until Ctrl-C; with --screenshot: exit)."),
    screenshot_timeout: float = typer.Option(120.0, help="Give up on the screenshot when the page is not ready after this many seconds."),
):
    """Watch an episode in the browser (house, robot, frames, memory, uncertainty, time slider): run live, or replay a record."""
    from nue.errors import ConfigError

    try:
        import rerun  # noqa: F401
    except ImportError:
        raise ConfigError("nue view", "needs the viewer library: pip install 'nue[view]' (rerun-sdk)") from None
    from nue.viz.view import LiveSource, ReplaySource, ViewConfig, view

    A.non_negative("--max-steps", max_steps)
    if save:
        check_output_file(save, "the recording")
    if screenshot:
        check_output_file(screenshot, "the screenshot")
    if records or key:
        if not (records and key):
            raise ConfigError("--records", "a replay needs both --records and --key")
        source = ReplaySource(records=tuple(map(str, records)), key=key, scenes_root=str(scenes_root),
                              episodes=str(episodes) if episodes else None, episodes_dir=str(episodes_dir), task=task,
                              maps=maps, checkpoint=str(checkpoint) if checkpoint else None)
    else:
        if scene is None or episodes is None:
            raise ConfigError("--scene", "a live run needs --scene and --episodes (or replay with --records and --key)")
        source = LiveSource(scene=str(scene), episodes=str(episodes), episode=episode,
                            checkpoint=str(checkpoint) if checkpoint else None, task=task, seed=seed, max_steps=max_steps)
    cfg = ViewConfig(port=port, grpc_port=grpc_port, serve=serve, save=str(save) if save else None)
    view(cfg, source, screenshot=str(screenshot) if screenshot else None, serve_seconds=serve_seconds,
         screenshot_timeout=screenshot_timeout, echo=typer.echo)


def main(argv: list[str] | None = None) -> None:
    """The ``nue`` console entry point: runs the command line ``argv`` (default ``sys.argv[1:]``); a failure the
    user can fix is one line ``error: ...`` and exit status 2 (:func:`nue.cli_args.run`)."""
    A.run(app, argv)


if __name__ == "__main__":
    main()
