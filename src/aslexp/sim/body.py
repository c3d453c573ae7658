"""What a simulated body is, independent of the simulator: URDF, joint groups, motion layout.

A body config (``conf/body/*.yaml``) names a URDF (or a builder), groups its joints (the PD
gains and reward weights are given per group), lists its end effectors and says how the
columns of a motion file map onto its joints. Nothing here is hand-specific: the upper-body
humanoid is another body config with spherical joints and a longer motion layout.
"""

from __future__ import annotations

import fnmatch
import hashlib
import os
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aslexp.config_schema import Choice, Section, key
from aslexp.files import atomic_write_text
from aslexp.sim.motion import ROOT_COLUMNS
from aslexp.sim.urdf import HandProportions, JointInfo, read_joints

BUILDERS = ("hand15", "upper_body")
# How the root is held: welded to the world (PyBullet's fixed base), a free base pinned to the world
# by a fixed constraint (what stable PD needs: PyBullet 3.2.7's stable PD misreads the joint states
# of fixed-base multibodies), or free, standing on a ground plane (the authors' upper body).
BASES = ("fixed", "pinned", "free")


@dataclass(frozen=True)
class BodySpec(Section):
    """Plain description of a body (see ``conf/body/hand15.yaml`` for the fields)."""

    SECTION = "body"

    name: str
    urdf: str | None = None
    builder: str | None = None
    proportions: dict[str, Any] = field(default_factory=dict)
    base: str = field(default="fixed", metadata=key(Choice(*BASES)))
    # With base free: links allowed to touch the ground (the feet); any other contact is a fall.
    ground_contacts: tuple[str, ...] = ()
    self_collision: bool = True
    global_scaling: float = 1.0
    # False (PyBullet's default, the thesis'): each link's inertia comes from its collision shapes and
    # URDF mass; True: the URDF's <inertia> (PyBullet's URDF_USE_INERTIA_FROM_FILE).
    inertia_from_file: bool = False
    # Group name -> list of joint-name patterns (fnmatch); every actuated joint needs one group.
    joint_groups: dict[str, list[str]] = field(default_factory=lambda: {"all": ["*"]})
    end_effectors: list[str] = field(default_factory=list)
    # Point on each end-effector link (link frame, metres) taken as its tip.
    end_effector_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    # Motion columns after the root, as [joint name, width]; None: actuated joints in URDF order.
    # Entries naming joints that are fixed or absent in the model are read and ignored.
    motion_layout: list[list[Any]] | None = None
    # True: a motion-layout joint absent from the URDF is an error naming the model (a custom URDF
    # that lost a joint must not silently drop its columns); joints present but fixed are skipped.
    strict_layout: bool = False


@dataclass(frozen=True)
class ActuatedJoint:
    """One joint the controller drives, with where it sits in the state and motion vectors."""

    name: str
    index: int  # PyBullet joint index (URDF order with URDF_MAINTAIN_LINK_ORDER)
    dof: int  # 1 (revolute) or 4 (spherical, quaternion w x y z in the motion)
    group: str
    motion_column: int  # first column in a motion frame (after the 7 root values)
    lower: float | None = None
    upper: float | None = None


@dataclass(frozen=True)
class BodyLayout:
    """The actuated joints of a body and the motion columns that feed them."""

    joints: tuple[ActuatedJoint, ...]
    motion_columns: int  # values per motion frame without dt (root included)
    groups: tuple[str, ...] = ()  # every joint group of the body config (some may have no joints)

    @property
    def num_joints(self) -> int:
        return len(self.joints)

    @property
    def all_revolute(self) -> bool:
        return all(j.dof == 1 for j in self.joints)

    @property
    def action_size(self) -> int:
        return sum(j.dof for j in self.joints)

    @property
    def velocity_names(self) -> tuple[str, ...]:
        """The joint of each joint-velocity value (1 per revolute joint, 3 per spherical joint)."""
        return tuple(j.name for j in self.joints for _ in range(1 if j.dof == 1 else 3))

    @property
    def quaternion_columns(self) -> tuple[int, ...]:
        """First column of each quaternion block in a motion frame (root and spherical joints)."""
        return (3,) + tuple(j.motion_column for j in self.joints if j.dof == 4)

    def group_of(self, name: str) -> str:
        return next(j.group for j in self.joints if j.name == name)


def _group_for(joint: str, groups: dict[str, list[str]]) -> str:
    for group, patterns in groups.items():
        if any(fnmatch.fnmatch(joint, p) for p in patterns):
            return group
    raise ValueError(f"joint {joint!r} is in no joint group; groups: {groups}")


def build_layout(spec: BodySpec, joints: list[JointInfo], source: str | os.PathLike | None = None) -> BodyLayout:
    """Match the URDF's joints with the body's groups and motion layout (``source``: the URDF, for errors)."""
    if spec.strict_layout and spec.motion_layout is not None:
        present = {j.name for j in joints}
        absent = [name for name, _ in spec.motion_layout if name not in present]
        if absent:
            raise ValueError(
                f"body {spec.name}: the model {source or '(URDF)'} has no joints {absent}, which the motion "
                f"layout needs ({len(absent)} of {len(spec.motion_layout)} joints missing)"
            )
    index_of = {j.name: i for i, j in enumerate(joints)}
    by_name = {j.name: j for j in joints}
    layout = spec.motion_layout
    if layout is None:
        layout = [[j.name, j.dof] for j in joints if j.dof > 0]
    actuated: list[ActuatedJoint] = []
    column = ROOT_COLUMNS
    for name, width in layout:
        info = by_name.get(name)
        if info is not None and info.dof > 0:
            if info.dof != int(width):
                raise ValueError(
                    f"body {spec.name}: motion layout gives joint {name!r} {width} columns but the "
                    f"URDF joint is {info.type} ({info.dof} columns)"
                )
            actuated.append(ActuatedJoint(
                name=name, index=index_of[name], dof=info.dof,
                group=_group_for(name, spec.joint_groups), motion_column=column,
                lower=info.lower, upper=info.upper,
            ))
        column += int(width)
    missing = [j.name for j in joints if j.dof > 0 and j.name not in {a.name for a in actuated}]
    if missing:
        raise ValueError(f"body {spec.name}: actuated joints {missing} have no motion columns")
    return BodyLayout(tuple(actuated), motion_columns=column, groups=tuple(spec.joint_groups))


def resolve_urdf(spec: BodySpec, data_root: str | os.PathLike | None = None,
                 cache_dir: str | os.PathLike | None = None) -> Path:
    """Path of the body's URDF: the named file (absolute or under the data root) or a built one."""
    if spec.urdf:
        if spec.urdf.startswith("pybullet_data:"):
            from aslexp.sim.upper_body import PYBULLET_DATA_PREFIX, pybullet_data_path

            path = pybullet_data_path(spec.urdf[len(PYBULLET_DATA_PREFIX):])
            if not path.is_file():
                raise FileNotFoundError(f"body {spec.name}: URDF {spec.urdf!r} not found ({path})")
            return path
        path = Path(spec.urdf).expanduser()
        candidates = [path] if path.is_absolute() else [Path.cwd() / path]
        if not path.is_absolute() and data_root is not None:
            candidates.append(Path(data_root) / path)
        for candidate in candidates:
            if candidate.is_file():
                return candidate.resolve()
        raise FileNotFoundError(
            f"body {spec.name}: URDF {spec.urdf!r} not found (tried {', '.join(map(str, candidates))})"
        )
    if spec.builder not in BUILDERS:
        raise ValueError(f"body {spec.name}: give `urdf` or a `builder` in {BUILDERS}, got {spec.builder!r}")
    text = build_urdf_text(spec)
    # Content-addressed cache: the same proportions reuse one file, different ones never clash.
    digest = hashlib.sha1(text.encode()).hexdigest()[:12]
    folder = Path(cache_dir) if cache_dir else Path(tempfile.gettempdir()) / "aslexp-urdf"
    target = folder / f"{spec.builder}-{digest}.urdf"
    if not target.is_file():
        atomic_write_text(target, text)
    return target


def build_urdf_text(spec: BodySpec) -> str:
    """URDF text of a built body (``spec.builder`` with ``spec.proportions``)."""
    if spec.builder == "hand15":
        from aslexp.sim.urdf import build_hand_urdf

        return build_hand_urdf(HandProportions.parse(spec.proportions))
    if spec.builder == "upper_body":
        from aslexp.sim.upper_body import UpperBodyProportions, build_upper_body_urdf

        return build_upper_body_urdf(UpperBodyProportions.parse(spec.proportions))
    raise ValueError(f"body {spec.name}: unknown builder {spec.builder!r}; expected one of {BUILDERS}")


def load_layout(spec: BodySpec, data_root: str | os.PathLike | None = None) -> tuple[Path, BodyLayout]:
    """URDF path and joint layout of a body."""
    urdf = resolve_urdf(spec, data_root)
    return urdf, build_layout(spec, read_joints(urdf), source=urdf)
