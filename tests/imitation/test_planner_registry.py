"""A planner update is a module plus a YAML (the registry shaped like the reward errors'), and a
planned episode whose body falls ends there, counted as a fall."""

from __future__ import annotations

import numpy as np
import pytest

from aslexp.control import mpc
from aslexp.control.mpc import PlannerSpec, SamplingPlanner, evaluate_planner, plan_episode
from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.batched import BatchedImitationEnv

from .registration import fresh_registration

TRACKING = {"control_hz": 30, "action_mode": "residual", "residual_range": 0.2, "reference_state_init": False,
            "early_termination": {"min_reward": None}}


@pytest.fixture
def elite(monkeypatch):
    for _ in fresh_registration(monkeypatch, "elite_planner", lambda: mpc.unregister_update("elite_mean")):
        yield {"method": "elite_mean", "module": "elite_planner", "horizon": 3, "samples": 8, "noise": 0.05}


def test_a_registered_update_plans_with_no_edit_to_aslexp(elite, data_root):
    with pytest.raises(ValueError, match=r"planner.method=elite_mean: expected one of predictive_sampling, mppi, "
                                         r"cem \(a registered update: planner.module names its module\)"):
        PlannerSpec.parse({k: v for k, v in elite.items() if k != "module"})
    spec = PlannerSpec.parse(elite)  # its module imported: the update registered
    assert "elite_mean" in mpc.update_names()
    setup = ImitationSetup.from_groups(data_root / "motions/hand/A.txt", "hand15", "reference_velocity_tuned",
                                       "hand_thesis", TRACKING, "mujoco", data_root=data_root)
    planner = SamplingPlanner(spec, setup)
    body = BatchedImitationEnv.from_setup(1, setup)
    episode = plan_episode(planner, body, 0.2, 6)
    planner.close(), body.close()
    assert len(episode.rewards) == 6 and not episode.diverged and all(0 < r <= 1 for r in episode.rewards)
    # the plan is the mean of two candidates: a correction no single candidate had (the zero plan is one)
    assert any(np.abs(a).max() > 0 for a in episode.actions)
    with pytest.raises(ValueError, match="already registered"):
        mpc.register_update("elite_mean")(lambda *a: a)
    with pytest.raises(ValueError, match="planner.module=no_such_planners: could not be imported"):
        PlannerSpec.parse({**elite, "module": "no_such_planners"})


def test_a_planned_episode_that_falls_ends_there_and_is_counted(data_root):
    """Position control of the standing upper body falls within seconds (the standing ceiling's
    reference-velocity row: 0.06-0.24); a planner too weak to hold it (3 samples, a horizon of one
    step, no noise to speak of) falls with it: the episode ends at the fall, counted as one, not as a
    blow-up, and the score is over the steps it stood."""
    setup = ImitationSetup.from_groups(data_root / "motions/upper_body/00433.txt", {"base": "free"},
                                       "upper_body_reference_velocity", "upper_body_table6_4_run3",
                                       {"action_mode": "residual", "residual_range": 0.2, "reference_state_init": False,
                                        "early_termination": {"min_reward": None, "fall": True}},
                                       "mujoco", data_root=data_root,
                                       defaults={"body": "upper_body"})
    planner = SamplingPlanner(PlannerSpec(horizon=1, knots=1, samples=3, noise=1e-9), setup)
    body = BatchedImitationEnv.from_setup(1, setup.merged(env={"episode_steps": 240}))
    episode = plan_episode(planner, body, 0.0, 240)
    planner.close(), body.close()
    assert episode.fell and not episode.diverged and 0 < len(episode.rewards) < 240
    assert episode.mean_reward == pytest.approx(sum(episode.rewards) / 240)  # no score after the fall
    result = evaluate_planner(PlannerSpec(horizon=1, knots=1, samples=3, noise=1e-9), setup, (0.0,), 240)
    assert result["fell"] == 1 and result["diverged"] == 0
    assert result["reward"] == pytest.approx(episode.mean_reward, abs=1e-9)  # the same episode, evaluated
