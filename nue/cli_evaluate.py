"""The ``nue expert``, ``nue eval``, ``nue report`` and ``nue diagnose`` commands (running episodes, Table I,
closed-loop diagnostics); registered on the app in :mod:`nue.cli`, which handles errors."""

from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, Optional

import typer

from nue import cli_args as A
from nue.cli_config import RAY_ADDRESS, WORKERS, ConfigOptions, Opt, config_command
from nue.outputs import check_output_dir, check_output_file

if TYPE_CHECKING:
    from nue.evaluate.exploration import ExploreConfig
    from nue.evaluate.runner import EvalConfig


def _echo_episode_checks(skipped, snapped: dict | None = None, source=None) -> None:
    """Print the episodes left out by --skip-invalid, and those whose start or goal was snapped."""
    if skipped:
        typer.echo(f"skipped {len(skipped)} invalid episode(s) (--skip-invalid):")
        for e in skipped:
            typer.echo(f"  {e}")
    if snapped:
        parts = [f"{eid} (start {s.start:.3f} m, goal {s.goal:.3f} m)" for eid, s in snapped.items()]
        typer.echo(f"{source}: snapped to navigable cells: {', '.join(parts)}")


DROP_HELP = ("A records file with a key recorded twice is refused; with this, keep the first record of each key and "
             "say how many were dropped.")


def _echo_dropped(path: Path, n: int) -> None:
    from nue.evaluate.record_keys import dropped_message

    typer.echo(dropped_message(path, n), err=True)


def expert_cmd(
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


EVAL = ConfigOptions(
    "nue.evaluate.runner:EvalConfig", Opt("episodes_dir", path=True), Opt("scenes_root", path=True), "task", "seed",
    Opt("device", check=A.device), "swap_maps", Opt("max_episodes", check=A.non_negative), Opt("per_bin", check=A.non_negative),
    Opt("max_steps", check=A.non_negative), "skip_invalid", Opt("temperature", check=A.non_negative),
    Opt("batch", check=A.positive))


@config_command
def eval_cmd(
    method: list[str] = typer.Option(..., "--checkpoint", "-c", help="Checkpoint path, name=path, 'expert', 'expert-explore', "
                                     "or sling+name=path (the checkpoint with the last-mile wrapper); repeatable."),
    out: Path = typer.Option(Path("results/records.jsonl"), help="JSON-lines file the records are appended to."),
    cfg: EvalConfig = EVAL,
    last_mile: Optional[Path] = typer.Option(None, "--last-mile", help="JSON file of the sling+ wrapper's settings "
                                             "(LastMileConfig, nested as records store them; a key left out keeps "
                                             "its default), e.g. {\"pose\": {\"contrast_threshold\": 0.01}}."),
    workers: int = WORKERS,
    ray_address: Optional[str] = RAY_ADDRESS,
):
    """Evaluate checkpoints on the fixed validation episodes (resumes if rerun)."""
    import dataclasses

    from nue.evaluate.metrics import aggregate, format_table
    from nue.evaluate.report import load_records
    from nue.evaluate.runner import run_eval

    A.positive("--workers", workers)
    check_output_file(out, "the records file")
    if last_mile is not None:
        cfg = dataclasses.replace(cfg, last_mile=_read_last_mile(last_mile))
    skipped: list = []
    run_eval(method, out, cfg, workers=workers, ray_address=ray_address, skipped=skipped)
    _echo_episode_checks(skipped)
    records = load_records(out, drop_duplicates=True, on_dropped=_echo_dropped)  # duplicates of an older writer
    for name in sorted({r.method for r in records}):
        typer.echo(f"## {name}\n" + format_table(aggregate([r for r in records if r.method == name])))


def _read_last_mile(path: Path):
    """``--last-mile``: the wrapper's settings from a JSON file (DataError / ConfigError naming the file)."""
    import json

    from nue.errors import DataError
    from nue.policy.last_mile import LastMileConfig

    try:
        data = json.loads(path.read_text())
    except OSError as e:
        raise DataError(path, f"cannot read the last-mile settings: {e.strerror or e}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(path, f"not a JSON file of last-mile settings: {e}") from None
    return LastMileConfig.from_dict(data, str(path))


EXPLORE = ConfigOptions(
    "nue.evaluate.exploration:ExploreConfig", Opt("episodes_dir", path=True), Opt("scenes_root", path=True), "task",
    "seed", Opt("device", check=A.device), Opt("steps", check=A.positive), Opt("per_bin", check=A.non_negative))


@config_command
def explore_cmd(
    method: list[str] = typer.Option(..., "--checkpoint", "-c", help="Checkpoint path, name=path, 'expert-explore' "
                                     "or 'random'; repeatable."),
    out: Path = typer.Option(Path("results/explore.jsonl"), help="JSON-lines file the records are appended to."),
    cfg: ExploreConfig = EXPLORE,
    reference: str = typer.Option("abl_at_cbam", help="Method (default: the ablation without f_u) the others' seen area is divided by in the summary."),
    workers: int = WORKERS,
    ray_address: Optional[str] = RAY_ADDRESS,
):
    """Exploration benchmark: seen floor area over STEPS steps from the episodes' starts with a goal photo from
    another house (nothing to find; resumes if rerun)."""
    from nue.evaluate.exploration import exploration_summary, format_exploration_markdown, run_explore
    from nue.evaluate.report import load_records

    A.positive("--workers", workers)
    check_output_file(out, "the records file")
    run_explore(method, out, cfg, workers=workers, ray_address=ray_address)
    records = load_records(out, drop_duplicates=True, on_dropped=_echo_dropped)  # duplicates of an older writer
    typer.echo(format_exploration_markdown(exploration_summary(records, reference), reference))


def _record_files(spec: str) -> list[Path]:
    """The files of a ``--set`` value's FILE part: comma-separated paths, each a path or a glob pattern (a pattern
    matching nothing is an error; a plain path is checked by the reader)."""
    import glob

    from nue.errors import ConfigError

    files: list[Path] = []
    for part in filter(None, (p.strip() for p in spec.split(","))):
        if glob.has_magic(part):
            hits = sorted(glob.glob(part))
            if not hits:
                raise ConfigError("--set", f"no record file matches {part!r}")
            files += map(Path, hits)
        else:
            files.append(Path(part))
    if not files:
        raise ConfigError("--set", f"no record file in {spec!r}")
    return files


def report_cmd(
    records: list[Path] = typer.Argument(..., help="Record files (JSON lines) from `nue eval`."),
    out: Path = typer.Option(Path("results/report"), help="Folder for table.md/.csv/.tex and coverage.png."),
    results_md: Optional[Path] = typer.Option(None, help="Also write this RESULTS.md (its generalisation section from "
                                          "RESULTS.generalisation.json beside it, when there is one)."),
    command: str = typer.Option("", help="The evaluation command, recorded in RESULTS.md."),
    task: str = typer.Option("paper", help="Task preset of the records (its action ids, for the closed-loop diagnostics)."),
    episode_set: list[str] = typer.Option([], "--set", help="NAME=FILE[,FILE...]: records of a further episode set "
                                          "(e.g. val252=results/records_val252.jsonl; several files by commas or a "
                                          "quoted glob: 'val_plain=results/gru/records_val_plain*.jsonl'), its own "
                                          "section in RESULTS.md and report folder OUT/NAME; repeatable."),
    name: str = typer.Option("", help="The episode set of RECORDS (e.g. val252), as RESULTS.md's pooled section names "
                             "it; default \"Table I's episodes\"."),
    explore: list[str] = typer.Option([], help="NAME=FILE: `nue explore` records from set NAME's starts, a section of "
                                      "RESULTS.md; repeatable."),
    drop_duplicates: bool = typer.Option(False, help=DROP_HELP),
    reference: str = typer.Option("nue", help="Method the report folder's paired differences are to (e.g. nue_lean, "
                                  "to compare candidates with a variant of NUE); RESULTS.md always compares to NUE."),
    generalisation: str = typer.Option("", help="Reference set (e.g. val252: the name of RECORDS or of a --set): write "
                                       "OUT/generalisation.md, and a RESULTS.md section, with each model's SR / SPL "
                                       "on it and on every held-out style set given (val_plain, val_pale), the drop, "
                                       "and paired differences on each."),
    pair: list[str] = typer.Option([], help="A,B: with --generalisation, the paired difference A - B of two methods on "
                                   "the reference set and every held-out set, in one table (in place of the "
                                   "differences to --reference); repeatable."),
):
    """Table I (SR / SPL / DTS per difficulty, CIs, paired differences to NUE) and coverage."""
    import json
    import platform

    from nue.errors import ConfigError
    from nue.evaluate.report import load_records, write_report
    from nue.evaluate.results_md import HELD_OUT_FILE, load_held_out, render_results_md
    from nue.evaluate.table import canonical_method, split_seed
    from nue.viz.coverage import write_coverage_figure

    check_output_dir(out, "the report folder")
    if results_md:
        check_output_file(results_md)
    read: dict[str, Any] = {"drop_duplicates": drop_duplicates, "on_dropped": _echo_dropped}
    recs = load_records(*records, **read)
    sets = {}
    for spec in episode_set:
        set_name, sep, path = spec.partition("=")
        if not sep or not set_name or not path:
            raise ConfigError("--set", f"expected NAME=FILE[,FILE...], got {spec!r}")
        if set_name in sets:
            raise ConfigError("--set", f"episode set {set_name!r} given twice")
        sets[set_name] = load_records(*_record_files(path), **read)
    pairs = []
    for spec in pair:
        a, sep, b = spec.partition(",")
        if not sep or not a or not b or "," in b:
            raise ConfigError("--pair", f"expected A,B (two method names), got {spec!r}")
        pairs.append((canonical_method(a), canonical_method(b)))
    if pairs and not generalisation:
        raise ConfigError("--pair", "needs --generalisation (the pairs are compared on its sets)")
    explored = {}
    for spec in explore:
        set_name, sep, path = spec.partition("=")
        if not sep or not set_name or not path:
            raise ConfigError("--explore", f"expected NAME=FILE, got {spec!r}")
        explored[set_name] = load_records(Path(path), **read)
    if reference != "nue" and not any(canonical_method(split_seed(r.method)[0]) == canonical_method(reference)
                                      for r in recs):
        raise ConfigError("--reference", f"no record of method {reference!r} in {', '.join(map(str, records))}")
    paths = {**write_report(recs, out, task=task, compare_to=reference), **write_coverage_figure(recs, out)}
    for set_name, set_recs in sets.items():
        write_report(set_recs, out / set_name, task=task, compare_to=reference)
        write_coverage_figure(set_recs, out / set_name)
    for set_name, set_recs in explored.items():
        paths.update(write_coverage_figure(set_recs, out, f"explore_{set_name}.png",
                                           f"Exploration benchmark from {set_name}'s starts"))
    typer.echo((out / "table.md").read_text() if (out / "table.md").is_file() else "")
    if generalisation:
        from nue.evaluate.results_md import generalisation_section

        all_sets = {name or "val": recs, **sets}
        if generalisation not in all_sets:
            raise ConfigError("--generalisation", f"{generalisation!r} is not the name of RECORDS (--name) or of a --set")
        section = generalisation_section(generalisation, all_sets, compare_to=reference, pairs=pairs)
        if not section:
            typer.echo("no generalisation table: no model ran the reference set and a held-out set (--set val_plain=...)")
        else:
            (out / "generalisation.md").write_text(section)
            paths["generalisation"] = out / "generalisation.md"
            typer.echo(section)
    if results_md:
        meta_path = results_md.parent / f"{results_md.stem}.meta.json"
        meta = json.loads(meta_path.read_text()) if meta_path.is_file() else {
            "command": command, "date": "", "commit": "", "machine": f"{platform.machine()}, {os.cpu_count()} CPUs"}
        held_path = results_md.parent / f"{results_md.stem}.{HELD_OUT_FILE}"
        held = load_held_out(held_path) if held_path.is_file() else None
        results_md.write_text(render_results_md(recs, meta, task, sets=sets, main_name=name, explore=explored,
                                                generalisation=generalisation, held_out=held))
        typer.echo(f"wrote {results_md}")
    typer.echo(f"wrote {', '.join(str(p) for p in paths.values())}")


def diagnose_cmd(
    records: list[Path] = typer.Option([], "--records", help="Record files (JSON lines) from `nue eval`; repeatable."),
    method: list[str] = typer.Option([], help="Only these methods (repeatable; default: all)."),
    checkpoint: Optional[Path] = typer.Option(None, help="With --data: held-out accuracy with intact, mirrored and other-step maps, and P(forward) after blocked moves."),
    data: Optional[Path] = typer.Option(None, help="Collection folder: previous-action probe on its maps (and the map controls)."),
    part: str = typer.Option("heldout", help="Part of the collection to use (heldout or train)."),
    task: str = typer.Option("paper", help="Task preset the records' action ids belong to."),
    max_episodes: int = typer.Option(200, help="Map controls: at most this many episodes."),
    probe_steps: int = typer.Option(20_000, help="Probe: subsample at most this many steps."),
    probe_cog: bool = typer.Option(False, help="Probe: add the mean norm of I_cog to the features."),
    seed: int = typer.Option(0, help="Seed of the other-step maps, the probe's subsample and its shuffled control."),
    handoff: bool = typer.Option(False, help="With --records: recompute the exploration -> exploitation hand-off of "
                                 "records made without it into their hand-off files (records_X.handoff.jsonl; resumes)."),
    agree: str = typer.Option("", help="With --records: A,B, two methods' per-step action agreement over the first "
                              "--agree-steps steps of the episodes both ran (e.g. a --batch 8 run against --batch 1)."),
    agree_steps: int = typer.Option(50, help="--agree: steps compared per episode."),
    episodes_dir: Optional[Path] = typer.Option(None, help="--handoff: the records' episode files (<house>.json)."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="--handoff: where the houses are (generated if missing)."),
    workers: int = WORKERS,
    out: Optional[Path] = typer.Option(None, help="Also write everything as JSON here."),
    drop_duplicates: bool = typer.Option(False, help=DROP_HELP),
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
    if handoff and (not records or episodes_dir is None):
        raise ConfigError("--handoff", "needs --records and --episodes-dir (the records' episode files)")
    if records:
        from nue.evaluate.handoff import format_handoff_markdown, handoff_summaries
        from nue.evaluate.handoff_job import handoff_path, load_records_with_handoff, run_handoff

        A.positive("--workers", workers)
        if handoff:
            for r in records:
                recs_r = D.read_records(r, drop_duplicates=drop_duplicates)
                bare = sum(x.extra.get("trajectory") is None for x in recs_r)
                if bare:
                    typer.echo(f"{r}: {bare} record(s) without a trajectory (made before trajectories were stored): "
                               "no hand-off for them")
                run_handoff(recs_r, handoff_path(r), episodes_dir, scenes_root, task, workers=workers)
        recs = load_records_with_handoff(*records, drop_duplicates=drop_duplicates, on_dropped=_echo_dropped)
        diags = D.record_diagnostics(recs, task, method)
        result["records"] = diags
        typer.echo("## Closed-loop diagnostics\n\n" + D.format_record_diagnostics(diags))
        if agree:
            pair = [m.strip() for m in agree.split(",")]
            A.positive("--agree-steps", agree_steps)
            if len(pair) != 2 or not set(pair) <= {r.method for r in recs}:
                raise ConfigError("--agree", f"expected two methods of the records as A,B, got {agree!r}")
            ag = D.action_agreement(recs, pair[0], pair[1], agree_steps)
            result["agreement"] = ag
            first = "–" if ag.median_first_difference is None else f"{ag.median_first_difference:.0f}"
            typer.echo(f"## Action agreement\n\n{ag.a} vs {ag.b}: {100 * ag.agreement:.1f}% of {ag.steps} steps "
                       f"(the first {agree_steps} of {ag.episodes} episodes both ran) chose the same action; "
                       f"{ag.identical} episodes identical throughout; median first difference at step {first}\n")
        summaries = {k: v for k, v in handoff_summaries(recs).items() if not method or k in method}
        if summaries:
            result["handoff"] = summaries
            typer.echo("## Exploration -> exploitation hand-off\n\n" + format_handoff_markdown(summaries))
    if data is not None:
        from nue.evaluate import diagnose_maps as M
        from nue.sim.task import get_task
        from nue.train.dataset import DemoSet

        demos = DemoSet(data, part, verify=False)
        if checkpoint is not None:
            result["map_controls"] = M.map_controls(checkpoint, demos, seed=seed, max_episodes=max_episodes)
            typer.echo("## Map controls\n\n" + M.format_map_controls(result["map_controls"]))
            demo_task = get_task(demos.manifest.task)
            result["after_blocked"] = M.after_blocked(checkpoint, demos, demo_task.forward_step,
                                                      demo_task.action_id("MOVE_FORWARD"))
            typer.echo("## After a blocked move\n\n" + M.format_after_blocked(result["after_blocked"]))
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
