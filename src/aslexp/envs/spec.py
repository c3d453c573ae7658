"""``conf/env/*.yaml`` as plain values: the environment's rates, episode, action, observation and
termination settings (read by :class:`aslexp.envs.imitation.ImitationEnv`, assembled by
:mod:`aslexp.envs.assembly`)."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aslexp.config_schema import Choice, Float, Section, key
from aslexp.errors import ConfigError
from aslexp.sim.engine import DEFAULT_CAMERA

OBSERVATIONS = ("aslexp", "deepmimic")
# Env keys that shape the training reward alone (ImitationEnv shape_reward): no score depends on them.
TRAINING_ONLY_KEYS = ("heading_shaping", "offset_shaping")
# Env keys that move the base a residual policy corrects: the no-learning baselines ("the controller"
# = the reference one step ahead) are defined without them, so a variant cannot move its own bar.
RESIDUAL_BASE_KEYS = ("residual_base_smoothing", "residual_base_smoothing_groups")
UP_AXIS = 1  # the motions and worlds are y-up (gravity -9.8 y)
CONTROL_HZ = Float(1, 10_000)
PHYSICS_HZ = Float(1, 100_000)


@dataclass(frozen=True)
class EnvSpec(Section):
    """``conf/env/*.yaml`` as plain values."""

    SECTION = "env"

    # Hz, bounded so that a slip fails at once (control_hz=0.001 asked for 240 000 physics steps per
    # action and ran silently for minutes); the physics rate is a whole multiple of the control rate.
    physics_hz: float = field(default=240.0, metadata=key(PHYSICS_HZ))
    control_hz: float = field(default=30.0, metadata=key(CONTROL_HZ))
    gravity: tuple[float, float, float] = (0.0, -9.8, 0.0)
    solver_iterations: int = 10
    non_contact_inner_iterations: int = 1
    episode_steps: int = 300
    reference_state_init: bool = True
    early_termination: dict[str, Any] = field(default_factory=lambda: {"min_reward": None})
    # rad/s: a joint faster than this (or any non-finite state) is a simulation that blew up. Far
    # above the 100 rad/s both engines clamp every joint speed to (engine.joint_speed_limit): a
    # transient the clamp absorbs is physics, not divergence.
    max_joint_velocity: float = 1000.0
    action_mode: str = field(default="absolute", metadata=key(Choice("absolute", "residual")))
    residual_range: float = 0.5
    reference_lookahead: int = 1
    observe_future: tuple[int, ...] = ()
    # How the reference frames at observe_future are seen: as the reference's joint positions
    # (reference), or as each one minus the body's joint positions now (error: the tracking error a
    # feedback correction acts on, the same quantity whichever motion is followed).
    observe_future_as: str = field(default="reference", metadata=key(Choice("reference", "error")))
    # The motion's phase (time over its length) first in the observation; across a pool of motions of
    # different lengths it says more about which motion is followed than about what to do.
    observe_phase: bool = True
    observe_joints: bool = False
    observe_future_velocities: bool = False  # also the reference joint velocities at observe_future
    # The reference's root now, in the frame the links are seen in (position relative to the
    # simulated root, rotation): 7 values that show how far the body has drifted or turned, which
    # the heading frame of the deepmimic observation hides (it removes the yaw).
    observe_reference_root: bool = False
    # Training only: with ImitationEnv(..., shape_reward=True), as aslexp.jobs.imitate builds its
    # training envs, the reward PPO learns from is the step reward times
    # exp(-heading_shaping * yaw^2 - offset_shaping * |d|^2): yaw the turn (rad) of the simulated
    # root against the reference's about the up axis, d its horizontal offset (m). Slipping feet turn
    # and shift the body over seconds, past a 30 Hz policy's horizon; this charges the drift at every
    # step. Every score (evaluations, baselines, reports) stays the reward config's alone. 0: off.
    heading_shaping: float = field(default=0.0, metadata=key(Float(0)))
    offset_shaping: float = field(default=0.0, metadata=key(Float(0)))
    residual_velocity_range: float = 0.0  # rad/s; > 0 appends velocity-target corrections to the action
    # Residual only: the base the correction is added to, low-pass filtered,
    # base_t = alpha * base_(t-1) + (1 - alpha) * reference_(t + lookahead), on the joints of
    # residual_base_smoothing_groups (None: all); restarted every episode. 0: the reference itself.
    # With alpha > 0 a zero correction is the smoothed-reference baseline (aslexp.rl.evaluate), the
    # strongest no-learning one on the standing upper body: gentler targets, less slip.
    residual_base_smoothing: float = field(default=0.0, metadata=key(Float(0, 1, high_open=True)))
    residual_base_smoothing_groups: tuple[str, ...] | None = None
    # Residual only: the joint groups (conf/body joint_groups) the policy corrects and observes (the
    # reference frames ahead and the joint state of observe_future / observe_joints); the other joints
    # follow the residual base, the controller alone, and are not seen. None: every joint.
    policy_groups: tuple[str, ...] | None = None
    # The policy's action is [-1, 1] per value, mapped affinely onto the box above (absolute: each
    # joint's range, e.g. [-1, 1] -> [0, 2] rad; residual: +-residual_range, +-residual_velocity_range).
    normalize_actions: bool = False
    # The box of absolute targets: each joint's range (joint), or the range the reference motion
    # visits widened by action_range_margin rad on each side, within the joint range (motion).
    action_range: str = field(default="joint", metadata=key(Choice("joint", "motion")))
    action_range_margin: float = 0.25
    # Links in the observation (fnmatch patterns on link names, URDF order); None: every link;
    # []: none (the observation is then the phase and the observe_* options alone).
    observe_links: tuple[str, ...] | None = None
    camera: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_CAMERA))
    # aslexp (root frame, per link 13 values) | deepmimic (the authors')
    observation: str = field(default="aslexp", metadata=key(Choice(*OBSERVATIONS)))

    def __post_init__(self) -> None:
        unknown_end = set(self.early_termination or {}) - {"min_reward", "fall", "patience"}
        if unknown_end:
            raise ConfigError(f"early_termination: unknown keys {sorted(unknown_end)}; expected min_reward, "
                              f"patience, fall")
        patience = (self.early_termination or {}).get("patience", 1)
        if patience is None or isinstance(patience, bool) or int(patience) != patience or patience < 1:
            raise ConfigError(f"early_termination.patience={patience}: expected an integer >= 1 (control steps "
                              f"below min_reward before the end)")
        for name in TRAINING_ONLY_KEYS:
            if not np.isfinite(getattr(self, name)):
                raise ConfigError(f"{name}={getattr(self, name)}: expected a finite number >= 0")
        alpha = self.residual_base_smoothing
        if alpha > 0 and self.action_mode != "residual":
            raise ConfigError(f"residual_base_smoothing={alpha}: needs action_mode residual (it filters the base "
                              f"a correction is added to), got {self.action_mode!r}")
        if self.policy_groups is not None and (self.action_mode != "residual" or self.residual_velocity_range > 0):
            raise ConfigError(f"policy_groups={list(self.policy_groups)}: needs action_mode residual without "
                              f"residual_velocity_range (the other joints follow the residual base), got "
                              f"{self.action_mode!r}, residual_velocity_range {self.residual_velocity_range:g}")
        if self.action_range == "motion" and (self.action_mode != "absolute" or self.action_range_margin < 0):
            raise ConfigError(f"action_range=motion: needs action_mode absolute and action_range_margin >= 0, "
                              f"got {self.action_mode!r}, {self.action_range_margin}")
        ratio = self.physics_hz / self.control_hz
        if abs(ratio - round(ratio)) > 1e-6 or ratio < 1:
            raise ConfigError(f"physics_hz={self.physics_hz:g}: expected a whole multiple of control_hz "
                              f"({self.control_hz:g}): 1x, 2x, ...")

    @property
    def reads_joints(self) -> bool:
        """Whether the observation needs the joint positions and velocities."""
        return self.observe_joints or (self.observe_future_as == "error" and bool(self.observe_future))

    @property
    def substeps(self) -> int:
        return int(round(self.physics_hz / self.control_hz))
