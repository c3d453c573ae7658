"""DeepMimic-style imitation reward: error terms, each mapped to exp(-k e), combined by config.

    r = sum_x w_x exp(-k_x e_x)         (combine: sum, the thesis)
    r = prod_x exp(-k_x e_x) ** w_x     (combine: product, for later bodies)

Errors (``x``): ``pose`` = sum_j w_j angle_j^2 with angle_j the quaternion-difference angle of
joint j (for a revolute joint |q_sim - q_ref|); ``velocity`` = sum_j w_j |qd_sim - qd_ref|^2;
``end_effector`` = mean over end effectors of |p_sim - p_ref|^2 (world, metres); ``root`` =
c_p |dp|^2 + c_r angle^2 + c_v |dv|^2 + c_w |dw|^2 over the root's pose and velocities.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from aslexp.sim.body import BodyLayout
from aslexp.sim.world import quat_angle

TERMS = ("pose", "velocity", "end_effector", "root")
COMBINE = ("sum", "product")


@dataclass(frozen=True)
class TermSpec:
    weight: float
    scale: float


@dataclass(frozen=True)
class RewardSpec:
    """``conf/reward/*.yaml`` as plain values."""

    terms: dict[str, TermSpec]
    combine: str = "sum"
    joint_weights: dict[str, float] = field(default_factory=dict)
    root_error: dict[str, float] = field(default_factory=lambda: {
        "position": 1.0, "rotation": 0.1, "velocity": 0.01, "angular_velocity": 0.001})

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> "RewardSpec":
        unknown = set(values) - {"terms", "combine", "joint_weights", "root_error"}
        if unknown:
            raise ValueError(f"reward config: unknown keys {sorted(unknown)}")
        terms = {}
        for name, term in (values.get("terms") or {}).items():
            if name not in TERMS:
                raise ValueError(f"reward config: unknown term {name!r}; known terms: {TERMS}")
            terms[name] = TermSpec(float(term["weight"]), float(term["scale"]))
        combine = values.get("combine", "sum")
        if combine not in COMBINE:
            raise ValueError(f"reward config: combine must be one of {COMBINE}, got {combine!r}")
        spec = cls(terms=terms, combine=combine, joint_weights=dict(values.get("joint_weights") or {}))
        if values.get("root_error"):
            spec = cls(terms=terms, combine=combine, joint_weights=spec.joint_weights,
                       root_error={**spec.root_error, **values["root_error"]})
        return spec


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
        self._revolute_q, self._revolute_v, self._spherical_q, self._spherical_v = [], [], [], []
        self._revolute_w, self._spherical_w = [], []
        offset = voffset = 0
        for joint, weight in zip(layout.joints, self.joint_weights):
            if joint.dof == 1:
                self._revolute_q.append(offset)
                self._revolute_v.append(voffset)
                self._revolute_w.append(weight)
                offset, voffset = offset + 1, voffset + 1
            else:
                self._spherical_q.append(offset)
                self._spherical_v.append(voffset)
                self._spherical_w.append(weight)
                offset, voffset = offset + 4, voffset + 3
        self._revolute_q = np.asarray(self._revolute_q, dtype=int)
        self._revolute_v = np.asarray(self._revolute_v, dtype=int)
        self._revolute_w = np.asarray(self._revolute_w)
        self._spherical_w = np.asarray(self._spherical_w)

    def errors(self, sim: PoseSnapshot, ref: PoseSnapshot) -> dict[str, float]:
        """The four error terms (see the module docstring)."""
        dq = sim.q[self._revolute_q] - ref.q[self._revolute_q]
        dv = sim.qd[self._revolute_v] - ref.qd[self._revolute_v]
        pose = float(np.sum(self._revolute_w * dq * dq))
        vel = float(np.sum(self._revolute_w * dv * dv))
        for q0, v0, w in zip(self._spherical_q, self._spherical_v, self._spherical_w):
            angle = float(quat_angle(sim.q[q0:q0 + 4], ref.q[q0:q0 + 4]))
            pose += w * angle * angle
            vel += w * float(np.sum((sim.qd[v0:v0 + 3] - ref.qd[v0:v0 + 3]) ** 2))
        if len(sim.end_effectors):
            end = float(np.mean(np.sum((sim.end_effectors - ref.end_effectors) ** 2, axis=1)))
        else:
            end = 0.0
        c = self.spec.root_error
        root_angle = float(quat_angle(sim.root_rot, ref.root_rot))
        root = (c["position"] * float(np.sum((sim.root_pos - ref.root_pos) ** 2))
                + c["rotation"] * root_angle * root_angle
                + c["velocity"] * float(np.sum((sim.root_vel - ref.root_vel) ** 2))
                + c["angular_velocity"] * float(np.sum((sim.root_ang_vel - ref.root_ang_vel) ** 2)))
        return {"pose": pose, "velocity": vel, "end_effector": end, "root": root}

    def combine(self, errors: dict[str, float]) -> tuple[float, dict[str, float]]:
        """Total reward and the per-term rewards exp(-k e) (before weighting)."""
        terms = {name: math.exp(-t.scale * errors[name]) for name, t in self.spec.terms.items()}
        if self.spec.combine == "sum":
            total = sum(self.spec.terms[name].weight * r for name, r in terms.items())
        else:
            total = math.prod(r ** self.spec.terms[name].weight for name, r in terms.items())
        return float(total), terms

    def __call__(self, sim: PoseSnapshot, ref: PoseSnapshot) -> tuple[float, dict[str, float], dict[str, float]]:
        errors = self.errors(sim, ref)
        total, terms = self.combine(errors)
        return total, terms, errors
