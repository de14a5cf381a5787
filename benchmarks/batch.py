"""Lock-step batch benchmark: ms per episode-step of a real ``nue eval`` (in this process, one worker) of each method
at ``--batch 1`` and ``--batch B`` (planning left out), and of the policy's part of it (``PolicyAgent.act`` / ``act_batch``).
The methods (``--method``, repeatable, ``nue eval -c``'s spelling) default to the shipped NUE (``fast`` memory), the
recurrent NUE on the ``lean`` memory (``results/gru/``), FR and the geodesic expert.

Per method the runs go B = 1, B, B = 1 again (the machine is shared: the second B = 1 run shows the drift), each on the same
validation episodes (the first ``--episodes`` of ``--houses`` val houses, cut at ``--max-steps`` steps) into a
fresh records file; the worker's caches (envs, policy, slot memories) are warmed by a run of one episode per house
at batch size B first. Episode-steps are the records' steps; the load average is read before and after each run. Memory:
:class:`nue.nerf.slots.MemoryList` (per-slot memories; only the policy forward is batched). Writes
``benchmarks/results/batch.json``.

    nice -n 15 python benchmarks/batch.py [--method nue=checkpoints/nue.pt ...] [--batch 8]
"""

from __future__ import annotations

import os

os.environ.setdefault("LP_NUM_THREADS", "1")  # llvmpipe on one core; set before the GL context exists
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import shutil  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import CACHE, write_result  # noqa: E402

from nue.evaluate import runner  # noqa: E402
from nue.evaluate.runner import EvalConfig, run_eval  # noqa: E402
from nue.policy.agent import PolicyAgent  # noqa: E402

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_METHODS = (f"nue={ROOT / 'checkpoints/nue.pt'}", f"nue_gru_lean={ROOT / 'results/gru/nue_gru_lean.pt'}",
                   f"fr={ROOT / 'checkpoints/fr.pt'}", "expert")
"""What ``make bench`` compares: NUE as shipped, the recurrent NUE on the lean memory, FR and the geodesic expert."""
POLICY_S = [0.0]


PLAN_S = [0.0]


def _timed(fn, total: list[float] = POLICY_S):
    def wrapper(*args, **kwargs):
        t = time.perf_counter()
        try:
            return fn(*args, **kwargs)
        finally:
            total[0] += time.perf_counter() - t
    return wrapper


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--method", action="append", default=None,
                    help=f"NAME=CHECKPOINT or an expert name, repeatable (default: {' '.join(DEFAULT_METHODS)}).")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--houses", type=int, default=3)
    ap.add_argument("--episodes", type=int, default=8, help="Episodes per house.")
    ap.add_argument("--max-steps", type=int, default=12)
    ap.add_argument("--scenes-root", default=str(CACHE), help="Where the val houses are (generated if missing).")
    args = ap.parse_args()
    torch.set_num_threads(1)
    PolicyAgent.act = _timed(PolicyAgent.act)  # type: ignore[method-assign]
    runner.plan_eval = _timed(runner.plan_eval, PLAN_S)
    PolicyAgent.act_batch = staticmethod(_timed(PolicyAgent.act_batch))  # type: ignore[method-assign]
    tmp = Path(tempfile.mkdtemp(prefix="nue-batch-bench-"))
    try:
        eps = tmp / "episodes"
        eps.mkdir()
        for f in sorted((ROOT / "episodes/val").glob("val_*.json"))[: args.houses]:
            shutil.copy(f, eps / f.name)
        base = EvalConfig(episodes_dir=str(eps), scenes_root=args.scenes_root, max_steps=args.max_steps)

        def run(method: str, batch: int, name: str, max_episodes: int) -> dict:
            cfg = EvalConfig(**{**base.__dict__, "batch": batch, "max_episodes": max_episodes})
            POLICY_S[0] = PLAN_S[0] = 0.0
            load0 = os.getloadavg()[0]
            t = time.perf_counter()
            out = run_eval([method], tmp / f"{name}.jsonl", cfg, progress=False)
            wall = time.perf_counter() - t - PLAN_S[0]  # the episodes only, not the planning (houses, checks)
            steps = sum(json.loads(line)["steps"] for line in out.read_text().splitlines())
            row = {"batch": batch, "episodes": len(out.read_text().splitlines()), "episode_steps": steps,
                   "wall_s": round(wall, 2), "plan_s": round(PLAN_S[0], 2), "ms_per_episode_step": round(1000 * wall / steps, 2),
                   "policy_ms_per_episode_step": round(1000 * POLICY_S[0] / steps, 2),
                   "load_before": round(load0, 2), "load_after": round(os.getloadavg()[0], 2)}
            print(method.split("=")[0], name, json.dumps(row), flush=True)
            return row

        results = {}
        for method in args.method or DEFAULT_METHODS:
            key = method.split("=")[0]
            run(method, args.batch, f"{key}_warm", 1)  # builds the worker's envs, agent and memories
            rows = [run(method, 1, f"{key}_b1", args.episodes), run(method, args.batch, f"{key}_bB", args.episodes),
                    run(method, 1, f"{key}_b1again", args.episodes)]
            b1 = (rows[0]["ms_per_episode_step"] + rows[2]["ms_per_episode_step"]) / 2
            ratio = round(b1 / rows[1]["ms_per_episode_step"], 3)
            print(f"{key}: B=1 (mean of the two runs) / B={args.batch}: {ratio}x episode-steps per second", flush=True)
            entry = {"method": method, "runs": rows, "speedup": ratio}
            if "=" in method:
                entry["forward_ms_per_row"] = forward_ms_per_row(method.split("=", 1)[1], args.batch)
                print(f"{key}: policy forward alone, ms per row: {json.dumps(entry['forward_ms_per_row'])}", flush=True)
            results[key] = entry
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    write_result("batch", {"batch": args.batch, "houses": args.houses, "episodes_per_house": args.episodes,
                           "max_steps": args.max_steps, "methods": results})


def forward_ms_per_row(checkpoint: str, batch: int, reps: int = 20) -> dict:
    """The checkpoint's model forward alone on random inputs of 1 and ``batch`` rows: median ms per row
    (interleaved, ``reps`` times each), with the load average."""
    import numpy as np

    from nue.policy.checkpoint import load_agent, load_header
    from nue.sim.task import get_task

    agent, memory = load_agent(checkpoint, get_task(load_header(checkpoint).task))
    cam, mem = get_task(load_header(checkpoint).task).camera, memory.config if memory is not None else None
    rng = np.random.default_rng(0)

    class Maps:
        i_u = rng.random((1, mem.map_height, mem.map_width), dtype=np.float32) if mem else None
        i_cog = rng.standard_normal((64, mem.map_height, mem.map_width), dtype=np.float32) if mem else None
        panorama = None

    obs = {"rgb": rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8),
           "depth": rng.random((cam.height, cam.width, 1), dtype=np.float32) * 3,
           "goal": rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8), "pose": np.zeros(3)}
    agents = [agent.twin() for _ in range(batch)]
    for a in agents:
        a.reset(None, obs, 0)
    times: dict[int, list[float]] = {1: [], batch: []}
    for _ in range(reps):
        for n in (1, batch):
            t = time.perf_counter()
            PolicyAgent.act_batch(agents[:n], [obs] * n, [Maps()] * n, rows=n)
            times[n].append((time.perf_counter() - t) * 1000 / n)
    return {f"rows_{n}": round(float(np.median(v)), 2) for n, v in times.items()} | {"load": round(os.getloadavg()[0], 2)}


if __name__ == "__main__":
    main()
