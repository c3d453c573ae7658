"""The MuJoCo engine: the thesis' bodies from the same URDFs, stepped one or many at a time.

:class:`MujocoBody` compiles a body config's URDF (``conf/body``) with MuJoCo's own URDF reader and
adds what PyBullet gets from load flags: every URDF link a body (no fused fixed links: the
observation sees PyBullet's links), the root held as the body config says (``fixed`` and ``pinned``:
a mocap body, so every environment of a batch can stand it where its reference stands; ``free``: a
free joint and a ground plane facing +y), self-collision with every ancestor excluded (PyBullet's
``URDF_USE_SELF_COLLISION_EXCLUDE_ALL_PARENTS``), ``global_scaling``, the motions' y-up gravity,
the physics rate, a site at each end effector's tip, and one PD actuator per joint degree of freedom
(three on a spherical joint, which MuJoCo calls ball) with gains from ``conf/controller``:

* ``stable_pd`` (physical gains, N m/rad and N m s/rad): force = kp (q* - q - dt qd) + kd (qd* - qd),
  Tan et al.'s stable PD with the damping integrated implicitly (``engine.integrator: implicitfast``).
* ``position`` (PyBullet's POSITION_CONTROL: a velocity constraint with dimensionless gains, the
  thesis' hand kp 0.22, kd 0.87): PyBullet asks the next velocity to be
  kp (q* - q) / dt + kd (qd* - qd); the torque that gives it to a joint of inertia I is
  I kp / dt^2 (q* - q) + I kd / dt qd* - I (1 + kd) / dt qd, so the actuator gets those physical
  gains with I the diagonal of the joint-space inertia at the model's zero pose, its stiffness times
  ``engine.motor_gain_scale`` (2: the implicit damping slows the response a per-step match would
  restore with 2 + kd, which diverges on the coupled finger chains at 240 Hz; 2 was chosen among
  1, 2 and 2.87 by the reference baselines' agreement on letters A-E, docs/engines.md), and no
  force limit (``max_force`` caps PyBullet's constraint impulse, not this torque: capped, the upper
  body's stand-in motors stall).
* ``physical_groups`` in a controller file replaces ``groups`` in MuJoCo with physical gains given as
  such (e.g. found by ``aslexp tune_pd engine=mujoco``).

Stepping goes through ``mujoco.rollout`` (C, threads, no Python per physics step) from full physics
states, for one environment (:class:`MujocoCharacter`, the gymnasium env) and for a batch
(:mod:`aslexp.envs.batched`) alike: one code path, so a batch equals its environments stepped one
by one (tested). Link states and end-effector tips come from a probe: the same model without
contacts or actuators, its sensors evaluated at many states in one ``mujoco.batch`` call.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aslexp.config_schema import Choice, Int, Positive, Section, key
from aslexp.quaternion import rotate, rotvec, z_to
from aslexp.sim.body import BodyLayout, BodySpec
from aslexp.sim.engine import EngineSpec, Simulation, SimulationRequest, register_engine
from aslexp.sim.urdf import read_joints


log = logging.getLogger("aslexp.mujoco")


def _mujoco():
    try:
        import mujoco
        from mujoco import rollout  # noqa: F401 - the batched stepper
    except ImportError as exc:  # pragma: no cover - a dependency in pyproject
        raise ImportError("engine=mujoco needs the mujoco package (pip install mujoco)") from exc
    if mujoco.get_mju_user_warning() is None:  # MuJoCo's warnings to the log, not MUJOCO_LOG.TXT in the cwd
        mujoco.set_mju_user_warning(_warn)
    return mujoco


_WARNINGS = {"count": 0}


def _warn(text: str) -> None:
    """MuJoCo's warnings, the first few in full: a diverging batch warns at every step of every
    environment, and the environments count and end those episodes themselves (``diverged``)."""
    _WARNINGS["count"] += 1
    count = _WARNINGS["count"]
    if count <= 5 or count in (10, 100, 1000) or count % 10000 == 0:
        log.warning("MuJoCo (warning %d%s): %s", count, "; later ones at 10, 100, 1000, every 10,000" if count == 5
                    else "", text.strip())


def _state_slices(mujoco, model) -> dict[str, slice]:
    """Where each component sits in aslexp's state vector of a MuJoCo body: the
    ``mjSTATE_FULLPHYSICS`` vector (components in the order of their bits, as mj_getState writes
    them), then the mocap bodies' positions and quaternions, which a rollout takes as controls."""
    full = int(mujoco.mjtState.mjSTATE_FULLPHYSICS)
    out, offset = {}, 0
    for bit in sorted(int(b) for b in mujoco.mjtState.__members__.values()):
        if bit & (bit - 1) or not bit & full:
            continue  # a combination, or not in the full physics state
        size = mujoco.mj_stateSize(model, bit)
        name = mujoco.mjtState(bit).name.removeprefix("mjSTATE_").lower()
        out[name] = slice(offset, offset + size)
        offset += size
    out["physics"] = slice(0, offset)
    out["mocap_pos"] = slice(offset, offset + 3 * model.nmocap)
    out["mocap_quat"] = slice(offset + 3 * model.nmocap, offset + 7 * model.nmocap)
    return out


# A rollout's controls: the actuators' inputs, then the mocap poses (the fixed and pinned roots).
CONTROL_SPEC = ("mjSTATE_CTRL", "mjSTATE_MOCAP_POS", "mjSTATE_MOCAP_QUAT")


INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")
SOLVERS = ("Newton", "CG", "PGS")


@dataclass(frozen=True)
class MujocoOptions(Section):
    """MuJoCo's own keys of ``conf/engine/mujoco.yaml``."""

    SECTION = "engine"

    # the integrator (implicitfast treats the PD actuators' damping implicitly: stable at any gain,
    # as stable PD), the constraint solver and its iterations
    integrator: str = field(default="implicitfast", metadata=key(Choice(*INTEGRATORS)))
    solver: str = field(default="Newton", metadata=key(Choice(*SOLVERS)))
    iterations: int = field(default=50, metadata=key(Int(1)))
    # controller mode position: the stiffness of the actuators that stand for PyBullet's velocity
    # motor, times this (the module docstring says why 2)
    motor_gain_scale: float = field(default=2.0, metadata=key(Positive()))
    # threads stepping a batch of environments (0: every core this process may use)
    threads: int = field(default=0, metadata=key(Int(0)))
    # every generalised velocity (the joints' and a free base's six) clamped to +-this after each
    # physics step, and the step's positions integrated with the clamped velocity: PyBullet's
    # btMultiBody does exactly this whenever it applies a velocity change (maxJointVelocity, 100 rad/s
    # by default, which aslexp never changes), so both engines share one joint-speed semantics.
    # null: MuJoCo's own, no clamp (a transient PyBullet cannot produce, e.g. at a looping motion's seam).
    joint_speed_limit: float | None = field(default=100.0, metadata=key(Positive(nullable=True)))  # rad/s


DEFAULT_SPEC = EngineSpec(name="mujoco", options=MujocoOptions())


class MujocoBody:
    """A body config compiled for MuJoCo, with the maps between the motion layout and MuJoCo's
    vectors (qpos, qvel, ctrl, state)."""

    def __init__(self, urdf: str | os.PathLike, spec: BodySpec, layout: BodyLayout, physics, controller=None,
                 engine: EngineSpec | None = None) -> None:
        mujoco = _mujoco()
        self.mujoco = mujoco
        self.spec, self.layout, self.physics = spec, layout, physics
        self.engine = engine or DEFAULT_SPEC
        self.controller = controller
        urdf = Path(urdf)
        joints = read_joints(urdf)
        # PyBullet's link order (URDF_MAINTAIN_LINK_ORDER): each joint's child link, file order.
        self.link_names = [j.child for j in joints]
        self.num_links = len(self.link_names)
        mspec = mujoco.MjSpec.from_file(str(urdf))
        mspec.compiler.fusestatic = False  # keep fixed links: PyBullet observes them
        mspec.compiler.discardvisual = True
        root = mspec.worldbody.first_body()
        self.root_name = root.name
        self.base = spec.base
        if spec.global_scaling != 1.0:
            _scale(mspec, float(spec.global_scaling))
        if spec.base == "free":
            root.add_freejoint()
        else:  # fixed or pinned: a mocap body, placed per environment through the state
            root.mocap = True
        mspec.option.timestep = 1.0 / float(physics.physics_hz)
        mspec.option.gravity = list(physics.gravity)
        mspec.option.integrator = getattr(mujoco.mjtIntegrator, f"mjINT_{self.engine.options.integrator.upper()}")
        mspec.option.solver = getattr(mujoco.mjtSolver, f"mjSOL_{self.engine.options.solver.upper()}")
        mspec.option.iterations = int(self.engine.options.iterations)
        bodies = {b.name: b for b in mspec.bodies}
        self._collisions(mspec)
        for k, name in enumerate(spec.end_effectors):
            if name not in bodies:
                raise ValueError(f"body {spec.name}: no link named {name!r}; links: {self.link_names}")
            bodies[name].add_site(name=f"tip_{k}", pos=list(spec.end_effector_offset))
        self._add_actuators(mspec)
        if not spec.inertia_from_file:
            _inertia_from_shapes(mujoco, mspec)
        # A diverging state stays diverged (MuJoCo would silently reset it): the env counts and ends it.
        mspec.option.disableflags = int(mujoco.mjtDisableBit.mjDSBL_AUTORESET)
        self._extend_spec(mspec)
        self.model = mspec.compile()  # the physics: no sensors to evaluate at every step
        self.tip_probe, self.probe = self._compile_probes(mspec, root.name)
        self._tip_values = 3 * len(spec.end_effectors)
        self.slices = _state_slices(mujoco, self.model)
        self.state_size = self.slices["mocap_quat"].stop
        self.physics_size = self.slices["physics"].stop
        self.control_spec = sum(int(getattr(mujoco.mjtState, name)) for name in CONTROL_SPEC)
        self._index_maps(urdf)
        self._data = mujoco.MjData(self.model)
        self.set_gains(controller)
        self._runner = None
        self.clamped_steps = 0  # physics steps of one environment where the joint-speed clamp acted
        self.peak_speeds = np.zeros(0)  # per environment of the last step(): fastest joint before the clamp
        self.peak_dofs = np.zeros(0, dtype=int)  # and its MuJoCo degree of freedom (dof_name)
        self._dof_names = {int(v): name for v, name in zip(self.qvel_index, layout.velocity_names)}

    def _collisions(self, mspec) -> None:
        """PyBullet's collision rules: self collision without any ancestor pair, else the ground only;
        a free base's ground plane, normal to gravity."""
        spec, mujoco = self.spec, self.mujoco
        if spec.self_collision:
            for body in mspec.bodies:  # PyBullet excludes every ancestor; MuJoCo only the parent
                ancestor = body.parent
                ancestor = ancestor.parent if ancestor is not None and ancestor.name != "world" else None
                while ancestor is not None and ancestor.name != "world":
                    mspec.add_exclude(bodyname1=ancestor.name, bodyname2=body.name)
                    ancestor = ancestor.parent
        else:  # the body's geoms collide with the ground only
            for geom in mspec.geoms:
                geom.contype, geom.conaffinity = 2, 1
        if spec.base == "free":
            up = -np.asarray(self.physics.gravity, dtype=np.float64)
            up /= max(np.linalg.norm(up), 1e-12)
            ground = mspec.worldbody.add_geom(name="ground", type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1])
            ground.quat = z_to(up)
            ground.contype, ground.conaffinity = 1, 3

    def _add_actuators(self, mspec) -> None:
        """One PD actuator per degree of freedom of the layout's joints, in layout order."""
        mujoco = self.mujoco
        axes = np.eye(3)
        for joint in self.layout.joints:
            for axis in ([None] if joint.dof == 1 else axes):
                act = mspec.add_actuator(name=joint.name if axis is None else f"{joint.name}_{'xyz'[int(np.argmax(axis))]}",
                                         target=joint.name, trntype=mujoco.mjtTrn.mjTRN_JOINT)
                if axis is not None:
                    act.gear = [*axis, 0, 0, 0]
                act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
                act.biastype = mujoco.mjtBias.mjBIAS_AFFINE
                act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE

    def _compile_probes(self, mspec, root_name: str):
        """The tip probe and the link probe (see below), compiled from the physics' spec."""
        # Probes read what the observation and reward need, as sensors: the end-effector tips (the
        # reference's probe), then every link's and the root's frame (world position, orientation,
        # linear and angular velocity; the simulated body's probe). A probe is the model without
        # contacts, constraints or actuators, whose forward stages (:meth:`_probe`) read a state's sensors.
        mujoco = self.mujoco
        for k in range(len(self.spec.end_effectors)):
            mspec.add_sensor(type=mujoco.mjtSensor.mjSENS_FRAMEPOS, objtype=mujoco.mjtObj.mjOBJ_SITE, objname=f"tip_{k}")
        tip_probe = mspec.compile()
        for name in [root_name, *self.link_names]:
            for kind in ("FRAMEPOS", "FRAMEQUAT", "FRAMELINVEL", "FRAMEANGVEL"):
                mspec.add_sensor(type=getattr(mujoco.mjtSensor, f"mjSENS_{kind}"), objtype=mujoco.mjtObj.mjOBJ_XBODY,
                                 objname=name)
        probe = mspec.compile()
        off = mujoco.mjtDisableBit
        for one in (probe, tip_probe):
            one.opt.disableflags = int(off.mjDSBL_CONSTRAINT | off.mjDSBL_CONTACT | off.mjDSBL_ACTUATION
                                       | off.mjDSBL_GRAVITY | off.mjDSBL_SPRING | off.mjDSBL_DAMPER
                                       | off.mjDSBL_WARMSTART | off.mjDSBL_ISLAND | off.mjDSBL_AUTORESET)
            one.opt.integrator = mujoco.mjtIntegrator.mjINT_EULER
        return tip_probe, probe

    def _index_maps(self, urdf: Path) -> None:
        """The maps between layout vectors and MuJoCo's: joints to qpos/qvel, links to bodies, the
        root's free joint, the tips' bodies, the ground geom."""
        mujoco, m, spec, layout = self.mujoco, self.model, self.spec, self.layout
        qpos_index, qvel_index = [], []
        for joint in layout.joints:
            jid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, joint.name)
            if jid < 0:
                raise ValueError(f"body {spec.name}: MuJoCo dropped joint {joint.name!r} of {urdf}")
            qpos_index.extend(range(m.jnt_qposadr[jid], m.jnt_qposadr[jid] + joint.dof))
            qvel_index.extend(range(m.jnt_dofadr[jid], m.jnt_dofadr[jid] + (1 if joint.dof == 1 else 3)))
        self.qpos_index, self.qvel_index = np.asarray(qpos_index), np.asarray(qvel_index)
        self.spherical = np.asarray([j.dof == 4 for j in layout.joints])
        self.link_bodies = np.asarray([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, n) for n in self.link_names])
        if np.any(self.link_bodies < 0):
            missing = [n for n, b in zip(self.link_names, self.link_bodies) if b < 0]
            raise ValueError(f"body {spec.name}: MuJoCo has no bodies for links {missing} of {urdf}")
        self.root_body = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, self.root_name)
        self._body_link = {int(b): i for i, b in enumerate(self.link_bodies)}  # a body id -> its link index
        self.root_free_qpos = (int(m.jnt_qposadr[m.body_jntadr[self.root_body]]) if spec.base == "free" else None)
        self.root_free_qvel = (int(m.jnt_dofadr[m.body_jntadr[self.root_body]]) if spec.base == "free" else None)
        self.tip_bodies = np.asarray([m.site_bodyid[k] for k in range(len(spec.end_effectors))], dtype=int)
        self.ground_geom = (mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "ground") if spec.base == "free" else -1)

    def _extend_spec(self, mspec) -> None:
        """What a subclass adds to the model before it compiles (the MJX engine: its collision limits)."""

    def dof_name(self, dof: int) -> str:
        """The layout joint a MuJoCo degree of freedom belongs to ("the root" for a free base's)."""
        return self._dof_names.get(int(dof), "the root")

    # -- control ------------------------------------------------------------------------------------
    def set_gains(self, controller) -> None:
        """Write the actuators' gains for a :class:`~aslexp.sim.pd.PDController` (None: zero)."""
        m, mujoco = self.model, self.mujoco
        self.controller = controller
        nu = m.nu
        kp, kv, kv_target, limit = np.zeros(nu), np.zeros(nu), np.zeros(nu), np.full(nu, np.inf)
        if controller is not None:
            dt = m.opt.timestep
            spec = controller.spec
            groups = spec.physical_groups or spec.groups
            inertia = self.joint_inertia()
            i = 0
            for joint in self.layout.joints:
                gains = groups.get(joint.group, groups.get("default"))
                if gains is None:
                    raise ValueError(f"controller {spec.name}: no gains for joint group {joint.group!r} and no `default`")
                # Per group: stable-PD groups (the group's `mode`, else the controller's) and every
                # physical_groups entry carry physical gains; position groups get the motor's stand-in.
                physical = bool(spec.physical_groups) or spec.mode_of(gains) == "stable_pd"
                for k in range(1 if joint.dof == 1 else 3):
                    if physical:  # stable PD: kp (q* - q - dt qd) + kd (qd* - qd)
                        kp[i], kv[i], kv_target[i] = gains.kp, gains.kd + gains.kp * dt, gains.kd
                    else:  # PyBullet's velocity-constraint motor, per joint (module docstring)
                        mass = inertia[i]
                        kv[i], kv_target[i] = (1.0 + gains.kd) * mass / dt, gains.kd * mass / dt
                        kp[i] = self.engine.options.motor_gain_scale * gains.kp * mass / (dt * dt)
                    # PyBullet caps its motor's constraint impulse; the stand-in's PD torque also fights
                    # the coupled chain and gravity that the constraint absorbs, and capped at the same
                    # value it stalls the upper body (docs/engines.md): only physical gains keep the cap.
                    limit[i] = gains.max_force if physical else np.inf
                    i += 1
        m.actuator_gainprm[:, 0] = kp
        m.actuator_biasprm[:, 0:3] = np.stack([np.zeros(nu), -kp, -kv], axis=1)
        finite = np.isfinite(limit)
        m.actuator_forcelimited[:] = finite
        m.actuator_forcerange[:] = np.stack([-np.where(finite, limit, 0), np.where(finite, limit, 0)], axis=1)
        self._velocity_lead = np.divide(kv_target, kp, out=np.zeros(nu), where=kp > 0)
        mujoco.mj_setConst(m, self._data)

    def joint_inertia(self) -> np.ndarray:
        """Per actuator, the joint-space inertia's diagonal entry of its degree of freedom (zero pose)."""
        m, d, mujoco = self.model, self._data, self.mujoco
        mujoco.mj_resetData(m, d)
        mujoco.mj_forward(m, d)
        full = np.zeros((m.nv, m.nv))
        mujoco.mj_fullM(m, d, full)
        return np.diag(full)[self.qvel_index]

    def controls(self, targets: np.ndarray, target_velocities: np.ndarray | None = None) -> np.ndarray:
        """(N, nu) actuator inputs for (N, layout) joint targets (quaternions w x y z for spherical
        joints: each becomes its rotation vector, what a ball joint's three actuators measure) and
        (N, velocity layout) target velocities (None: zero)."""
        targets = np.atleast_2d(np.asarray(targets, dtype=np.float64))
        if not self.spherical.any():
            ctrl = targets.copy()
        else:
            parts, offset = [], 0
            for joint in self.layout.joints:
                if joint.dof == 1:
                    parts.append(targets[:, offset:offset + 1])
                else:
                    quat = targets[:, offset:offset + 4]
                    norm = np.linalg.norm(quat, axis=1, keepdims=True)
                    quat = np.where(norm < 1e-6, np.array([1.0, 0, 0, 0]), quat / np.maximum(norm, 1e-12))
                    parts.append(rotvec(quat))
                offset += joint.dof
            ctrl = np.concatenate(parts, axis=1)
        if target_velocities is not None:
            ctrl = ctrl + self._velocity_lead * np.atleast_2d(target_velocities)
        return ctrl

    # -- states -------------------------------------------------------------------------------------
    def new_states(self, n: int) -> np.ndarray:
        """(n, state) full physics states at the model's zero pose."""
        m, d, mujoco = self.model, self._data, self.mujoco
        mujoco.mj_resetData(m, d)
        state = np.empty(self.state_size)
        mujoco.mj_getState(m, d, state[:self.physics_size], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        state[self.slices["mocap_pos"]] = d.mocap_pos.ravel()
        state[self.slices["mocap_quat"]] = d.mocap_quat.ravel()
        return np.tile(state, (n, 1))

    def write(self, states: np.ndarray, rows, q: np.ndarray, qd: np.ndarray | None, root_pos: np.ndarray,
              root_rot: np.ndarray, root_vel: np.ndarray | None = None, root_ang: np.ndarray | None = None) -> None:
        """Teleport the rows ``rows`` of ``states``: joints (:meth:`write_joints`), then the root
        (:meth:`write_root`)."""
        self.write_joints(states, rows, q, qd)
        self.write_root(states, rows, root_pos, root_rot, root_vel, root_ang)

    def write_joints(self, states: np.ndarray, rows, q: np.ndarray, qd: np.ndarray | None) -> None:
        """Set the layout's joint values ``q`` and velocities ``qd`` (None: zero) in ``states[rows]``."""
        qpos, qvel = states[rows, self.slices["qpos"]], states[rows, self.slices["qvel"]]
        qpos[..., self.qpos_index] = q
        qvel[..., self.qvel_index] = 0.0 if qd is None else qd
        states[rows, self.slices["qpos"]] = qpos
        states[rows, self.slices["qvel"]] = qvel

    def write_root(self, states: np.ndarray, rows, root_pos: np.ndarray, root_rot: np.ndarray,
                   root_vel: np.ndarray | None = None, root_ang: np.ndarray | None = None) -> None:
        """Place the root: a mocap root takes the pose; a free root the pose and the world linear
        and angular velocities (None: zero)."""
        if self.root_free_qpos is None:
            states[rows, self.slices["mocap_pos"]] = root_pos
            states[rows, self.slices["mocap_quat"]] = root_rot
            return
        qpos, qvel = states[rows, self.slices["qpos"]], states[rows, self.slices["qvel"]]
        a, v = self.root_free_qpos, self.root_free_qvel
        qpos[..., a:a + 3], qpos[..., a + 3:a + 7] = root_pos, root_rot
        qvel[..., v:v + 3] = 0.0 if root_vel is None else root_vel
        # MuJoCo's free joint: angular velocity in the body frame
        qvel[..., v + 3:v + 6] = 0.0 if root_ang is None else rotate(_conjugate(root_rot), root_ang)
        states[rows, self.slices["qpos"]] = qpos
        states[rows, self.slices["qvel"]] = qvel

    def joints(self, states: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, layout) joint values and (N, velocity layout) velocities of ``states``."""
        return (states[:, self.slices["qpos"]][:, self.qpos_index],
                states[:, self.slices["qvel"]][:, self.qvel_index])

    def read(self, states: np.ndarray, tips_only: bool = False) -> np.ndarray:
        """(N, sensors) of ``states``: the end-effector tips' positions (3 each), then (unless
        ``tips_only``) per frame (the root, then PyBullet's links) world position, orientation
        (w x y z), linear velocity of its origin and angular velocity (13 values). See
        :meth:`frames` and :meth:`tips`."""
        return self._probe(self.tip_probe if tips_only else self.probe, states,
                           self.mujoco.mjtStage.mjSTAGE_POS if tips_only else self.mujoco.mjtStage.mjSTAGE_VEL)

    def _probe(self, model, states: np.ndarray, stage) -> np.ndarray:
        """``model``'s sensors at ``states`` (N, state): its forward stages up to ``stage`` (positions
        for the tips; velocities too for the frames) in one ``mujoco.batch`` call on the thread pool,
        no step (a rollout step would also build and factor the inertia and integrate, for nothing).
        The values are those a probe step's sensors read, bit for bit (tested)."""
        n = len(states)
        self._runners()
        probe = self._probes.get(id(model))
        if probe is None or probe[0].nsim < n:  # one batch per probe, grown to the most rows read at once
            from mujoco import batch as mj_batch

            size = max(n, 2 * probe[0].nsim if probe else 1)
            batch = mj_batch.Batch(model, nsim=size, nthread=self._threads if self._threads > 1 else 1)
            probe = self._probes[id(model)] = (batch, *(batch.bind(f) for f in
                                                        ("qpos", "qvel", "mocap_pos", "mocap_quat", "sensordata")))
        batch, qpos, qvel, mocap_pos, mocap_quat, sensordata = probe
        slices = self.slices
        qpos[:n], qvel[:n] = states[:, slices["qpos"]], states[:, slices["qvel"]]
        mocap_pos[:n] = states[:, slices["mocap_pos"]].reshape(n, -1, 3)
        mocap_quat[:n] = states[:, slices["mocap_quat"]].reshape(n, -1, 4)
        batch.forward(ids=None if n == batch.nsim else np.arange(n), stage=int(stage))
        return sensordata[:n].copy()

    def frames(self, sensors: np.ndarray) -> np.ndarray:
        """(N, 1 + num_links, 13) frame rows of :meth:`read`'s values: the root, then the links."""
        return sensors[:, self._tip_values:].reshape(len(sensors), 1 + self.num_links, 13)

    def tips(self, sensors: np.ndarray) -> np.ndarray:
        """(N, end effectors, 3) world positions of the end-effector tips."""
        return sensors[:, :self._tip_values].reshape(len(sensors), -1, 3)

    def step(self, states: np.ndarray, ctrl: np.ndarray, nstep: int) -> np.ndarray:
        """Advance (N, state) ``states`` by ``nstep`` physics steps under held controls (N, nu), in
        place and in C threads (one per core unless ``engine.threads``); returns ``states``."""
        self._rollout(self.model, states, ctrl, nstep)
        return states

    def _runners(self) -> None:
        """The thread pools, made at the first step or read (``engine.threads``; 0: every core)."""
        if self._runner is None:
            from mujoco import rollout

            threads = self.engine.options.threads or (len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity")
                                              else os.cpu_count() or 1)
            self._threads = max(1, threads)
            # A pool for batches; one environment steps in this thread (a hand-off costs more than its step).
            self._runner = rollout.Rollout(nthread=self._threads if self._threads > 1 else 0)
            self._single = rollout.Rollout(nthread=0) if self._threads > 1 else self._runner
            self._datas = {id(self.model): [self.mujoco.MjData(self.model) for _ in range(self._threads)]}
            self._buffers: dict[tuple, tuple] = {}
            self._probes: dict[int, tuple] = {}

    def _rollout(self, model, states: np.ndarray, ctrl: np.ndarray, nstep: int):
        self._runners()
        n = len(states)
        key = (id(model), n, nstep)
        buffers = self._buffers.get(key)
        if buffers is None:  # the arguments the C rollout takes without Python's checks
            buffers = self._buffers[key] = ([model] * n, np.empty((n, nstep, self.physics_size)),
                                            np.empty((n, nstep, model.nsensordata)))
        models, out, sensordata = buffers
        inputs = np.concatenate([ctrl, states[:, self.physics_size:]], axis=1)
        control = np.ascontiguousarray(np.broadcast_to(inputs[:, None, :], (n, nstep, inputs.shape[1])))
        initial = np.ascontiguousarray(states[:, :self.physics_size])
        datas = self._datas[id(model)]
        runner, datas = (self._runner, datas) if n > 1 else (self._single, datas[:1])
        runner.rollout(models, datas, initial, control, control_spec=self.control_spec, nstep=nstep,
                       state=out, sensordata=sensordata, skip_checks=True)
        # Each environment's fastest joint over the substeps, before any clamp (NaN stays NaN): what
        # the environments' divergence guard reads, so the clamp cannot hide a simulation that blew up.
        velocity = np.abs(out[:, :, self.slices["qvel"]])
        speeds = velocity.max(axis=(1, 2)) if n else np.zeros(0)
        limit = self.engine.options.joint_speed_limit
        # and which degree of freedom it was (a NaN counts as the fastest), what a blow-up names: only
        # for the environments past the clamp's speed (a blow-up passes it), none on most steps
        self.peak_dofs = np.zeros(n, dtype=int)
        for row in np.flatnonzero(~(speeds <= (limit if limit is not None else 100.0))):
            self.peak_dofs[row] = int(np.argmax(np.where(np.isnan(velocity[row]), np.inf, velocity[row]).max(axis=0)))
        if limit is not None:
            # The fast path checks every substep of the whole batch at once; only an environment
            # that passed the limit somewhere is stepped again, one substep at a time, clamped.
            for row in np.flatnonzero(~(speeds <= limit)):
                out[row, -1], speeds[row] = self._clamped_steps(model, initial[row], inputs[row], nstep, float(limit))
        self.peak_speeds = speeds
        states[:, :self.physics_size] = out[:, -1]
        return states

    def _clamped_steps(self, model, initial: np.ndarray, inputs: np.ndarray, nstep: int,
                       limit: float) -> tuple[np.ndarray, float]:
        """One environment's ``nstep`` physics steps with PyBullet's joint-speed clamp: after each
        step every generalised velocity is clipped to +-``limit`` and the positions are integrated
        from the step's start with the clipped velocity (btMultiBody clamps the velocity before it
        steps the positions). Returns the final physics state and the fastest joint speed the steps
        produced before clamping (NaN if one was not finite)."""
        mujoco, qpos, qvel = self.mujoco, self.slices["qpos"], self.slices["qvel"]
        runner = self._single
        data = self._datas[id(model)][:1]
        state = initial[None].copy()
        control = np.ascontiguousarray(inputs[None, None, :])
        step = np.empty((1, 1, self.physics_size))
        dt = float(model.opt.timestep)
        peak = 0.0
        for _ in range(nstep):
            runner.rollout([model], data, state, control, control_spec=self.control_spec, nstep=1, state=step,
                           skip_checks=True)
            new = step[0, 0].copy()
            velocity = new[qvel]
            fastest = float(np.max(np.abs(velocity))) if len(velocity) else 0.0
            peak = fastest if not fastest <= peak else peak  # a NaN is kept
            if np.any(np.abs(velocity) > limit):
                self.clamped_steps += 1
                clipped = np.clip(velocity, -limit, limit)
                position = state[0, qpos].copy()
                mujoco.mj_integratePos(model, position, clipped, dt)
                new[qpos], new[qvel] = position, clipped
            state[0] = new
        return state[0], peak

    def set_threads(self, threads: int) -> None:
        """Step batches on ``threads`` threads (rollout workers: one each; 0: every core)."""
        self.engine = self.engine.replace(threads=int(threads))

    def contacts(self, state: np.ndarray) -> set[int]:
        """Link indices (-1: the root) touching the ground in one state."""
        if self.ground_geom < 0:
            return set()
        m, d, mujoco = self.model, self._data, self.mujoco
        mujoco.mj_setState(m, d, state[:self.physics_size], mujoco.mjtState.mjSTATE_FULLPHYSICS)
        d.mocap_pos[:] = state[self.slices["mocap_pos"]].reshape(-1, 3)
        d.mocap_quat[:] = state[self.slices["mocap_quat"]].reshape(-1, 4)
        mujoco.mj_kinematics(m, d)
        mujoco.mj_collision(m, d)
        if d.ncon == 0:
            return set()
        # the contact arrays at once (slicing d.contact builds a Python object per contact: ~10x slower)
        pairs = np.asarray(d.contact.geom)[:d.ncon]
        ground = self.ground_geom
        others = np.concatenate([pairs[pairs[:, 0] == ground, 1], pairs[pairs[:, 1] == ground, 0]])
        bodies = {int(b) for b in m.geom_bodyid[others[others != ground]]}
        return {-1 if body == self.root_body else self._body_link.get(body, -1) for body in bodies}

    def close(self) -> None:
        if self._runner is not None:
            self._runner.close()
            if self._single is not self._runner:
                self._single.close()
            self._runner, self._probes = None, {}


def _conjugate(q: np.ndarray) -> np.ndarray:
    return np.asarray(q, dtype=np.float64) * np.array([1.0, -1.0, -1.0, -1.0])


def _inertia_from_shapes(mujoco, mspec) -> None:
    """PyBullet's default (no URDF_USE_INERTIA_FROM_FILE): each link keeps its URDF mass and takes
    the inertia of its collision shapes; MuJoCo gets it by spreading the mass over the link's geoms
    (by volume where MuJoCo can say, else evenly) and computing inertia from them."""
    for body in mspec.bodies:
        geoms = [g for g in body.geoms]
        if not geoms or body.name == "world":
            continue
        for geom in geoms:
            geom.mass = float(body.mass) / len(geoms)
    mspec.compiler.inertiafromgeom = mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE


def _scale(mspec, s: float) -> None:
    """PyBullet's globalScaling: lengths times s, inertia times s^2, masses kept."""
    for body in mspec.bodies:
        if body.name == "world":
            continue
        body.pos = np.asarray(body.pos) * s
        body.ipos = np.asarray(body.ipos) * s
        body.inertia = np.asarray(body.inertia) * s * s
        if np.any(np.asarray(body.fullinertia)):
            body.fullinertia = np.asarray(body.fullinertia) * s * s
    for joint in mspec.joints:
        joint.pos = np.asarray(joint.pos) * s
    for geom in mspec.geoms:
        geom.pos = np.asarray(geom.pos) * s
        geom.size = np.asarray(geom.size) * s
        if np.any(np.isfinite(geom.fromto)) and np.any(np.asarray(geom.fromto)):
            geom.fromto = np.asarray(geom.fromto) * s
    for site in mspec.sites:
        site.pos = np.asarray(site.pos) * s


class MujocoWorld:
    """The :class:`~aslexp.sim.world.World` of the MuJoCo engine: one character, stepped by
    :meth:`step` through the same batched stepper as a batch of environments."""

    def __init__(self, physics, engine: EngineSpec | None = None) -> None:
        self.physics = physics
        self.engine = engine or DEFAULT_SPEC
        self.character: MujocoCharacter | None = None

    @property
    def timestep(self) -> float:
        return 1.0 / self.physics.physics_hz

    def add_ground(self) -> int:
        """The ground is compiled into a free-base body's model; its geom id."""
        if self.character is None or self.character.body.ground_geom < 0:
            raise ValueError("engine mujoco: a ground comes with a body whose base is free")
        return self.character.body.ground_geom

    def step(self, substeps: int = 1) -> None:
        if self.character is not None:
            self.character.advance(substeps)

    def close(self) -> None:
        if self.character is not None:
            self.character.body.close()


class MujocoCharacter:
    """The :class:`~aslexp.sim.world.Character` of the MuJoCo engine: one body's state, read and
    written in motion-layout terms."""

    engine = "mujoco"

    def __init__(self, world: MujocoWorld, urdf, spec: BodySpec, layout: BodyLayout, base_position=(0.0, 0.0, 0.0),
                 base_orientation_wxyz=(1.0, 0.0, 0.0, 0.0), kinematic: bool = False,
                 body: MujocoBody | None = None) -> None:
        self.world, self.spec, self.layout = world, spec, layout
        self.body = body or MujocoBody(urdf, spec, layout, world.physics, None, world.engine)
        self.base = spec.base
        self.kinematic = kinematic
        self.link_names = list(self.body.link_names)
        self.num_links = self.body.num_links
        self.end_effector_links = [self.link_names.index(n) for n in spec.end_effectors]
        self.state = self.body.new_states(1)
        self.ctrl = np.zeros((1, self.body.model.nu))
        self._bodies: np.ndarray | None = None
        self.set_base(base_position, base_orientation_wxyz)
        if not kinematic:
            world.character = self

    # -- control (the engine seam: PDController.drive) ------------------------------------------------
    def check_controller(self, controller) -> None:
        """Every controller runs on every base here (MuJoCo reads a fixed base's joints right)."""

    def drive(self, controller, targets: np.ndarray, target_velocities: np.ndarray | None, substeps: int) -> None:
        """Hold ``targets`` for ``substeps`` physics steps: an actuator holds its input, set once."""
        controller.commands_sent += 1
        if self.body.controller is not controller:
            self.body.set_gains(controller)
        targets = np.asarray(targets, dtype=np.float64)
        self.ctrl = self.body.controls(targets[None], None if target_velocities is None else target_velocities[None])
        self.advance(substeps)

    def advance(self, substeps: int) -> None:
        self.body.step(self.state, self.ctrl, substeps)
        self._bodies = None
        self.peak_speed = float(self.body.peak_speeds[0])
        self.peak_joint = self.body.dof_name(self.body.peak_dofs[0])

    peak_speed = 0.0  # the fastest joint of the last advance(), before the joint-speed clamp
    peak_joint = ""  # and its name

    # -- state -------------------------------------------------------------------------------------------
    def _sensors(self) -> np.ndarray:
        if self._bodies is None:
            self._bodies = self.body.read(self.state)
        return self._bodies

    def set_base(self, position, orientation_wxyz, linear_velocity=(0.0, 0.0, 0.0),
                 angular_velocity=(0.0, 0.0, 0.0)) -> None:
        """Teleport the root (a fixed or pinned root only moves: no velocity)."""
        free = self.base == "free"
        self.body.write_root(self.state, slice(None), np.asarray(position, dtype=np.float64),
                             np.asarray(orientation_wxyz, dtype=np.float64),
                             np.asarray(linear_velocity, dtype=np.float64) if free else None,
                             np.asarray(angular_velocity, dtype=np.float64) if free else None)
        self._bodies = None

    def set_state(self, q: np.ndarray, qd: np.ndarray | None = None) -> None:
        self.body.write_joints(self.state, slice(None), q, qd)
        self._bodies = None

    def joint_state(self) -> tuple[np.ndarray, np.ndarray]:
        q, qd = self.body.joints(self.state)
        return q[0].copy(), qd[0].copy()

    def base_state(self):
        root = self.body.frames(self._sensors())[0, 0]
        return root[0:3].copy(), root[3:7].copy(), root[7:10].copy(), root[10:13].copy()

    def link_states(self, velocities: bool = True, links: list[int] | None = None) -> np.ndarray:
        out = self.body.frames(self._sensors())[0, 1:].copy()
        if not velocities:
            out[:, 7:13] = 0.0
        return out

    def end_effector_positions(self, links: np.ndarray | None = None) -> np.ndarray:
        if self.kinematic and self._bodies is None:  # the reference's question: its tips alone
            return self.body.tips(self.body.read(self.state, tips_only=True))[0].copy()
        return self.body.tips(self._sensors())[0].copy()

    def ground_contacts(self, ground: int) -> set[int]:
        return self.body.contacts(self.state[0])



@register_engine("mujoco", options=MujocoOptions, batched=True,
                 summary="MuJoCo: the same URDFs; many environments per process (envs.batched)",
                 divergence_hint="a stable-PD controller (physical gains) or engine=pybullet, whose motors "
                                 "the MuJoCo stand-in only approximates")
def build(spec: EngineSpec, request: SimulationRequest, body_class: type[MujocoBody] = MujocoBody) -> Simulation:
    """One environment: the simulated character and its kinematic reference share one compiled
    model (the reference is posed, never stepped); images are drawn by PyBullet's TinyRenderer
    from the poses (MuJoCo's renderer needs OpenGL). ``body_class``: the body that steps them
    (another engine's subclass of :class:`MujocoBody`, e.g. the MJX engine's)."""
    world = MujocoWorld(request.physics, spec)
    body = body_class(request.urdf, request.body, request.layout, request.physics, None, spec)
    sim = MujocoCharacter(world, request.urdf, request.body, request.layout, request.root_position,
                          request.root_rotation, body=body)
    ref = MujocoCharacter(world, request.urdf, request.body, request.layout, request.root_position,
                          request.root_rotation, kinematic=True, body=sim.body)
    ground = world.add_ground() if request.body.base == "free" else None
    views: list = []

    def render(camera: dict[str, float], size: tuple[int, int]) -> np.ndarray:
        if not views:
            from aslexp.sim.world import PoseRenderer

            views.append(PoseRenderer(request.urdf, request.body, request.layout, request.physics))
        return views[0].draw((ref, sim), camera, size)

    def close() -> None:
        world.close()
        for view in views:
            view.close()

    return Simulation(sim=sim, ref=ref, ground=ground, batch=sim.body, render_fn=render, close_fn=close)
