"""Bad command-line input: argument checks (counts, probabilities, devices, choices), each refused with a
:class:`~nue.errors.ConfigError` naming the option before any work starts, and :func:`run`, which turns every
failure the user can fix into one line on stderr and exit status 2.

Output paths are checked by :mod:`nue.outputs`; input files by their readers (scene folders, episode
files, checkpoints, record files), which raise their own typed errors.
"""

from __future__ import annotations

import importlib
import sys
from typing import Callable, Iterable

import typer

from nue.errors import ConfigError, NueError

try:  # typer >= 0.26 ships its own copy of click, whose usage errors these are
    from typer._click import exceptions as click_errors
except ImportError:  # pragma: no cover - an older typer runs on click itself
    from click import exceptions as click_errors  # type: ignore[no-redef]


def positive(option: str, value: int | float) -> None:
    """``value`` must be >= 1 (a count such as ``--workers`` or ``--per-bin``)."""
    if value < 1:
        raise ConfigError(option, f"must be at least 1, got {value}")


def non_negative(option: str, value: int | float) -> None:
    """``value`` must be >= 0 (0 usually meaning 'no limit' or 'the preset's')."""
    if value < 0:
        raise ConfigError(option, f"must be 0 or more, got {value}")


def above_zero(option: str, value: float) -> None:
    """``value`` must be > 0 (a weight or a scale)."""
    if not value > 0:
        raise ConfigError(option, f"must be above 0, got {value}")


def probability(option: str, value: float) -> None:
    """``value`` must lie in [0, 1]."""
    if not 0.0 <= value <= 1.0:
        raise ConfigError(option, f"must be a probability in [0, 1], got {value}")


def choice(option: str, value: str, choices: Iterable[str]) -> None:
    """``value`` must be one of ``choices``."""
    choices = tuple(choices)
    if value not in choices:
        raise ConfigError(option, f"must be one of {', '.join(choices)}, got {value!r}")


def one_of(ref: str) -> Callable[[str, str], None]:
    """A check that the value is one of the names ``module:NAME`` holds (imported when the check runs, so the
    command line does not import the library to declare its options)."""

    def check(option: str, value: str) -> None:
        module, _, name = ref.partition(":")
        choice(option, value, getattr(importlib.import_module(module), name))

    return check


def ints(option: str, text: str) -> tuple[int, ...]:
    """Comma-separated integers (``"0,3,5"``); :class:`~nue.errors.ConfigError` naming ``option`` otherwise."""
    try:
        return tuple(int(v) for v in text.split(",") if v.strip()) if text else ()
    except ValueError:
        raise ConfigError(option, f"expected comma-separated integers, got {text!r}") from None


def device(option: str, value: str) -> None:
    """A torch device string that exists on this machine (``cuda`` needs a CUDA build and a GPU)."""
    if value == "cpu":
        return
    import torch

    try:
        dev = torch.device(value)
    except (RuntimeError, ValueError):
        raise ConfigError(option, f"not a device: {value!r} (use cpu or cuda[:N])") from None
    if dev.type == "cuda":
        if not torch.cuda.is_available():
            why = "this torch build has no CUDA" if torch.version.cuda is None else "no CUDA GPU is visible"
            raise ConfigError(option, f"{value!r} requested, but {why}; use --device cpu")
        if dev.index is not None and dev.index >= torch.cuda.device_count():
            raise ConfigError(option, f"{value!r} requested, but only {torch.cuda.device_count()} CUDA device(s)")
    elif dev.type != "cpu":
        raise ConfigError(option, f"unsupported device {value!r} (use cpu or cuda[:N])")


def usage_problem(exc: click_errors.UsageError, command=None, args: Iterable[str] = ()) -> str:
    """One line for a usage error of click / typer (unknown option or command, a missing argument, a
    value that is not a number, ...): ``<command>: <problem> (see '<command> --help')``.

    The command is the error's context, or (for the errors raised without one, such as an option
    missing its value) the leading words of ``args`` that name subcommands of the click ``command``."""
    if exc.ctx is not None:
        path = exc.ctx.command_path
    else:
        words = ["nue"]
        for word in args:
            command = getattr(command, "commands", {}).get(word)
            if command is None:
                break
            words.append(word)
        path = " ".join(words)
    problem = " ".join(exc.format_message().split())
    return f"{path}: {problem} (see '{path} --help')"


def run(app: typer.Typer, argv: list[str] | None = None) -> None:
    """Run the command line ``argv`` (default ``sys.argv[1:]``) of ``app`` as ``nue``, and exit.

    Every failure the user can fix is one line on stderr and exit status 2: a usage error found by
    click (unknown option, missing argument, bad number; its boxed usage text is not shown) as
    ``error: <command>: <problem>``, bad input as ``error: <file or option>: <problem>``. ``--help``
    and a bare group (which prints its help) behave as click's. An injected test failure exits 3.
    """
    from nue.jobs import InjectedFailure

    args = sys.argv[1:] if argv is None else list(argv)
    command = typer.main.get_command(app)
    try:
        code = command.main(args=args, prog_name="nue", standalone_mode=False)
    except click_errors.UsageError as exc:
        if type(exc).__name__ == "NoArgsIsHelpError":  # ``nue`` or ``nue scenes`` alone: its help (as typer does)
            if exc.format_message().strip():
                exc.show()
        else:
            typer.echo(f"error: {usage_problem(exc, command, args)}", err=True)
        sys.exit(2)
    except click_errors.ClickException as exc:
        typer.echo(f"error: {' '.join(exc.format_message().split())}", err=True)
        sys.exit(exc.exit_code)
    except typer.Abort:
        typer.echo("Aborted!", err=True)
        sys.exit(1)
    except NueError as exc:
        typer.echo(f"error: {exc}", err=True)
        sys.exit(2)
    except InjectedFailure as exc:
        typer.echo(f"stopped: {exc}", err=True)
        sys.exit(3)
    sys.exit(code if isinstance(code, int) else 0)  # an int is click's exit code (``--help``: 0, Ctrl-C: 130)
