"""The ``nue`` command line: the app with its scenes, episodes, demo and view commands; the others are in
:mod:`nue.cli_learn` (collect, convert, train, dagger, select), :mod:`nue.cli_evaluate` (expert, eval, report,
diagnose) and :mod:`nue.cli_reproduce`; options of configs come from their dataclasses (:mod:`nue.cli_config`).

Bad input (a malformed scene folder, episode file, ...) prints ``error: <file>: <problem>`` and exits
with status 2, without a traceback (:func:`nue.cli_args.run`).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Optional

import typer

from nue import cli_args as A
from nue.cli_config import ConfigOptions, Opt, config_command
from nue.cli_evaluate import diagnose_cmd, eval_cmd, expert_cmd, explore_cmd, report_cmd
from nue.cli_learn import collect_cmd, convert_cmd, dagger_cmd, select_cmd, train_cmd
from nue.cli_reproduce import make_set_cmd, reproduce_cmd
from nue.outputs import check_output_dir, check_output_file

if TYPE_CHECKING:
    from nue.sim.episode_gen import EpisodeGenConfig
    from nue.viz.view import ViewConfig

app = typer.Typer(add_completion=False, pretty_exceptions_enable=False, no_args_is_help=True,
                  help="Image-goal navigation with an uncertainty-aware NeRF memory.")
scenes_app = typer.Typer(no_args_is_help=True, help="Generate and inspect Gibson-layout scenes.")
episodes_app = typer.Typer(no_args_is_help=True, help="Generate and convert navigation episodes.")
app.add_typer(scenes_app, name="scenes")
app.add_typer(episodes_app, name="episodes")


@scenes_app.command("generate")
def scenes_generate(
    split: str = typer.Option(..., help="train (21 houses), val (14 houses), val_plain (14 houses of the held-out "
                              "plain scene style), train_diverse (42 houses, a style drawn per house from the "
                              "diverse distribution) or val_pale (14 houses of the held-out pale family)."),
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


@scenes_app.command("stats")
def scenes_stats(
    splits: str = typer.Option("train,val,val_plain,train_diverse,val_pale", help="Comma-separated splits to measure."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the houses are (generated if missing)."),
    out: Optional[Path] = typer.Option(None, help="Markdown file to write the table to (and the same stem .json with "
                                       "every house's numbers); default: print the table."),
    reference_split: str = typer.Option("train_diverse", "--reference", help="Training split the look distances are "
                                        "measured to."),
):
    """Appearance and layout statistics of generated splits: wall lightness, chroma and pattern contrast,
    wall-floor contrast, shared wall colours, layouts, and parameters outside the training style distribution."""
    import json

    from nue.scene.generator import SPLITS, ensure_house
    from nue.scene.style_stats import house_stats, split_stats, stats_markdown

    names = [s for s in splits.split(",") if s]
    for name in names:
        A.choice("--splits", name, SPLITS)
    A.choice("--reference", reference_split, SPLITS)
    if out is not None:
        check_output_file(out, "the statistics file")
    houses = {n: [house_stats(ensure_house(n, i, scenes_root)) for i in range(len(SPLITS[n]))] for n in names}
    reference = houses.get(reference_split) or [house_stats(ensure_house(reference_split, i, scenes_root))
                                                for i in range(len(SPLITS[reference_split]))]
    stats = {n: split_stats(h, reference) for n, h in houses.items()}
    table = stats_markdown(stats)
    if out is None:
        typer.echo(table, nl=False)
        return
    out.write_text(f"# Scene style statistics\n\nMade by `nue scenes stats --splits {','.join(names)} --reference "
                   f"{reference_split} --out {out}` (nue.scene.style_stats; median [min, max] over each split's "
                   "houses; look distance: wall L*, C* and pattern contrast in units of their spread over the "
                   "reference split, to its nearest other house).\n\n" + table)
    out.with_suffix(".json").write_text(json.dumps({"splits": stats, "houses": houses}, indent=1) + "\n")
    typer.echo(f"{sum(len(h) for h in houses.values())} houses -> {out}, {out.with_suffix('.json')}")


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


app.command("expert")(expert_cmd)
app.command("collect")(collect_cmd)
app.command("convert")(convert_cmd)
app.command("train")(train_cmd)
app.command("dagger")(dagger_cmd)
app.command("select")(select_cmd)
app.command("reproduce")(reproduce_cmd)
app.command("eval")(eval_cmd)
app.command("explore")(explore_cmd)
app.command("report")(report_cmd)
app.command("diagnose")(diagnose_cmd)


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


_VIEW = "nue.viz.view"
VIEW_LIVE = ConfigOptions(
    f"{_VIEW}:LiveSource",
    Opt("scene", path=True, default=None, help="Live run: scene folder."),
    Opt("episodes", path=True, default=None, help="Live run: episode file; replay: the file holding the record's episode "
                                                  "(default EPISODES_DIR/<scene>.json)."),
    Opt("episode", help="Live run: episode id or index in the file."),
    Opt("checkpoint", path=True, help="Live run: policy checkpoint (default: the geodesic expert). Replay with --maps: "
                                      "the memory's preset and initial weights."),
    as_dict=True)
VIEW_REPLAY = ConfigOptions(
    f"{_VIEW}:ReplaySource", Opt("records", path=True, default=(), help="Replay: record files (JSON lines); repeatable."),
    Opt("key", default=None, help="Replay: the record's key (method/scene/episode_id)."),
    Opt("maps", help="Replay: re-run the memory along the recorded poses to show I_u / I_cog."),
    Opt("scenes_root", path=True, help="Replay: where the record's house is."),
    Opt("episodes_dir", path=True, help="Replay: folder of per-house episode files (default: the set under "
                                        "episodes/ whose file holds the record's episode, found by its digest)."),
    Opt("drop_duplicates", help="Replay: a records file with a key recorded twice is refused; with this, use the first "
                                "record of each key and say how many were dropped."), as_dict=True)
VIEW_RUN = ConfigOptions(f"{_VIEW}:LiveSource", "task", Opt("seed", help="Live run: episode seed."),
                         Opt("max_steps", check=A.non_negative, help="Live run: override the step limit (0 = the preset's)."),
                         as_dict=True)
VIEW_SERVE = ConfigOptions(f"{_VIEW}:ViewConfig", "host", Opt("port", help="Port of the web page."), "grpc_port",
                           Opt("save", path=True, help="Also write the recording here (.rrd; opens with `rerun FILE`)."),
                           Opt("serve", help="Serve the page (--no-serve: only --save)."))


@config_command
def view_cmd(
    live: dict = VIEW_LIVE,
    replay: dict = VIEW_REPLAY,
    run: dict = VIEW_RUN,
    cfg: ViewConfig = VIEW_SERVE,
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
    from nue.viz.view import LiveSource, ReplaySource, view

    if cfg.save:
        check_output_file(Path(cfg.save), "the recording")
    if screenshot:
        check_output_file(screenshot, "the screenshot")
    if replay["records"] or replay["key"]:
        if not (replay["records"] and replay["key"]):
            raise ConfigError("--records", "a replay needs both --records and --key")
        source = ReplaySource(**replay, task=run["task"], episodes=live["episodes"], checkpoint=live["checkpoint"])
    else:
        if live["scene"] is None or live["episodes"] is None:
            raise ConfigError("--scene", "a live run needs --scene and --episodes (or replay with --records and --key)")
        source = LiveSource(**live, **run)
    view(cfg, source, screenshot=str(screenshot) if screenshot else None, serve_seconds=serve_seconds,
         screenshot_timeout=screenshot_timeout, echo=typer.echo)


app.command("view")(view_cmd)


def main(argv: list[str] | None = None) -> None:
    """The ``nue`` console entry point: runs the command line ``argv`` (default ``sys.argv[1:]``); a failure the
    user can fix is one line ``error: ...`` and exit status 2 (:func:`nue.cli_args.run`)."""
    A.run(app, argv)


if __name__ == "__main__":
    main()
