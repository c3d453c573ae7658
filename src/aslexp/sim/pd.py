"""PD control: gains per joint group; each engine's character applies them (PyBullet: its motors,
``aslexp.sim.world.Character.drive``; MuJoCo: PD actuators, ``aslexp.sim.mujoco_engine``).

Two modes (``mode`` in ``conf/controller/*.yaml``):
* ``position``: PyBullet's POSITION_CONTROL motor, a PD controller solved as a velocity
  constraint, ``kp * (q* - q) + kd * (qd* - qd)`` limited by ``max_force``; its gains are
  dimensionless (the thesis' hand: kp 0.22, kd 0.87). The motor persists across physics steps.
* ``stable_pd``: PyBullet's STABLE_PD_CONTROL (Tan et al.'s stable PD: torques from physical
  gains, N m/rad and N m s/rad, computed implicitly over the next step), the upper-body controller
  of the authors' code (THESIS.md 10.1; the thesis text's for the body joints only). Two PyBullet
  3.2.7 facts shape it: the command is cleared after every physics step,
  so the PyBullet character re-sends it before each substep (sent once per 30 Hz control step
  the joints would be driven 1 substep in 8); and on a fixed-base body the server reads each
  joint's state 7 slots off, so the body must be loaded with a free base, pinned or standing
  (``body.base: pinned | free``; a fixed base is refused).

A joint group may carry its own ``mode`` (``groups: {fingers: {kp: 0.22, kd: 0.87, mode: position}}``;
absent or null: the controller's ``mode``): the thesis' upper body drives its body joints with stable
PD and its hands with the chapter-5 hand's position motor (conf/controller/upper_body_thesis.yaml).
:meth:`aslexp.sim.world.Character.apply_pd` then sends one PyBullet motor call per mode with that mode's joints; the
stable-PD rules above (re-sent every substep, no fixed base) hold as soon as one joint is stable PD.

Two agent-side options shape the targets the environment gives the motors (defaults: the thesis
controller): ``target_velocity: reference`` feeds the reference joint velocity (times
``velocity_scale``) as the motor's velocity target instead of 0, and ``target_rate: physics``
re-samples the reference part of the targets at every physics substep instead of holding one
target for the whole control step (the policy's correction is held). Neither touches the reward
or the reference motion.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from aslexp.sim.body import BodyLayout

MODES = ("position", "stable_pd")
TARGET_VELOCITIES = ("zero", "reference")
TARGET_RATES = ("control", "physics")


GAIN_KEYS = ("kp", "kd", "max_force", "mode")


@dataclass(frozen=True)
class Gains:
    kp: float
    kd: float
    max_force: float = 100.0
    mode: str | None = None  # position | stable_pd; None: the controller's mode

    @classmethod
    def from_dict(cls, values: dict[str, Any], where: str, allow_mode: bool = True) -> "Gains":
        if not isinstance(values, dict):
            raise ValueError(f"controller config: {where} must be a mapping of {GAIN_KEYS}, got {values!r}")
        keys = GAIN_KEYS if allow_mode else GAIN_KEYS[:3]
        unknown = set(values) - set(keys)
        if unknown:
            extra = " (mujoco_groups are physical gains: no mode)" if "mode" in unknown and not allow_mode else ""
            raise ValueError(f"controller config: {where}: unknown keys {sorted(unknown)}{extra}")
        missing = {"kp", "kd"} - set(values)
        if missing:
            raise ValueError(f"controller config: {where}: missing {sorted(missing)}")
        mode = values.get("mode")
        if mode is not None and mode not in MODES:
            raise ValueError(f"controller config: {where}: mode must be one of {MODES} or null, got {mode!r}")
        return cls(kp=float(values["kp"]), kd=float(values["kd"]),
                   max_force=float(values.get("max_force", 100.0)), mode=mode)


@dataclass(frozen=True)
class ControllerSpec:
    """``conf/controller/*.yaml``: a mode and gains per joint group (``default`` fills the rest)."""

    name: str
    mode: str
    groups: dict[str, Gains]
    target_velocity: str = "zero"  # zero (thesis) | reference: reference joint velocity as target
    velocity_scale: float = 1.0  # multiplies the reference velocity target
    target_rate: str = "control"  # control (thesis) | physics: reference re-sampled every substep
    # engine=mujoco: physical gains (N m/rad, N m s/rad) replacing `groups` there (None: `groups`,
    # physical for stable_pd, translated from PyBullet's motor for position: sim/mujoco_engine.py)
    mujoco_groups: dict[str, Gains] | None = None

    def mode_of(self, gains: Gains) -> str:
        """The mode a group's gains are applied with: its own ``mode``, else the controller's."""
        return gains.mode or self.mode

    @property
    def is_thesis_pd(self) -> bool:
        """True when the targets are the thesis' (held positions, zero velocity)."""
        return self.target_velocity == "zero" and self.target_rate == "control"

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "ControllerSpec":
        unknown = set(values) - {"name", "mode", "groups", "target_velocity", "velocity_scale", "target_rate",
                                 "mujoco_groups"}
        if unknown:
            raise ValueError(f"controller config: unknown keys {sorted(unknown)}")
        mode = values.get("mode", "position")
        if mode not in MODES:
            raise ValueError(f"controller config: mode must be one of {MODES}, got {mode!r}")
        groups = {name: Gains.from_dict(gains, f"groups.{name}")
                  for name, gains in (values.get("groups") or {}).items()}
        if not groups:
            raise ValueError("controller config: `groups` must give gains for at least `default`")
        target_velocity = values.get("target_velocity", "zero")
        if target_velocity not in TARGET_VELOCITIES:
            raise ValueError(f"controller config: target_velocity must be one of {TARGET_VELOCITIES}, "
                             f"got {target_velocity!r}")
        target_rate = values.get("target_rate", "control")
        if target_rate not in TARGET_RATES:
            raise ValueError(f"controller config: target_rate must be one of {TARGET_RATES}, got {target_rate!r}")
        mujoco_groups = values.get("mujoco_groups")
        if mujoco_groups is not None:
            mujoco_groups = {name: Gains.from_dict(gains, f"mujoco_groups.{name}", allow_mode=False)
                             for name, gains in mujoco_groups.items()}
        return cls(name=values.get("name", "custom"), mode=mode, groups=groups, target_velocity=target_velocity,
                   velocity_scale=float(values.get("velocity_scale", 1.0)), target_rate=target_rate,
                   mujoco_groups=mujoco_groups or None)


class PDController:
    """Per-joint gains expanded from the groups; :meth:`apply` sets the motors for the next steps."""

    def __init__(self, spec: ControllerSpec, layout: BodyLayout) -> None:
        self.spec = spec
        self.layout = layout
        per_joint = []
        for joint in layout.joints:
            gains = spec.groups.get(joint.group, spec.groups.get("default"))
            if gains is None:
                raise ValueError(
                    f"controller {spec.name}: no gains for joint group {joint.group!r} and no `default`"
                )
            per_joint.append(gains)
        self.kp = [g.kp for g in per_joint]
        self.kd = [g.kd for g in per_joint]
        self.max_force = [g.max_force for g in per_joint]
        self.modes = [spec.mode_of(g) for g in per_joint]  # per joint: position | stable_pd
        # Per mode, in layout order: the joints (layout positions) and where each one's target and
        # target velocity start in the motion-layout vectors.
        self.by_mode: dict[str, list[int]] = {}
        for k, mode in enumerate(self.modes):
            self.by_mode.setdefault(mode, []).append(k)
        self.offsets, self.voffsets = [], []
        offset = voffset = 0
        for joint in layout.joints:
            self.offsets.append(offset)
            self.voffsets.append(voffset)
            offset += joint.dof
            voffset += 1 if joint.dof == 1 else 3
        self.commands_sent = 0  # motor commands given (PyBullet: one per substep under stable PD; a test counts them)
        self.motor_calls = {mode: 0 for mode in MODES}  # PyBullet motor calls per mode

    @property
    def resend_every_substep(self) -> bool:
        """True when a joint is stable PD, whose command PyBullet clears after each physics step."""
        return "stable_pd" in self.by_mode

    def check_body(self, character) -> None:
        """Refuse a body this controller cannot drive on the character's engine (PyBullet: stable
        PD on a fixed base)."""
        character.check_controller(self)

    def drive(self, character, targets: np.ndarray, target_velocities: np.ndarray | None, substeps: int) -> None:
        """Hold ``targets`` (motion-layout joint vector) for ``substeps`` physics steps: the engine's
        character applies this controller's gains (:class:`aslexp.sim.engine.EngineCharacter`)."""
        character.drive(self, np.asarray(targets, dtype=np.float64), target_velocities, substeps)
