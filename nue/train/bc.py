"""``nue train``: behaviour cloning on demonstrations — cross-entropy on the expert's actions (class
balanced) plus lambda * L1 on the goal angle when the model has the auxiliary head.

Reads top to bottom: config, distributed setup, data, model, optimiser and schedule, resume, loop (with TensorBoard
scalars under ``losses/``, ``metrics/``, ``charts/``), held-out evaluation and atomic checkpoints (``last.pt`` to
resume, ``best.pt`` by held-out action accuracy — model selection on held-out episodes of the training houses). Every
model trains through ``forward_sequence`` on (T, B) batches (T = 1 for reactive models), so the loop never branches on
the model type; one step's forward and loss are :mod:`nue.train.step`'s.
Multi-process data parallel: launch with ``torchrun``; ranks split each batch (gloo on CPU, nccl on GPU).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from nue.errors import CheckpointError, ConfigError, DataError
from nue.jobs import fail_point
from nue.output_lock import hold_output
from nue.policy import build_model
from nue.policy.accuracy import held_out_accuracy
from nue.policy.checkpoint import PolicyHeader, load_checkpoint, load_resumable, policy_meta, save_checkpoint
from nue.policy.config import get_model_config
from nue.sim.task import get_task
from nue.train.losses import bc_loss, class_weights, goal_head_loss, in_view_weight  # noqa: F401  (re-exported)
from nue.train.dataset import BufferSampler, DemoSet, SequenceSampler, data_roots, swap_maps
from nue.train.hardware import check_compile, resolve_precision
from nue.train.step import SequenceForward, forward_loss


@dataclass(frozen=True)
class TrainConfig:
    """Behaviour-cloning run."""

    data: str = "data/demos"
    """Collection folder (``nue collect --out``); several, comma-separated, are aggregated (DAgger)."""
    init_from: str = ""
    """Start from this checkpoint's weights (e.g. the previous DAgger round) instead of a fresh init."""
    out: str = "runs/nue"
    """Run folder: checkpoints and TensorBoard logs."""
    model: str = "nue"
    """Model preset (``nue``, an ablation, ``fr``, ``nav_a3c``, ``nrns``, ``vgm``). ``vgm`` first pre-trains its
    embedding network contrastively on the training frames (``nue.train.contrastive``; the preset's ``embed_steps``)."""
    steps: int = 3000
    """Optimiser steps."""
    batch_size: int = 64
    """Samples per step (summed over data-parallel ranks); sequences for recurrent models."""
    seq_len: int = 8
    """Recurrent models: steps per training sequence (truncated BPTT)."""
    lr: float = 1e-3
    """Peak AdamW learning rate."""
    weight_decay: float = 1e-4
    """AdamW weight decay."""
    warmup: int = 100
    """Linear warm-up steps, then cosine decay to ``lr * final_lr_ratio``."""
    final_lr_ratio: float = 0.05
    """Learning rate at the last step relative to the peak."""
    aux_weight: float = 0.5
    """lambda of the goal-angle L1 loss (radians) when the model has the auxiliary head."""
    goal_weight: float = 0.5
    """Weight of the exploitation head's loss (models with ``goal_head``): binary cross-entropy of goal-in-view
    plus the L1 of the log distance on the steps with the goal in view."""
    goal_balance: bool = True
    """Weigh the in-view steps of the exploitation head's cross-entropy by the training data's ratio of other steps to
    them (about 9 on the v6 demonstrations), so the rare positives drive the head; False: unweighted (the head's
    probability is then calibrated to the data's rate)."""
    exploit_weight: float = 1.0
    """Weight of the action cross-entropy on the steps with the goal in view (the exploring expert's switch; about a
    tenth of the steps) against the others' 1 (:func:`~nue.train.losses.action_loss`): above 1 the exploitation phase
    counts more. Needs a collection with ``goal_in_view`` labels; stored in the checkpoint only when not 1."""
    class_balance: float = 0.5
    """Class weights (n / n_c)^p normalised to mean 1: p = 0 none, 1 inverse frequency, 0.5 in between."""
    grad_clip: float = 5.0
    """Gradient-norm clip."""
    buffer_episodes: int = 64
    """Episodes per shuffle buffer."""
    eval_every: int = 250
    """Held-out evaluation and checkpoint interval, steps."""
    log_every: int = 25
    """TensorBoard scalar interval, steps."""
    time_budget_s: float = 0.0
    """Stop (and checkpoint) after this many seconds of training; 0 = no limit."""
    budget_clock: str = "wall"
    """What the time budget (and the schedule that follows it) counts: ``wall`` (wall-clock) or ``cpu`` (this
    process's CPU time, ``time.process_time``: a run that shares its cores with other work still gets the compute
    its budget names, so a budget means the same on a busy machine; with one torch thread, seconds on one core).
    ``cpu`` is for CPU training: on CUDA the GPU's time is not counted."""
    seed: int = 0
    """Seed of the model initialisation and of batch sampling."""
    device: str = "cpu"
    """Training device."""
    precision: str = "auto"
    """``auto`` (default): ``bf16`` where the device runs bfloat16 natively (CPU with AVX512-BF16/AMX, CUDA
    with bf16), else ``fp32``; ``bf16``: forward and backward under bfloat16 autocast (weights, optimiser and
    loss stay float32), about 2x the samples/s on CPUs with AVX512-BF16 (``make bench``) and the same
    held-out accuracy step for step (fp32 vs bf16 curves: the benchmarks history in ``docs/history/``); ``fp32``: no
    autocast."""
    compile: bool = False
    """``torch.compile`` (inductor) the training forward and backward: the same arithmetic, fused and rounded
    differently; ~1.5x the samples/s on CPU (``benchmarks/train.py``) for up to ~1 min of compiling; needs a C++
    compiler (CPU) or Triton (CUDA). Evaluation and selection run eager; a resume may switch it. Works in fp32 and
    bf16."""
    map_dropout: float = 0.0
    """Probability per sample that its memory maps (I_u, I_cog) are replaced by those of another sample of
    the batch, so the policy cannot rely on the maps alone (e.g. for obstacle avoidance); 0 = off."""
    select: str = "accuracy"
    """How ``best.pt`` is chosen: ``accuracy`` (held-out action accuracy at each evaluation) or
    ``closed_loop`` (after training, the last ``select_candidates`` snapshots are run in closed loop on the
    selection episodes of the training houses and the one with the highest SR (then SPL) wins)."""
    select_episodes: str = "episodes/select"
    """Closed-loop selection: folder of episode files of training houses (never the validation houses)."""
    select_candidates: int = 3
    """Closed-loop selection: how many of the last snapshots compete."""
    select_workers: int = 1
    """Closed-loop selection: worker processes."""
    select_scenes_root: str = "data/scenes"
    """Closed-loop selection: where the training houses are (generated if missing)."""
    verify_data: bool = True
    """Check every episode file's checksums when opening the data (bad files are skipped)."""

    def __post_init__(self) -> None:
        if self.precision not in PRECISIONS:
            raise ConfigError("train config", f"precision must be one of {', '.join(PRECISIONS)}, got {self.precision!r}")
        if not 0.0 <= self.map_dropout <= 1.0:
            raise ConfigError("train config", f"map_dropout must be in [0, 1], got {self.map_dropout}")
        if self.budget_clock not in BUDGET_CLOCKS:
            raise ConfigError("train config", f"budget_clock must be one of {', '.join(BUDGET_CLOCKS)}, "
                                              f"got {self.budget_clock!r}")
        if self.select not in SELECTIONS:
            raise ConfigError("train config", f"select must be one of {', '.join(SELECTIONS)}, got {self.select!r}")

    def replace(self, **kw) -> "TrainConfig":
        return dataclasses.replace(self, **kw)


PRECISIONS = ("auto", "fp32", "bf16")
SELECTIONS = ("accuracy", "closed_loop")
BUDGET_CLOCKS = ("wall", "cpu")


def _dist():
    """(rank, world): initialise torch.distributed when launched by torchrun."""
    world = int(os.environ.get("WORLD_SIZE", "1"))
    if world > 1 and not torch.distributed.is_initialized():
        backend = "nccl" if torch.cuda.is_available() and os.environ.get("NUE_DDP_BACKEND") != "gloo" else "gloo"
        torch.distributed.init_process_group(backend)
    return (torch.distributed.get_rank() if world > 1 else 0), world


def lr_factor(step: int, cfg: TrainConfig, elapsed_s: float = 0.0) -> float:
    """Warm-up then cosine: the learning-rate multiplier at ``step``.

    With a time budget, the cosine follows whichever is further along, steps or time, so a run
    stopped by its budget still ends at the low learning rate (not deterministic across machines).
    """
    if step < cfg.warmup:
        return (step + 1) / cfg.warmup
    p = min(1.0, (step - cfg.warmup) / max(1, cfg.steps - cfg.warmup))
    if cfg.time_budget_s > 0:
        p = max(p, min(1.0, elapsed_s / cfg.time_budget_s))
    return cfg.final_lr_ratio + (1 - cfg.final_lr_ratio) * 0.5 * (1 + math.cos(math.pi * p))


@dataclass
class TrainResult:
    """Where a run left its checkpoints and how far it got."""

    best: Path
    last: Path
    step: int
    """Optimiser steps done in total (including before a resume)."""
    steps_this_call: int
    elapsed_s: float


Selector = Callable[[Path, TrainConfig, bool], object]
"""Closed-loop selection of a finished run (``TrainConfig.select == "closed_loop"``), called by :func:`train` with
(run folder, the run's config, progress) on rank 0 while the run folder is held: it runs the run's last snapshots
on episodes and copies the winner to ``best.pt``. Running episodes belongs to evaluation, which training does not
import; the selector to pass is :func:`nue.selection.select_run`."""

FAIL_AT_ENV = "NUE_FAIL_AT_STEP"
"""Tests: raise InjectedFailure right after the checkpoint at this step (as if the job were killed)."""


def train(cfg: TrainConfig, resume: bool = False, progress: bool = True, select: Selector | None = None) -> TrainResult:
    """Run (or resume from ``out/last.pt``) behaviour cloning; rank 0 holds the run folder (one writer per output).
    With ``cfg.select == "closed_loop"``, ``select`` (:data:`Selector`) picks ``best.pt`` among the snapshots at the
    end; :class:`ConfigError` if it is not given. A model of kind ``nrns`` trains by :mod:`nue.train.nrns_train`."""
    if get_model_config(cfg.model).kind == "nrns":  # NRNS's distance network: regression, not cloning
        from nue.train.nrns_train import train_distance

        return train_distance(cfg, resume, progress)
    if cfg.select == "closed_loop" and select is None:
        raise ConfigError("train config", "select 'closed_loop' needs the closed-loop selector "
                                          "(select=nue.selection.select_run)")
    with hold_output(cfg.out) if _dist()[0] == 0 else contextlib.nullcontext():
        return _train(cfg, resume, progress, select)


def _train(cfg: TrainConfig, resume: bool, progress: bool, select: Selector | None) -> TrainResult:
    rank, world = _dist()
    device = torch.device(cfg.device)
    out_dir = Path(cfg.out)
    if cfg.batch_size % world:
        raise DataError(None, f"batch size {cfg.batch_size} is not divisible by {world} processes")

    # -- data ------------------------------------------------------------------------------------
    data = DemoSet(cfg.data, "train", verify=cfg.verify_data)
    if data.n_episodes == 0:
        raise DataError(cfg.data, "no usable episode files in train/")
    first = data_roots(cfg.data)[0]
    heldout = DemoSet(first, "heldout", verify=cfg.verify_data) if (first / "heldout").is_dir() else None
    manifest = data.manifest
    task = get_task(manifest.task)
    model_cfg = get_model_config(cfg.model).for_task(task)
    data.check_layout(model_cfg)
    unlabelled = [f for f, e in zip(data.files, data.episodes) if "goal_in_view" not in e]
    if cfg.exploit_weight != 1.0 and unlabelled:  # every file: merged roots (DAgger rollouts) may mix collections
        raise DataError(unlabelled[0], f"exploit_weight {cfg.exploit_weight} weighs the steps with the goal in view, "
                                       "but this episode file has no 'goal_in_view' labels (collect again)")
    weights = class_weights(data.action_counts(model_cfg.num_actions), cfg.class_balance)
    goal_pos_weight = in_view_weight(data) if model_cfg.goal_head and cfg.goal_balance else 1.0

    # -- model, optimiser, schedule ----------------------------------------------------------------
    torch.manual_seed(cfg.seed)
    model = build_model(model_cfg).to(device)
    if cfg.init_from:
        init = load_checkpoint(cfg.init_from)
        if PolicyHeader.from_dict(init, cfg.init_from).model != model_cfg:
            raise CheckpointError(cfg.init_from, f"holds another model config than {model_cfg.name!r}")
        model.load_state_dict(init["model_state"])
    net = SequenceForward(model)
    if world > 1:
        net = torch.nn.parallel.DistributedDataParallel(net, device_ids=[device.index] if device.type == "cuda" else None)
    if cfg.compile:
        check_compile(device)
        net = torch.compile(net, dynamic=False)
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    clock = {"elapsed": 0.0}
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: lr_factor(s, cfg, clock["elapsed"]))
    rng = np.random.default_rng([cfg.seed, rank])
    step, best = 0, -math.inf  # the score is held-out accuracy, or -loss without held-out episodes
    elapsed = 0.0
    per_rank = cfg.batch_size // world
    if model_cfg.recurrent:
        sampler = SequenceSampler(data, per_rank, cfg.seq_len, rng, rank=0, world=1)
    else:
        sampler = BufferSampler(data, per_rank, rng, cfg.buffer_episodes, rank=0, world=1)
    # Before a resume restores torch's generator: building the memory's field (policy_meta) draws from it.
    stored_cfg = dataclasses.asdict(cfg)
    if not model_cfg.goal_head:  # only models with the exploitation head record its weight (older checkpoints' dicts)
        del stored_cfg["goal_weight"], stored_cfg["goal_balance"]
    if cfg.exploit_weight == 1.0:  # as in checkpoints made before it existed
        del stored_cfg["exploit_weight"]
    meta = policy_meta(task, manifest.memory, model_cfg, manifest.scenes, manifest.hash(),
                       {**stored_cfg, "precision_resolved": resolve_precision(cfg.precision, device)}, data.summary())
    if resume and (out_dir / "last.pt").is_file():
        # Everything the next step depends on: weights, optimiser, schedule, clock, and per rank the
        # generator, the sampler's position and torch's generator (older checkpoints: the generator only).
        ck = load_resumable(out_dir / "last.pt", model_cfg, meta)
        model.load_state_dict(ck["model_state"])
        opt.load_state_dict(ck["optimizer"])
        sched.load_state_dict(ck["scheduler"])
        step, best, elapsed = ck["step"], ck.get("best", -1.0), ck.get("elapsed_s", 0.0)
        clock["elapsed"] = elapsed
        rng.bit_generator.state = ck["rng_states"][rank]
        if "sampler_states" in ck:
            sampler.load_state_dict(ck["sampler_states"][rank])
            torch.set_rng_state(ck["torch_rng_states"][rank])

    writer = None
    if rank == 0:
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(str(out_dir / "tb"))
    if step == 0 and not cfg.init_from and model_cfg.pretrains_embedding:
        _pretrain_embedding(model, data, model_cfg, cfg.seed, device, writer, progress and rank == 0)

    def checkpoint(name: str, full: bool, metrics: dict | None = None) -> Path:
        payload = {**meta, "model_state": model.state_dict(), "step": step, "best": best, "elapsed_s": elapsed,
                   "metrics": metrics or {}}
        if full:
            mine = (rng.bit_generator.state, sampler.state_dict(), torch.get_rng_state())
            states = [mine]
            if world > 1:
                states = [None] * world
                torch.distributed.all_gather_object(states, mine)
            payload.update(optimizer=opt.state_dict(), scheduler=sched.state_dict(), rng_states=[s[0] for s in states],
                           sampler_states=[s[1] for s in states], torch_rng_states=[s[2] for s in states])
        return save_checkpoint(out_dir / name, payload) if rank == 0 else out_dir / name

    # -- loop ------------------------------------------------------------------------------------
    model.train()
    it = iter(sampler)
    bar = tqdm(total=cfg.steps, initial=step, desc=f"train {model_cfg.name}", disable=not progress or rank > 0)
    clock_s = time.process_time if cfg.budget_clock == "cpu" else time.perf_counter
    t_start = clock_s() - elapsed
    first_step = step
    samples_seen, t_window = 0, time.perf_counter()
    spent = cfg.time_budget_s > 0 and elapsed >= cfg.time_budget_s  # a resumed run whose budget is used up
    while step < cfg.steps and not spent:
        drawn = next(it)
        if model_cfg.recurrent:
            eps, steps_, reset = drawn
            batch = data.batch(eps, steps_, model_cfg, device, in_view=cfg.exploit_weight != 1.0)
            reset_t = torch.as_tensor(reset, device=device)
        else:
            eps, steps_ = drawn
            batch = data.batch(eps[None], steps_[None], model_cfg, device, in_view=cfg.exploit_weight != 1.0)
            reset_t = torch.ones(batch.action.shape, dtype=torch.bool, device=device)
        batch = swap_maps(batch, rng, cfg.map_dropout)  # a no-op (no draws) for models without maps
        loss, ce, aux = forward_loss(net, model, batch, reset_t, weights, cfg, device, goal_pos_weight)
        if not torch.isfinite(loss):
            raise DataError(out_dir, f"the training loss is {loss.item()} at step {step + 1} (precision "
                                     f"{resolve_precision(cfg.precision, device)}, compile {cfg.compile}); stopped, "
                                     f"last.pt holds the last checkpoint")
        opt.zero_grad(set_to_none=True)
        loss.backward()
        gnorm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip)
        opt.step()
        clock["elapsed"] = clock_s() - t_start
        sched.step()
        step += 1
        samples_seen += batch.action.numel() * world
        bar.update(1)
        elapsed = clock_s() - t_start
        if writer is not None and step % cfg.log_every == 0:
            writer.add_scalar("losses/total", loss.item(), step)
            writer.add_scalar("losses/action_ce", ce.item(), step)
            if aux is not None:
                writer.add_scalar("losses/goal_angle_l1", aux.item(), step)
            writer.add_scalar("charts/learning_rate", sched.get_last_lr()[0], step)
            writer.add_scalar("charts/grad_norm", float(gnorm), step)
            writer.add_scalar("charts/samples_per_s", samples_seen / max(time.perf_counter() - t_window, 1e-9), step)
            samples_seen, t_window = 0, time.perf_counter()
        out_of_time = cfg.time_budget_s > 0 and elapsed >= cfg.time_budget_s
        if step % cfg.eval_every == 0 or step == cfg.steps or out_of_time:
            metrics = held_out_accuracy(model, heldout, model_cfg, device) if heldout is not None and heldout.n_episodes else {}
            if writer is not None:
                for k, v in metrics.items():
                    writer.add_scalar(f"metrics/{k}", v, step)
            score = metrics.get("action_accuracy", -loss.item())
            if cfg.select == "closed_loop":
                checkpoint(f"snapshots/step_{step:06d}.pt", full=False, metrics=metrics)
            if score > best:
                best = score
                checkpoint("best.pt" if cfg.select == "accuracy" else "best_accuracy.pt", full=False, metrics=metrics)
            checkpoint("last.pt", full=True, metrics=metrics)
            bar.set_postfix(loss=f"{loss.item():.3f}", **{k: f"{v:.3f}" for k, v in metrics.items()})
            fail_point(FAIL_AT_ENV, step, f"the checkpoint at step {step}")
        if out_of_time:
            break
    bar.close()
    if writer is not None:
        writer.close()
    if world > 1:
        torch.distributed.barrier()
    if cfg.select == "closed_loop" and rank == 0:
        assert select is not None  # train() refuses closed_loop without a selector
        select(out_dir, cfg, progress)
    if world > 1:
        torch.distributed.barrier()
    return TrainResult(out_dir / "best.pt", out_dir / "last.pt", step, step - first_step, elapsed)


def _pretrain_embedding(model, data: DemoSet, model_cfg, seed: int, device, writer, progress: bool) -> None:
    """VGM: contrastive pre-training of the embedding network on the training frames (no labels), before imitation;
    not repeated on a resume or from ``init_from`` (the weights hold it). Loss per step under ``losses/embed_nce``."""
    from nue.train.contrastive import demo_pairs, pretrain_embedding

    c = model_cfg
    bar = tqdm(total=c.embed_steps, desc=f"embed {c.name}", disable=not progress)

    def tick(i: int, loss: float) -> None:
        bar.update(1)
        if writer is not None:
            writer.add_scalar("losses/embed_nce", loss, i)

    pretrain_embedding(model.embed, demo_pairs(data, c, c.embed_window, device), c.embed_steps, c.embed_batch,
                       c.embed_temperature, c.embed_lr, seed, tick)
    bar.close()
