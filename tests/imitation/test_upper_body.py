"""The upper-body humanoid with two hands (thesis chapter 6): model, motion mapping, environment."""

from __future__ import annotations

import json

import gymnasium as gym
import numpy as np
import pybullet
import pytest

import aslexp  # noqa: F401  (registers the environments)
from aslexp.compose import resolve_group
from aslexp.envs.upper_body import UpperBodyImitationEnv
from aslexp.pose.retarget import UPPER_BODY_COLUMNS
from aslexp.sim.body import BodySpec, load_layout
from aslexp.sim.motion import MotionFormatError
from aslexp.sim.upper_body import UpperBodyProportions, build_upper_body_urdf, write_upper_body_urdf
from aslexp.sim.urdf import compare_joint_tables, read_joints
from aslexp.quaternion import multiply as quat_multiply


@pytest.fixture(scope="module")
def thesis_urdf(data_root):
    path = data_root / "models" / "whole_upper_humanoid.urdf"
    if not path.is_file():
        pytest.skip(f"thesis model not found: {path}")
    return path


@pytest.fixture(scope="module")
def sign(data_root):
    return data_root / "motions" / "upper_body" / "00433.txt"


def test_built_model_matches_the_thesis_model(tmp_path, thesis_urdf):
    ours = read_joints(write_upper_body_urdf(tmp_path / "upper.urdf"))
    theirs = read_joints(thesis_urdf)
    assert compare_joint_tables(ours, theirs) == []
    types = [j.type for j in ours]
    assert (len(ours), types.count("fixed"), types.count("spherical"), types.count("revolute")) == (45, 7, 4, 34)
    by_name = {j.name: j for j in ours}
    for side in ("right", "left"):
        assert by_name[f"{side}_elbow"].axis == (0.0, 0.0, 1.0)
        assert (by_name[f"{side}_elbow"].lower, by_name[f"{side}_elbow"].upper) == (0.0, 3.14)
        assert by_name[f"{side}_wrist"].axis == (1.0, 0.0, 0.0)
        assert (by_name[f"{side}_wrist"].lower, by_name[f"{side}_wrist"].upper) == (-1.57, 1.57)
    assert by_name["r_index_prox"].axis == (1.0, 0.0, 0.0) and by_name["l_index_prox"].axis == (-1.0, 0.0, 0.0)
    assert by_name["l_thumb_prox"].axis == (0.0, 1.0, 0.0)  # the thesis mirrors only x-axis fingers


def test_built_model_has_the_thesis_link_frames_in_pybullet(tmp_path, thesis_urdf):
    client = pybullet.connect(pybullet.DIRECT)
    try:
        kwargs = dict(useFixedBase=True, globalScaling=0.25, flags=pybullet.URDF_MAINTAIN_LINK_ORDER,
                      physicsClientId=client)
        ours = pybullet.loadURDF(str(write_upper_body_urdf(tmp_path / "upper.urdf")), **kwargs)
        theirs = pybullet.loadURDF(str(thesis_urdf), **kwargs)
        n = pybullet.getNumJoints(ours, physicsClientId=client)
        assert n == pybullet.getNumJoints(theirs, physicsClientId=client) == 45
        for j in range(n):
            a = pybullet.getJointInfo(ours, j, physicsClientId=client)
            b = pybullet.getJointInfo(theirs, j, physicsClientId=client)
            assert (a[1], a[2], a[13]) == (b[1], b[2], b[13])  # name, type, axis
            pa = pybullet.getLinkState(ours, j, physicsClientId=client)[4:6]
            pb = pybullet.getLinkState(theirs, j, physicsClientId=client)[4:6]
            np.testing.assert_allclose(pa[0], pb[0], atol=1e-6)
            np.testing.assert_allclose(pa[1], pb[1], atol=1e-6)
    finally:
        pybullet.disconnect(client)


def test_builder_options_and_errors(tmp_path):
    smaller = UpperBodyProportions.parse({"hand": {"palm_mass": 0.3}, "wrist_limits": [-1.0, 1.0]})
    text = build_upper_body_urdf(smaller)
    assert 'mass value="0.3"' in text and 'lower="-1" upper="1"' in text
    with pytest.raises(ValueError, match="body.proportions.tail=1: unknown key"):
        UpperBodyProportions.parse({"tail": 1})
    with pytest.raises(FileNotFoundError, match="nope.urdf"):
        build_upper_body_urdf(UpperBodyProportions(humanoid=str(tmp_path / "nope.urdf")))


def test_body_config_layout_is_the_76_column_format(data_root):
    spec = BodySpec.parse(resolve_group("body", "upper_body"))
    assert [tuple(entry) for entry in spec.motion_layout] == list(UPPER_BODY_COLUMNS)
    for name in ("upper_body", "upper_body_thesis"):
        _, layout = load_layout(BodySpec.parse(resolve_group("body", name)), data_root)
        assert layout.motion_columns == 75  # 76 columns with dt
        assert layout.num_joints == 38 and layout.action_size == 50  # 4 x 4 (quaternions) + 34
        assert not any(j.name.endswith(("hip", "knee", "ankle")) for j in layout.joints)


def test_reset_puts_a_known_frame_into_the_simulator(sign, data_root):
    raw = json.loads(sign.read_text())["Frames"]
    k = 17
    env = UpperBodyImitationEnv(sign, body="upper_body_thesis", data_root=data_root)
    env.reset(options={"time": env.motion.times[k]})
    pb, body = env.sim.world.client, env.sim.id
    index = {pb.getJointInfo(body, i)[1].decode(): i for i in range(pb.getNumJoints(body))}
    column, checked = 8, 0  # dt and the 7 root values come first
    for name, width in UPPER_BODY_COLUMNS:
        expected = np.asarray(raw[k][column:column + width])
        column += width
        if name.endswith(("hip", "knee", "ankle")):
            continue  # fixed in the model
        position = pb.getJointStateMultiDof(body, index[name])[0]
        if width == 4:
            x, y, z, w = position
            got = np.asarray([w, x, y, z])
            assert min(np.abs(got - expected).max(), np.abs(got + expected).max()) < 1e-6, name
        else:
            assert position[0] == pytest.approx(expected[0], abs=1e-9), name
        checked += 1
    assert checked == 38
    env.close()


def test_spherical_velocities_are_in_the_child_frame_as_pybullet_integrates_them(sign, data_root):
    env = UpperBodyImitationEnv(sign, data_root=data_root)
    chest = env.layout.joints[0]
    assert chest.name == "chest" and chest.dof == 4
    # The reference angular velocity carries each frame onto the next: q_i+1 = q_i exp(w dt).
    frames, dt = env.motion.frames, env.motion.dt
    c = chest.motion_column
    for i in (3, 20, 40):
        omega = env.reference.joint_velocities(env.motion.times[i] + 1e-6)[0:3]
        angle = np.linalg.norm(omega) * dt[i]
        step = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * omega / np.linalg.norm(omega)])
        predicted = quat_multiply(frames[i, c:c + 4], step)
        assert min(np.abs(predicted - frames[i + 1, c:c + 4]).max(),
                   np.abs(predicted + frames[i + 1, c:c + 4]).max()) < 1e-6
    # PyBullet integrates a spherical joint's velocity the same way (child frame), no gravity/motors.
    pb, body = env.sim.world.client, env.sim.id
    pb.setGravity(0, 0, 0)
    pb.setTimeStep(1e-3)
    q0 = np.asarray([0.9, 0.3, 0.2, 0.1]) / np.linalg.norm([0.9, 0.3, 0.2, 0.1])
    omega = np.asarray([0.0, 0.0, 1.0])
    pb.resetJointStateMultiDof(body, chest.index, [q0[1], q0[2], q0[3], q0[0]], list(omega))
    pb.stepSimulation()
    x, y, z, w = pb.getJointStateMultiDof(body, chest.index)[0]
    half = np.concatenate([[1.0], 0.5e-3 * omega])
    child, parent = quat_multiply(q0, half), quat_multiply(half, q0)
    got = np.asarray([w, x, y, z])
    assert np.abs(got - child).max() < 0.1 * np.abs(got - parent).max()
    env.close()


def test_registered_with_defaults(sign):
    env = gym.make("aslexp/UpperBodyImitation-v0", motion=str(sign))
    obs, _ = env.reset(seed=0)
    # phase + 39 links x 13 (legs left out: fixed); thesis 509 = this + DeepMimic's root height.
    assert obs.shape == env.observation_space.shape == (508,)
    assert env.action_space.shape == (50,)
    _, reward, terminated, _, info = env.step(env.unwrapped.reference_action(1))
    assert 0.0 < reward <= 1.0 and not terminated
    terms = ("pose_body", "pose_hands", "velocity_body", "velocity_hands", "end_effector", "root")
    assert reward == pytest.approx(np.prod([info[f"r_{t}"] for t in terms]))
    env.close()


def test_bad_motions_and_models_are_clear_errors(tmp_path, sign, data_root, thesis_urdf):
    payload = json.loads(sign.read_text())
    hand = data_root / "motions" / "hand" / "A.txt"
    with pytest.raises(MotionFormatError, match=r"A\.txt.*75 values per frame.*22"):
        UpperBodyImitationEnv(hand, data_root=data_root)
    bad = json.loads(json.dumps(payload))
    bad["Frames"][5][9:13] = [2.0, 0.0, 0.0, 0.0]  # chest quaternion of norm 2
    (tmp_path / "scaled.txt").write_text(json.dumps(bad))
    with pytest.raises(MotionFormatError, match=r"scaled\.txt.*columns 8-11.*not a unit quaternion.*frame 5"):
        UpperBodyImitationEnv(tmp_path / "scaled.txt", data_root=data_root)
    nan = sign.read_text().replace(str(payload["Frames"][2][10]), "NaN", 1)
    (tmp_path / "nan.txt").write_text(nan)
    with pytest.raises(MotionFormatError, match=r"nan\.txt.*non-finite"):
        UpperBodyImitationEnv(tmp_path / "nan.txt", data_root=data_root)
    # A custom URDF that lost a finger joint: the error names the model and the joint.
    text = thesis_urdf.read_text()
    start = text.index('<joint name="l_pinkie_dist"')
    broken = text[:start] + text[text.index("</joint>", start) + len("</joint>"):]
    (tmp_path / "no_pinkie.urdf").write_text(broken)
    with pytest.raises(ValueError, match=r"no_pinkie\.urdf.*l_pinkie_dist"):
        UpperBodyImitationEnv(sign, body={"urdf": str(tmp_path / "no_pinkie.urdf"), "builder": None},
                              data_root=data_root)


def test_deepmimic_humanoid_motions_load(data_root):
    from aslexp.sim.upper_body import pybullet_data_path

    motion = pybullet_data_path("data/motions/humanoid3d_punch.txt")
    env = UpperBodyImitationEnv(motion, body="upper_body_humanoid", data_root=data_root)
    assert env.layout.motion_columns == 43 and env.action_space.shape == (36,)
    env.reset(options={"time": 0.0})
    _, reward, _, _, _ = env.step(env.reference_action(1))
    assert 0.0 < reward <= 1.0
    env.close()
