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
    spec = ControllerSpec.parse({"groups": {"default": {"kp": 0.22, "kd": 0.87}}})
    assert spec.is_thesis_pd and spec.target_velocity == "zero" and spec.target_rate == "control"
    with pytest.raises(ValueError, match="controller.target_velocity=ref: expected one of zero, reference"):
        ControllerSpec.parse({"groups": {"default": {"kp": 1, "kd": 1}}, "target_velocity": "ref"})
    with pytest.raises(ValueError, match="controller.target_rate=fast: expected one of control, physics"):
        ControllerSpec.parse({"groups": {"default": {"kp": 1, "kd": 1}}, "target_rate": "fast"})


def test_physics_rate_needs_residual_actions(motion_a):
    with pytest.raises(ValueError, match="needs env action_mode residual"):
        ImitationEnv(motion_a, controller="reference_velocity", env={"action_mode": "absolute"})


@pytest.mark.parametrize("controller", ["reference_velocity", "reference_velocity_tuned"])
def test_reference_velocity_pd_beats_the_thesis_baselines_which_stay_unchanged(motion_a, controller):
    # The tuned controller has other gains: its baselines must still be the thesis controller's.
    thesis = ImitationEnv(motion_a, env=RESIDUAL)
    stronger = ImitationEnv(motion_a, env=RESIDUAL, controller=controller)
    plain, both = baselines(thesis, steps=120), baselines(stronger, steps=120)
    assert set(plain) == {"reference", "lookahead"}
    assert both["reference"] == pytest.approx(plain["reference"], abs=1e-9)
    assert both["lookahead"] == pytest.approx(plain["lookahead"], abs=1e-9)
    # Measured over 300 steps (letter A): lookahead .933, reference_velocity .967, tuned .970.
    assert both["reference_velocity_pd"] > both["lookahead"] + 0.015, both
    thesis.close()
    stronger.close()


def test_reference_velocities_in_the_observation(motion_a):
    base = {"observe_future": [1, 2], "episode_steps": 10, "observe_joints": False}  # the velocities come last
    env = ImitationEnv(motion_a, env={**base, "observe_future_velocities": True})
    plain = ImitationEnv(motion_a, env=base)
    assert env.observation_space.shape[0] == plain.observation_space.shape[0] + 2 * 15
    obs, _ = env.reset(options={"time": 0.25})
    expected = np.concatenate([env.reference.joint_velocities(0.25 + k * env.control_dt) for k in (1, 2)])
    np.testing.assert_allclose(obs[-30:], expected, rtol=1e-5, atol=1e-5)
    env.close()
    plain.close()


def test_velocity_corrections_extend_the_action(motion_a):
    cfg = {**RESIDUAL, "residual_velocity_range": 2.0, "episode_steps": 10}
    env = ImitationEnv(motion_a, env=cfg, controller="reference_velocity")
    plain = ImitationEnv(motion_a, env={**RESIDUAL, "episode_steps": 10}, controller="reference_velocity")
    assert env.action_space.shape == (30,) and env.action_space.high[-1] == pytest.approx(2.0)
    assert env.reference_action(1).shape == (30,)
    rewards = {}
    for name, e, action in (("zero", env, np.zeros(30)), ("plain", plain, np.zeros(15)),
                            ("pushed", env, np.r_[np.zeros(15), np.full(15, 2.0)])):
        e.reset(options={"time": 0.1})
        rewards[name] = e.step(action)[1]
    assert rewards["zero"] == pytest.approx(rewards["plain"], abs=1e-12)  # zero correction: the controller
    assert rewards["pushed"] != pytest.approx(rewards["zero"], abs=1e-6)
    with pytest.raises(ValueError, match="expected 30"):
        env.step(np.zeros(15))
    env.close()
    plain.close()
