"""Find run directories and summarise them: ``aslexp runs list``.

A run directory is any folder with a run.json (see :mod:`aslexp.runs.record`); its overrides
come from Hydra's ``.hydra/overrides.yaml`` and its resolved config from ``.hydra/config.yaml``.
A run whose run.json still says "running" but whose process on this machine is gone (killed,
out of memory, the machine's power) is listed as ``lost``; a sweep's resume records its trials
as interrupted. A damaged file (see :mod:`aslexp.runs.read`) is named in one warning line: a run
without a usable run.json is skipped, one without usable overrides or config is listed without.
"""

from __future__ import annotations

import json
import logging
import math
import os
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from aslexp.runs import read
from aslexp.process import process_is_gone
from aslexp.runs.record import RUN_FILE

log = logging.getLogger(__name__)

# Folders never worth descending into when looking for runs.
_SKIP_DIRS = {".hydra", ".submitit", "__pycache__", ".git", ".venv", "node_modules", "report"}


@dataclass
class RunSummary:
    """One row of ``runs list``."""

    path: Path
    job: str | None
    started: str | None
    status: str | None
    overrides: list[str] = field(default_factory=list)
    metric_name: str | None = None
    metric_value: float | None = None
    metric_goal: str | None = None
    info: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"path": str(self.path), "job": self.job, "started": self.started,
                "status": self.status, "overrides": self.overrides,
                "metric": self.metric_name, "value": self.metric_value, "goal": self.metric_goal,
                "seed": self.info.get("seed"), "git": self.info.get("git"),
                "host": self.info.get("host")}


def read_overrides(run_dir: str | os.PathLike) -> list[str]:
    """The run's overrides; [] when absent or damaged (a warning names the file)."""
    return read.read_overrides(run_dir) or []


def read_config(run_dir: str | os.PathLike) -> dict[str, Any]:
    """The run's resolved config (``.hydra/config.yaml``) as plain containers; {} when absent or
    damaged (a warning names the file)."""
    return read.read_config(run_dir) or {}


def find_run_dirs(roots: Iterable[str | os.PathLike]) -> Iterator[Path]:
    """Every directory under ``roots`` (inclusive) that holds a run.json."""
    for root in roots:
        root = Path(root)
        if not root.exists():
            continue
        for current, dirs, files in os.walk(root):
            dirs[:] = sorted(d for d in dirs if d not in _SKIP_DIRS)
            if RUN_FILE in files:
                yield Path(current)


def summarise(run_dir: Path) -> RunSummary | None:
    """The run's row; None (after a warning naming the file) when its run.json is damaged."""
    info = read.read_run_info(run_dir)
    if info is None:
        return None
    main = info.get("main_metric") or {}
    value = main.get("value")
    status = info.get("status")
    if status == "running" and process_is_gone(info.get("process")):
        status = "lost"
    return RunSummary(path=run_dir, job=info.get("job"), started=info.get("started"),
                      status=status, overrides=read_overrides(run_dir),
                      metric_name=main.get("name"),
                      metric_value=float(value) if isinstance(value, (int, float)) else None,
                      metric_goal=main.get("goal"), info=info)


def _config_value(config: dict[str, Any], dotted: str) -> Any:
    node: Any = config
    for part in dotted.split("."):
        if not isinstance(node, dict) or part not in node:
            return None
        node = node[part]
    return node


def matches(run: RunSummary, where: list[str]) -> bool:
    """``KEY=VALUE`` filters: true when the run's resolved config (or an override) says so."""
    if not where:
        return True
    config = None
    for condition in where:
        key, _, wanted = condition.partition("=")
        key = key.strip()
        if any(o.lstrip("+~") == f"{key}={wanted}" for o in run.overrides):
            continue
        if config is None:
            config = read_config(run.path)
        value = _config_value(config, key)
        if value is None or str(value) != wanted and yaml.safe_load(wanted) != value:
            return False
    return True


def list_runs(roots: Iterable[str | os.PathLike], job: str | None = None,
              status: str | None = None, since: str | None = None,
              where: list[str] | None = None, sort: str = "time",
              limit: int | None = None) -> list[RunSummary]:
    """Runs under ``roots``, filtered and sorted (time: newest first; metric: best first)."""
    runs = []
    for run_dir in find_run_dirs(roots):
        run = summarise(run_dir)
        if run is None:  # named in its warning line
            continue
        if job and run.job != job:
            continue
        if status and run.status != status:
            continue
        if since and (run.started or "") < since:
            continue
        if not matches(run, where or []):
            continue
        runs.append(run)
    if sort == "metric":
        def key(r: RunSummary) -> tuple:
            value = r.metric_value
            if value is None or math.isnan(value):
                return (1, 0.0)
            return (0, -value if (r.metric_goal or "maximize") == "maximize" else value)
        runs.sort(key=key)
    else:
        runs.sort(key=lambda r: r.started or "", reverse=True)
    return runs[:limit] if limit else runs


def format_table(runs: list[RunSummary], base: Path | None = None) -> str:
    """A text table: time, job, run dir, status, main metric, then the overrides, whole (the last
    column, never cut: the override that tells two runs apart is often the last one)."""
    rows = [("started", "job", "run", "status", "main metric", "overrides")]
    for r in runs:
        where = r.path
        if base is not None:
            try:
                where = r.path.resolve().relative_to(base.resolve())
            except ValueError:
                pass
        metric = "-"
        if r.metric_name is not None:
            shown = "nan" if r.metric_value is None else f"{r.metric_value:.4g}"
            metric = f"{r.metric_name}={shown}"
        overrides = " ".join(o for o in r.overrides if not o.startswith("hydra."))
        rows.append(((r.started or "-")[:19].replace("T", " "), r.job or "-", str(where), r.status or "-", metric,
                     overrides or "-"))
    widths = [max(len(row[i]) for row in rows) for i in range(len(rows[0]))]
    lines = ["  ".join(cell.ljust(w) for cell, w in zip(row, widths)).rstrip() for row in rows]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def format_json(runs: list[RunSummary]) -> str:
    return json.dumps([r.as_dict() for r in runs], indent=2, default=str)
