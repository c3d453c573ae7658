"""DeepMimic-style imitation reward: error terms, each mapped to exp(-k e), combined by config.

    r = sum_x w_x exp(-k_x e_x)         (combine: sum, the thesis)
    r = prod_x exp(-k_x e_x) ** w_x     (combine: product, for later bodies)

Errors (``x``): ``pose`` = sum_j w_j angle_j^2 with angle_j the quaternion-difference angle of
joint j (for a revolute joint |q_sim - q_ref|); ``velocity`` = sum_j w_j |qd_sim - qd_ref|^2;
``end_effector`` = mean over end effectors of |p_sim - p_ref|^2 (world, metres); ``root`` =
c_p |dp|^2 + c_r angle^2 + c_v |dv|^2 + c_w |dw|^2 over the root's pose and velocities.

A term may be named freely when it says which ``error`` it uses and, for pose and velocity,
which joint ``groups`` it covers: the upper body's multiplicative reward (thesis 6.1-6.3)
``r = r_p * r_v * r_e * r_r`` splits r_p and r_v into body and hands this way
(``pose_body: {error: pose, groups: [chest, ...]}``, ``pose_hands: {error: pose, groups: [fingers]}``).
A pose or velocity term with ``root: true`` also counts the root as a joint, as the authors' code
(DeepMimic's) does: the root's rotation angle^2 is added to the pose error, its angular-velocity
error |dw|^2 to the velocity error.

Joint errors are summed (Eq. 5.10, the thesis and the authors' code) unless
``normalize_joint_weights`` makes them a weighted mean (aslexp's earlier upper-body default).

A new kind of error is a registration, not a patch: a function of the reward and the two snapshots
(arrays with a leading batch axis) returning one error per state, registered by name, and a term
that names it in a reward YAML, whose ``module`` key imports the registering module::

    @register_error("worst_tip")
    def worst_tip(reward, sim, ref):      # ImitationReward, PoseSnapshot (N, ...) x 2 -> (N,)
        return np.max(np.sum((sim.end_effectors - ref.end_effectors) ** 2, axis=-1), axis=-1)

    # conf/reward/my_reward.yaml
    module: my_package.my_errors
    terms: {pose: {weight: 0.5, scale: 2}, worst_tip: {weight: 0.5, scale: 40}}
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from aslexp.config_schema import Choice, Section, key
from aslexp.errors import ConfigError
from aslexp.sim.body import BodyLayout
from aslexp.quaternion import angle as quat_angle
from aslexp.plugins import import_modules, register_function

TERMS = ("pose", "velocity", "end_effector", "root")  # the built-in errors, computed together every step
COMBINE = ("sum", "product")
# Registered errors beyond the built-ins: name -> f(reward, sim, ref) -> (N,) errors.
_ERRORS: dict[str, Callable[..., np.ndarray]] = {}


def register_error(name: str, *, replace: bool = False):
    """Decorator: make ``f(reward, sim, ref) -> (N,)`` the error ``name`` a reward term may use."""
    return register_function(_ERRORS, "reward error", name, replace, built_in=TERMS)


def unregister_error(name: str) -> None:
    """Forget a registered error (tests register throwaway ones)."""
    _ERRORS.pop(name, None)


def error_names() -> tuple[str, ...]:
    return TERMS + tuple(_ERRORS)


@dataclass(frozen=True)
class TermSpec(Section):
    SECTION = "reward.terms"

    weight: float
    scale: float
    error: str | None = None  # which error (TERMS); None: the term's own name
    groups: tuple[str, ...] | None = None  # joint groups of a pose/velocity term; None: all
    root: bool = False  # pose/velocity term: the root counts as one more joint (the authors' code)

    def kind(self, name: str) -> str:
        return self.error or name


DEFAULT_ROOT_ERROR = {"position": 1.0, "rotation": 0.1, "velocity": 0.01, "angular_velocity": 0.001}


@dataclass(frozen=True)
class RewardSpec(Section):
    """``conf/reward/*.yaml`` as plain values (a term set to null by an override is off)."""

    SECTION = "reward"

    terms: dict[str, TermSpec] = field(default_factory=dict)
    combine: str = field(default="sum", metadata=key(Choice(*COMBINE)))
    joint_weights: dict[str, float] = field(default_factory=dict)
    # the keys given replace these (the rest stay)
    root_error: dict[str, float] = field(default_factory=lambda: dict(DEFAULT_ROOT_ERROR))
    # True: joint weights are normalised to sum to 1 over each pose/velocity term's joints (a
    # weighted mean, as DeepMimic's normalised joint weights); False: a weighted sum (the hand).
    normalize_joint_weights: bool = False
    # module(s) imported first: they register reward errors (register_error) the terms may name
    module: str | list[str] | None = None

    def __post_init__(self) -> None:
        import_modules(self.module)
        for name, term in self.terms.items():
            kind = term.kind(name)
            if kind not in TERMS and kind not in _ERRORS:
                raise ConfigError(f"terms.{name}: unknown term (error {kind!r}); known errors: "
                                  f"{', '.join(error_names())} (a registered one: reward.module names its module)")
            if (term.groups is not None or term.root) and kind not in ("pose", "velocity"):
                raise ConfigError(f"terms.{name}: `groups` and `root` apply to pose and velocity only")
        object.__setattr__(self, "root_error", {**DEFAULT_ROOT_ERROR, **self.root_error})


@dataclass
class PoseSnapshot:
    """What the reward compares, for the simulated or the reference character."""

    q: np.ndarray  # joint positions, motion layout (quaternions w x y z)
    qd: np.ndarray  # joint velocities (1 per revolute, 3 per spherical joint)
    end_effectors: np.ndarray  # (K, 3) world positions
    root_pos: np.ndarray
    root_rot: np.ndarray  # w x y z
    root_vel: np.ndarray
    root_ang_vel: np.ndarray


class ImitationReward:
    """Computes the error terms and the combined reward for one body layout."""

    def __init__(self, spec: RewardSpec, layout: BodyLayout) -> None:
        self.spec = spec
        self.layout = layout
        self.joint_weights = np.asarray([spec.joint_weights.get(j.group, 1.0) for j in layout.joints])
        # Index helpers: revolute joints compare values, spherical joints compare quaternions.
        rev_q, rev_v, sph_q, sph_v = [], [], [], []
        offset = voffset = 0
        for joint in layout.joints:
            if joint.dof == 1:
                rev_q.append(offset)
                rev_v.append(voffset)
                offset, voffset = offset + 1, voffset + 1
            else:
                sph_q.append(np.arange(offset, offset + 4))
                sph_v.append(np.arange(voffset, voffset + 3))
                offset, voffset = offset + 4, voffset + 3
        self._revolute = np.asarray([j.dof == 1 for j in layout.joints])
        self._revolute_q = np.asarray(rev_q, dtype=int)
        self._revolute_v = np.asarray(rev_v, dtype=int)
        self._spherical_q = np.asarray(sph_q, dtype=int).reshape(-1, 4)
        self._spherical_v = np.asarray(sph_v, dtype=int).reshape(-1, 3)
        # Per joint-weight mask of every grouped term (joint order: revolute first, then spherical).
        groups = [j.group for j in layout.joints]
        known = set(groups) | set(getattr(layout, "groups", ()))
        order = [i for i, r in enumerate(self._revolute) if r] + [i for i, r in enumerate(self._revolute) if not r]
        self._ordered_weights = self._normalized(self.joint_weights[order])
        self._term_weights: dict[str, np.ndarray] = {}
        for name, term in spec.terms.items():
            if term.groups is None:
                continue
            unknown = set(term.groups) - known
            if unknown:
                raise ValueError(f"reward term {name!r}: joint groups {sorted(unknown)} are not in the body "
                                 f"(groups: {sorted(known)})")
            mask = np.asarray([groups[i] in term.groups for i in order], dtype=float)
            self._term_weights[name] = self._normalized(self.joint_weights[order] * mask)

    def _normalized(self, weights: np.ndarray) -> np.ndarray:
        if not self.spec.normalize_joint_weights or weights.sum() <= 0:
            return weights
        return weights / weights.sum()

    def joint_errors(self, sim: PoseSnapshot, ref: PoseSnapshot) -> tuple[np.ndarray, np.ndarray]:
        """Squared pose and velocity error per joint (revolute joints first, then spherical); the
        snapshots' arrays may carry a leading batch axis (then so do the errors)."""
        dq = sim.q[..., self._revolute_q] - ref.q[..., self._revolute_q]
        dv = sim.qd[..., self._revolute_v] - ref.qd[..., self._revolute_v]
        if len(self._spherical_q) == 0:
            return dq * dq, dv * dv
        angle = quat_angle(sim.q[..., self._spherical_q], ref.q[..., self._spherical_q])
        sdv = sim.qd[..., self._spherical_v] - ref.qd[..., self._spherical_v]
        return (np.concatenate([dq * dq, angle * angle], axis=-1),
                np.concatenate([dv * dv, np.sum(sdv * sdv, axis=-1)], axis=-1))

    def errors_many(self, sim: PoseSnapshot, ref: PoseSnapshot) -> dict[str, np.ndarray]:
        """The error terms (see the module docstring) of N states at once: snapshots of (N, ...)
        arrays in, (N,) arrays out. The one implementation: :meth:`errors` is a batch of one."""
        pose_j, vel_j = self.joint_errors(sim, ref)
        pose = pose_j @ self._ordered_weights
        vel = vel_j @ self._ordered_weights
        n = pose.shape[0]
        if sim.end_effectors.shape[-2]:
            end = np.mean(np.sum((sim.end_effectors - ref.end_effectors) ** 2, axis=-1), axis=-1)
        else:
            end = np.zeros(n)
        c = self.spec.root_error
        root_angle = quat_angle(sim.root_rot, ref.root_rot)
        root_ang_err = np.sum((sim.root_ang_vel - ref.root_ang_vel) ** 2, axis=-1)
        root = (c["position"] * np.sum((sim.root_pos - ref.root_pos) ** 2, axis=-1)
                + c["rotation"] * root_angle * root_angle
                + c["velocity"] * np.sum((sim.root_vel - ref.root_vel) ** 2, axis=-1)
                + c["angular_velocity"] * root_ang_err)
        root_as_joint = {"pose": root_angle * root_angle, "velocity": root_ang_err}
        out = {"pose": pose, "velocity": vel, "end_effector": end, "root": root}
        for name, term in self.spec.terms.items():
            kind = term.kind(name)
            if kind not in out:  # a registered error, computed once per step whichever terms use it
                out[kind] = np.asarray(_ERRORS[kind](self, sim, ref), dtype=np.float64).reshape(n)
            if name in self._term_weights:
                per_joint = pose_j if kind == "pose" else vel_j
                out[name] = per_joint @ self._term_weights[name]
            if term.root:
                out[name] = out.get(name, out[kind]) + root_as_joint[kind]
        return out

    def combine_many(self, errors: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
        """Total reward (N,) and the per-term rewards exp(-k e) (before weighting) of N states."""
        terms = {name: np.exp(-t.scale * errors[name if name in errors else t.kind(name)])
                 for name, t in self.spec.terms.items()}
        if self.spec.combine == "sum":
            total = sum(self.spec.terms[name].weight * r for name, r in terms.items())
        else:
            total = math.prod(r ** self.spec.terms[name].weight for name, r in terms.items())
        if not terms:
            total = np.zeros_like(next(iter(errors.values())))
        return np.asarray(total, dtype=np.float64), terms

    def many(self, sim: PoseSnapshot, ref: PoseSnapshot) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, np.ndarray]]:
        """Reward, per-term rewards and errors of N states ((N, ...) snapshots)."""
        errors = self.errors_many(sim, ref)
        total, terms = self.combine_many(errors)
        return total, terms, errors

    def errors(self, sim: PoseSnapshot, ref: PoseSnapshot) -> dict[str, float]:
        """The error terms of one state (a batch of one through :meth:`errors_many`)."""
        return {k: float(v[0]) for k, v in self.errors_many(_one(sim), _one(ref)).items()}

    def combine(self, errors: dict[str, float]) -> tuple[float, dict[str, float]]:
        """Total reward and the per-term rewards exp(-k e) (before weighting) of one state."""
        total, terms = self.combine_many({k: np.asarray([v], dtype=np.float64) for k, v in errors.items()})
        return float(total[0]), {k: float(v[0]) for k, v in terms.items()}

    def __call__(self, sim: PoseSnapshot, ref: PoseSnapshot) -> tuple[float, dict[str, float], dict[str, float]]:
        total, terms, errors = self.many(_one(sim), _one(ref))
        return (float(total[0]), {k: float(v[0]) for k, v in terms.items()},
                {k: float(v[0]) for k, v in errors.items()})


def _one(snapshot: PoseSnapshot) -> PoseSnapshot:
    """A snapshot as a batch of one."""
    return PoseSnapshot(*(np.asarray(getattr(snapshot, f), dtype=np.float64)[None] for f in _SNAPSHOT_FIELDS))


_SNAPSHOT_FIELDS = tuple(f.name for f in dataclasses.fields(PoseSnapshot))
