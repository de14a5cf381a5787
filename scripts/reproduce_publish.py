"""Publish a finished `nue reproduce` run as the repository's shipped rows (run once):

    python scripts/reproduce_publish.py --run results/reproduce/run --previous v5

1. ``checkpoints/<model>.pt`` (the previous recipe's) move to ``results/<previous>/checkpoints/<model>_<previous>.pt``
   and the run's ``runs/<model>/best.pt`` take their place;
2. in ``results/records.jsonl``, ``records_val252.jsonl`` and ``records_val_plain.jsonl`` the previous recipe's
   rows are renamed ``<method>_<previous>`` (``nue+swap`` -> ``nue_<previous>+swap``: RESULTS.md's "Earlier
   recipes"), the experts' rows are replaced by the run's (the script counts how many differ: the simulator and
   the experts are deterministic, so none should), and the run's records are added — ``records.jsonl`` gets
   the run's ``val252`` records of the 84 episodes of ``episodes/val``. Every earlier row's ``extra.key`` becomes
   ``<method>/<scene>/<episode_id>`` (``nue view --key`` finds a record by it; ``nue_v2``, ``nue_v3`` and ``nue_v4``
   had all kept the key ``nue/...`` of the run that made them).

Then regenerate RESULTS.md with the command the script prints (after updating RESULTS.meta.json by hand).
``--root`` (default: the repository holding this script) and ``--run`` (default ``<root>/results/reproduce/run``)
may be given relative to the current folder.
``--partial`` skips the check that the run finished (for a preview into a copy: ``--root /tmp/copy``).
``--table`` only prints the run's table for ``checkpoints/README.md`` (parameters, size, samples, closed-loop
selection, and on the 84 episodes of ``episodes/val`` SR, SPL, collisions, P(forward | blocked), NUE minus it),
computed from the run's files, and changes nothing.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
"""The repository this script belongs to."""

SETS = {"records.jsonl": ("val252", "val"), "records_val252.jsonl": ("val252", None),
        "records_val_plain.jsonl": ("val_plain", None)}
"""results file -> (the run's evaluation set whose records it gets, the episode folder that subsets them)"""
EXPERTS = ("expert", "expert-explore")


def fail(path, problem: str) -> None:
    print(f"error: {path}: {problem}", file=sys.stderr)
    sys.exit(2)


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def renamed(method: str, models: set[str], previous: str) -> str:
    base, swap = (method[:-5], "+swap") if method.endswith("+swap") else (method, "")
    return f"{base}_{previous}{swap}" if base in models else method


def episode_keys(folder: Path) -> set[tuple[str, str]]:
    keys = set()
    for f in sorted(folder.glob("*.json")):
        keys |= {(f.stem, str(e["episode_id"])) for e in json.loads(f.read_text())["episodes"]}
    return keys


def outcome(r: dict) -> tuple:
    return r["success"], r["steps"], r["collisions"], round(r["path_length"], 6)


def publish_records(root: Path, run: Path, models: set[str], previous: str) -> None:
    for name, (set_name, subset) in SETS.items():
        path = root / "results" / name
        old = read_jsonl(path)
        if any(r["method"] == f"nue_{previous}" for r in old):
            fail(path, f"already has {previous} rows renamed (published before?)")
        new = []
        for stage in (set_name, f"{set_name}+swap"):
            f = run / "records" / f"{stage}.jsonl"
            if f.exists():
                new += read_jsonl(f)
        if subset:
            keys = episode_keys(root / "episodes" / subset)
            new = [r for r in new if (r["scene"], str(r["episode_id"])) in keys]
        ran = {(r["method"], r["scene"], str(r["episode_id"])): r for r in new}
        kept, differ, rekeyed = [], 0, 0
        for r in old:
            if r["method"] in EXPERTS:
                twin = ran.get((r["method"], r["scene"], str(r["episode_id"])))
                differ += twin is not None and outcome(twin) != outcome(r)
                if twin is not None:
                    continue  # the run's record of the same expert episode replaces it
            method = renamed(r["method"], models, previous)
            key = f"{method}/{r['scene']}/{r['episode_id']}"  # `nue view --key` finds a row by it: one per row
            rekeyed += r["extra"].get("key") != key
            kept.append({**r, "method": method, "extra": {**r["extra"], "key": key}})
        path.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in kept + new))
        print(f"{path}: {len(old)} -> {len(kept) + len(new)} records ({len(new)} from the run; "
              f"expert episodes whose outcome differs from the earlier record: {differ}; earlier rows re-keyed "
              f"<method>/<scene>/<episode>: {rekeyed})")


def publish_checkpoints(root: Path, run: Path, models: list[str], previous: str) -> None:
    keep = root / "results" / previous / "checkpoints"
    keep.mkdir(parents=True, exist_ok=True)
    for m in models:
        best = run / "runs" / m / "best.pt"
        if not best.exists():
            fail(best, "missing (the model was not trained in this run)")
        target = keep / f"{m}_{previous}.pt"
        if target.exists():
            fail(target, "exists already (published before?)")
        shutil.move(root / "checkpoints" / f"{m}.pt", target)
        shutil.copyfile(best, root / "checkpoints" / f"{m}.pt")
    size = sum(f.stat().st_size for f in (root / "checkpoints").glob("*.pt"))
    print(f"checkpoints/: {len(models)} files replaced, {size / 2**20:.1f} MiB of .pt in all")


def checkpoint_table(root: Path, run: Path, models: list[str]) -> str:
    """The markdown table of the run's models (needs the package: ``.venv/bin/python``)."""
    from nue.evaluate.diagnose import record_diagnostics
    from nue.evaluate.metrics import summarize
    from nue.evaluate.report import method_label, paired_differences
    from nue.sim.record import EpisodeRecord
    from nue.policy.checkpoint import load_policy

    keys = episode_keys(root / "episodes" / "val")
    recs = [EpisodeRecord.from_dict(r) for r in read_jsonl(run / "records" / "val252.jsonl")
            if (r["scene"], str(r["episode_id"])) in keys]
    diags = record_diagnostics(recs)
    diffs = {d.method: d for d in paired_differences(recs, metrics=("sr",))}
    lines = ["| file | model | parameters | size | samples (selected step / last) | closed-loop selection SR (21 "
             "training-house episodes) | SR on the 84 val episodes | SPL | collisions / episode | P(forward \\| blocked) "
             "| NUE − it (paired 95%) |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for m in models:
        best = run / "runs" / m / "best.pt"
        policy, header = load_policy(best)
        params = sum(p.numel() for p in policy.parameters())
        cfg = header.train_config
        per_step = cfg["batch_size"] * (8 if m == "nav_a3c" else 1)
        sel = json.loads((run / "runs" / m / "selection.json").read_text())
        chosen = next(c for c in sel["candidates"] if c["name"] == sel["selected"])
        mine = [r for r in recs if r.method == m]
        sr, spl = summarize(mine).sr, summarize(mine).spl
        d = diags[m]
        diff = "–" if m == "nue" else (lambda x: f"{-100 * x.mean:+.1f} [{-100 * x.hi:+.1f}, {-100 * x.lo:+.1f}]")(diffs[m])
        lines.append(f"| `{m}.pt` | {method_label(m)} | {params:,} | {best.stat().st_size / 1e6:.1f} MB | "
                     f"{chosen['step'] * per_step / 1000:.0f}k ({chosen['step']:,} / {cfg['steps']:,}) | "
                     f"{round(chosen['sr'] * chosen['n'])} / {chosen['n']} | {100 * sr:.1f}% | {spl:.3f} | "
                     f"{d.collisions_per_episode:.2f} | {100 * d.p_forward_after_blocked:.1f}% | {diff} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", type=Path, default=None, help="the run's folder (default ROOT/results/reproduce/run)")
    ap.add_argument("--previous", required=True, help="name of the recipe being replaced, e.g. v5")
    ap.add_argument("--root", type=Path, default=ROOT, help="the repository (or a copy of it)")
    ap.add_argument("--partial", action="store_true", help="do not require the run's report stage")
    ap.add_argument("--table", action="store_true", help="only print the table for checkpoints/README.md")
    a = ap.parse_args()
    if a.run is None:
        a.run = a.root / "results" / "reproduce" / "run"
    recipe_file = a.run / "recipe.json"
    if not recipe_file.exists():
        fail(recipe_file, "missing: not a reproduce run")
    models = list(json.loads(recipe_file.read_text())["recipe"]["models"])
    if a.table:
        print(checkpoint_table(a.root, a.run, models))
        return
    if not a.partial and not (a.run / "stages" / "report.json").exists():
        fail(a.run / "stages", "the run has not finished (no report.json); --partial previews it")
    publish_checkpoints(a.root, a.run, models, a.previous)
    publish_records(a.root, a.run, set(models), a.previous)
    # the 252-episode set leads (the targets are judged on it, as the run's own RESULTS.md does); the 84-episode
    # set, which alone holds the v1-v4 rows, follows with its earlier-recipes table
    print("next: update RESULTS.meta.json, then\n  nue report results/records_val252.jsonl --name val252 --set val=results/records.jsonl "
          "--set val_plain=results/records_val_plain.jsonl --out results/report --results-md RESULTS.md")


if __name__ == "__main__":
    main()
