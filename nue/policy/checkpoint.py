"""Policy checkpoints: weights plus everything needed to run and to refuse a mismatched evaluation.

A checkpoint embeds the task preset, the memory (NeRF) config and its fixed initial weights, the
model config, the demonstration manifest's hash and scene hashes, the git commit and the training
config. In code that description is a :class:`PolicyHeader`; the file (``torch.save`` of a dict,
format ``nue-checkpoint/1``) holds its :meth:`~PolicyHeader.to_dict` next to the weights and training
state, all plain data: dicts, lists, tuples, strings, numbers, booleans, None and tensors. Saving is atomic
(temporary file + rename) and refuses anything else; loading uses ``torch.load(..., weights_only=True)``, which
rebuilds only such data and refuses a file asking for any other object, so a checkpoint never runs code.
``load_header`` reads the description, ``load_policy`` rebuilds the network; ``check_compatible`` refuses a
task/memory preset or scene set that differs from the stored one; ``load_agent`` gives the agent and memory of the
shared loop (eval, DAgger collection, the demo), ``load_memory`` the memory alone (``nue view``'s replay).
"""

from __future__ import annotations

import collections
import dataclasses
import os
import pickle
import re
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import torch

from nue.errors import CheckpointError, NueError
from nue.nerf.config import MemoryConfig
from nue.nerf.online import OnlineNeRF
from nue.policy import PolicyModel, build_model
from nue.policy.agent import PolicyAgent
from nue.policy.config import ModelConfig
from nue.policy.nrns_agent import NRNSAgent
from nue.policy.nrns_model import DistanceNetwork
from nue.sim.task import CameraConfig, TaskConfig

FORMAT = "nue-checkpoint/1"
"""Format version of a checkpoint file."""


@dataclass(frozen=True)
class PolicyHeader:
    """What a policy checkpoint says about itself besides its weights: how to rebuild and run the policy
    (model and memory config) and what it was trained for and on (task preset, data, scenes, commit)."""

    model: ModelConfig
    """Architecture of the network (``model_config`` in the file)."""
    task: str = ""
    """Task preset name the policy was trained for ('' = not recorded); a run of another preset is refused."""
    memory: MemoryConfig | None = None
    """The online NeRF memory it was trained with (None = not recorded); its initial weights are stored apart."""
    manifest_hash: str = ""
    """:meth:`~nue.train.manifest.CollectionManifest.hash` of the training data."""
    scenes: Mapping[str, str] = field(default_factory=dict)
    """Scene name -> content hash of the training houses."""
    git_commit: str = ""
    """Commit the weights were trained at ('' outside a checkout)."""
    task_config: Mapping[str, Any] = field(default_factory=dict)
    """The task preset's values as stored (``dataclasses.asdict(TaskConfig)`` at training time; a record —
    only ``task`` is checked)."""
    train_config: Mapping[str, Any] = field(default_factory=dict)
    """The training run's config (``TrainConfig`` fields and the resolved precision), as stored."""
    data: Mapping[str, Any] = field(default_factory=dict)
    """What the run trained on: episode and step counts, skipped files."""

    @property
    def name(self) -> str:
        """The model preset's name (the method name in records when none is given)."""
        return self.model.name

    @classmethod
    def of(cls, task: TaskConfig, memory: MemoryConfig, model: ModelConfig, scenes: Mapping[str, str],
           manifest_hash: str = "", train_config: Mapping | None = None, data: Mapping | None = None) -> "PolicyHeader":
        """The header of a policy being trained now (at this checkout's commit)."""
        return cls(model=model, task=task.name, memory=memory, manifest_hash=manifest_hash, scenes=dict(scenes),
                   git_commit=git_commit(), task_config=dataclasses.asdict(task), train_config=dict(train_config or {}),
                   data=dict(data or {}))

    def to_dict(self) -> dict:
        """The header's entries of the checkpoint dict (``format`` is added by :func:`save_checkpoint`)."""
        d: dict[str, Any] = {}
        if self.task or self.task_config:
            d["task"] = {**self.task_config, "name": self.task}
        if self.memory is not None:
            d["memory"] = self.memory.to_dict()
        d.update(model_config=self.model.to_dict(), manifest_hash=self.manifest_hash, scenes=dict(self.scenes),
                 git_commit=self.git_commit, train_config=dict(self.train_config), data=dict(self.data))
        return d

    @classmethod
    def from_dict(cls, ckpt: Mapping[str, Any], path=None) -> "PolicyHeader":
        """The header of a checkpoint dict (weights and training state are ignored); entries a checkpoint
        lacks keep their defaults. :class:`CheckpointError` naming ``path`` if it is malformed."""
        try:
            task = dict(ckpt.get("task") or {})
            memory = ckpt.get("memory")
            return cls(model=ModelConfig.from_dict(ckpt["model_config"]), task=task.get("name", ""),
                       memory=MemoryConfig.from_dict(memory) if memory is not None else None,
                       manifest_hash=ckpt.get("manifest_hash", ""), scenes=dict(ckpt.get("scenes") or {}),
                       git_commit=ckpt.get("git_commit", ""), task_config=task,
                       train_config=dict(ckpt.get("train_config") or {}), data=dict(ckpt.get("data") or {}))
        except (KeyError, TypeError, ValueError, NueError) as exc:
            problem = exc.problem if isinstance(exc, NueError) else f"{type(exc).__name__}: {exc}"
            raise CheckpointError(path, f"malformed checkpoint header ({problem})") from None


def git_commit() -> str:
    """The repository's HEAD commit ('' outside a checkout)."""
    try:
        out = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                             cwd=Path(__file__).resolve().parent, timeout=10)
        return out.stdout.strip() if out.returncode == 0 else ""
    except (OSError, subprocess.SubprocessError):
        return ""


def save_checkpoint(path, payload: dict) -> Path:
    """Write ``payload`` (with ``format`` added) atomically with ``torch.save``; TypeError if it holds anything but
    plain data (:func:`plain_data_problem`), which :func:`load_checkpoint` could not read back."""
    problem = plain_data_problem(payload)
    if problem:
        raise TypeError(f"checkpoint {path}: {problem}")
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
    """A checkpoint file's dict, read with ``weights_only=True`` (tensors and plain data only; nothing in the file
    is executed); :class:`CheckpointError` if it is missing, a folder, unreadable, asks for other objects, is of
    another format, or holds weights (model or memory) that are not finite."""
    path = Path(path)
    if path.is_dir():
        raise CheckpointError(path, "is a directory, not a checkpoint file")
    if not path.is_file():
        raise CheckpointError(path, "checkpoint not found")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except pickle.UnpicklingError as exc:
        if "weights only" not in str(exc).lower():  # a pickle cut short or otherwise corrupt
            raise CheckpointError(path, f"cannot read checkpoint ({type(exc).__name__})") from None
        wants = re.search(r"GLOBAL ([\w.]+)", str(exc))
        what = f" ({wants.group(1)})" if wants else ""
        raise CheckpointError(path, f"refused: holds objects other than tensors and plain data{what}; nue reads "
                                    "checkpoints as data only and runs no code from them") from None
    except Exception as exc:
        raise CheckpointError(path, f"cannot read checkpoint ({type(exc).__name__})") from None
    if not isinstance(ckpt, dict) or ckpt.get("format") != FORMAT:
        raise CheckpointError(path, f"not a {FORMAT} checkpoint")
    for part in ("model_state", "memory_init"):
        bad = _non_finite(ckpt.get(part))
        if bad:
            raise CheckpointError(path, f"weights are not finite: {part} {bad} holds NaN or inf")
    return ckpt


PLAIN = (str, int, float, bool, type(None))
"""Types of the leaves a checkpoint may hold besides tensors (exactly these: a numpy float is not one)."""


def plain_data_problem(value, where: str = "") -> str:
    """'' if ``value`` is plain data, all of which ``weights_only=True`` reads back: tensors and :data:`PLAIN`
    values in dicts (also ordered ones, as state dicts are) with string or int keys, lists and tuples; else which
    entry is not, e.g. ``"train_config.out is a PosixPath, not plain data"``."""
    if type(value) in PLAIN or isinstance(value, torch.Tensor):
        return ""
    if type(value) in (dict, collections.OrderedDict):
        for k, v in value.items():
            name = f"{where}.{k}" if where else str(k)
            if not isinstance(k, (str, int)):
                return f"{name}: key of type {type(k).__name__}"
            problem = plain_data_problem(v, name)
            if problem:
                return problem
        return ""
    if type(value) in (list, tuple):
        return next((p for i, v in enumerate(value) if (p := plain_data_problem(v, f"{where}[{i}]"))), "")
    return f"{where or 'the payload'} is a {type(value).__name__}, not plain data"


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


def load_header(path) -> PolicyHeader:
    """The :class:`PolicyHeader` of a checkpoint file (checked as :func:`load_checkpoint` does)."""
    return PolicyHeader.from_dict(load_checkpoint(path), path)


def load_policy(path, device="cpu") -> tuple[PolicyModel, PolicyHeader]:
    """(model in eval mode, its header) from a checkpoint file."""
    model, header, _ = _load_policy(path, device)
    return model, header


def _load_policy(path, device) -> tuple[PolicyModel, PolicyHeader, dict]:
    ckpt = load_checkpoint(path)
    header = PolicyHeader.from_dict(ckpt, path)
    model = build_model(header.model)
    try:
        model.load_state_dict(ckpt["model_state"])
    except (KeyError, RuntimeError) as exc:
        raise CheckpointError(path, f"weights do not fit the stored model config ({exc})") from None
    return model.to(device).eval(), header, ckpt


def load_agent(checkpoint, task: TaskConfig, device: str | torch.device = "cpu", *, scenes: dict[str, str] | None = None,
               memory: bool | None = None, greedy: bool | None = None, temperature: float = 1.0
               ) -> tuple[PolicyAgent | NRNSAgent, OnlineNeRF | None]:
    """The policy agent of a checkpoint and its online NeRF memory (the stored config and fixed initial
    weights), both on ``device``, after :func:`check_compatible` with ``task`` and ``scenes``.

    ``memory``: None = a memory only when the model reads its maps, True = always (figures), False = never
    (the caller brings its own). ``greedy``: None = the task's rule (``task.greedy``); ``temperature``: of the
    sampled actions (:func:`~nue.policy.base.choose_actions`; 0 = argmax). The agent's
    ``git_commit`` is the commit the weights were trained at. An NRNS distance network (kind ``nrns``) gives its
    graph agent (:class:`nue.policy.nrns_agent.NRNSAgent`, deterministic; ``greedy`` and ``temperature`` do not apply).
    """
    model, header, ckpt = _load_policy(checkpoint, device)
    check_compatible(header, checkpoint, task=task, scenes=scenes)
    nerf = None
    if memory or (memory is None and model.config.uses_memory_maps):
        nerf = _memory(ckpt, header, checkpoint, task.camera, device)
    if isinstance(model, DistanceNetwork):  # NRNS acts through its graph agent, not from action logits
        return NRNSAgent(model, device=device, git_commit=header.git_commit), nerf
    agent = PolicyAgent(model, greedy=task.greedy if greedy is None else greedy, device=device,
                        git_commit=header.git_commit, temperature=temperature)
    return agent, nerf


def load_memory(checkpoint, camera: CameraConfig, device: str | torch.device = "cpu") -> OnlineNeRF:
    """A checkpoint's online NeRF memory (its stored config and fixed initial weights) for ``camera``."""
    ckpt = load_checkpoint(checkpoint)
    return _memory(ckpt, PolicyHeader.from_dict(ckpt, checkpoint), checkpoint, camera, device)


def _memory(ckpt: dict, header: PolicyHeader, path, camera: CameraConfig, device) -> OnlineNeRF:
    if header.memory is None or "memory_init" not in ckpt:
        raise CheckpointError(path, "holds no memory config and initial weights (needed for the memory maps)")
    return OnlineNeRF(header.memory, camera, init_state=ckpt["memory_init"], device=device)


def check_compatible(header: PolicyHeader, path, task: TaskConfig | None = None, memory: MemoryConfig | None = None,
                     scenes: Mapping[str, str] | None = None) -> None:
    """Raise :class:`CheckpointError` if the task preset, memory config or a known scene's content
    differs from what the checkpoint was trained with (scenes absent from training are fine)."""
    if task is not None and header.task != task.name:
        raise CheckpointError(path, f"trained for task preset {header.task!r}, asked to run {task.name!r}")
    if memory is not None and header.memory is not None and header.memory != memory:
        trained, asked = header.memory.to_dict(), memory.to_dict()
        diff = sorted(k for k in set(trained) | set(asked) if trained.get(k) != asked.get(k))
        raise CheckpointError(path, f"memory preset differs from the trained one in: {', '.join(diff)}")
    for name, h in (scenes or {}).items():
        trained_hash = header.scenes.get(name)
        if trained_hash is not None and trained_hash != h:
            raise CheckpointError(path, f"scene {name} has content {h}, but the policy was trained on content {trained_hash}")


def policy_meta(task: TaskConfig, memory_cfg: MemoryConfig, model_cfg: ModelConfig, scenes: Mapping[str, str],
                manifest_hash: str = "", train_config: Mapping | None = None, data: Mapping | None = None) -> dict:
    """Everything a checkpoint file carries besides the policy's weights and training state: the
    :class:`PolicyHeader`'s entries and the memory's fixed initial weights (``memory_init``)."""
    header = PolicyHeader.of(task, memory_cfg, model_cfg, scenes, manifest_hash, train_config, data)
    return {**header.to_dict(), "memory_init": OnlineNeRF(memory_cfg, task.camera).initial_state()}


RESUME_FREE = frozenset({"out", "data", "device", "verify_data", "select_workers", "select_scenes_root", "precision",
                         "compile"})
"""``nue.train.bc.TrainConfig`` fields a resumed run may change: where things are and how many workers select, not what is
trained (``precision`` is compared as resolved; the data by its manifest hash; ``compile`` changes only the rounding)."""


def resume_mismatches(stored: dict, now: dict) -> list[str]:
    """What a resumed run would change: ``"name stored -> now"`` per differing training setting (fields in
    both configs only, so older checkpoints compare what they recorded) and the data's manifest hashes (the first
    folder's, and every folder's in ``data["manifests"]`` when the stored checkpoint has them). Both
    arguments are checkpoint payloads / metas (``train_config``, ``manifest_hash``)."""

    def norm(v):
        return [norm(x) for x in v] if isinstance(v, (list, tuple)) else v

    a, b = dict(stored.get("train_config") or {}), dict(now.get("train_config") or {})
    free = RESUME_FREE
    if not a.get("time_budget_s") and not b.get("time_budget_s"):
        free = free | {"budget_clock"}  # which clock a budget counts on matters only with a budget
    out = [f"{k} {a[k]!r} -> {b[k]!r}" for k in sorted((a.keys() & b.keys()) - free) if norm(a[k]) != norm(b[k])]
    if stored.get("manifest_hash") and stored["manifest_hash"] != now.get("manifest_hash"):
        out.append(f"training data (manifest {stored['manifest_hash']} -> {now.get('manifest_hash')})")
    before, after = (d.get("manifests") for d in (stored.get("data") or {}, now.get("data") or {}))
    if before is not None and before != after:  # every folder's manifest (checkpoints before it was recorded: the first)
        out.append(f"training data folders (manifests {'+'.join(before)} -> {'+'.join(after or [])})")
    return out


def load_resumable(path: Path, model_cfg: ModelConfig, meta: dict) -> dict:
    """The ``last.pt`` a training run resumes from, once it is known to continue the same run: a CheckpointError
    when it was trained with another model config or other settings (:func:`resume_mismatches` against ``meta``,
    the :func:`policy_meta` of the run about to start)."""
    ck = load_checkpoint(path)
    if PolicyHeader.from_dict(ck, path).model != model_cfg:
        raise CheckpointError(path, "was trained with another model config; use another --out")
    changed = resume_mismatches(ck, meta)
    if changed:
        raise CheckpointError(path, f"was started with other settings ({'; '.join(changed)}); "
                              "resume with the same settings or use another --out")
    return ck
