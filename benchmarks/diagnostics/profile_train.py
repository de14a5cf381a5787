"""Where one behaviour-cloning step goes: ``torch.profiler`` over a few training steps, by operator and input shape.

A diagnostic, not part of ``make bench`` (profiling inflates small ops): it builds ``benchmarks/train.py``'s
synthetic collection, runs ``--steps`` full steps (``forward_loss`` + backward + AdamW) of one model on a fixed
batch at the given precision and thread count, and prints the operators with the most self time, ms per step
and share, grouped by input shapes (so f_cog's first convolution is told apart from f_p's).

    python benchmarks/diagnostics/profile_train.py --model nue --precision bf16 --threads 2
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "2")

import numpy as np  # noqa: E402
import torch  # noqa: E402
from torch.profiler import profile  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from train import BATCH, synthetic_collection  # noqa: E402

from nue.policy import build_model  # noqa: E402
from nue.policy.config import get_model_config  # noqa: E402
from nue.sim.task import get_task  # noqa: E402
from nue.train.bc import TrainConfig, class_weights  # noqa: E402
from nue.train.step import SequenceForward, forward_loss  # noqa: E402
from nue.train.dataset import BufferSampler, DemoSet  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--model", default="nue")
    ap.add_argument("--precision", default="bf16", choices=("fp32", "bf16"))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--steps", type=int, default=4)
    ap.add_argument("--rows", type=int, default=25)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    with tempfile.TemporaryDirectory() as tmp:
        synthetic_collection(Path(tmp) / "demos", episodes=10)
        data = DemoSet(Path(tmp) / "demos", "train")
        cfg = get_model_config(args.model).for_task(get_task("paper"))
        torch.manual_seed(0)
        model = build_model(cfg)
        net = SequenceForward(model)
        opt = torch.optim.AdamW(model.parameters(), lr=1e-3)
        weights = class_weights(np.ones(cfg.num_actions), 0.5)
        eps, steps = next(iter(BufferSampler(data, BATCH, np.random.default_rng(0))))
        batch = data.batch(eps[None], steps[None], cfg)
        reset = torch.ones(batch.action.shape, dtype=torch.bool)
        train_cfg = TrainConfig(precision=args.precision)
        cpu = torch.device("cpu")

        def step() -> None:
            loss = forward_loss(net, model, batch, reset, weights, train_cfg, cpu)[0]
            opt.zero_grad(set_to_none=True)
            loss.backward()
            opt.step()

        step(), step()  # warm-up: oneDNN primitives, allocator
        with profile(record_shapes=True) as prof:
            for _ in range(args.steps):
                step()
    rows = sorted(prof.key_averages(group_by_input_shape=True), key=lambda e: -e.self_cpu_time_total)
    total = sum(e.self_cpu_time_total for e in rows)
    print(f"{args.model}, {args.precision}, {args.threads} thread(s), batch {BATCH}: "
          f"{total / args.steps / 1e3:.1f} ms of self time per step ({BATCH * args.steps / total * 1e6:.0f} samples/s "
          "under the profiler)")
    by_op = sorted(prof.key_averages(), key=lambda e: -e.self_cpu_time_total)[:6]
    print("largest operators over all shapes: " + ", ".join(
        f"{e.key} {100 * e.self_cpu_time_total / total:.0f}%" for e in by_op))
    print("| operator | ms / step | share | calls / step | input shapes |")
    print("|---|---:|---:|---:|---|")
    for e in rows[: args.rows]:
        shapes = ", ".join(str(tuple(s)) for s in e.input_shapes if s)
        print(f"| `{e.key}` | {e.self_cpu_time_total / args.steps / 1e3:.2f} | {100 * e.self_cpu_time_total / total:.1f}% "
              f"| {e.count / args.steps:g} | {shapes[:90]} |")


if __name__ == "__main__":
    main()
