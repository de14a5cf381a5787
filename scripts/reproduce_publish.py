"""Publish a finished `nue reproduce` run as the repository's shipped rows (once per recipe):

    python scripts/reproduce_publish.py --run runs/reproduce_v12 --previous v6 --previous-checkpoints drop

1. **Checkpoints.** Every Table I row the run trained (the recipe's models under their row names) ships its seed-0
   run: ``checkpoints/<row>.pt`` becomes ``RUN/runs/<row>/best.pt``. The other seeds are not shipped; every record
   names its checkpoint's sha256 (``extra.settings.agent``). The files in ``checkpoints/`` before move to
   ``results/<previous>/checkpoints/<row>_<previous>.pt`` (``--previous-checkpoints keep``) or are deleted (``drop``,
   for the clone's size: their hashes stay in their records and their recipe rebuilds them). The shipped total must
   stay within ``--max-mb`` (default 40, issue 42); ``--not-shipped ROW`` leaves a row's file out (say so in
   ``checkpoints/README.md``). Nothing is changed when the check fails.
2. **Records.** For each evaluation set of the recipe, ``results/records_<set>.jsonl`` (made if missing) gets the
   run's ``records/<set>.jsonl``, ``<set>+swap.jsonl`` and ``<set>+sling.jsonl``; ``results/records.jsonl`` gets
   those of ``val252`` on the 84 episodes of ``episodes/val``. The rows already there: the previous recipe's rows
   are renamed ``<row>_<previous>`` (``nue+swap`` -> ``nue_v6+swap``, ``sling+fr`` -> ``sling+fr_v6``, ``nue@s1`` ->
   ``nue_v6@s1``: RESULTS.md's "Earlier recipes"); earlier recipes' rows (``*_v<N>``) stay; the experts' rows are
   replaced by the run's where it has them (the script counts, per expert, those whose outcome differs: simulator
   and experts are deterministic, so ``expert``'s should not; ``expert-explore`` steers by its seen map, which the
   depth check of 7a2b8f9 changed after v6, so some of v6's differ), else kept; any other row (a memory baseline's or SLING's experiment appended to the table) must be a copy
   of a record committed elsewhere under ``results/`` and is removed, else the script stops naming it. Every kept
   row's ``extra.key`` becomes ``<method>/<scene>/<episode_id>`` (``nue view --key`` finds a record by it). The
   hand-off file beside a records file (``records_<set>.handoff.jsonl``: the hand-off of records made before the
   evaluation measured it) follows: a kept row's line moves to its new key, the lines of replaced or removed rows
   go (the run's records carry their own hand-off), so no hand-off is recomputed.
3. **Exploration.** ``results/explore_<set>.jsonl`` likewise from ``RUN/records/explore/<set>.jsonl`` (the references
   ``expert-explore`` and ``random`` are replaced like the experts).
4. **Metadata.** ``RESULTS.meta.json``'s ``demonstrations``, ``stage wall-clock`` and ``stage machines`` come from
   the run's files (:func:`nue.reproduce.run_meta`: its collections' markers; each stage's wall-clock, each
   evaluation's summed episode time, where each stage finished); the script lists the entries left to revise by hand
   (the command, the discussion, ...).

Then regenerate the derived files and RESULTS.md with the commands the script prints. ``--root`` (default: the
repository holding this script) may be a copy (a preview); ``--partial`` skips the check that the run finished and
publishes only the sets the run has records of (the others' files are left as they are).
``--table`` only prints the shipped rows' table for ``checkpoints/README.md`` and changes nothing.
A problem is one line ``error: <path>: <problem>`` and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
"""The repository this script belongs to."""

SLING = "sling+"
SWAP = "+swap"


class Refused(Exception):
    """A check failed: (path, problem), reported as one line before anything is written."""


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def write_jsonl(path: Path, rows: list[dict]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in rows))
    tmp.replace(path)


def split_method(method: str) -> tuple[str, str, str, str]:
    """``sling+nue@s1+swap`` -> (``sling+``, ``nue``, ``@s1``, ``+swap``); absent parts are ''."""
    prefix = SLING if method.startswith(SLING) else ""
    rest = method[len(prefix):]
    swap = SWAP if rest.endswith(SWAP) else ""
    rest = rest[:len(rest) - len(swap)]
    base, at, k = rest.rpartition("@s")
    if at and k.isdigit():
        return prefix, base, f"@s{k}", swap
    return prefix, rest, "", swap


def renamed(method: str, rows: set[str], previous: str) -> str | None:
    """The earlier-recipe name of a previous recipe's row (``nue+swap`` -> ``nue_v6+swap``); None for other rows."""
    prefix, base, seed, swap = split_method(method)
    return f"{prefix}{base}_{previous}{seed}{swap}" if base in rows else None


def episode_keys(folder: Path) -> set[tuple[str, str]]:
    keys = set()
    for f in sorted(folder.glob("*.json")):
        keys |= {(f.stem, str(e["episode_id"])) for e in json.loads(f.read_text())["episodes"]}
    return keys


def identity(r: dict) -> tuple:
    return r["method"], r["scene"], str(r["episode_id"])


def outcome(r: dict) -> tuple:
    return r["success"], r["steps"], r["collisions"], round(r["path_length"], 6)


class Copies:
    """Every record committed under ``results/`` outside the files being published, by identity -> its outcomes
    (one method name may hold several runs' records: an experiment's and a later run's); read only when a row needs
    it."""

    def __init__(self, root: Path, exclude: set[Path]):
        self.root, self.exclude, self._index = root, {p.resolve() for p in exclude}, None

    def has(self, r: dict) -> bool:
        if self._index is None:
            self._index = {}
            for f in sorted((self.root / "results").rglob("*.jsonl")):
                if f.resolve() in self.exclude or f.name.endswith(".handoff.jsonl"):
                    continue
                for line in f.read_text().splitlines():
                    if '"method"' in line:
                        x = json.loads(line)
                        if {"method", "scene", "episode_id", "success"} <= set(x):
                            self._index.setdefault(identity(x), set()).add(outcome(x))
        return outcome(r) in self._index.get(identity(r), ())


def merge(path: Path, new: list[dict], prev_rows: set[str], previous: str, experts: set[str],
          copies: Copies) -> tuple[list[dict], dict[str, str], str]:
    """The rows of ``path`` (if it exists) after publishing ``new`` into it, the record key of each kept row before
    -> after, and a line saying what changed."""
    from nue.evaluate.record_keys import record_key

    old = read_jsonl(path) if path.exists() else []
    ran = {identity(r): r for r in new}
    old_methods = {r["method"] for r in old}
    kept, removed = [], 0
    differ = {m: 0 for m in sorted(experts & old_methods)}
    keys: dict[str, str] = {}
    for r in old:
        method = r["method"]
        if method in experts:
            twin = ran.get(identity(r))
            if twin is not None:
                differ[method] += outcome(twin) != outcome(r)
                continue  # the run's record of the same expert episode replaces it
        elif (name := renamed(method, prev_rows, previous)) is not None:
            method = name
        elif not _earlier(method):
            if not copies.has(r):
                raise Refused(path, f"row {method!r} ({r['scene']}/{r['episode_id']}) is neither the previous recipe's "
                                    "nor an earlier one's, and no copy of it is committed elsewhere under results/")
            removed += 1
            continue
        if method != r["method"] and method in old_methods:
            raise Refused(path, f"already has rows named {method!r} (published before?)")
        key = f"{method}/{r['scene']}/{r['episode_id']}"
        keys[record_key(r)] = key
        kept.append({**r, "method": method, "extra": {**r.get("extra", {}), "key": key}})
    rows = kept + new
    differs = ", ".join(f"{m} {n}" for m, n in differ.items()) or "none"
    return rows, keys, (f"{path}: {len(old)} -> {len(rows)} records ({len(new)} from the run; {removed} removed, "
                        f"copies elsewhere; expert records whose outcome differs from the earlier one: {differs})")


def moved_handoff(path: Path, keys: dict[str, str]) -> tuple[Path, list[dict], str] | None:
    """The hand-off file beside the records file ``path`` after publishing (each kept row's line under its new key,
    the other lines dropped) and a line saying what changed; None when there is no such file."""
    from nue.evaluate.handoff_job import handoff_path

    file = handoff_path(path)
    if not file.is_file():
        return None
    lines = read_jsonl(file)
    out = []
    for line in lines:
        key = keys.get(line["key"])
        if key is not None:
            out.append({**line, "key": key, "method": key.rsplit("/", 2)[0]})
    return file, out, f"{file}: {len(lines)} -> {len(out)} lines (kept rows' lines under their new keys)"


def _earlier(method: str) -> bool:
    from nue.evaluate.table import is_earlier_recipe

    return is_earlier_recipe(method)


def plan_records(root: Path, run: Path, recipe, previous_recipe, partial: bool = False
                 ) -> tuple[list[tuple[Path, list[dict], str]], list[str]]:
    """(file, its rows after publishing, what changed) for every records, hand-off and exploration file, and the
    sets left out: with ``partial`` a set the run has no records of yet is skipped (its file is left as it is)."""
    from nue.evaluate.runner import EXPERT_METHODS

    prev_rows = {t.name for t in previous_recipe.training_runs() if t.seed_index == 0}
    experts = set(EXPERT_METHODS)  # not trained: the run's record replaces an earlier one, else that one stays
    targets: list[tuple[Path, list[dict]]] = []
    skipped: list[str] = []
    for s in recipe.eval_sets:
        new = [r for stage in (s, f"{s}{SWAP}", f"{s}+sling") for f in [run / "records" / f"{stage}.jsonl"]
               if f.exists() for r in read_jsonl(f)]
        if not new and partial:
            skipped.append(s)
            continue
        if not new:
            raise Refused(run / "records" / f"{s}.jsonl", "missing: the run has no records of this set")
        targets.append((root / "results" / f"records_{s}.jsonl", new))
        if s == "val252":
            keys = episode_keys(root / "episodes" / "val")
            targets.append((root / "results" / "records.jsonl",
                            [r for r in new if (r["scene"], str(r["episode_id"])) in keys]))
    for s in recipe.explore_sets:
        f = run / "records" / "explore" / f"{s}.jsonl"
        if not f.exists() and partial:
            skipped.append(f"explore/{s}")
            continue
        if not f.exists():
            raise Refused(f, "missing: the run has no exploration records of this set")
        targets.append((root / "results" / f"explore_{s}.jsonl", read_jsonl(f)))
    copies = Copies(root, {t[0] for t in targets})
    out = []
    for path, new in targets:
        rows, keys, line = merge(path, new, prev_rows, previous_recipe.name, experts, copies)
        out.append((path, rows, line))
        handoff = moved_handoff(path, keys)
        if handoff is not None:
            out.append(handoff)
    return out, skipped


def plan_checkpoints(root: Path, run: Path, recipe, not_shipped: set[str], max_mb: float) -> list[str]:
    """The rows whose seed-0 checkpoint ships; Refused when one is missing or the total is over ``max_mb``."""
    rows = [t.name for t in recipe.training_runs() if t.seed_index == 0]
    unknown = not_shipped - set(rows)
    if unknown:
        raise Refused(run / "recipe.json", f"--not-shipped {', '.join(sorted(unknown))}: not a row of this recipe "
                                           f"(rows: {', '.join(rows)})")
    shipped = [r for r in rows if r not in not_shipped]
    for r in shipped:
        if not (run / "runs" / r / "best.pt").is_file():
            raise Refused(run / "runs" / r / "best.pt", "missing (the row was not trained in this run)")
    sizes = {r: (run / "runs" / r / "best.pt").stat().st_size for r in shipped}
    if sum(sizes.values()) > max_mb * 1e6:
        listed = ", ".join(f"{r} {s / 1e6:.1f}" for r, s in sorted(sizes.items(), key=lambda x: -x[1]))
        raise Refused(root / "checkpoints", f"{sum(sizes.values()) / 1e6:.1f} MB for {len(shipped)} rows is over "
                                            f"--max-mb {max_mb:g} (MB: {listed}); leave rows out with --not-shipped")
    return shipped


def publish_checkpoints(root: Path, run: Path, shipped: list[str], previous: str, keep: bool) -> str:
    folder = root / "checkpoints"
    moved_to = root / "results" / previous / "checkpoints"
    before = sorted(folder.glob("*.pt"))
    if keep:
        for f in before:
            if (moved_to / f"{f.stem}_{previous}.pt").exists():
                raise Refused(moved_to / f"{f.stem}_{previous}.pt", "exists already (published before?)")
        moved_to.mkdir(parents=True, exist_ok=True)
    for f in before:
        if keep:
            shutil.move(f, moved_to / f"{f.stem}_{previous}.pt")
        else:
            f.unlink()
    for r in shipped:
        shutil.copyfile(run / "runs" / r / "best.pt", folder / f"{r}.pt")
    size = sum(f.stat().st_size for f in folder.glob("*.pt"))
    fate = f"moved to {moved_to}" if keep else "deleted"
    return f"{folder}: {len(before)} earlier files {fate}; {len(shipped)} rows shipped, {size / 1e6:.1f} MB in all"


META_FROM_RUN = ("demonstrations", "stage wall-clock", "stage machines")
"""RESULTS.meta.json's entries the publish takes from the run's files (:func:`nue.reproduce.run_meta`); the others
describe the run in words and are revised by hand."""


def plan_meta(root: Path, run: Path, recipe) -> tuple[Path, dict, str]:
    """RESULTS.meta.json after publishing (:data:`META_FROM_RUN` from the run, the rest as it was) and a line saying
    what changed and what is left to revise by hand."""
    from nue.reproduce import RunFolders, run_meta

    path = root / "RESULTS.meta.json"
    try:
        meta = json.loads(path.read_text()) if path.exists() else {}
    except ValueError as e:
        raise Refused(path, f"not JSON ({e})") from None
    if not isinstance(meta, dict):
        raise Refused(path, "not a JSON object")
    facts = run_meta(recipe, RunFolders(run, root / "data" / "scenes", root / "episodes"))
    updated = {**meta, **{k: facts[k] for k in META_FROM_RUN}}
    by_hand = ", ".join(k for k in updated if k not in META_FROM_RUN) or "none"
    return path, updated, (f"{path}: {', '.join(META_FROM_RUN)} from the run's stage markers; revise by hand: "
                           f"{by_hand}")


def checkpoint_table(root: Path, run: Path, recipe, shipped: list[str]) -> str:
    """The markdown table of the shipped rows (needs the package: ``.venv/bin/python``)."""
    from nue.evaluate.metrics import summarize
    from nue.evaluate.report import method_label
    from nue.evaluate.table import split_seed
    from nue.policy.checkpoint import load_checkpoint, load_policy
    from nue.sim.record import EpisodeRecord

    recs = [EpisodeRecord.from_dict(r) for r in read_jsonl(run / "records" / "val252.jsonl")]
    lines = ["| file | model preset | parameters | size | samples (selected step / last) | selection | SR on val252, "
             "this seed | SR on val252, every seed (mean) | SPL, this seed |", "|---|---|---|---|---|---|---|---|---|"]
    preset = {t.name: t.model for t in recipe.training_runs()}
    for row in shipped:
        best = run / "runs" / row / "best.pt"
        policy, header = load_policy(best)
        cfg = header.train_config
        params = sum(p.numel() for p in policy.parameters())
        per_step = recipe.samples_per_step(preset[row])
        stored = load_checkpoint(best)
        step, metrics = stored["step"], stored.get("metrics") or {}
        sel_file = run / "runs" / row / "selection.json"
        if sel_file.exists():
            s = json.loads(sel_file.read_text())
            chosen = next(c for c in s["candidates"] if c["name"] == s["selected"])
            sel = f"closed-loop SR {round(chosen['sr'] * chosen['n'])} / {chosen['n']}"
        elif "distance_mae" in metrics:
            sel = f"held-out distance error {metrics['distance_mae']:.2f} m"
        else:
            sel = "the last step"
        mine = summarize([r for r in recs if r.method == row])
        seeds = [summarize([r for r in recs if r.method == m]).sr for m in sorted({r.method for r in recs})
                 if split_seed(m)[0] == row]
        lines.append(f"| `{row}.pt` | `{preset[row]}` ({method_label(row)}) | {params:,} | "
                     f"{best.stat().st_size / 1e6:.1f} MB | {step * per_step / 1000:.0f}k ({step:,} / "
                     f"{cfg['steps']:,}) | {sel} | {100 * mine.sr:.1f}% | {100 * sum(seeds) / len(seeds):.1f}% "
                     f"({len(seeds)} seed{'s' if len(seeds) > 1 else ''}) | {mine.spl:.3f} |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--run", type=Path, default=None,
                    help="the run's folder (nue reproduce --out; default ROOT/results/reproduce/run, the v6 run's)")
    ap.add_argument("--previous", required=True, help="the recipe being replaced, e.g. v6")
    ap.add_argument("--previous-checkpoints", choices=("keep", "drop"), default="keep",
                    help="move the replaced checkpoints to results/<previous>/checkpoints (keep) or delete them (drop)")
    ap.add_argument("--not-shipped", action="append", default=[], metavar="ROW", help="a row whose file is not shipped")
    ap.add_argument("--max-mb", type=float, default=40.0, help="the most checkpoints/ may hold, in MB (1e6 bytes)")
    ap.add_argument("--root", type=Path, default=ROOT, help="the repository (or a copy of it)")
    ap.add_argument("--partial", action="store_true", help="do not require the run's report stage")
    ap.add_argument("--table", action="store_true", help="only print the table for checkpoints/README.md")
    a = ap.parse_args(argv)
    sys.path.insert(0, str(ROOT))
    from nue.errors import ConfigError
    from nue.recipes import get_recipe

    a.run = a.root / "results" / "reproduce" / "run" if a.run is None else a.run
    try:
        recipe_file = a.run / "recipe.json"
        if not recipe_file.exists():
            raise Refused(recipe_file, "missing: not a reproduce run")
        stored = json.loads(recipe_file.read_text())["recipe"]
        try:
            recipe, previous = get_recipe(stored["name"]), get_recipe(a.previous)
        except ConfigError as e:
            raise Refused(recipe_file, str(e)) from None
        shipped = plan_checkpoints(a.root, a.run, recipe, set(a.not_shipped), a.max_mb)
        if a.table:
            print(checkpoint_table(a.root, a.run, recipe, shipped))
            return
        if not a.partial and not (a.run / "stages" / "report.json").exists():
            raise Refused(a.run / "stages", "the run has not finished (no report.json); --partial previews it")
        # every check before the first write
        planned, skipped = plan_records(a.root, a.run, recipe, previous, a.partial)
        meta_path, meta, meta_line = plan_meta(a.root, a.run, recipe)
        print(publish_checkpoints(a.root, a.run, shipped, previous.name, a.previous_checkpoints == "keep"))
        for path, rows, line in planned:
            write_jsonl(path, rows)
            print(line)
        tmp = meta_path.with_name(meta_path.name + ".tmp")
        tmp.write_text(json.dumps(meta, indent=1, ensure_ascii=False) + "\n")
        tmp.replace(meta_path)
        print(meta_line)
        for s in skipped:
            print(f"{s}: no records in the run yet, left as it was (--partial)")
    except Refused as e:
        path, problem = e.args
        print(f"error: {path}: {problem}", file=sys.stderr)
        sys.exit(2)
    sets = " ".join(f"--set {s}=results/records_{s}.jsonl" for s in recipe.eval_sets
                    if s != "val252" and (a.root / "results" / f"records_{s}.jsonl").exists())
    explore = " ".join(f"--explore {s}=results/explore_{s}.jsonl" for s in recipe.explore_sets
                       if (a.root / "results" / f"explore_{s}.jsonl").exists())
    from nue.sim.episode_sets import held_out_sets

    published = {s for s in recipe.eval_sets if (a.root / "results" / f"records_{s}.jsonl").exists()}
    held = " --generalisation val252" if set(held_out_sets()) & published else ""
    print("next: revise RESULTS.meta.json's other entries; then\n  nue report results/records_val252.jsonl --name val252 "
          f"--set val=results/records.jsonl {sets} {explore}{held} --out results/report --results-md RESULTS.md")


if __name__ == "__main__":
    main()
