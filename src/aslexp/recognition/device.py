"""Where torch models train: ``trainer.device`` and ``trainer.precision``.

    device     auto (CUDA when available, else CPU) | cpu | cuda | cuda:<i>
    precision  32 (float32) | bf16 | fp16 (autocast; fp16 scales the loss, CUDA only)

A request the machine cannot serve (``cuda`` without CUDA, ``cuda:3`` on a 1-GPU node, fp16 on
CPU) is an error naming the setting, never a silent fallback.
"""

from __future__ import annotations

import contextlib
from typing import Any

import torch

PRECISIONS = ("32", "bf16", "fp16")


def resolve_device(spec: str | torch.device | None) -> torch.device:
    """The torch device for a ``trainer.device`` value."""
    if isinstance(spec, torch.device):
        return spec
    text = str(spec or "auto").strip().lower()
    if text == "auto":
        return torch.device("cuda" if torch.cuda.is_available() else "cpu")
    try:
        device = torch.device(text)
    except RuntimeError:
        raise ValueError(f"trainer.device={spec!r}: expected auto, cpu, cuda or cuda:<index>") from None
    if device.type == "cuda":
        if not torch.cuda.is_available():
            raise ValueError(f"trainer.device={spec!r}: CUDA is not available here (torch {torch.__version__}); "
                             "use trainer.device=cpu or auto")  # fmt: skip
        if device.index is not None and device.index >= torch.cuda.device_count():
            raise ValueError(f"trainer.device={spec!r}: only {torch.cuda.device_count()} CUDA device(s)")
    elif device.type != "cpu":
        raise ValueError(f"trainer.device={spec!r}: expected auto, cpu, cuda or cuda:<index>")
    return device


def check_precision(precision: str, device: torch.device) -> str:
    precision = str(precision).lower().removesuffix("-mixed")
    precision = {"32": "32", "fp32": "32", "float32": "32", "bf16": "bf16", "bfloat16": "bf16",
                 "fp16": "fp16", "16": "fp16", "float16": "fp16"}.get(precision, precision)  # fmt: skip
    if precision not in PRECISIONS:
        raise ValueError(f"trainer.precision={precision!r}: expected one of {PRECISIONS}")
    if precision == "fp16" and device.type != "cuda":
        raise ValueError("trainer.precision=fp16 needs a CUDA device (use bf16 on CPU)")
    return precision


def autocast(device: torch.device, precision: str) -> contextlib.AbstractContextManager:
    """Mixed-precision context for forward passes (a no-op for float32)."""
    if precision == "32":
        return contextlib.nullcontext()
    dtype = torch.bfloat16 if precision == "bf16" else torch.float16
    return torch.autocast(device_type=device.type, dtype=dtype)


def device_info(device: torch.device, precision: str = "32") -> dict[str, Any]:
    """What a run records about where it trained (metrics.json ``device``)."""
    info: dict[str, Any] = {"device": str(device), "type": device.type, "precision": precision,
                            "torch": torch.__version__}  # fmt: skip
    if device.type == "cuda":
        index = device.index if device.index is not None else torch.cuda.current_device()
        info.update(name=torch.cuda.get_device_name(index), cuda=torch.version.cuda,
                    memory_gib=round(torch.cuda.get_device_properties(index).total_memory / 2**30, 1))  # fmt: skip
    else:
        info.update(name="cpu", threads=torch.get_num_threads())
    return info
