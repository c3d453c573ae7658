"""Reward terms against hand-computed values for known states."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aslexp.compose import resolve_group
from aslexp.envs.imitation import ImitationEnv
from aslexp.envs.reward import ImitationReward, PoseSnapshot, RewardSpec
from aslexp.sim.body import BodySpec, load_layout

from .thesis_values import TABLE_5_2


@pytest.fixture(scope="module")
def layout(data_root):
    return load_layout(BodySpec.parse(resolve_group("body", "hand15")), data_root)[1]


def snapshot(q=None, qd=None, ee=None, root_pos=(0, 0.9, 0), root_rot=(1, 0, 0, 0)):
    return PoseSnapshot(
        q=np.zeros(15) if q is None else np.asarray(q, float),
        qd=np.zeros(15) if qd is None else np.asarray(qd, float),
        end_effectors=np.zeros((5, 3)) if ee is None else np.asarray(ee, float),
        root_pos=np.asarray(root_pos, float), root_rot=np.asarray(root_rot, float),
        root_vel=np.zeros(3), root_ang_vel=np.zeros(3),
    )


@pytest.mark.parametrize("name", ["deepmimic", "hand_thesis"])
def test_table_5_2_is_the_config(name):
    spec = RewardSpec.parse(resolve_group("reward", name))
    assert {k: (t.weight, t.scale) for k, t in spec.terms.items()} == TABLE_5_2
    assert spec.combine == "sum" and not spec.normalize_joint_weights  # Eq. 5.12, sums (Eq. 5.10)


def test_hand_thesis_equals_the_hand_computation_and_the_code_is_an_option(layout):
    """Eq. 5.10/5.12 with Table 5.2 on a known state; the root counts as a joint (authors' code)."""
    q = np.zeros(15)
    q[[2, 9]] = [0.1, -0.2]
    qd = np.zeros(15)
    qd[[0, 7]] = [1.0, -2.0]
    ee = np.zeros((5, 3))
    ee[2] = [0.0, 0.01, 0.0]
    angle = 0.1
    sim = snapshot(q, qd, ee, root_pos=(0.1, 0.9, 0.0), root_rot=(math.cos(angle / 2), math.sin(angle / 2), 0, 0))
    errors = {"pose": 0.1 ** 2 + 0.2 ** 2 + angle ** 2, "velocity": 1.0 + 4.0, "end_effector": 0.01 ** 2 / 5,
              "root": 0.1 ** 2 + 0.1 * angle ** 2}
    for name, table in (("hand_thesis", TABLE_5_2),
                        ("hand_code", {"pose": (0.5 / 0.9, 2), "velocity": (0.05 / 0.9, 0.1),
                                       "end_effector": (0.15 / 0.9, 40), "root": (0.2 / 0.9, 5)})):
        total, _, got = ImitationReward(RewardSpec.parse(resolve_group("reward", name)), layout)(sim, snapshot())
        assert {k: got[k] for k in errors} == pytest.approx(errors, rel=1e-9), name
        assert total == pytest.approx(sum(w * math.exp(-k * errors[t]) for t, (w, k) in table.items()), rel=1e-9)


def test_identical_states_score_one(layout):
    reward = ImitationReward(RewardSpec.parse(resolve_group("reward", None)), layout)
    total, terms, errors = reward(snapshot(), snapshot())
    assert total == pytest.approx(1.0) and all(e == 0 for e in errors.values())


def test_terms_equal_hand_computed_values(layout):
    reward = ImitationReward(RewardSpec.parse(resolve_group("reward", None)), layout)
    q = np.zeros(15)
    q[4] = 0.1  # one joint 0.1 rad off
    qd = np.zeros(15)
    qd[[0, 7]] = [1.0, -2.0]  # two joints off in velocity
    ee = np.zeros((5, 3))
    ee[2] = [0.0, 0.01, 0.0]  # one fingertip 1 cm off
    sim = snapshot(q, qd, ee, root_pos=(0.1, 0.9, 0.0))
    total, terms, errors = reward(sim, snapshot())
    assert errors["pose"] == pytest.approx(0.01)
    assert errors["velocity"] == pytest.approx(5.0)
    assert errors["end_effector"] == pytest.approx(0.0001 / 5)
    assert errors["root"] == pytest.approx(0.01)
    expected = (0.65 * math.exp(-2 * 0.01) + 0.1 * math.exp(-0.1 * 5.0)
                + 0.15 * math.exp(-40 * 0.00002) + 0.1 * math.exp(-10 * 0.01))
    assert total == pytest.approx(expected)
    assert terms["velocity"] == pytest.approx(math.exp(-0.5))


def test_root_rotation_uses_the_quaternion_angle(layout):
    reward = ImitationReward(RewardSpec.parse(resolve_group("reward", None)), layout)
    angle = 0.3
    rotated = (math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0)
    _, _, errors = reward(snapshot(root_rot=rotated), snapshot())
    assert errors["root"] == pytest.approx(0.1 * angle ** 2)


def test_joint_group_weights_and_product_combination(layout):
    spec = RewardSpec.parse(resolve_group("reward", {"combine": "product", "joint_weights": {"thumb": 2.0}}))
    reward = ImitationReward(spec, layout)
    q = np.zeros(15)
    q[0] = 0.1  # thumb joint, weight 2
    total, terms, errors = reward(snapshot(q), snapshot())
    assert errors["pose"] == pytest.approx(0.02)
    assert total == pytest.approx(math.exp(-2 * 0.02) ** 0.65)


def test_env_reports_each_term(motion_a, data_root):
    env = ImitationEnv(motion_a, data_root=data_root, env={"reference_state_init": False})
    env.reset(options={"time": 0.0})
    _, reward, _, _, info = env.step(env.reference_action(1))
    parts = sum(w * info[f"r_{k}"] for k, w in
                {"pose": 0.65, "velocity": 0.1, "end_effector": 0.15, "root": 0.1}.items())
    assert reward == pytest.approx(parts)
    assert {"e_pose", "e_velocity", "e_end_effector", "e_root"} <= set(info)
    env.close()
