"""Benchmark the policy networks on CPU: parameters, inference ms per step (batch 1), training samples/s (batch 64).

Run as ``python benchmarks/policy.py`` (part of ``make bench``); writes
``benchmarks/results/policy.json`` and prints its markdown table.

* input preparation: ``prepare_input`` on a raw 180 x 240 frame + goal + maps (1 thread);
* inference: ``model.act`` (eval mode, sampling, Nav-A3C carrying its state), median (and min)
  over ``--runs`` steps after 10 warm-up steps, with 1 and 2 torch threads;
* training: one AdamW step on cross-entropy (+ angle L1 when the model has the AT head) over
  64 samples fed as ``forward_sequence`` of T = 8 x B = 8 (reactive models fold it into one batch
  of 64; Nav-A3C unrolls its LSTM), median over ``--train-iters`` steps after one warm-up step.

The machine may be shared: ``os.getloadavg()`` is recorded before (``loadavg_before``) and after (``loadavg``).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from _common import machine  # benchmarks/_common.py (the script's folder is on sys.path)
from nue.policy import (
    MODEL_PRESETS, ModelConfig, PolicyInput, angle_l1_loss, build_model, choose_actions, get_model_config, prepare_input,
)

OUT = Path(__file__).resolve().parent / "results" / "policy.json"


def bench_configs() -> dict[str, ModelConfig]:
    """Every action-policy preset at the defaults (maps 45 x 60, frames 90 x 120) plus NUE at the authors' sizes
    (NRNS's distance network picks no actions: its agent's step cost is not measured here)."""
    configs = {name: cfg for name, cfg in MODEL_PRESETS.items() if cfg.kind != "nrns"}
    nue = get_model_config("nue")
    configs["nue@maps90x120"] = nue.replace(map_height=90, map_width=120)
    configs["nue@maps90x120,frame180x240"] = nue.replace(
        map_height=90, map_width=120, frame_height=180, frame_width=240
    )
    return configs


def random_input(cfg: ModelConfig, lead: tuple[int, ...], gen: torch.Generator) -> PolicyInput:
    h, w = cfg.map_size
    return PolicyInput(
        rgbd=torch.rand(*lead, 4, *cfg.frame_size, generator=gen),
        goal=torch.rand(*lead, 3, *cfg.goal_size, generator=gen),
        i_u=torch.rand(*lead, 1, h, w, generator=gen) if cfg.uses_i_u else None,
        i_cog=torch.randn(*lead, cfg.cog_channels, h, w, generator=gen) if cfg.uses_i_cog else None,
    )


def inference_ms(cfg: ModelConfig, runs: int) -> tuple[float, float]:
    """(median, min) ms of one ``act`` step at batch 1; the min approximates the cost on an idle machine."""
    torch.manual_seed(0)
    model = build_model(cfg).eval()
    gen = torch.Generator().manual_seed(0)
    inp = random_input(cfg, (1,), gen)
    state = model.initial_state(1)
    times = []
    for i in range(runs + 10):
        t0 = time.perf_counter()
        with torch.no_grad():  # PolicyAgent.act's model step
            out = model(inp, state)
        choose_actions(out.logits, False, gen)
        state = out.state
        if i >= 10:
            times.append(time.perf_counter() - t0)
    return 1000.0 * statistics.median(times), 1000.0 * min(times)


def prepare_input_ms(cfg: ModelConfig, runs: int) -> float:
    """Median ms of ``prepare_input`` on one raw 180 x 240 frame, goal and maps (numpy in)."""
    rng = np.random.default_rng(0)
    rgb = rng.integers(0, 256, (180, 240, 3), dtype=np.uint8)
    depth = rng.uniform(0.0, 8.0, (180, 240)).astype(np.float32)
    goal = rng.integers(0, 256, (180, 240, 3), dtype=np.uint8)
    i_u = rng.uniform(0.0, 1.0, cfg.map_size).astype(np.float32)
    i_cog = rng.standard_normal((cfg.cog_channels, *cfg.map_size)).astype(np.float32)
    times = []
    for i in range(runs + 5):
        t0 = time.perf_counter()
        prepare_input(rgb, depth, goal, i_u, i_cog, cfg)
        if i >= 5:
            times.append(time.perf_counter() - t0)
    return 1000.0 * statistics.median(times)


def train_samples_per_s(cfg: ModelConfig, iters: int, t: int = 8, b: int = 8) -> float:
    torch.manual_seed(0)
    model = build_model(cfg).train()
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
    gen = torch.Generator().manual_seed(0)
    inp = random_input(cfg, (t, b), gen)
    labels = torch.randint(0, cfg.num_actions, (t * b,), generator=gen)
    angles = torch.rand(t, b, generator=gen) * 6.0 - 3.0
    times = []
    for i in range(iters + 1):
        t0 = time.perf_counter()
        out = model.forward_sequence(inp, model.initial_state(b))
        loss = F.cross_entropy(out.logits.reshape(t * b, -1), labels)
        if out.aux_angle is not None:
            loss = loss + angle_l1_loss(out.aux_angle, angles)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if i >= 1:
            times.append(time.perf_counter() - t0)
    return t * b / statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=50, help="timed inference steps per config and thread count")
    parser.add_argument("--train-iters", type=int, default=3, help="timed training steps per config and thread count")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args()

    load_before = os.getloadavg()
    results = {}
    for name, cfg in bench_configs().items():
        model = build_model(cfg)
        row: dict = {
            "parameters": model.num_parameters(),
            "parameters_by_module": {n: sum(p.numel() for p in m.parameters()) for n, m in model.named_children()},
            "map_size": list(cfg.map_size),
            "frame_size": list(cfg.frame_size),
            "prepare_input_ms": None,
            "inference_ms_batch1": {},
            "inference_ms_batch1_min": {},
            "train_samples_per_s_batch64": {},
        }
        torch.set_num_threads(1)
        row["prepare_input_ms"] = round(prepare_input_ms(cfg, args.runs), 3)
        for n in args.threads:
            torch.set_num_threads(n)
            med, best = inference_ms(cfg, args.runs)
            row["inference_ms_batch1"][str(n)] = round(med, 3)
            row["inference_ms_batch1_min"][str(n)] = round(best, 3)
            row["train_samples_per_s_batch64"][str(n)] = round(train_samples_per_s(cfg, args.train_iters), 1)
        results[name] = row
        print(f"{name:30s} {row['parameters']:>9,d} params  prepare ms {row['prepare_input_ms']}  "
              f"infer ms {row['inference_ms_batch1']}  "
              f"train samples/s {row['train_samples_per_s_batch64']}", flush=True)

    facts = machine()  # commit, date, cpus, loadavg (at the end), python, platform
    facts.update(loadavg_before=[round(x, 2) for x in load_before], torch=torch.__version__)
    report = {
        "machine": facts,
        "settings": {"inference_runs": args.runs, "train_iters": args.train_iters,
                     "train_batch": "T=8 x B=8 via forward_sequence", "optimizer": "AdamW lr 1e-3"},
        "configs": results,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(report, indent=2) + "\n")

    threads = [str(n) for n in args.threads]
    print("\n| config | params | prepare_input ms | "
          + " | ".join(f"infer ms ({n} thr) median (min)" for n in threads) + " | "
          + " | ".join(f"train samples/s ({n} thr)" for n in threads) + " |")
    print("|---|---:|---:|" + "---:|" * (2 * len(threads)))
    for name, row in results.items():
        print(f"| `{name}` | {row['parameters']:,} | {row['prepare_input_ms']:.2f} | "
              + " | ".join(f"{row['inference_ms_batch1'][n]:.2f} ({row['inference_ms_batch1_min'][n]:.2f})"
                           for n in threads) + " | "
              + " | ".join(f"{row['train_samples_per_s_batch64'][n]:.0f}" for n in threads) + " |")
    m = report["machine"]
    print(f"\nload average before {m['loadavg_before']}, after {[round(x, 2) for x in m['loadavg']]}; wrote {args.out}")


if __name__ == "__main__":
    main()
