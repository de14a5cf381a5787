"""The SLING rows against the policies they wrap: paired SR / SPL difference ``sling+X - X`` (bootstrap over the
episodes both ran), episodes gained and lost, the accepted goal estimates' error against the true goal, the wrapper's
CPU milliseconds per step by part, and the failures split by the hand-off (``nue.evaluate.handoff``).

    python scripts/sling_stats.py results/records_val252.jsonl results/sling/records_val252_sling_*.jsonl

The first file holds the wrapped policies' records (and, beside it, ``<name>.handoff.jsonl`` for records made before
the hand-off was stored); each further file one ``sling+X`` method. One JSON line per method.
"""

from __future__ import annotations

import argparse
import collections
import json
from pathlib import Path

import numpy as np

from nue.evaluate.stats import paired_bootstrap


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _spl(r: dict) -> float:
    return r["success"] * r["geodesic_start"] / max(r["path_length"], r["geodesic_start"])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("base", type=Path, help="records of the wrapped policies")
    ap.add_argument("sling", type=Path, nargs="+", help="records of sling+X methods")
    args = ap.parse_args()
    base: dict[str, dict] = collections.defaultdict(dict)
    for r in _lines(args.base):
        base[r["method"]][(r["scene"], r["episode_id"])] = r
    handoff = args.base.with_name(args.base.name.replace(".jsonl", ".handoff.jsonl"))
    outcomes = {tuple(h["key"].split("/")): h["handoff"]["outcome"] for h in _lines(handoff)} if handoff.is_file() else {}

    def outcome(method: str, r: dict) -> str:
        return (r["extra"].get("handoff") or {}).get("outcome") or outcomes.get((method, r["scene"], r["episode_id"]), "?")

    for path in args.sling:
        recs = _lines(path)
        method = recs[0]["method"]
        wrapped = method.split("+", 1)[1]
        ref = [base[wrapped][(r["scene"], r["episode_id"])] for r in recs]
        a, b = np.array([r["success"] for r in recs], float), np.array([r["success"] for r in ref], float)
        d = np.stack([a - b, [_spl(x) - _spl(y) for x, y in zip(recs, ref)]], axis=1)
        mean, lo, hi = paired_bootstrap(d)
        errors = np.array([e for r in recs for e in r["extra"]["last_mile"].get("accepted_errors", [])])
        steps = sum(r["steps"] for r in recs)
        ms: dict[str, float] = collections.defaultdict(float)
        for r in recs:
            for part, v in r["extra"]["last_mile"]["ms_per_step"].items():
                ms[part] += v * r["steps"]
        print(json.dumps({
            "method": method, "episodes": len(recs), "sr": round(100 * a.mean(), 1), "wrapped_sr": round(100 * b.mean(), 1),
            "sr_diff": [round(100 * v, 1) for v in (mean[0], lo[0], hi[0])],
            "spl_diff": [round(float(v), 3) for v in (mean[1], lo[1], hi[1])],
            "gained": int(((a == 1) & (b == 0)).sum()), "lost": int(((a == 0) & (b == 1)).sum()),
            "accepted_estimates": int(len(errors)),
            "episodes_with_an_accepted_estimate": sum(bool(r["extra"]["last_mile"].get("accepted_errors")) for r in recs),
            "accepted_within_0.5m": round(float((errors <= 0.5).mean()), 3) if len(errors) else None,
            "accepted_median_error_m": round(float(np.median(errors)), 3) if len(errors) else None,
            "wrapper_cpu_ms_per_step": {k: round(v / steps, 2) for k, v in ms.items()},
            "wrapper_cpu_ms_per_step_total": round(sum(ms.values()) / steps, 2),
            "episode_wall_ms_per_step": round(1000 * sum(r["wall_time"] for r in recs) / steps, 1),
            "failures": dict(collections.Counter(outcome(method, r) for r in recs if not r["success"])),
            "wrapped_failures": dict(collections.Counter(outcome(wrapped, r) for r in ref if not r["success"])),
        }))


if __name__ == "__main__":
    main()
