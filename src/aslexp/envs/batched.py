"""N imitation environments of one body, stepped together: a gymnasium vector environment.

``BatchedImitationEnv(num_envs, motion, ..., engine=...)`` is what ``N`` copies of
:class:`~aslexp.envs.imitation.ImitationEnv` on an engine that batches
(its :class:`~aslexp.sim.engine.BatchedBody`) would be, with
no Python per environment in a step: the physics of all N advances in one call (C threads), the
link states of the N bodies and of their N references come back from one more, and the MDP (PD
targets and the residual base, divergence, episode ends, drift shaping, the observation:
:mod:`aslexp.envs.mdp`) and the reward (``ImitationReward.many``) are computed on arrays of N by the
same functions the single environment calls with a batch of one. Same seeds and actions give the
same transitions as N single environments (tested step for step).

Vector-environment conventions as :mod:`aslexp.rl.vector`'s: same-step autoreset (an episode's
last observation in ``info["final_obs"]``, the returned one starts the next), reset seeds per
environment, and the running statistics PPO reads (``call("term_means")``,
``call("counter_values")``). Every option of the single environment runs here: the tracking PD's
(physics-rate targets, velocity-target corrections), a fall of a free-base body
(``early_termination.fall``: the engine's ground contacts read row by row, the row's episode ended
early and counted in ``falls``; ``info["fall"]`` says which rows fell), and the training options of
the upper body's free-base residual work (``residual_base_smoothing``, a filter state per row
restarted with each row's episode; drift shaping with ``shape_reward``). The single environment's
``thesis_pd()`` (its baselines) has no batched form: a batch drives its own controller.

Many motions (``motions=[...]``): each row imitates one motion of the pool, drawn from the row's
random stream at every episode start (or named: ``options={"clip": k}``; or the same in every
episode: ``pin_clips``); its targets, reward, reference root and observation (the reference frames
ahead it sees, ``env.observe_future``) are that motion's (:class:`~aslexp.sim.reference.ReferencePool`). The motion the setup names gives
the spaces only. ``clip`` holds each row's motion index, ``clip_episodes`` the episodes per motion.
"""

from __future__ import annotations

import os
from collections import defaultdict
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from aslexp.envs import mdp
from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.imitation import ImitationEnv
from aslexp.envs.reward import PoseSnapshot
from aslexp.sim.engine import batching_engines
from aslexp.sim.motion import Motion
from aslexp.sim.reference import ReferenceMotion, ReferencePool


class BatchedImitationEnv(VectorEnv):
    """``num_envs`` imitation environments of one motion and body on an engine that batches."""

    metadata = {"autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs: int, motion, body=None, controller=None, reward=None, env=None,
                 engine: str | dict | None = None, data_root: str | os.PathLike | None = None,
                 complete_configs: bool = False, shape_reward: bool = False,
                 env_class: type[ImitationEnv] = ImitationEnv, threads: int | None = None,
                 motions: list[Motion | str | os.PathLike] | None = None) -> None:
        """The arguments of :class:`ImitationEnv` (``env_class``: its subclass whose group defaults
        apply, e.g. the upper body's), for ``num_envs`` environments (``engine`` None: the first engine
        that batches); ``threads`` overrides ``engine.threads`` (rollout workers step their batch on
        one thread each); ``motions``: a pool of motions of the body, one per row and episode (module
        docstring)."""
        if engine is None:
            engine = batching_engines()[0]
        setup = ImitationSetup.from_groups(motion, body, controller, reward, env, engine, data_root=data_root,
                                           complete=complete_configs, defaults=env_class.GROUP_DEFAULTS)
        self._assemble(num_envs, setup, shape_reward, threads, env_class, motions)

    @classmethod
    def from_setup(cls, num_envs: int, setup: ImitationSetup, shape_reward: bool = False, threads: int | None = None,
                   env_class: type[ImitationEnv] = ImitationEnv,
                   motions: list[Motion | str | os.PathLike] | None = None) -> "BatchedImitationEnv":
        """``num_envs`` environments of an assembled experiment (:mod:`aslexp.envs.assembly`)."""
        batch = cls.__new__(cls)
        batch._assemble(num_envs, setup, shape_reward, threads, env_class, motions)
        return batch

    def _assemble(self, num_envs: int, setup: ImitationSetup, shape_reward: bool, threads: int | None,
                  env_class: type[ImitationEnv], motions: list[Motion | str | os.PathLike] | None = None) -> None:
        if isinstance(num_envs, bool) or not isinstance(num_envs, (int, np.integer)) or num_envs < 1:
            raise ValueError(f"ppo config: num_envs must be an integer >= 1, got {num_envs!r}")
        # One single environment holds the configuration (specs, spaces, reference, reward, model).
        self.template = env_class.from_setup(setup, shape_reward=shape_reward)
        t = self.template
        if t.simulation.batch is None:
            raise ValueError(f"ppo config: vector_env batched needs an engine that steps many environments at "
                             f"once; the engine is {t.engine_spec.name!r} (one that batches: "
                             f"{batching_engines()}; or vector_env auto/sync/async/workers)")
        self.num_envs = int(num_envs)
        self.spec_env, self.reference, self.layout = t.spec_env, t.reference, t.layout
        self.pool = ReferencePool([t.reference] if not motions else
                                  [ReferenceMotion(setup.load_motion(m), t.layout) for m in motions])
        self.body = t.simulation.batch
        if threads is not None:
            self.body.set_threads(int(threads))
        self.body.set_gains(t.controller)
        self.reward_fn = t.reward_fn
        self.single_observation_space = t.observation_space
        self.single_action_space = t.action_space
        self.observation_space = batch_space(t.observation_space, self.num_envs)
        self.action_space = batch_space(t.action_space, self.num_envs)
        self.control_dt = t.control_dt
        self.substeps = self.spec_env.substeps
        self.observed = t.observed_links
        self.target_rule = t.target_rule()  # the env's own controller: a batch has no thesis_pd()
        self.termination, self.shapes_drift = t.termination, t.shapes_drift
        n = self.num_envs
        self.states = self.body.new_states(n)
        self.ref_states = self.body.new_states(n)
        self.time = np.zeros(n)
        self.steps = np.zeros(n, dtype=np.int64)
        self._below = np.zeros(n, dtype=np.int64)
        self._filter_state: np.ndarray | None = None  # residual_base_smoothing: each row's filtered base
        self._rngs = [np.random.default_rng() for _ in range(n)]
        self.clip = np.zeros(n, dtype=np.int64)
        self._pinned: np.ndarray | None = None  # pin_clips(): each row's motion for every episode
        self.clip_episodes = np.zeros(len(self.pool), dtype=np.int64)  # episodes started per pool motion
        # The reference's end effectors are read with its root where the single environment's
        # kinematic reference stands: each row's motion's first root pose.
        self._clip_roots = [r.root(0.0)[:2] for r in self.pool.references]
        self._ref_root = tuple(np.array(np.broadcast_to(v, (n, len(v)))) for v in self._clip_roots[0])
        self.counters: dict[str, int] = defaultdict(int, {name: 0 for name in mdp.END_COUNTERS})
        self._term_sums: dict[str, float] = defaultdict(float)
        # A fall (early_termination.fall, free base): a link other than the body's ground_contacts
        # touching the ground, read per row from the engine's contacts (as the single environment).
        self._fall_check = self.termination.fall and t.body_spec.base == "free" and t.ground is not None
        self._allowed_contacts = set(t._allowed_contacts)

    # -- episodes -------------------------------------------------------------------------------------
    def reset(self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None):
        """Start every environment's episode (``seed``: one per environment, or one for the first
        and the next integers for the others, as gymnasium's vector environments; options as
        :meth:`ImitationEnv.reset`)."""
        if seed is not None:
            seeds = list(seed) if isinstance(seed, (list, tuple, np.ndarray)) else [seed + i for i in range(self.num_envs)]
            if len(seeds) != self.num_envs:
                raise ValueError(f"reset: {len(seeds)} seeds for {self.num_envs} environments")
            self._rngs = [gym.utils.seeding.np_random(int(s))[0] for s in seeds]
        self._start(np.arange(self.num_envs), options or {})
        return self._observe(slice(None), self._read(slice(None))[0]), {}

    def _start(self, rows: np.ndarray, options: dict[str, Any]) -> None:
        """Start new episodes in the environments ``rows`` (a motion of the pool each, then reference
        state initialisation)."""
        if "clip" in options:
            clips = np.broadcast_to(np.asarray(options["clip"], dtype=np.int64), (len(rows),))
            if clips.min(initial=0) < 0 or clips.max(initial=0) >= len(self.pool):
                raise ValueError(f"reset: clip {options['clip']} for a pool of {len(self.pool)} motions")
            self.clip[rows] = clips
        elif self._pinned is not None:  # drawn from no stream: a pinned row's stream stays a single env's
            self.clip[rows] = self._pinned[rows]
        elif len(self.pool) > 1:  # a pool of one draws nothing: its rows' streams stay a single env's
            self.clip[rows] = [int(self._rngs[i].integers(len(self.pool))) for i in rows]
        durations = self.pool.durations[self.clip[rows]]
        if "time" in options:
            times = np.full(len(rows), float(options["time"]))
        elif "phase" in options:  # one phase for every row, or one per row
            times = np.broadcast_to(np.asarray(options["phase"], dtype=np.float64), (len(rows),)) * durations
        elif self.spec_env.reference_state_init:
            times = np.asarray([float(self._rngs[i].uniform(0.0, d)) for i, d in zip(rows, durations)])
        else:
            times = np.zeros(len(rows))
        self.time[rows], self.steps[rows], self._below[rows] = times, 0, 0
        reference = self._rows(rows)
        q, qd = reference.joints_many(times), reference.joint_velocities_many(times)
        fresh = self.body.new_states(len(rows))
        self.body.write(fresh, slice(None), q, qd, *reference.root_many(times))
        self.states[rows] = fresh
        if len(self.pool) > 1:
            for c, k in zip(*np.unique(self.clip[rows], return_counts=True)):
                chosen = rows[self.clip[rows] == c]
                self._ref_root[0][chosen], self._ref_root[1][chosen] = self._clip_roots[c]
                self.clip_episodes[c] += int(k)
        self.counters["episodes"] += len(rows)

    def pin_clips(self, clips) -> None:
        """Row ``i`` imitates pool motion ``clips[i]`` in every episode from the next reset on (many
        runs in one batch, each its own motion: :mod:`aslexp.rl.stacked`)."""
        clips = np.asarray(clips, dtype=np.int64)
        if clips.shape != (self.num_envs,) or clips.min(initial=0) < 0 or clips.max(initial=0) >= len(self.pool):
            raise ValueError(f"pin_clips: {clips.tolist()} for {self.num_envs} rows and a pool of {len(self.pool)} "
                             f"motions (one index in [0, {len(self.pool)}) per row)")
        self._pinned = clips

    def _rows(self, rows) -> ReferenceMotion:
        """The references the environments ``rows`` imitate (one motion: that motion's)."""
        return self.pool.select(self.clip[rows])

    def restart_from(self, state: np.ndarray, time: float) -> None:
        """Every environment continues from one physics ``state`` (a row of this body's state array)
        at reference time ``time``, its episode counters cleared: the rollouts a planner compares."""
        self.states[:] = state
        self.time[:] = time
        self.steps[:] = 0
        self._below[:] = 0

    # -- one step of every environment ----------------------------------------------------------------
    def step(self, actions):
        actions = np.asarray(actions, dtype=np.float64).reshape(self.num_envs, -1)
        size = self.single_action_space.shape[0]
        if actions.shape[1] != size:
            raise ValueError(f"actions have {actions.shape[1]} values per environment, expected {size}")
        n, all_rows = self.num_envs, np.arange(self.num_envs)
        finite = mdp.finite_actions(actions)
        nan_rows = np.flatnonzero(~finite)
        nan_obs = self._observe(nan_rows, self._read(nan_rows)[0]) if len(nan_rows) else None
        # a NaN row steps with a zero action (the physics never sees the NaN); its episode ends below
        physical = self.template.physical_action(actions if len(nan_rows) == 0 else np.where(finite[:, None], actions, 0.0))
        rule, reference = self.target_rule, self._rows(all_rows)
        base = None
        if rule.residual and not rule.physics_rate:
            self._filter_state, base = mdp.residual_base(
                reference.joints_many(rule.base_times(self.time)), self._filter_state, self.steps == 0,
                self.template.base_smoothing)  # a row's filter restarts with its episode
        peak = np.zeros(n)  # the fastest joint over the step's physics, before the engine's speed clamp
        for targets, velocities, steps in mdp.pd_targets(rule, physical, self.time, reference, base):
            self.body.step(self.states, self.body.controls(targets, velocities), steps)
            peak = np.maximum(peak, self.body.peak_speeds)
        self.time += self.control_dt
        self.steps += 1

        ref_q, ref_qd, *ref_root = reference.state_many(self.time)
        sim_frames, sim_tips, ref_tips = self._read(slice(None), reference=ref_q)
        q, qd = self.body.joints(self.states)
        diverged = mdp.diverged(sim_frames, qd, mdp.joint_speeds(qd, peak), self.spec_env.max_joint_velocity)
        root = sim_frames[:, 0]
        sim = PoseSnapshot(q, qd, sim_tips, root[:, 0:3], root[:, 3:7], root[:, 7:10], root[:, 10:13])
        ref = PoseSnapshot(ref_q, ref_qd, ref_tips, *ref_root)
        reward, terms, _ = self.reward_fn.many(sim, ref)
        scored = finite & ~diverged
        fell = np.zeros(n, dtype=bool)
        if self._fall_check:
            for row in np.flatnonzero(scored):
                fell[row] = bool(self.body.contacts(self.states[row]) - self._allowed_contacts)
        ends = mdp.episode_ends(self.termination, finite, diverged, reward, self._below, fell, self.steps)
        self._below = ends.below
        mdp.count_ends(self.counters, ends)
        factor = None
        if self.shapes_drift:
            factor = mdp.drift(sim.root_pos, sim.root_rot, ref.root_pos, ref.root_rot,
                               self.spec_env.heading_shaping, self.spec_env.offset_shaping)
        mdp.add_term_sums(self._term_sums, ends.scored, reward, terms, factor)
        if factor is not None:
            reward = reward * factor  # the training reward; train_reward (the sums) stays unshaped
        reward = np.where(ends.scored, reward, 0.0)
        terminated, truncated = ends.terminated, ends.truncated

        obs = self._observe(slice(None), sim_frames, q, qd)
        if len(nan_rows):
            obs[nan_rows] = nan_obs
        if ends.diverged.any():
            obs[ends.diverged] = np.nan_to_num(obs[ends.diverged], nan=0.0, posinf=0.0, neginf=0.0)
        info: dict[str, Any] = {"fall": ends.fell, "_fall": ends.fell.copy()} if self._fall_check else {}
        if ends.diverged.any():  # which rows blew up (an evaluation's error, never its score)
            info.update({"diverged": ends.diverged.copy(), "_diverged": ends.diverged.copy()})
        ended = np.flatnonzero(terminated | truncated)
        if len(ended):  # same-step autoreset
            final = np.zeros_like(obs)
            final[ended] = obs[ended]
            info.update({"final_obs": final, "_final_obs": np.isin(all_rows, ended)})
            self._start(ended, {})
            obs[ended] = self._observe(ended, self._read(ended)[0])
        return obs, reward.astype(np.float64), terminated, truncated, info

    def _read(self, rows: np.ndarray, reference: np.ndarray | None = None):
        """Frames (root, links) and end-effector tips of the environments ``rows``; given the
        references' joint values ``reference`` (one row per environment of ``rows``), also their tips."""
        sensors = self.body.read(self.states[rows])
        frames, tips = self.body.frames(sensors), self.body.tips(sensors)
        if reference is None:
            return frames, tips
        self.body.write(self.ref_states, rows, reference, None, self._ref_root[0][rows], self._ref_root[1][rows])
        return frames, tips, self.body.tips(self.body.read(self.ref_states[rows], tips_only=True))

    def _observe(self, rows: np.ndarray, frames: np.ndarray, q: np.ndarray | None = None,
                 qd: np.ndarray | None = None) -> np.ndarray:
        links = frames[:, 1:][:, self.observed]
        joints = None
        if self.spec_env.reads_joints:
            if q is None:
                q, qd = self.body.joints(self.states[rows])
            joints = (q, qd)
        return mdp.observe(self.spec_env, self._rows(rows), self.time[rows], links, frames[:, 0, 0:3],
                           frames[:, 0, 3:7], joints, self.template.policy_seen)

    # -- what PPO reads ---------------------------------------------------------------------------------
    # Mean reward and per-term rewards over every environment's steps since the last call.
    pop_term_means = ImitationEnv.pop_term_means

    def call(self, name: str, *args, **kwargs) -> tuple:
        """``call("term_means")`` and ``call("counter_values")`` as :mod:`aslexp.rl.vector` reads
        them (one entry: the batch's), else the attribute of the batch."""
        if name == "term_means":
            return (self.pop_term_means(),)
        if name == "counter_values":
            return (dict(self.counters),)
        value = getattr(self, name)
        return (value(*args, **kwargs) if callable(value) else value,)

    def close_extras(self, **kwargs) -> None:
        self.template.close()

