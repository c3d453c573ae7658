"""One place assembles an imitation experiment: the environment, the batch, the
baselines and the job all build from an :class:`~aslexp.envs.assembly.ImitationSetup`."""

from __future__ import annotations

import pickle

import numpy as np
import pytest

from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.batched import BatchedImitationEnv
from aslexp.envs.baselines import Baseline, no_learning_baselines
from aslexp.envs.imitation import ImitationEnv


def test_the_env_of_a_setup_is_the_env_of_its_groups(motion_a):
    setup = ImitationSetup.from_groups(motion_a, "hand15", "thesis", "hand_thesis", "default")
    assert setup.body.name == "hand15" and setup.env.control_hz == 30 and setup.engine.name == "pybullet"
    a, b = ImitationEnv.from_setup(setup), ImitationEnv(motion_a, reward="hand_thesis", env="default")
    for env in (a, b):
        env.reset(options={"time": 0.2})
    for _ in range(5):
        step_a, step_b = a.step(a.reference_action(1)), b.step(b.reference_action(1))
        np.testing.assert_array_equal(step_a[0], step_b[0])
        assert step_a[1] == step_b[1]
    a.close(), b.close()
    # workers receive the setup pickled: it survives the trip whole
    assert pickle.loads(pickle.dumps(setup)).groups == setup.groups


def test_merged_overrides_one_group_and_keeps_the_rest(motion_a):
    setup = ImitationSetup.from_groups(motion_a, engine="mujoco")
    pinned = setup.merged(body={"base": "pinned"}, env={"control_hz": 240})
    assert pinned.body.base == "pinned" and setup.body.base == "fixed"
    assert pinned.env.control_hz == 240 and pinned.env.physics_hz == setup.env.physics_hz
    assert pinned.engine == setup.engine and pinned.motion is setup.motion
    swapped = setup.merged(controller="reference_velocity_tuned")  # a name replaces the group
    assert swapped.controller.target_velocity == "reference" and not swapped.controller.is_thesis_pd
    with pytest.raises(ValueError, match="unknown config group 'ppo'"):
        setup.merged(ppo={"lr": 1})
    # the batch and the single environment are built from the same setup
    batch = BatchedImitationEnv.from_setup(3, setup)
    assert batch.num_envs == 3 and batch.template.setup is setup
    batch.close()


def test_baselines_take_a_setup_and_each_row_overrides_it(motion_a):
    setup = ImitationSetup.from_groups(motion_a, reward="hand_thesis", env="default")
    rows = no_learning_baselines(setup, [Baseline(label="fixed", controller="thesis", lookahead=(1,)),
                                         Baseline(label="pinned", controller="thesis", body={"base": "pinned"},
                                                  lookahead=(1,))], seconds=0.5)
    assert [r["base"] for r in rows] == ["fixed", "pinned"] and all(r["steps"] == 15 for r in rows)
    env = ImitationEnv.from_setup(setup)
    env.reset(options={"time": 0.0})
    direct = np.mean([env.step(env.reference_action(1))[1] for _ in range(15)])
    assert rows[0]["reward"] == pytest.approx(direct)
    env.close()
