"""The ``nue reproduce`` command (Table I in one resumable run) and ``nue episodes make-set`` (the fixed
evaluation episode sets); registered on the app in :mod:`nue.cli`, which handles errors."""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import typer

from nue import cli_args as A
from nue.errors import ConfigError
from nue.outputs import check_output_dir, check_output_file


def reproduce_cmd(
    out: Path = typer.Option(Path("runs/reproduce"), help="Run folder (recipe, demonstrations, runs, records, report)."),
    # "v12" is nue.recipes.DEFAULT_RECIPE (a test checks; importing it would load torch for every command)
    recipe: str = typer.Option("v12", help="Recipe preset (nue.recipes.RECIPES): v12 (the default: a recurrent NUE and "
                                           "ablations on the lean memory, 3 seeds for the compared rows, VGM, NRNS and "
                                           "the SLING rows, trained in both house sets, evaluated on val252 and both "
                                           "held-out style families, with the exploration benchmark; ~35 h on 2 "
                                           "cores), v10 (the same in the train houses only; ~24 h), v6 (the shipped "
                                           "checkpoints' and RESULTS.md's; ~10 h), v7, v8, v9, v11, v5, v3 or quick."),
    quick: bool = typer.Option(False, help="Tiny everything (the quick recipe): an end-to-end check in about a minute."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the houses are (generated if missing)."),
    episodes_root: Path = typer.Option(Path("episodes"), help="The committed episode sets (val, val252, val_plain, select)."),
    workers: int = typer.Option(1, help="Parallel local worker processes (collection, training side by side, evaluation)."),
    ray_address: Optional[str] = typer.Option(None, help="Run episodes and trainings as tasks on this Ray cluster."),
    device: str = typer.Option("cpu", help="cpu or cuda."),
    results_md: Optional[Path] = typer.Option(None, help="Also write RESULTS.md here (e.g. the repository's)."),
    estimate_only: bool = typer.Option(False, "--estimate", help="Print the time estimate and stop (what is left, if OUT holds a run)."),
    compile: bool = typer.Option(False, help="Train with torch.compile (nue train --compile): ~1.5x the samples/s of NUE "
                                             "on a CPU, the same arithmetic rounded differently; not part of the recipe."),
    adopt: list[str] = typer.Option([], "--adopt", help="NAME=FOLDER: a collection (collect, collect/<split>) or "
                                    "training run (nue, nue@s1) made outside the run with the stage's exact settings, "
                                    "checked and put into the run folder so the stage resumes it; repeatable."),
):
    """Collect, train every model of Table I, evaluate on the fixed episode sets, report: one resumable run."""
    from nue.recipe import format_estimate
    from nue.recipes import get_recipe
    from nue.reproduce import RunFolders, check_recipe, remaining_estimate, reproduce
    from nue.reproduce_adopt import Adoption
    from nue.reproduce_calibrate import calibration

    A.positive("--workers", workers)
    A.device("--device", device)
    chosen = get_recipe("quick" if quick else recipe)
    adoptions = [Adoption.parse(a) for a in adopt]
    if adoptions and estimate_only:
        raise ConfigError("--adopt", "adopts into a run; without --estimate (the estimate then counts what was adopted)")
    if estimate_only:
        if (out / "recipe.json").is_file():
            check_recipe(out, chosen)  # a run of another recipe: refused, as a rerun would be
        folders = RunFolders(out, scenes_root, episodes_root)
        measured = calibration(chosen, folders, compile)
        left, note = remaining_estimate(chosen, folders, workers, compile, measured.cost_model()), measured.describe()
        typer.echo(f"recipe {chosen.name!r}, {workers} worker(s):\n{format_estimate(left)}" + (f"\n{note}" if note else ""))
        return
    check_output_dir(out, "the run folder")
    check_output_dir(scenes_root, "the scenes folder")
    if results_md:
        check_output_file(results_md)
    res = reproduce(chosen, out, scenes_root, episodes_root, workers=workers, ray_address=ray_address, device=device,
                    results_md=results_md, echo=typer.echo, compile=compile, adopt=adoptions)
    typer.echo(f"{len(res.ran)} stage(s) run, {len(res.kept)} kept from an earlier call; {res.results_md}")


def make_set_cmd(
    name: str = typer.Argument(..., help="Episode set (nue.sim.episode_sets.EPISODE_SETS): val, val252, val_plain, val_pale; select, select_diverse (closed-loop selection)."),
    root: Path = typer.Option(Path("episodes"), help="Folder of the sets: writes ROOT/NAME/, reads the set it extends there."),
    scenes_root: Path = typer.Option(Path("data/scenes"), help="Where the houses are (generated if missing)."),
    houses: str = typer.Option("", help="Comma-separated house indices (default: all of the split)."),
):
    """Rebuild a fixed evaluation episode set from its seeds (one file per house)."""
    from nue.sim.episode_sets import build_episode_set, get_episode_set

    get_episode_set(name)
    check_output_dir(root / name, "the episode set folder")
    paths = build_episode_set(name, scenes_root, root, A.ints("--houses", houses))
    typer.echo(f"{len(paths)} episode files -> {root / name}")
