"""Demonstration storage: bytes per step, quantisation error and held-out accuracy of float16 vs compact episodes.

Reads the held-out part of a float16 (version 1) collection, re-encodes every episode with the compact
:class:`~nue.train.compact.StepStorage` into a temporary folder (the collection itself is only read), and
reports: bytes per step of both; the absolute error of I_cog / RGB / depth after quantisation (against the
float16 values); held-out action accuracy of a checkpoint through ``nue.policy.accuracy.held_out_accuracy`` on both, and
the fraction of steps where its argmax action agrees; and the time to gather a training batch of each.

    python benchmarks/storage.py --data data/demos_explore --checkpoint results/v3/checkpoints/nue_v3.pt

Without ``--data`` (``make bench``) a small synthetic float16 collection stands in and the result goes to
``results/storage_synthetic.json``: bytes, error and batch time only (random maps say little about real
errors, so no accuracy).
"""

from __future__ import annotations

import argparse
import copy
import dataclasses
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from scipy.stats import binomtest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import write_result  # noqa: E402

from nue.policy.accuracy import held_out_accuracy  # noqa: E402
from nue.policy.checkpoint import load_policy  # noqa: E402
from nue.policy.config import get_model_config  # noqa: E402
from nue.train.compact import QuantizedArray, StepStorage  # noqa: E402
from nue.train.dataset import DemoSet  # noqa: E402
from nue.train.episode_file import read_header, write_episode_file  # noqa: E402
from nue.train.manifest import write_manifest  # noqa: E402

COMPACT = ("rgbd", "i_u", "i_cog")


class ArgmaxRecorder:
    """Stands in for a policy in ``held_out_accuracy``: forwards everything, keeps each ``forward_sequence``'s argmax."""

    def __init__(self, model):
        self.model, self.actions = model, []

    def forward_sequence(self, *args, **kwargs):
        out = self.model.forward_sequence(*args, **kwargs)
        self.actions.append(out.logits.argmax(-1).reshape(-1).cpu().numpy())
        return out

    def __getattr__(self, name):
        return getattr(self.model, name)


def compact_copy(data: DemoSet, out: Path, storage: StepStorage) -> tuple[DemoSet, dict]:
    """Every episode of ``data`` re-encoded with ``storage`` into ``out`` (same manifest); the new DemoSet and the
    absolute error per array against the stored float16 values (max, mean, and the mean |x| for scale)."""
    out.mkdir(parents=True)
    write_manifest(out, data.manifest)
    err = {k: [0.0, 0.0, 0, 0.0] for k in ("i_cog", "rgb", "depth", "i_u")}  # max, sum, count, sum of |x|
    for i, (arrays, meta) in enumerate(zip(data.episodes, data.metas)):
        new = dict(arrays)
        for k in COMPACT:
            x = np.asarray(arrays[k], dtype=np.float32)
            new[k] = storage.encode(k, x)
            y = np.asarray(new[k], dtype=np.float32)
            parts = {"rgb": (slice(None), slice(0, 3)), "depth": (slice(None), slice(3, 4))} if k == "rgbd" else {k: ()}
            for name, sl in parts.items():
                d = np.abs(y[sl] - x[sl])
                e = err[name]
                e[0], e[1], e[2] = max(e[0], float(d.max())), e[1] + float(d.sum(dtype=np.float64)), e[2] + d.size
                e[3] += float(np.abs(x[sl]).sum(dtype=np.float64))
        write_episode_file(out / data.part / "all" / f"{i:05d}.nue", new, meta)  # the same episode order
    errors = {k: {"max": e[0], "mean": e[1] / max(e[2], 1), "mean_abs_value": e[3] / max(e[2], 1)}
              for k, e in err.items()}
    return DemoSet(out, data.part, verify=True), errors


def bytes_per_step(data: DemoSet) -> dict:
    """File bytes per step of ``data``'s episodes, and per array (its first episode; per-episode arrays / T)."""
    total = sum(f.stat().st_size for f in data.files)
    arrays, t = data.episodes[0], int(data.lengths[0])
    per_array = {k: (a.nbytes if isinstance(a, QuantizedArray) else np.asarray(a).nbytes) / t
                 for k, a in arrays.items()}
    return {"bytes_per_step": total / len(data), "KiB_per_step": total / len(data) / 1024, "episodes": data.n_episodes,
            "steps": len(data), "version": read_header(data.files[0])[0]["version"],
            "first_episode_bytes_per_step_by_array": per_array}


def in_memory(data: DemoSet, episodes: int) -> DemoSet:
    """A copy of ``data`` holding its first ``episodes`` episodes in RAM (times decoding, not the disk)."""
    def load(a):
        if isinstance(a, QuantizedArray):
            return QuantizedArray(np.array(a.codes), np.array(a.lo), np.array(a.scale), a.bits, a.width)
        return np.array(a)

    view = copy.copy(data)
    view.episodes = [{k: load(a) for k, a in arrays.items()} for arrays in data.episodes[:episodes]]
    view.lengths = data.lengths[:episodes]
    return view


def batch_ms(data: DemoSet, cfg, batch: int = 64, repeats: int = 10) -> float:
    """Median ms of ``DemoSet.batch`` for ``batch`` random steps (the same draws for every data set)."""
    rng = np.random.default_rng(0)
    times = []
    for _ in range(repeats + 1):
        e = rng.integers(0, data.n_episodes, batch)
        s = (rng.random(batch) * data.lengths[e]).astype(np.int64)
        t = time.perf_counter()
        data.batch(e, s, cfg)
        times.append(time.perf_counter() - t)
    return float(np.median(times[1:]) * 1000)


def mcnemar_p(b: int, c: int) -> float:
    """Exact two-sided McNemar p-value of ``b`` vs ``c`` discordant steps (binomial test of b against p = 1/2)."""
    return 1.0 if b + c == 0 else float(binomtest(b, b + c, 0.5).pvalue)


def main(argv=None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", type=Path, default=None, help="A float16 collection (its heldout/ part is read).")
    ap.add_argument("--checkpoint", type=Path, default=None, help="Checkpoint for the held-out accuracy.")
    ap.add_argument("--max-episodes", type=int, default=200, help="Held-out episodes to use.")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    storage = StepStorage()
    with tempfile.TemporaryDirectory(prefix="nue_storage_") as tmp:
        tmp = Path(tmp)
        if args.data is None:
            from train import synthetic_collection  # benchmarks/train.py: random float16 episodes

            synthetic_collection(tmp / "f16", episodes=4, steps=30)
            old = DemoSet(tmp / "f16", "train", verify=True)
        else:
            old = DemoSet(args.data, "heldout", verify=False, max_episodes=args.max_episodes)
        t0 = time.perf_counter()
        new, errors = compact_copy(old, tmp / "compact", storage)
        encode_s = time.perf_counter() - t0
        cfg = get_model_config("nue")
        result = {"storage": dataclasses.asdict(storage), "data": str(args.data or "synthetic"),
                  "float16": bytes_per_step(old), "compact": bytes_per_step(new), "errors": errors,
                  "encode_s_per_step": encode_s / len(old),
                  "batch64_ms_in_ram": {"float16": batch_ms(in_memory(old, 4), cfg),
                                        "compact": batch_ms(in_memory(new, 4), cfg)}}
        if args.checkpoint is not None:
            model, _ = load_policy(args.checkpoint)
            old.check_layout(model.config)
            acc = {}
            for name, data in (("float16", old), ("compact", new)):
                rec = ArgmaxRecorder(model)
                t = time.perf_counter()
                acc[name] = held_out_accuracy(rec, data, model.config, "cpu", max_episodes=args.max_episodes)
                acc[name]["seconds"] = time.perf_counter() - t
                acc[name]["pred"] = np.concatenate(rec.actions)
            n = min(old.n_episodes, args.max_episodes)
            truth = np.concatenate([np.asarray(a["action"], np.int64) for a in old.episodes[:n]])
            pred = {k: acc[k].pop("pred") for k in acc}
            right = {k: p == truth for k, p in pred.items()}
            only_f16 = int((right["float16"] & ~right["compact"]).sum())
            only_compact = int((right["compact"] & ~right["float16"]).sum())
            result["heldout"] = {"checkpoint": str(args.checkpoint), "episodes": n, "steps": len(truth), **acc,
                                 "argmax_agreement": float((pred["float16"] == pred["compact"]).mean()),
                                 "right_only_float16": only_f16, "right_only_compact": only_compact,
                                 "mcnemar_p": mcnemar_p(only_f16, only_compact)}
    path = write_result("storage" if args.data is not None else "storage_synthetic", result)
    print(json.dumps(result, indent=1))
    print(f"wrote {path}")
    return result


if __name__ == "__main__":
    main()
