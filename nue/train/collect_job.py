"""What one ``nue collect`` episode job carries to its worker: who drives (:class:`AgentSpec`) and the
episode, house and memory (:class:`CollectJob`); frozen dataclasses, pickled as they are.

The only dict forms are the ones written to files: ``AgentSpec.to_dict`` in the collection manifest
(``agent``, for DAgger collections) and :meth:`CollectJob.agent_meta` in each episode file's header.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from nue.errors import DataError
from nue.nerf.config import MemoryConfig
from nue.sim.episodes import Episode
from nue.train.compact import StepStorage

AGENT_KINDS = ("expert", "dagger")


@dataclass(frozen=True)
class AgentSpec:
    """Who drives a collection: the expert, or DAgger's mix of a policy with the expert (the expert labels
    every step either way; which expert and the DART noise are :class:`CollectJob` fields)."""

    kind: str = "expert"
    """``expert`` or ``dagger``."""
    checkpoint: str = ""
    """DAgger: the policy checkpoint that drives with probability 1 - ``beta``."""
    beta: float = 0.0
    """DAgger: probability that a step's executed action is the expert's."""
    expert_steps_from: str = ""
    """DAgger: the expert collection whose per-episode step counts cap policy control."""
    max_factor: float = 3.0
    """DAgger: policy control stops after this multiple of the expert's step count; the expert finishes."""

    def __post_init__(self) -> None:
        if self.kind not in AGENT_KINDS:
            raise DataError(None, f"unknown agent kind {self.kind!r}; known: {', '.join(AGENT_KINDS)}")
        if self.kind == "dagger" and not (self.checkpoint and self.expert_steps_from):
            raise DataError(None, "a dagger agent needs a checkpoint and the expert collection (expert_steps_from)")

    @classmethod
    def dagger(cls, checkpoint: str | Path, beta: float, expert_steps_from: str | Path, max_factor: float = 3.0
               ) -> "AgentSpec":
        return cls("dagger", str(checkpoint), beta, str(expert_steps_from), max_factor)

    def to_dict(self) -> dict:
        """The manifest's ``agent`` entry: ``{"kind": "expert"}`` or all five DAgger entries."""
        if self.kind == "expert":
            return {"kind": "expert"}
        return {"kind": self.kind, "checkpoint": self.checkpoint, "beta": self.beta,
                "expert_steps_from": self.expert_steps_from, "max_factor": self.max_factor}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> "AgentSpec":
        if d.get("kind", "expert") == "expert":
            return cls()
        return cls(d["kind"], d["checkpoint"], d["beta"], d["expert_steps_from"], d.get("max_factor", 3.0))


@dataclass(frozen=True)
class CollectJob:
    """One collection episode: everything its worker needs (``jobs.Job.payload``)."""

    scene: str
    """Scene folder."""
    episode: Episode
    """The episode to run."""
    task: str
    """Task preset name."""
    memory: MemoryConfig
    """The online NeRF memory (the manifest's); its initial weights from ``memory.init_seed``."""
    model: str
    """Model preset whose input layout the arrays are stored in."""
    seed: int
    """The episode's own seed (memory, action sampling, noise)."""
    device: str
    """Device of the memory (and of a DAgger policy)."""
    agent: AgentSpec
    """Who drives."""
    expert: str = "geodesic"
    """Which expert drives or labels (``geodesic`` or ``explore``)."""
    noise: float = 0.0
    """DART noise: probability that a random move is executed instead (the label stays the expert's)."""
    expert_steps: int = 0
    """DAgger: the expert's step count on this episode (0 = unknown: no cap on policy control)."""
    storage: StepStorage = StepStorage()
    """How the episode's step arrays are encoded in its file (compact by default)."""

    def agent_meta(self) -> dict:
        """Who drove, as stored in the episode file's header (``meta["agent"]``)."""
        d = {**self.agent.to_dict(), "expert": self.expert, "noise": self.noise}
        if self.agent.kind == "dagger":
            d["expert_steps"] = self.expert_steps
        return d
