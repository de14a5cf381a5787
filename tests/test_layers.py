"""The package's layers (README "Layout"): scene -> sim -> nerf -> policy -> the agent loop and jobs -> train |
evaluate -> closed-loop selection -> viz -> the commands. A module imports only from its own part of a layer or
from the layers before it; train and evaluate stand side by side in one layer and neither imports the other."""

import ast
from pathlib import Path

import nue

ROOT = Path(nue.__file__).parent
LAYERS = [
    [{"nue.errors", "nue.outputs", "nue.output_lock"}],
    [{"nue.scene"}],
    [{"nue.sim"}],
    [{"nue.nerf"}],
    [{"nue.policy"}],
    [{"nue.rollout", "nue.jobs"}],
    [{"nue.train"}, {"nue.evaluate"}],
    [{"nue.selection"}],
    [{"nue.viz"}],
    [{"nue.demo", "nue.recipe", "nue.recipes", "nue.recipe_estimate", "nue.reproduce", "nue.reproduce_eval",
      "nue.reproduce_adopt", "nue.reproduce_marker", "nue.reproduce_train", "nue.cli", "nue.cli_args", "nue.cli_config", "nue.cli_evaluate",
      "nue.cli_learn", "nue.cli_reproduce", "nue"}],
]
"""Layers bottom up; each a list of its parts (sets of modules and packages), side by side: a part may not import
another part of its own layer."""


def layer_of(module: str) -> tuple[int, int]:
    """(index in LAYERS, index of the part within that layer) of ``module`` (``nue.sim.env`` is where ``nue.sim``
    is)."""
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        for i, layer in enumerate(LAYERS):
            for j, part in enumerate(layer):
                if ".".join(parts[:n]) in part:
                    return i, j
    raise KeyError(module)


def may_import(module: str, target: str) -> bool:
    """``module`` may import ``target``: a lower layer, or the same part of its own layer."""
    (i, j), (ti, tj) = layer_of(module), layer_of(target)
    return ti < i or (ti, tj) == (i, j)


def imports_of(path: Path) -> set[str]:
    """The ``nue`` modules a source file imports, anywhere in it (function-level imports too)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
    return {m for m in found if m == "nue" or m.startswith("nue.")}


def test_layer_of_a_module_is_that_of_its_package():
    assert layer_of("nue.sim.env") == layer_of("nue.sim") < layer_of("nue.train.bc") < layer_of("nue.evaluate")
    assert layer_of("nue.train.bc")[0] == layer_of("nue.evaluate.runner")[0]  # one layer, two parts
    assert layer_of("nue.scene.navgrid") < layer_of("nue.nerf.online") < layer_of("nue.viz.view") < layer_of("nue.cli")


def test_train_and_evaluate_import_neither_way():
    assert not may_import("nue.train.bc", "nue.evaluate.runner")
    assert not may_import("nue.evaluate.runner", "nue.train.checkpoint")
    assert may_import("nue.selection", "nue.train.bc") and may_import("nue.selection", "nue.evaluate.runner")
    assert may_import("nue.train.bc", "nue.policy.checkpoint") and may_import("nue.evaluate.runner", "nue.policy")


def test_imports_point_down_the_layers_and_not_across():
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        module = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        if module == "nue":  # the package's face re-exports every layer
            continue
        for target in imports_of(path):
            if target != "nue" and not may_import(module, target):
                upward.append(f"{module} -> {target}")
    assert upward == []


def test_imports_of_sees_function_level_and_plain_imports(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("import numpy\nimport nue.sim.env\nfrom . import x\n\ndef f():\n    from nue.train.bc import train\n")
    assert imports_of(src) == {"nue.sim.env", "nue.train.bc"}
