"""The upper body's rewards against hand computations of Eqs. 5.10 and 6.1-6.3 on a known state:
every k column of Tables 6.4 and 6.5 (summed errors, wrists with the hands, the root a joint of the
body terms), the code's root scale, and the averaged alternative."""

from __future__ import annotations

import math

import numpy as np
import pytest

from aslexp.compose import resolve_group
from aslexp.envs.reward import ImitationReward, PoseSnapshot, RewardSpec
from aslexp.sim.body import BodySpec, load_layout

from . import thesis_values as T

COLUMNS = {**{f"upper_body_table6_4_{c}": k for c, k in T.TABLE_6_4.items()},
           **{f"upper_body_table6_5_{c}": k for c, k in T.TABLE_6_5.items()},
           "upper_body_thesis": T.TABLE_6_5["run4"]}


@pytest.fixture(scope="module")
def layout(data_root):
    return load_layout(BodySpec.parse(resolve_group("body", "upper_body")), data_root)[1]


def rest(layout, **changes):
    """Identity quaternions and zero angles, velocities and wrist positions, then ``changes``."""
    q = np.concatenate([[1.0, 0.0, 0.0, 0.0] if j.dof == 4 else [0.0] for j in layout.joints])
    qd = np.zeros(sum(3 if j.dof == 4 else 1 for j in layout.joints))
    values = dict(q=q, qd=qd, end_effectors=np.zeros((2, 3)), root_pos=np.asarray([0.0, 0.9, 0.0]),
                  root_rot=np.asarray([1.0, 0.0, 0.0, 0.0]), root_vel=np.zeros(3), root_ang_vel=np.zeros(3))
    values.update(changes)
    return PoseSnapshot(**values)


def offsets(layout):
    q_at, v_at, q, v = {}, {}, 0, 0
    for j in layout.joints:
        q_at[j.name], v_at[j.name] = q, v
        q, v = q + j.dof, v + (3 if j.dof == 4 else 1)
    return q_at, v_at


def known_state(layout):
    """A simulated state off the reference in every term, and its errors worked out by hand."""
    q_at, v_at = offsets(layout)
    chest_angle, root_angle = 0.3, 0.2
    sim = rest(layout, root_pos=np.asarray([0.01, 0.9, 0.0]),
               root_rot=np.asarray([math.cos(root_angle / 2), 0.0, 0.0, math.sin(root_angle / 2)]),
               root_vel=np.asarray([0.1, 0.0, 0.0]), root_ang_vel=np.asarray([0.0, 0.5, 0.0]))
    sim.q[q_at["chest"]:q_at["chest"] + 4] = [math.cos(chest_angle / 2), 0.0, math.sin(chest_angle / 2), 0.0]
    sim.q[q_at["right_elbow"]] = 0.2
    sim.q[q_at["left_wrist"]] = 0.4          # a wrist: the hands' group (the authors' grouping)
    sim.q[q_at["l_index_inter"]] = 0.1
    sim.qd[v_at["neck"]:v_at["neck"] + 3] = [1.0, 2.0, 0.0]   # |dw|^2 = 5
    sim.qd[v_at["right_wrist"]] = 2.0
    sim.qd[v_at["r_thumb_prox"]] = 3.0
    sim.end_effectors[0] = [0.0, 0.02, 0.0]  # right wrist 2 cm off
    # Eq. 5.10: sums over joints; the root is one more joint of the body terms (authors' code).
    errors = {
        "pose_body": chest_angle ** 2 + 0.2 ** 2 + root_angle ** 2,
        "pose_hands": 0.4 ** 2 + 0.1 ** 2,
        "velocity_body": 5.0 + 0.5 ** 2,
        "velocity_hands": 2.0 ** 2 + 3.0 ** 2,
        "end_effector": 0.02 ** 2 / 2,                     # mean over the two wrists
        "root": 0.01 ** 2 + 0.1 * root_angle ** 2 + 0.01 * 0.1 ** 2 + 0.001 * 0.5 ** 2,
    }
    return sim, rest(layout), errors


@pytest.mark.parametrize("name", sorted(COLUMNS))
def test_each_thesis_column_equals_the_hand_computation(layout, name):
    kpb, kph, kvb, kvh = COLUMNS[name]
    reward = ImitationReward(RewardSpec.parse(resolve_group("reward", name)), layout)
    sim, ref, errors = known_state(layout)
    total, terms, got = reward(sim, ref)
    scales = {"pose_body": kpb, "pose_hands": kph, "velocity_body": kvb, "velocity_hands": kvh,
              "end_effector": T.K_END_EFFECTOR, "root": T.K_ROOT}
    for term, error in errors.items():
        assert got[term] == pytest.approx(error, rel=1e-9), term
        assert terms[term] == pytest.approx(math.exp(-scales[term] * error), rel=1e-9), term
    # Eq. 6.1-6.3: r = (r_p,b r_p,h) (r_v,b r_v,h) r_e r_r
    r_p = terms["pose_body"] * terms["pose_hands"]
    r_v = terms["velocity_body"] * terms["velocity_hands"]
    assert total == pytest.approx(r_p * r_v * terms["end_effector"] * terms["root"], rel=1e-9)
    assert total == pytest.approx(math.exp(-sum(scales[t] * e for t, e in errors.items())), rel=1e-9)


def test_the_codes_root_scale_is_an_option(layout):
    sim, ref, errors = known_state(layout)
    text = ImitationReward(RewardSpec.parse(resolve_group("reward", "upper_body_table6_4_run3")), layout)
    code = ImitationReward(RewardSpec.parse(resolve_group("reward", "upper_body_code")), layout)
    (r_text, _, _), (r_code, terms, _) = text(sim, ref), code(sim, ref)
    assert terms["root"] == pytest.approx(math.exp(-T.K_ROOT_CODE * errors["root"]))
    assert r_code / r_text == pytest.approx(math.exp((T.K_ROOT - T.K_ROOT_CODE) * errors["root"]))


def test_the_averaged_reward_is_a_named_alternative(layout):
    # aslexp's earlier default: means over joints, wrists in the body, no root in the body terms.
    spec = RewardSpec.parse(resolve_group("reward", "upper_body_averaged"))
    sim, ref, _ = known_state(layout)
    _, _, errors = ImitationReward(spec, layout)(sim, ref)
    body, hands = 8, 30  # chest, neck, 2 shoulders, 2 elbows, 2 wrists | 2 x 15 finger joints
    assert errors["pose_body"] == pytest.approx((0.3 ** 2 + 0.2 ** 2 + 0.4 ** 2) / body)
    assert errors["pose_hands"] == pytest.approx(0.1 ** 2 / hands)
    assert errors["velocity_hands"] == pytest.approx(9.0 / hands)


def test_identical_states_score_one_and_the_additive_reward_stays_selectable(layout):
    for name in ("upper_body_thesis", "upper_body_averaged", "deepmimic_upper_body", "deepmimic"):
        reward = ImitationReward(RewardSpec.parse(resolve_group("reward", name)), layout)
        total, _, _ = reward(rest(layout), rest(layout))
        assert total == pytest.approx(1.0), name
    additive = ImitationReward(RewardSpec.parse(resolve_group("reward", "deepmimic_upper_body")), layout)
    q_at, _ = offsets(layout)
    sim = rest(layout)
    sim.q[q_at["l_index_inter"]] = 0.1
    total, _, errors = additive(sim, rest(layout))
    assert errors["pose"] == pytest.approx(0.01)  # a sum over all joints, as for the hand
    assert total == pytest.approx(0.65 * math.exp(-2 * 0.01) + 0.35)


def test_bad_reward_configs_are_clear_errors(layout):
    with pytest.raises(ValueError, match=r"reward.terms.posture: unknown term \(error 'posture'\)"):
        RewardSpec.parse({"terms": {"posture": {"weight": 1, "scale": 1}}})
    with pytest.raises(ValueError, match="`groups` and `root` apply to pose and velocity only"):
        RewardSpec.parse({"terms": {"root": {"weight": 1, "scale": 1, "groups": ["chest"]}}})
    spec = RewardSpec.parse({"terms": {"pose_x": {"weight": 1, "scale": 1, "error": "pose",
                                                      "groups": ["tail"]}}})
    with pytest.raises(ValueError, match=r"'pose_x'.*\['tail'\]"):
        ImitationReward(spec, layout)
