"""The upper-body humanoid with two hands (thesis chapter 6), composed from parts.

The DeepMimic humanoid (``humanoid/humanoid.urdf`` in ``pybullet_data``, or any URDF with the
same joint names) gets its legs fixed (the root is fixed by the body config), its one-DoF
elbows kept, its fixed wrists replaced by one-DoF revolute wrists carrying a palm-shaped link,
and on each palm the five fingers of the project's hand (:class:`~aslexp.sim.urdf.HandProportions`),
the left hand with the flexion axes mirrored as in the thesis model
(``models/whole_upper_humanoid.urdf``: same finger origins, index to pinkie about -x).
"""

from __future__ import annotations

import copy
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from aslexp.config_schema import Section
from aslexp.files import atomic_write_text
from aslexp.sim.urdf import HandProportions, _link, _vec, finger_chains_urdf

PYBULLET_DATA_PREFIX = "pybullet_data:"


def pybullet_data_path(relative: str) -> Path:
    """A file shipped in PyBullet's ``pybullet_data`` package."""
    import pybullet_data

    return Path(pybullet_data.getDataPath()) / relative


@dataclass(frozen=True)
class UpperBodyProportions(Section):
    """Everything the upper-body builder needs; the defaults give the thesis' model."""

    SECTION = "body.proportions"

    name: str = "upper_body"
    # The humanoid to start from: a path, or ``pybullet_data:<relative path>``.
    humanoid: str = "pybullet_data:humanoid/humanoid.urdf"
    fixed_joints: tuple[str, ...] = ("right_hip", "right_knee", "right_ankle",
                                     "left_hip", "left_knee", "left_ankle")
    # Wrist joint: replaces the humanoid's fixed wrist at the same place.
    wrist_axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    wrist_limits: tuple[float, float] = (-1.57, 1.57)
    wrist_rpy: tuple[float, float, float] = (1.57, 0.0, 0.0)
    wrist_effort: float = 1000.0
    wrist_velocity: float = 0.5
    hand: HandProportions = field(default_factory=HandProportions)
    sides: tuple[tuple[str, str], ...] = (("right", "r_"), ("left", "l_"))  # side, finger prefix

    def humanoid_path(self) -> Path:
        if self.humanoid.startswith(PYBULLET_DATA_PREFIX):
            return pybullet_data_path(self.humanoid[len(PYBULLET_DATA_PREFIX):])
        return Path(self.humanoid).expanduser()


def _read_robot(path: Path) -> ET.Element:
    if not path.is_file():
        raise FileNotFoundError(f"upper-body builder: humanoid URDF not found: {path}")
    text = path.read_text(encoding="utf-8", errors="replace")
    end = text.rfind("</robot>")
    try:
        return ET.fromstring(text[: end + len("</robot>")] if end >= 0 else text)
    except ET.ParseError as exc:
        raise ValueError(f"upper-body builder: {path} is not valid URDF XML: {exc}") from exc


def build_upper_body_urdf(proportions: UpperBodyProportions | None = None) -> str:
    """URDF text of the humanoid upper body with two hands (see the module docstring)."""
    up = proportions or UpperBodyProportions()
    source = up.humanoid_path()
    robot = _read_robot(source)
    joints = {j.get("name"): j for j in robot.findall("joint")}
    links = {link.get("name"): link for link in robot.findall("link")}
    needed = list(up.fixed_joints) + [f"{side}_wrist" for side, _ in up.sides]
    missing = [name for name in needed if name not in joints]
    if missing:
        raise ValueError(f"upper-body builder: humanoid {source} has no joints {missing}; "
                         f"joints: {sorted(joints)}")
    for name in up.fixed_joints:
        joints[name].set("type", "fixed")

    out = ET.Element("robot", {"name": up.name})
    hp = up.hand
    for element in list(robot):
        name = element.get("name")
        side = next((s for s, _ in up.sides if name == f"{s}_wrist"), None)
        if element.tag == "link" and side is not None:
            # The wrist link becomes the palm of the hand (same box, mass and frame as the hand's).
            out.append(ET.fromstring(_link(name, hp.palm_mass, hp.palm_size, hp.palm_size[2] / 2, hp.inertia)))
            continue
        if element.tag == "joint" and side is not None:
            origin = element.find("origin")
            xyz = origin.get("xyz", "0 0 0") if origin is not None else "0 0 0"
            lower, upper = up.wrist_limits
            out.append(ET.fromstring(
                f'<joint name="{name}" type="revolute"><parent link="{element.find("parent").get("link")}"/>'
                f'<child link="{element.find("child").get("link")}"/>'
                f'<origin rpy="{_vec(up.wrist_rpy)}" xyz="{xyz}"/><axis xyz="{_vec(up.wrist_axis)}"/>'
                f'<limit effort="{up.wrist_effort:g}" lower="{lower:g}" upper="{upper:g}" '
                f'velocity="{up.wrist_velocity:g}"/></joint>'
            ))
            prefix = dict(up.sides)[side]
            fingers = ET.fromstring("<r>" + finger_chains_urdf(hp, parent=name, prefix=prefix,
                                                               mirror_axes=side == "left") + "</r>")
            out.extend(list(fingers))
            continue
        out.append(copy.deepcopy(element))
    del links  # links are kept in file order; only the wrists change
    ET.indent(out, space="  ")
    return '<?xml version="1.0"?>\n' + ET.tostring(out, encoding="unicode") + "\n"


def write_upper_body_urdf(path: str | os.PathLike, proportions: UpperBodyProportions | None = None) -> Path:
    """Write the built upper body to ``path`` (atomically) and return the path."""
    return atomic_write_text(path, build_upper_body_urdf(proportions))
