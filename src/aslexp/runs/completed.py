"""The completed runs under a set of folders, as the reports read them: one job's runs with their
metrics.json (the latest of them), the recognition runs beside the runs of other jobs, a run's
predictions.csv and the config choices it composed (``.hydra/hydra.yaml``).

A file that cannot be read is named in one warning line and its run left out; the counts of what
was left out, by reason, come back with the runs.
"""

from __future__ import annotations

import csv
import json
import logging
from collections import defaultdict
from pathlib import Path
from typing import Any

from aslexp.runs import read
from aslexp.runs.record import METRICS_FILE, RUN_FILE

log = logging.getLogger(__name__)


def read_json(path: Path) -> Any:
    """The file's JSON, or None with a warning naming it (a run it belongs to is left out)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        log.warning("warning: %s: %s; left out", path, err)
        return None


def completed(run_dir: Path) -> bool:
    """Whether the run's run.json says it completed."""
    info = read_json(run_dir / RUN_FILE)
    return isinstance(info, dict) and info.get("status") == "completed"


def find_job_runs(folders: list[Path], job: str, needed: str = "table"
                  ) -> tuple[list[tuple[Path, dict[str, Any]]], dict[str, int]]:
    """Completed runs of ``job`` under ``folders`` whose metrics.json has ``needed`` (run folder,
    metrics), and what was left out, counted by reason."""
    runs, skipped = [], {}
    for folder in folders:
        for path in sorted(Path(folder).rglob(RUN_FILE)):
            info = read_json(path) or {}
            if info.get("job") != job:
                continue
            if info.get("status") != "completed":
                reason = f"status {info.get('status', 'unknown')}"
                skipped[reason] = skipped.get(reason, 0) + 1
                continue
            metrics = read_json(path.parent / "metrics.json")
            if not isinstance(metrics, dict) or needed not in metrics:
                reason = f"no {needed} in metrics.json"
                skipped[reason] = skipped.get(reason, 0) + 1
                continue
            runs.append((path.parent, metrics))
    return runs, skipped


def latest(runs: list[tuple[Path, dict[str, Any]]], skipped: dict[str, int]) -> tuple[Path, dict[str, Any]]:
    """The run that finished last (the earlier ones are counted in ``skipped``)."""
    if len(runs) > 1:
        skipped["earlier completed runs (the latest is reported)"] = len(runs) - 1
    return max(runs, key=lambda r: ((read_json(r[0] / RUN_FILE) or {}).get("finished") or "", str(r[0])))


def hydra_choices(run_dir: Path) -> dict[str, str]:
    """The config group options a run composed (``.hydra/hydra.yaml``: hydra.runtime.choices)."""
    import yaml

    path = Path(run_dir) / ".hydra" / "hydra.yaml"
    try:
        loaded = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError):
        return {}
    choices = ((loaded.get("hydra") or {}).get("runtime") or {}).get("choices") or {}
    return {str(k): str(v) for k, v in choices.items() if not str(k).startswith("hydra/")}


_OBJECT_KEYS = ("context", "objective", "baseline", "split_sizes", "paired_vs_baseline")
_CONTEXT_KEYS = ("split", "property", "classifier")


def _recognition_problem(metrics: dict[str, Any]) -> str | None:
    """What a recognition run's metrics.json lacks for the tables (None: nothing)."""
    for key in _OBJECT_KEYS:
        if not isinstance(metrics.get(key), dict):
            return f'"{key}" is missing or not an object'
    for key in _CONTEXT_KEYS:
        if not isinstance(metrics["context"].get(key), str):
            return f'"context.{key}" is missing or not a string'
    return None


def find_runs(paths: list[Path]) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, int]]:
    """(completed recognition runs, runs of other jobs, what was skipped and why) under ``paths``.
    A damaged run.json or metrics.json is named in one warning line and its run skipped."""
    runs, others, skipped = [], [], defaultdict(int)
    for base in paths:
        if not base.exists():
            raise FileNotFoundError(f"{base}: no such file or directory")
        for run_file in sorted(base.rglob(RUN_FILE)):
            run_dir = run_file.parent
            info = read.read_run_info(run_dir)
            if info is None:
                skipped["damaged run.json"] += 1
                continue
            if info.get("job") != "recognize":
                others.append({"dir": run_dir, "info": info})
                continue
            if info.get("status") != "completed" or not (run_dir / METRICS_FILE).exists():
                skipped[f"status {info.get('status')}"] += 1
                continue
            metrics = read.read_metrics(run_dir)
            if metrics is None:
                skipped["damaged metrics.json"] += 1
                continue
            if "test_interval" not in metrics:
                skipped["metrics.json of an older format (no test_interval)"] += 1
                continue
            problem = _recognition_problem(metrics)
            if problem:
                read.warn(read.RunFileError(run_dir / METRICS_FILE, problem), "run skipped")
                skipped["damaged metrics.json"] += 1
                continue
            layout = (metrics.get("layout") or {}).get("name", metrics["context"].get("pose"))
            runs.append({"dir": run_dir, "info": info, "metrics": metrics, **metrics["context"], "layout": layout})
    return runs, others, dict(skipped)


def read_predictions(run_dir: Path) -> dict[tuple[int, int], dict[str, tuple[str, str]]]:
    """A recognition run's predictions.csv: (split, seed) -> video_id -> (true, predicted)."""
    runs: dict[tuple[int, int], dict[str, tuple[str, str]]] = defaultdict(dict)
    path = run_dir / "predictions.csv"
    if not path.exists():
        return {}
    with open(path, encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            runs[(int(row.get("split", 0) or 0), int(row["seed"]))][row["video_id"]] = (row["true"], row["predicted"])
    return runs
