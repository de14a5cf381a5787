"""The package's layers (README "Layout"): scene -> sim -> nerf -> policy -> the agent loop and jobs -> train /
evaluate -> viz -> the commands. A module imports only from its own layer or the ones before it."""

import ast
from pathlib import Path

import nue

ROOT = Path(nue.__file__).parent
LAYERS = [
    {"nue.errors", "nue.outputs", "nue.output_lock"},
    {"nue.scene"},
    {"nue.sim"},
    {"nue.nerf"},
    {"nue.policy"},
    {"nue.rollout", "nue.jobs"},
    {"nue.train", "nue.evaluate"},
    {"nue.viz"},
    {"nue.demo", "nue.recipe", "nue.recipe_estimate", "nue.reproduce", "nue.reproduce_train", "nue.cli", "nue.cli_args", "nue.cli_config", "nue.cli_evaluate",
     "nue.cli_learn", "nue.cli_reproduce", "nue"},
]


def layer_of(module: str) -> int:
    """Index in LAYERS of ``module`` (``nue.sim.env`` is in ``nue.sim``'s layer)."""
    parts = module.split(".")
    for n in range(len(parts), 0, -1):
        for i, layer in enumerate(LAYERS):
            if ".".join(parts[:n]) in layer:
                return i
    raise KeyError(module)


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
    assert layer_of("nue.sim.env") == layer_of("nue.sim") < layer_of("nue.train.bc") == layer_of("nue.evaluate")
    assert layer_of("nue.scene.navgrid") < layer_of("nue.nerf.online") < layer_of("nue.viz.view") < layer_of("nue.cli")


def test_imports_point_down_the_layers():
    upward = []
    for path in sorted(ROOT.rglob("*.py")):
        rel = path.relative_to(ROOT.parent).with_suffix("")
        module = ".".join(rel.parts[:-1] if rel.name == "__init__" else rel.parts)
        if module == "nue":  # the package's face re-exports every layer
            continue
        for target in imports_of(path):
            if target != "nue" and layer_of(target) > layer_of(module):
                upward.append(f"{module} -> {target}")
    assert upward == []


def test_imports_of_sees_function_level_and_plain_imports(tmp_path):
    src = tmp_path / "m.py"
    src.write_text("import numpy\nimport nue.sim.env\nfrom . import x\n\ndef f():\n    from nue.train.bc import train\n")
    assert imports_of(src) == {"nue.sim.env", "nue.train.bc"}
