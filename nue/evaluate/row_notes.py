"""Notes under Table I about rows the paper has and we do not: its SLING rows (we wrap our own policies instead)
and its MSM row (the work could not be identified, docs/msm.md). Each note appears only when a related row of ours
is in the table."""

from __future__ import annotations

from collections.abc import Sequence

from nue.evaluate.table import TableRow, paper_table, split_seed
from nue.policy.last_mile import SLING_PREFIX


MEMORY_BASELINES: tuple[str, ...] = ("vgm", "nrns")
"""The paper's memory baselines with a row of ours (MSM has none: :func:`msm_note`)."""


def msm_note(rows: Sequence[TableRow], paper=None) -> str:
    """When some row is a memory baseline (VGM, NRNS): the paper's MSM row has no counterpart here, because the work
    could not be identified (docs/msm.md), with its total; else ''."""
    if not any(split_seed(r.method)[0] in MEMORY_BASELINES for r in rows):
        return ""
    paper = paper_table() if paper is None else paper
    total = paper.get("MSM", {}).get("total")
    theirs = f" (the paper's total: {total[0]:.2f}% SR, SPL {total[1]:.3f})" if total else ""
    return ("\n*MSM* (the paper's third memory baseline, its ref. 62, \"Multi-Storage Memory\"): not identified, so it "
            f"has no row of ours{theirs}; what was searched is in docs/msm.md. How VGM and NRNS are built and "
            "adapted to one 90-degree RGB-D camera: docs/vgm.md, docs/nrns.md.\n")


def sling_notes(rows: Sequence[TableRow], paper=None) -> str:
    """What the *SLING + X* rows are and the paper's SLING rows' totals (they have no counterpart here), with a blank
    line before, when some row is a ``sling+`` method; else ''."""
    if not any(split_seed(r.method)[0].startswith(SLING_PREFIX) for r in rows):
        return ""
    paper = paper_table() if paper is None else paper
    theirs = "; ".join(f"{name} {paper[name]['total'][0]:.2f}% SR, SPL {paper[name]['total'][1]:.3f}"
                       for name in ("SLING+DDPPO", "SLING+OVRL") if name in paper)
    return ("\n*SLING + X* rows: SLING's last-mile module (SIFT matches between the goal photo and the frame, the goal's "
            "pose by PnP with the depth, a point-goal controller on the robot's own depth-built map; "
            "`nue.policy.last_mile`) wrapped around our policy X, on the same episodes with the same per-episode seeds. "
            "The paper's SLING rows wrap DD-PPO (2.5 billion frames of reinforcement learning) and OVRL (an encoder "
            "pretrained on other data); neither can be had here (CPU only, nothing downloaded), so they have no row of "
            f"ours. The paper's totals: {theirs}.\n")
