"""A tiny deterministic Hydra job for testing and benchmarking sweeps.

Maximise ``-(x - 0.3)^2 - (y + 1)^2`` (optionally plus seeded noise). With ``steps > 0`` the job
reports an intermediate value per step that converges to the objective, so pruners have something
to compare; ``fail_if`` / ``nan_if`` make chosen points raise or return NaN; ``sleep`` makes a
trial take time. It follows the run-directory conventions of every job (run.json, metrics.json,
main metric) so that the ``runs`` and ``sweep`` tools see it like any other.

    python -m aslexp.jobs.quadratic x=0.1 y=-0.5
    python -m aslexp.jobs.quadratic -m +sweeps=quadratic hydra.sweep.dir=outputs/sweeps/q
"""

from __future__ import annotations

import math
import operator
import re
import time

import numpy as np
from omegaconf import DictConfig

from aslexp.jobs._common import job_main, log, run_guarded
from aslexp.runs.record import Run
from aslexp.tuning.context import trial_reporter

_CONDITION = re.compile(r"^\s*([xy])\s*(<=|>=|<|>|==|!=)\s*([-+0-9.eE]+)\s*$")
_OPERATORS = {"<": operator.lt, ">": operator.gt, "<=": operator.le, ">=": operator.ge,
              "==": operator.eq, "!=": operator.ne}


def condition_holds(condition: str | None, point: dict[str, float]) -> bool:
    """Evaluate ``"always"`` or ``"NAME OP NUMBER"`` (NAME in x, y) without eval()."""
    if condition is None:
        return False
    if str(condition).strip() == "always":
        return True
    match = _CONDITION.match(str(condition))
    if match is None:
        raise ValueError(
            f"quadratic.yaml: fail_if/nan_if must be 'always' or 'NAME OP NUMBER' with NAME in "
            f"x, y and OP in < > <= >= == != (got {condition!r})"
        )
    name, op, number = match.groups()
    return _OPERATORS[op](point[name], float(number))


def objective(x: float, y: float) -> float:
    return -((x - 0.3) ** 2) - (y + 1.0) ** 2


def quadratic(cfg: DictConfig, run: Run) -> float:
    point = {"x": float(cfg.x), "y": float(cfg.y)}
    value = objective(point["x"], point["y"])
    if cfg.noise:
        value += float(np.random.default_rng(int(cfg.seed)).normal(0.0, float(cfg.noise)))
    reporter = trial_reporter(cfg)
    steps = int(cfg.steps)
    for step in range(steps):
        if cfg.sleep:
            time.sleep(float(cfg.sleep))
        # Converges to the final value; worse points stay worse at every step.
        reporter.report(value - 0.1 * (steps - 1 - step), step, final=step == steps - 1)
    if not cfg.steps and cfg.sleep:
        time.sleep(float(cfg.sleep))
    if condition_holds(cfg.fail_if, point):
        raise RuntimeError(f"quadratic: fail_if {cfg.fail_if!r} holds at x={point['x']}, y={point['y']}")
    if condition_holds(cfg.nan_if, point):
        value = math.nan
    run.save_metrics({"objective": value, **point})
    run.set_main_metric("objective", value, "maximize")
    log.info("objective(x=%.6g, y=%.6g) = %.6g", point["x"], point["y"], value)
    return value


@job_main("quadratic")
def main(cfg: DictConfig) -> float:
    return run_guarded("quadratic", cfg, lambda run: quadratic(cfg, run))


if __name__ == "__main__":
    main()
