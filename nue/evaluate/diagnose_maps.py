"""Diagnostics on demonstration data (``nue diagnose --data``): do the memory maps leak the agent's own
history, and what does a policy do where the demonstrations bumped into something?

The maps I_u (1, h, w) and I_cog (64, h, w) are rendered before the memory learns the current frame,
so they can encode the previous action (after a left turn the newly seen left edge of I_u is high).
Two tools:

* **map controls** (:func:`map_controls`): a checkpoint's held-out action accuracy (:func:`nue.policy.accuracy.held_out_accuracy`)
  with intact maps, with both maps mirrored left-right, and with each step given the maps of another
  step of the same episode (>= ``min_gap`` steps away when possible); n/a for models without maps;
* **previous-action probe** (:func:`previous_action_probe`): multinomial logistic regression from
  I_u average-pooled to 5 x 6 blocks (log1p; optionally + the mean per-pixel norm of I_cog) at step t
  to the executed action at t - 1, leave-one-house-out; the same probe on maps permuted across the
  steps of each house is the control (it should sit at chance);
* **after a blocked move** (:func:`after_blocked`): at the demonstration steps that follow an executed
  forward move which advanced less than 96% of the task's step (blocked, sliding or not), the share of
  expert labels that say forward and a checkpoint's mean P(forward) and argmax-forward rate there — the
  offline counterpart of the closed-loop P(forward | previous move blocked) of :mod:`nue.evaluate.diagnose`.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np
import torch
from sklearn.linear_model import LogisticRegression
from sklearn.metrics import balanced_accuracy_score
from sklearn.model_selection import LeaveOneGroupOut
from sklearn.pipeline import make_pipeline
from sklearn.preprocessing import StandardScaler

from nue.errors import DataError
from nue.evaluate.diagnose import fmt
from nue.policy.accuracy import held_out_accuracy
from nue.policy.checkpoint import load_policy

MAP_KEYS = ("i_u", "i_cog")


class ProbeUnavailable(DataError):
    """Too little data for the leave-one-house-out probe (fewer than 2 houses)."""


# --- map controls -------------------------------------------------------------------------------
def mirror_maps(x: np.ndarray) -> np.ndarray:
    """Maps (..., h, w) flipped left-right (the width axis reversed)."""
    return np.asarray(x)[..., ::-1]


def other_step_indices(n: int, rng: np.random.Generator, min_gap: int = 10) -> np.ndarray:
    """(n,) int: for each step t of an n-step episode, a uniformly drawn step s with |s - t| >= g,
    g = min(min_gap, the largest distance available from t); so s != t whenever n >= 2."""
    t = np.arange(n)
    g = np.maximum(np.minimum(min_gap, np.maximum(t, n - 1 - t)), 1)
    left = np.maximum(t - g + 1, 0)  # candidates 0 .. t - g
    right = np.maximum(n - t - g, 0)  # candidates t + g .. n - 1
    total = left + right
    if n and total.min() == 0:  # n == 1: no other step exists
        return t
    u = rng.integers(0, total) if n else t
    return np.where(u < left, u, t + g + (u - left))


class _StepView:
    """Stands in for an episode's (T, C, h, w) map array in ``DemoSet.batch``: step t reads ``base[index[t]]``,
    mirrored if asked (reads stay lazy, so memory-mapped files are not loaded whole)."""

    def __init__(self, base, index: np.ndarray | None = None, mirror: bool = False):
        self.base, self.index, self.mirror = base, index, mirror
        self.shape, self.dtype = base.shape, base.dtype

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, t):
        x = np.asarray(self.base[t if self.index is None else self.index[t]])
        return np.ascontiguousarray(mirror_maps(x)) if self.mirror else x


def with_maps(data, condition: str, rng: np.random.Generator | None = None, min_gap: int = 10):
    """A shallow copy of a ``DemoSet`` whose maps are ``intact``, ``mirrored`` or from an ``other_step``."""
    if condition == "intact":
        return data
    view = copy.copy(data)
    view.episodes = []
    for a in data.episodes:
        index = other_step_indices(len(a["action"]), rng, min_gap) if condition == "other_step" else None
        if condition not in ("mirrored", "other_step"):
            raise ValueError(f"unknown map condition {condition!r}")
        view.episodes.append({**a, **{k: _StepView(a[k], index, condition == "mirrored") for k in MAP_KEYS if k in a}})
    return view


@dataclass(frozen=True)
class MapControls:
    """Held-out action accuracy / balanced accuracy of a checkpoint under three map conditions (None: n/a)."""

    checkpoint: str
    model: str
    """Model preset name."""
    uses_maps: bool
    """The model reads I_u or I_cog; False: every accuracy is None."""
    episodes: int
    """Held-out episodes evaluated."""
    steps: int
    accuracy: dict[str, float | None]
    """``intact`` / ``mirrored`` / ``other_step`` -> fraction of steps whose argmax matches the expert label."""
    balanced_accuracy: dict[str, float | None]
    """The same, averaged over the expert's action classes."""


CONDITIONS = ("intact", "mirrored", "other_step")


def map_controls(checkpoint, data, seed: int = 0, min_gap: int = 10, max_episodes: int = 200,
                 device: str = "cpu") -> MapControls:
    """Load ``checkpoint`` and evaluate it on ``data`` (a ``DemoSet``, held-out part) under :data:`CONDITIONS`."""
    model, _ = load_policy(checkpoint, device)
    cfg = model.config
    n_eps = min(data.n_episodes, max_episodes)
    steps = int(data.lengths[:n_eps].sum())
    if not cfg.uses_memory_maps:
        none = dict.fromkeys(CONDITIONS)
        return MapControls(str(checkpoint), cfg.name, False, n_eps, steps, none, dict(none))
    data.check_layout(cfg)
    rng = np.random.default_rng(seed)
    acc, bal = {}, {}
    for cond in CONDITIONS:
        res = held_out_accuracy(model, with_maps(data, cond, rng, min_gap), cfg, device, max_episodes=max_episodes)
        acc[cond], bal[cond] = res["action_accuracy"], res["balanced_accuracy"]
    return MapControls(str(checkpoint), cfg.name, True, n_eps, steps, acc, bal)


# --- after a blocked move -----------------------------------------------------------------------
BLOCKED_SLACK = 0.96
"""A forward move that advanced less than this fraction of ``forward_step`` was blocked."""


def blocked_steps(data, forward_step: float, forward: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(episode, step) (K,), (K,) of every step t + 1 whose step t executed ``forward`` and moved less than
    :data:`BLOCKED_SLACK` x ``forward_step`` in xy (from the stored poses)."""
    eps, steps = [], []
    for e, a in enumerate(data.episodes):
        executed = np.asarray(a["executed"] if "executed" in a else a["action"])
        moved = np.linalg.norm(np.diff(np.asarray(a["pose"], dtype=np.float64)[:, :2], axis=0), axis=1)
        t = np.nonzero((executed[:-1] == forward) & (moved < BLOCKED_SLACK * forward_step))[0]
        eps.append(np.full(len(t), e, dtype=np.int64))
        steps.append((t + 1).astype(np.int64))
    if not eps:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    return np.concatenate(eps), np.concatenate(steps)


@dataclass(frozen=True)
class AfterBlocked:
    """What the expert and a checkpoint do at the demonstration steps right after a blocked forward move."""

    checkpoint: str
    model: str
    """Model preset name."""
    steps: int
    """Steps right after a blocked forward move."""
    expert_forward: float | None
    """Share of them whose expert label is forward (None: no such step)."""
    policy_forward: float | None
    """The checkpoint's mean P(forward) there."""
    policy_argmax_forward: float | None
    """Share of them where forward is the checkpoint's most likely action."""


def after_blocked(checkpoint, data, forward_step: float, forward: int = 0, device: str = "cpu") -> AfterBlocked:
    """:class:`AfterBlocked` of ``checkpoint`` on ``data`` (a ``DemoSet``). Each episode holding such a step is run
    whole through ``forward_sequence``, so a recurrent policy sees the history it would have had."""
    model, _ = load_policy(checkpoint, device)
    cfg = model.config
    data.check_layout(cfg)
    eps, steps = blocked_steps(data, forward_step, forward)
    if not len(eps):
        return AfterBlocked(str(checkpoint), cfg.name, 0, None, None, None)
    labels, p_fwd, top = [], [], []
    model.eval()
    with torch.no_grad():
        for e in np.unique(eps):
            t = np.arange(data.lengths[e])
            batch = data.batch(np.full((len(t), 1), e), t[:, None], cfg, device)
            out = model.forward_sequence(batch.inp, model.initial_state(1, device),
                                         torch.zeros(len(t), 1, dtype=torch.bool, device=device))
            probs = out.logits.float().softmax(-1).reshape(len(t), -1).cpu().numpy()
            at = steps[eps == e]
            labels.append(batch.action.reshape(-1).cpu().numpy()[at] == forward)
            p_fwd.append(probs[at, forward])
            top.append(probs[at].argmax(-1) == forward)
    mean = lambda xs: float(np.concatenate(xs).mean())  # noqa: E731
    return AfterBlocked(str(checkpoint), cfg.name, len(eps), mean(labels), mean(p_fwd), mean(top))


def format_after_blocked(ab: AfterBlocked) -> str:
    """One Markdown table row set: expert and policy forward rates right after a blocked move."""
    return (f"At the {ab.steps} demonstration steps right after a blocked forward move (`{ab.checkpoint}`, {ab.model})\n\n"
            "| expert label forward % | policy mean P(forward) % | policy argmax forward % |\n|---|---|---|\n"
            f"| {fmt(ab.expert_forward, '.1f', 100)} | {fmt(ab.policy_forward, '.1f', 100)} | "
            f"{fmt(ab.policy_argmax_forward, '.1f', 100)} |\n")


# --- previous-action probe ----------------------------------------------------------------------
def pool_i_u(i_u: np.ndarray, grid: tuple[int, int] = (5, 6)) -> np.ndarray:
    """I_u (N, 1, h, w) -> (N, gh * gw): log1p of the mean of each block of a gh x gw grid (row-major)."""
    x = np.asarray(i_u, dtype=np.float32).mean(axis=1)
    n, h, w = x.shape
    rows = np.linspace(0, h, grid[0] + 1).round().astype(int)
    cols = np.linspace(0, w, grid[1] + 1).round().astype(int)
    s = np.add.reduceat(np.add.reduceat(x, rows[:-1], axis=1), cols[:-1], axis=2)
    area = np.outer(np.diff(rows), np.diff(cols))
    return np.log1p(np.maximum(s / area, 0.0)).reshape(n, -1)


def cog_norm(i_cog: np.ndarray) -> np.ndarray:
    """I_cog (N, C, h, w) -> (N,): the mean over pixels of the feature vector's L2 norm."""
    return np.sqrt((np.asarray(i_cog, dtype=np.float32) ** 2).sum(axis=1)).mean(axis=(1, 2))


def probe_samples(data, max_steps: int, rng: np.random.Generator, with_cog: bool = False):
    """(X (N, 30[+1]), y (N,) executed action at t - 1, groups (N,) scene) for steps t >= 1, at most ``max_steps``."""
    pairs = np.array([(e, t) for e, n in enumerate(data.lengths) for t in range(1, int(n))], dtype=np.int64).reshape(-1, 2)
    if len(pairs) > max_steps:
        pairs = pairs[np.sort(rng.choice(len(pairs), max_steps, replace=False))]
    xs, ys, gs = [], [], []
    for e in np.unique(pairs[:, 0]):
        a, ts = data.episodes[e], pairs[pairs[:, 0] == e, 1]
        if "executed" not in a:
            raise DataError(data.metas[e].get("key", data.root), "no 'executed' array (collected before it was stored)")
        f = pool_i_u(a["i_u"][ts])
        if with_cog:
            f = np.concatenate([f, np.log1p(cog_norm(a["i_cog"][ts]))[:, None]], axis=1)
        xs.append(f)
        ys.append(np.asarray(a["executed"], dtype=np.int64)[ts - 1])
        gs += [str(data.metas[e].get("scene", ""))] * len(ts)
    if not xs:
        raise ProbeUnavailable(data.root, f"no steps to probe in part {data.part!r}")
    return np.concatenate(xs), np.concatenate(ys), np.array(gs)


@dataclass(frozen=True)
class ProbeScores:
    """Leave-one-house-out scores pooled over the held-out predictions of every fold."""

    accuracy: float
    balanced_accuracy: float
    """Mean per-class recall (chance: 1 / number of classes)."""
    majority_accuracy: float
    """Accuracy of predicting each fold's training majority class."""


def fit_probe(x: np.ndarray, y: np.ndarray, groups: np.ndarray) -> ProbeScores:
    """Standardised multinomial logistic regression (class-balanced weights), leave-one-group-out."""
    if len(np.unique(groups)) < 2:
        raise ProbeUnavailable(None, f"the probe needs episodes from at least 2 houses (leave-one-house-out), "
                                     f"found {len(np.unique(groups))}")
    pred, base = np.empty_like(y), np.empty_like(y)
    for tr, te in LeaveOneGroupOut().split(x, y, groups):
        classes, counts = np.unique(y[tr], return_counts=True)
        base[te] = classes[counts.argmax()]
        if len(classes) < 2:
            pred[te] = classes[0]
            continue
        clf = make_pipeline(StandardScaler(), LogisticRegression(max_iter=1000, class_weight="balanced"))
        pred[te] = clf.fit(x[tr], y[tr]).predict(x[te])
    return ProbeScores(float((pred == y).mean()), float(balanced_accuracy_score(y, pred)), float((base == y).mean()))


def shuffle_within_groups(x: np.ndarray, groups: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Rows of ``x`` permuted among the rows of the same group (a house keeps its maps, steps lose theirs)."""
    out = x.copy()
    for g in np.unique(groups):
        idx = np.flatnonzero(groups == g)
        out[idx] = x[rng.permutation(idx)]
    return out


@dataclass(frozen=True)
class ProbeResult:
    """Previous-action probe on the maps and on shuffled maps (the control)."""

    features: str
    """``i_u_5x6_log1p`` (+ ``cog_norm``)."""
    steps: int
    """Steps probed (after subsampling)."""
    houses: int
    classes: tuple[int, ...]
    """Action ids that occur as targets."""
    class_fractions: tuple[float, ...]
    chance_balanced_accuracy: float
    maps: ProbeScores
    shuffled: ProbeScores


def previous_action_probe(data, seed: int = 0, max_steps: int = 20_000, with_cog: bool = False) -> ProbeResult:
    """Probe a ``DemoSet``'s maps at step t for the executed action at t - 1 (see the module docstring)."""
    rng = np.random.default_rng(seed)
    x, y, groups = probe_samples(data, max_steps, rng, with_cog)
    classes, counts = np.unique(y, return_counts=True)
    return ProbeResult("i_u_5x6_log1p" + ("+cog_norm" if with_cog else ""), len(y), len(np.unique(groups)),
                       tuple(int(c) for c in classes), tuple(float(c) for c in counts / len(y)), 1.0 / len(classes),
                       fit_probe(x, y, groups), fit_probe(shuffle_within_groups(x, groups, rng), y, groups))


# --- formatting ---------------------------------------------------------------------------------
def format_map_controls(mc: MapControls) -> str:
    """Markdown table: held-out accuracy and balanced accuracy per map condition."""
    lines = [f"Held-out action accuracy of `{mc.checkpoint}` ({mc.model}; {mc.episodes} episodes, {mc.steps} steps)"
             + ("" if mc.uses_maps else ": n/a, the model reads no memory maps") + "\n",
             "| maps | accuracy % | balanced accuracy % |", "|---|---|---|"]
    label = {"intact": "intact", "mirrored": "mirrored left-right", "other_step": "of another step (>= 10 away)"}
    lines += [f"| {label[c]} | {fmt(mc.accuracy[c], '.1f', 100)} | {fmt(mc.balanced_accuracy[c], '.1f', 100)} |"
              for c in CONDITIONS]
    return "\n".join(lines) + "\n"


def format_probe(p: ProbeResult, action_names: tuple[str, ...]) -> str:
    """Markdown table: probe and control scores, with the chance levels."""
    share = ", ".join(f"{action_names[c] if c < len(action_names) else c} {100 * f:.1f}%"
                      for c, f in zip(p.classes, p.class_fractions))
    lines = [f"Previous-action probe ({p.features} -> executed action at t - 1; {p.steps} steps, {p.houses} houses, "
             f"leave-one-house-out; targets: {share}; chance balanced accuracy {100 * p.chance_balanced_accuracy:.1f}%)\n",
             "| maps | accuracy % | balanced accuracy % | majority-class accuracy % |", "|---|---|---|---|"]
    for name, s in (("intact", p.maps), ("shuffled within house (control)", p.shuffled)):
        lines.append(f"| {name} | {100 * s.accuracy:.1f} | {100 * s.balanced_accuracy:.1f} | {100 * s.majority_accuracy:.1f} |")
    return "\n".join(lines) + "\n"
