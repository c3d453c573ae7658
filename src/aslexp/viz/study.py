"""A sweep's study drawn by Optuna's matplotlib plots (history, importances, parallel coordinates,
slices, intermediate values) as PNG files (Agg)."""

from __future__ import annotations

import logging
import warnings
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import optuna  # noqa: E402
from optuna.trial import TrialState  # noqa: E402
from optuna.visualization import matplotlib as ovm  # noqa: E402

log = logging.getLogger(__name__)


def plot_study(study: optuna.Study, out_dir: Path) -> list[Path]:
    """Each plot the study has enough trials for, as ``out_dir/<name>.png``; the others skipped with a
    log line saying why. Returns the files written."""
    # choice() values reach matplotlib as strings; it logs one INFO line per such axis.
    logging.getLogger("matplotlib.category").setLevel(logging.WARNING)
    written: list[Path] = []
    completed = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    with_steps = [t for t in study.get_trials(deepcopy=False) if t.intermediate_values]
    plots = {
        "optimization_history": (ovm.plot_optimization_history, 1),
        "param_importances": (ovm.plot_param_importances, 2),
        "parallel_coordinate": (ovm.plot_parallel_coordinate, 1),
        "slice": (ovm.plot_slice, 1),
    }
    if with_steps:
        plots["intermediate_values"] = (ovm.plot_intermediate_values, 0)
    for name, (plot, needed) in plots.items():
        if len(completed) < needed:
            log.info("report: %s skipped (needs %d completed trials, has %d)", name, needed,
                     len(completed))
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # Optuna marks these plots experimental
                result = plot(study)
        except (ValueError, RuntimeError, ZeroDivisionError) as err:
            log.info("report: %s skipped: %s", name, err)
            continue
        axes = result.flatten()[0] if hasattr(result, "flatten") else result
        figure = axes.get_figure()
        figure.set_size_inches(max(figure.get_size_inches()[0], 8), max(figure.get_size_inches()[1], 5))
        path = out_dir / f"{name}.png"
        figure.savefig(path, dpi=100, bbox_inches="tight")
        plt.close(figure)
        written.append(path)
    return written
