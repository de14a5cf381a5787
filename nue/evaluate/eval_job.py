"""What one ``nue eval`` episode job carries to its worker (:class:`EvalJob`) and the settings stored in
its record and compared on resume (:class:`RunSettings`); frozen dataclasses, pickled as they are.

The only dict form is the record's ``extra["settings"]`` (:meth:`RunSettings.to_dict`).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
from dataclasses import dataclass
from typing import Any, Mapping

from nue.sim.episodes import Episode


@dataclass(frozen=True)
class RunSettings:
    """Everything that changes an episode's record: stored in it (``extra['settings']``) and compared when
    a run resumes. The device is left out (it does not change what a policy does, only how fast)."""

    agent: str
    """The checkpoint's content hash (:func:`nue.evaluate.runner.file_sha256`), or the expert method's name."""
    task: str
    """Task preset name."""
    max_steps: int
    """Step limit override (0 = the preset's)."""
    seed: int
    """Base seed of the run."""
    swap_maps: bool
    """Maps from another episode of the house (control)."""
    coverage: bool
    """Seen floor area recorded after every step."""
    episode: str
    """sha256 (16 hex digits) of the episode's canonical JSON (:meth:`episode_digest`)."""
    scene: str
    """The house's content hash."""
    goal_from: str = ""
    """Exploration benchmark: ``<scene hash>/<episode digest>`` of the other house's episode whose goal photo the
    agent is given ('' = the episode's own goal). Settings added later carry defaults: a record made before they
    existed reads as having the default."""
    explore_only: bool = False
    """Success never ends the episode (the exploration benchmark)."""
    last_mile: dict | None = None
    """The last-mile wrapper's settings (:meth:`nue.policy.last_mile.LastMileConfig.to_dict`) of a ``sling+``
    method; None otherwise (then left out of the stored form, as in records made before it existed)."""
    temperature: float = 1.0
    """Sampling temperature of a policy's actions (``nue eval --temperature``; 0 = argmax). Left out of the stored
    form when 1 (the paper's sampling, as in records made before it existed)."""
    batch: int = 1
    """Lock-step slots of the worker that ran the episode (``nue eval --batch``); the policy's forward runs on this
    many rows, which changes its rounding. Left out of the stored form when 1 (as in records made before it existed)."""

    @staticmethod
    def episode_digest(episode: Episode) -> str:
        """sha256 (16 hex digits) of ``dataclasses.asdict(episode)`` as canonical JSON."""
        return hashlib.sha256(json.dumps(dataclasses.asdict(episode), sort_keys=True).encode()).hexdigest()[:16]

    def to_dict(self) -> dict:
        """The record's ``extra['settings']`` (``last_mile`` only when set, ``temperature`` only when not 1,
        ``batch`` only when > 1)."""
        d = dataclasses.asdict(self)
        if d["temperature"] == 1.0:
            del d["temperature"]
        if d["last_mile"] is None:
            del d["last_mile"]
        if d["batch"] == 1:
            del d["batch"]
        return d

    def differences(self, stored: Mapping[str, Any] | None) -> list[str]:
        """Sorted names of the settings in which a record's stored ``extra['settings']`` differs from these
        (``["settings (an older record)"]`` for a record made before settings were stored)."""
        if stored is None:
            return ["settings (an older record)"]
        now = self.to_dict()
        default = {f.name: f.default for f in dataclasses.fields(self) if f.default is not dataclasses.MISSING}
        names = [f.name for f in dataclasses.fields(self)]  # also those left out of one stored form (default)
        return sorted(k for k in names if (k in now or k in stored) and stored.get(k, default.get(k)) != now.get(k, default.get(k)))


@dataclass(frozen=True)
class EvalJob:
    """One episode of one method: everything its worker needs (``jobs.Job.payload``)."""

    method: str
    """Method name written to the record (``+swap`` appended for the swapped-maps control)."""
    checkpoint: str | None
    """Policy checkpoint path; None for an expert."""
    expert: str
    """Which expert runs when ``checkpoint`` is None (``geodesic`` or ``explore``); '' for a policy."""
    scene: str
    """Scene folder."""
    episode: Episode
    """The episode to run."""
    other: Episode | None
    """Swapped-maps control: the episode of the same house whose memory maps the policy is fed; else None."""
    task: str
    """Task preset name."""
    seed: int
    """The episode's own seed (memory, action sampling)."""
    device: str
    """Device of policy and memory."""
    coverage: bool
    """Record the seen floor area after every step."""
    max_steps: int
    """Step limit override (0 = the preset's)."""
    settings: RunSettings
    """What the record stores to be compared on resume."""
    goal_scene: str = ""
    """Exploration benchmark: scene folder of the house whose goal photo the agent is given ('' = its own)."""
    goal_episode: Episode | None = None
    """Exploration benchmark: the episode (of ``goal_scene``) whose goal photo the agent is given."""
    explore_only: bool = False
    """Success never ends the episode; it runs to the step limit."""
    last_mile: Any = None
    """A ``sling+`` method: the :class:`nue.policy.last_mile.LastMileConfig` its agent is wrapped with; else None."""
    temperature: float = 1.0
    """Sampling temperature of a policy's actions (0 = argmax)."""
