"""The command line's config options come from the dataclasses (nue/cli_config.py): defaults and help are the
fields' defaults and docstrings, a changed default changes the CLI, checks name the option."""

from __future__ import annotations

import dataclasses
import importlib
import re
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import typer

from nue import cli_args as A
from nue.cli import app, main
from nue.cli_config import _UNSET, ConfigOptions, Opt, config_command, config_fields, plain_doc
from nue.cli_learn import TRAIN


def _commands() -> dict[str, object]:
    """Every leaf command of ``nue``, by its path ("train", "episodes generate")."""
    found, todo = {}, [("", typer.main.get_command(app))]
    while todo:
        path, cmd = todo.pop()
        for name, sub in getattr(cmd, "commands", {}).items():
            todo.append((f"{path} {name}".strip(), sub))
        if not hasattr(cmd, "commands"):
            found[path] = cmd
    return found


def _params(command) -> dict[str, object]:
    return {opt: p for p in command.params for opt in p.opts}


def _as_fields(help: str) -> str:
    """Help with the flags of other options (`--select-candidates`) named as their fields (`select_candidates`)."""
    return re.sub(r"`--([a-z0-9-]+)`", lambda m: f"`{m[1].replace('-', '_')}`", help)


def _help_text(capsys, *command: str) -> str:
    """``nue <command> --help`` with the boxes removed and white space folded (wrapped lines joined)."""
    with pytest.raises(SystemExit) as stop:
        main([*command, "--help"])
    assert stop.value.code == 0
    return " ".join(re.sub("[│╭╮╰╯─]", " ", capsys.readouterr().out).split())


def test_train_help_shows_each_config_option_with_the_fields_default_and_docstring(capsys):
    from nue.train.bc import TrainConfig

    defaults = {f.name: f.default for f in dataclasses.fields(TrainConfig)}
    params = _params(_commands()["train"])
    text = _help_text(capsys, "train")
    plain = [o for o in TRAIN.opts if not o.help and not o.minutes]
    assert len(plain) >= 15
    for o in plain:
        doc, param = TRAIN.field(o.field).doc, params[o.option]
        assert doc and _as_fields(param.help) == doc, o.field  # `--select-candidates` is `select_candidates`
        default = defaults[o.field]
        if default == "":  # a path option without a default (--init-from)
            assert param.default is None and f"{param.help} [default" not in text
        else:
            assert param.default == (Path(default) if o.path else default), o.field
            shown = f"{'' if default else 'no-'}{o.field.replace('_', '-')}" if isinstance(default, bool) else default
            assert f"{param.help} [default: {shown}]" in text, o.field  # a flag: [default: no-compile]
    assert "--lr <float> Peak AdamW learning rate. [default: 0.001]" in text  # the docstring, by hand
    assert "--time-budget <float> Stop (and checkpoint) after this many minutes" in text
    assert "--dagger" not in text and "--rounds" not in text  # DAgger is `nue dagger`'s (the old spellings are gone)


def test_dagger_has_trains_options_and_its_own():
    from nue.train.dagger import DaggerConfig

    train, dagger = _params(_commands()["train"]), _params(_commands()["dagger"])
    assert dagger["--out"].default == Path("runs/nue_dagger") and train["--out"].default == Path("runs/nue")
    for flag in ("--data", "--model", "--batch-size", "--lr", "--precision", "--select", "--warmup"):
        assert dagger[flag].default == train[flag].default, flag
    defaults = {f.name: f.default for f in dataclasses.fields(DaggerConfig)}
    assert dagger["--beta"].default == defaults["beta0"] and dagger["--round-steps"].default == defaults["steps_per_round"]
    assert dagger["--time-budget"].default == defaults["round_budget_s"] / 60
    assert not {"--dagger-rounds", "--rounds", "--scene", "--workers"} & set(train)  # removed from `nue train`


def test_every_config_option_has_the_default_and_type_its_dataclass_has():
    """The fields are read from source without importing it; the imported class must agree."""
    seen = set()
    for path, command in _commands().items():
        for group in getattr(command.callback, "config_options", {}).values():
            module, _, cls_name = group.ref.partition(":")
            cls = getattr(importlib.import_module(module), cls_name)
            real = {f.name: f for f in dataclasses.fields(cls)}
            for o in group.opts:
                read = group.field(o.field)
                required = real[o.field].default is dataclasses.MISSING  # the option gives a default of its own
                assert (o.default is not _UNSET) if required else read.default == real[o.field].default, (path, o.field)
                assert read.doc, (path, o.field)
                seen.add(f"{cls_name}.{o.field}")
            built = group.build({o.field: group._cli_default(o) for o in group.opts})
            for o in group.opts:  # the defaults typer hands over build the dataclass's defaults
                if o.default is _UNSET:
                    value = built[o.field] if group.as_dict else getattr(built, o.field)
                    assert value == real[o.field].default, (path, o.field)
    for field in ("TrainConfig.lr", "CollectConfig.houses", "DaggerConfig.beta0", "EvalConfig.swap_maps",
                  "SelectConfig.candidates", "StepStorage.rgbd_bits", "EpisodeGenConfig.per_bin",
                  "ViewConfig.grpc_port", "LiveSource.max_steps", "ReplaySource.episodes_dir"):
        assert field in seen


TINY = '''
    from dataclasses import dataclass, field

    @dataclass(frozen=True)
    class Tiny:
        """A config for the adapter's tests."""

        steps: int = {steps}
        """How many ``steps``;
        wrapped over two lines."""
        out: str = "runs/a"
        """Where to write."""
        ids: tuple[int, ...] = (1, 2)
        """Which ones."""
        fast: bool = False
        """Go fast (see `steps`)."""
        budget_s: float = 120.0
        """Seconds."""
        nested: object = field(default_factory=object, repr=False)
        """Not an option."""
'''


@pytest.fixture()
def tiny(tmp_path, monkeypatch):
    """``make(steps)`` writes the module ``tiny_cfg`` with that default and returns a fresh typer app whose
    ``run`` command echoes the config it gets."""
    monkeypatch.syspath_prepend(str(tmp_path))

    def make(steps: int) -> typer.Typer:
        (tmp_path / "tiny_cfg.py").write_text(textwrap.dedent(TINY.format(steps=steps)))
        config_fields.cache_clear()
        sys.modules.pop("tiny_cfg", None)
        importlib.invalidate_caches()
        group = ConfigOptions("tiny_cfg:Tiny", Opt("steps", check=A.positive), Opt("out", path=True), "ids", "fast",
                              Opt("budget_s", flag="--budget", minutes=True, help="Minutes."))

        @config_command
        def run(cfg: object = group, loud: bool = typer.Option(False, help="Louder.")):
            typer.echo(f"{cfg!r} loud={loud}")

        tiny_app = typer.Typer(add_completion=False)
        tiny_app.command("run")(run)
        tiny_app.command("other")(lambda: None)  # two commands: `run` is a subcommand
        return tiny_app

    yield make
    config_fields.cache_clear()
    sys.modules.pop("tiny_cfg", None)


def _run(capsys, app_, *args) -> tuple[int, str, str]:
    with pytest.raises(SystemExit) as stop:
        A.run(app_, [str(a) for a in args])
    out = capsys.readouterr()
    return stop.value.code, out.out, out.err


def test_a_changed_dataclass_default_changes_the_cli_default(tiny, capsys):
    for steps in (5, 7):
        code, out, _ = _run(capsys, tiny(steps), "run")
        assert code == 0 and out.startswith(f"Tiny(steps={steps}, out='runs/a', ids=(1, 2), fast=False, budget_s=120.0")
        code, out, _ = _run(capsys, tiny(steps), "run", "--help")
        text = " ".join(re.sub("[│╭╮╰╯─]", " ", out).split())
        assert code == 0 and f"--steps <int> How many `steps`; wrapped over two lines. [default: {steps}]" in text
    assert "--out <path> Where to write. [default: runs/a]" in text
    assert "--ids <str> Which ones. Comma-separated integers. [default: 1,2]" in text
    assert "--fast --no-fast <bool> Go fast (see `--steps`). [default: no-fast]" in text  # a field's flag
    assert "--budget <float> Minutes. [default: 2.0]" in text and "--nested" not in text
    code, out, _ = _run(capsys, tiny(5), "run", "--steps", 3, "--out", "x/y", "--ids", "4,5", "--fast", "--budget", 1.5,
                        "--loud")
    assert code == 0 and out.strip() == "Tiny(steps=3, out='x/y', ids=(4, 5), fast=True, budget_s=90.0) loud=True"


@pytest.mark.parametrize("args, line", [
    (["--steps", 0], "error: --steps: must be at least 1, got 0"),
    (["--ids", "1,x"], "error: --ids: expected comma-separated integers, got '1,x'"),
    (["--steps", "many"], "error: nue run: Invalid value for '--steps'"),
])
def test_bad_values_of_generated_options_are_one_line_naming_the_option(tiny, capsys, args, line):
    code, out, err = _run(capsys, tiny(5), "run", *args)
    assert code == 2 and out == "" and err.strip().startswith(line) and "\n" not in err.strip()


def test_bad_choices_are_refused_naming_the_option_before_anything_is_written(capsys, tmp_path):
    for argv, line in ((["train", "--precision", "fp8"], "error: --precision: must be one of auto, fp32, bf16"),
                       (["dagger", "--select", "best"], "error: --select: must be one of accuracy, closed_loop"),
                       (["collect", "--expert", "oracle"], "error: --expert: must be one of geodesic, explore"),
                       (["collect", "--split", "val"], "error: --split: must be one of train, train_diverse, got 'val'"),
                       (["convert", tmp_path, "--rgbd-bits", 5], "error: --rgbd-bits: must be 0 or one of")):
        with pytest.raises(SystemExit) as stop:
            main([str(a) for a in argv] + ["--out", str(tmp_path / "out")])
        err = capsys.readouterr().err.strip()
        assert stop.value.code == 2 and err.startswith(line) and "\n" not in err, err
    assert not (tmp_path / "out").exists()


def test_a_config_field_the_command_line_cannot_give_is_refused_when_declared(tiny):
    tiny(5)
    with pytest.raises(TypeError, match="no field 'nested'"):
        ConfigOptions("tiny_cfg:Tiny", "nested")
    with pytest.raises(TypeError, match="needs its own help"):
        ConfigOptions("tiny_cfg:Tiny", Opt("budget_s", minutes=True))
    with pytest.raises(TypeError, match="--steps is both"):
        @config_command
        def clash(cfg: object = ConfigOptions("tiny_cfg:Tiny", "steps"), steps: int = typer.Option(1)):
            pass


def test_plain_doc_folds_white_space_and_sphinx_markup():
    assert plain_doc("""``fp32``; :func:`~nue.train.compact.quantize`,
        :class:`nue.errors.ConfigError` and `x`.""") == "`fp32`; `quantize`, `nue.errors.ConfigError` and `x`."


def test_the_command_line_starts_without_importing_the_library():
    """Options are read from the config modules' source: `import nue.cli` imports neither torch nor them."""
    code = ("import sys, nue.cli; heavy = [m for m in ('torch', 'nue.train.bc', 'nue.evaluate.runner', 'rich') "
            "if m in sys.modules]; print(heavy)")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "[]", res.stdout + res.stderr
