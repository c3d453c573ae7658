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


# A URDF that loads but cannot be simulated, or that no engine can load, is refused where every
# body's URDF is read (aslexp.sim.urdf.read_joints, through load_layout), before either engine.
INDEX_MASS = ('<link name="index_prox" >\n\t\t<inertial>\n            <origin rpy = "0 0 0" xyz = "0 0 0.02" />'
              '\n\t\t\t<mass value = "0.05" />')
INDEX_LIMIT = '<limit effort="1000" lower="0" upper="2" velocity="0.5"/>'
INDEX_BOX = '<child link="index_prox" />'
BOX = '<box size="0.025 0.025 0.04" />'


def _damaged_hand(data_root, tmp_path, damage: str):
    """The thesis hand (models/final_hand.urdf) with one thing changed, and the line that names it."""
    text = (data_root / "models" / "final_hand.urdf").read_text()
    assert text.count(INDEX_MASS) == 1 and INDEX_LIMIT in text
    path = tmp_path / f"hand_{damage}.urdf"
    if damage in ("negative_mass", "zero_mass"):
        mass = "-0.05" if damage == "negative_mass" else "0"
        text = text.replace(INDEX_MASS, INDEX_MASS.replace('"0.05"', f'"{mass}"'))
        expected = f"URDF {path}: link 'index_prox' has mass {float(mass):g}; expected a positive mass in kg " \
                   "(a link that a joint moves needs one)"
    elif damage == "limits":
        start = text.index('<joint name="index_prox"')
        end = text.index("</joint>", start)
        text = text[:start] + text[start:end].replace('lower="0" upper="2"', 'lower="2" upper="0"') + text[end:]
        expected = f"URDF {path}: joint 'index_prox' has limits lower=2 > upper=0; expected lower <= upper"
    else:  # the index's first phalanx drawn from a mesh file
        start = text.index('<link name="index_prox"')
        end = text.index("</link>", start)
        text = text[:start] + text[start:end].replace(BOX, '<mesh filename="meshes/phalanx.obj" />') + text[end:]
        expected = (f"URDF {path}: link 'index_prox': mesh 'meshes/phalanx.obj' not found "
                    f"(tried {tmp_path / 'meshes' / 'phalanx.obj'})")
    path.write_text(text)
    return path, expected


@pytest.mark.parametrize("damage", ["negative_mass", "zero_mass", "limits", "missing_mesh"])
def test_a_urdf_that_cannot_be_simulated_is_refused_naming_the_file_and_the_part(data_root, tmp_path, damage):
    from aslexp.errors import DataError
    from aslexp.sim.body import load_layout

    path, expected = _damaged_hand(data_root, tmp_path, damage)
    with pytest.raises(DataError) as error:
        load_layout(BodySpec(name="hand15", urdf=str(path)), data_root)
    assert str(error.value) == expected


def test_a_mesh_beside_the_urdf_is_found_and_loads(data_root, tmp_path):
    path, _ = _damaged_hand(data_root, tmp_path, "missing_mesh")
    (tmp_path / "meshes").mkdir()
    corners = [(x, y, z) for x in (-0.0125, 0.0125) for y in (-0.0125, 0.0125) for z in (0.0, 0.04)]
    faces = ["1 2 4 3", "5 7 8 6", "1 5 6 2", "3 4 8 7", "1 3 7 5", "2 6 8 4"]
    (tmp_path / "meshes" / "phalanx.obj").write_text(
        "".join(f"v {x} {y} {z}\n" for x, y, z in corners) + "".join(f"f {f}\n" for f in faces))
    thesis_hand = read_joints(data_root / "models" / "final_hand.urdf")
    assert [j.name for j in read_joints(path)] == [j.name for j in thesis_hand]
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(path), useFixedBase=True, physicsClientId=client)
        assert pybullet.getNumJoints(body, physicsClientId=client) == 16
    finally:
        pybullet.disconnect(client)


def test_built_hand_proportions_that_cannot_move_are_a_config_error():
    from aslexp.errors import ConfigError

    with pytest.raises(ConfigError, match=r"^body.proportions.phalanx_mass=-0.05: expected a positive mass in kg$"):
        HandProportions.parse({"phalanx_mass": -0.05})
    with pytest.raises(ConfigError, match=r"^body.proportions.palm_mass=0.0: expected a positive mass"):
        HandProportions.parse({"palm_mass": 0})
    with pytest.raises(ConfigError, match=r"^body.proportions.joint_limits=\[2.0, 0.0\]: expected \[lower, upper\]"):
        HandProportions.parse({"joint_limits": [2, 0]})


@pytest.mark.parametrize("engine", ["pybullet", "mujoco"])
def test_imitate_stops_on_a_bad_urdf_in_one_line_before_either_engine(data_root, tmp_path, engine):
    import os
    import sys
    from pathlib import Path

    import job_process

    path, expected = _damaged_hand(data_root, tmp_path, "negative_mass")
    run_dir = tmp_path / "run"
    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.imitate", "motion=B", f"engine={engine}",
                            f"body.urdf={path}", "ppo.total_steps=256", f"hydra.run.dir={run_dir}"],
                           cwd=Path(__file__).resolve().parents[2], env=dict(os.environ), capture_output=True,
                           text=True, timeout=300)  # fmt: skip
    lines = [line for line in proc.stderr.splitlines() if line.strip() and not line.startswith("[20")]
    assert proc.returncode == 2, proc.stderr[-3000:]
    assert len(lines) == 1 and expected in lines[0], lines
    assert not (run_dir / "progress.csv").exists() and not (run_dir / "checkpoints").exists()
