"""The hand-off issue's targets (issue 37), checked on every set from the records: the numbers the recipe's NUE was
chosen to reach, each with its measurement and a verdict.

1. **Near misses halved**: NUE's near misses, failures that came within ``near`` = 2 m geodesic of the goal
   (:class:`~nue.evaluate.handoff.HandoffConfig`; the closest approach of :mod:`nue.evaluate.handoff`), at most half
   (rounded down) of the earlier recipe's NUE's on the same episodes (:data:`EARLIER`: v6 had 25 on ``val252`` -> at
   most 12). With several training seeds the count is their mean.
2. **Never near no more often than without f_u**: NUE's *never near* failures at most the no-f_u ablation's
   (``abl_at_cbam``; seed means), with the paired difference of the rates (:func:`~nue.evaluate.handoff.
   outcome_differences`).
3. **Explores more**: on the exploration benchmark (:mod:`nue.evaluate.exploration`) NUE's mean seen area at step
   500 at least 1.3x the no-f_u ablation's, with the seed-pooled interval of the ratio above 1.
4. **SR**: NUE's seed-mean SR at least 90% on ``val252``.
5. **Ahead of the no-f_u ablation and of FR**: the seed-pooled paired SR interval above 0
   (:func:`~nue.evaluate.generalisation.pair_differences`); the section also says whether each cell survives a
   Holm-Bonferroni correction across these cells.

Every target is shown on every set where its rows ran; 1, 2 and 5 have a verdict on each, 3 on each set of starts of
the exploration benchmark, 4 on ``val252`` only. Earlier recipes' rows (``*_v<N>``) enter only as 1's reference.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Mapping, Sequence

from nue.evaluate.handoff import HandoffConfig, outcome_differences, record_handoff
from nue.evaluate.table import canonical_method, split_seed
from nue.sim.record import EpisodeRecord

NUE = "nue"
NO_FU = "abl_at_cbam"
"""The ablation without the uncertainty branch f_u (f_u=off AT=on CBAM=on)."""
FR = "fr"
EARLIER = "v6"
"""The recipe whose NUE the near-miss target halves (its rows are ``nue_v6``)."""
SR_TARGET, SR_SET = 0.90, "val252"
RATIO_TARGET, EXPLORE_STEP = 1.3, 500


@dataclass(frozen=True)
class Cell:
    """One target on one set."""

    text: str
    """What was measured."""
    met: bool | None
    """The verdict; None where the target has none on this set."""

    def markdown(self) -> str:
        verdict = "" if self.met is None else ": **met**" if self.met else ": not met"
        return self.text + verdict


def _runs(records: Sequence[EpisodeRecord], method: str) -> dict[int, dict[tuple[str, str], EpisodeRecord]]:
    """Seed index -> (scene, episode id) -> record of ``method``'s training-seed runs."""
    by: dict[int, dict[tuple[str, str], EpisodeRecord]] = {}
    seeds = {m: split_seed(m) for m in {r.method for r in records}}
    ours = {m: k for m, (base, k) in seeds.items() if canonical_method(base) == method}
    for r in records:
        if r.method in ours:
            by.setdefault(ours[r.method], {})[(r.scene, str(r.episode_id))] = r
    return by


NEAR_MISS = "near_miss"
"""The count :func:`_mean_count` gives for near misses (failed, came within ``near`` of the goal)."""


def _counted(r: EpisodeRecord, outcome: str) -> bool:
    h = record_handoff(r)
    if h is None:
        return False
    if outcome == NEAR_MISS:
        return not r.success and h.closest_geodesic <= HandoffConfig().near
    return h.outcome == outcome


def _mean_count(runs: Mapping[int, Mapping[tuple[str, str], EpisodeRecord]], keys, outcome: str) -> tuple[float, list[int]]:
    """The mean over the runs of the episodes among ``keys`` counted as ``outcome`` (a hand-off class or
    :data:`NEAR_MISS`), and each run's count."""
    counts = [sum(_counted(run[k], outcome) for k in keys) for run in runs.values()]
    return sum(counts) / len(counts), counts


def _with_handoff(runs) -> set[tuple[str, str]]:
    """The episodes every run ran and measured the hand-off of."""
    keys = [{k for k, r in run.items() if record_handoff(r) is not None} for run in runs.values()]
    return set.intersection(*keys) if keys else set()


def _counts_text(mean: float, counts: list[int]) -> str:
    return f"{mean:.1f} ({', '.join(map(str, counts))})" if len(counts) > 1 else f"{counts[0]}"


def near_miss_cell(records: Sequence[EpisodeRecord]) -> Cell | None:
    nue, earlier = _runs(records, NUE), _runs(records, f"{NUE}_{EARLIER}")
    keys = _with_handoff(nue)
    if not keys:
        return None
    if not earlier or not (keys & _with_handoff(earlier)):
        mean, counts = _mean_count(nue, sorted(keys), NEAR_MISS)
        return Cell(f"{_counts_text(mean, counts)} of {len(keys)}; no {EARLIER} rows to halve", None)
    keys &= _with_handoff(earlier)
    mean, counts = _mean_count(nue, sorted(keys), NEAR_MISS)
    ref, ref_counts = _mean_count(earlier, sorted(keys), NEAR_MISS)
    limit = math.floor(ref / 2)
    return Cell(f"{_counts_text(mean, counts)} of {len(keys)}; {EARLIER}: {_counts_text(ref, ref_counts)} -> at most "
                f"{limit}", mean <= limit)


def never_near_cell(records: Sequence[EpisodeRecord]) -> Cell | None:
    nue, ablated = _runs(records, NUE), _runs(records, NO_FU)
    keys = _with_handoff(nue) & _with_handoff(ablated)
    if not keys:
        return None
    mean, counts = _mean_count(nue, sorted(keys), "never_near")
    ref, ref_counts = _mean_count(ablated, sorted(keys), "never_near")
    two = [r for r in records if canonical_method(split_seed(r.method)[0]) in (NUE, NO_FU)]
    d = next(d for d in outcome_differences(two, reference=NUE, classes=("never_near",)) if d.method == NO_FU)
    return Cell(f"{_counts_text(mean, counts)} vs {_counts_text(ref, ref_counts)} of {len(keys)} (NUE − no f_u: "
                f"{100 * d.diff:+.1f} points [{100 * d.lo:+.1f}, {100 * d.hi:+.1f}])", mean <= ref)


def sr_cell(records: Sequence[EpisodeRecord], name: str) -> Cell | None:
    nue = _runs(records, NUE)
    keys = set.intersection(*(set(run) for run in nue.values())) if nue else set()
    if not keys:
        return None
    srs = [sum(bool(run[k].success) for k in keys) / len(keys) for run in nue.values()]
    mean = sum(srs) / len(srs)
    text = f"{100 * mean:.1f}%" + (f" ({', '.join(f'{100 * s:.1f}' for s in srs)})" if len(srs) > 1 else "")
    return Cell(f"{text} of {len(keys)}", mean >= SR_TARGET if name == SR_SET else None)


def explore_cell(records: Sequence[EpisodeRecord]) -> Cell | None:
    from nue.evaluate.exploration import exploration_summary

    rows = {r.method: r for r in exploration_summary(records, reference=NO_FU, steps=(EXPLORE_STEP,))}
    ratio = rows[NUE].ratio.get(EXPLORE_STEP) if NUE in rows else None
    if ratio is None:
        return None
    r, lo, hi = ratio
    return Cell(f"{r:.2f} [{lo:.2f}, {hi:.2f}] ({rows[NUE].runs} starts, {rows[NUE].seeds} x {rows[NO_FU].seeds} "
                "seeds)", r >= RATIO_TARGET and lo > 1)


def handoff_targets_markdown(sets: Mapping[str, Sequence[EpisodeRecord]],
                             explore: Mapping[str, Sequence[EpisodeRecord]] | None = None) -> str:
    """RESULTS.md's section on the hand-off targets over ``sets`` (name -> goal-episode records) and ``explore``
    (name of the set of starts -> exploration benchmark records); '' when no target compares NUE with anything (its
    SR alone, or its near misses without the earlier recipe's)."""
    from nue.evaluate.generalisation import pair_differences, pairs_holm

    explore = explore or {}
    names = list(dict.fromkeys([*sets, *explore]))
    pairs = [(NUE, NO_FU), (NUE, FR)]
    diffs = pair_differences(sets, pairs)
    rejected = pairs_holm(diffs)

    def ahead(pair, name) -> Cell | None:
        d = diffs.get(pair, {}).get(name)
        if d is None:
            return None
        after = "" if d.lo <= 0 or rejected[(pair, name)] else " (not after Holm)"
        return Cell(f"{100 * d.mean:+.1f} points [{100 * d.lo:+.1f}, {100 * d.hi:+.1f}] ({d.n_pairs} episodes, "
                    f"{d.seeds} x {d.reference_seeds} seeds){after}", d.lo > 0)

    def on(cell, records) -> Cell | None:
        return None if records is None else cell(records)

    rows = [
        (f"NUE's near misses (failed within 2 m of the goal) at most half of {EARLIER}'s NUE's",
         lambda n: on(near_miss_cell, sets.get(n))),
        ("NUE's *never near* failures at most the no-f_u ablation's", lambda n: on(never_near_cell, sets.get(n))),
        (f"NUE's seen area at step {EXPLORE_STEP} of the exploration benchmark at least {RATIO_TARGET:g}x the no-f_u "
         "ablation's, interval above 1", lambda n: on(explore_cell, explore.get(n))),
        (f"NUE's SR at least {100 * SR_TARGET:.0f}% on `{SR_SET}` (seed mean; each seed's)",
         lambda n: on(lambda recs: sr_cell(recs, n), sets.get(n))),
        ("NUE ahead of the no-f_u ablation: paired ΔSR interval above 0", lambda n: ahead(pairs[0], n)),
        ("NUE ahead of FR: paired ΔSR interval above 0", lambda n: ahead(pairs[1], n)),
    ]
    grid = [(label, [cell_of(n) for n in names]) for label, cell_of in rows]
    grid = [(label, cells) for label, cells in grid if any(c is not None for c in cells)]
    if not any(c is not None and c.met is not None for label, cells in grid if label != rows[3][0] for c in cells):
        return ""  # no comparison (NUE's SR alone, near misses without the earlier recipe's): nothing to check
    verdicts = [c.met for _, cells in grid for c in cells if c is not None and c.met is not None]
    table = "\n".join(f"| {label} | " + " | ".join("–" if c is None else c.markdown() for c in cells) + " |"
                      for label, cells in grid)
    seeded = any(len(_runs(recs, m)) > 1 for recs in [*sets.values(), *explore.values()] for m in (NUE, NO_FU, FR))
    cells = sum(len(r) for r in diffs.values())
    return ("## The hand-off targets (issue 37)\n\n"
            "What the recipe's NUE was built to reach (`nue.evaluate.handoff_targets`), on every set where the rows "
            "ran: counts are failures of a run over the episodes every run compared ran"
            + (" (with several training seeds, their mean and each seed's in brackets)" if seeded else "")
            + "; the no-f_u ablation is f_u=off AT=on CBAM=on; intervals are 95% bootstraps over the episodes or starts"
            + (" (with several seeds on either side two-level: seeds, then episodes or starts)" if seeded else "")
            + ", 10,000 resamples, seed 0"
            + (f"; *not after Holm* marks a lead that does not survive a Holm-Bonferroni correction across the {cells} "
               "paired SR cells of this table" if cells else "")
            + f". Met: {sum(verdicts)} of {len(verdicts)}.\n\n"
            "| target | " + " | ".join(f"`{n}`" for n in names) + " |\n|" + "---|" * (len(names) + 1) + "\n"
            + table + "\n")
