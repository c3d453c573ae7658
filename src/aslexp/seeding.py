"""One place to seed every random number generator the project uses."""

from __future__ import annotations

import random

import numpy as np


def seed_everything(seed: int, deterministic: bool | None = None) -> None:
    """Seed python, numpy and torch. ``deterministic`` (if not None) sets torch's
    deterministic-kernels flag, process-wide, warning instead of failing where none exists."""
    import torch  # here, not at import: every job imports this module, not every job uses torch

    random.seed(seed)
    np.random.seed(seed % (2**32))
    torch.manual_seed(seed)
    if deterministic is not None:
        set_deterministic(deterministic)


def set_deterministic(mode: bool) -> None:
    """torch.use_deterministic_algorithms(mode, warn_only=True) without its import of the compiler.

    That call imports torch._inductor (and with it dynamo, sympy and FSDP: ~1.5 s a process, as long
    as importing torch) only to set inductor's own flag. aslexp never compiles, so the compiler's
    flag is set only where something has already imported it; the kernels' flag is always set."""
    import sys

    import torch

    torch._C._set_deterministic_algorithms(mode, warn_only=True)
    inductor = sys.modules.get("torch._inductor.config")
    if inductor is not None:
        inductor.deterministic = mode
