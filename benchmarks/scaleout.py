"""Scale-out benchmark: collection and evaluation throughput with 1 and 2 local worker processes and with a
local Ray cluster, as steps/s and efficiency per worker.

Writes ``benchmarks/results/scaleout.json``. The same jobs run under every backend: ``nue eval``'s
(:func:`nue.evaluate.runner.run_eval`) on the first ``--eval-episodes`` episodes of validation houses with
``checkpoints/nue.pt`` (the memory online, coverage tracked), each cut at ``--eval-steps`` steps, and ``nue
collect``'s (:func:`nue.train.collect.collect`) with the geodesic expert on ``--collect-houses`` training
houses (``--collect-per-bin`` episodes per difficulty bin). Each worker runs one torch thread and llvmpipe on one thread.

Per run: wall-clock of the call (process start-up, loading and the jobs; a Ray cluster's start is timed
apart, before the call), environment steps done, steps/s, and efficiency per worker =
(steps/s with N workers) / (N x steps/s with 1 worker). Output folders are temporary and deleted.

    python benchmarks/scaleout.py [--eval-episodes 4] [--eval-steps 100] [--collect-houses 2] [--no-ray]
"""

from __future__ import annotations

import os

os.environ.setdefault("LP_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402

from nue.evaluate.runner import EvalConfig, run_eval  # noqa: E402
from nue.scene.generator import ensure_house  # noqa: E402
from nue.train.collect import CollectConfig, collect  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
SCENES = ROOT / "data" / "scenes"


def eval_steps(records: Path) -> int:
    return sum(json.loads(line)["steps"] for line in records.read_text().splitlines() if line.strip())


def time_eval(tmp: Path, episodes_dir: Path, args, workers: int, ray_address: str | None) -> dict:
    out = tmp / f"eval_{workers}_{bool(ray_address)}.jsonl"
    cfg = EvalConfig(episodes_dir=str(episodes_dir), scenes_root=str(SCENES), max_episodes=args.eval_episodes,
                     max_steps=args.eval_steps)
    t = time.perf_counter()
    run_eval([f"nue={ROOT / 'checkpoints' / 'nue.pt'}"], out, cfg, workers=workers, ray_address=ray_address,
             progress=False)
    wall = time.perf_counter() - t
    steps = eval_steps(out)
    return {"wall_s": wall, "steps": steps, "episodes": len(out.read_text().splitlines()), "steps_per_s": steps / wall}


def time_collect(tmp: Path, args, workers: int, ray_address: str | None) -> dict:
    out = tmp / f"collect_{workers}_{bool(ray_address)}"
    cfg = CollectConfig(houses=tuple(range(args.collect_houses)), episodes_per_bin=args.collect_per_bin, heldout_per_bin=0)
    t = time.perf_counter()
    summary = collect(out, cfg, SCENES, workers=workers, ray_address=ray_address, progress=False)
    wall = time.perf_counter() - t
    steps = summary.steps
    return {"wall_s": wall, "steps": steps, "episodes": summary.episodes, "steps_per_s": steps / wall}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--eval-episodes", type=int, default=4, help="episodes per validation house (2 houses)")
    ap.add_argument("--eval-steps", type=int, default=100, help="step limit per evaluation episode")
    ap.add_argument("--collect-houses", type=int, default=2, help="training houses collected")
    ap.add_argument("--collect-per-bin", type=int, default=3, help="episodes per difficulty bin and house collected")
    ap.add_argument("--no-ray", action="store_true", help="skip the local Ray cluster")
    args = ap.parse_args()
    load_before = os.getloadavg()
    tmp = Path(tempfile.mkdtemp(prefix="nue_scaleout_"))
    episodes_dir = tmp / "episodes"
    episodes_dir.mkdir()
    for i in range(2):  # two houses, so two workers get the same share of each
        ensure_house("val", i, SCENES)
        shutil.copyfile(ROOT / "episodes" / "val" / f"val_{i:02d}.json", episodes_dir / f"val_{i:02d}.json")
    for i in range(args.collect_houses):
        ensure_house("train", i, SCENES)
    backends: list[tuple[str, int, str | None]] = [("local", 1, None), ("local", 2, None)]
    ray_start_s = None
    if not args.no_ray:
        import ray

        t = time.perf_counter()
        ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False,
                 runtime_env={"env_vars": {"OMP_NUM_THREADS": "1", "LP_NUM_THREADS": "1"}})
        ray_start_s = time.perf_counter() - t
        backends.append(("ray", 2, "auto"))
    results: dict[str, dict] = {"eval": {}, "collect": {}}
    try:
        for kind, fn in (("eval", lambda w, a: time_eval(tmp, episodes_dir, args, w, a)),
                         ("collect", lambda w, a: time_collect(tmp, args, w, a))):
            for backend, workers, address in backends:
                name = f"{backend}_{workers}"
                results[kind][name] = fn(workers, address)
                print(f"{kind:8s} {name:8s} {results[kind][name]['steps']:5d} steps "
                      f"{results[kind][name]['wall_s']:6.1f} s  {results[kind][name]['steps_per_s']:6.1f} steps/s",
                      flush=True)
            base = results[kind]["local_1"]["steps_per_s"]
            for name, r in results[kind].items():
                n = int(name.split("_")[1])
                r["workers"] = n
                r["efficiency_per_worker"] = r["steps_per_s"] / (n * base)
    finally:
        if ray_start_s is not None:
            import ray

            ray.shutdown()
        shutil.rmtree(tmp, ignore_errors=True)
    path = write_result("scaleout", {
        "eval_jobs": f"checkpoints/nue.pt, first {args.eval_episodes} episodes of val_00 and val_01, "
                     f"cut at {args.eval_steps} steps",
        "collect_jobs": f"geodesic expert, {args.collect_houses} training house(s) x 3 bins x {args.collect_per_bin} episode(s)",
        "ray_start_s": ray_start_s, "loadavg_before": load_before, "loadavg_after": os.getloadavg(), **results})
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
