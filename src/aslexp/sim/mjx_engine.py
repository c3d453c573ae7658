"""The MJX engine: the CPU MuJoCo engine's bodies stepped as one JAX batch, on the learner's device.

``engine=mjx`` (``conf/engine/mjx.yaml``) builds exactly the model :class:`~aslexp.sim.mujoco_engine.MujocoBody`
builds (same URDF reader, links, root, self-collision exclusions, PD actuators and gains: it *is* a
``MujocoBody``) and steps it with MJX (``mujoco.mjx``, MuJoCo in JAX): ``jax.vmap`` of ``mjx.step``
under ``jax.jit``, the physics substeps a ``lax.scan``, PyBullet's joint-speed clamp inside the scan
as the CPU engine applies it (after each physics step every generalised velocity clipped to
+-``joint_speed_limit`` and that step's positions integrated from its start with the clipped
velocity). The state vector is the CPU engine's (``mjSTATE_FULLPHYSICS``, then the mocap poses), so
:class:`~aslexp.envs.batched.BatchedImitationEnv` and the single environment run on it unchanged,
their arrays coming back to numpy.

The device-resident path (for a learner on a GPU, no host copy between physics and learner):
:meth:`MjxBody.device_states`, :meth:`MjxBody.device_step` and :meth:`MjxBody.device_read` take and
give JAX arrays on the engine's device; :func:`to_torch` and :func:`from_torch` hand them to torch
and back through DLPack (zero-copy on the same device).

What differs from the CPU engine (docs/engines.md, "MJX"):

* single precision (JAX's default; MuJoCo's C engine computes in double);
* the solver: Newton or CG only (no PGS), the same iterations; MJX's line search is its own;
* collisions: MJX computes every candidate geom pair's contacts at every step, 8 per box-box pair;
  the hand's self-collision (16 boxes, 45 pairs) is 360 candidate contacts, 1,440 constraint rows.
  ``max_geom_pairs`` (8) keeps the nearest pairs of each kind (by bounding sphere; planes keep all),
  ``max_contact_points`` (32) the deepest contacts of each contact dimension: the runtime, memory (a
  batch of 64k upper bodies with every candidate contact would not fit a GPU) and compile-time knob,
  at the cost of contacts beyond them (tracking the reference, the CPU engine finds none on the hand
  and the pinned upper body, 8 on the standing one's feet);
* ground contacts for a fall (:meth:`contacts`) are read by the CPU engine's collision on the same
  state (exact, one state at a time, as the CPU engine does).
"""

from __future__ import annotations

import contextlib
import functools
import io
import logging
from dataclasses import dataclass, field

import numpy as np

from aslexp.config_schema import Choice, Int, Positive, Section, key
from aslexp.sim.engine import EngineSpec, Simulation, SimulationRequest, register_engine
from aslexp.sim.mujoco_engine import MujocoBody, build as build_mujoco

log = logging.getLogger("aslexp.mjx")

INTEGRATORS = ("Euler", "implicitfast", "RK4")  # MJX has no `implicit`
SOLVERS = ("Newton", "CG")  # MJX has no PGS


def _jax():
    """jax and mujoco.mjx, imported on first use (an optional extra: pip install -e .[mjx])."""
    try:
        import jax
        # MJX prints a line to stdout when its optional Warp backend is missing: not ours to show
        with contextlib.redirect_stdout(io.StringIO()):
            from mujoco import mjx
    except ImportError as exc:
        raise ImportError(f"engine=mjx needs jax and mujoco-mjx (pip install -e '.[mjx]'): {exc}") from exc
    return jax, mjx


@dataclass(frozen=True)
class MjxOptions(Section):
    """MJX's own keys of ``conf/engine/mjx.yaml`` (the first five as the CPU engine's)."""

    SECTION = "engine"

    integrator: str = field(default="implicitfast", metadata=key(Choice(*INTEGRATORS)))
    solver: str = field(default="Newton", metadata=key(Choice(*SOLVERS)))
    iterations: int = field(default=50, metadata=key(Int(1)))
    ls_iterations: int = field(default=50, metadata=key(Int(1)))  # the solver's line search (MuJoCo's default)
    motor_gain_scale: float = field(default=2.0, metadata=key(Positive()))
    joint_speed_limit: float | None = field(default=100.0, metadata=key(Positive(nullable=True)))  # rad/s
    # MJX's collision limits (module docstring, conf/engine/mjx.yaml); null: every candidate pair, every contact
    max_geom_pairs: int | None = field(default=8, metadata=key(Int(1, nullable=True)))
    max_contact_points: int | None = field(default=32, metadata=key(Int(1, nullable=True)))
    # the JAX platform that steps the batch (null: JAX's default, a GPU when jax has one)
    device: str | None = field(default=None, metadata=key(Choice("cpu", "gpu", "cuda", nullable=True)))
    # MuJoCo's C threads: only the CPU parts (ground contacts, the gains' inertia); unused by MJX
    threads: int = field(default=0, metadata=key(Int(0)))


def _bucket(n: int) -> int:
    """Batch sizes are padded to a power of two: each size is one XLA compilation."""
    return 1 if n <= 1 else 1 << (int(n) - 1).bit_length()


class MjxBody(MujocoBody):
    """A :class:`MujocoBody` whose batches MJX steps and reads (the :class:`~aslexp.sim.engine.BatchedBody`
    interface, numpy in and out), with a device-resident path beside it (module docstring)."""

    def __init__(self, urdf, spec, layout, physics, controller=None, engine: EngineSpec | None = None) -> None:
        self._device_model = None
        super().__init__(urdf, spec, layout, physics, controller, engine)
        self.jax, self.mjx = _jax()
        extra = [name for name in ("act", "history", "plugin", "plastic")
                 if name in self.slices and self.slices[name].stop > self.slices[name].start]
        if extra:
            raise ValueError(f"engine mjx: body {spec.name} has {extra[0]} state, which the MJX engine does not carry")
        backend = self.engine.options.device
        self.device = self.jax.devices("gpu" if backend == "cuda" else backend)[0] if backend else self.jax.devices()[0]
        s = self.slices
        # where MJX's fields sit in a state row, as (start, stop) pairs (hashable: the jitted functions' key)
        # then the mocap root's body (None: a free base)
        self._layout = (*((s[name].start, s[name].stop) for name in ("time", "qpos", "qvel", "mocap_pos", "mocap_quat")),
                        None if self.root_free_qpos is not None else int(self.root_body))
        self._frame_bodies = np.asarray([self.root_body, *self.link_bodies])
        self._pad = self.new_states(1)[0]

    def _extend_spec(self, mspec) -> None:
        options = self.engine.options
        mspec.option.ls_iterations = int(options.ls_iterations)
        for name in ("max_geom_pairs", "max_contact_points"):  # MJX reads them as custom numerics
            if getattr(options, name) is not None:
                mspec.add_numeric(name=name, data=[float(getattr(options, name))])

    # -- the model on the device -------------------------------------------------------------------
    def set_gains(self, controller) -> None:
        super().set_gains(controller)
        self._device_model = None  # the gains are in the model: put it again before the next step

    @property
    def device_model(self):
        """The MJX model (and a template of its data) on the engine's device, with the current gains."""
        if self._device_model is None:
            model = self.mjx.put_model(self.model, device=self.device)
            self._device_model = (model, self.mjx.make_data(model, device=self.device))
        return self._device_model

    # -- the device-resident path ------------------------------------------------------------------
    def device_states(self, states: np.ndarray):
        """(N, state) states as a float32 JAX array on the engine's device."""
        return self.jax.device_put(np.asarray(states, dtype=np.float32), self.device)

    def device_step(self, states, ctrl, nstep: int):
        """``nstep`` physics steps of (N, state) JAX ``states`` under held (N, nu) controls, on the
        device. Returns the new states, each row's fastest joint before the clamp (N,), the degree of
        freedom it was (N,) and the physics steps where the clamp acted (N,)."""
        model, template = self.device_model
        limit = self.engine.options.joint_speed_limit
        fn = _stepper(self.mjx, self._layout, int(nstep), None if limit is None else float(limit))
        return fn(model, template, states, self.jax.numpy.asarray(ctrl, dtype=states.dtype))

    def device_read(self, states, tips_only: bool = False):
        """(N, sensors) of :meth:`read` for JAX ``states``, on the device."""
        model, template = self.device_model
        fn = _reader(self.mjx, self._layout, tuple(int(b) for b in self._frame_bodies), bool(tips_only))
        return fn(model, template, states)

    # -- the BatchedBody interface (numpy) ---------------------------------------------------------
    def _padded(self, states: np.ndarray, *more: np.ndarray):
        n = len(states)
        size = _bucket(n)
        if size == n:
            return n, (states, *more)
        pad = [np.concatenate([states, np.broadcast_to(self._pad, (size - n, len(self._pad)))])]
        pad += [np.concatenate([m, np.zeros((size - n, m.shape[1]))]) for m in more]
        return n, tuple(pad)

    def step(self, states: np.ndarray, ctrl: np.ndarray, nstep: int) -> np.ndarray:
        """Advance (N, state) ``states`` by ``nstep`` physics steps under held controls (N, nu), in
        place (MJX on the engine's device, back to numpy); returns ``states``."""
        n, (padded, control) = self._padded(np.asarray(states), np.asarray(ctrl, dtype=np.float64))
        if n == 0:
            self.peak_speeds, self.peak_dofs = np.zeros(0), np.zeros(0, dtype=int)
            return states
        new, peak, dof, clamped = self.device_step(self.device_states(padded), control, nstep)
        states[:, :self.physics_size] = np.asarray(new, dtype=np.float64)[:n, :self.physics_size]
        self.peak_speeds = np.asarray(peak, dtype=np.float64)[:n]
        self.peak_dofs = np.asarray(dof, dtype=int)[:n]
        self.clamped_steps += int(np.asarray(clamped)[:n].sum())
        return states

    def read(self, states: np.ndarray, tips_only: bool = False) -> np.ndarray:
        """(N, sensors) as :meth:`MujocoBody.read` gives them (tips, then 13 values per frame),
        computed by MJX's kinematics and velocities."""
        n, (padded,) = self._padded(np.asarray(states))
        if n == 0:
            return np.zeros((0, self._tip_values if tips_only else self._tip_values + 13 * (1 + self.num_links)))
        return np.asarray(self.device_read(self.device_states(padded), tips_only), dtype=np.float64)[:n]


def to_torch(array):
    """A JAX array as a torch tensor on the same device, through DLPack (no copy)."""
    import torch

    return torch.from_dlpack(array)


def from_torch(tensor):
    """A torch tensor as a JAX array on the same device, through DLPack (no copy)."""
    jax, _ = _jax()
    return jax.dlpack.from_dlpack(tensor.contiguous())


def _data(model, template, layout, row):
    """One state row (aslexp's layout) as MJX model and data. A fixed or pinned root is a mocap
    body, which MJX's kinematics places after the tree (its children would stay at the model's
    pose): the row's model takes the root's pose as the root body's own, so the tree follows."""
    import jax.numpy as jnp

    time, qpos, qvel, mocap_pos, mocap_quat = (slice(*pair) for pair in layout[:5])
    root = layout[5]
    position, rotation = row[mocap_pos].reshape(-1, 3), row[mocap_quat].reshape(-1, 4)
    if root is not None:
        quat = rotation[0] / jnp.linalg.norm(rotation[0])
        model = model.replace(body_pos=jnp.asarray(model.body_pos).at[root].set(position[0]),
                              body_quat=jnp.asarray(model.body_quat).at[root].set(quat))
    return model, template.replace(time=row[time.start], qpos=row[qpos], qvel=row[qvel], mocap_pos=position,
                                   mocap_quat=rotation)


@functools.lru_cache(maxsize=None)
def _stepper(mjx, layout, nstep: int, limit: float | None):
    """The jitted batch step (one per substep count and clamp; XLA compiles one per batch size)."""
    import jax
    import jax.numpy as jnp
    from mujoco.mjx._src.forward import _integrate_pos  # the integrator's own position update

    time, qpos, qvel = (slice(*pair) for pair in layout[:3])

    def one(model, template, row, ctrl):
        model, data = _data(model, template, layout, row)
        data = data.replace(ctrl=ctrl)

        def substep(carry, _):
            data, peak, clamped = carry
            start = data.qpos
            data = mjx.step(model, data)
            speed = jnp.abs(data.qvel)
            peak = jnp.where(jnp.isnan(speed) | (speed > peak), speed, peak)  # a NaN is kept
            if limit is not None:  # PyBullet's clamp (module docstring)
                over = jnp.any(speed > limit)
                clipped = jnp.clip(data.qvel, -limit, limit)
                position = _integrate_pos(model.jnt_type, start, clipped, model.opt.timestep)
                data = data.replace(qpos=jnp.where(over, position, data.qpos), qvel=jnp.where(over, clipped, data.qvel))
                clamped = clamped + over.astype(jnp.int32)
            return (data, peak, clamped), None

        init = (data, jnp.zeros_like(data.qvel), jnp.zeros((), jnp.int32))
        (data, peak, clamped), _ = jax.lax.scan(substep, init, None, length=nstep)
        out = row.at[time.start].set(data.time).at[qpos].set(data.qpos).at[qvel].set(data.qvel)
        fastest = jnp.where(jnp.isnan(peak), jnp.inf, peak)
        top = jnp.argmax(fastest) if peak.shape[0] else jnp.zeros((), jnp.int32)
        speed = peak[top] if peak.shape[0] else jnp.zeros((), peak.dtype)
        return out, speed, top, clamped

    return jax.jit(jax.vmap(one, in_axes=(None, None, 0, 0)))


@functools.lru_cache(maxsize=None)
def _reader(mjx, layout, frame_bodies: tuple[int, ...], tips_only: bool):
    """The jitted batch read: the sensors of the CPU engine's probes, from MJX's kinematics."""
    import jax
    import jax.numpy as jnp

    bodies = np.asarray(frame_bodies)

    def one(model, template, row):
        model, data = _data(model, template, layout, row)
        data = mjx.kinematics(model, data)
        tips = data.site_xpos.reshape(-1)
        if tips_only:
            return tips
        data = mjx.com_vel(model, mjx.com_pos(model, data))
        # MuJoCo's frame velocity of a body (mj_objectVelocity, world frame): cvel is about the
        # subtree's centre of mass of the body's root; shifted to the body's origin
        angular, linear = data.cvel[bodies, :3], data.cvel[bodies, 3:]
        offset = data.xpos[bodies] - data.subtree_com[model.body_rootid[bodies]]
        linear = linear - jnp.cross(offset, angular)
        frames = jnp.concatenate([data.xpos[bodies], data.xquat[bodies], linear, angular], axis=1)
        return jnp.concatenate([tips, frames.reshape(-1)])

    return jax.jit(jax.vmap(one, in_axes=(None, None, 0)))


@register_engine("mjx", options=MjxOptions, batched=True,
                 summary="MJX (MuJoCo in JAX): the MuJoCo engine's bodies as one JAX batch, on a GPU where jax has one",
                 divergence_hint="a stable-PD controller (physical gains), engine=mujoco or engine=pybullet")
def build(spec: EngineSpec, request: SimulationRequest) -> Simulation:
    """The CPU MuJoCo engine's simulation (its characters, reference, renderer) with an MJX body."""
    return build_mujoco(spec, request, body_class=MjxBody)
