"""What the results page's job-table entries share (``report: retrieval``, ``report: seen_glosses``):
the completed runs of one job under the entry's folders, the latest of them, and the entry rendered
with the job's own table in place of the generic one (:mod:`aslexp.reports.results_page` draws the rest)."""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from aslexp.runfile import RUN_FILE

log = logging.getLogger(__name__)


def read_json(path: Path) -> Any:
    """The file's JSON, or None with a warning naming it (a run it belongs to is left out)."""
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as err:
        log.warning("warning: %s: %s; left out", path, err)
        return None


def number(value: Any) -> float | None:
    """A finite number rounded for a snapshot; None for a missing or non-finite one."""
    if value is None:
        return None
    value = float(value)
    return round(value, 6) if math.isfinite(value) else None


def find_runs(folders: list[Path], job: str, needed: str = "table") -> tuple[list[tuple[Path, dict[str, Any]]], dict[str, int]]:
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


def render_with_table(entry: dict[str, Any], snapshot: dict[str, Any] | None,
                      render_entry: Callable[[dict[str, Any], dict[str, Any] | None], list[str]],
                      table: list[str], legend: list[str]) -> list[str]:
    """``render_entry``'s lines with ``table`` and ``legend`` in place of its generic table and its
    line of numbers."""
    lines = render_entry(entry, snapshot)
    if snapshot is None:
        return lines
    start = next((i for i, line in enumerate(lines) if line.startswith("| ")), None)
    end = next((i for i, line in enumerate(lines) if line.startswith("Numbers:")), None)
    if start is None or end is None:
        return lines
    return lines[:start] + table + [""] + legend + lines[end + 2:]
