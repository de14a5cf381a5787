"""The Table I estimate in ``make bench``: ``nue reproduce --estimate`` of the default recipe and of the one before
it, on 1 and 2 workers, eager and compiled (the cost model of ``nue.recipe_estimate``, whose fields say which
runs their numbers come from; nothing is timed here).

Writes ``benchmarks/results/estimate.json``.

    python benchmarks/estimate.py [--recipes v12,v10]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402

from nue.recipes import DEFAULT_RECIPE, get_recipe  # noqa: E402
from nue.recipe_estimate import estimate, format_duration  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--recipes", default=f"{DEFAULT_RECIPE},v10", help="comma-separated recipe presets")
    args = ap.parse_args()
    rows = {}
    print("| recipe | runs (models x seeds) | 1 worker | 2 workers | 2 workers, compiled | largest stage (2 workers) |")
    print("|---|---|---|---|---|---|")
    for name in args.recipes.split(","):
        recipe = get_recipe(name)
        totals = {}
        for label, workers, compiled in (("1", 1, False), ("2", 2, False), ("2c", 2, True)):
            stages = estimate(recipe, workers=workers, compiled=compiled)
            totals[label] = {"total_s": sum(s.seconds for s in stages), "stages": {s.stage: s.seconds for s in stages}}
        top = max(totals["2"]["stages"].items(), key=lambda kv: kv[1])
        rows[name] = {"runs": len(recipe.training_runs()), **totals}
        print(f"| {name}{' (default)' if name == DEFAULT_RECIPE else ''} | {rows[name]['runs']} | "
              f"{format_duration(totals['1']['total_s'])} | {format_duration(totals['2']['total_s'])} | "
              f"{format_duration(totals['2c']['total_s'])} | {top[0]} {format_duration(top[1])} |")
    path = write_result("estimate", {"default": DEFAULT_RECIPE, "target_h": 12.0, "recipes": rows})
    print(f"-> {path}")


if __name__ == "__main__":
    main()
