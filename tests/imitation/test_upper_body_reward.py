"""The multiplicative reward of the upper body (thesis 6.1-6.3) against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aslexp.envs.config import CONF_DIR, resolve_group
from aslexp.envs.reward import ImitationReward, PoseSnapshot, RewardSpec
from aslexp.sim.body import BodySpec, load_layout


@pytest.fixture(scope="module")
def layout(data_root):
    return load_layout(BodySpec.from_dict(resolve_group("body", "upper_body")), data_root)[1]


def rest(layout, **changes):
    """Identity quaternions and zero angles, velocities and wrist positions, then ``changes``."""
    q = np.concatenate([[1.0, 0.0, 0.0, 0.0] if j.dof == 4 else [0.0] for j in layout.joints])
    qd = np.zeros(sum(3 if j.dof == 4 else 1 for j in layout.joints))
    values = dict(q=q, qd=qd, end_effectors=np.zeros((2, 3)), root_pos=np.asarray([0.0, 0.9, 0.0]),
                  root_rot=np.asarray([1.0, 0.0, 0.0, 0.0]), root_vel=np.zeros(3), root_ang_vel=np.zeros(3))
    values.update(changes)
    return PoseSnapshot(**values)


def offsets(layout):
    """Position and velocity offsets of every joint in the state vectors."""
    q_at, v_at, q, v = {}, {}, 0, 0
    for j in layout.joints:
        q_at[j.name], v_at[j.name] = q, v
        q, v = q + j.dof, v + (3 if j.dof == 4 else 1)
    return q_at, v_at


def test_multiplicative_terms_equal_hand_computed_values(layout):
    spec = RewardSpec.from_dict(resolve_group("reward", "multiplicative"))
    assert spec.combine == "product" and spec.normalize_joint_weights
    reward = ImitationReward(spec, layout)
    q_at, v_at = offsets(layout)
    ref = rest(layout)
    sim = rest(layout)
    angle = 0.3  # chest rotated 0.3 rad about y
    sim.q[q_at["chest"]:q_at["chest"] + 4] = [math.cos(angle / 2), 0.0, math.sin(angle / 2), 0.0]
    sim.q[q_at["right_elbow"]] = 0.2
    sim.q[q_at["l_index_inter"]] = 0.1
    sim.qd[v_at["neck"]:v_at["neck"] + 3] = [1.0, 2.0, 0.0]  # |dw|^2 = 5
    sim.qd[v_at["r_thumb_prox"]] = 3.0
    sim.end_effectors[0] = [0.0, 0.02, 0.0]  # right wrist 2 cm off
    total, terms, errors = reward(sim, ref)
    body, hands = 8, 30  # chest, neck, 2 shoulders, 2 elbows, 2 wrists | 2 x 15 finger joints
    expected_errors = {"pose_body": (angle ** 2 + 0.2 ** 2) / body, "pose_hands": 0.1 ** 2 / hands,
                       "velocity_body": 5.0 / body, "velocity_hands": 9.0 / hands,
                       "end_effector": 0.02 ** 2 / 2, "root": 0.0}
    scales = {"pose_body": 2.0, "pose_hands": 2.0, "velocity_body": 0.1, "velocity_hands": 0.1,
              "end_effector": 40.0, "root": 10.0}
    for name, value in expected_errors.items():
        assert errors[name] == pytest.approx(value), name
        assert terms[name] == pytest.approx(math.exp(-scales[name] * value)), name
    # r = r_p * r_v * r_e * r_r with r_p and r_v split into body and hands.
    r_p = terms["pose_body"] * terms["pose_hands"]
    r_v = terms["velocity_body"] * terms["velocity_hands"]
    assert total == pytest.approx(r_p * r_v * terms["end_effector"] * terms["root"])
    assert total == pytest.approx(math.exp(-sum(scales[k] * v for k, v in expected_errors.items())))


def test_identical_states_score_one_and_the_additive_reward_stays_selectable(layout):
    for name in ("multiplicative", "deepmimic_upper_body", "deepmimic"):
        reward = ImitationReward(RewardSpec.from_dict(resolve_group("reward", name)), layout)
        total, _, _ = reward(rest(layout), rest(layout))
        assert total == pytest.approx(1.0), name
    additive = ImitationReward(RewardSpec.from_dict(resolve_group("reward", "deepmimic_upper_body")), layout)
    q_at, _ = offsets(layout)
    sim = rest(layout)
    sim.q[q_at["l_index_inter"]] = 0.1
    total, _, errors = additive(sim, rest(layout))
    assert errors["pose"] == pytest.approx(0.01)  # a weighted sum over all joints, as for the hand
    assert total == pytest.approx(0.65 * math.exp(-2 * 0.01) + 0.35)


def test_named_k_factor_sets_exist_and_say_where_numbers_are_unknown():
    names = ["multiplicative"] + [f"multiplicative_run{i}" for i in (1, 2, 3)] + \
        [f"multiplicative_father_run{i}" for i in (1, 2, 3, 4)]
    for name in names:
        spec = RewardSpec.from_dict(resolve_group("reward", name))
        assert set(spec.terms) == {"pose_body", "pose_hands", "velocity_body", "velocity_hands",
                                   "end_effector", "root"}
        text = (CONF_DIR / "reward" / f"{name}.yaml").read_text()
        assert "not available offline" in text, name


def test_bad_reward_configs_are_clear_errors(layout):
    with pytest.raises(ValueError, match="unknown term 'posture'"):
        RewardSpec.from_dict({"terms": {"posture": {"weight": 1, "scale": 1}}})
    with pytest.raises(ValueError, match="groups.*pose and velocity only"):
        RewardSpec.from_dict({"terms": {"root": {"weight": 1, "scale": 1, "groups": ["chest"]}}})
    spec = RewardSpec.from_dict({"terms": {"pose_x": {"weight": 1, "scale": 1, "error": "pose",
                                                      "groups": ["tail"]}}})
    with pytest.raises(ValueError, match=r"'pose_x'.*\['tail'\]"):
        ImitationReward(spec, layout)
