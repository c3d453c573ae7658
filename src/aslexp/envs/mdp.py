"""The imitation MDP written once for N rows: actions to PD targets, the residual base, divergence,
episode ends, drift shaping and the observation, as functions of plain numpy arrays of N rows.

:class:`~aslexp.envs.imitation.ImitationEnv` calls them with arrays of one row,
:class:`~aslexp.envs.batched.BatchedImitationEnv` with one row per environment: what an episode is, is
written here alone, and the two environments only read their engines and keep their counters.
Every function is pure except :func:`count_ends` and :func:`add_term_sums`, which add into the
dictionaries they are given. The order of one control step (module docstring of
:mod:`aslexp.envs.imitation`):

1. :func:`residual_base` (``action_mode: residual``: the reference ``reference_lookahead`` steps ahead,
   or its low-pass filter), then :func:`pd_targets`: the targets and velocity targets the motors hold,
   and for how many physics steps each;
2. the engine steps; :func:`joint_speeds` and :func:`diverged` read what came back;
3. the reward (``ImitationReward.many``), :func:`episode_ends` (NaN actions, divergence,
   ``early_termination``, truncation), :func:`count_ends`, :func:`add_term_sums`, and for a training
   env :func:`drift` (``heading_shaping``, ``offset_shaping``);
4. :func:`observe`.

A ``reference`` argument is anything with ReferenceMotion's ``*_many`` methods: one motion, or a
:class:`~aslexp.sim.reference.ReferencePool`'s rows (a motion per row).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from aslexp import quaternion
from aslexp.envs.spec import UP_AXIS, EnvSpec
from aslexp.sim.pd import ControllerSpec


# -- actions -> PD targets -------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class TargetRule:
    """How physical actions become PD targets: the env's and controller's settings as plain values."""

    residual: bool  # action_mode residual: the position part is a correction added to a base
    action_size: int  # values of the position part; the rest are velocity-target corrections
    lower: np.ndarray  # the joint limits the targets are clipped to (joint-value layout)
    upper: np.ndarray
    control_dt: float
    substeps: int  # physics steps per control step
    lookahead: int  # reference_lookahead: control steps ahead the base is read
    physics_rate: bool  # target_rate physics: the reference re-sampled at the end of every physics step
    velocity_scale: float | None  # target_velocity reference: the reference velocity's scale; None: zero

    @classmethod
    def of(cls, env: EnvSpec, controller: ControllerSpec, lower: np.ndarray, upper: np.ndarray, action_size: int,
           plain: bool = False) -> "TargetRule":
        """The rule of an env spec and a controller spec (``plain``: the thesis' controller stands in,
        ``thesis_pd()``: no target options)."""
        plain = plain or controller.is_thesis_pd
        return cls(residual=env.action_mode == "residual", action_size=int(action_size), lower=lower, upper=upper,
                   control_dt=1.0 / env.control_hz, substeps=env.substeps, lookahead=int(env.reference_lookahead),
                   physics_rate=controller.target_rate == "physics" and not plain,
                   velocity_scale=(float(controller.velocity_scale)
                                   if controller.target_velocity == "reference" and not plain else None))

    def base_times(self, times: np.ndarray) -> np.ndarray:
        """(N,) the times the residual base is read at: ``reference_lookahead`` control steps ahead."""
        return times + self.lookahead * self.control_dt


@dataclass(frozen=True, eq=False)
class BaseSmoothing:
    """``residual_base_smoothing``: the filter's ``alpha``, the joint values it filters, and the box of
    corrections (position part) the filtered base stays within around the reference."""

    alpha: float
    values: np.ndarray  # indices into a joint-value vector
    low: np.ndarray
    high: np.ndarray


def residual_base(reference: np.ndarray, previous: np.ndarray | None, restart: np.ndarray,
                  smoothing: BaseSmoothing | None) -> tuple[np.ndarray | None, np.ndarray]:
    """(the filter's new state, the base) of N rows: the reference targets ``reference`` (N, size)
    themselves, or with ``smoothing`` base_t = alpha base_(t-1) + (1 - alpha) reference on the chosen
    values, from the filter state ``previous`` (N, size; None: none yet). Rows of ``restart`` (N,) start
    the filter over (an episode's first step). The base is held within the correction box around the
    reference, as smoothed_reference_policy's clipped action holds it: a zero correction then drives
    exactly that baseline."""
    if smoothing is None:
        return None, reference
    filtered = reference.copy()
    if previous is not None:
        rows = np.flatnonzero(~np.asarray(restart, dtype=bool))
        if len(rows):
            cells = np.ix_(rows, smoothing.values)
            filtered[cells] = smoothing.alpha * previous[cells] + (1.0 - smoothing.alpha) * reference[cells]
    return filtered, reference + np.clip(filtered - reference, smoothing.low, smoothing.high)


def velocity_targets(reference_velocities: np.ndarray | None, scale: float | None,
                     corrections: np.ndarray) -> np.ndarray | None:
    """(N, velocity size) motor velocity targets, or None (zero): the reference velocities times
    ``scale`` (None: not fed), plus the policy's velocity-target corrections (N, 0 when it has none)."""
    velocity = scale * reference_velocities if scale is not None else None
    if corrections.shape[1]:
        velocity = corrections if velocity is None else velocity + corrections
    return velocity


def pd_targets(rule: TargetRule, physical: np.ndarray, times: np.ndarray, reference,
               base: np.ndarray | None = None) -> list[tuple[np.ndarray, np.ndarray | None, int]]:
    """What the motors hold through one control step from ``times`` (N,): a list of (targets (N, size)
    clipped to the joint limits, velocity targets or None, physics steps). ``physical`` (N, action):
    the policy's actions in the controller's units. Absolute targets, or corrections added to ``base``
    (:func:`residual_base`, at control rate) held for the whole step; with ``rule.physics_rate`` one
    hold per physics step, the correction added to the reference at its end."""
    positions, corrections = physical[:, :rule.action_size], physical[:, rule.action_size:]

    def velocities(t: np.ndarray) -> np.ndarray | None:
        fed = reference.joint_velocities_many(t) if rule.velocity_scale is not None else None
        return velocity_targets(fed, rule.velocity_scale, corrections)

    if rule.physics_rate:
        substep = rule.control_dt / rule.substeps
        holds = []
        for i in range(rule.substeps):
            t = times + (i + 1) * substep
            targets = np.clip(reference.joints_many(t) + positions, rule.lower, rule.upper)
            holds.append((targets, velocities(t), 1))
        return holds
    if rule.residual:
        if base is None:
            raise ValueError("pd_targets: action_mode residual at control rate needs the residual base")
        positions = base + positions
    targets = np.clip(positions, rule.lower, rule.upper)
    return [(targets, velocities(rule.base_times(times)), rule.substeps)]


# -- divergence -----------------------------------------------------------------------------------------
def finite_actions(actions: np.ndarray) -> np.ndarray:
    """(N,) rows whose every value is finite (a NaN action ends its episode; the physics never sees it)."""
    return np.all(np.isfinite(actions), axis=1)


def joint_speeds(qd: np.ndarray, peak: np.ndarray | float) -> np.ndarray:
    """(N,) each row's fastest joint speed: of the joint velocities ``qd`` (N, dofs) and of the engine's
    speed before its joint-speed clamp (``peak``, N or one value; 0 for an engine that does not clamp).
    A NaN stays NaN."""
    return np.maximum(np.max(np.abs(qd), axis=1), peak)


def diverged(state: np.ndarray, qd: np.ndarray, speed: np.ndarray, max_joint_velocity: float) -> np.ndarray:
    """(N,) rows whose simulation blew up: a non-finite value in ``state`` (N, ...: the link states read)
    or ``qd``, or a joint faster than ``max_joint_velocity`` (``speed``: :func:`joint_speeds`; a NaN
    speed compares False, so it counts)."""
    finite = np.isfinite(state.reshape(len(qd), -1)).all(axis=1) & np.isfinite(qd).all(axis=1)
    return ~(finite & (speed <= max_joint_velocity))


# -- episode ends ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Termination:
    """``early_termination`` and ``episode_steps`` as plain values."""

    min_reward: float | None
    patience: int
    fall: bool
    episode_steps: int

    @classmethod
    def of(cls, env: EnvSpec) -> "Termination":
        ending = env.early_termination or {}
        min_reward = ending.get("min_reward")
        return cls(None if min_reward is None else float(min_reward), int(ending.get("patience", 1)),
                   bool(ending.get("fall")), int(env.episode_steps))


@dataclass(frozen=True, eq=False)
class Ends:
    """How each of N steps ended (all (N,) arrays)."""

    nan_action: np.ndarray  # a non-finite action: the row was not stepped
    diverged: np.ndarray
    scored: np.ndarray  # stepped and not diverged: its reward counts
    fell: np.ndarray  # a forbidden ground contact (scored rows)
    early: np.ndarray  # early_termination: a fall, or patience steps below min_reward
    terminated: np.ndarray  # nan_action | diverged | early
    truncated: np.ndarray  # episode_steps reached, not terminated
    below: np.ndarray  # consecutive steps below min_reward, this one included (the new count)


def episode_ends(rule: Termination, finite: np.ndarray, diverged_rows: np.ndarray, reward: np.ndarray,
                 below: np.ndarray, fell: np.ndarray, steps: np.ndarray) -> Ends:
    """The ends of N steps, all (N,) arrays: ``finite`` (:func:`finite_actions`), ``diverged_rows``
    (:func:`diverged`), the step rewards, the count of steps below ``min_reward`` before this one, the
    rows that fell and the steps taken in each episode (this one included)."""
    scored = finite & ~diverged_rows
    if rule.min_reward is not None:
        below = np.where(scored & (reward < rule.min_reward), below + 1, 0)
        early = below >= rule.patience
    else:
        below, early = np.zeros(len(scored), dtype=np.int64), False
    fell = scored & fell if rule.fall else np.zeros(len(scored), dtype=bool)
    early = scored & (early | fell)
    terminated = ~scored | early
    return Ends(nan_action=~finite, diverged=finite & diverged_rows, scored=scored, fell=fell, early=early,
                terminated=terminated, truncated=~terminated & (steps >= rule.episode_steps), below=below)


END_COUNTERS = ("nan_actions", "diverged", "early_terminations", "falls")


def count_ends(counters: dict[str, int], ends: Ends) -> None:
    """Add the ends to the env's counters (:data:`END_COUNTERS`). A counter is created by its first end
    (``falls``, a kind of early end, with the first early end); a batch, which logs every counter from
    its first row, creates them at 0."""
    early = np.count_nonzero(ends.early)
    for name, count in (("nan_actions", np.count_nonzero(ends.nan_action)),
                        ("diverged", np.count_nonzero(ends.diverged)), ("early_terminations", early)):
        if count:
            counters[name] += int(count)
    if early:
        counters["falls"] += int(np.count_nonzero(ends.fell))


def add_term_sums(sums: dict[str, float], rows: np.ndarray, reward: np.ndarray,
                  terms: dict[str, np.ndarray], drift_factors: np.ndarray | None = None) -> None:
    """Add the scored ``rows`` (N,) rewards, per-term rewards and (a training env's) drift factors to
    the running sums the training logs read (``pop_term_means``; ``reward`` is the unshaped one)."""
    for name, values in terms.items():
        sums[name] += float(values[rows].sum())
    sums["reward"] += float(reward[rows].sum())
    sums["steps"] += int(rows.sum())
    if drift_factors is not None:
        sums["drift"] += float(drift_factors[rows].sum())


# -- drift shaping of the training reward ---------------------------------------------------------------
def drift(sim_root_pos: np.ndarray, sim_root_rot: np.ndarray, ref_root_pos: np.ndarray, ref_root_rot: np.ndarray,
          heading_shaping: float, offset_shaping: float) -> np.ndarray:
    """(N,) exp(-heading_shaping yaw^2 - offset_shaping |d|^2): yaw the turn (rad) of each simulated root
    against its reference about the up axis, d its horizontal offset (m). A training env's reward is
    the step reward times this (``env.heading_shaping``, ``env.offset_shaping``)."""
    relative = quaternion.multiply(quaternion.conjugate(ref_root_rot), np.asarray(sim_root_rot, dtype=np.float64))
    turn = 2.0 * np.arctan2(relative[..., 1 + UP_AXIS], relative[..., 0])
    yaw = (turn + np.pi) % (2.0 * np.pi) - np.pi  # in [-pi, pi), as quaternion.twist_angle
    offset = np.delete(sim_root_pos - ref_root_pos, UP_AXIS, axis=-1)
    return np.exp(-heading_shaping * yaw * yaw - offset_shaping * np.sum(offset * offset, axis=-1))


# -- the observation ------------------------------------------------------------------------------------
def heading_rotation(root_rot: np.ndarray) -> np.ndarray:
    """The root's rotation about the up axis alone (its heading), as DeepMimic's state frame: the
    root's x axis projected on the ground plane gives the heading angle. (..., 4) -> (..., 4)."""
    forward = quaternion.rotate(root_rot, np.array([1.0, 0.0, 0.0]))
    heading = np.arctan2(-forward[..., 2], forward[..., 0])  # about +y (y up)
    zero = np.zeros_like(heading)
    return np.stack([np.cos(heading / 2), zero, np.sin(heading / 2), zero], axis=-1)


def observe(spec: EnvSpec, reference, times: np.ndarray, links: np.ndarray, root_pos: np.ndarray,
            root_rot: np.ndarray, joints: tuple[np.ndarray, np.ndarray] | None = None,
            seen: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The observations (N, size) of N bodies (:mod:`aslexp.envs.imitation`'s docstring): ``times`` (N,)
    on ``reference``, the observed links' world states (N, L, 13), the roots' positions (N, 3) and
    rotations (N, 4), with ``spec.reads_joints`` the joint positions and velocities (N, ...).
    ``seen`` (``env.policy_groups``): the joint values and velocities of the reference frames ahead
    and the joint state that are observed (indices); None: all."""
    values, speeds = seen if seen is not None else (slice(None), slice(None))
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
    parts = [reference.phase_many(times)[:, None]] if spec.observe_phase else []
    if deepmimic:  # phase, root height, then all poses, then all velocities (DeepMimic's order)
        parts += [root_pos[:, UP_AXIS:UP_AXIS + 1], local[..., 0:7].reshape(n, -1), local[..., 7:13].reshape(n, -1)]
    else:
        parts.append(local.reshape(n, -1))
    control_dt = 1.0 / spec.control_hz
    for k in spec.observe_future:
        ahead = reference.joints_many(times + k * control_dt)
        parts.append((ahead - joints[0] if spec.observe_future_as == "error" else ahead)[:, values])
    if spec.observe_future_velocities:
        for k in spec.observe_future:
            parts.append(reference.joint_velocities_many(times + k * control_dt)[:, speeds])
    if spec.observe_joints:
        parts += [joints[0][:, values], joints[1][:, speeds]]
    if spec.observe_reference_root:
        ref_pos, ref_rot, _, _ = reference.root_many(times)
        ref_local = quaternion.multiply(quaternion.conjugate(frame), ref_rot)
        parts += [quaternion.rotate(quaternion.conjugate(frame), ref_pos - root_pos),
                  np.where(ref_local[:, :1] < 0, -ref_local, ref_local)]
    return np.concatenate(parts, axis=1).astype(np.float32)
