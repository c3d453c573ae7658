"""No-learning baselines: each controller driven by the reference alone, scored under one reward.

A learned result is only readable beside what the same body, reward and rate give with no policy at
all. A :class:`Baseline` names a controller (and any body/env overrides: a pinned or standing base,
another rate or solver) and the lookaheads to try: 0 is "the reference as the PD target", 1 "the
target one control step ahead". Controllers with target options (the aslexp reference-velocity
controllers) run with a residual action and no correction, so their own targets are measured.
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.config_schema import Section
from aslexp.envs.assembly import ImitationSetup
from aslexp.compose import deep_merge, resolve_group
from aslexp.envs.imitation import ImitationEnv
from aslexp.envs.tracking import reference_rollout
from aslexp.sim.pd import ControllerSpec

_log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Baseline(Section):
    """One no-learning row: ``label`` as shown, a controller config name, overrides, lookaheads."""

    SECTION = "report.baselines"

    label: str
    controller: str
    body: dict[str, Any] = field(default_factory=dict)
    env: dict[str, Any] = field(default_factory=dict)
    lookahead: tuple[int, ...] = (0, 1)
    aslexp: bool = False  # an aslexp addition, not the thesis' (shown as a labelled aslexp row)


def no_learning_baselines(setup: ImitationSetup, rows: list[Baseline], seconds: float = 10.0,
                          phases: tuple[float, ...] = (0.0,)) -> list[dict[str, Any]]:
    """Mean reward per step of every row x lookahead over ``seconds`` of simulated time from each
    start phase of ``phases`` (the learned policy's evaluation protocol; an early end, e.g. a fall,
    scores 0 for the rest), averaged over the phases, under the setup's reward (and, in ``scores``,
    under each of its ``score_rewards``); each row's overrides are merged over the setup's groups
    (the run's). ``diverged``: episodes whose simulation blew up (never a score)."""
    out: list[dict[str, Any]] = []
    phases = tuple(float(p) for p in phases) or (0.0,)
    score_rewards = setup.score_rewards
    motion = setup.motion.source or "motion"
    # Progress: each row x lookahead is seconds of simulation per phase (minutes at 240 Hz for all rows).
    total = sum(len(r.lookahead) or 1 for r in rows)
    started = time.perf_counter()
    simulated = 0
    for row in rows:
        options = not ControllerSpec.parse(resolve_group("controller", row.controller)).is_thesis_pd
        # (policy_groups: which joints a policy corrects; a baseline drives every joint itself)
        env_overrides = deep_merge(row.env, {"reference_state_init": False, "residual_velocity_range": 0.0,
                                             "policy_groups": None, "early_termination": {"min_reward": None},
                                             **({"action_mode": "residual"} if options else {})})
        instance = ImitationEnv.from_setup(setup.merged(body=row.body, controller=row.controller, env=env_overrides))
        try:
            steps = max(1, int(round(seconds * instance.spec_env.control_hz)))
            lookaheads = (instance.spec_env.reference_lookahead,) if options else row.lookahead
            for k in lookaheads:
                runs = [reference_rollout(instance, steps, k, start_time=p * instance.reference.duration)
                        for p in phases]
                simulated += sum(len(run.rewards) for run in runs)
                terms = {name: float(np.mean([run.terms.get(name, 0.0) for run in runs])) for name in runs[0].terms}
                out.append({"label": row.label, "controller": row.controller, "lookahead": k,
                            "aslexp": row.aslexp, "reward": float(np.mean([run.mean_reward for run in runs])),
                            "per_phase": [run.mean_reward for run in runs], "phases": list(phases),
                            "steps": int(np.mean([len(run.rewards) for run in runs])),
                            "planned_steps": steps, "fell": any(run.fell for run in runs),
                            "diverged": sum(run.diverged for run in runs),
                            "control_hz": instance.spec_env.control_hz, "base": instance.body_spec.base,
                            "terms": terms,
                            **({"scores": {name: float(np.mean([run.scores.get(name, 0.0) for run in runs]))
                                           for name in score_rewards}} if score_rewards else {})})
                done = len(out)
                spent = time.perf_counter() - started
                _log.info("baselines of %s: %d/%d (%s, lookahead %d) reward %.4f; %.1f s, %.0f steps/s, "
                          "ETA %.0f s", Path(str(motion)).stem, done, max(total, done), row.label, k,
                          out[-1]["reward"], spent, simulated / max(spent, 1e-9),
                          spent / done * max(total - done, 0))
        finally:
            instance.close()
    return out
