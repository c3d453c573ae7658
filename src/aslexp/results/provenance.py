"""Where a result's runs are and where and when they ran: the run folders of an entry's first ``runs``
alternative that holds a completed run, and the snapshot's provenance read from them (run.json,
metrics.json, ``.hydra/hydra.yaml``).
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import Any

from aslexp.results.catalogue import NOT_WHAT
from aslexp.runfile import RUN_FILE, machines
from aslexp.runs.completed import completed, hydra_choices, read_json


def entry_folders(entry: dict[str, Any], outputs: Path) -> tuple[list[Path], dict[str, Any]]:
    """The folders of the first ``runs`` alternative under ``outputs`` that holds a completed run
    (globs expanded, sorted), and that alternative; ([], {}) when none does."""
    for alternative in entry["runs"]:
        folders: list[Path] = []
        for pattern in alternative["folders"]:
            folders += sorted(p for p in Path(outputs).glob(str(pattern)) if p.is_dir())
        folders = list(dict.fromkeys(folders))
        if any(completed(path.parent) for folder in folders for path in folder.rglob(RUN_FILE)):
            return folders, alternative
    return [], {}


def utc(stamp: str | None) -> _dt.datetime | None:
    """A time stamp with its offset as UTC; None for a missing one or one without an offset."""
    try:
        value = _dt.datetime.fromisoformat(str(stamp))
    except (TypeError, ValueError):
        return None
    if value.tzinfo is None:
        return None
    return value.astimezone(_dt.timezone.utc)


def provenance(run_dirs: list[Path], outputs: Path, folders: list[Path], alternative: dict[str, Any]) -> dict[str, Any]:
    """Where and when the runs ran, from their run.json, metrics.json and .hydra/hydra.yaml: the
    first start and last finish (UTC), hosts, platforms, devices, Python and torch versions, git
    commits, the engine and reward they composed, and their overrides (those all runs share, and per
    key the values of those that vary)."""
    read = [(d, read_json(d / RUN_FILE)) for d in run_dirs]
    infos = [info for _, info in read if isinstance(info, dict)]
    started = [t for t in (utc(i.get("started")) for i in infos) if t]
    finished = [t for t in (utc(i.get("finished")) for i in infos) if t]
    # Every machine that trained a run's steps: its own, and those of the runs it was resumed from.
    found, resumed = [], 0
    for run_dir, info in read:
        metrics = read_json(run_dir / "metrics.json") if (run_dir / "metrics.json").is_file() else None
        chain = machines(info if isinstance(info, dict) else {}, metrics if isinstance(metrics, dict) else None)
        found += chain
        resumed += len(chain) > 1
    devices = set()
    for machine in found:
        device = machine.get("device")
        if isinstance(device, dict):
            device = device.get("name") or device.get("type")
        if device:
            devices.add(str(device))
    choices = [hydra_choices(d) for d in run_dirs]
    overrides = [[o for o in (i.get("overrides") or []) if not o.startswith(NOT_WHAT)] for i in infos]
    common = sorted(set.intersection(*(set(o) for o in overrides))) if overrides else []
    varied: dict[str, set[str]] = {}
    for run in overrides:
        for override in run:
            if override not in common:
                key, _, value = override.partition("=")
                varied.setdefault(key, set()).add(value)

    def values(key: str) -> list[str]:
        return sorted({str(m[key]) for m in found if m.get(key)})

    def relative(path: Path) -> str:
        try:
            return path.resolve().relative_to(outputs.resolve()).as_posix()
        except ValueError:
            return path.as_posix()

    return {
        "folders": [relative(f) for f in folders],
        "machine_label": alternative.get("machine"),
        "runs": len(run_dirs),
        "started": min(started).isoformat() if started else None,
        "finished": max(finished).isoformat() if finished else None,
        "hosts": values("host"),
        "platforms": values("platform"),
        **({"resumed": resumed} if resumed else {}),
        "devices": sorted(devices),
        "versions": {"python": values("python"), "torch": values("torch")},
        "git": sorted({f"{(i.get('git') or {}).get('commit', '')[:10]}{'+' if (i.get('git') or {}).get('dirty') else ''}"
                       for i in infos if (i.get("git") or {}).get("commit")}),
        "engine": sorted({c["engine"] for c in choices if "engine" in c}),
        "reward": sorted({c["reward"] for c in choices if "reward" in c}),
        "overrides": {"common": common, "varied": {k: sorted(v) for k, v in sorted(varied.items())}},
    }
