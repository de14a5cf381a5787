"""Command-line argument checks (counts, probabilities, devices, choices), each refused with a
:class:`~nue.errors.ConfigError` naming the option before any work starts.

Output paths are checked by :mod:`nue.outputs`; input files by their readers (scene folders, episode
files, checkpoints, record files), which raise their own typed errors.
"""

from __future__ import annotations

from typing import Iterable

from nue.errors import ConfigError


def positive(option: str, value: int | float) -> None:
    """``value`` must be >= 1 (a count such as ``--workers`` or ``--per-bin``)."""
    if value < 1:
        raise ConfigError(option, f"must be at least 1, got {value}")


def non_negative(option: str, value: int | float) -> None:
    """``value`` must be >= 0 (0 usually meaning 'no limit' or 'the preset's')."""
    if value < 0:
        raise ConfigError(option, f"must be 0 or more, got {value}")


def probability(option: str, value: float) -> None:
    """``value`` must lie in [0, 1]."""
    if not 0.0 <= value <= 1.0:
        raise ConfigError(option, f"must be a probability in [0, 1], got {value}")


def choice(option: str, value: str, choices: Iterable[str]) -> None:
    """``value`` must be one of ``choices``."""
    choices = tuple(choices)
    if value not in choices:
        raise ConfigError(option, f"must be one of {', '.join(choices)}, got {value!r}")


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
