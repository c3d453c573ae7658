"""The physics engine: a PyBullet world in DIRECT mode and the characters in it.

A :class:`World` owns one PyBullet client (its own physics server: worlds never share state).
A :class:`Character` is a body loaded into a world, read and written in the motion layout's
terms (joint vector q in motion order, quaternions w x y z for spherical joints). The imitation
environment uses two worlds: the simulated character, stepped, and a kinematic reference
character in a world that is never stepped (it only answers forward-kinematics questions).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aslexp.quaternion import rotate, wxyz_to_xyzw, z_to
from aslexp.sim.body import BodyLayout, BodySpec


@dataclass(frozen=True)
class PhysicsConfig:
    """Engine settings (``conf/env/*.yaml`` holds them next to the control rate)."""

    physics_hz: float = 240.0
    gravity: tuple[float, float, float] = (0.0, -9.8, 0.0)
    solver_iterations: int = 10
    # PyBullet's numNonContactInnerIterations: sweeps over the joint motors and limits inside each
    # solver iteration. For long articulated chains (the upper body) 10 x 10 converges where 100 x 1
    # does not (docs/imitation_upper_body.md, "Solver convergence").
    non_contact_inner_iterations: int = 1


class World:
    """One PyBullet physics server in DIRECT mode (no GUI, no shared state with other worlds)."""

    def __init__(self, physics: PhysicsConfig | None = None) -> None:
        # PyBullet loads here, not at import: the MuJoCo engine's path runs where PyBullet has no
        # wheel (Python 3.12 GPU machines). The first import silences its banner.
        from aslexp.sim._pybullet import c_output_quieted, pybullet
        from pybullet_utils import bullet_client

        self.physics = physics or PhysicsConfig()
        with c_output_quieted((1,)):  # PyBullet's C code prints "argv[0]=" on every connection
            self.client = bullet_client.BulletClient(connection_mode=pybullet.DIRECT)
        self.client.setTimeStep(1.0 / self.physics.physics_hz)
        self.client.setGravity(*self.physics.gravity)
        self.client.setPhysicsEngineParameter(
            numSolverIterations=int(self.physics.solver_iterations),
            numNonContactInnerIterations=int(self.physics.non_contact_inner_iterations),
        )

    @property
    def timestep(self) -> float:
        return 1.0 / self.physics.physics_hz

    def add_ground(self) -> int:
        """A static plane through the origin facing against gravity (y up: the motions' frame)."""
        import pybullet_data

        up = np.asarray(self.physics.gravity, dtype=np.float64)
        up = -up / max(np.linalg.norm(up), 1e-12)
        xyzw = wxyz_to_xyzw(z_to(up))  # plane_implicit.urdf faces +z; turn +z onto `up`
        return self.client.loadURDF(str(Path(pybullet_data.getDataPath()) / "plane_implicit.urdf"),
                                    [0.0, 0.0, 0.0], xyzw, useMaximalCoordinates=True)

    def step(self, substeps: int = 1) -> None:
        for _ in range(substeps):
            self.client.stepSimulation()

    def close(self) -> None:
        if self.client is not None:
            from aslexp.sim._pybullet import pybullet

            try:
                self.client.disconnect()
            except pybullet.error:
                pass
            self.client = None

    def __del__(self) -> None:  # pragma: no cover - best effort at interpreter exit
        try:
            self.close()
        except Exception:
            pass


class Character:
    """A body in a world: load it, set its pose, read joints and links in motion-layout terms."""

    engine = "pybullet"

    def __init__(self, world: World, urdf: str | os.PathLike, spec: BodySpec, layout: BodyLayout,
                 base_position=(0.0, 0.0, 0.0), base_orientation_wxyz=(1.0, 0.0, 0.0, 0.0),
                 kinematic: bool = False) -> None:
        self.world = world
        self.spec = spec
        self.layout = layout
        pb = world.client
        flags = pb.URDF_MAINTAIN_LINK_ORDER
        if spec.inertia_from_file:
            flags |= pb.URDF_USE_INERTIA_FROM_FILE
        if spec.self_collision and not kinematic:
            flags |= pb.URDF_USE_SELF_COLLISION | pb.URDF_USE_SELF_COLLISION_EXCLUDE_ALL_PARENTS
        path = Path(urdf)
        if not path.is_file():
            raise FileNotFoundError(f"URDF not found: {path}")
        # A kinematic reference is never stepped: a fixed base is the cheapest holder for it.
        self.base = "fixed" if kinematic else spec.base
        from aslexp.sim._pybullet import c_output_quieted

        with c_output_quieted((1, 2)):  # "no axis element for Joint" per spherical joint, per load
            self.id = pb.loadURDF(
                str(path), list(base_position), wxyz_to_xyzw(np.asarray(base_orientation_wxyz)),
                useFixedBase=self.base == "fixed", globalScaling=spec.global_scaling, flags=flags,
            )
        self._pin: int | None = None
        if self.base == "pinned":
            # Held by a constraint, not welded: PyBullet 3.2.7's stable PD reads a fixed-base body's
            # joint states 7 slots off (its server's convertPose), a pinned free base reads right.
            self._pin = pb.createConstraint(self.id, -1, -1, -1, pb.JOINT_FIXED, [0, 0, 0], [0, 0, 0],
                                            list(base_position),
                                            childFrameOrientation=wxyz_to_xyzw(base_orientation_wxyz))
            pb.changeConstraint(self._pin, maxForce=1e9)
        self.num_links = pb.getNumJoints(self.id)
        self.link_names = [pb.getJointInfo(self.id, i)[12].decode() for i in range(self.num_links)]
        self.joint_indices = [j.index for j in layout.joints]
        self.end_effector_links = [self._link_index(name) for name in spec.end_effectors]
        self.end_effector_offset = np.asarray(spec.end_effector_offset, dtype=np.float64)
        if kinematic:
            # A reference pose holder: no collisions, never simulated.
            pb.setCollisionFilterGroupMask(self.id, -1, 0, 0)
            for link in range(self.num_links):
                pb.setCollisionFilterGroupMask(self.id, link, 0, 0)
        self._disable_default_motors()

    def _link_index(self, name: str) -> int:
        try:
            return self.link_names.index(name)
        except ValueError:
            raise ValueError(f"body {self.spec.name}: no link named {name!r}; links: {self.link_names}") from None

    def _disable_default_motors(self) -> None:
        """PyBullet gives every joint a default motor; switch them off (spherical ones too)."""
        pb = self.world.client
        for joint in self.layout.joints:
            if joint.dof == 1:
                pb.setJointMotorControl2(self.id, joint.index, pb.VELOCITY_CONTROL, force=0)
            else:
                pb.setJointMotorControlMultiDof(self.id, joint.index, pb.POSITION_CONTROL,
                                                targetPosition=[0, 0, 0, 1], positionGain=0,
                                                velocityGain=0, force=[0, 0, 0])

    # -- state -----------------------------------------------------------------------------
    def set_base(self, position, orientation_wxyz, linear_velocity=(0.0, 0.0, 0.0),
                 angular_velocity=(0.0, 0.0, 0.0)) -> None:
        """Teleport the root (a pinned root is pinned there); a fixed root only moves."""
        pb = self.world.client
        xyzw = wxyz_to_xyzw(orientation_wxyz)
        pb.resetBasePositionAndOrientation(self.id, [float(v) for v in position], xyzw)
        if self.base == "fixed":
            return
        if self._pin is not None:
            pb.changeConstraint(self._pin, jointChildPivot=[float(v) for v in position],
                                jointChildFrameOrientation=xyzw, maxForce=1e9)
            linear_velocity = angular_velocity = (0.0, 0.0, 0.0)
        pb.resetBaseVelocity(self.id, [float(v) for v in linear_velocity], [float(v) for v in angular_velocity])

    def ground_contacts(self, ground: int) -> set[int]:
        """Link indices (-1: the base) touching the body ``ground``."""
        return {c[3] for c in self.world.client.getContactPoints(bodyA=self.id, bodyB=ground)}

    def set_state(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        """Teleport the joints to ``q`` (motion-layout joint vector) with velocities ``qd``."""
        pb = self.world.client
        if self.layout.all_revolute:  # one array call instead of one call per joint
            velocities = np.zeros_like(q) if qd is None else qd
            pb.resetJointStatesMultiDof(self.id, self.joint_indices, [[float(v)] for v in q],
                                        [[float(v)] for v in velocities])
            return
        positions, velocities = [], []
        offset, voffset = 0, 0
        for joint in self.layout.joints:
            if joint.dof == 1:
                positions.append([float(q[offset])])
                velocities.append([0.0 if qd is None else float(qd[voffset])])
                offset, voffset = offset + 1, voffset + 1
            else:
                positions.append(wxyz_to_xyzw(q[offset:offset + 4]))
                velocities.append([0.0] * 3 if qd is None else [float(v) for v in qd[voffset:voffset + 3]])
                offset, voffset = offset + 4, voffset + 3
        pb.resetJointStatesMultiDof(self.id, self.joint_indices, positions, velocities)

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Joint positions (motion layout) and velocities (1 per revolute, 3 per spherical joint)."""
        pb = self.world.client
        if self.layout.all_revolute:
            states = pb.getJointStates(self.id, self.joint_indices)
            return (np.fromiter((s[0] for s in states), np.float64, len(states)),
                    np.fromiter((s[1] for s in states), np.float64, len(states)))
        return pack_joint_states(self.layout.joints, pb.getJointStatesMultiDof(self.id, self.joint_indices))

    def base_state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Root position, orientation (w x y z), linear and angular velocity (world frame)."""
        pb = self.world.client
        pos, orn = pb.getBasePositionAndOrientation(self.id)
        lin, ang = pb.getBaseVelocity(self.id)
        return (np.asarray(pos), np.asarray([orn[3], orn[0], orn[1], orn[2]]),
                np.asarray(lin), np.asarray(ang))

    def link_states(self, velocities: bool = True, links: list[int] | None = None) -> np.ndarray:
        """Per link (all non-base links): world position, orientation (w x y z), lin/ang velocity.

        Shape (num_links, 13); the orientation is the link frame's, positions its origin. With
        ``links`` only those rows are read from PyBullet (the others stay zero): the environment
        asks for the links it observes and rewards, not all of them.
        """
        pb = self.world.client
        indices = list(range(self.num_links)) if links is None else list(links)
        states = pb.getLinkStates(self.id, indices,
                                  computeLinkVelocity=int(velocities), computeForwardKinematics=1)
        return pack_link_states(states, indices, self.num_links, velocities)

    def end_effector_positions(self, links: np.ndarray | None = None) -> np.ndarray:
        """World positions of the end-effector tips, shape (num_end_effectors, 3)."""
        if links is None:  # only the end-effector links (the reference character's question)
            links = self.link_states(velocities=False, links=self.end_effector_links)
        tips = links[self.end_effector_links]
        return tips[:, 0:3] + rotate(tips[:, 3:7], self.end_effector_offset)


def pack_joint_states(joints, states) -> tuple[np.ndarray, np.ndarray]:
    """PyBullet multi-DoF joint states (one per joint of ``joints``) as the motion layout's vectors:
    positions (a spherical joint's quaternion as w x y z) and velocities (1 or 3 per joint)."""
    q, qd = [], []
    for joint, (pos, vel, *_rest) in zip(joints, states):
        if joint.dof == 1:
            q.append(pos[0])
            qd.append(vel[0])
        else:
            q.extend([pos[3], pos[0], pos[1], pos[2]])
            qd.extend(vel)
    return np.asarray(q), np.asarray(qd)


def pack_link_states(states, indices, num_links: int, velocities: bool = True) -> np.ndarray:
    """PyBullet link states of the links ``indices`` as rows of a (num_links, 13) array: world
    position, orientation (w x y z), linear and angular velocity; rows not read stay zero."""
    out = np.zeros((num_links, 13))
    for i, s in zip(indices, states):
        out[i, 0:3] = s[4]
        x, y, z, w = s[5]
        out[i, 3:7] = (w, x, y, z)
        if velocities:
            out[i, 7:10] = s[6]
            out[i, 10:13] = s[7]
    return out
