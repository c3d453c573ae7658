"""What a sweep did: ``aslexp sweep status|best|report|dashboard SWEEP_DIR``.

status: trial counts by state against the budget; best: the best trial and a command line
that re-runs exactly it; report: Optuna's plots as PNG (:mod:`aslexp.viz.study`) plus a CSV of all trials;
dashboard: the study in optuna-dashboard (a web UI) on loopback.
"""

from __future__ import annotations

import logging
import shlex
from pathlib import Path
from typing import Any

import optuna
from optuna.trial import FrozenTrial, TrialState

from aslexp.runs import read
from aslexp.runs.record import METRICS_FILE, RUN_FILE
from aslexp.tuning.study import StudyError, SweepInfo, status_summary, trial_summary
from aslexp.tuning.worker import ATTR_OVERRIDES, ATTR_RUN_DIR, run_dir_of

log = logging.getLogger(__name__)

REPORT_DIR = "report"
_FAILED_SHOWN = 10


def rerun_command(job: str, overrides: list[str], python_module: str | None = None) -> str:
    """The command line that runs one trial's configuration again as a single run."""
    head = ["python", "-m", python_module] if python_module else ["aslexp", job]
    return shlex.join([*head, *overrides])


def trial_overrides(trial: FrozenTrial, study_name: str | None = None) -> list[str]:
    """The task overrides a trial's job got: from its run directory, else from the study."""
    run_dir = run_dir_of(trial.user_attrs.get(ATTR_RUN_DIR), study_name)
    if run_dir and (Path(run_dir) / ".hydra" / "overrides.yaml").exists():
        loaded = read.read_overrides(run_dir, consequence="the overrides the study recorded are used")
        if loaded is not None:
            return loaded
    return [str(x) for x in trial.user_attrs.get(ATTR_OVERRIDES) or []]


def best_summary(study: optuna.Study, info: SweepInfo | None) -> dict[str, Any]:
    completed = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not completed:
        raise StudyError(f"study {study.study_name!r} has no completed trial yet")
    best = study.best_trial
    overrides = trial_overrides(best, study.study_name)
    job = info.job if info else "JOB"
    result = trial_summary(best, study.study_name)
    result.update({
        "job": job,
        "direction": study.direction.name.lower(),
        "overrides": overrides,
        "command": rerun_command(job, overrides),
        "python_command": rerun_command(job, overrides, info.task_module if info else None)
        if info and info.task_module else None,
    })
    return result


def format_status(summary: dict[str, Any], sweep_dir: Path) -> str:
    counts = summary["counts"]
    budget = summary.get("n_trials_budget")
    used = summary["trials"] - counts.get("interrupted", 0)
    lines = [
        f"sweep {sweep_dir}",
        f"study {summary['study_name']!r} ({summary['direction']})",
        f"trials: {summary['trials']}" + (f"  (budget {budget}, {used} counted, "
                                          f"{max(0, budget - used)} to go)" if budget else ""),
    ]
    order = ["complete", "pruned", "fail", "interrupted", "running", "waiting"]
    shown = [f"{state} {counts[state]}" for state in order if counts.get(state)]
    lines.append("  " + ("  ".join(shown) if shown else "no trials yet"))
    if counts.get("interrupted"):
        lines.append("  (interrupted: lost to a stopped or dead worker; not counted, re-run on resume)")
    if summary.get("lost"):
        lines.append(f"  ({summary['lost']} of the running trials' workers are gone: they are marked "
                     "interrupted when the sweep resumes)")
    if summary.get("orphans_finished"):
        lines.append(f"  ({summary['orphans_finished']} of the running trials' workers are gone but "
                     "their jobs finished: the resume adopts their results from run.json)")
    if summary.get("orphans_running"):
        lines.append(f"  ({summary['orphans_running']} of the running trials' workers are gone but "
                     "their jobs still run: the resume waits for them and adopts their results)")
    adopted = summary.get("adopted") or []
    if adopted:
        shown = ", ".join(str(n) for n in adopted[:10]) + (", ..." if len(adopted) > 10 else "")
        lines.append(f"  (results adopted from their run folder after their worker was gone: "
                     f"{len(adopted)} trial(s): {shown})")
    if summary.get("other_studies"):
        lines.append("other studies in this folder: " + ", ".join(summary["other_studies"]))
    failed = summary.get("failed") or []
    if failed:
        lines.append("failed and interrupted trials (the error their run.json records too):")
        shown = failed[-_FAILED_SHOWN:]
        if len(failed) > len(shown):
            lines.append(f"  ... {len(failed) - len(shown)} earlier ones (--json lists all)")
        lines += [f"  trial {t['number']}: {t['error']}" for t in shown]
    best = summary.get("best")
    if best:
        lines.append(f"best: trial {best['number']} value {best['value']:.6g} params {best['params']}")
    return "\n".join(lines)


def format_best(best: dict[str, Any]) -> str:
    lines = [
        f"best trial {best['number']}: value {best['value']!r} ({best['direction']})",
        "params:",
        *[f"  {k} = {v!r}" for k, v in best["params"].items()],
        f"run dir: {best.get('run_dir') or '-'}",
        "re-run exactly this trial:",
        f"  {best['command']}",
    ]
    if best.get("python_command"):
        lines.append(f"  {best['python_command']}")
    return "\n".join(lines)


def failed_trials(study: optuna.Study) -> list[dict[str, Any]]:
    return [trial_summary(t, study.study_name) for t in study.get_trials(deepcopy=False, states=(TrialState.FAIL,))]


def write_report(study: optuna.Study, sweep_dir: Path, out_dir: Path | None = None) -> list[Path]:
    """Save the study's plots as PNG (:func:`aslexp.viz.study.plot_study`) and trials.csv; returns the
    files written.

    Plots that need more than the study has (e.g. importances with fewer than two completed
    trials) are skipped with a log line saying why.
    """
    from aslexp.viz.study import plot_study

    out_dir = Path(out_dir) if out_dir else Path(sweep_dir) / REPORT_DIR
    out_dir.mkdir(parents=True, exist_ok=True)
    written: list[Path] = []
    frame = study.trials_dataframe()
    csv_path = out_dir / "trials.csv"
    frame.to_csv(csv_path, index=False)
    written.append(csv_path)
    return written + plot_study(study, out_dir)


def check_trial_files(study: optuna.Study) -> int:
    """Read every trial folder's run.json, metrics.json (of a completed trial) and overrides; each
    damaged file is named in one warning line (the study's own record is unaffected). Returns how
    many were damaged."""
    damaged = 0
    for trial in study.get_trials(deepcopy=False):
        run_dir = run_dir_of(trial.user_attrs.get(ATTR_RUN_DIR), study.study_name)
        if not run_dir or not (Path(run_dir) / RUN_FILE).is_file():
            continue
        what = f"trial {trial.number}'s folder: the study's record of it stands"
        damaged += read.read_run_info(run_dir, what) is None
        if trial.state == TrialState.COMPLETE and (Path(run_dir) / METRICS_FILE).exists():
            damaged += read.read_metrics(run_dir, what) is None
        damaged += read.read_overrides(run_dir, what) is None
    return damaged


def serve_dashboard(study: optuna.Study, host: str = "127.0.0.1", port: int = 8080) -> None:
    """Serve the study's storage in optuna-dashboard until interrupted (blocks)."""
    try:
        from optuna_dashboard import run_server
    except ImportError as err:
        raise RuntimeError("optuna-dashboard is not installed: pip install optuna-dashboard") from err
    print(f"optuna-dashboard for study {study.study_name!r}: http://{host}:{port}/dashboard/ "
          "(Ctrl-C stops it)", flush=True)
    run_server(study._storage, host=host, port=port)


__all__ = ["best_summary", "status_summary", "format_status", "format_best", "write_report",
           "serve_dashboard", "failed_trials", "check_trial_files"]
