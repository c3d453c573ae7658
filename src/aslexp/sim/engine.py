"""Which physics engine simulates a body: ``conf/engine/*.yaml`` as plain values.

PyBullet (:mod:`aslexp.sim.world`) is the thesis' engine and the default. MuJoCo
(:mod:`aslexp.sim.mujoco_engine`) loads the same URDFs, body configs, motion layouts and
controllers, and steps many environments per process (:mod:`aslexp.envs.batched`). The two engines
share everything above the body: the reference, observation, action and reward code.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import Any

ENGINES = ("pybullet", "mujoco")
INTEGRATORS = ("Euler", "implicitfast", "implicit", "RK4")
SOLVERS = ("Newton", "CG", "PGS")


@dataclass(frozen=True)
class EngineSpec:
    """``conf/engine/<name>.yaml``; the MuJoCo keys are ignored by PyBullet."""

    name: str = "pybullet"
    # MuJoCo: the integrator (implicitfast treats the PD actuators' damping implicitly: stable at
    # any gain, as stable PD), the constraint solver and its iterations.
    integrator: str = "implicitfast"
    solver: str = "Newton"
    iterations: int = 50
    # MuJoCo, controller mode position: the stiffness of the actuators that stand for PyBullet's
    # velocity motor, times this (sim/mujoco_engine.py says why 2).
    motor_gain_scale: float = 2.0
    # MuJoCo: threads stepping a batch of environments (0: every core this process may use).
    threads: int = 0
    # MuJoCo: every generalised velocity (the joints' and a free base's six) clamped to +-this after
    # each physics step, and the step's positions integrated with the clamped velocity: PyBullet's
    # btMultiBody does exactly this whenever it applies a velocity change (maxJointVelocity, 100 rad/s
    # by default, which aslexp never changes), so both engines share one joint-speed semantics.
    # null: MuJoCo's own, no clamp (a transient PyBullet cannot produce, e.g. at a looping motion's seam).
    joint_speed_limit: float | None = 100.0

    @classmethod
    def from_dict(cls, values: dict[str, Any] | None) -> "EngineSpec":
        values = dict(values or {})
        known = {f.name for f in fields(cls)}
        unknown = set(values) - known
        if unknown:
            raise ValueError(f"engine config: unknown keys {sorted(unknown)}; expected {sorted(known)}")
        spec = cls(**values)
        if spec.name not in ENGINES:
            raise ValueError(f"engine config: name must be one of {ENGINES}, got {spec.name!r}")
        if spec.integrator not in INTEGRATORS:
            raise ValueError(f"engine config: integrator must be one of {INTEGRATORS}, got {spec.integrator!r}")
        if spec.solver not in SOLVERS:
            raise ValueError(f"engine config: solver must be one of {SOLVERS}, got {spec.solver!r}")
        scale = spec.motor_gain_scale
        if isinstance(scale, bool) or not isinstance(scale, (int, float)) or not scale > 0:
            raise ValueError(f"engine config: motor_gain_scale must be a number > 0, got {scale!r}")
        limit = spec.joint_speed_limit
        if limit is not None and (isinstance(limit, bool) or not isinstance(limit, (int, float)) or not limit > 0):
            raise ValueError(f"engine config: joint_speed_limit must be a number > 0 (rad/s) or null, got {limit!r}")
        for key in ("iterations", "threads"):
            value = getattr(spec, key)
            if isinstance(value, bool) or not isinstance(value, int) or value < (1 if key == "iterations" else 0):
                raise ValueError(f"engine config: {key} must be an integer >= {1 if key == 'iterations' else 0}, "
                                 f"got {value!r}")
        return spec
