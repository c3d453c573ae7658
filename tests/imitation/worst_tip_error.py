"""A test-only reward error registered from the tests, with no edit to aslexp: the squared distance
of the worst end effector (the built-in ``end_effector`` error is their mean)."""

from __future__ import annotations

import numpy as np

from aslexp.envs.reward import register_error


@register_error("worst_tip")
def worst_tip(reward, sim, ref) -> np.ndarray:
    return np.max(np.sum((sim.end_effectors - ref.end_effectors) ** 2, axis=-1), axis=-1)
