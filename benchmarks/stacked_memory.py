"""Stacked-memory benchmark: ms per episode-step of the `fast` memory (``render_maps`` + ``step``) for one
:class:`~nue.nerf.online.OnlineNeRF` and for a :class:`~nue.nerf.stacked.StackedMemory` of B = 1 and B = 8 slots
(issue 38), in one run, on one torch thread.

Writes ``benchmarks/results/stacked_memory.json``. Protocol: the geodesic expert's trajectory in validation
house 0 (``nerf.py``'s, 180 x 240 RGB-D); slot b plays it from frame ``7 b`` on (so the slots see different
frames), with seed b and its first frame as start pose. Each variant resets its memories, runs ``--warmup`` steps
untimed (the replay fills), then times ``--steps`` steps; a step is one ``render_maps`` and one ``step`` call over
all slots (for OnlineNeRF: its own two calls). The ``floor_*`` variants repeat this with the preset's rays cut
to almost none (``FLOOR``), measuring the cost per call that does not grow with rays. Variants are interleaved ``--repeats`` times; per variant the median
step over all repeats, divided by B, is the cost per episode-step, in wall time and in the thread's CPU time (less
sensitive to other load on the machine), and each is also given as a ratio to the OnlineNeRF measured in the same
run.

    python benchmarks/stacked_memory.py [--steps 40] [--warmup 10] [--repeats 2] [--slots 1,8] [--no-floor]
"""

from __future__ import annotations

import os

os.environ.setdefault("LP_NUM_THREADS", "1")  # llvmpipe on one core; set before the GL context exists
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402
from nerf import expert_trajectory  # noqa: E402

from nue.nerf import OnlineNeRF, get_memory  # noqa: E402
from nue.nerf.stacked import StackedMemory  # noqa: E402

KINDS = ("render", "step", "render_cpu", "step_cpu")
OFFSET = 7  # frames between the starts of consecutive slots
FLOOR = {"train_rays": 8, "map_height": 3, "map_width": 4}
"""The preset with almost no rays (8 per iteration, 3 x 4 maps): what a call costs besides the per-ray work — the
per-op overhead that stacking can share, and the per-frame work of ``observe`` that it cannot."""


def clock() -> tuple[float, float]:
    """(wall, this thread's CPU time) in seconds."""
    return time.perf_counter(), time.thread_time()


def record(times: dict[str, list[float]], t0, t1, t2) -> None:
    for i, kind in enumerate(("", "_cpu")):
        times["render" + kind].append(t1[i] - t0[i])
        times["step" + kind].append(t2[i] - t1[i])


def run_online(memory: OnlineNeRF, frames, warmup: int, steps: int) -> dict[str, list[float]]:
    memory.reset(0, frames[0][2], 0.0)
    times: dict[str, list[float]] = {k: [] for k in KINDS}
    for t, (rgb, depth, pose) in enumerate(frames[: warmup + steps]):
        t0 = clock()
        memory.render_maps(pose, depth)
        t1 = clock()
        memory.step(rgb, depth, pose)
        t2 = clock()
        if t >= warmup:
            record(times, t0, t1, t2)
    return times


def run_stacked(memory: StackedMemory, frames, warmup: int, steps: int) -> dict[str, list[float]]:
    b = memory.slots
    slots = list(range(b))
    for i in slots:
        memory.reset_slot(i, i, frames[OFFSET * i][2], 0.0)
    times: dict[str, list[float]] = {k: [] for k in KINDS}
    zs = [0.0] * b
    for t in range(warmup + steps):
        fr = [frames[OFFSET * i + t] for i in slots]
        t0 = clock()
        memory.render_maps(slots, [f[2] for f in fr], [f[1] for f in fr], zs)
        t1 = clock()
        memory.step(slots, [f[0] for f in fr], [f[1] for f in fr], [f[2] for f in fr], zs)
        t2 = clock()
        if t >= warmup:
            record(times, t0, t1, t2)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=40, help="timed steps per variant and repeat")
    ap.add_argument("--warmup", type=int, default=10, help="untimed steps first (the replay fills)")
    ap.add_argument("--repeats", type=int, default=2, help="interleaved repeats of the variants")
    ap.add_argument("--slots", default="1,8", help="slot counts B of the stacked memory")
    ap.add_argument("--memory", default="fast", help="memory preset (field_type grid)")
    ap.add_argument("--no-floor", action="store_true", help="skip the per-call floor variants (see FLOOR)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    sizes = [int(s) for s in args.slots.split(",")]
    n_frames = OFFSET * (max(sizes) - 1) + args.warmup + args.steps
    _, frames, camera = expert_trajectory(0, n_frames)
    cfg = get_memory(args.memory)
    variants: dict[str, object] = {"online": OnlineNeRF(cfg, camera)}
    variants.update({f"stacked_b{b}": StackedMemory(cfg, b, camera) for b in sizes})
    if not args.no_floor:
        floor = cfg.replace(name=cfg.name + "_floor", **FLOOR)
        variants["floor_online"] = OnlineNeRF(floor, camera)
        variants.update({f"floor_stacked_b{b}": StackedMemory(floor, b, camera) for b in sizes})
    times: dict[str, dict[str, list[float]]] = {name: {k: [] for k in KINDS} for name in variants}
    t_start = time.perf_counter()
    for rep in range(args.repeats + 1):  # repeat 0 warms up (caches, lazy buffers) and is not kept
        for name, memory in variants.items():
            if isinstance(memory, OnlineNeRF):
                got = run_online(memory, frames, args.warmup, args.steps)
            else:
                assert isinstance(memory, StackedMemory)
                got = run_stacked(memory, frames, args.warmup, args.steps if rep else 5)
            if rep:
                for k in got:
                    times[name][k] += got[k]
    elapsed = time.perf_counter() - t_start
    result = {}
    for name, memory in variants.items():
        b = memory.slots if isinstance(memory, StackedMemory) else 1
        r: dict[str, float | int] = {"slots": b, "calls_timed": len(times[name]["render"])}
        for kind, label in (("", "ms"), ("_cpu", "cpu_ms")):
            render, step = np.asarray(times[name]["render" + kind]), np.asarray(times[name]["step" + kind])
            r[f"render_{label}_per_episode_step"] = 1000.0 * float(np.median(render)) / b
            r[f"step_{label}_per_episode_step"] = 1000.0 * float(np.median(step)) / b
            r[f"{label}_per_episode_step"] = 1000.0 * float(np.median(render + step)) / b
        r["episode_steps_per_s"] = 1000.0 / r["ms_per_episode_step"]
        result[name] = r
    for name, r in result.items():
        ref = result["floor_online" if name.startswith("floor") else "online"]["ms_per_episode_step"]
        r["speedup_over_online"] = ref / r["ms_per_episode_step"]
        ref_cpu = result["floor_online" if name.startswith("floor") else "online"]["cpu_ms_per_episode_step"]
        r["cpu_speedup_over_online"] = ref_cpu / r["cpu_ms_per_episode_step"]
    path = write_result("stacked_memory", {
        "memory": cfg.name, "floor_changes": None if args.no_floor else FLOOR,
        "torch_threads": torch.get_num_threads(), "steps": args.steps, "warmup": args.warmup,
        "repeats": args.repeats, "slot_offset_frames": OFFSET, "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(), "elapsed_s": elapsed, "variants": result,
    })
    print("| variant | B | render ms | step ms | ms per episode-step | x online | CPU ms per episode-step | x online (CPU) |")
    print("|---|---|---|---|---|---|---|---|")
    for name, r in result.items():
        print(f"| {name} | {r['slots']} | {r['render_ms_per_episode_step']:.2f} | {r['step_ms_per_episode_step']:.2f} | "
              f"{r['ms_per_episode_step']:.2f} | {r['speedup_over_online']:.2f} | {r['cpu_ms_per_episode_step']:.2f} | "
              f"{r['cpu_speedup_over_online']:.2f} |")
    print(f"load average {load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after; {elapsed:.0f} s -> {path}")


if __name__ == "__main__":
    main()
