"""A controller whose joint groups carry their own mode: the thesis' upper body (THESIS.md 4.9, its
text) drives the body joints with stable PD and the hands' finger joints with the chapter-5 hand's
position motor (kp 0.22, kd 0.87). One PyBullet motor call per mode with that mode's joints, the
stable-PD rules (re-sent every substep, no fixed base) as soon as one group is stable PD, and in
MuJoCo physical gains for stable-PD actuators and the position motor's stand-in for the others."""

from __future__ import annotations

import numpy as np
import pytest

from aslexp.compose import resolve_group
from aslexp.envs.tracking import reference_rollout
from aslexp.envs.upper_body import UpperBodyImitationEnv
from aslexp.sim.pd import ControllerSpec

from . import thesis_values as T

BODY_GROUPS = ("chest", "neck", "shoulder", "elbow", "wrist")


@pytest.fixture(scope="module")
def sign(data_root):
    return data_root / "motions" / "upper_body" / "00433.txt"


def make(sign, data_root, base, controller="upper_body_thesis", env="upper_body_thesis", **kwargs):
    return UpperBodyImitationEnv(sign, body={"base": base}, controller=controller, reward="upper_body_thesis",
                                 env=env, data_root=data_root, **kwargs)


def test_group_modes_parse_and_are_checked():
    spec = ControllerSpec.parse(resolve_group("controller", "upper_body_thesis"))
    assert spec.mode == "stable_pd"
    assert spec.mode_of(spec.groups["fingers"]) == "position"
    assert all(spec.mode_of(spec.groups[g]) == "stable_pd" for g in BODY_GROUPS)  # None: the controller's
    with pytest.raises(ValueError, match="controller.groups.fingers.mode=torque: expected null or one of position, stable_pd"):
        ControllerSpec.parse({"mode": "position", "groups": {"fingers": {"kp": 1, "kd": 1, "mode": "torque"}}})
    with pytest.raises(ValueError, match=r"controller.groups.default.kv=1: unknown key; expected one of kp, kd"):
        ControllerSpec.parse({"groups": {"default": {"kp": 1, "kv": 1}}})
    with pytest.raises(ValueError, match="physical_groups are physical gains: no mode"):
        ControllerSpec.parse({"groups": {"default": {"kp": 1, "kd": 1}},
                                  "physical_groups": {"default": {"kp": 1, "kd": 1, "mode": "position"}}})


def test_mixed_controller_sends_one_call_per_mode_and_the_pinned_body_follows(sign, data_root):
    env = make(sign, data_root, "pinned")
    controller = env.controller
    fingers = [k for k, j in enumerate(env.layout.joints) if j.group == "fingers"]
    assert len(fingers) == 30
    assert [k for k, m in enumerate(controller.modes) if m == "position"] == fingers
    assert controller.resend_every_substep
    pb = env.sim.world.client
    calls = []
    for name in ("setJointMotorControlArray", "setJointMotorControlMultiDofArray"):
        original = getattr(pb, name)

        def record(body, joints, mode, *args, _name=name, _original=original, **kwargs):
            calls.append((_name, mode, list(joints), list(kwargs["positionGains"])))
            return _original(body, joints, mode, *args, **kwargs)

        setattr(pb, name, record)
    try:
        run = reference_rollout(env, 240, lookahead=1)  # 1 s at 240 Hz, one physics step per action
    finally:
        for name in ("setJointMotorControlArray", "setJointMotorControlMultiDofArray"):
            delattr(pb, name)
    assert controller.commands_sent == 240 and controller.motor_calls == {"position": 240, "stable_pd": 240}
    ids = env.sim.joint_indices
    finger_ids = [ids[k] for k in fingers]
    body_ids = [i for i in ids if i not in finger_ids]
    position = [c for c in calls if c[1] == pb.POSITION_CONTROL]
    stable = [c for c in calls if c[1] == pb.STABLE_PD_CONTROL]
    assert len(position) == len(stable) == 240 and len(calls) == 480
    # the fingers (all revolute) through the array call with the hand's gains, the rest stable PD
    assert {(c[0], tuple(c[2])) for c in position} == {("setJointMotorControlArray", tuple(finger_ids))}
    assert {(c[0], tuple(c[2])) for c in stable} == {("setJointMotorControlMultiDofArray", tuple(body_ids))}
    assert position[0][3] == [0.22] * 30
    assert stable[0][3] == [T.UPPER_BODY_GAINS[env.layout.joints[ids.index(i)].group][0] for i in body_ids]
    # and the joints follow: the reward and the fingers' distance to the reference (measured: 0.871 and
    # 0.089 rad under the authors' 10 x 1 solver, 0.023 rad at 10 x 10; fingers held still: 0.73 rad)
    assert run.mean_reward > 0.8 and not run.ended_early, run.mean_reward
    q, _ = env.sim.joint_state()
    reference = env.reference.joints(env.time)
    offsets = np.cumsum([0] + [j.dof for j in env.layout.joints])
    finger_error = np.abs(q[offsets[fingers]] - reference[offsets[fingers]])
    assert finger_error.mean() < 0.2, finger_error.mean()
    env.close()


def test_any_stable_pd_group_refuses_a_fixed_base(sign, data_root):
    with pytest.raises(ValueError, match=r"stable PD needs a free base.*7 slots.*stable-PD groups \['chest'"):
        make(sign, data_root, "fixed")
    one_group = {"name": "one_stable_group", "mode": "position",
                 "groups": {"default": {"kp": 0.22, "kd": 0.87}, "wrist": {"kp": 50.0, "kd": 0.5, "mode": "stable_pd"}}}
    with pytest.raises(ValueError, match=r"stable PD needs a free base.*stable-PD groups \['wrist'\]"):
        make(sign, data_root, "fixed", controller=one_group, env="upper_body")
    one_group["groups"]["wrist"]["mode"] = "position"  # no stable-PD group: a fixed base is fine
    env = make(sign, data_root, "fixed", controller=one_group, env="upper_body")
    assert not env.controller.resend_every_substep
    env.close()


def test_mujoco_gives_position_groups_the_stand_in_and_stable_pd_groups_physical_gains(sign, data_root):
    env = make(sign, data_root, "pinned", engine="mujoco")
    body = env.sim.body
    body.set_gains(env.controller)
    m = body.model
    dt, scale = m.opt.timestep, body.engine.options.motor_gain_scale
    inertia = body.joint_inertia()
    groups = env.controller.spec.groups
    i = 0
    for joint in env.layout.joints:
        gains = groups[joint.group]
        for _ in range(1 if joint.dof == 1 else 3):
            kp, bias = m.actuator_gainprm[i, 0], m.actuator_biasprm[i, :3]
            if joint.group == "fingers":  # PyBullet's velocity-constraint motor, translated, uncapped
                assert kp == pytest.approx(scale * 0.22 * inertia[i] / dt ** 2, rel=1e-9)
                assert bias[2] == pytest.approx(-(1.0 + 0.87) * inertia[i] / dt, rel=1e-9)
                assert not m.actuator_forcelimited[i]
            else:  # stable PD: the physical gains, capped at max_force
                assert (kp, bias[1]) == (gains.kp, -gains.kp)
                assert bias[2] == pytest.approx(-(gains.kd + gains.kp * dt), rel=1e-12)
                assert m.actuator_forcelimited[i] and m.actuator_forcerange[i, 1] == gains.max_force
            i += 1
    assert i == m.nu
    env.close()
