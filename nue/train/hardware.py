"""What the training hardware supports: the precision ``auto`` resolves to (native bfloat16 or fp32) and whether
``torch.compile`` can build kernels here."""

from __future__ import annotations

import importlib.util
import os
import shutil
from pathlib import Path

import torch

from nue.errors import ConfigError


def resolve_precision(precision: str, device: torch.device) -> str:
    """``auto`` -> ``bf16`` where ``device`` runs bfloat16 natively (CPU: AVX512-BF16 or AMX-BF16 in its flags, and a
    oneDNN that uses them; CUDA: bf16 support), else ``fp32``; other values pass through. oneDNN alone also reports
    bf16 on AVX512 CPUs without those instructions, where it is emulated."""
    if precision != "auto":
        return precision
    if device.type == "cuda":
        return "bf16" if torch.cuda.is_bf16_supported() else "fp32"
    try:
        onednn = torch.ops.mkldnn._is_mkldnn_bf16_supported()
    except (AttributeError, RuntimeError):  # pragma: no cover - builds without oneDNN
        return "fp32"
    return "bf16" if onednn and cpu_has_native_bf16() else "fp32"


def cpu_has_native_bf16(cpuinfo: str | None = None) -> bool:
    """Whether the CPU executes bfloat16 arithmetic natively: ``avx512_bf16`` or ``amx_bf16`` among the flags of
    ``/proc/cpuinfo`` (or of ``cpuinfo``, its text). Without them bf16 autocast is emulated (several times slower
    than fp32, benchmarks/results/train_no_native_bf16.json). No ``/proc/cpuinfo`` (not Linux): False."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return False
    flags = set(cpuinfo.split())
    return "avx512_bf16" in flags or "amx_bf16" in flags


def cpu_model(cpuinfo: str | None = None) -> str:
    """The CPU's model name from ``/proc/cpuinfo`` (or ``cpuinfo``, its text); '' where there is none."""
    if cpuinfo is None:
        try:
            cpuinfo = Path("/proc/cpuinfo").read_text()
        except OSError:
            return ""
    for line in cpuinfo.splitlines():
        if line.startswith("model name"):
            return line.split(":", 1)[1].strip()
    return ""


def machine_summary() -> str:
    """This machine in a few words for run markers and RESULTS.md: CPU model (or the architecture) and CPU count."""
    import platform

    return f"{cpu_model() or platform.machine()}, {os.cpu_count()} CPUs"


def check_compile(device: torch.device) -> None:
    """Refuse ``compile`` where torch.compile's inductor cannot build kernels: no C++ compiler (CPU), no Triton
    (CUDA)."""
    if device.type == "cuda":
        if importlib.util.find_spec("triton") is None:
            raise ConfigError("--compile", "torch.compile on CUDA needs Triton (pip install triton)")
    elif not any(shutil.which(c) for c in (os.environ.get("CXX", "g++"), "g++", "clang++")):
        raise ConfigError("--compile", "torch.compile on CPU needs a C++ compiler (g++ or clang++; set CXX)")
