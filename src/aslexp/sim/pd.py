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

from dataclasses import dataclass, field

import numpy as np

from aslexp.config_schema import GAIN, MAX_FORCE, Choice, Float, Section, key
from aslexp.errors import ConfigError
from aslexp.sim.body import BodyLayout

MODES = ("position", "stable_pd")
TARGET_VELOCITIES = ("zero", "reference")
TARGET_RATES = ("control", "physics")


@dataclass(frozen=True)
class Gains(Section):
    SECTION = "gains"

    kp: float = field(metadata=key(GAIN))
    kd: float = field(metadata=key(GAIN))
    max_force: float = field(default=100.0, metadata=key(MAX_FORCE))
    mode: str | None = field(default=None, metadata=key(Choice(*MODES, nullable=True)))  # None: the controller's


@dataclass(frozen=True)
class ControllerSpec(Section):
    """``conf/controller/*.yaml``: a mode and gains per joint group (``default`` fills the rest)."""

    SECTION = "controller"

    name: str = "custom"
    mode: str = field(default="position", metadata=key(Choice(*MODES)))
    groups: dict[str, Gains] = field(default_factory=dict)
    # zero (thesis) | reference: reference joint velocity as target
    target_velocity: str = field(default="zero", metadata=key(Choice(*TARGET_VELOCITIES)))
    velocity_scale: float = field(default=1.0, metadata=key(Float(finite=True)))  # multiplies the reference velocity target
    # control (thesis) | physics: reference re-sampled every substep
    target_rate: str = field(default="control", metadata=key(Choice(*TARGET_RATES)))
    # Physical gains (N m/rad, N m s/rad) in place of `groups` for an engine whose actuators take
    # them (MuJoCo's; PyBullet ignores them). None: `groups`, physical for stable_pd, translated
    # from PyBullet's motor for position (sim/mujoco_engine.py).
    physical_groups: dict[str, Gains] | None = None

    def __post_init__(self) -> None:
        if not self.groups:
            raise ConfigError("groups: must give gains for at least `default`")
        moded = [name for name, gains in (self.physical_groups or {}).items() if gains.mode is not None]
        if moded:
            raise ConfigError(f"physical_groups.{moded[0]}.mode: physical_groups are physical gains: no mode")
        if self.physical_groups == {}:
            object.__setattr__(self, "physical_groups", None)

    def mode_of(self, gains: Gains) -> str:
        """The mode a group's gains are applied with: its own ``mode``, else the controller's."""
        return gains.mode or self.mode

    @property
    def is_thesis_pd(self) -> bool:
        """True when the targets are the thesis' (held positions, zero velocity)."""
        return self.target_velocity == "zero" and self.target_rate == "control"


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
