"""The paper's two claims on Table I, checked step by step with paired differences on every set (seeds pooled,
:func:`nue.evaluate.generalisation.pair_differences`); a step *holds* on a set when its interval lies above 0 and it
survives a Holm-Bonferroni correction across all the steps and sets of its table
(:func:`nue.evaluate.generalisation.pairs_holm`).

1. The ablation ordering: NUE (full) > each single ablation > all ablated. A *single ablation* removes one of the
   three parts (the uncertainty branch f_u, the attention AT, CBAM): ``abl_at_cbam`` (no f_u), ``abl_fu_cbam`` (no
   AT), ``abl_fu_at`` (no CBAM); *all ablated* is ``abl_none``. ``abl_fu`` (f_u alone) removes two parts and is no
   step of the ordering.
2. NUE ahead of every baseline: FR, Nav-A3C, the memory baselines VGM and NRNS, and SLING's last mile around FR and
   Nav-A3C (MSM has no row: docs/msm.md).

Beside them, what NUE's two controls say (:func:`controls_markdown`): a lead over the swapped-maps control
(``nue+swap``) that NUE reads its maps, and only a lead over the no-f_u ablation that it uses uncertainty.
"""

from __future__ import annotations

from typing import Mapping, Sequence

from nue.evaluate.generalisation import pair_differences, pairs_holm, pairs_markdown
from nue.evaluate.table import method_label
from nue.sim.record import EpisodeRecord

FULL = "nue"
ALL_OFF = "abl_none"
SINGLE = (("abl_at_cbam", "f_u"), ("abl_fu_cbam", "AT"), ("abl_fu_at", "CBAM"))
"""Each single ablation's row and the part it removes."""
STEPS = tuple((FULL, a) for a, _ in SINGLE) + tuple((a, ALL_OFF) for a, _ in SINGLE)
"""The ordering's six steps ``(better, worse)``: full over each single ablation, each single ablation over all-off."""


def _compared(sets: Mapping[str, Sequence[EpisodeRecord]], pairs):
    """``(diffs, rejected)``: the paired differences of ``pairs`` on every set where both rows ran, and per
    ``(pair, set)`` whether "no difference" is rejected after Holm across them all."""
    diffs = pair_differences(sets, pairs)
    return diffs, pairs_holm(diffs)


def step_verdicts(sets: Mapping[str, Sequence[EpisodeRecord]]):
    """``(diffs, holds)``: :func:`~nue.evaluate.generalisation.pair_differences` of the :data:`STEPS` on ``sets``, and
    per ``(step, set)`` where both rows ran whether the step holds (interval above 0, and after Holm)."""
    diffs, rejected = _compared(sets, STEPS)
    return diffs, {(step, name): bool(d.lo > 0 and rejected[(step, name)]) for step, row in diffs.items()
                   for name, d in row.items()}


def ablation_ordering_markdown(sets: Mapping[str, Sequence[EpisodeRecord]]) -> str:
    """RESULTS.md's section on the paper's ordering over ``sets`` (name -> records; earlier recipes' rows are left
    out); '' when no step ran on any set."""
    diffs, holds = step_verdicts(sets)
    if not diffs:
        return ""
    removed = dict(SINGLE)
    lines = []
    for name in sets:
        ran = [s for s in STEPS if (s, name) in holds]
        if not ran:
            continue
        verdict = "holds" if len(ran) == len(STEPS) and all(holds[(s, name)] for s in ran) else "is not shown"

        def listed(steps, side):
            held = [removed[s[side]] for s in steps if holds[(s, name)]]
            return f"{len(held)} of {len(steps)}" + (f" (without {', '.join(held)})" if held else "")

        upper = listed([s for s in ran if s[0] == FULL], 1)
        lower = listed([s for s in ran if s[1] == ALL_OFF], 0)
        lines.append(f"- `{name}`: the ordering {verdict}; full > single ablation holds for {upper}, single "
                     f"ablation > all ablated for {lower}.")
    return ("## The paper's ablation ordering: full > each single ablation > all ablated\n\n"
            "A single ablation removes one part: f_u=off AT=on CBAM=on (without f_u), f_u=on AT=off CBAM=on (without "
            "AT), f_u=on AT=on CBAM=off (without CBAM); all ablated is f_u=off AT=off CBAM=off. f_u alone (f_u=on "
            "AT=off CBAM=off) removes two parts and is no step of the ordering. A step holds on a set when its "
            "interval lies above 0 and survives the Holm correction across the table's cells; the ordering holds "
            "when all six do.\n\n" + pairs_markdown(sets, STEPS, diffs=diffs) + "\n" + "\n".join(lines) + "\n")


BASELINES = ("fr", "nav_a3c", "vgm", "nrns", "sling+fr", "sling+nav_a3c")
"""The rows NUE is claimed to beat (those present in the records are compared)."""


def baselines_markdown(sets: Mapping[str, Sequence[EpisodeRecord]]) -> str:
    """RESULTS.md's section on NUE against every baseline over ``sets``; '' when NUE and no baseline ran together."""
    pairs = [(FULL, b) for b in BASELINES]
    diffs, rejected = _compared(sets, pairs)
    if not diffs:
        return ""
    lines = []
    for name in sets:
        ran = [p for p in pairs if name in diffs.get(p, {})]
        if not ran:
            continue
        ahead = [method_label(b) for (_, b) in ran if diffs[(FULL, b)][name].lo > 0 and rejected[((FULL, b), name)]]
        behind = [method_label(b) for (_, b) in ran if diffs[(FULL, b)][name].hi < 0 and rejected[((FULL, b), name)]]
        lines.append(f"- `{name}`: NUE ahead of {len(ahead)} of {len(ran)} baselines"
                     + (f" ({', '.join(ahead)})" if ahead else "")
                     + (f"; behind {', '.join(behind)}" if behind else "") + ".")
    return ("## NUE against every baseline\n\n"
            "The paper's claim: NUE (full) ahead of FR, Nav-A3C, the memory baselines VGM and NRNS and SLING's last "
            "mile around FR and Nav-A3C (MSM has no row: docs/msm.md). NUE is ahead (or behind) on a set when the "
            "interval excludes 0 on that side and survives the Holm correction across the table's cells.\n\n"
            + pairs_markdown(sets, pairs, diffs=diffs) + "\n" + "\n".join(lines) + "\n")


SWAPPED = "nue+swap"
"""NUE fed the maps of another episode of the same house (the swapped-maps control, every training seed)."""
NO_FU = SINGLE[0][0]
"""The single ablation without f_u (NUE without its uncertainty branch)."""
CONTROLS = ((FULL, SWAPPED, "reads its maps"), (FULL, NO_FU, "uses uncertainty"))
"""The two controls ``(better, control, what a resolved lead says)``; nothing else earns either phrase."""


def controls_markdown(sets: Mapping[str, Sequence[EpisodeRecord]]) -> str:
    """RESULTS.md's section on what NUE's lead over its two controls says, per set: over the swapped-maps control
    that it *reads its maps*, over the no-f_u ablation that it *uses uncertainty*; '' when neither ran beside NUE."""
    pairs = [(a, b) for a, b, _ in CONTROLS]
    diffs, rejected = _compared(sets, pairs)
    if not diffs:
        return ""
    lines = []
    for name in sets:
        said = []
        for a, b, phrase in CONTROLS:
            d = diffs.get((a, b), {}).get(name)
            if d is None:
                continue
            shown = "not shown" if d.lo <= 0 else "shown" if rejected[((a, b), name)] else "not shown after Holm"
            said.append(f"{phrase}: {shown} ({method_label(a)} − {method_label(b)} "
                        f"{100 * d.mean:+.1f} points [{100 * d.lo:+.1f}, {100 * d.hi:+.1f}])")
        if said:
            lines.append(f"- `{name}`: " + "; ".join(said) + ".")
    return ("## What NUE's controls say: it reads its maps, it uses uncertainty\n\n"
            "Two controls, each NUE with one thing taken away. The swapped-maps control (`nue+swap`, every training "
            "seed) is NUE fed the memory maps recorded along the expert's run of another episode of the same house: a "
            "lead of NUE over it says that NUE *reads its maps*, not what in them it uses. The no-f_u ablation "
            "(f_u=off AT=on CBAM=on) is NUE without its uncertainty branch: only a lead over it says that NUE *uses "
            "uncertainty*. Each is shown on a set when the interval lies above 0 and survives the Holm correction "
            "across the table's cells.\n\n" + pairs_markdown(sets, pairs, diffs=diffs) + "\n" + "\n".join(lines) + "\n")
