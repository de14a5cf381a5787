"""The text of RESULTS.md, a pure function of episode records and metadata: the main episode set's Table I
next to the paper, its ordering, the earlier recipes' rows, paired differences, coverage and closed-loop diagnostics,
then one section per further episode set (``results/records_<set>.jsonl``), the further sets pooled, the paper's two
claims (ablation ordering, NUE ahead of every baseline) step by step on every set, what NUE's controls say (it reads
its maps, it uses uncertainty), the hand-off targets, the
generalisation to held-out styles, Table I's recipe trained again (when the generalisation manifest names replicates),
then the discussion.
The tables themselves are :mod:`nue.evaluate.report`'s. A method trained with several seeds (runs ``<model>@s<k>``) is
one row of seed means in each Table I, and its paired differences pool seeds x episodes (:mod:`nue.evaluate.paired`);
the notes on seeds appear only then, so a table of single runs reads as before."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Mapping, Sequence

from nue.evaluate import coverage as cov
from nue.evaluate.handoff_targets import handoff_targets_markdown
from nue.evaluate.paper_claims import ablation_ordering_markdown, baselines_markdown, controls_markdown
from nue.evaluate.replicate import replicate_section
from nue.evaluate.report import (
    NOTES, handoff_markdown, ordering_markdown, build_table, canonical_method, closed_loop_markdown, coverage_curves, format_counts_markdown,
    format_markdown, method_label, paired_differences, paired_markdown, paper_table, seed_notes, unreachable_markdown,
)
from nue.evaluate.table import is_earlier_recipe  # noqa: F401  (re-exported)
from nue.sim.record import EpisodeRecord


def _counts_markdown(records: Sequence[EpisodeRecord], rows) -> str:
    """Episodes per cell, then the episodes left out of DTS (if any)."""
    left_out = unreachable_markdown(records)
    return format_counts_markdown(rows) + (f"\n{left_out}" if left_out else "")


def _not_extended(sets: Mapping[str, Sequence[EpisodeRecord]]) -> dict[str, Sequence[EpisodeRecord]]:
    """``sets`` without those another of them extends (``val`` beside ``val252``: its episodes are ``val252``'s)."""
    from nue.sim.episode_sets import EPISODE_SETS

    extended = {EPISODE_SETS[n].extends for n in sets if n in EPISODE_SETS}
    return {n: recs for n, recs in sets.items() if n not in extended}


MAIN_SET = "Table I's episodes"
"""The name the main records go by among the sets :func:`pooled_section_markdown` pools."""

def _comparison_parts(rows, paper, records: Sequence[EpisodeRecord], where: str) -> list[str]:
    """The ordering against the paper's (of ``rows``), the paired differences to NUE and the coverage (of
    ``records``) of a further set's section, each titled with ``where`` (`` on `val252` `` or ``, pooled``)."""
    parts = []
    ordering = ordering_markdown(rows, paper)
    if ordering:
        parts.append(f"Ordering by total SR{where}:\n\n{ordering}")
    diffs = paired_differences(records)
    if diffs:
        parts.append(f"Paired differences to NUE{where} (95% paired bootstrap):\n\n{paired_markdown(diffs)}")
    curves = coverage_curves(records)
    if curves:
        parts.append(f"Exploration coverage{where} (mean seen floor area, m²; earlier recipes left out, as in the "
                     "main set's table):\n\n"
                     f"{cov.format_coverage_markdown(curves, {k: method_label(k) for k in curves})}")
    return parts


def set_section_markdown(name: str, records: Sequence[EpisodeRecord], description: str = "",
                         task: str = "paper") -> str:
    """RESULTS.md's section of a further episode set ``name``: Table I next to the paper, the episodes per
    cell, the ordering against the paper's, the paired differences to NUE, coverage and the closed-loop
    diagnostics, all from ``records`` (that set's). Earlier recipes' ``*_v<N>`` rows are left out of the
    table and the ordering, as in the main one, and get a table of their own after the episode counts."""
    current = [r for r in records if not is_earlier_recipe(r.method)]
    earlier = [r for r in records if is_earlier_recipe(r.method)]
    rows = build_table(current)
    paper = paper_table()
    parts = [f"## Table I on `{name}`" + (f": {description}" if description else "") + "\n\n"
             f"{format_markdown(rows, paper)}\n{NOTES}\n{seed_notes(rows)}\n"
             f"Episodes per cell (successes / episodes):\n\n{_counts_markdown(current, rows)}"]
    if earlier:
        parts.append(f"Earlier recipes on `{name}` (`<method>_v<N>`, see \"Earlier recipes\" above; kept in the "
                     f"comparisons below):\n\n{format_markdown(build_table(earlier))}")
    parts += _comparison_parts(rows, paper, records, f" on `{name}`")
    if records:
        parts.append(f"Closed-loop diagnostics on `{name}`:\n\n{closed_loop_markdown(records, task)}")
    handoff = handoff_markdown(records)
    if handoff:
        parts.append(f"Exploration -> exploitation hand-off on `{name}`:\n\n{handoff}")
    return "\n".join(parts)


def pooled_section_markdown(sets: Mapping[str, Sequence[EpisodeRecord]]) -> str:
    """RESULTS.md's section pooling two or more further sets: the methods (earlier recipes left out) that ran
    every set, each set's episodes all counted once, so a paired difference rests on the sum of the sets'
    episodes (pairs matched on scene and episode id; the sets' houses differ). Table I, the ordering, the
    paired differences to NUE and coverage. A set whose episodes (scene, episode id) all lie in another one is left
    out (``val`` inside ``val252``). Empty with fewer than two sets left or no method common to all."""
    keys = {name: {(r.scene, r.episode_id) for r in recs} for name, recs in sets.items()}
    order = list(sets)
    # a set whose episodes all lie in another (val in val252) would count them twice: keep the larger one
    # (of two equal ones the later: a further set over the main records, which come first)
    sets = {n: sets[n] for i, n in enumerate(order)
            if not any(keys[n] < keys[m] or (keys[n] == keys[m] and j > i) for j, m in enumerate(order) if m != n)}
    if len(sets) < 2:
        return ""
    per_set = {name: [r for r in recs if not is_earlier_recipe(r.method)] for name, recs in sets.items()}
    common = set.intersection(*({canonical_method(r.method) for r in recs} for recs in per_set.values()))
    pooled = [r for recs in per_set.values() for r in recs if canonical_method(r.method) in common]
    if not pooled:
        return ""
    names = " + ".join(n if n == MAIN_SET else f"`{n}`" for n in sets)  # a named main set in backticks too
    rows = build_table(pooled)
    paper = paper_table()
    both = "both" if len(sets) == 2 else f"all {len(sets)}"
    parts = [f"## Pooled: {names}\n\nThe methods that ran {both} sets, their episodes pooled (each set's houses "
             f"are its own, so no episode is counted twice); the paired differences rest on every episode both a method "
             f"and NUE ran.\n\n{format_markdown(rows, paper)}"]
    return "\n".join(parts + _comparison_parts(rows, paper, pooled, ", pooled"))


def exploration_section_markdown(name: str, records: Sequence[EpisodeRecord], reference: str = "abl_at_cbam") -> str:
    """RESULTS.md's section of the exploration benchmark from the starts of set ``name`` (:mod:`nue.evaluate.exploration`)."""
    from nue.evaluate.exploration import exploration_summary, format_exploration_markdown

    rows = exploration_summary(records, reference)
    starts = len({(r.scene, r.episode_id) for r in records})
    labels = {m: method_label(canonical_method(m)) for m in {r.method for r in rows} | {reference}}
    return (f"## Exploration benchmark from `{name}`'s starts\n\nActive Neural SLAM's protocol on our houses: {starts} "
            f"starts of `{name}`, the goal photo of another house (nothing to find; success never ends a run), seen floor "
            "area (m², mean and 95% bootstrap interval over the starts), the mean fraction of the start's traversable "
            f"floor seen, and the ratio of means to {method_label(reference)} (95% paired bootstrap over the starts). "
            "`expert-explore`: frontier exploration on its own seen map; `random`: uniform random moves."
            + (" A method with several training seeds is one row: the seeds' mean over the starts every seed ran, its "
               "interval and ratio a two-level bootstrap (seeds, then starts)." if any(r.seeds > 1 for r in rows) else "")
            + "\n\n"
            f"{format_exploration_markdown(rows, reference, labels)}")


def committed_explore(root) -> dict[str, list[EpisodeRecord]]:
    """The exploration benchmark's committed records, ``results/explore_<set>.jsonl`` -> {set: records}."""
    from nue.evaluate.report import load_records
    from nue.sim.episode_sets import EPISODE_SETS

    base = Path(root) / "results"
    return {name: load_records(base / f"explore_{name}.jsonl") for name in EPISODE_SETS
            if (base / f"explore_{name}.jsonl").is_file()}


def render_results_md(records: Sequence[EpisodeRecord], meta: Mapping[str, object], task: str = "paper",
                      sets: Mapping[str, Sequence[EpisodeRecord]] | None = None, main_name: str = "",
                      explore: Mapping[str, Sequence[EpisodeRecord]] | None = None,
                      generalisation: str = "", held_out: HeldOutInputs | None = None) -> str:
    """The text of RESULTS.md, a pure function of the records and ``meta``.

    ``meta``: ``command``, ``date``, ``commit``, ``machine`` (shown first), any other keys
    (sorted). Methods named ``<method>_v<N>`` (:func:`is_earlier_recipe`) get their own table after
    Table I and stay in the paired differences, coverage and diagnostics. ``sets``: the records of
    further episode sets (name -> records), each given its own section (:func:`set_section_markdown`)
    before the discussion; ``main_name``: the main records' episode set (``val252``), as the pooled section names
    it (default "Table I's episodes"); ``explore``: the exploration benchmark's records per set of starts (a section
    each, :func:`exploration_section_markdown`; also the hand-off targets' exploration ratio); after the sets'
    sections, the paper's claims (:mod:`nue.evaluate.paper_claims`) and the hand-off targets
    (:mod:`nue.evaluate.handoff_targets`) over every set; ``generalisation``: a reference set's name (``val252``, the main
    records or one of ``sets``): a section comparing it with every held-out set of ``sets``
    (:mod:`nue.evaluate.generalisation`; '' = none); ``held_out``: a further generalisation section (after it) from
    its own record files (:class:`HeldOutInputs`, ``RESULTS.generalisation.json``: models that are not Table
    I's), and with its ``replicates`` a section comparing Table I's runs with another training of the same recipe
    (:mod:`nue.evaluate.replicate`). Same inputs give the same bytes (the bootstrap is seeded).
    """
    current = [r for r in records if not is_earlier_recipe(r.method)]
    earlier = [r for r in records if is_earlier_recipe(r.method)]
    rows = build_table(current)
    paper = paper_table()
    first = ["command", "date", "commit", "machine"]
    keys = [k for k in first if k in meta] + sorted(k for k in meta if k not in first and k != "discussion")
    info = "\n".join(f"| {k} | {'`%s`' % meta[k] if k == 'command' else meta[k]} |" for k in keys)
    parts = [
        "# Results\n",
        "Image-goal navigation in the layout of the paper's Table I, regenerated from the episode records "
        "by `nue.evaluate.results_md.render_results_md`.\n",
        f"| | |\n|---|---|\n{info}\n",
        f"## Episodes per cell (successes / episodes)\n\n{_counts_markdown(current, rows)}",
        f"## Table I: ours next to the paper\n\n{format_markdown(rows, paper)}\n{NOTES}\n{seed_notes(rows)}",
    ]
    ordering = ordering_markdown(rows, paper)
    if ordering:
        parts.append(f"## Ordering by total SR\n\n{ordering}")
    if earlier:
        parts.append("## Earlier recipes\n\nRows named `<method>_v<N>` are that method trained with an earlier recipe, "
                     "`<method>_v<N><letter>` an earlier run of a recipe (`checkpoints/README.md`), evaluated on the same episodes with the same seeds; they are left out "
                     "of Table I and the ordering above, and kept in the comparisons below.\n\n"
                     f"{format_markdown(build_table(earlier))}")
    diffs = paired_differences(records)
    if diffs:
        parts.append("## Paired differences to NUE\n\nPer method, the mean over the episodes both it and NUE ran "
                     "(matched on scene and episode id) of its result minus NUE's, with a 95% paired-bootstrap "
                     "interval (10,000 resamples, seed 0). The episode count resolves the ordering when the "
                     f"interval excludes 0.\n\n{paired_markdown(diffs)}")
    curves = coverage_curves(records)
    if curves:
        parts.append(f"## Exploration coverage (mean seen floor area, m²)\n\n{cov.COVERAGE_NOTE}\n\n"
                     f"{cov.format_coverage_markdown(curves, {k: method_label(k) for k in curves})}")
    if records:
        parts.append(f"## Closed-loop diagnostics\n\n{closed_loop_markdown(records, task)}")
    handoff = handoff_markdown(records)
    if handoff:
        parts.append(f"## Exploration -> exploitation hand-off\n\n{handoff}")
    for name, recs in (explore or {}).items():
        parts.append(exploration_section_markdown(name, recs))
    if sets:
        from nue.sim.episode_sets import EPISODE_SETS  # descriptions of the committed sets

        for name, recs in sets.items():
            spec = EPISODE_SETS.get(name)
            parts.append(set_section_markdown(name, recs, spec.description if spec else "", task))
        pooled = pooled_section_markdown({main_name or MAIN_SET: records, **sets})
        if pooled:
            parts.append(pooled)
    # the paper's claims across every set (after the sets' sections: the main ones do not depend on the others)
    independent = _not_extended({main_name or MAIN_SET: records, **(sets or {})})
    parts += [text for text in (ablation_ordering_markdown(independent), baselines_markdown(independent),
                                controls_markdown(independent), handoff_targets_markdown(independent, explore)) if text]
    if generalisation:
        section = generalisation_section(generalisation, {main_name or MAIN_SET: records, **(sets or {})})
        if section:
            parts.append(section)
    if held_out is not None:
        section = generalisation_section(held_out.reference, held_out.sets, pairs=held_out.pairs,
                                         labels=held_out.labels, about=held_out.about, title=held_out.title)
        if section:
            parts.append(section)
        if held_out.replicates:
            section = replicate_section({main_name or MAIN_SET: records, **(sets or {})}, held_out.sets,
                                        held_out.replicates, about=held_out.replicate_about)
            if section:
                parts.append(section)
    if meta.get("discussion"):
        parts.append(f"## Discussion\n\n{meta['discussion']}\n")
    return "\n".join(parts)


GENERALISATION_TITLE = "Generalisation to held-out styles"
"""The generalisation section's default title."""


def generalisation_section(reference: str, sets: Mapping[str, Sequence[EpisodeRecord]], compare_to: str = "nue",
                           pairs: Sequence[tuple[str, str]] = (), labels: Mapping[str, str] | None = None,
                           about: str = "", title: str = GENERALISATION_TITLE) -> str:
    """RESULTS.md's (and ``nue report``'s) generalisation section: ``reference`` against every held-out set
    (:func:`nue.sim.episode_sets.held_out_sets`) among ``sets``, paired differences to ``compare_to`` (or between
    ``pairs``, :func:`nue.evaluate.generalisation.generalisation_markdown`), ``about`` as its first paragraph; ''
    when none of them ran both."""
    from nue.evaluate.generalisation import generalisation_markdown
    from nue.sim.episode_sets import held_out_sets

    families = [name for name in held_out_sets() if name in sets]
    if reference not in sets or not families:
        return ""
    table = generalisation_markdown(sets, reference, families, compare_to, pairs, labels)
    if not table:
        return ""
    names = ", ".join(f"`{f}`" for f in families)
    return (f"## {title}\n\n" + (f"{about}\n\n" if about else "")
            + f"Each model on `{reference}` (houses of its training style) and on "
            f"the held-out style families {names}, whose houses lie outside every training style (docs/styles.md).\n\n"
            f"{table}")


def results_set_files(root) -> dict[str, Path]:
    """The further episode sets' record files committed beside ``root/results/records.jsonl``:
    ``results/records_<set>.jsonl`` for each known set (:data:`nue.sim.episode_sets.EPISODE_SETS`, in its
    order) whose file exists."""
    from nue.sim.episode_sets import EPISODE_SETS

    base = Path(root) / "results"
    return {name: base / f"records_{name}.jsonl" for name in EPISODE_SETS if (base / f"records_{name}.jsonl").is_file()}


def committed_inputs(root) -> tuple[list[EpisodeRecord], dict, dict[str, list[EpisodeRecord]], str]:
    """What the repository's RESULTS.md is rendered from: ``(main records, meta, further sets, main set name)``.
    ``results/records.jsonl`` holds the ``val`` episodes and ``results/records_<set>.jsonl`` the others
    (:func:`results_set_files`); the meta's ``main set`` (e.g. ``val252``) names the set shown first, else ``val``."""
    import json

    from nue.evaluate.report import load_records

    root = Path(root)
    meta = json.loads((root / "RESULTS.meta.json").read_text())
    files = {"val": root / "results" / "records.jsonl", **results_set_files(root)}
    main = str(meta.get("main set", ""))
    main_file = files.pop(main or "val")
    return load_records(main_file), meta, {name: load_records(f) for name, f in files.items()}, main


@dataclass(frozen=True)
class HeldOutInputs:
    """What RESULTS.md's generalisation section is rendered from when its models are not Table I's: the file
    ``RESULTS.generalisation.json`` beside RESULTS.md (:func:`load_held_out`)."""

    reference: str
    """The set of the training style the drops are measured from (``val252``)."""
    sets: dict[str, list[EpisodeRecord]]
    """Set name -> the records of every listed file."""
    pairs: tuple[tuple[str, str], ...]
    """(a, b) method keys: the paired differences a - b shown on every set."""
    labels: dict[str, str]
    """Row names by method key (e.g. which recipe and training houses)."""
    about: str
    """The section's first paragraph: what the rows are and where their records come from."""
    title: str = GENERALISATION_TITLE
    """The section's title."""
    replicates: dict[str, str] = field(default_factory=dict)
    """Table I's method key -> the key of a run of the same recipe among these records (``nue`` ->
    ``nue_gru_lean_mix``): a section compares the two (:mod:`nue.evaluate.replicate`); empty = none."""
    replicate_about: str = ""
    """That section's first paragraph: how the replicate was made."""


HELD_OUT_FILE = "generalisation.json"
"""Suffix of the generalisation manifest beside a RESULTS.md: ``RESULTS.generalisation.json``. Its keys: ``reference``
(a set name), ``sets`` (set name -> record files, relative to the manifest's folder), ``pairs`` (list of [a, b]),
``labels`` (method key -> row name), ``about`` (text), ``title`` (optional, the section's title), and optionally
``replicates`` (Table I's method key -> a listed method key trained with Table I's recipe) with ``replicate about``."""


def load_held_out(path: Path) -> HeldOutInputs:
    """The manifest at ``path`` with its record files loaded; a malformed manifest or a missing file -> DataError
    naming the manifest."""
    import json

    from nue.errors import DataError
    from nue.evaluate.report import load_records

    try:
        raw = json.loads(Path(path).read_text())
    except (OSError, ValueError) as exc:
        raise DataError(path, f"cannot read the generalisation manifest ({exc})") from None
    try:
        reference, about = str(raw["reference"]), str(raw.get("about", ""))
        title = str(raw.get("title", GENERALISATION_TITLE))
        files = {str(k): [Path(path).parent / str(f) for f in v] for k, v in dict(raw["sets"]).items()}
        pairs = tuple((str(a), str(b)) for a, b in raw.get("pairs", []))
        labels = {str(k): str(v) for k, v in dict(raw.get("labels", {})).items()}
        replicates = {str(k): str(v) for k, v in dict(raw.get("replicates", {})).items()}
        replicate_about = str(raw.get("replicate about", ""))
    except (KeyError, TypeError, ValueError) as exc:
        raise DataError(path, f"expected keys reference, sets {{name: [files]}}, pairs [[a, b]], labels, about ({exc!r})") from None
    if reference not in files:
        raise DataError(path, f"reference set {reference!r} is not among its sets ({', '.join(files)})")
    missing = [str(f) for fs in files.values() for f in fs if not f.is_file()]
    if missing:
        raise DataError(path, f"record file(s) not found: {', '.join(missing)}")
    sets = {k: load_records(*v) for k, v in files.items()}
    if replicates:
        from nue.evaluate.table import canonical_method, split_seed

        listed = {canonical_method(split_seed(r.method)[0]) for recs in sets.values() for r in recs}
        unknown = [v for v in replicates.values() if canonical_method(v) not in listed]
        if unknown:
            raise DataError(path, f"replicates name method(s) none of its record files holds: {', '.join(unknown)}")
    return HeldOutInputs(reference, sets, pairs, labels, about, title, replicates, replicate_about)


def committed_held_out(root) -> HeldOutInputs | None:
    """The repository's ``RESULTS.generalisation.json`` loaded (:func:`load_held_out`), or None without one."""
    path = Path(root) / f"RESULTS.{HELD_OUT_FILE}"
    return load_held_out(path) if path.is_file() else None
