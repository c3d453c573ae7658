"""Agent-side controller options: reference velocity targets and physics-rate reference targets.

The thesis baselines stay defined with held position targets and zero velocity targets; the
stronger controller is reported beside them as ``reference_velocity_pd``.
"""

from __future__ import annotations

import numpy as np
import pytest

from aslexp.envs.imitation import ImitationEnv
from aslexp.rl.evaluate import baselines
from aslexp.sim.pd import ControllerSpec

RESIDUAL = {"action_mode": "residual", "residual_range": 0.2, "early_termination": {"min_reward": None}}


def test_controller_options_are_validated():
    spec = ControllerSpec.from_dict({"groups": {"default": {"kp": 0.22, "kd": 0.87}}})
    assert spec.is_thesis_pd and spec.target_velocity == "zero" and spec.target_rate == "control"
    with pytest.raises(ValueError, match="target_velocity must be one of"):
        ControllerSpec.from_dict({"groups": {"default": {"kp": 1, "kd": 1}}, "target_velocity": "ref"})
    with pytest.raises(ValueError, match="target_rate must be one of"):
        ControllerSpec.from_dict({"groups": {"default": {"kp": 1, "kd": 1}}, "target_rate": "fast"})


def test_physics_rate_needs_residual_actions(motion_a):
    with pytest.raises(ValueError, match="needs env action_mode residual"):
        ImitationEnv(motion_a, controller="reference_velocity", env={"action_mode": "absolute"})


def test_reference_velocity_pd_beats_the_thesis_baselines_which_stay_unchanged(motion_a):
    thesis = ImitationEnv(motion_a, env=RESIDUAL)
    stronger = ImitationEnv(motion_a, env=RESIDUAL, controller="reference_velocity")
    plain, both = baselines(thesis, steps=120), baselines(stronger, steps=120)
    assert set(plain) == {"reference", "lookahead"}
    assert both["reference"] == pytest.approx(plain["reference"], abs=1e-9)
    assert both["lookahead"] == pytest.approx(plain["lookahead"], abs=1e-9)
    # Measured over 300 steps: lookahead .933, reference-velocity PD at physics rate .967 (letter A).
    assert both["reference_velocity_pd"] > both["lookahead"] + 0.015, both
    thesis.close()
    stronger.close()


def test_reference_velocities_in_the_observation(motion_a):
    base = {"observe_future": [1, 2], "episode_steps": 10}
    env = ImitationEnv(motion_a, env={**base, "observe_future_velocities": True})
    plain = ImitationEnv(motion_a, env=base)
    assert env.observation_space.shape[0] == plain.observation_space.shape[0] + 2 * 15
    obs, _ = env.reset(options={"time": 0.25})
    expected = np.concatenate([env.reference.joint_velocities(0.25 + k * env.control_dt) for k in (1, 2)])
    np.testing.assert_allclose(obs[-30:], expected, rtol=1e-5, atol=1e-5)
    env.close()
    plain.close()
