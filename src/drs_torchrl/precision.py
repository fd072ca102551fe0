"""Learner precision (``algo.precision``): fp32, or bf16/fp16 autocast with fp32 master weights.

Only the learner's matrix work changes: the SAC and discriminator forward/backward passes run inside
``torch.autocast`` (matrix products in the low precision), while parameters, gradients, optimiser
state, the networks' outputs (:class:`OutputFloat32` ends every MLP, so distributions, log-probs and
losses are fp32) and the reward the agent is trained on stay fp32.

``auto`` picks bf16 only where the hardware multiplies bf16 natively (AVX512-BF16 or AMX on x86
CPUs, compute capability >= 8.0 on CUDA) and fp32 elsewhere: on a CPU without those instructions
oneDNN emulates bf16 and it is several times slower than fp32 (``results/bench/``).
"""

from __future__ import annotations

import contextlib
from pathlib import Path

import torch
from torch import nn

from drs_torchrl.runtime.errors import UserError

PRECISIONS = ("auto", "fp32", "bf16", "fp16")
_DTYPES = {"bf16": torch.bfloat16, "fp16": torch.float16}


class PrecisionError(UserError, ValueError):
    """A precision this device cannot run."""


def _cpu_flags() -> set[str]:
    try:
        text = Path("/proc/cpuinfo").read_text()
    except OSError:
        return set()
    for line in text.splitlines():
        if line.startswith("flags"):
            return set(line.split(":", 1)[1].split())
    return set()


def native_bf16(device: torch.device | str = "cpu") -> bool:
    """True where bf16 matrix products run in hardware on ``device`` (not emulated)."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.get_device_capability(device)[0] >= 8
    if device.type != "cpu":
        return False
    cpu = getattr(torch, "cpu", None)
    for probe in ("_is_avx512_bf16_supported", "_is_amx_tile_supported"):
        fn = getattr(cpu, probe, None)
        if fn is not None:
            try:
                if fn():
                    return True
            except RuntimeError:
                pass
    return bool(_cpu_flags() & {"avx512_bf16", "amx_bf16"})


def resolve_precision(name: str, device: torch.device | str) -> str:
    """``auto`` -> ``bf16`` or ``fp32`` for ``device``; other names are checked and returned."""
    device = torch.device(device)
    if name not in PRECISIONS:
        raise PrecisionError(f"algo.precision must be one of {'|'.join(PRECISIONS)}, got {name!r}")
    if name == "auto":
        return "bf16" if native_bf16(device) else "fp32"
    if name == "fp16" and device.type != "cuda":
        raise PrecisionError(
            "algo.precision=fp16 needs a CUDA device (CPUs have no fp16 matrix units torch uses); "
            "use algo.precision=bf16 or fp32"
        )
    return name


def describe_precision(name: str, device: torch.device | str) -> str:
    """One line for the run's log: the precision in use and why."""
    device = torch.device(device)
    native = native_bf16(device)
    where = f"{device.type} {'with' if native else 'without'} native bf16"
    if name == "fp32":
        return f"learner precision fp32 ({where})"
    note = "" if name != "bf16" or native else "; emulated here, expect it to be slower than fp32"
    return f"learner precision {name} autocast, fp32 master weights ({where}{note})"


def autocast(name: str, device: torch.device | str):
    """The context for the learner's forward passes: ``torch.autocast`` for bf16/fp16, else nothing."""
    if name in _DTYPES:
        return torch.autocast(torch.device(device).type, dtype=_DTYPES[name])
    return contextlib.nullcontext()


def grad_scaler(name: str, device: torch.device | str):
    """A ``torch.amp.GradScaler`` for fp16 (its small exponent range underflows gradients), else None."""
    if name == "fp16":
        return torch.amp.GradScaler(torch.device(device).type)
    return None


class OutputFloat32(nn.Module):
    """Last layer of the SAC networks: returns fp32 whatever precision the matmuls ran in, so the
    tanh-Gaussian, log-probs, targets and losses are fp32 under autocast (a no-op in fp32).
    It has no parameters: checkpoints are unchanged."""

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x.float()
