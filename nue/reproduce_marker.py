"""The marker a finished ``nue reproduce`` stage leaves (``OUT/stages/<stage>.json``), typed.

A marker is a :class:`StageMarker`: the stage's name, wall-clock, finish time and its summary, one dataclass per
kind of stage. JSON is only the file format (:meth:`StageMarker.to_dict` / :meth:`StageMarker.from_dict`, which
give back the same dict: a marker read and written again is the same file). :class:`RunFolders` says where a run's
files are, :func:`stage_done` reads a stage's marker.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Union

from nue.errors import DataError
from nue.train.collect import CollectSummary
from nue.train.dagger import DaggerRound


@dataclass(frozen=True)
class HousesSummary:
    """The ``scenes`` stage: the houses it made or kept."""

    houses: list[str]
    """``<split>_<index>`` of each house, in order."""

    def to_dict(self) -> dict:
        return {"houses": list(self.houses)}

    @classmethod
    def from_dict(cls, d: dict) -> HousesSummary:
        return cls(houses=list(d["houses"]))


@dataclass(frozen=True)
class TrainRunSummary:
    """A ``train/<run>`` stage: the run's best checkpoint and what training it took."""

    best: str
    """The best checkpoint (closed-loop selection's choice when the recipe selects)."""
    seconds: float
    """Wall time of the run in the worker."""
    steps: int | None = None
    """Optimiser steps (behaviour cloning; None with DAgger)."""
    train_seconds: float | None = None
    """Training time as the trainer measured it (behaviour cloning; None with DAgger)."""
    rounds: list[DaggerRound] | None = None
    """DAgger's rounds (None for behaviour cloning)."""
    model: str | None = None
    """The model preset (None in markers written before it was recorded)."""
    seed: int | None = None
    """The training seed (None in markers written before it was recorded)."""

    def to_dict(self) -> dict:
        """The JSON form: the entries that are set, in the order the trainer wrote them."""
        d: dict = {"best": self.best}
        if self.steps is not None:
            d["steps"] = self.steps
        if self.train_seconds is not None:
            d["train_seconds"] = self.train_seconds
        if self.rounds is not None:
            d["rounds"] = [r.to_dict() for r in self.rounds]
        if self.model is not None:
            d["model"] = self.model
        if self.seed is not None:
            d["seed"] = self.seed
        d["seconds"] = self.seconds
        return d

    @classmethod
    def from_dict(cls, d: dict) -> TrainRunSummary:
        rounds = d.get("rounds")
        return cls(best=d["best"], seconds=d["seconds"], steps=d.get("steps"), train_seconds=d.get("train_seconds"),
                   rounds=None if rounds is None else [DaggerRound.from_dict(r) for r in rounds],
                   model=d.get("model"), seed=d.get("seed"))


@dataclass(frozen=True)
class EvalStageSummary:
    """An ``eval/<set>`` or ``explore/<set>`` stage: its records file and what it evaluated."""

    records: str
    """The records file (JSON lines)."""
    episode_set: str
    """The episode set's name."""
    methods: list[str]
    """``<run>=<checkpoint>`` of every training run, then the experts (none for a swapped-maps stage)."""

    def to_dict(self) -> dict:
        return {"records": self.records, "episode_set": self.episode_set, "methods": list(self.methods)}

    @classmethod
    def from_dict(cls, d: dict) -> EvalStageSummary:
        return cls(records=d["records"], episode_set=d["episode_set"], methods=list(d["methods"]))


@dataclass(frozen=True)
class ReportSummary:
    """The ``report`` stage: the RESULTS.md it wrote."""

    results_md: str

    def to_dict(self) -> dict:
        return {"results_md": self.results_md}

    @classmethod
    def from_dict(cls, d: dict) -> ReportSummary:
        return cls(results_md=d["results_md"])


StageSummary = Union[HousesSummary, CollectSummary, TrainRunSummary, EvalStageSummary, ReportSummary]
"""What a stage reports; its kind follows from the stage's name (:func:`summary_type`)."""


def summary_type(stage: str) -> type[StageSummary]:
    """The summary class of a stage name (``scenes``, ``collect``, ``collect/<split>``, ``train/<run>``, ``eval/<set>``, ``explore/<set>``, ``report``)."""
    if stage == "scenes":
        return HousesSummary
    if stage == "collect" or stage.startswith("collect/"):
        return CollectSummary
    if stage.startswith("train/"):
        return TrainRunSummary
    if stage.startswith(("eval/", "explore/")):
        return EvalStageSummary
    if stage == "report":
        return ReportSummary
    raise ValueError(f"unknown reproduce stage {stage!r}")


@dataclass(frozen=True)
class StageMarker:
    """A finished stage: skipped by a rerun, its wall-clock in RESULTS.md."""

    stage: str
    """The stage's name (``train/nue``)."""
    seconds: float
    """Wall-clock of the call that finished it."""
    finished: str
    """When it finished (``YYYY-MM-DD HH:MM UTC``)."""
    summary: StageSummary
    """What it made (the class of its kind of stage)."""
    machine: str = ""
    """Where the call that finished it ran (:func:`nue.train.hardware.machine_summary`); '' in markers written before
    this field."""

    def to_dict(self) -> dict:
        return {"stage": self.stage, "seconds": self.seconds, "finished": self.finished,
                "summary": self.summary.to_dict(), **({"machine": self.machine} if self.machine else {})}

    @classmethod
    def from_dict(cls, d: dict) -> StageMarker:
        stage = d["stage"]
        return cls(stage=stage, seconds=d["seconds"], finished=d["finished"],
                   summary=summary_type(stage).from_dict(d["summary"]), machine=str(d.get("machine", "")))

    @classmethod
    def read(cls, path: Path) -> StageMarker:
        """The marker in ``path``; a file that is not one stops with a :class:`~nue.errors.DataError` naming it."""
        try:
            return cls.from_dict(json.loads(path.read_text()))
        except (ValueError, KeyError, TypeError, AttributeError) as e:
            raise DataError(path, f"is not a reproduce stage marker ({type(e).__name__}: {e})") from None

    def train_run(self) -> TrainRunSummary:
        """The summary of a training stage (ValueError for a stage of another kind)."""
        if not isinstance(self.summary, TrainRunSummary):
            raise ValueError(f"stage {self.stage!r} is not a training run")
        return self.summary


@dataclass(frozen=True)
class RunFolders:
    """Where a reproduce run reads and writes."""

    out: Path
    """The run folder."""
    scenes_root: Path
    """Generated houses (shared with other commands; kept when intact)."""
    episodes_root: Path
    """The committed episode sets (``episodes/``: ``val``, ``val252``, ``val_plain``, ``select``)."""

    @property
    def demos(self) -> Path:
        """The demonstrations of the recipe's ``train_split``."""
        return self.out / "demos"

    def demos_of(self, split: str, first: bool) -> Path:
        """The demonstrations of a recipe's collection in ``split``: :attr:`demos` for the ``first`` (``train_split``),
        ``demos_<split>`` for one of ``also_train``."""
        return self.demos if first else self.out / f"demos_{split}"

    def run(self, name: str) -> Path:
        """The folder of a training run (``nue``, ``nue@s1``)."""
        return self.out / "runs" / name

    def records(self, stage: str) -> Path:
        return self.out / "records" / f"{stage.removeprefix('eval/')}.jsonl"

    def marker(self, stage: str) -> Path:
        return self.out / "stages" / f"{stage.replace('/', '__')}.json"


def stage_done(folders: RunFolders, stage: str) -> StageMarker | None:
    """The marker of a finished stage (its seconds, summary and finish time), or None."""
    path = folders.marker(stage)
    return StageMarker.read(path) if path.is_file() else None
