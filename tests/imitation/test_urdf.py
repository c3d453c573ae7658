"""The hand builder against the thesis' own model."""

from __future__ import annotations

import pybullet
import pytest

from aslexp.sim.body import BodySpec, build_layout, resolve_urdf
from aslexp.sim.urdf import (HandProportions, build_hand_urdf, compare_joint_tables, read_joints,
                             write_hand_urdf)


def test_built_hand_matches_thesis_model(tmp_path, data_root):
    ours = read_joints(write_hand_urdf(tmp_path / "hand.urdf"))
    theirs = read_joints(data_root / "models" / "final_hand.urdf")
    assert compare_joint_tables(ours, theirs) == []
    revolute = [j for j in ours if j.type == "revolute"]
    assert len(revolute) == 15
    assert [j.axis for j in revolute[:3]] == [(0.0, 1.0, 0.0)] * 3  # thumb about y
    assert all(j.axis == (1.0, 0.0, 0.0) for j in revolute[3:])  # the others about x
    assert all((j.lower, j.upper) == (0.0, 2.0) for j in revolute)


def test_built_hand_loads_in_pybullet_like_the_thesis_model(tmp_path, data_root):
    client = pybullet.connect(pybullet.DIRECT)
    try:
        ours = pybullet.loadURDF(str(write_hand_urdf(tmp_path / "hand.urdf")), useFixedBase=True,
                                 flags=pybullet.URDF_MAINTAIN_LINK_ORDER, physicsClientId=client)
        theirs = pybullet.loadURDF(str(data_root / "models" / "final_hand.urdf"), useFixedBase=True,
                                   flags=pybullet.URDF_MAINTAIN_LINK_ORDER, physicsClientId=client)
        n = pybullet.getNumJoints(ours, physicsClientId=client)
        assert n == pybullet.getNumJoints(theirs, physicsClientId=client) == 16
        for j in range(n):
            a = pybullet.getJointInfo(ours, j, physicsClientId=client)
            b = pybullet.getJointInfo(theirs, j, physicsClientId=client)
            assert a[1] == b[1] and a[2] == b[2]  # name, type
            assert a[8:10] == b[8:10]  # limits
            assert a[13] == b[13]  # axis
            # Same geometry: link frames at the same place in the zero pose.
            pa = pybullet.getLinkState(ours, j, physicsClientId=client)[4]
            pb = pybullet.getLinkState(theirs, j, physicsClientId=client)[4]
            assert pa == pytest.approx(pb, abs=1e-6)
    finally:
        pybullet.disconnect(client)


def test_proportions_change_the_model():
    longer = HandProportions.parse({"fingers": {"index": {"segment_lengths": [0.08, 0.07]}},
                                        "phalanx_mass": 0.04})
    text = build_hand_urdf(longer)
    assert 'xyz="0 0 0.08"' in text and 'mass value="0.04"' in text
    with pytest.raises(ValueError, match="body.proportions.fingers.sixth: unknown entry; expected one of thumb"):
        HandProportions.parse({"fingers": {"sixth": {}}})


def test_missing_urdf_is_a_clear_error(tmp_path):
    spec = BodySpec(name="broken", urdf=str(tmp_path / "nope.urdf"))
    with pytest.raises(FileNotFoundError, match="nope.urdf"):
        resolve_urdf(spec, tmp_path)
    with pytest.raises(FileNotFoundError, match="URDF not found"):
        read_joints(tmp_path / "nope.urdf")


def test_layout_groups_and_motion_columns(tmp_path):
    spec = BodySpec(name="hand15", builder="hand15",
                    joint_groups={"thumb": ["thumb_*"], "fingers": ["*"]})
    layout = build_layout(spec, read_joints(write_hand_urdf(tmp_path / "h.urdf")))
    assert layout.num_joints == 15 and layout.motion_columns == 22
    assert [j.group for j in layout.joints[:4]] == ["thumb", "thumb", "thumb", "fingers"]
    assert layout.joints[0].motion_column == 7
    # A layout naming a fixed joint (as the upper-body motions do for the legs) skips its column.
    spec2 = BodySpec(name="h", builder="hand15",
                     motion_layout=[["right_wrist", 1]] + [[j.name, 1] for j in layout.joints])
    skipped = build_layout(spec2, read_joints(tmp_path / "h.urdf"))
    assert skipped.motion_columns == 23 and skipped.joints[0].motion_column == 8
