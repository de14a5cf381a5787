"""Policy checkpoints: weights plus everything needed to run and to refuse a mismatched evaluation.

A checkpoint embeds the task preset, the memory (NeRF) config and its fixed initial weights, the
model config, the demonstration manifest's hash and scene hashes, the git commit and the training
config. Saving is atomic (temporary file + rename). ``load_policy`` rebuilds the network;
``check_compatible`` refuses a task/memory preset or scene set that differs from the stored one;
``load_agent`` gives the agent and memory of the shared loop (eval, DAgger collection, the demo).
"""

from __future__ import annotations

import dataclasses
import os
import subprocess
import tempfile
from pathlib import Path

import torch

from nue.errors import CheckpointError
from nue.nerf.config import MemoryConfig
from nue.nerf.online import OnlineNeRF
from nue.policy import build_model
from nue.policy.agent import PolicyAgent
from nue.policy.config import ModelConfig
from nue.sim.task import TaskConfig

FORMAT = "nue-checkpoint/1"


def git_commit() -> str:
    """The repository's HEAD commit ('' outside a checkout)."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                             cwd=Path(__file__).resolve().parent, timeout=10)
        return out.stdout.strip() if out.returncode == 0 else ""
    except (OSError, subprocess.SubprocessError):
        return ""


def save_checkpoint(path, payload: dict) -> Path:
    """Write ``payload`` (with ``format`` added) atomically with ``torch.save``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    os.close(fd)
    try:
        torch.save({"format": FORMAT, **payload}, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


def load_checkpoint(path, map_location="cpu") -> dict:
    """A checkpoint file's dict; :class:`CheckpointError` if it is missing, a folder, unreadable, of
    another format, or holds weights (model or memory) that are not finite."""
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(path, "is a directory, not a checkpoint file")
    if not path.is_file():
        raise CheckpointError(path, "checkpoint not found")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=False)
    except Exception as exc:
        raise CheckpointError(path, f"cannot read checkpoint ({type(exc).__name__})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise CheckpointError(path, f"not a {FORMAT} checkpoint")
    for part in ("model_state", "memory_init"):
        bad = _non_finite(ckpt.get(part))
        if bad:
            raise CheckpointError(path, f"weights are not finite: {part} {bad} holds NaN or inf")
    return ckpt


def _non_finite(state, prefix: str = "") -> str:
    """Name of the first floating tensor in a (nested) state dict holding NaN or inf, '' if none."""
    if isinstance(state, torch.Tensor):
        finite = not state.is_floating_point() or bool(torch.isfinite(state).all())
        return "" if finite else (prefix or "tensor")
    items = state.items() if isinstance(state, dict) else enumerate(state) if isinstance(state, (list, tuple)) else ()
    for k, v in items:
        bad = _non_finite(v, f"{prefix}.{k}" if prefix else str(k))
        if bad:
            return bad
    return ""


def load_policy(path, device="cpu"):
    """(model in eval mode, checkpoint dict) from a checkpoint file."""
    ckpt = load_checkpoint(path)
    model = build_model(ModelConfig.from_dict(ckpt["model_config"]))
    try:
        model.load_state_dict(ckpt["model_state"])
    except RuntimeError as exc:
        raise CheckpointError(path, f"weights do not fit the stored model config ({exc})") from None
    return model.to(device).eval(), ckpt


def load_agent(checkpoint, task: TaskConfig, device: str | torch.device = "cpu", *, scenes: dict[str, str] | None = None,
               memory: bool | None = None, greedy: bool | None = None) -> tuple[PolicyAgent, OnlineNeRF | None]:
    """The policy agent of a checkpoint and its online NeRF memory (the stored config and fixed initial
    weights), both on ``device``, after :func:`check_compatible` with ``task`` and ``scenes``.

    ``memory``: None = a memory only when the model reads its maps, True = always (figures), False = never
    (the caller brings its own). ``greedy``: None = the task's rule (``task.greedy``). The agent's
    ``git_commit`` is the commit the weights were trained at.
    """
    model, ckpt = load_policy(checkpoint, device)
    check_compatible(ckpt, checkpoint, task=task, scenes=scenes)
    nerf = None
    if memory or (memory is None and model.config.uses_memory_maps):
        nerf = OnlineNeRF(MemoryConfig.from_dict(ckpt["memory"]), task.camera, init_state=ckpt["memory_init"], device=device)
    agent = PolicyAgent(model, greedy=task.greedy if greedy is None else greedy, device=device,
                        git_commit=ckpt.get("git_commit", ""))
    return agent, nerf


def check_compatible(ckpt: dict, path, task=None, memory=None, scenes: dict[str, str] | None = None) -> None:
    """Raise :class:`CheckpointError` if the task preset, memory config or a known scene's content
    differs from what the checkpoint was trained with (scenes absent from training are fine)."""
    if task is not None and ckpt["task"]["name"] != task.name:
        raise CheckpointError(path, f"trained for task preset {ckpt['task']['name']!r}, asked to run {task.name!r}")
    if memory is not None and ckpt.get("memory") is not None and ckpt["memory"] != memory.to_dict():
        diff = sorted(k for k in set(ckpt["memory"]) | set(memory.to_dict()) if ckpt["memory"].get(k) != memory.to_dict().get(k))
        raise CheckpointError(path, f"memory preset differs from the trained one in: {', '.join(diff)}")
    for name, h in (scenes or {}).items():
        trained = ckpt.get("scenes", {}).get(name)
        if trained is not None and trained != h:
            raise CheckpointError(path, f"scene {name} has content {h}, but the policy was trained on content {trained}")


def policy_meta(task, memory_cfg, model_cfg, scenes: dict[str, str], manifest_hash: str = "",
                train_config: dict | None = None, data: dict | None = None) -> dict:
    """Everything a checkpoint carries besides weights (see the module docstring)."""
    return {
        "task": dataclasses.asdict(task),
        "memory": memory_cfg.to_dict(),
        "memory_init": OnlineNeRF(memory_cfg, task.camera).initial_state(),
        "model_config": model_cfg.to_dict(),
        "manifest_hash": manifest_hash,
        "scenes": dict(scenes),
        "git_commit": git_commit(),
        "train_config": train_config or {},
        "data": data or {},
    }
