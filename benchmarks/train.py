"""Training-throughput benchmark: samples/s of behaviour cloning at batch 64 on one CPU thread.

Writes ``benchmarks/results/train.json``. Uses a synthetic collection in the real episode-file
layout (random arrays, 20 episodes x 40 steps, page-cache hot), so it needs no collected data. Per
model it times, side by side in one run: batch assembly alone (memory-mapped gather + float16 ->
float32), forward + backward + AdamW alone on a fixed batch, and the whole training step.
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
from nue.train.bc import bc_loss, class_weights  # noqa: E402
from nue.train.collect import data_layout  # noqa: E402
from nue.train.dataset import BufferSampler, DemoSet  # noqa: E402
from nue.train.episode_file import write_episode_file  # noqa: E402

BATCH, ITERS = 64, 12


def synthetic_collection(root: Path, episodes: int = 20, steps: int = 40) -> None:
    cfg = get_model_config("nue")
    rng = np.random.default_rng(0)
    manifest = {"format": "nue-demos/1", "task": "paper", "memory": get_memory("fast").to_dict(),
                "model_layout": data_layout(cfg), "split": "train", "scenes": {}, "episodes_per_bin": 0,
                "heldout_per_bin": 0, "seed": 0}
    root.mkdir(parents=True, exist_ok=True)
    (root / "manifest.json").write_text(json.dumps(manifest))
    for e in range(episodes):
        arrays = {
            "rgbd": rng.random((steps, 4, 90, 120), dtype=np.float32).astype(np.float16),
            "i_u": rng.random((steps, 1, 45, 60), dtype=np.float32).astype(np.float16),
            "i_cog": rng.normal(size=(steps, 64, 45, 60)).astype(np.float16),
            "action": rng.integers(0, 3, steps).astype(np.int8),
            "executed": rng.integers(0, 3, steps).astype(np.int8),
            "goal_angle": rng.uniform(-3, 3, steps).astype(np.float32),
            "pose": rng.normal(size=(steps, 3)).astype(np.float32),
            "goal_map": rng.random((3, 45, 60), dtype=np.float32).astype(np.float16),
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
    torch.set_num_threads(1)
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_collection(Path(tmp) / "demos")
        data = DemoSet(Path(tmp) / "demos", "train")
        for name in ("nue", "fr"):
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

            def compute(batch=None):
                b = batch if batch is not None else fixed
                out_ = model.forward_sequence(b.inp, None, torch.ones(b.action.shape, dtype=torch.bool))
                loss = bc_loss(out_, b, w, 0.5)[0]
                opt.zero_grad()
                loss.backward()
                opt.step()

            g, c, full = rate(gather, ITERS), rate(compute, ITERS), rate(lambda: compute(gather()), ITERS)
            out[name] = {"gather_samples_per_s": g, "compute_samples_per_s": c, "train_samples_per_s": full,
                         "gather_share_of_step": full / g, "target_samples_per_s": 400}
            print(f"{name}: train {full:.0f} samples/s (gather alone {g:.0f}, fwd+bwd+AdamW alone {c:.0f})")
    write_result("train", {"batch": BATCH, "threads": 1, "models": out})


if __name__ == "__main__":
    main()
