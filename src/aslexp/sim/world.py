"""The physics engine: a PyBullet world in DIRECT mode and the characters in it.

A :class:`World` owns one PyBullet client (its own physics server: worlds never share state).
A :class:`Character` is a body loaded into a world, read and written in the motion layout's
terms (joint vector q in motion order, quaternions w x y z for spherical joints). The imitation
environment uses two worlds: the simulated character, stepped, and a kinematic reference
character in a world that is never stepped (it only answers forward-kinematics questions).
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from aslexp.quaternion import rotate, wxyz_to_xyzw, z_to
from aslexp.sim.body import BodyLayout, BodySpec
from aslexp.sim.engine import (DEFAULT_CAMERA, EngineSpec, PhysicsConfig, Simulation, SimulationRequest,
                               register_engine)


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
    """A body in a world: load it, set its pose, read joints and links in motion-layout terms
    (:class:`aslexp.sim.engine.EngineCharacter`)."""

    # PyBullet reports joint speeds after its own clamp only: no faster speed to tell
    peak_speed = 0.0
    peak_joint = ""

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

    # -- PD control (the engine seam; aslexp.sim.pd.PDController holds the gains) ---------------
    def check_controller(self, controller) -> None:
        """Refuse stable PD on a fixed-base body (PyBullet 3.2.7 misreads its joint states)."""
        if "stable_pd" in controller.by_mode and self.base == "fixed":
            groups = sorted({self.layout.joints[k].group for k in controller.by_mode["stable_pd"]})
            raise ValueError(
                f"controller {controller.spec.name}: stable PD needs a free base (body.base=pinned or free); "
                f"on a fixed base PyBullet 3.2.7 reads the joint states 7 slots off (body {self.spec.name}, "
                f"stable-PD groups {groups})")

    def drive(self, controller, targets: np.ndarray, target_velocities: np.ndarray | None, substeps: int) -> None:
        """Hold ``targets`` for ``substeps`` physics steps: a position motor is set once, a stable-PD
        command is re-sent before every step (PyBullet clears it after each). A mixed controller
        re-sends both: the position motors' command is the same, so sending it again changes nothing."""
        if not controller.resend_every_substep:
            self.apply_pd(controller, targets, target_velocities)
            self.world.step(substeps)
            return
        for _ in range(substeps):
            self.apply_pd(controller, targets, target_velocities)
            self.world.step(1)

    def apply_pd(self, controller, targets: np.ndarray, target_velocities: np.ndarray | None = None) -> None:
        """Drive towards ``targets`` (motion-layout joint vector) until the next call: one PyBullet
        motor call per mode, with that mode's joints."""
        controller.commands_sent += 1
        pb = self.world.client
        layout = self.layout
        for mode, joints in controller.by_mode.items():
            controller.motor_calls[mode] += 1
            ids = [self.joint_indices[k] for k in joints]
            kp = [controller.kp[k] for k in joints]
            kd = [controller.kd[k] for k in joints]
            if mode == "position" and all(layout.joints[k].dof == 1 for k in joints):
                pb.setJointMotorControlArray(
                    self.id, ids, pb.POSITION_CONTROL,
                    targetPositions=[float(targets[controller.offsets[k]]) for k in joints],
                    targetVelocities=[0.0 if target_velocities is None
                                      else float(target_velocities[controller.voffsets[k]]) for k in joints],
                    forces=[controller.max_force[k] for k in joints], positionGains=kp, velocityGains=kd,
                )
                continue
            positions, velocities, forces = [], [], []
            for k in joints:
                joint, offset, voffset = layout.joints[k], controller.offsets[k], controller.voffsets[k]
                if joint.dof == 1:
                    positions.append([float(targets[offset])])
                    velocities.append([0.0 if target_velocities is None else float(target_velocities[voffset])])
                    forces.append([controller.max_force[k]])
                else:
                    w, x, y, z = targets[offset:offset + 4]
                    norm = math.sqrt(w * w + x * x + y * y + z * z)
                    if norm < 1e-6:  # a policy's zero quaternion: hold the identity rotation
                        w, x, y, z, norm = 1.0, 0.0, 0.0, 0.0, 1.0
                    positions.append([float(x / norm), float(y / norm), float(z / norm), float(w / norm)])
                    velocities.append([0.0, 0.0, 0.0] if target_velocities is None
                                      else [float(v) for v in target_velocities[voffset:voffset + 3]])
                    forces.append([controller.max_force[k]] * 3)
            pb.setJointMotorControlMultiDofArray(
                self.id, ids, pb.POSITION_CONTROL if mode == "position" else pb.STABLE_PD_CONTROL,
                targetPositions=positions, targetVelocities=velocities, forces=forces,
                positionGains=kp, velocityGains=kd,
            )


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


# -- rendering: PyBullet's TinyRenderer (no OpenGL), for its own worlds and any engine's poses ------

REFERENCE_RGB, SIMULATION_RGB = (0.25, 0.45, 0.85), (0.95, 0.55, 0.15)  # blue, orange


def colour(character: Character, rgb: tuple[float, float, float]) -> None:
    """Colour a character for rendering; distal links lighter so finger tips stand out."""
    pb = character.world.client
    for link in range(-1, character.num_links):
        shade = 1.0 if link < 0 or not character.link_names[link].endswith("dist") else 1.25
        pb.changeVisualShape(character.id, link, rgbaColor=[min(c * shade, 1.0) for c in rgb] + [1.0])


def snapshot(character: Character, size: tuple[int, int], camera: dict[str, float] | None = None) -> np.ndarray:
    """One (H, W, 3) image of ``character`` in its world."""
    camera = {**DEFAULT_CAMERA, **(camera or {})}
    pb = character.world.client
    base, _ = pb.getBasePositionAndOrientation(character.id)
    links = character.link_states(velocities=False)
    target = links[:, 0:3].mean(axis=0) if len(links) else np.asarray(base)
    width, height = size
    view = pb.computeViewMatrixFromYawPitchRoll(cameraTargetPosition=list(target),
                                                distance=float(camera["distance"]), yaw=float(camera["yaw"]),
                                                pitch=float(camera["pitch"]), roll=0, upAxisIndex=1)
    proj = pb.computeProjectionMatrixFOV(fov=60, aspect=width / height, nearVal=0.01, farVal=10.0)
    _, _, rgba, _, _ = pb.getCameraImage(width, height, view, proj, renderer=pb.ER_TINY_RENDERER)
    return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]


class PoseRenderer:
    """Draws the poses of another engine's characters: two coloured kinematic PyBullet holders
    (reference blue, simulation orange) posed from any :class:`~aslexp.sim.engine.EngineCharacter`."""

    def __init__(self, urdf, spec: BodySpec, layout: BodyLayout, physics: PhysicsConfig) -> None:
        self.holders = []
        for rgb in (REFERENCE_RGB, SIMULATION_RGB):
            holder = Character(World(PhysicsConfig(physics.physics_hz, physics.gravity)), urdf, spec, layout,
                               kinematic=True)
            colour(holder, rgb)
            self.holders.append(holder)

    def draw(self, sources, camera: dict[str, float], size: tuple[int, int]) -> np.ndarray:
        images = []
        for holder, source in zip(self.holders, sources):
            holder.set_state(*source.joint_state())
            position, rotation, _, _ = source.base_state()
            holder.set_base(position, rotation)
            images.append(snapshot(holder, size, camera))
        return np.concatenate(images, axis=1)

    def close(self) -> None:
        for holder in self.holders:
            holder.world.close()


@register_engine("pybullet", summary="PyBullet 3.2.7: the thesis' engine and the default")
def build(spec: EngineSpec, request: SimulationRequest) -> Simulation:
    """One environment: the simulated character in its world, the kinematic reference in a world of
    its own that is never stepped (it only answers forward-kinematics questions)."""
    sim_world, ref_world = World(request.physics), World(request.physics)
    sim = Character(sim_world, request.urdf, request.body, request.layout, request.root_position,
                    request.root_rotation)
    ground = sim_world.add_ground() if request.body.base == "free" else None
    ref = Character(ref_world, request.urdf, request.body, request.layout, request.root_position,
                    request.root_rotation, kinematic=True)
    if request.render:
        colour(ref, REFERENCE_RGB)
        colour(sim, SIMULATION_RGB)

    def render(camera: dict[str, float], size: tuple[int, int]) -> np.ndarray:
        return np.concatenate([snapshot(ref, size, camera), snapshot(sim, size, camera)], axis=1)

    def close() -> None:
        sim_world.close()
        ref_world.close()

    return Simulation(sim=sim, ref=ref, ground=ground, render_fn=render, close_fn=close)
