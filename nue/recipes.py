"""The named recipes of ``nue reproduce`` (:class:`nue.recipe.Recipe` presets): ``RECIPES``, ``get_recipe`` and the
default, ``DEFAULT_RECIPE``.

``v12``, the default, is ``v10`` — the recipe chosen in issue 37: a recurrent NUE and its ablations on the ``lean``
memory, 3 training seeds for the compared rows, the memory baselines and the SLING rows — trained in both house sets
(the 21 ``train`` houses and the 42 style-diverse ``train_diverse``, issue 43), evaluated on both held-out style
families, with the exploration benchmark. ``v6`` is the recipe of the shipped
``checkpoints/*.pt`` (``checkpoints/README.md``) and of today's RESULTS.md: ``v5`` with a budget of 256,000 samples per
model, the same on any machine. ``v7`` is ``v6`` with 3 training seeds for NUE, the no-f_u and all-off ablations and FR
(``Recipe.train_seeds``: a row of Table I is then the seeds' runs). ``v5`` trains each model for 50 minutes on one
core (its models are ``results/v5/checkpoints/``), ``v3`` for 34 minutes with three snapshots competing in the
selection; ``v8`` is ``v7`` with the SLING rows (NUE, FR and Nav-A3C wrapped in the last-mile module); ``v9`` is
``v8`` on the ``lean`` memory with VGM and NRNS; ``v11`` is ``v10`` trained in the diverse houses only;
``quick`` is tiny everything, for CI (with 2 training seeds of NUE and its SLING row, so CI runs those paths end to
end).
"""

from __future__ import annotations

from nue.errors import ConfigError
from nue.policy.config import ABLATION_PRESETS
from nue.recipe import Collection, Recipe, StepPlan

V3 = Recipe(name="v3")
V5 = V3.replace(name="v5", train_minutes=50.0, select_candidates=2,
                steps=(("nue", StepPlan(30_000, 1_500)), ("fr", StepPlan(80_000, 3_000)),
                       ("nav_a3c", StepPlan(30_000, 1_000))))

V6 = V5.replace(name="v6", train_minutes=0.0, train_samples=256_000)
"""v5 with a budget in samples seen instead of minutes: the same for every model whatever the machine, its load or
how many sessions a run spans (a time budget gives a slower machine's models fewer samples). 256,000 samples are
4,000 optimiser steps of 64 samples (Nav-A3C: 8 sequences of 8); why that many: docs/history/checkpoints.md."""

V7 = V6.replace(name="v7", train_seeds=(("nue", 3), ("abl_at_cbam", 3), ("abl_none", 3), ("fr", 3)))
"""v6 with 3 training seeds for NUE, the no-f_u ablation (``abl_at_cbam``: f_u off, AT and CBAM on — NUE without
f_u; ``abl_fu`` is the other way round, f_u alone), the all-off ablation (``abl_none``) and FR, so their rows and the
comparisons between them pool seeds x episodes (issue 37, item 6); the other models train once. Only the training
seed differs between a model's seeds."""

V8 = V7.replace(name="v8", last_mile=("nue", "fr", "nav_a3c"))
"""v7 with the SLING rows of Table I (issue 40): NUE (every seed), FR (every seed) and Nav-A3C also run wrapped in the
last-mile module on every evaluation set."""

TABLE_I_MODELS_LEAN: tuple[str, ...] = (tuple(f"{m}_lean" for m in ("nue", *ABLATION_PRESETS))
                                        + ("fr", "nav_a3c", "vgm", "nrns"))
"""Table I's trained rows on the ``lean`` memory: the ``_lean`` twins of NUE and its ablations (30 x 40 maps), FR,
Nav-A3C and the memory baselines VGM and NRNS (which read no maps; MSM could not be identified, docs/msm.md)."""

MEMORY_BASELINE_STEPS: tuple[tuple[str, StepPlan], ...] = (("vgm", StepPlan(30_000, 1_500)),
                                                           ("nrns", StepPlan(30_000, 1_500)))
"""Step plans of the memory baselines' kinds (under a samples budget only ``eval_every`` is read): VGM's held-out
accuracy, NRNS's held-out distance error every 1,500 steps, as NUE's."""

V9 = V8.replace(name="v9", memory="lean", models=TABLE_I_MODELS_LEAN, steps=V8.steps + MEMORY_BASELINE_STEPS,
                rows=tuple((f"{m}_lean", m) for m in ("nue", *ABLATION_PRESETS)),
                train_seeds=(("nue_lean", 3), ("abl_at_cbam_lean", 3), ("abl_none_lean", 3), ("fr", 3), ("nav_a3c", 3),
                             ("vgm", 3), ("nrns", 3)),
                swap_maps=("nue_lean",), last_mile=("nue_lean", "fr", "nav_a3c"))
"""v8 on the ``lean`` memory (issue 38: 1.7x less per NUE episode step, 1.4x faster NUE training), with the memory
baselines VGM and NRNS (issue 39) and 3 training seeds for NUE, the no-f_u and all-off ablations, FR, Nav-A3C, VGM
and NRNS. A candidate, not the default: its ``_lean`` models fill NUE's and the ablations' rows (``rows``: run ``nue``
trains ``nue_lean``) (results/lean/README.md has the
comparison with ``fast`` that decides it)."""

TABLE_I_MODELS_GRU_LEAN: tuple[str, ...] = (("nue_gru_lean",) + tuple(f"{m}_gru_lean" for m in ABLATION_PRESETS)
                                            + ("fr", "nav_a3c", "vgm", "nrns"))
"""Table I's trained rows with a recurrent NUE: ``nue_gru_lean`` and its ablations with the same 256-unit GRU after
the fusion (``abl_*_gru_lean``), on the ``lean`` memory; the baselines as in v9."""

V10 = V9.replace(name="v10", models=TABLE_I_MODELS_GRU_LEAN,
                 rows=tuple((f"{m}_gru_lean", m) for m in ("nue", *ABLATION_PRESETS)),
                 train_seeds=(("nue_gru_lean", 3), ("abl_at_cbam_gru_lean", 3), ("abl_none_gru_lean", 3), ("fr", 3),
                              ("nav_a3c", 3), ("vgm", 3), ("nrns", 3)),
                 swap_maps=("nue_gru_lean",), last_mile=("nue_gru_lean", "fr", "nav_a3c"))
"""v9 with a recurrent NUE and its ablations carrying the same state, so an ablation row differs from NUE only by the
components the paper switches off; the default until ``v12``. Why it was chosen (issue 37): ``nue_gru_lean``
reached 83.3% on val252 in each of 3 training seeds against reactive ``nue_lean``'s 77.8 / 78.2 / 79.0%, +5.0 points
[+0.4, +9.8] pooled over seeds x episodes (results/gru/README.md); no other change to the hand-off measured better.
Recurrent models train on ``batch_size // seq_len`` sequences, the same samples per step."""

V11 = V10.replace(name="v11", train_split="train_diverse", episodes_per_bin=3, heldout_per_bin=1,
                 select_set="select_diverse", eval_sets=("val252", "val_plain", "val_pale"))
"""v10 trained in the 42 style-diverse ``train_diverse`` houses (issue 43, docs/styles.md), on both held-out families:
3 + 1 held-out episodes per bin per house (v10's 378 training episodes), 256k samples per model, ``select_diverse``.
Not the default: its NUE-GRU lost 5.2 SR points on val252 against v10's (2 x 3 seeds, [-10.8, +0.2]); FR did not."""

V12 = V10.replace(name="v12", also_train=(Collection("train_diverse", episodes_per_bin=3, heldout_per_bin=1),),
                  select_set="select_diverse", eval_sets=("val252", "val_plain", "val_pale"),
                  explore_sets=("val252",), explore_models=TABLE_I_MODELS_GRU_LEAN)
"""v10's demonstrations in the 21 ``train`` houses and v11's in the 42 ``train_diverse`` (756 episodes, 63 houses),
256k samples per model as every recipe, ``select_diverse``; on both held-out families (issue 43: the "mix" runs of
results/mix/README.md), and every model (every seed) in the exploration benchmark from 42 of val252's starts (issue
42). The default (``DEFAULT_RECIPE``), chosen in issue 43: its NUE-GRU reached 81.7 / 80.2 / 79.4% on val252 in 3
training seeds against v10's 83.3% in each of 3, -2.9 points [-7.5, +1.6] pooled over seeds x episodes (the issue's
"no loss on val252": the interval includes 0), and kept or raised its level on the held-out families (3 seeds each:
val_plain 86.0%, val_pale 81.6%, against v10's 86.1% and 78.7%), where v11 (the diverse houses alone) lost 5 points
on val_plain."""

RECIPES: dict[str, Recipe] = {
    "v6": V6,
    "v7": V7,
    "v8": V8,
    "v9": V9,
    "v10": V10,
    "v11": V11,
    "v12": V12,
    "v5": V5,
    "v3": V3,
    "quick": V3.replace(
        name="quick", expert="geodesic", episodes_per_bin=1, heldout_per_bin=0, train_houses=(0,), train_minutes=0.0,
        steps=(("nue", StepPlan(2, 2)), ("fr", StepPlan(2, 2)), ("nav_a3c", StepPlan(2, 2))), batch_size=4,
        seq_len=2, warmup=1, precision="fp32", select="accuracy", eval_houses=(0,), eval_max_episodes=1,
        eval_max_steps=5, experts=("expert",), train_seeds=(("nue", 2),), last_mile=("nue",),
        also_train=(Collection("train_diverse", episodes_per_bin=1, heldout_per_bin=0, houses=(0,)),),
        explore_sets=("val252",), explore_models=("nue",), explore_houses=(0, 1), explore_steps=5),
}
"""Named recipes: ``v12`` (the default: v10 trained in both house sets), ``v10`` (v9 with a recurrent NUE and
ablations), ``v6`` (the shipped checkpoints' and RESULTS.md's: v5 with 256k samples per model instead of 50 minutes),
``v7`` (v6 with 3 training seeds for NUE, abl_at_cbam, abl_none and FR), ``v8`` (v7 with the SLING rows of NUE, FR and
Nav-A3C), ``v9`` (v8 on the lean memory with VGM and NRNS, 3 seeds for 7 rows), ``v11`` (v10 trained in the
style-diverse houses), ``v5``, ``v3`` (docs/history/checkpoints.md) and ``quick`` (CI; 2 training seeds of NUE, its
SLING row and a second collection)."""

DEFAULT_RECIPE = "v12"
"""What ``nue reproduce`` runs without ``--recipe``."""


def get_recipe(name: str) -> Recipe:
    """A recipe preset by name; unknown -> ConfigError."""
    try:
        return RECIPES[name]
    except KeyError:
        raise ConfigError("--recipe", f"unknown recipe {name!r}; known: {', '.join(RECIPES)}") from None
