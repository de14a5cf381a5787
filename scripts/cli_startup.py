"""Measure the command line's start-up: ``nue --help`` / ``nue train --help`` as generated now (options read from
the config dataclasses' source, :mod:`nue.cli_config`) against tyro building the same help from the imported
classes (which imports the config modules, and with them torch).

    PYTHONPATH=.:<a folder with tyro> python scripts/cli_startup.py [--repeat 3]

Each variant runs ``--repeat`` times in a fresh interpreter; printed: the least CPU time (user + sys of the child,
which the machine's other load changes least) and the least wall-clock. Variants needing tyro are skipped when it
is not importable (it is not a dependency of nue).
"""

from __future__ import annotations

import argparse
import os
import resource
import subprocess
import sys
import time

CONFIGS = {  # every config dataclass whose fields are nue's options today
    "collect": "nue.train.collect:CollectConfig", "storage": "nue.train.compact:StepStorage",
    "train": "nue.train.bc:TrainConfig", "dagger": "nue.train.dagger:DaggerConfig",
    "select": "nue.selection:SelectConfig", "eval": "nue.evaluate.runner:EvalConfig",
    "explore": "nue.evaluate.exploration:ExploreConfig", "episodes": "nue.sim.episode_gen:EpisodeGenConfig",
    "view": "nue.viz.view:ViewConfig", "live": "nue.viz.view:LiveSource", "replay": "nue.viz.view:ReplaySource",
}
_IMPORT_ALL = "import importlib\n" + "".join(
    f"{k} = getattr(importlib.import_module({ref.split(':')[0]!r}), {ref.split(':')[1]!r})\n" for k, ref in CONFIGS.items())
VARIANTS = {
    "python -c pass": "pass",
    "nue --help (generator)": "import sys; from nue.cli import main; main(['--help'])",
    "nue train --help (generator)": "import sys; from nue.cli import main; main(['train', '--help'])",
    "import tyro": "import tyro",
    "import the config classes": _IMPORT_ALL,
    "tyro: TrainConfig --help": "import tyro\nfrom nue.train.bc import TrainConfig\ntyro.cli(TrainConfig, args=['--help'])",
    "tyro: 11 config subcommands --help": ("import tyro\n" + _IMPORT_ALL
                                          + f"tyro.extras.subcommand_cli_from_dict({{{', '.join(f'{k!r}: {k}' for k in CONFIGS)}}}, "
                                            "args=['--help'])"),
}
NEEDS_TYRO = {"import tyro", "tyro: TrainConfig --help", "tyro: 11 config subcommands --help"}


def measure(code: str) -> tuple[float, float, int]:
    """(CPU seconds of the child, wall seconds, exit code) of one fresh interpreter running ``code``."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         env={**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if res.returncode not in (0,):
        sys.stderr.write(res.stderr[-2000:])
    return (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), wall, res.returncode


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--only", default="", help="comma-separated substrings of variant names to run")
    args = ap.parse_args()
    try:
        import tyro  # noqa: F401
        have_tyro = True
    except ImportError:
        have_tyro = False
    for name, code in VARIANTS.items():
        if args.only and not any(s in name for s in args.only.split(",")):
            continue
        if name in NEEDS_TYRO and not have_tyro:
            print(f"{name:40s} skipped (tyro not importable)", flush=True)
            continue
        runs = [measure(code) for _ in range(args.repeat)]
        codes = sorted({c for _, _, c in runs})
        print(f"{name:40s} CPU {min(c for c, _, _ in runs):6.2f} s   wall {min(w for _, w, _ in runs):6.2f} s   "
              f"exit {codes}", flush=True)


if __name__ == "__main__":
    main()
