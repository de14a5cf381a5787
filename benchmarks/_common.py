"""Helpers shared by the benchmark scripts: result files with machine facts, timing, a scene cache."""

from __future__ import annotations

import json
import os
import platform
import subprocess
import time
from pathlib import Path

from nue.train.hardware import cpu_model

RESULTS = Path(__file__).parent / "results"
CACHE = Path(__file__).resolve().parent.parent / "outputs" / "bench_scenes"


def _git(*args: str) -> str:
    try:
        return subprocess.run(["git", *args], capture_output=True, text=True, cwd=Path(__file__).parent).stdout.strip()
    except OSError:
        return ""


def machine() -> dict:
    """Facts about the run: commit (``+dirty`` when the code under test has uncommitted changes), CPU model, CPU
    count, load average, Python and platform."""
    commit = _git("rev-parse", "--short", "HEAD")
    if commit and _git("status", "--porcelain", "--", "../nue", ".", ":!results"):
        commit += "+dirty"
    return {
        "commit": commit,
        "date": time.strftime("%Y-%m-%d %H:%M:%S"),
        "cpu_model": cpu_model(),
        "cpus": os.cpu_count(),
        "loadavg": os.getloadavg(),
        "python": platform.python_version(),
        "platform": platform.platform(),
        "LP_NUM_THREADS": os.environ.get("LP_NUM_THREADS"),
    }


def write_result(name: str, payload: dict) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    path.write_text(json.dumps({"machine": machine(), **payload}, indent=2) + "\n")
    return path


def median_ms(fn, repeats: int, warmup: int = 3) -> float:
    """Median wall time of ``fn()`` in milliseconds."""
    for _ in range(warmup):
        fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    times.sort()
    return 1000.0 * times[len(times) // 2]
