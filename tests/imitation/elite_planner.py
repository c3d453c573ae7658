"""A test-only planner update, registered as a user's module would register one (conf/planner/*.yaml
``method: elite_mean``, ``module: elite_planner``): the plan is the mean of the two best candidates."""

from __future__ import annotations

import numpy as np

from aslexp.control.mpc import register_update


@register_update("elite_mean")
def elite_mean(spec, candidates, returns, noise, scale):
    best = candidates[np.argsort(-returns, kind="stable")[:2]]
    return best.mean(axis=0), noise
