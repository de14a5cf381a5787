"""``nue train --model nrns``: NRNS's distance network trained on the demonstrations (regression, not cloning).

NRNS learns from passive trajectories: each frame is labelled with the geodesic distance to its episode's goal. Here
the trajectories are the ``nue collect`` demonstrations, whose ``geodesic`` array holds that distance per step (the
simulator's, on the house's navigation grid: training may use the scene, the agent never does). Collections made
before the array existed are labelled with what remains of their path (:func:`path_labels`): the length travelled
from the step's pose to the end of the episode plus the final geodesic distance the episode record stores — the
geodesic distance for a shortest-path expert up to its comfort detours, an over-estimate by every detour of an
exploring expert or of noise (a warning says so).

A training sample is a view (step ``t``), its goal photo and a point: with probability ``p_here`` the view's own
position (offset (0, 0), label ``d_t``), else a later step ``s`` of the same episode within ``horizon`` steps and
``max_offset`` metres, as offset (forward, left) in the view's robot frame with label ``d_s`` — how far the goal is
from a point the view shows, what the agent asks of its ghost nodes. Loss: smooth L1 in metres. Held-out error (mean
absolute, metres, at the views' own positions and at offsets) picks ``best.pt``. Checkpoints are those of
:mod:`nue.train.bc` (same header), so ``nue eval -c nrns=<checkpoint>`` loads the graph agent.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from tqdm import tqdm

from nue.errors import CheckpointError, ConfigError, DataError
from nue.output_lock import hold_output
from nue.policy import build_model
from nue.policy.checkpoint import PolicyHeader, load_checkpoint, load_resumable, policy_meta, save_checkpoint
from nue.policy.config import get_model_config
from nue.policy.nrns_model import DistanceNetwork
from nue.sim.task import get_task
from nue.train.bc import TrainConfig, TrainResult, lr_factor
from nue.train.dataset import DemoSet, data_roots


@dataclass(frozen=True)
class DistanceSampling:
    """Which (view, point) pairs a training batch holds."""

    p_here: float = 0.3
    """Share of samples at the view's own position."""
    horizon: int = 12
    """The other samples take a later step up to this many steps ahead (3 m of forward moves)..."""
    max_offset: float = 2.0
    """... within this distance of the view, metres (else the view's own position)."""
    heldout_views: int = 512
    """Held-out error: at most this many views (a fixed draw)."""


def path_labels(poses: np.ndarray, path_length: float, final_geodesic: float) -> np.ndarray:
    """(T,) distance to the goal from each step's pose: the path length still to travel (``path_length`` is the
    episode's whole path, the last move included) plus the final geodesic distance, metres."""
    xy = np.asarray(poses, dtype=np.float64)[:, :2]
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))])
    return np.maximum(path_length - travelled, 0.0) + final_geodesic


def episode_labels(arrays, meta: dict, path) -> np.ndarray:
    """(T,) distance labels of one episode file: its ``geodesic`` array where finite, else :func:`path_labels`."""
    record = meta.get("record") or {}
    fallback = None
    if "path_length" in record and "final_geodesic" in record:
        fallback = path_labels(np.asarray(arrays["pose"]), float(record["path_length"]), float(record["final_geodesic"]))
    if "geodesic" not in arrays:
        if fallback is None:
            raise DataError(path, "holds neither per-step geodesic distances nor an episode record to label with")
        return fallback
    geo = np.asarray(arrays["geodesic"], dtype=np.float64)
    if fallback is None or np.isfinite(geo).all():
        return geo
    return np.where(np.isfinite(geo), geo, fallback)


class DistanceData:
    """A :class:`DemoSet` with per-step distance labels, served as (view, offset, label) batches."""

    def __init__(self, demos: DemoSet, sampling: DistanceSampling = DistanceSampling()):
        self.demos, self.sampling = demos, sampling
        self.labels: list[np.ndarray] = []
        self.poses: list[np.ndarray] = []
        self.path_labelled = 0
        """Episodes without a stored ``geodesic`` array, labelled by :func:`path_labels`."""
        for arrays, meta, path in zip(demos.episodes, demos.metas, demos.files):
            poses = np.asarray(arrays["pose"], dtype=np.float64)
            self.poses.append(poses)
            self.labels.append(episode_labels(arrays, meta, path))
            self.path_labelled += "geodesic" not in arrays
        if self.path_labelled:
            warnings.warn(f"{demos.root}: {self.path_labelled} of {demos.n_episodes} episodes store no per-step geodesic "
                          "distance (collected before it was stored); labelled by the path still to travel, which "
                          "over-estimates the detours of exploring or noisy demonstrations", stacklevel=2)

    def draw(self, rng: np.random.Generator, n: int, p_here: float | None = None):
        """``n`` samples: (episodes (n,), steps (n,), offsets (n, 2) forward/left metres, labels (n,) metres)."""
        s = self.sampling
        p_here = s.p_here if p_here is None else p_here
        idx = rng.integers(len(self.demos), size=n)
        ep, t = self.demos.locate(idx)
        ahead = rng.integers(1, s.horizon + 1, size=n)
        other = rng.random(n) >= p_here
        offsets, labels = np.zeros((n, 2)), np.zeros(n)
        for i, (e, ti) in enumerate(zip(ep, t)):
            poses = self.poses[e]
            si = min(int(ti + ahead[i]), len(poses) - 1) if other[i] else int(ti)
            d = poses[si, :2] - poses[ti, :2]
            if np.linalg.norm(d) > s.max_offset:
                si, d = int(ti), np.zeros(2)
            c, sn = math.cos(poses[ti, 2]), math.sin(poses[ti, 2])
            offsets[i] = (c * d[0] + sn * d[1], -sn * d[0] + c * d[1])
            labels[i] = self.labels[e][si]
        return ep, t, offsets, labels

    def predict(self, model: DistanceNetwork, ep, t, offsets, device) -> torch.Tensor:
        """The model's distances (n,) for drawn samples."""
        inp = self.demos.batch(ep, t, model.config, device).inp
        return model.distance(inp, torch.as_tensor(offsets, dtype=torch.float32, device=device)[:, None])[:, 0]


def distance_errors(model: DistanceNetwork, data: DistanceData, device="cpu", seed: int = 0) -> dict[str, float]:
    """Mean absolute error (metres) on a fixed draw of views: at their own positions (``distance_mae``) and at
    sampled points ahead (``distance_mae_offset``); also the error of predicting the mean label (``baseline_mae``)."""
    rng = np.random.default_rng(seed)
    n = min(len(data.demos), data.sampling.heldout_views)
    out = {}
    was_training = model.training
    model.eval()
    with torch.no_grad():
        for name, p_here in (("distance_mae", 1.0), ("distance_mae_offset", 0.0)):
            ep, t, offsets, labels = data.draw(rng, n, p_here)
            pred = data.predict(model, ep, t, offsets, device).cpu().numpy()
            out[name] = float(np.abs(pred - labels).mean())
            if p_here == 1.0:
                out["baseline_mae"] = float(np.abs(labels.mean() - labels).mean())
    model.train(was_training)
    return out


def train_distance(cfg: TrainConfig, resume: bool = False, progress: bool = True) -> TrainResult:
    """Train the distance network of ``cfg.model`` (kind ``nrns``) on ``cfg.data``; checkpoints as behaviour cloning's
    (``last.pt``, ``best.pt`` by held-out ``distance_mae``, or by training loss without held-out episodes).
    One process, float32 (``precision``, ``compile`` and closed-loop selection do not apply); ``time_budget_s`` counts
    ``budget_clock`` as in behaviour cloning."""
    with hold_output(cfg.out):
        return _train(cfg, resume, progress)


def _train(cfg: TrainConfig, resume: bool, progress: bool) -> TrainResult:
    device, out_dir = torch.device(cfg.device), Path(cfg.out)
    if cfg.select != "accuracy":
        raise ConfigError("train config", "model kind 'nrns' is selected by held-out distance error (select 'accuracy')")
    demos = DemoSet(cfg.data, "train", verify=cfg.verify_data)
    if demos.n_episodes == 0:
        raise DataError(cfg.data, "no usable episode files in train/")
    first = data_roots(cfg.data)[0]
    held = DemoSet(first, "heldout", verify=cfg.verify_data) if (first / "heldout").is_dir() else None
    manifest, task = demos.manifest, get_task(demos.manifest.task)
    model_cfg = get_model_config(cfg.model).for_task(task)
    demos.check_layout(model_cfg)
    data = DistanceData(demos)
    heldout = DistanceData(held) if held is not None and held.n_episodes else None

    torch.manual_seed(cfg.seed)
    model = build_model(model_cfg).to(device)
    assert isinstance(model, DistanceNetwork)
    if cfg.init_from:
        init = load_checkpoint(cfg.init_from)
        if PolicyHeader.from_dict(init, cfg.init_from).model != model_cfg:
            raise CheckpointError(cfg.init_from, f"holds another model config than {model_cfg.name!r}")
        model.load_state_dict(init["model_state"])
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    clock = {"elapsed": 0.0}
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_factor(s, cfg, clock["elapsed"]))
    rng = np.random.default_rng([cfg.seed, 0])
    meta = policy_meta(task, manifest.memory, model_cfg, manifest.scenes, manifest.hash(),
                       {**dataclasses.asdict(cfg), "precision_resolved": "fp32"},
                       demos.summary())
    step, best, elapsed = 0, -math.inf, 0.0
    if resume and (out_dir / "last.pt").is_file():
        ck = load_resumable(out_dir / "last.pt", model_cfg, meta)
        model.load_state_dict(ck["model_state"])
        opt.load_state_dict(ck["optimizer"])
        sched.load_state_dict(ck["scheduler"])
        step, best, elapsed = ck["step"], ck.get("best", -math.inf), ck.get("elapsed_s", 0.0)
        rng.bit_generator.state = ck["rng_states"][0]
        clock["elapsed"] = elapsed

    def checkpoint(name: str, full: bool, metrics: dict) -> Path:
        payload = {**meta, "model_state": model.state_dict(), "step": step, "best": best, "elapsed_s": elapsed,
                   "metrics": metrics}
        if full:
            payload.update(optimizer=opt.state_dict(), scheduler=sched.state_dict(), rng_states=[rng.bit_generator.state])
        return save_checkpoint(out_dir / name, payload)

    model.train()
    bar = tqdm(total=cfg.steps, initial=step, desc=f"train {model_cfg.name}", disable=not progress)
    clock_s = time.process_time if cfg.budget_clock == "cpu" else time.perf_counter
    t_start = clock_s() - elapsed
    first_step = step
    while step < cfg.steps and not (cfg.time_budget_s > 0 and elapsed >= cfg.time_budget_s):
        ep, t, offsets, labels = data.draw(rng, cfg.batch_size)
        pred = data.predict(model, ep, t, offsets, device)
        loss = F.smooth_l1_loss(pred, torch.as_tensor(labels, dtype=torch.float32, device=device))
        if not torch.isfinite(loss):
            raise DataError(out_dir, f"the training loss is {loss.item()} at step {step + 1}; stopped, last.pt holds "
                                     "the last checkpoint")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        opt.step()
        elapsed = clock["elapsed"] = clock_s() - t_start
        sched.step()
        step += 1
        bar.update(1)
        out_of_time = cfg.time_budget_s > 0 and elapsed >= cfg.time_budget_s
        if step % cfg.eval_every == 0 or step == cfg.steps or out_of_time:
            metrics = {"loss": float(loss.item())}
            if heldout is not None:
                metrics.update(distance_errors(model, heldout, device))
            score = -metrics.get("distance_mae", metrics["loss"])
            if score > best:
                best = score
                checkpoint("best.pt", full=False, metrics=metrics)
            checkpoint("last.pt", full=True, metrics=metrics)
            bar.set_postfix(**{k: f"{v:.3f}" for k, v in metrics.items()})
    bar.close()
    return TrainResult(out_dir / "best.pt", out_dir / "last.pt", step, step - first_step, elapsed)
