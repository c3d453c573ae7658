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
        torch.use_deterministic_algorithms(deterministic, warn_only=True)
