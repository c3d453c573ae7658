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

The steps above are written once for N rows in :mod:`aslexp.envs.mdp`; this environment calls them
with rows of one, :class:`~aslexp.envs.batched.BatchedImitationEnv` with one row per environment.

Actions are in the controller's units (the joint range for absolute targets, +-``residual_range``
for corrections) or, with ``normalize_actions``, in [-1, 1] per value mapped affinely onto that
box (DeepMimic's parametrisation: any learner sees a unit box; :meth:`ImitationEnv.physical_action`).
"""

from __future__ import annotations

import os
from collections import defaultdict
from contextlib import contextmanager
from typing import Any

import gymnasium as gym
import numpy as np

from aslexp.envs import mdp
from aslexp.envs.assembly import ImitationSetup, warn_travelling_root
from aslexp.envs.mdp import heading_rotation, observe  # noqa: F401 (importers of the env's module find them)
from aslexp.envs.reward import PoseSnapshot
from aslexp.envs.spec import EnvSpec  # noqa: F401 (the env's keys, conf/env, live there)
from aslexp.sim.engine import DEFAULT_CAMERA
from aslexp.sim.motion import Motion
from aslexp.sim.pd import PDController


class ImitationEnv(gym.Env):
    """Imitation of one reference motion by one body (see the module docstring)."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 30}
    # Group files chosen for the groups given as None or as partial dicts (empty: the imitate job's own
    # defaults, conf/imitate.yaml; a subclass names another body, which brings its own groups).
    GROUP_DEFAULTS: dict[str, str] = {}

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
        ``engine``: ``conf/engine`` (a name or a dict; None: the default engine, the thesis').
        ``shape_reward``: a training env, whose returned reward carries the env's training-only
        shaping (``heading_shaping``, ``offset_shaping``); every other env returns the reward config's reward.
        ``score_rewards``: name -> reward config (a name or a complete dict) under which every step is
        also scored, as ``info["score_<name>"]`` (reporting only: the same trajectory under another
        reward scale, e.g. the authors' code weights beside the thesis' Table 5.2)."""
        setup = ImitationSetup.from_groups(motion, body, controller, reward, env, engine, data_root=data_root,
                                           complete=complete_configs, defaults=self.GROUP_DEFAULTS,
                                           score_rewards=score_rewards)
        self._assemble(setup, render_mode, render_size, shape_reward)

    @classmethod
    def from_setup(cls, setup: ImitationSetup, render_mode: str | None = None,
                   render_size: tuple[int, int] = (320, 320), shape_reward: bool = False) -> "ImitationEnv":
        """The environment of an assembled experiment (:mod:`aslexp.envs.assembly`)."""
        env = cls.__new__(cls)
        env._assemble(setup, render_mode, render_size, shape_reward)
        return env

    def _assemble(self, setup: ImitationSetup, render_mode: str | None, render_size: tuple[int, int],
                  shape_reward: bool) -> None:
        super().__init__()
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.render_size = tuple(render_size)
        self.shape_reward = bool(shape_reward)
        self.setup = setup
        self.data_root = setup.data_root
        self.body_spec, self.controller_spec, self.reward_spec = setup.body, setup.controller, setup.reward
        self.spec_env, self.engine_spec = setup.env, setup.engine
        self.urdf, self.layout, self.motion = setup.urdf, setup.layout, setup.motion
        self.reference = setup.reference
        self.control_dt = 1.0 / self.spec_env.control_hz
        warn_travelling_root(self.motion, self.body_spec.base)

        # -- engine: a simulated character and a kinematic reference, built by the engine ---------
        self.simulation = setup.simulation(render=render_mode == "rgb_array")
        self.sim, self.ref, self.ground = self.simulation.sim, self.simulation.ref, self.simulation.ground
        unknown = [n for n in self.body_spec.ground_contacts if n not in self.sim.link_names]
        if unknown:
            raise ValueError(f"body {self.body_spec.name}: ground_contacts {unknown} are not links; "
                             f"links: {self.sim.link_names}")
        self._allowed_contacts = {self.sim.link_names.index(n) for n in self.body_spec.ground_contacts}
        self.controller = setup.pd_controller()
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
        self._filter_state: np.ndarray | None = None  # the residual's filtered base, (1, size); None: restart
        self._plain_base = False  # set by thesis_pd(): the base is the reference itself
        self._default_controller: PDController | None = None
        self.reward_fn = setup.reward_function()
        self.score_fns = {name: setup.reward_function(spec) for name, spec in setup.score_rewards.items()}

        self._action_spaces()
        alpha = self.spec_env.residual_base_smoothing
        self.base_smoothing = (mdp.BaseSmoothing(alpha, self.joint_value_indices(
            self.spec_env.residual_base_smoothing_groups, "env residual_base_smoothing_groups"),
            *self._correction_box()) if alpha > 0 else None)
        self.termination = mdp.Termination.of(self.spec_env)
        self._target_rules: dict[bool, mdp.TargetRule] = {}  # by plain (thesis_pd) or not
        self.observed_links = self._select_links(self.spec_env.observe_links)
        # Links read from the engine each step: the observed ones and the end effectors (None: all).
        self._state_links = (None if self.spec_env.observe_links is None else
                             sorted(set(self.observed_links.tolist()) | set(self.sim.end_effector_links)))
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, shape=(self._observation_size(),), dtype=np.float32)

        # -- episode state and counters --------------------------------------------------
        self.time = 0.0
        self.steps = 0
        self._steps_below = 0
        self.last_sim_state: PoseSnapshot | None = None
        self.last_reference_state: PoseSnapshot | None = None
        self.counters: dict[str, int] = defaultdict(int)
        self._term_sums: dict[str, float] = defaultdict(float)

    def _action_spaces(self) -> None:
        """The joint ranges, the action space (absolute or residual, in physical units or [-1, 1] with
        ``normalize_actions``) and the physical box step() maps onto."""
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
        self.velocity_size = sum(1 if j.dof == 1 else 3 for j in self.layout.joints)
        # env.policy_groups: the joint values (and velocities) the policy corrects and sees; None: all
        self.policy_seen = self._policy_columns(self.spec_env.policy_groups)
        if self.spec_env.action_mode == "residual":
            r = float(self.spec_env.residual_range)
            size = self.layout.action_size if self.policy_seen is None else len(self.policy_seen[0])
            self.action_space = gym.spaces.Box(-r, r, shape=(size,), dtype=np.float32)
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

    def _policy_columns(self, groups: tuple[str, ...] | None) -> tuple[np.ndarray, np.ndarray] | None:
        """(joint-value indices, joint-velocity indices) of the joints of ``groups``; None for None."""
        if groups is None:
            return None
        values = self.joint_value_indices(groups, "env policy_groups")
        chosen = {j.name for j in self.layout.joints if j.group in groups}
        return values, np.asarray([i for i, name in enumerate(self.layout.velocity_names) if name in chosen])

    def _correction_box(self) -> tuple[np.ndarray, np.ndarray]:
        """The box of position corrections per joint value (residual): the action box's, 0 on the joints
        the policy does not correct (``policy_groups``)."""
        size = self.layout.action_size if self.policy_seen is None else len(self.policy_seen[0])
        low, high = self.physical_action_space.low[:size], self.physical_action_space.high[:size]
        if self.policy_seen is None:
            return low, high
        full_low, full_high = np.zeros(self.layout.action_size), np.zeros(self.layout.action_size)
        full_low[self.policy_seen[0]], full_high[self.policy_seen[0]] = low, high
        return full_low, full_high

    @contextmanager
    def whole_body(self):
        """This env, or with ``policy_groups`` one of the same setup whose actions reach every joint:
        a no-learning baseline drives every joint itself, whichever joints a policy corrects."""
        if self.policy_seen is None:
            yield self
            return
        env = type(self).from_setup(self.setup.merged(env={"policy_groups": None}))
        try:
            yield env
        finally:
            env.close()

    def policy_part(self, action: np.ndarray) -> np.ndarray:
        """The values of a controller's action for every joint that the policy acts on (``policy_groups``)."""
        return action if self.policy_seen is None else np.asarray(action)[..., self.policy_seen[0]]

    def _observation_size(self) -> int:
        """The observation's length: phase, 13 values per observed link, the reference's next frames
        (and their velocities), the root height, the body's joints, the reference root."""
        values, speeds = ((self.layout.action_size, self.velocity_size) if self.policy_seen is None
                          else tuple(len(c) for c in self.policy_seen))
        size = (int(self.spec_env.observe_phase) + 13 * len(self.observed_links)
                + len(self.spec_env.observe_future) * values)
        size += self.spec_env.observation == "deepmimic"  # the root height
        if self.spec_env.observe_future_velocities:
            size += len(self.spec_env.observe_future) * speeds
        if self.spec_env.observe_joints:
            size += values + speeds
        size += 7 * self.spec_env.observe_reference_root
        return size

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
        return self._residual_base()[1][0]

    def _residual_base(self) -> tuple[np.ndarray | None, np.ndarray]:
        """(the filter's new state, the base), rows of one (:func:`aslexp.envs.mdp.residual_base`)."""
        reference = self.reference_targets(self.spec_env.reference_lookahead)[None]
        smoothing = None if self._plain_base else self.base_smoothing
        return mdp.residual_base(reference, self._filter_state, np.array([self.steps == 0]), smoothing)

    def reference_action(self, lookahead: int = 0) -> np.ndarray:
        """The action that drives the PD targets with the reference (the no-learning baseline)."""
        target = self.reference_targets(lookahead)
        if self.spec_env.action_mode == "residual":
            target = target - self.residual_base()
        if self.spec_env.residual_velocity_range > 0:
            target = np.concatenate([target, np.zeros(self.velocity_size)])
        return self.normalize_action(self.policy_part(target)).astype(np.float32)

    def physical_action(self, action: np.ndarray) -> np.ndarray:
        """The controller's action (rad, quaternion components, rad/s) for a policy action (one, or
        rows): the same values, or with ``normalize_actions`` the affine map of [-1, 1] onto the box
        (-1 -> low, +1 -> high, exactly; values outside [-1, 1] are not clipped here: the targets are
        clipped to the joint limits as for physical actions); with ``policy_groups`` a zero
        correction on every other joint."""
        if self.spec_env.normalize_actions:
            action = self._action_center + self._action_half_range * action
        if self.policy_seen is None:
            return action
        full = np.zeros(np.shape(action)[:-1] + (self.layout.action_size,))
        full[..., self.policy_seen[0]] = action
        return full

    def normalize_action(self, action: np.ndarray) -> np.ndarray:
        """The inverse of :meth:`physical_action` on the values the policy acts on (the policy action
        giving a physical one; :meth:`policy_part` picks them from every joint's)."""
        if not self.spec_env.normalize_actions:
            return action
        return (np.asarray(action, dtype=np.float64) - self._action_center) / self._action_half_range

    @contextmanager
    def thesis_pd(self):
        """Within the block a controller with target options (reference velocity, physics rate)
        is replaced by the body's default controller (its ``conf/body`` file's: the thesis gains, held
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
            spec = self.setup.thesis_controller()
            if not spec.is_thesis_pd:
                raise ValueError(f"default controller {spec.name!r} has target options; baselines need a plain one")
            self._default_controller = self.setup.pd_controller(spec)
            self._default_controller.check_body(self.sim)
        previous = self._thesis_pd, self.controller
        self._thesis_pd, self.controller = True, self._default_controller
        try:
            yield self
        finally:
            self._thesis_pd, self.controller = previous

    def target_rule(self) -> mdp.TargetRule:
        """How this env's physical actions become PD targets now (within thesis_pd(): the plain controller's)."""
        plain = self._thesis_pd
        if plain not in self._target_rules:
            self._target_rules[plain] = mdp.TargetRule.of(self.spec_env, self.controller_spec, self.joint_lower,
                                                          self.joint_upper, self.layout.action_size, plain)
        return self._target_rules[plain]

    def _drive(self, action: np.ndarray) -> None:
        """Set the motors from the action and step the physics through one control step."""
        rule = self.target_rule()
        base = None
        if rule.residual and not rule.physics_rate:
            self._filter_state, base = self._residual_base()
        for targets, velocities, steps in mdp.pd_targets(rule, action[None], np.array([self.time]), self.reference,
                                                         base):
            self.controller.drive(self.sim, targets[0], None if velocities is None else velocities[0], steps)

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
        joints = [a[None] for a in self.sim.joint_state()] if self.spec_env.reads_joints else None
        return observe(self.spec_env, self.reference, np.asarray([self.time]), links[None], root_pos[None],
                       root_rot[None], joints, self.policy_seen)[0]

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
        if action.shape[0] != size:
            raise ValueError(f"action has {action.shape[0]} values, expected {size}")
        finite = mdp.finite_actions(action[None])
        if not finite[0]:  # a NaN action ends the episode (flagged, counted); the physics is never fed it
            mdp.count_ends(self.counters, self._ends(finite, [False], 0.0, False))
            links = self.sim.link_states(links=self._state_links)
            return self._observation(links), 0.0, True, False, {"nan_action": True, "diverged": False}

        self._drive(self.physical_action(action))
        self.time += self.control_dt
        self.steps += 1

        links = self.sim.link_states(links=self._state_links)
        sim_state = self._sim_snapshot(links)
        # An engine that clamps joint speeds after each step reports the speed before its clamp
        # (peak_speed), which a simulation that blew up sends far past max_joint_velocity (or to NaN).
        speed = mdp.joint_speeds(sim_state.qd[None], getattr(self.sim, "peak_speed", 0.0))
        if mdp.diverged(links[None], sim_state.qd[None], speed, self.spec_env.max_joint_velocity)[0]:
            mdp.count_ends(self.counters, self._ends(finite, [True], 0.0, False))
            obs = np.nan_to_num(self._observation(links), nan=0.0, posinf=0.0, neginf=0.0)
            return obs, 0.0, True, False, {"nan_action": False, "diverged": True,
                                           "divergence": self._divergence(sim_state.qd, float(speed[0]))}

        ref_state = self._reference_snapshot(self.time)
        self.last_sim_state, self.last_reference_state = sim_state, ref_state  # what the reward compared
        reward, terms, errors = self.reward_fn(sim_state, ref_state)
        fell = self.termination.fall and self.fallen()
        ends = self._ends(finite, [False], reward, fell)
        self._steps_below = int(ends.below[0])
        mdp.count_ends(self.counters, ends)
        early, truncated = bool(ends.early[0]), bool(ends.truncated[0])
        info = {"nan_action": False, "diverged": False, "early_termination": early, "fall": fell,
                **{f"r_{k}": v for k, v in terms.items()}, **{f"e_{k}": v for k, v in errors.items()},
                **{f"score_{name}": fn(sim_state, ref_state)[0] for name, fn in self.score_fns.items()}}
        factor = None
        if self.shapes_drift:
            factor = mdp.drift(sim_state.root_pos[None], sim_state.root_rot[None], ref_state.root_pos[None],
                               ref_state.root_rot[None], self.spec_env.heading_shaping, self.spec_env.offset_shaping)
            info["r_drift"] = float(factor[0])  # logged as train_drift; train_reward stays unshaped
        mdp.add_term_sums(self._term_sums, ends.scored, np.array([reward]),
                          {k: np.array([v]) for k, v in terms.items()}, factor)
        if factor is not None:
            reward *= info["r_drift"]
        return self._observation(links), reward, early, truncated, info

    @property
    def shapes_drift(self) -> bool:
        """A training env whose reward carries the drift shaping (``heading_shaping``, ``offset_shaping``)."""
        return self.shape_reward and (self.spec_env.heading_shaping > 0 or self.spec_env.offset_shaping > 0)

    def _ends(self, finite: np.ndarray, diverged: list[bool], reward: float, fell: bool) -> mdp.Ends:
        """How this step ended (:func:`aslexp.envs.mdp.episode_ends`, a row of one)."""
        return mdp.episode_ends(self.termination, finite, np.asarray(diverged), np.array([reward]),
                                np.array([self._steps_below]), np.array([fell]), np.array([self.steps]))

    def _divergence(self, qd: np.ndarray, speed: float) -> dict[str, Any]:
        """Where a blow-up showed: the fastest joint (before any engine's clamp; a NaN counts as the
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
        """Reference (left) and simulation (right) side by side, as the engine renders them."""
        if self.render_mode != "rgb_array":
            return None
        return self.simulation.render({**DEFAULT_CAMERA, **(self.spec_env.camera or {})}, self.render_size)

    @property
    def sim_world(self):
        """The simulated character's world (an engine's own object: engine-specific tests reach it)."""
        return self.sim.world

    @property
    def ref_world(self):
        return self.ref.world

    def close(self) -> None:
        self.simulation.close()
