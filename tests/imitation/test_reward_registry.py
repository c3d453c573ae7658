"""A new kind of reward error is a module plus a YAML: registered from the tests,
it scores the single and the batched environment with no edit to aslexp."""

from __future__ import annotations

import numpy as np
import pytest

from aslexp.envs import reward as rewards
from aslexp.envs.batched import BatchedImitationEnv
from aslexp.envs.imitation import ImitationEnv

from .registration import fresh_registration

# conf/reward/worst_tip.yaml, as a user would write it
WORST_TIP = {"module": "worst_tip_error", "combine": "sum",
             "terms": {"pose": {"weight": 0.5, "scale": 2.0}, "worst_tip": {"weight": 0.5, "scale": 40.0}}}


@pytest.fixture
def worst_tip(monkeypatch):
    for _ in fresh_registration(monkeypatch, "worst_tip_error", lambda: rewards.unregister_error("worst_tip")):
        yield WORST_TIP


def test_a_registered_error_is_a_reward_term_in_both_environments(worst_tip, motion_a):
    env = ImitationEnv(motion_a, body="hand15", controller="thesis", reward=worst_tip, env="default", engine="mujoco",
                       complete_configs=True)  # the reward as given, not merged over the default file
    env.reset(options={"time": 0.3})
    action = env.reference_action(1)
    _, reward, _, _, info = env.step(action)
    sim, ref = env.last_sim_state, env.last_reference_state
    expected = np.max(np.sum((sim.end_effectors - ref.end_effectors) ** 2, axis=-1))
    assert info["e_worst_tip"] == pytest.approx(expected) and expected > 0
    assert info["e_worst_tip"] >= info["e_end_effector"]  # the worst tip against their mean
    assert reward == pytest.approx(0.5 * np.exp(-2.0 * info["e_pose"]) + 0.5 * np.exp(-40.0 * expected))
    batch = BatchedImitationEnv(1, motion_a, body="hand15", controller="thesis", reward=worst_tip, env="default",
                                engine="mujoco", complete_configs=True)
    batch.reset(options={"time": 0.3})
    _, batch_reward, _, _, _ = batch.step(action[None])
    assert batch_reward[0] == pytest.approx(reward, abs=1e-9)  # the same step, the same error
    batch.close(), env.close()


def test_an_unregistered_error_is_refused_with_the_way_to_register_it(worst_tip):
    with pytest.raises(ValueError, match=r"reward.terms.worst_tip: unknown term.*reward.module names its module"):
        rewards.RewardSpec.parse({"terms": worst_tip["terms"]})
    with pytest.raises(ValueError, match="reward.module=no_such_errors: could not be imported"):
        rewards.RewardSpec.parse({**worst_tip, "module": "no_such_errors"})
    with pytest.raises(ValueError, match="'pose' is built in"):
        rewards.register_error("pose")(lambda reward, sim, ref: 0)
