"""Closed-loop diagnostics from evaluation records: how often an agent is blocked, what it does next,
whether it dithers between turns, and which actions it takes (``nue diagnose``, ``nue report``).

Per method (records grouped by canonical method key), pooled over its episodes:

* collisions per episode / per step: from the records' ``collisions`` and ``steps`` fields, so
  records made before trajectories existed count too;
* P(forward | blocked): over the steps t + 1 whose step t was a blocked forward move, the fraction
  choosing MOVE_FORWARD again. The simulator slides a blocked move along the obstacle, so most blocked
  moves still advance (a trained NUE's: median 0.21 m of a 0.25 m step); P(forward | stuck) counts only the
  blocked moves that advanced less than ``STUCK_FRACTION`` of the forward step (from the poses), where
  another forward move is the wall-pushing the diagnostic is after; P(blocked again | blocked): over the
  same steps t + 1, the fraction whose move was blocked too (a forward move into the obstacle again,
  whatever it advanced), so forward moves that cleared the obstacle do not count;
* turn reversals: over the turns at steps t >= 1, the fraction whose step t - 1 was the opposite turn;
* action histogram: the fraction of steps per action of the task preset.

The last three need ``record.trajectory()``; methods without any show n/a (NaN). Action ids come
from the task preset (``paper``: 0 forward, 1 left, 2 right; ``habitat``: 0 STOP, 1 forward, 2 left,
3 right). Map controls and the previous-action probe on demonstration data: :mod:`nue.evaluate.diagnose_maps`.
"""

from __future__ import annotations

import binascii
import collections
import json
import math
from dataclasses import MISSING, asdict, astuple, dataclass, field, fields, is_dataclass
from pathlib import Path
from typing import Sequence

import numpy as np

from nue.errors import DataError
from nue.evaluate.record_keys import OnDropped, UniqueKeys
from nue.evaluate.table import by_method, canonical_method, run_label
from nue.sim.record import EpisodeRecord, RecordFormatError, Trajectory
from nue.sim.task import TaskConfig, get_task


def action_short_names(task: str | TaskConfig = "paper") -> tuple[str, ...]:
    """``MOVE_FORWARD`` -> ``forward``, ``TURN_LEFT`` -> ``left``, ... in action-id order."""
    return tuple(a.lower().replace("move_", "").replace("turn_", "") for a in get_task(task).actions)


@dataclass(frozen=True)
class TrajectoryCounts:
    """Raw counts of one trajectory (or a sum of several): the numerators and denominators of the rates."""

    steps: int
    """T, actions taken."""
    collisions: int
    """Steps whose forward move was blocked."""
    after_blocked: int
    """Steps t + 1 (t + 1 < T) whose step t was blocked."""
    forward_after_blocked: int
    """Of those, how many chose MOVE_FORWARD."""
    after_stuck: int
    """Steps t + 1 (t + 1 < T) whose step t was blocked and advanced < ``STUCK_FRACTION`` x the forward step."""
    forward_after_stuck: int
    """Of those, how many chose MOVE_FORWARD."""
    blocked_again: int
    """Steps t + 1 (t + 1 < T) whose step t was blocked and which were blocked too."""
    turns: int
    """Turns (left or right) at steps t >= 1."""
    reversals: int
    """Of those, how many follow the opposite turn at t - 1."""
    action_counts: tuple[int, ...]
    """Steps per action id (length = the preset's number of actions)."""

    def __add__(self, other: "TrajectoryCounts") -> "TrajectoryCounts":
        s, o = astuple(self), astuple(other)
        return TrajectoryCounts(*(a + b for a, b in zip(s[:-1], o[:-1])), tuple(np.add(s[-1], o[-1]).tolist()))


STUCK_FRACTION = 0.5
"""A blocked forward move that advanced less than this share of the forward step counts as stuck."""


def trajectory_counts(traj: Trajectory, task: str | TaskConfig = "paper") -> TrajectoryCounts:
    """Counts of one trajectory: ``actions`` (T,), ``collided`` (T,) (``collided[t]``: step t's forward move was
    blocked) and ``poses`` (T + 1, 3), whose xy displacement tells a stuck move from a slide."""
    task = get_task(task)
    a = np.asarray(traj.actions, dtype=np.int64)
    c = np.asarray(traj.collided, dtype=bool)
    moved = np.linalg.norm(np.diff(np.asarray(traj.poses, dtype=np.float64)[:, :2], axis=0), axis=1)  # (T,)
    stuck = c & (moved < STUCK_FRACTION * task.forward_step)
    fwd, left, right = (task.action_id(n) for n in ("MOVE_FORWARD", "TURN_LEFT", "TURN_RIGHT"))
    nxt = a[1:][c[:-1]]  # actions at t + 1 after a blocked step t
    nxt_stuck = a[1:][stuck[:-1]]
    again = c[1:] & c[:-1]
    cur, prev = a[1:], a[:-1]
    turns = (cur == left) | (cur == right)
    reversed_ = ((cur == left) & (prev == right)) | ((cur == right) & (prev == left))
    if a.size and (a.min() < 0 or a.max() >= len(task.actions)):
        raise ValueError(f"trajectory: action id {int(a.max())} outside task preset {task.name!r}")
    return TrajectoryCounts(int(a.size), int(c.sum()), int(nxt.size), int((nxt == fwd).sum()), int(nxt_stuck.size),
                            int((nxt_stuck == fwd).sum()), int(again.sum()), int(turns.sum()),
                            int(reversed_.sum()), tuple(int(v) for v in np.bincount(a, minlength=len(task.actions))))


def _ratio(num: float, den: float) -> float:
    return num / den if den else math.nan


@dataclass(frozen=True)
class RecordDiagnostics:
    """Closed-loop diagnostics of one method (see the module docstring); rates are NaN when undefined."""

    method: str
    """Canonical method key."""
    episodes: int
    """Records of the method."""
    steps: int
    """Sum of the records' ``steps``."""
    collisions: int
    """Sum of the records' ``collisions``."""
    without_trajectory: int
    """Records lacking a trajectory (excluded from the trajectory-based rates)."""
    counts: TrajectoryCounts
    """Summed counts over the records that have a trajectory."""
    actions: tuple[str, ...] = field(default=())
    """Short action names of the task preset, in id order."""

    @property
    def collisions_per_episode(self) -> float:
        return _ratio(self.collisions, self.episodes)

    @property
    def collisions_per_step(self) -> float:
        return _ratio(self.collisions, self.steps)

    @property
    def p_forward_after_blocked(self) -> float:
        return _ratio(self.counts.forward_after_blocked, self.counts.after_blocked)

    @property
    def p_forward_after_stuck(self) -> float:
        return _ratio(self.counts.forward_after_stuck, self.counts.after_stuck)

    @property
    def p_blocked_again(self) -> float:
        return _ratio(self.counts.blocked_again, self.counts.after_blocked)

    @property
    def turn_reversal_rate(self) -> float:
        return _ratio(self.counts.reversals, self.counts.turns)

    @property
    def action_fractions(self) -> dict[str, float]:
        """Fraction of trajectory steps per action (NaN without trajectories)."""
        return {n: _ratio(k, self.counts.steps) for n, k in zip(self.actions, self.counts.action_counts)}

    def summary(self) -> dict:
        """Plain-dict form (for JSON)."""
        return {"method": self.method, "episodes": self.episodes, "steps": self.steps, "collisions": self.collisions,
                "without_trajectory": self.without_trajectory, "trajectory_episodes": self.episodes - self.without_trajectory,
                "collisions_per_episode": self.collisions_per_episode, "collisions_per_step": self.collisions_per_step,
                "p_forward_after_blocked": self.p_forward_after_blocked, "after_blocked_steps": self.counts.after_blocked,
                "p_forward_after_stuck": self.p_forward_after_stuck, "after_stuck_steps": self.counts.after_stuck,
                "p_blocked_again": self.p_blocked_again,
                "turn_reversal_rate": self.turn_reversal_rate, "turns": self.counts.turns,
                "action_fractions": self.action_fractions, "counts": asdict(self.counts)}


def record_diagnostics(records: Sequence[EpisodeRecord], task: str | TaskConfig = "paper",
                       methods: Sequence[str] = ()) -> dict[str, RecordDiagnostics]:
    """Diagnostics per canonical method key, in table order; ``methods`` keeps only those (any alias)."""
    task = get_task(task)
    keep = {canonical_method(m) for m in methods}
    zero = TrajectoryCounts(0, 0, 0, 0, 0, 0, 0, 0, 0, (0,) * len(task.actions))
    out = {}
    for key, recs in by_method(records).items():
        if keep and key not in keep:
            continue
        total, missing = zero, 0
        for r in recs:
            traj = r.trajectory()
            if traj is None:
                missing += 1
            else:
                total = total + trajectory_counts(traj, task)
        out[key] = RecordDiagnostics(key, len(recs), sum(r.steps for r in recs), sum(r.collisions for r in recs),
                                     missing, total, action_short_names(task))
    return out


@dataclass(frozen=True)
class ActionAgreement:
    """How closely two runs of the same episodes act (e.g. ``nue eval --batch 8`` against ``--batch 1``)."""

    a: str
    b: str
    episodes: int
    """Episodes both runs have with a trajectory."""
    steps: int
    """Steps compared: per episode the first ``min(limit, T_a, T_b)``."""
    agreement: float
    """Fraction of the compared steps at which both chose the same action."""
    identical: int
    """Episodes whose whole action sequences are equal."""
    median_first_difference: float | None
    """Median step of the first differing action over the episodes that differ (None if none does)."""


def action_agreement(records: Sequence[EpisodeRecord], a: str, b: str, limit: int = 50) -> ActionAgreement:
    """Per-step action agreement of methods ``a`` and ``b`` (record method names, e.g. ``nue_gru_lean`` and
    ``nue_gru_lean_b8``) over the first ``limit`` steps of the episodes (scene, episode id) both ran."""
    runs: dict[str, dict[tuple[str, str], np.ndarray]] = {a: {}, b: {}}
    for r in records:
        traj = r.trajectory() if r.method in runs else None
        if traj is not None:
            runs[r.method][(r.scene, r.episode_id)] = traj.actions
    keys = sorted(set(runs[a]) & set(runs[b]))
    same = steps = identical = 0
    firsts = []
    for k in keys:
        x, y = runs[a][k], runs[b][k]
        n = min(limit, len(x), len(y))
        same += int((x[:n] == y[:n]).sum())
        steps += n
        m = min(len(x), len(y))
        diff = np.flatnonzero(x[:m] != y[:m])
        if len(diff):
            firsts.append(int(diff[0]))
        elif len(x) == len(y):
            identical += 1
        else:
            firsts.append(m)
    return ActionAgreement(a, b, len(keys), steps, same / steps if steps else float("nan"), identical,
                           float(np.median(firsts)) if firsts else None)


_PARSED: "collections.OrderedDict[tuple[str, int, int], list[tuple[int, dict, EpisodeRecord]]]" = collections.OrderedDict()
"""Checked records of the files read last, by (path, size, mtime): a report reads each file several times."""
_PARSED_FILES = 16


def _parsed_lines(p) -> list[tuple[int, dict, EpisodeRecord]]:
    """(line number, dict, record) of every record line of file ``p``, each checked; cached while the file is
    unchanged (same size and modification time)."""
    try:
        st = Path(p).stat()
        key = (str(Path(p).resolve()), st.st_size, st.st_mtime_ns)
        if key in _PARSED:
            _PARSED.move_to_end(key)
            return _PARSED[key]
        lines = Path(p).read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        reason = (exc.strerror if isinstance(exc, OSError) else None) or type(exc).__name__
        raise DataError(p, f"cannot read records ({reason})") from None
    parsed = []
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            d = json.loads(line)
            if not isinstance(d, dict):
                raise TypeError(f"a JSON {type(d).__name__}, not an object")
            missing = [f.name for f in fields(EpisodeRecord) if f.name not in d
                       and f.default is MISSING and f.default_factory is MISSING]
            if missing:
                raise TypeError(f"missing {', '.join(missing)}")
            r = EpisodeRecord.from_dict(d)
            if not isinstance(r.extra, dict):
                raise TypeError("extra is not an object")
            r.trajectory()
        except json.JSONDecodeError:
            raise DataError(p, f"line {i}: not JSON") from None
        except RecordFormatError as exc:
            raise DataError(p, f"line {i}: {exc}") from None
        except (TypeError, AttributeError) as exc:
            raise DataError(p, f"line {i}: not an episode record ({exc})") from None
        except (ValueError, KeyError, binascii.Error) as exc:
            raise DataError(p, f"line {i}: bad trajectory ({exc})") from None
        parsed.append((i, d, r))
    _PARSED[key] = parsed
    while len(_PARSED) > _PARSED_FILES:
        _PARSED.popitem(last=False)
    return parsed


def read_records(*paths, drop_duplicates: bool = False, on_dropped: OnDropped | None = None) -> list[EpisodeRecord]:
    """Records from JSON-lines files, checked: a bad line or trajectory raises :class:`DataError` naming file and line,
    and so does a key recorded twice in one file (:mod:`nue.evaluate.record_keys`), unless ``drop_duplicates``: then
    the first record of each key is kept and ``on_dropped(file, n)`` told how many were left out. A file read again
    unchanged is not parsed again."""
    out = []
    for p in paths:
        unique = UniqueKeys(p, drop_duplicates)
        for i, d, r in _parsed_lines(p):
            if unique.first(d, i):
                out.append(r)
        unique.report(on_dropped)
    return out


# --- formatting ---------------------------------------------------------------------------------
def fmt(x: float | None, spec: str, scale: float = 1.0) -> str:
    """``format(scale * x, spec)``, or ``n/a`` for None / NaN."""
    return "n/a" if x is None or (isinstance(x, float) and math.isnan(x)) else format(scale * x, spec)


def format_record_diagnostics(diags: dict[str, RecordDiagnostics]) -> str:
    """Markdown table, one row per method: episodes, steps, collisions, P(forward | blocked), reversals, actions."""
    names = next(iter(diags.values())).actions if diags else action_short_names()
    head = ["method", "episodes", "steps", "collisions / episode", "collisions / step",
            "P(forward \\| blocked) %", "P(forward \\| stuck) % (n)", "P(blocked again \\| blocked) %", "turn reversals %", f"actions % ({' / '.join(names)})", "no trajectory"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for key, d in diags.items():
        hist = d.action_fractions
        acts = "n/a" if not d.counts.steps else " / ".join(fmt(hist[n], ".1f", 100) for n in d.actions)
        lines.append(f"| {run_label(key, diags)} | {d.episodes} | {d.steps} | {fmt(d.collisions_per_episode, '.2f')} | "
                     f"{fmt(d.collisions_per_step, '.3f')} | {fmt(d.p_forward_after_blocked, '.1f', 100)} | "
                     f"{_stuck_cell(d)} | {fmt(d.p_blocked_again, '.1f', 100)} | "
                     f"{fmt(d.turn_reversal_rate, '.1f', 100)} | {acts} | {d.without_trajectory} |")
    return "\n".join(lines) + "\n"


def _stuck_cell(d: RecordDiagnostics) -> str:
    return "n/a" if not d.counts.steps else f"{fmt(d.p_forward_after_stuck, '.1f', 100)} ({d.counts.after_stuck})"


DIAGNOSTICS_NOTES = (
    "Collisions from the records' counts (steps whose forward move was blocked); P(forward | blocked): of the steps "
    "right after a blocked forward move, the share that tried forward again (blocked moves slide along the obstacle, "
    "so most still advance); P(forward | stuck): the same after the blocked moves that advanced less than half a "
    "step, with their count in brackets; P(blocked again | blocked): of the steps right after a blocked move, the "
    "share blocked too (pushing into the obstacle again; forward moves that cleared it do not count); turn "
    "reversals: of the turns, the share "
    "right after the opposite turn. Both, and the action shares, pool the steps of the episodes that carry a "
    "trajectory; n/a where no record of the method has one (records made before trajectories were stored)."
)


def to_jsonable(obj):
    """Dataclasses, numpy scalars / arrays, tuples -> JSON types; NaN -> None."""
    if is_dataclass(obj) and not isinstance(obj, type):
        return to_jsonable(obj.summary() if hasattr(obj, "summary") else asdict(obj))
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, np.ndarray)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, (np.floating, float)):
        return None if math.isnan(obj) else float(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    return obj
