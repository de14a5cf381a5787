"""Stacked-memory benchmark: ms per episode-step of the `fast` memory (``render_maps`` + ``step``) for one
:class:`~nue.nerf.online.OnlineNeRF` and for a :class:`~nue.nerf.stacked.StackedMemory` of B = 1 and B = 8 slots
(issue 38), in one run, on one torch thread.

Writes ``benchmarks/results/stacked_memory.json``. Protocol: the geodesic expert's trajectory in validation
house 0 (``nerf.py``'s, 180 x 240 RGB-D); slot b plays it from frame ``7 b`` on (so the slots see different
frames), with seed b and its first frame as start pose. Each variant resets its memories, runs ``--warmup`` steps
untimed (the replay fills), then times ``--steps`` steps; a step is one ``render_maps`` and one ``step`` call over
all slots (for OnlineNeRF: its own two calls). Variants are interleaved ``--repeats`` times; per variant the median
step over all repeats, divided by B, is the cost per episode-step, and each is also given as a ratio to the
OnlineNeRF measured in the same run.

    python benchmarks/stacked_memory.py [--steps 40] [--warmup 10] [--repeats 2] [--slots 1,8]
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

OFFSET = 7  # frames between the starts of consecutive slots


def run_online(memory: OnlineNeRF, frames, warmup: int, steps: int) -> dict[str, list[float]]:
    memory.reset(0, frames[0][2], 0.0)
    times: dict[str, list[float]] = {"render": [], "step": []}
    for t, (rgb, depth, pose) in enumerate(frames[: warmup + steps]):
        t0 = time.perf_counter()
        memory.render_maps(pose, depth)
        t1 = time.perf_counter()
        memory.step(rgb, depth, pose)
        t2 = time.perf_counter()
        if t >= warmup:
            times["render"].append(t1 - t0)
            times["step"].append(t2 - t1)
    return times


def run_stacked(memory: StackedMemory, frames, warmup: int, steps: int) -> dict[str, list[float]]:
    b = memory.slots
    slots = list(range(b))
    for i in slots:
        memory.reset_slot(i, i, frames[OFFSET * i][2], 0.0)
    times: dict[str, list[float]] = {"render": [], "step": []}
    zs = [0.0] * b
    for t in range(warmup + steps):
        fr = [frames[OFFSET * i + t] for i in slots]
        t0 = time.perf_counter()
        memory.render_maps(slots, [f[2] for f in fr], [f[1] for f in fr], zs)
        t1 = time.perf_counter()
        memory.step(slots, [f[0] for f in fr], [f[1] for f in fr], [f[2] for f in fr], zs)
        t2 = time.perf_counter()
        if t >= warmup:
            times["render"].append(t1 - t0)
            times["step"].append(t2 - t1)
    return times


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--steps", type=int, default=40, help="timed steps per variant and repeat")
    ap.add_argument("--warmup", type=int, default=10, help="untimed steps first (the replay fills)")
    ap.add_argument("--repeats", type=int, default=2, help="interleaved repeats of the variants")
    ap.add_argument("--slots", default="1,8", help="slot counts B of the stacked memory")
    ap.add_argument("--memory", default="fast", help="memory preset (field_type grid)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    load_before = os.getloadavg()
    sizes = [int(s) for s in args.slots.split(",")]
    n_frames = OFFSET * (max(sizes) - 1) + args.warmup + args.steps
    _, frames, camera = expert_trajectory(0, n_frames)
    cfg = get_memory(args.memory)
    variants: dict[str, object] = {"online": OnlineNeRF(cfg, camera)}
    variants.update({f"stacked_b{b}": StackedMemory(cfg, b, camera) for b in sizes})
    times = {name: {"render": [], "step": []} for name in variants}
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
        render = 1000.0 * float(np.median(times[name]["render"])) / b
        step = 1000.0 * float(np.median(times[name]["step"])) / b
        total = 1000.0 * float(np.median(np.add(times[name]["render"], times[name]["step"]))) / b
        result[name] = {"slots": b, "render_ms_per_episode_step": render, "step_ms_per_episode_step": step,
                        "ms_per_episode_step": total, "episode_steps_per_s": 1000.0 / total,
                        "calls_timed": len(times[name]["render"])}
    ref = result["online"]["ms_per_episode_step"]
    for r in result.values():
        r["speedup_over_online"] = ref / r["ms_per_episode_step"]
    path = write_result("stacked_memory", {
        "memory": cfg.name, "torch_threads": torch.get_num_threads(), "steps": args.steps, "warmup": args.warmup,
        "repeats": args.repeats, "slot_offset_frames": OFFSET, "loadavg_before": load_before,
        "loadavg_after": os.getloadavg(), "elapsed_s": elapsed, "variants": result,
    })
    print("| variant | B | render ms | step ms | total ms per episode-step | episode-steps/s | x online |")
    print("|---|---|---|---|---|---|---|")
    for name, r in result.items():
        print(f"| {name} | {r['slots']} | {r['render_ms_per_episode_step']:.2f} | {r['step_ms_per_episode_step']:.2f} | "
              f"{r['ms_per_episode_step']:.2f} | {r['episode_steps_per_s']:.1f} | {r['speedup_over_online']:.2f} |")
    print(f"load average {load_before[0]:.2f} before, {os.getloadavg()[0]:.2f} after; {elapsed:.0f} s -> {path}")


if __name__ == "__main__":
    main()
