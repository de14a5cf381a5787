"""Lean memory variants against ``fast`` in one run (issue 38, item 2): cost per env step and memory quality.

Writes ``benchmarks/results/lean_memory.json``. Same trajectories and quality protocol as ``benchmarks/nerf.py``
(its ``expert_trajectory`` and ``run_preset``: the geodesic expert through val_00 and val_01, 101 frames each,
every 5th frame held out; PSNR on seen pixels of held-out frames at 90 x 120; AUROC of I_u, never-seen vs seen).
Cost: one torch thread, CPU time of the process (``time.process_time``: on a shared machine, with this run
niced, wall time mostly measures waiting for a core); each variant fills its replay with ``TIMING_FRAMES`` frames, then the variants are timed
round-robin (``ROUNDS`` rounds of ``PAIRS`` (render_maps, step) pairs each, so load drifts hit them alike);
medians over all pairs, and each variant's ratio to ``fast`` of the same run.

``python benchmarks/lean_memory.py`` runs ``fast`` and the registered lean presets; ``--screen`` adds the
candidate variants (``CANDIDATES``) that were measured to choose them.
"""

from __future__ import annotations

import os

os.environ.setdefault("LP_NUM_THREADS", "1")  # llvmpipe on one core; set before the GL context exists

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import nerf as nerf_bench  # noqa: E402
from _common import RESULTS, machine, write_result  # noqa: E402

from nue.nerf import MEMORY_PRESETS, OnlineNeRF, get_memory  # noqa: E402
from nue.nerf.config import MemoryConfig  # noqa: E402
from nue.nerf.rays import SamplerConfig  # noqa: E402

FAST = get_memory("fast")
PRESETS = ("fast", "lean")
"""Registered presets measured by every run (``fast`` is the yardstick)."""
CANDIDATES: dict[str, MemoryConfig] = {
    "it1x512": FAST.replace(name="it1x512", iters_per_update=1),
    "it2x256": FAST.replace(name="it2x256", train_rays=256),
    "s4": FAST.replace(name="s4", train_samples=4, render_samples=4),
    "maps30x40": FAST.replace(name="maps30x40", map_height=30, map_width=40),
    "it1x512_s4": FAST.replace(name="it1x512_s4", iters_per_update=1, train_samples=4, render_samples=4),
    "it1x768_s4": FAST.replace(name="it1x768_s4", iters_per_update=1, train_rays=768, train_samples=4,
                               render_samples=4),
    "it2x256_s4": FAST.replace(name="it2x256_s4", train_rays=256, train_samples=4, render_samples=4),
    "every2_s4": FAST.replace(name="every2_s4", update_every=2, train_samples=4, render_samples=4),
    "s4_band02": FAST.replace(name="s4_band02", train_samples=4, render_samples=4, sampler=SamplerConfig(band=0.2)),
}
_S4M30 = {"train_samples": 4, "render_samples": 4, "map_height": 30, "map_width": 40}
CANDIDATES.update({
    "s4_m30": FAST.replace(name="s4_m30", **_S4M30),
    "it1x512_s4_m30": FAST.replace(name="it1x512_s4_m30", iters_per_update=1, **_S4M30),
    "it1x512_s4_m30_nf05": FAST.replace(name="it1x512_s4_m30_nf05", iters_per_update=1, newest_fraction=0.5, **_S4M30),
    "it1x512_s4_m30_lr": FAST.replace(name="it1x512_s4_m30_lr", iters_per_update=1, lr=4e-3, grid_lr=0.75, **_S4M30),
    "every2_s4_m30": FAST.replace(name="every2_s4_m30", update_every=2, **_S4M30),
    "it2x192_s4_m30": FAST.replace(name="it2x192_s4_m30", train_rays=192, **_S4M30),
    "it2x128_s4_m30": FAST.replace(name="it2x128_s4_m30", train_rays=128, **_S4M30),
})
for _lr, _glr in ((4e-3, 0.5), (8e-3, 0.5), (8e-3, 0.75), (4e-3, 1.0), (1.6e-2, 0.75), (2e-3, 0.75), (2e-3, 1.0)):
    _n = f"it1x512_s4_m30_lr{_lr:g}_g{_glr:g}"
    CANDIDATES[_n] = FAST.replace(name=_n, iters_per_update=1, lr=_lr, grid_lr=_glr, **_S4M30)
"""Variants of ``fast`` screened with ``--screen`` (names say what changes: iterations x rays, samples per ray,
map size, update every k-th step, band half-width)."""
SCREEN = "--screen" in sys.argv[1:]
TIMING_FRAMES = 20
ROUNDS = int(os.environ.get("LEAN_BENCH_ROUNDS", "4"))
PAIRS = 5


def configs() -> dict[str, MemoryConfig]:
    out = {name: get_memory(name) for name in PRESETS if name in MEMORY_PRESETS}
    if SCREEN:
        only = os.environ.get("LEAN_BENCH_ONLY")  # a comma list: time these candidates only (with the presets)
        out.update({n: c for n, c in CANDIDATES.items() if not only or n in only.split(",")})
    return out


def time_variants(cfgs: dict[str, MemoryConfig], frames, camera) -> dict[str, dict]:
    """Median CPU ms of ``render_maps`` and of ``step`` per variant, timed round-robin on one thread."""
    nerfs, cursor = {}, {}
    for name, cfg in cfgs.items():
        nerfs[name] = OnlineNeRF(cfg, camera)
        nerfs[name].reset(0)
        for rgb, depth, pose in frames[:TIMING_FRAMES]:
            nerfs[name].observe(rgb, depth, pose)
        cursor[name] = TIMING_FRAMES
    times: dict[str, dict[str, list[float]]] = {n: {"render": [], "step": []} for n in cfgs}
    for r in range(ROUNDS + 1):  # round 0 warms up
        for name, nerf in nerfs.items():
            for _ in range(PAIRS):
                rgb, depth, pose = frames[cursor[name] % len(frames)]
                cursor[name] += 1
                t0 = time.process_time()
                nerf.render_maps(pose, depth)
                t1 = time.process_time()
                nerf.step(rgb, depth, pose)
                t2 = time.process_time()
                if r:
                    times[name]["render"].append(1000 * (t1 - t0))
                    times[name]["step"].append(1000 * (t2 - t1))
        print(f"timing round {r}: load {os.getloadavg()[0]:.2f}", file=sys.stderr, flush=True)
    out = {}
    for name, t in times.items():
        # update_every > 1: the mean, not the median, is the cost per step (median would hide the updates)
        step = float(np.mean(t["step"])) if cfgs[name].update_every > 1 else float(np.median(t["step"]))
        render = float(np.median(t["render"]))
        out[name] = {"render_ms": render, "update_ms": step, "ms_per_step": render + step}
    return out


def quality(cfg: MemoryConfig, trajectories) -> dict:
    """PSNR and AUROC per eval step of one variant on the trajectories (nerf.py's protocol, one thread)."""
    runs = [nerf_bench.run_preset(cfg, frames, cam) for _, frames, cam in trajectories]
    fake_timing = {1: {"ms_per_step": 1.0}}
    s = nerf_bench.summarise(cfg, runs, fake_timing, OnlineNeRF(cfg, trajectories[0][2]).flops_per_step(), {1: 1.0})
    return {"psnr": s["psnr"], "auroc": s["auroc"], "gflop_per_step": s["gflop_per_step"]}


def main() -> None:
    """``--timing``: cost of every variant (one run, ratios to ``fast``); ``--quality a,b``: PSNR / AUROC of the
    named variants (deterministic, so separate runs can share the file); neither: both for every variant.
    Results are merged into ``results/lean_memory.json`` variant by variant."""
    torch.set_num_threads(1)
    cfgs = configs()
    args = sys.argv[1:]
    do_timing = "--timing" in args or "--quality" not in args
    names = args[args.index("--quality") + 1].split(",") if "--quality" in args else list(cfgs)
    path = RESULTS / "lean_memory.json"
    previous = json.loads(path.read_text()) if path.exists() else {}
    previous.pop("machine", None)  # write_result writes this run's
    variants = previous.get("variants", {})
    trajectories = [nerf_bench.expert_trajectory(h, nerf_bench.STEPS + 1) for h in nerf_bench.HOUSES]
    extra: dict = {}
    if do_timing:
        _, frames0, camera = trajectories[0]
        load_start = os.getloadavg()
        timing = time_variants(cfgs, frames0, camera)
        base = timing["fast"]
        run_date = time.strftime("%Y-%m-%d %H:%M:%S")
        for name, tm in timing.items():
            variants.setdefault(name, {})["config"] = cfgs[name].to_dict()
            variants[name]["timing"] = {
                **tm, "ratio_update": base["update_ms"] / tm["update_ms"],
                "ratio_render": base["render_ms"] / tm["render_ms"], "ratio_total": base["ms_per_step"] / tm["ms_per_step"],
                "run": run_date, "loadavg_start": load_start, "loadavg_end": os.getloadavg(),
                "rounds": ROUNDS, "pairs_per_round": PAIRS, "timing_frames_in_replay": TIMING_FRAMES, "threads": 1, "clock": "process_time",
            }
        extra["timing_run"] = {"variants": list(cfgs), "loadavg_start": load_start, "loadavg_end": os.getloadavg(),
                               "machine": machine()}
        print(table(variants), flush=True)
        write_result("lean_memory", {**previous, **extra, "variants": variants})
    if "--quality" in args or "--timing" not in args:
        for name in names:
            t0 = time.perf_counter()
            variants.setdefault(name, {})["config"] = cfgs[name].to_dict()
            variants[name]["quality"] = quality(cfgs[name], trajectories)
            print(f"{name}: quality {time.perf_counter() - t0:.0f} s, load {os.getloadavg()[0]:.2f}", file=sys.stderr, flush=True)
            write_result("lean_memory", {**previous, **extra, "variants": variants})
    print(table(variants), flush=True)
    previous = json.loads(path.read_text())
    previous["protocol"] = {"houses": [n for n, _, _ in trajectories], "steps": nerf_bench.STEPS,
                            "eval_steps": list(nerf_bench.EVAL_STEPS), "quality_threads": 1}
    path.write_text(json.dumps(previous, indent=2) + "\n")
    print(f"wrote {path}")


def table(variants: dict) -> str:
    steps = " / ".join(str(s) for s in nerf_bench.EVAL_STEPS)
    lines = [f"| variant | update ms | render ms | total ms | fast / variant: update, render, total | PSNR dB @ {steps} "
             f"| AUROC @ {steps} |", "|---|---:|---:|---:|---|---|---|"]
    for name, v in variants.items():
        t, q = v.get("timing"), v.get("quality")
        cost = (f"{t['update_ms']:.2f} | {t['render_ms']:.2f} | {t['ms_per_step']:.2f} | "
                f"{t['ratio_update']:.2f}x, {t['ratio_render']:.2f}x, **{t['ratio_total']:.2f}x**") if t else "– | – | – | –"
        p = " / ".join(f"{q['psnr'][str(s)]:.2f}" for s in nerf_bench.EVAL_STEPS) if q else "–"
        a = " / ".join(f"{q['auroc'][str(s)]:.3f}" for s in nerf_bench.EVAL_STEPS) if q else "–"
        lines.append(f"| `{name}` | {cost} | {p} | {a} |")
    return "\n".join(lines)


if __name__ == "__main__":
    main()
