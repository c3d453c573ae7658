"""run.json, the record in a run's folder, as every layer names it: its file name, its time
stamps, and the one change made to it from outside its job (a sweep worker that lost the job
marks the run interrupted).

The jobs write the record (:mod:`aslexp.runs.record`), the tools read it (:mod:`aslexp.runs.read`),
and a sweep (:mod:`aslexp.tuning`) adopts a trial's result from it: all three import this leaf
module, so the sweep machinery does not import the run tools above it.
"""

from __future__ import annotations

import datetime as _dt
import os
from pathlib import Path
from typing import Any

from aslexp.files import read_json, write_json

RUN_FILE = "run.json"


def timestamp() -> str:
    """Now as run.json records it: local time with its UTC offset, to the second."""
    return _dt.datetime.now().astimezone().isoformat(timespec="seconds")


def mark_interrupted(run_dir: str | os.PathLike, reason: str,
                     replace: tuple[str, ...] = ("running",)) -> bool:
    """Record a run that never finished as interrupted (its process was killed or cancelled).

    Only a run.json whose status is one of ``replace`` (still "running"; a sweep's trial stopped
    by a full disk may say "failed" too) changes; returns whether it did.
    """
    path = Path(run_dir) / RUN_FILE
    try:
        info = read_json(path)
    except (OSError, ValueError):
        return False
    if not isinstance(info, dict) or info.get("status") not in replace:
        return False
    info.update(status="interrupted", finished=info.get("finished") or timestamp(), error=reason)
    write_json(path, info)
    return True


def machines(info: dict[str, Any], metrics: dict[str, Any] | None) -> list[dict[str, Any]]:
    """Every machine a run's steps were trained on: its own process's (run.json, metrics.json), then
    those of the runs it was resumed from (``resumed_from``, newest first)."""
    versions = info.get("versions") or {}
    found = [{"host": info.get("host"), "platform": info.get("platform"), "python": versions.get("python"),
              "torch": versions.get("torch"), "device": (metrics or {}).get("device")}]
    origin = (metrics or {}).get("resumed_from")
    while isinstance(origin, dict):
        found.append({k: origin.get(k) for k in ("host", "platform", "python", "torch", "device")})
        origin = origin.get("resumed_from")
    return found
