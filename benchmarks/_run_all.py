"""``make bench``: run every ``benchmarks/*.py`` (not the ``_`` helpers) one after the other, each in its own
process, and write how long each took to ``results/bench_times.json`` (with the machine facts of the run),
so the 10-minute budget of ``make bench`` is measured, not guessed. Stops at the first script that fails.

    python benchmarks/_run_all.py [script.py ...]   # default: all of them, in name order
"""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from _common import write_result  # noqa: E402


def main() -> int:
    names = sys.argv[1:] or sorted(p.name for p in HERE.glob("[!_]*.py"))
    times: dict[str, float] = {}
    start = time.perf_counter()
    for name in names:
        print(f"== benchmarks/{name}", flush=True)
        t = time.perf_counter()
        rc = subprocess.call([sys.executable, str(HERE / name)])
        times[name] = round(time.perf_counter() - t, 1)
        print(f"   {name}: {times[name]:.0f} s", flush=True)
        if rc != 0:
            print(f"benchmarks/{name} failed (exit {rc})", file=sys.stderr)
            return rc
    total = round(time.perf_counter() - start, 1)
    if not sys.argv[1:]:  # a partial run does not replace the record of the whole one
        write_result("bench_times", {"seconds": times, "total_s": total})
    print(f"make bench: {total:.0f} s in all ({total / 60:.1f} min)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
