"""Training-throughput benchmark: samples/s of behaviour cloning at batch 64 on CPU.

Writes ``benchmarks/results/train.json``. Uses a synthetic collection in the real episode-file
layout (random arrays, 20 episodes x 40 steps, page-cache hot), so it needs no collected data. The models: NUE on the
``fast`` memory's 45 x 60 maps (the shipped checkpoints'), ``nue_lean`` on the ``lean`` memory's 30 x 40 maps (issue
38), and FR. Per model it times, side by side in one run: batch assembly alone (memory-mapped gather + float16 ->
float32), forward + backward + AdamW alone on a fixed batch, and the whole training step, the
last for each precision (fp32, bf16 autocast) on 1 and 2 torch threads, eager and under ``torch.compile``
(``nue train --compile``), with bf16 / fp32 and compiled / eager ratios and the compile times.
Target (issue 5): >= 400 samples/s.
"""

from __future__ import annotations

import json
import os
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402

from nue.nerf.config import get_memory  # noqa: E402
from nue.policy import build_model  # noqa: E402
from nue.policy.config import get_model_config  # noqa: E402
from nue.sim.task import get_task  # noqa: E402
from nue.train.bc import TrainConfig, class_weights, resolve_precision  # noqa: E402
from nue.train.step import SequenceForward, forward_loss  # noqa: E402
from nue.train.manifest import data_layout  # noqa: E402
from nue.train.dataset import BufferSampler, DemoSet  # noqa: E402
from nue.train.hardware import cpu_has_native_bf16  # noqa: E402
from nue.train.episode_file import write_episode_file  # noqa: E402

BATCH, ITERS = 64, 12
TARGETS = {"nue": 600, "nue_lean": 600, "fr": 1200}
"""Issue 11's training targets, samples/s on 2 cores by the default path (issue 38: NUE's, with the maps the next
recipe adopts)."""


MEMORY = {"nue": "fast", "nue_lean": "lean", "fr": "fast"}
"""The memory preset whose maps each benchmarked model reads (``nue_lean``: the lean memory's 30 x 40 maps)."""


def synthetic_collection(root: Path, model: str = "nue", episodes: int = 20, steps: int = 40) -> None:
    cfg = get_model_config(model)
    mh, mw = cfg.map_height, cfg.map_width
    rng = np.random.default_rng(0)
    manifest = {"format": "nue-demos/1", "task": "paper", "memory": get_memory(MEMORY[model]).to_dict(),
                "model_layout": data_layout(cfg), "split": "train", "scenes": {}, "episodes_per_bin": 0,
                "heldout_per_bin": 0, "seed": 0}
    root.mkdir(parents=True, exist_ok=True)
    (root / "manifest.json").write_text(json.dumps(manifest))
    for e in range(episodes):
        arrays = {
            "rgbd": rng.random((steps, 4, 90, 120), dtype=np.float32).astype(np.float16),
            "i_u": rng.random((steps, 1, mh, mw), dtype=np.float32).astype(np.float16),
            "i_cog": rng.normal(size=(steps, 64, mh, mw)).astype(np.float16),
            "action": rng.integers(0, 3, steps).astype(np.int8),
            "executed": rng.integers(0, 3, steps).astype(np.int8),
            "goal_angle": rng.uniform(-3, 3, steps).astype(np.float32),
            "pose": rng.normal(size=(steps, 3)).astype(np.float32),
            "goal_map": rng.random((3, mh, mw), dtype=np.float32).astype(np.float16),
            "goal_frame": rng.random((3, 90, 120), dtype=np.float32).astype(np.float16),
        }
        write_episode_file(root / "train" / "s" / f"{e:03d}.nue", arrays, {"steps": steps})


def rate(fn, n: int) -> float:
    fn()
    t = time.perf_counter()
    for _ in range(n):
        fn()
    return BATCH * n / (time.perf_counter() - t)


def main() -> None:
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("nue", "nue_lean", "fr"):
            synthetic_collection(Path(tmp) / name, name)
            data = DemoSet(Path(tmp) / name, "train")
            cfg = get_model_config(name).for_task(get_task("paper"))
            torch.manual_seed(0)
            model = build_model(cfg)
            opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
            w = class_weights(np.ones(3), 0.5)
            it = iter(BufferSampler(data, BATCH, np.random.default_rng(0)))

            def gather():
                eps, st = next(it)
                return data.batch(eps[None], st[None], cfg)

            fixed = gather()

            net = SequenceForward(model)
            compiled = torch.compile(SequenceForward(model), dynamic=False)  # nue train --compile
            cpu = torch.device("cpu")

            def compute(batch=None, precision="fp32", use=None):
                b = batch if batch is not None else fixed
                reset = torch.ones(b.action.shape, dtype=torch.bool)
                loss = forward_loss(net if use is None else use, model, b, reset, w, TrainConfig(precision=precision), cpu)[0]
                opt.zero_grad()
                loss.backward()
                opt.step()

            torch.set_num_threads(1)
            g, c = rate(gather, ITERS), rate(compute, ITERS)
            res = {"gather_samples_per_s": g, "compute_samples_per_s": c, "target_samples_per_s": TARGETS[name]}
            for threads in (1, 2):
                torch.set_num_threads(threads)
                for precision in ("fp32", "bf16"):
                    res[f"train_samples_per_s_{precision}_{threads}t"] = rate(lambda: compute(gather(), precision), ITERS)
                res[f"bf16_over_fp32_{threads}t"] = res[f"train_samples_per_s_bf16_{threads}t"] / res[f"train_samples_per_s_fp32_{threads}t"]
                for precision in ("fp32", "bf16"):
                    if threads == 1:  # the first call compiles (again under bf16 autocast: another graph)
                        t0 = time.perf_counter()
                        compute(gather(), precision, compiled)
                        res["compile_s" if precision == "fp32" else "compile_s_bf16"] = time.perf_counter() - t0
                    res[f"train_samples_per_s_{precision}_compiled_{threads}t"] = rate(
                        lambda: compute(gather(), precision, compiled), ITERS)
                    res[f"compiled_over_{precision}_{threads}t"] = (res[f"train_samples_per_s_{precision}_compiled_{threads}t"]
                                                                    / res[f"train_samples_per_s_{precision}_{threads}t"])
            default = resolve_precision(TrainConfig().precision, cpu)  # what `nue train` runs here by default
            res["default_precision"] = default
            res["train_samples_per_s"] = res[f"train_samples_per_s_{default}_2t"]  # the headline: default path, 2 cores
            res["gather_share_of_step"] = res[f"train_samples_per_s_{default}_1t"] / g
            res["best_samples_per_s"] = max(v for k, v in res.items() if k.startswith("train_samples_per_s_"))
            out[name] = res
            print(f"{name}: fp32 {res['train_samples_per_s_fp32_1t']:.0f} / {res['train_samples_per_s_fp32_2t']:.0f} "
                  f"samples/s on 1 / 2 threads; compiled fp32 {res['train_samples_per_s_fp32_compiled_1t']:.0f} / "
                  f"{res['train_samples_per_s_fp32_compiled_2t']:.0f} ({res['compile_s']:.0f} s to compile); bf16 "
                  f"{res['train_samples_per_s_bf16_1t']:.0f} / "
                  f"{res['train_samples_per_s_bf16_2t']:.0f}; compiled bf16 {res['train_samples_per_s_bf16_compiled_1t']:.0f} / "
                  f"{res['train_samples_per_s_bf16_compiled_2t']:.0f} (gather alone {g:.0f}, fp32 fwd+bwd+AdamW alone {c:.0f})")
    write_result("train", {"batch": BATCH, "threads": [1, 2], "bf16_cpu": cpu_has_native_bf16(), "models": out})


if __name__ == "__main__":
    main()
