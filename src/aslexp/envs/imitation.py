"""The imitation environment: a body tracks a reference motion under PD control (gymnasium).

One control step (``1 / control_hz`` seconds):
  1. the action becomes PD targets: absolute joint positions, or (``action_mode: residual``)
     corrections added to the reference ``reference_lookahead`` control steps ahead (or, with
     the controller's ``target_rate: physics``, to the reference at the end of each physics
     substep; ``target_velocity: reference`` adds the reference velocity as velocity target);
  2. the world steps ``physics_hz / control_hz`` times;
  3. the reward compares the simulated character with the reference at the new time;
  4. the observation (``observation: aslexp``): phase, then each link's position, orientation,
     linear and angular velocity in the root frame, then (``observe_future``) upcoming reference
     joint positions (and, with ``observe_future_velocities``, velocities), then
     (``observe_joints``) the joint positions and velocities. ``observation: deepmimic`` is the
     authors' (DeepMimic's) state instead: phase, root height, every observed link's position
     (relative to the root) and orientation, then every link's linear and angular velocity, all in
     the root's heading frame (the root's yaw about the up axis removed: a tilt stays visible),
     followed by the same options.

Episodes end when ``episode_steps`` have passed (truncated), and are terminated on a NaN action,
a diverging simulation (non-finite state or a joint speed above ``max_joint_velocity``, 1,000 rad/s:
far above the engines' 100 rad/s clamp, so only a simulation that blew up trips it) or, if
configured, a step reward below ``early_termination.min_reward`` (for ``early_termination.patience``
consecutive control steps: 1 by default; more lets a policy recover from a moment every policy
loses, such as a looping motion's jump back to its first frame) or a fall
(``early_termination.fall``: with ``body.base: free``, a link other than ``body.ground_contacts``
touching the ground, as the authors' "forbidden ground contact"). Every such end is flagged in
``info`` and counted in :attr:`ImitationEnv.counters`.

Actions are in the controller's units (the joint range for absolute targets, +-``residual_range``
for corrections) or, with ``normalize_actions``, in [-1, 1] per value mapped affinely onto that
box (DeepMimic's parametrisation: any learner sees a unit box; :meth:`ImitationEnv.physical_action`).
"""

from __future__ import annotations

import os
from collections import defaultdict
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np

from aslexp.envs.config import CONF_DIR, load_group_file, resolve_group
from aslexp.envs.reward import TERMS, ImitationReward, PoseSnapshot, RewardSpec
from aslexp.sim.body import BodySpec, load_layout
from aslexp.sim.engine import EngineSpec
from aslexp.sim.motion import Motion, MotionFormatError, load_motion
from aslexp.sim.pd import ControllerSpec, PDController
from aslexp.sim.reference import ReferenceMotion
from aslexp import quaternion
from aslexp.sim.world import Character, PhysicsConfig, World


OBSERVATIONS = ("aslexp", "deepmimic")
# Env keys that shape the training reward alone (ImitationEnv shape_reward): no score depends on them.
TRAINING_ONLY_KEYS = ("heading_shaping", "offset_shaping")
# Env keys that move the base a residual policy corrects: the no-learning baselines ("the controller"
# = the reference one step ahead) are defined without them, so a variant cannot move its own bar.
RESIDUAL_BASE_KEYS = ("residual_base_smoothing", "residual_base_smoothing_groups")
UP_AXIS = 1  # the motions and worlds are y-up (gravity -9.8 y)

# Rendering camera (TinyRenderer) looking at the mean link position: the hand's view.
DEFAULT_CAMERA = {"distance": 0.5, "yaw": 90.0, "pitch": -10.0}


@dataclass(frozen=True)
class EnvSpec:
    """``conf/env/*.yaml`` as plain values."""

    physics_hz: float = 240.0
    control_hz: float = 30.0
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
    action_mode: str = "absolute"
    residual_range: float = 0.5
    reference_lookahead: int = 1
    observe_future: tuple[int, ...] = ()
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
    heading_shaping: float = 0.0
    offset_shaping: float = 0.0
    residual_velocity_range: float = 0.0  # rad/s; > 0 appends velocity-target corrections to the action
    # Residual only: the base the correction is added to, low-pass filtered,
    # base_t = alpha * base_(t-1) + (1 - alpha) * reference_(t + lookahead), on the joints of
    # residual_base_smoothing_groups (None: all); restarted every episode. 0: the reference itself.
    # With alpha > 0 a zero correction is the smoothed-reference baseline (aslexp.rl.evaluate), the
    # strongest no-learning one on the standing upper body: gentler targets, less slip.
    residual_base_smoothing: float = 0.0
    residual_base_smoothing_groups: tuple[str, ...] | None = None
    # The policy's action is [-1, 1] per value, mapped affinely onto the box above (absolute: each
    # joint's range, e.g. [-1, 1] -> [0, 2] rad; residual: +-residual_range, +-residual_velocity_range).
    normalize_actions: bool = False
    # The box of absolute targets: each joint's range (joint), or the range the reference motion
    # visits widened by action_range_margin rad on each side, within the joint range (motion).
    action_range: str = "joint"
    action_range_margin: float = 0.25
    # Links in the observation (fnmatch patterns on link names, URDF order); None: every link;
    # []: none (the observation is then the phase and the observe_* options alone).
    observe_links: tuple[str, ...] | None = None
    camera: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_CAMERA))
    observation: str = "aslexp"  # aslexp (root frame, per link 13 values) | deepmimic (the authors')

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "EnvSpec":
        unknown = set(values) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"env config: unknown keys {sorted(unknown)}")
        values = dict(values)
        values["gravity"] = tuple(values.get("gravity", (0.0, -9.8, 0.0)))
        values["observe_future"] = tuple(int(k) for k in values.get("observe_future") or ())
        if values.get("observe_links") is not None:
            values["observe_links"] = tuple(str(p) for p in values["observe_links"])
        if values.get("residual_base_smoothing_groups") is not None:
            values["residual_base_smoothing_groups"] = tuple(str(g) for g in values["residual_base_smoothing_groups"])
        spec = cls(**values)
        if spec.observation not in OBSERVATIONS:
            raise ValueError(f"env config: observation must be one of {OBSERVATIONS}, got {spec.observation!r}")
        unknown_end = set(spec.early_termination or {}) - {"min_reward", "fall", "patience"}
        if unknown_end:
            raise ValueError(f"env config: early_termination has unknown keys {sorted(unknown_end)}; "
                             f"expected min_reward, patience, fall")
        patience = (spec.early_termination or {}).get("patience", 1)
        if patience is None or int(patience) != patience or patience < 1:
            raise ValueError(f"env config: early_termination.patience must be an integer >= 1 "
                             f"(control steps below min_reward before the end), got {patience!r}")
        for name in TRAINING_ONLY_KEYS:
            value = getattr(spec, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not np.isfinite(value) or value < 0:
                raise ValueError(f"env config: {name} must be a number >= 0 (a scale of the training reward's "
                                 f"factor exp(-heading_shaping yaw^2 - offset_shaping |d|^2); 0 off), got {value!r}")
        alpha = spec.residual_base_smoothing
        if isinstance(alpha, bool) or not isinstance(alpha, (int, float)) or not 0.0 <= alpha < 1.0:
            raise ValueError(f"env config: residual_base_smoothing must be a number in [0, 1) (the low-pass "
                             f"filter's alpha on the residual's base; 0 off), got {alpha!r}")
        if alpha > 0 and spec.action_mode != "residual":
            raise ValueError(f"env config: residual_base_smoothing {alpha} needs action_mode residual "
                             f"(it filters the base a correction is added to), got {spec.action_mode!r}")
        if spec.action_range not in ("joint", "motion"):
            raise ValueError(f"env config: action_range must be joint or motion, got {spec.action_range!r}")
        if spec.action_range == "motion" and (spec.action_mode != "absolute" or spec.action_range_margin < 0):
            raise ValueError(f"env config: action_range motion needs action_mode absolute and "
                             f"action_range_margin >= 0, got {spec.action_mode!r}, {spec.action_range_margin}")
        if spec.action_mode not in ("absolute", "residual"):
            raise ValueError(f"env config: action_mode must be absolute or residual, got {spec.action_mode!r}")
        ratio = spec.physics_hz / spec.control_hz
        if abs(ratio - round(ratio)) > 1e-6 or ratio < 1:
            raise ValueError(f"env config: physics_hz ({spec.physics_hz}) must be a multiple of "
                             f"control_hz ({spec.control_hz})")
        return spec

    @property
    def substeps(self) -> int:
        return int(round(self.physics_hz / self.control_hz))


def resolve_motion_path(motion: str | os.PathLike, data_root: str | os.PathLike | None) -> Path:
    """A motion file given absolutely, relative to the current directory, or to the data root; or
    a motion's name in ``conf/motion`` (``"A"``, ``"00433"``)."""
    path = Path(motion).expanduser()
    if path.is_absolute() or path.is_file():
        return path
    if not path.suffix and len(path.parts) == 1 and (CONF_DIR / "motion" / f"{path}.yaml").is_file():
        path = Path(load_group_file("motion", str(path))["file"])
    if data_root is None:
        from aslexp.data.root import resolve_data_root

        data_root = resolve_data_root(None, must_exist=False)
    return Path(data_root) / path


ROOT_TRAVEL_WARNING_M = 0.25  # the thesis' clips hold their root still (0.0 m)
_warned_travel: set[str] = set()


def _warn_travelling_root(motion: Motion, base: str) -> None:
    """Warn (once per file) when a clip's root travels but the body's root is held still: the
    pose is then tracked from the wrong place and the reward stays near zero (a walk on a fixed
    root scores ~0.04)."""
    if base == "free" or motion.num_frames < 2 or (motion.source or "") in _warned_travel:
        return
    root = np.asarray(motion.frames)[:, :3]
    travel = float(np.linalg.norm(root - root[0], axis=1).max())
    if travel > ROOT_TRAVEL_WARNING_M:
        _warned_travel.add(motion.source or "")
        import logging

        logging.getLogger(__name__).warning(
            "%s: the root travels %.2f m over the clip, but body.base=%s holds it at its first pose: "
            "the pose is tracked from the wrong place and the reward will be low; a free root "
            "follows it (body.base=free)",
            motion.source or "motion", travel, base)


def _bodies_for(found: int | None, data_root: str | os.PathLike | None) -> str:
    """A hint naming the bodies (``conf/body``) whose motions have ``found`` values per frame."""
    if found is None:
        return ""
    fits = []
    for path in sorted((CONF_DIR / "body").glob("*.yaml")):
        try:
            _, layout = load_layout(BodySpec.from_dict(resolve_group("body", path.stem)), data_root)
        except Exception:  # noqa: BLE001 - a hint only: a body that cannot load fits nothing
            continue
        if layout.motion_columns == found:
            fits.append(f"body={path.stem}")
    return f"; {' or '.join(fits)} runs motions of that width" if fits else ""


class ImitationEnv(gym.Env):
    """Imitation of one reference motion by one body (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}
    # Group file used for a group given as None or as a partial dict (subclasses change them).
    GROUP_DEFAULTS: dict[str, str] = {"body": "hand15", "controller": "thesis", "reward": "deepmimic",
                                      "env": "default"}

    def __init__(
        self,
        motion: str | os.PathLike | Motion,
        body: str | dict | None = None,
        controller: str | dict | None = None,
        reward: str | dict | None = None,
        env: str | dict | None = None,
        data_root: str | os.PathLike | None = None,
        render_mode: str | None = None,
        render_size: tuple[int, int] = (320, 320),
        complete_configs: bool = False,
        shape_reward: bool = False,
        engine: str | dict | None = None,
        score_rewards: dict[str, str | dict] | None = None,
    ) -> None:
        """Group values are names, partial dicts merged over the group default, or None; with
        ``complete_configs`` dicts are taken as they are (the jobs pass Hydra-composed groups,
        which merged over another body's default file would gain its keys and reward terms).
        ``engine``: ``conf/engine`` (a name or a dict; None: PyBullet, the thesis' engine).
        ``shape_reward``: a training env, whose returned reward carries the env's training-only
        shaping (``heading_shaping``, ``offset_shaping``); every other env returns the reward config's reward.
        ``score_rewards``: name -> reward config (a name or a complete dict) under which every step is
        also scored, as ``info["score_<name>"]`` (reporting only: the same trajectory under another
        reward scale, e.g. the authors' code weights beside the thesis' Table 5.2)."""
        super().__init__()
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.render_size = tuple(render_size)
        self.shape_reward = bool(shape_reward)
        if data_root is None:
            from aslexp.data.root import resolve_data_root

            data_root = resolve_data_root(None, must_exist=False)
        self.data_root = Path(data_root)

        # -- configuration ----------------------------------------------------------------
        def group(name: str, value):
            if complete_configs and isinstance(value, dict):
                return value
            return resolve_group(name, value, self.GROUP_DEFAULTS[name])

        self.body_spec = BodySpec.from_dict(group("body", body))
        self.controller_spec = ControllerSpec.from_dict(group("controller", controller))
        self.reward_spec = RewardSpec.from_dict(group("reward", reward))
        self.spec_env = EnvSpec.from_dict(group("env", env))
        self.engine_spec = EngineSpec.from_dict(resolve_group("engine", engine, "pybullet")
                                                if not isinstance(engine, dict) else engine)
        self.urdf, self.layout = load_layout(self.body_spec, self.data_root)

        if isinstance(motion, Motion):
            if motion.num_columns != self.layout.motion_columns:
                raise ValueError(
                    f"{motion.source or 'motion'}: the model expects {self.layout.motion_columns} values "
                    f"per frame but the motion has {motion.num_columns}"
                )
            self.motion = motion
        else:
            try:
                self.motion = load_motion(resolve_motion_path(motion, self.data_root),
                                          expected_columns=self.layout.motion_columns,
                                          quaternions=self.layout.quaternion_columns)
            except MotionFormatError as err:
                raise MotionFormatError(f"{err}{_bodies_for(err.found, self.data_root)}") from None
        self.reference = ReferenceMotion(self.motion, self.layout)
        self.control_dt = 1.0 / self.spec_env.control_hz
        _warn_travelling_root(self.motion, self.body_spec.base)

        # -- engine: a simulated character and a kinematic reference in separate worlds ----
        physics = PhysicsConfig(self.spec_env.physics_hz, self.spec_env.gravity, self.spec_env.solver_iterations,
                                self.spec_env.non_contact_inner_iterations)
        root_pos, root_rot, _, _ = self.reference.root(0.0)
        if self.engine_spec.name == "mujoco":
            from aslexp.sim.mujoco_engine import MujocoCharacter, MujocoWorld

            self.sim_world = MujocoWorld(physics, self.engine_spec)
            self.sim = MujocoCharacter(self.sim_world, self.urdf, self.body_spec, self.layout, root_pos, root_rot)
            self.ref_world = self.sim_world  # the reference is kinematics on the same model, never stepped
            self.ref = MujocoCharacter(self.sim_world, self.urdf, self.body_spec, self.layout, root_pos, root_rot,
                                       kinematic=True, body=self.sim.body)
        else:
            self.sim_world = World(physics)
            self.ref_world = World(physics)
            self.sim = Character(self.sim_world, self.urdf, self.body_spec, self.layout, root_pos, root_rot)
        self._views: tuple | None = None  # MuJoCo: PyBullet pose holders that render()'s TinyRenderer draws
        self.ground = self.sim_world.add_ground() if self.body_spec.base == "free" else None
        unknown = [n for n in self.body_spec.ground_contacts if n not in self.sim.link_names]
        if unknown:
            raise ValueError(f"body {self.body_spec.name}: ground_contacts {unknown} are not links; "
                             f"links: {self.sim.link_names}")
        self._allowed_contacts = {self.sim.link_names.index(n) for n in self.body_spec.ground_contacts}
        if self.engine_spec.name == "pybullet":
            self.ref = Character(self.ref_world, self.urdf, self.body_spec, self.layout, root_pos, root_rot,
                                 kinematic=True)
        if render_mode == "rgb_array" and self.engine_spec.name == "pybullet":
            _colour(self.ref, (0.25, 0.45, 0.85))  # reference: blue
            _colour(self.sim, (0.95, 0.55, 0.15))  # simulation: orange
        self.controller = PDController(self.controller_spec, self.layout)
        self.controller.check_body(self.sim)
        if self.controller_spec.target_rate == "physics" and self.spec_env.action_mode != "residual":
            raise ValueError(f"controller {self.controller_spec.name}: target_rate physics re-samples the "
                             f"reference under the policy's correction and needs env action_mode residual, "
                             f"got {self.spec_env.action_mode!r}")
        if self.controller_spec.target_rate == "physics" and self.spec_env.residual_base_smoothing > 0:
            raise ValueError(f"controller {self.controller_spec.name}: target_rate physics re-samples the "
                             f"reference itself every physics step; env residual_base_smoothing needs "
                             f"target_rate control")
        self._thesis_pd = False  # set by thesis_pd(): the baselines use the thesis' controller
        # The residual's filtered base: the joint values filtered, and the last base (None: restart).
        self._smoothed_values = (self.joint_value_indices(self.spec_env.residual_base_smoothing_groups,
                                                          "env residual_base_smoothing_groups")
                                 if self.spec_env.residual_base_smoothing > 0 else None)
        self._filter_state: np.ndarray | None = None
        self._plain_base = False  # set by thesis_pd(): the base is the reference itself
        self._default_controller: PDController | None = None
        self.reward_fn = ImitationReward(self.reward_spec, self.layout)
        self.score_fns = {str(name): ImitationReward(RewardSpec.from_dict(
            value if isinstance(value, dict) else resolve_group("reward", value)), self.layout)
            for name, value in (score_rewards or {}).items()}

        # -- spaces ---------------------------------------------------------------------------
        lower, upper = [], []
        for joint in self.layout.joints:
            if joint.dof == 1:
                lower.append(joint.lower if joint.lower is not None else -np.pi)
                upper.append(joint.upper if joint.upper is not None else np.pi)
            else:
                lower.extend([-1.0] * 4)
                upper.extend([1.0] * 4)
        self.joint_lower = np.asarray(lower)
        self.joint_upper = np.asarray(upper)
        if self.spec_env.action_mode == "absolute":
            low, high = self.joint_lower, self.joint_upper
            if self.spec_env.action_range == "motion":
                low, high = self._motion_range(self.spec_env.action_range_margin)
            self.action_space = gym.spaces.Box(low.astype(np.float32), high.astype(np.float32), dtype=np.float32)
        else:
            r = float(self.spec_env.residual_range)
            self.action_space = gym.spaces.Box(-r, r, shape=(self.layout.action_size,), dtype=np.float32)
        self.velocity_size = sum(1 if j.dof == 1 else 3 for j in self.layout.joints)
        rv = float(self.spec_env.residual_velocity_range)
        if rv > 0:  # [position part, velocity-target corrections added to the motors' velocity targets]
            self.action_space = gym.spaces.Box(
                np.concatenate([self.action_space.low, np.full(self.velocity_size, -rv, np.float32)]),
                np.concatenate([self.action_space.high, np.full(self.velocity_size, rv, np.float32)]),
                dtype=np.float32)
        # The box above is in physical units (rad, quaternion components, rad/s): the controller's.
        # With normalize_actions the policy acts in [-1, 1] and step() maps onto that box.
        self.physical_action_space = self.action_space
        self._action_center = ((self.action_space.high.astype(np.float64) + self.action_space.low) / 2)
        self._action_half_range = ((self.action_space.high.astype(np.float64) - self.action_space.low) / 2)
        if self.spec_env.normalize_actions:
            if np.any(self._action_half_range <= 0):
                flat = [j.name for j in self.layout.joints for _ in range(1 if j.dof == 1 else 4)]
                empty = sorted({flat[i] for i in np.flatnonzero(self._action_half_range[:len(flat)] <= 0)})
                raise ValueError(f"env config: normalize_actions needs a non-empty range per action; "
                                 f"joints {empty} of body {self.body_spec.name} have lower == upper")
            self.action_space = gym.spaces.Box(-1.0, 1.0, shape=self.physical_action_space.shape, dtype=np.float32)
        self.observed_links = self._select_links(self.spec_env.observe_links)
        # Links read from PyBullet each step: the observed ones and the end effectors (None: all).
        self._state_links = (None if self.spec_env.observe_links is None else
                             sorted(set(self.observed_links.tolist()) | set(self.sim.end_effector_links)))
        obs_size = 1 + 13 * len(self.observed_links) + len(self.spec_env.observe_future) * self.layout.action_size
        obs_size += self.spec_env.observation == "deepmimic"  # the root height
        if self.spec_env.observe_future_velocities:
            obs_size += len(self.spec_env.observe_future) * self.velocity_size
        if self.spec_env.observe_joints:
            obs_size += self.layout.action_size + self.velocity_size
        obs_size += 7 * self.spec_env.observe_reference_root
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(obs_size,), dtype=np.float32)

        # -- episode state and counters --------------------------------------------------
        self.time = 0.0
        self.steps = 0
        self._steps_below = 0
        self.last_sim_state: PoseSnapshot | None = None
        self.last_reference_state: PoseSnapshot | None = None
        self.counters: dict[str, int] = defaultdict(int)
        self._term_sums: dict[str, float] = defaultdict(float)

    def _motion_range(self, margin: float) -> tuple[np.ndarray, np.ndarray]:
        """Per action value, the reference's min and max over the motion (sampled at four times
        its frame rate) widened by ``margin`` rad and kept within the joint range; quaternion
        components keep [-1, 1]."""
        frames = max(2, 4 * len(self.motion.frames))
        q = np.stack([self.reference.joints(t) for t in np.linspace(0.0, self.reference.duration, frames)])
        revolute = np.concatenate([[j.dof == 1] * (1 if j.dof == 1 else 4) for j in self.layout.joints])
        low = np.where(revolute, np.maximum(self.joint_lower, q.min(axis=0) - margin), self.joint_lower)
        high = np.where(revolute, np.minimum(self.joint_upper, q.max(axis=0) + margin), self.joint_upper)
        return low, high

    def _select_links(self, patterns: tuple[str, ...] | None) -> np.ndarray:
        """Indices of the observed links (all links, those matching one of ``patterns``, or none
        for an empty list)."""
        if patterns is None:
            return np.arange(self.sim.num_links)
        if not patterns:
            return np.zeros(0, dtype=int)
        import fnmatch

        chosen = [i for i, name in enumerate(self.sim.link_names)
                  if any(fnmatch.fnmatch(name, p) for p in patterns)]
        if not chosen:
            raise ValueError(f"env config: observe_links {list(patterns)} match no link of body "
                             f"{self.body_spec.name}; links: {self.sim.link_names}")
        return np.asarray(chosen, dtype=int)

    # ------------------------------------------------------------------------------------
    # Reference helpers
    def reference_targets(self, lookahead: int = 0) -> np.ndarray:
        """Reference joint positions ``lookahead`` control steps after the current time."""
        return self.reference.joints(self.time + lookahead * self.control_dt)

    def joint_value_indices(self, groups: tuple[str, ...] | list[str] | None, what: str = "groups") -> np.ndarray:
        """Indices into a joint-value vector (1 per revolute joint, 4 per spherical) of the joints
        of ``groups`` (None: every joint); ``what`` names the setting in the error."""
        chosen = [i for i, j in enumerate(self.layout.joints) if groups is None or j.group in groups]
        if not chosen:
            raise ValueError(f"{what}: no joint in groups {list(groups or [])}; the body's groups "
                             f"are {sorted({j.group for j in self.layout.joints})}")
        starts = np.cumsum([0] + [j.dof for j in self.layout.joints])
        return np.concatenate([np.arange(starts[i], starts[i + 1]) for i in chosen])

    def residual_base(self) -> np.ndarray:
        """The targets a residual correction is added to at the next control step: the reference
        ``reference_lookahead`` steps ahead, or with ``residual_base_smoothing`` its low-pass filter
        (the filter's state advances in step(), not here)."""
        return self._residual_base()[1]

    def _residual_base(self) -> tuple[np.ndarray | None, np.ndarray]:
        """(the filter's new state, the base). The base is the filtered reference held within the
        action box of the reference, as smoothed_reference_policy's clipped action holds it: a zero
        correction then drives exactly that baseline."""
        reference = self.reference_targets(self.spec_env.reference_lookahead)
        if self._smoothed_values is None or self._plain_base:
            return None, reference
        filtered = reference.copy()
        if self.steps > 0 and self._filter_state is not None:
            alpha, index = self.spec_env.residual_base_smoothing, self._smoothed_values
            filtered[index] = alpha * self._filter_state[index] + (1.0 - alpha) * reference[index]
        size = self.layout.action_size
        box = self.physical_action_space
        return filtered, reference + np.clip(filtered - reference, box.low[:size], box.high[:size])

    def reference_action(self, lookahead: int = 0) -> np.ndarray:
        """The action that drives the PD targets with the reference (the no-learning baseline)."""
        target = self.reference_targets(lookahead)
        if self.spec_env.action_mode == "residual":
            target = target - self.residual_base()
        if self.spec_env.residual_velocity_range > 0:
            target = np.concatenate([target, np.zeros(self.velocity_size)])
        return self.normalize_action(target).astype(np.float32)

    def physical_action(self, action: np.ndarray) -> np.ndarray:
        """The controller's action (rad, quaternion components, rad/s) for a policy action: the
        same values, or with ``normalize_actions`` the affine map of [-1, 1] onto the box
        (-1 -> low, +1 -> high, exactly; values outside [-1, 1] are not clipped here: the
        targets are clipped to the joint limits as for physical actions)."""
        if not self.spec_env.normalize_actions:
            return action
        return self._action_center + self._action_half_range * action

    def normalize_action(self, action: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`physical_action` (the policy action giving a physical one)."""
        if not self.spec_env.normalize_actions:
            return action
        return (np.asarray(action, dtype=np.float64) - self._action_center) / self._action_half_range

    @contextmanager
    def thesis_pd(self):
        """Within the block a controller with target options (reference velocity, physics rate)
        is replaced by the body's default controller (``GROUP_DEFAULTS``: the thesis gains, held
        positions, zero velocity targets): the reference-driven baselines are defined with it,
        so a tuned controller cannot lower the bar it is compared with. A plain controller stays.
        A residual's filtered base (``residual_base_smoothing``) is the reference itself within the
        block, for the same reason: a zero correction there is exactly the controller."""
        plain_base, self._plain_base = self._plain_base, True
        try:
            with self._thesis_controller():
                yield self
        finally:
            self._plain_base = plain_base

    @contextmanager
    def _thesis_controller(self):
        if self.controller_spec.is_thesis_pd:
            yield self
            return
        if self._default_controller is None:
            spec = ControllerSpec.from_dict(resolve_group("controller", None, self.GROUP_DEFAULTS["controller"]))
            if not spec.is_thesis_pd:
                raise ValueError(f"default controller {spec.name!r} has target options; baselines need a plain one")
            self._default_controller = PDController(spec, self.layout)
            self._default_controller.check_body(self.sim)
        previous = self._thesis_pd, self.controller
        self._thesis_pd, self.controller = True, self._default_controller
        try:
            yield self
        finally:
            self._thesis_pd, self.controller = previous

    def _drive(self, action: np.ndarray) -> None:
        """Set the motors from the action and step the physics through one control step."""
        spec, n = self.controller_spec, self.spec_env.substeps
        plain = self._thesis_pd or spec.is_thesis_pd
        feed_velocity = spec.target_velocity == "reference" and not plain
        action, velocity_correction = action[:self.layout.action_size], action[self.layout.action_size:]

        def velocity_targets(t: float) -> np.ndarray | None:
            velocity = spec.velocity_scale * self.reference.joint_velocities(t) if feed_velocity else None
            if len(velocity_correction):
                velocity = velocity_correction if velocity is None else velocity + velocity_correction
            return velocity

        if spec.target_rate == "physics" and not plain:
            substep = self.control_dt / n
            for i in range(n):
                t = self.time + (i + 1) * substep
                targets = np.clip(self.reference.joints(t) + action, self.joint_lower, self.joint_upper)
                self.controller.apply(self.sim, targets, velocity_targets(t))
                self.sim_world.step(1)
            return
        target_time = self.time + self.spec_env.reference_lookahead * self.control_dt
        if self.spec_env.action_mode == "residual":
            self._filter_state, base = self._residual_base()
            targets = base + action
        else:
            targets = action
        targets = np.clip(targets, self.joint_lower, self.joint_upper)
        self.controller.drive(self.sim, targets, velocity_targets(target_time), n)

    def _reference_snapshot(self, t: float) -> PoseSnapshot:
        q = self.reference.joints(t)
        qd = self.reference.joint_velocities(t)
        self.ref.set_state(q, qd)
        root_pos, root_rot, root_vel, root_ang = self.reference.root(t)
        return PoseSnapshot(q, qd, self.ref.end_effector_positions(), root_pos, root_rot, root_vel, root_ang)

    def _sim_snapshot(self, links: np.ndarray) -> PoseSnapshot:
        q, qd = self.sim.joint_state()
        root_pos, root_rot, root_vel, root_ang = self.sim.base_state()
        return PoseSnapshot(q, qd, self.sim.end_effector_positions(links), root_pos, root_rot, root_vel, root_ang)

    # ------------------------------------------------------------------------------------
    def _observation(self, links: np.ndarray) -> np.ndarray:
        root_pos, root_rot, _, _ = self.sim.base_state()
        if len(self.observed_links) != len(links):
            links = links[self.observed_links]
        joints = [a[None] for a in self.sim.joint_state()] if self.spec_env.observe_joints else None
        return observe(self.spec_env, self.reference, np.asarray([self.time]), links[None], root_pos[None],
                       root_rot[None], joints)[0]

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None):
        """Start an episode at ``options["time"]`` (seconds), ``options["phase"]``, a random phase
        (reference state initialisation) or 0."""
        super().reset(seed=seed)
        options = options or {}
        if "time" in options:
            self.time = float(options["time"])
        elif "phase" in options:
            self.time = float(options["phase"]) * self.reference.duration
        elif self.spec_env.reference_state_init:
            self.time = float(self.np_random.uniform(0.0, self.reference.duration))
        else:
            self.time = 0.0
        self.steps = 0
        self._steps_below = 0  # consecutive steps with a reward below early_termination.min_reward
        q = self.reference.joints(self.time)
        qd = self.reference.joint_velocities(self.time)
        self.sim.set_state(q, qd)
        self.sim.set_base(*self.reference.root(self.time))
        self._reference_snapshot(self.time)
        links = self.sim.link_states(links=self._state_links)
        self.counters["episodes"] += 1
        return self._observation(links), {"time": self.time}

    def step(self, action):
        action = np.asarray(action, dtype=np.float64).reshape(-1)
        size = self.action_space.shape[0]
        if action.shape[0] != size or not np.all(np.isfinite(action)):
            if action.shape[0] != size:
                raise ValueError(f"action has {action.shape[0]} values, expected {size}")
            # A NaN action ends the episode (flagged, counted); the physics is never fed it.
            self.counters["nan_actions"] += 1
            links = self.sim.link_states(links=self._state_links)
            return self._observation(links), 0.0, True, False, {"nan_action": True, "diverged": False}

        self._drive(self.physical_action(action))
        self.time += self.control_dt
        self.steps += 1

        links = self.sim.link_states(links=self._state_links)
        sim_state = self._sim_snapshot(links)
        # MuJoCo clamps joint speeds as PyBullet does: its guard reads the speed before the clamp,
        # which a simulation that blew up sends far past max_joint_velocity (or to NaN).
        speed = np.max([np.max(np.abs(sim_state.qd)), getattr(self.sim, "peak_speed", 0.0)])  # NaN stays NaN
        if (not np.all(np.isfinite(links)) or not np.all(np.isfinite(sim_state.qd))
                or not speed <= self.spec_env.max_joint_velocity):
            self.counters["diverged"] += 1
            obs = np.nan_to_num(self._observation(links), nan=0.0, posinf=0.0, neginf=0.0)
            return obs, 0.0, True, False, {"nan_action": False, "diverged": True,
                                           "divergence": self._divergence(sim_state.qd, speed)}

        ref_state = self._reference_snapshot(self.time)
        self.last_sim_state, self.last_reference_state = sim_state, ref_state  # what the reward compared
        reward, terms, errors = self.reward_fn(sim_state, ref_state)
        for name, value in terms.items():
            self._term_sums[name] += value
        self._term_sums["reward"] += reward
        self._term_sums["steps"] += 1

        ending = self.spec_env.early_termination or {}
        min_reward = ending.get("min_reward")
        fell = bool(ending.get("fall")) and self.fallen()
        low = min_reward is not None and reward < float(min_reward)
        self._steps_below = self._steps_below + 1 if low else 0
        early = fell or self._steps_below >= int(ending.get("patience", 1))
        if early:
            self.counters["early_terminations"] += 1
            self.counters["falls"] += fell
        truncated = self.steps >= self.spec_env.episode_steps and not early
        info = {"nan_action": False, "diverged": False, "early_termination": early, "fall": fell,
                **{f"r_{k}": v for k, v in terms.items()}, **{f"e_{k}": v for k, v in errors.items()},
                **{f"score_{name}": fn(sim_state, ref_state)[0] for name, fn in self.score_fns.items()}}
        yaw_scale, position_scale = self.spec_env.heading_shaping, self.spec_env.offset_shaping
        if self.shape_reward and (yaw_scale > 0 or position_scale > 0):
            yaw = quaternion.twist_angle(ref_state.root_rot, sim_state.root_rot, UP_AXIS)
            offset = np.delete(sim_state.root_pos - ref_state.root_pos, UP_AXIS)
            drift = float(np.exp(-yaw_scale * yaw * yaw - position_scale * float(offset @ offset)))
            self._term_sums["drift"] += drift  # logged as train_drift; train_reward stays unshaped
            info["r_drift"] = drift
            reward *= drift
        return self._observation(links), reward, early, truncated, info

    def _divergence(self, qd: np.ndarray, speed: float) -> dict[str, Any]:
        """Where a blow-up showed: the fastest joint (MuJoCo: before its clamp; a NaN counts as the
        fastest), its speed and the time into the episode (for the one line that reports it)."""
        joint = getattr(self.sim, "peak_joint", "")
        if not joint:
            names = self.layout.velocity_names
            fastest = int(np.argmax(np.where(np.isnan(qd), np.inf, np.abs(qd)))) if len(qd) else 0
            joint = names[fastest] if fastest < len(names) else "?"
        return {"joint": joint, "speed": float(speed), "step": int(self.steps),
                "seconds": round(self.steps / self.spec_env.control_hz, 4)}

    def fallen(self) -> bool:
        """True when a link other than the body's ``ground_contacts`` touches the ground."""
        if self.ground is None:
            return False
        return bool(self.sim.ground_contacts(self.ground) - self._allowed_contacts)

    def pop_term_means(self) -> dict[str, float]:
        """Mean reward and per-term rewards since the last call (for training logs)."""
        steps = self._term_sums.pop("steps", 0)
        out = {k: v / steps for k, v in self._term_sums.items()} if steps else {}
        self._term_sums.clear()
        return out

    # ------------------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """Reference (left) and simulation (right) side by side, PyBullet's TinyRenderer."""
        if self.render_mode != "rgb_array":
            return None
        camera = {**DEFAULT_CAMERA, **(self.spec_env.camera or {})}
        if self.engine_spec.name == "mujoco":  # MuJoCo's renderer needs OpenGL: PyBullet draws the poses
            return self._render_views(camera)
        return np.concatenate([_snapshot(self.ref_world, self.ref, self.render_size, camera),
                               _snapshot(self.sim_world, self.sim, self.render_size, camera)], axis=1)

    def _render_views(self, camera: dict[str, float]) -> np.ndarray:
        if self._views is None:
            physics = PhysicsConfig(self.spec_env.physics_hz, self.spec_env.gravity)
            views = []
            for rgb in ((0.25, 0.45, 0.85), (0.95, 0.55, 0.15)):  # reference blue, simulation orange
                world = World(physics)
                holder = Character(world, self.urdf, self.body_spec, self.layout, kinematic=True)
                _colour(holder, rgb)
                views.append((world, holder))
            self._views = tuple(views)
        images = []
        for (world, holder), source in zip(self._views, (self.ref, self.sim)):
            holder.set_state(*source.joint_state())
            position, rotation, _, _ = source.base_state()
            holder.set_base(position, rotation)
            images.append(_snapshot(world, holder, self.render_size, camera))
        return np.concatenate(images, axis=1)

    def close(self) -> None:
        self.sim_world.close()
        if self.ref_world is not self.sim_world:
            self.ref_world.close()
        for world, _ in self._views or ():
            world.close()
        self._views = None


def heading_rotation(root_rot: np.ndarray) -> np.ndarray:
    """The root's rotation about the up axis alone (its heading), as DeepMimic's state frame: the
    root's x axis projected on the ground plane gives the heading angle. (..., 4) -> (..., 4)."""
    forward = quaternion.rotate(root_rot, np.array([1.0, 0.0, 0.0]))
    heading = np.arctan2(-forward[..., 2], forward[..., 0])  # about +y (y up)
    zero = np.zeros_like(heading)
    return np.stack([np.cos(heading / 2), zero, np.sin(heading / 2), zero], axis=-1)


def observe(spec: EnvSpec, reference: ReferenceMotion, times: np.ndarray, links: np.ndarray, root_pos: np.ndarray,
            root_rot: np.ndarray, joints: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The observations (N, size) of N bodies (module docstring): ``times`` (N,), the observed links'
    world states (N, L, 13), the roots' positions (N, 3) and rotations (N, 4), with
    ``observe_joints`` the joint positions and velocities (N, ...). One implementation for the
    single environment (a batch of one) and the batched one."""
    n = len(times)
    deepmimic = spec.observation == "deepmimic"
    frame = heading_rotation(root_rot) if deepmimic else root_rot  # the frame links are seen in
    inverse = quaternion.conjugate(frame)[:, None, :]
    local = np.empty_like(links)
    count = links.shape[1]
    # positions (from the root), linear and angular velocities into the frame: one batched product
    # of row vectors with each body's rotation matrix (v R = (R^T v)^T)
    vectors = np.concatenate([links[..., 0:3] - root_pos[:, None, :], links[..., 7:10], links[..., 10:13]], axis=1)
    turned = np.matmul(vectors, quaternion.matrices(frame))
    local[..., 0:3], local[..., 7:10], local[..., 10:13] = (turned[:, :count], turned[:, count:2 * count],
                                                              turned[:, 2 * count:])
    rot = quaternion.multiply(inverse, links[..., 3:7])
    local[..., 3:7] = np.where(rot[..., :1] < 0, -rot, rot)  # one sign per rotation
    phase = reference.motion.phase_many(times)[:, None]
    if deepmimic:  # phase, root height, then all poses, then all velocities (DeepMimic's order)
        parts = [phase, root_pos[:, UP_AXIS:UP_AXIS + 1], local[..., 0:7].reshape(n, -1),
                 local[..., 7:13].reshape(n, -1)]
    else:
        parts = [phase, local.reshape(n, -1)]
    control_dt = 1.0 / spec.control_hz
    for k in spec.observe_future:
        parts.append(reference.joints_many(times + k * control_dt))
    if spec.observe_future_velocities:
        for k in spec.observe_future:
            parts.append(reference.joint_velocities_many(times + k * control_dt))
    if spec.observe_joints:
        parts.extend(joints)
    if spec.observe_reference_root:
        ref_pos, ref_rot, _, _ = reference.root_many(times)
        ref_local = quaternion.multiply(quaternion.conjugate(frame), ref_rot)
        parts += [quaternion.rotate(quaternion.conjugate(frame), ref_pos - root_pos),
                  np.where(ref_local[:, :1] < 0, -ref_local, ref_local)]
    return np.concatenate(parts, axis=1).astype(np.float32)


def _colour(character: Character, rgb: tuple[float, float, float]) -> None:
    """Colour a character for rendering; distal links lighter so finger tips stand out."""
    pb = character.world.client
    for link in range(-1, character.num_links):
        shade = 1.0 if link < 0 or not character.link_names[link].endswith("dist") else 1.25
        pb.changeVisualShape(character.id, link, rgbaColor=[min(c * shade, 1.0) for c in rgb] + [1.0])


def _snapshot(world: World, character: Character, size: tuple[int, int],
              camera: dict[str, float] | None = None) -> np.ndarray:
    camera = camera or DEFAULT_CAMERA
    pb = world.client
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
