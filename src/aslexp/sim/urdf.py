"""URDF models: the project's hand builder, and a reader for any URDF's joint table.

The hand is generated from proportions (:class:`HandProportions`): a fixed wrist and five fingers
of three revolute joints each (thumb about y, the others about x), so the thesis model
(``models/final_hand.urdf``) is one point in a family of hands. Bodies for later issues (the
upper-body humanoid) come as URDF paths; :func:`read_joints` gives the joint table either way.
"""

from __future__ import annotations

import math
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

from aslexp.config_schema import Section
from aslexp.errors import ConfigError, DataError
from aslexp.files import atomic_write_text

FINGERS = ("thumb", "index", "middle", "ring", "pinkie")
PHALANGES = ("prox", "inter", "dist")


@dataclass(frozen=True)
class JointInfo:
    """One joint of a URDF, as the simulator and the motion format see it."""

    name: str
    type: str  # revolute | continuous | prismatic | spherical | fixed
    parent: str
    child: str
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)
    lower: float | None = None
    upper: float | None = None

    @property
    def dof(self) -> int:
        """Motion columns this joint takes: 0 (fixed), 1 (revolute/prismatic), 4 (spherical, wxyz)."""
        return {"fixed": 0, "spherical": 4}.get(self.type, 1)


@dataclass(frozen=True)
class FingerProportions:
    """Where a finger starts on the palm and how long its phalanges are (metres, radians)."""

    origin_xyz: tuple[float, float, float]
    origin_rpy: tuple[float, float, float]
    # Distance from the proximal joint to the intermediate one, and from there to the distal one.
    segment_lengths: tuple[float, float]
    axis: tuple[float, float, float] = (1.0, 0.0, 0.0)


def _thesis_fingers() -> dict[str, FingerProportions]:
    # Values of the thesis model (final_hand.urdf), so the default build reproduces it.
    return {
        "thumb": FingerProportions((0.1, 0.0, 0.0), (3.14, -2.81, 0.0), (0.056, 0.066), (0.0, 1.0, 0.0)),
        "index": FingerProportions((0.08, 0.0, 0.22), (0.0, 0.0, 0.0), (0.061, 0.061)),
        "middle": FingerProportions((0.01, 0.0, 0.227), (0.0, 0.0, 0.1), (0.060, 0.062)),
        "ring": FingerProportions((-0.057, 0.0, 0.189), (0.0, -0.05, 0.11), (0.059, 0.052)),
        "pinkie": FingerProportions((-0.108, 0.0, 0.123), (0.0, -0.13, 0.21), (0.045, 0.044)),
    }


@dataclass(frozen=True)
class HandProportions(Section):
    """Everything the hand builder needs; the defaults are the thesis' 15-DoF hand (a partial dict
    changes only what it names, a finger's entries too)."""

    SECTION = "body.proportions"

    name: str = "hand15"
    fingers: dict[str, FingerProportions] = field(default_factory=_thesis_fingers, metadata={"names": FINGERS})
    palm_size: tuple[float, float, float] = (0.15, 0.04, 0.15)
    palm_mass: float = 0.5
    wrist_rpy: tuple[float, float, float] = (3.14, -1.57, 1.57)
    phalanx_size: tuple[float, float, float] = (0.025, 0.025, 0.04)
    phalanx_mass: float = 0.05
    # The thesis file declares 0.1 kg m^2; PyBullet ignores it unless URDF_USE_INERTIA_FROM_FILE.
    inertia: float = 0.1
    joint_limits: tuple[float, float] = (0.0, 2.0)
    effort: float = 1000.0
    velocity: float = 0.5

    def __post_init__(self) -> None:
        for name in ("palm_mass", "phalanx_mass"):  # a massless or negative link cannot be simulated
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name}={getattr(self, name)!r}: expected a positive mass in kg")
        lower, upper = self.joint_limits
        if not lower <= upper:
            raise ConfigError(f"joint_limits=[{lower!r}, {upper!r}]: expected [lower, upper] with lower <= upper "
                              "(radians)")  # fmt: skip

def _vec(values) -> str:
    return " ".join(f"{float(v):g}" for v in values)


def _link(name: str, mass: float, size, com_z: float, inertia: float) -> str:
    return f"""  <link name="{name}">
    <inertial>
      <origin rpy="0 0 0" xyz="0 0 {com_z:g}"/>
      <mass value="{mass:g}"/>
      <inertia ixx="{inertia:g}" ixy="0" ixz="0" iyy="{inertia:g}" iyz="0" izz="{inertia:g}"/>
    </inertial>
    <collision>
      <origin rpy="0 0 0" xyz="0 0 {com_z:g}"/>
      <geometry><box size="{_vec(size)}"/></geometry>
    </collision>
    <visual>
      <origin rpy="0 0 0" xyz="0 0 {com_z:g}"/>
      <geometry><box size="{_vec(size)}"/></geometry>
    </visual>
  </link>
"""


def build_hand_urdf(proportions: HandProportions | None = None) -> str:
    """URDF text of a fixed-wrist hand with five three-joint fingers (thumb first)."""
    hp = proportions or HandProportions()
    parts = [f'<?xml version="1.0"?>\n<robot name="{hp.name}">\n']
    parts.append(
        '  <link name="base">\n    <inertial>\n      <origin rpy="0 0 0" xyz="0 0 0"/>\n'
        '      <mass value="0.0001"/>\n'
        '      <inertia ixx="0.0001" ixy="0" ixz="0" iyy="0.0001" iyz="0" izz="0.0001"/>\n'
        "    </inertial>\n  </link>\n"
    )
    parts.append(_link("right_wrist", hp.palm_mass, hp.palm_size, hp.palm_size[2] / 2, hp.inertia))
    parts.append(
        f'  <joint name="right_wrist" type="fixed">\n    <parent link="base"/>\n'
        f'    <child link="right_wrist"/>\n    <origin rpy="{_vec(hp.wrist_rpy)}" xyz="0 0 0"/>\n'
        "  </joint>\n"
    )
    parts.append(finger_chains_urdf(hp, parent="right_wrist"))
    parts.append("</robot>\n")
    return "".join(parts)


def finger_chains_urdf(hp: HandProportions, parent: str, prefix: str = "",
                       mirror_axes: bool = False) -> str:
    """Links and joints of the five fingers of ``hp`` on link ``parent`` (names ``prefix + finger_phalanx``).

    ``mirror_axes`` flips the flexion axis of the fingers bending about x (a left hand in the
    thesis' upper body: same finger origins, index to pinkie about -x, thumb still about +y).
    """
    lower, upper = hp.joint_limits
    com_z = hp.phalanx_size[2] / 2
    parts = []
    for finger in FINGERS:
        fp = hp.fingers[finger]
        axis = fp.axis
        if mirror_axes and axis[0] != 0.0:
            axis = tuple(-a for a in axis)
        link_parent = parent
        offsets = [(fp.origin_xyz, fp.origin_rpy), ((0, 0, fp.segment_lengths[0]), (0, 0, 0)),
                   ((0, 0, fp.segment_lengths[1]), (0, 0, 0))]
        for phalanx, (xyz, rpy) in zip(PHALANGES, offsets):
            name = f"{prefix}{finger}_{phalanx}"
            parts.append(_link(name, hp.phalanx_mass, hp.phalanx_size, com_z, hp.inertia))
            parts.append(
                f'  <joint name="{name}" type="revolute">\n    <parent link="{link_parent}"/>\n'
                f'    <child link="{name}"/>\n    <origin rpy="{_vec(rpy)}" xyz="{_vec(xyz)}"/>\n'
                f'    <axis xyz="{_vec(axis)}"/>\n'
                f'    <limit effort="{hp.effort:g}" lower="{lower:g}" upper="{upper:g}" '
                f'velocity="{hp.velocity:g}"/>\n  </joint>\n'
            )
            link_parent = name
    return "".join(parts)


def write_hand_urdf(path: str | os.PathLike, proportions: HandProportions | None = None) -> Path:
    """Write the built hand to ``path`` (atomically) and return the path."""
    return atomic_write_text(path, build_hand_urdf(proportions))


# Joints that move their child link: a child without mass (or with a negative one) cannot be simulated.
MOVING_JOINTS = ("revolute", "continuous", "prismatic", "spherical", "floating", "planar")
LIMITED_JOINTS = ("revolute", "prismatic")


def _number(path: Path, where: str, text: str | None, default: str | None = None) -> float:
    value = text if text is not None else default
    try:
        return float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise DataError(f"URDF {path}: {where}={value!r}; expected a number") from None


def _mesh_candidates(path: Path, filename: str) -> list[Path]:
    """Where PyBullet and MuJoCo look for a mesh: as given (absolute) or beside the URDF; a
    ``package://name/rest`` path beside the URDF either with or without its package folder."""
    if filename.startswith("file://"):
        filename = filename[len("file://"):]
    if filename.startswith("package://"):
        rest = filename[len("package://"):]
        inner = rest.split("/", 1)[1] if "/" in rest else rest
        return [path.parent / rest, path.parent / inner]
    mesh = Path(filename).expanduser()
    return [mesh] if mesh.is_absolute() else [path.parent / mesh]


def check_urdf(path: Path, root: ET.Element) -> None:
    """Refuse, before any engine loads it, a URDF whose body cannot be simulated or loaded: a link on
    a moving joint with a mass <= 0, a joint limit with lower > upper, a mesh file that is not there.
    One :class:`DataError` naming the file, the link, joint or mesh, and what was expected."""
    moved = {child.get("link") for joint in root.findall("joint") if joint.get("type") in MOVING_JOINTS
             for child in joint.findall("child")}  # fmt: skip
    problems = []
    for link in root.findall("link"):
        name = link.get("name")
        mass_el = link.find("inertial/mass")
        if mass_el is not None:
            mass = _number(path, f"link {name!r} mass value", mass_el.get("value"))
            if mass < 0 or not math.isfinite(mass) or (mass == 0 and name in moved):
                problems.append(f"link {name!r} has mass {mass:g}; expected a positive mass in kg "
                                "(a link that a joint moves needs one)")  # fmt: skip
        for mesh in link.iter("mesh"):
            filename = mesh.get("filename")
            if not filename:
                problems.append(f"link {name!r}: a <mesh> without filename")
                continue
            candidates = _mesh_candidates(path, filename)
            if not any(candidate.is_file() for candidate in candidates):
                problems.append(f"link {name!r}: mesh {filename!r} not found "
                                f"(tried {', '.join(map(str, candidates))})")  # fmt: skip
    for joint in root.findall("joint"):
        limit_el = joint.find("limit")
        if limit_el is None or joint.get("type") not in LIMITED_JOINTS:
            continue
        name = joint.get("name")
        lower = _number(path, f"joint {name!r} limit lower", limit_el.get("lower"), "0")
        upper = _number(path, f"joint {name!r} limit upper", limit_el.get("upper"), "0")
        if lower > upper:
            problems.append(f"joint {name!r} has limits lower={lower:g} > upper={upper:g}; expected lower <= upper")
    if problems:
        more = f" (and {len(problems) - 1} more problems)" if len(problems) > 1 else ""
        raise DataError(f"URDF {path}: {problems[0]}{more}")


def read_joints(urdf: str | os.PathLike) -> list[JointInfo]:
    """The joints of a URDF file in file order (PyBullet's order with URDF_MAINTAIN_LINK_ORDER),
    after :func:`check_urdf` (every body's URDF is read here before either engine loads it)."""
    path = Path(urdf)
    if not path.is_file():
        raise FileNotFoundError(f"URDF not found: {path}")
    text = path.read_text(encoding="utf-8", errors="replace")
    end = text.rfind("</robot>")
    if end >= 0:  # PyBullet ignores bytes after </robot> (pybullet_data's humanoid.urdf has some)
        text = text[:end + len("</robot>")]
    try:
        root = ET.fromstring(text.lstrip())  # PyBullet reads a file with blank lines before <?xml
    except ET.ParseError as exc:
        raise DataError(f"URDF {path} is not valid XML: {exc}") from None
    check_urdf(path, root)
    joints = []
    for element in root.findall("joint"):  # the robot's own (a <transmission> names joints too)
        name = element.get("name")
        axis_el = element.find("axis")
        limit_el = element.find("limit")
        axis = (1.0, 0.0, 0.0)
        if axis_el is not None:
            axis = tuple(_number(path, f"joint {name!r} axis xyz", v) for v in (axis_el.get("xyz") or "").split())
            if len(axis) != 3:
                raise DataError(f"URDF {path}: joint {name!r} axis xyz={axis_el.get('xyz')!r}; expected three numbers")
        lower = upper = None
        if limit_el is not None:
            lower = _number(path, f"joint {name!r} limit lower", limit_el.get("lower"), "nan")
            upper = _number(path, f"joint {name!r} limit upper", limit_el.get("upper"), "nan")
        parent, child = element.find("parent"), element.find("child")
        if parent is None or child is None:
            raise DataError(f"URDF {path}: joint {name!r} needs a <parent link=...> and a <child link=...>")
        joints.append(JointInfo(
            name=name, type=element.get("type"),
            parent=parent.get("link"), child=child.get("link"),
            axis=axis, lower=lower, upper=upper,
        ))
    return joints


def compare_joint_tables(ours: list[JointInfo], theirs: list[JointInfo], tol: float = 1e-9) -> list[str]:
    """Differences in joint names, order, types, axes and limits (empty list: same model)."""
    problems = []
    if [j.name for j in ours] != [j.name for j in theirs]:
        problems.append(f"joint names/order differ: {[j.name for j in ours]} vs {[j.name for j in theirs]}")
        return problems
    for a, b in zip(ours, theirs):
        if a.type != b.type:
            problems.append(f"{a.name}: type {a.type} vs {b.type}")
        if a.type == "fixed":
            continue
        if any(abs(x - y) > tol for x, y in zip(a.axis, b.axis)):
            problems.append(f"{a.name}: axis {a.axis} vs {b.axis}")
        if (a.lower, a.upper) != (b.lower, b.upper):
            problems.append(f"{a.name}: limits {(a.lower, a.upper)} vs {(b.lower, b.upper)}")
        if a.parent != b.parent:
            problems.append(f"{a.name}: parent {a.parent} vs {b.parent}")
    return problems
