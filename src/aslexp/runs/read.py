"""Validated readers of a run folder's files, for every tool that reads runs (``runs list``,
``runs diff``, ``report``, ``sweep status|best``).

One damaged file never stops a tool: ``load_*`` raise :class:`RunFileError` (one line: the file
and what is wrong with it, e.g. ``.../run.json: a JSON list, expected an object``) for the tools
that must refuse (``runs diff`` exits 2); ``read_*`` log that line as a warning, say what the
tool does instead, and return None (or an empty value) so the tool goes on with the rest.

What is checked is what the tools rely on: run.json is an object whose text fields are strings,
whose context fields are objects and whose ``main_metric`` is an object with a string name, a
number (or null) as value and maximize/minimize as goal; metrics.json is an object;
``.hydra/overrides.yaml`` is a list of overrides and ``.hydra/config.yaml`` a mapping.
"""

from __future__ import annotations

import json
import logging
import os
from pathlib import Path
from typing import Any

import yaml

from aslexp.runs.record import METRICS_FILE, RUN_FILE

log = logging.getLogger(__name__)

OVERRIDES_FILE = Path(".hydra") / "overrides.yaml"
CONFIG_FILE = Path(".hydra") / "config.yaml"

_TEXT_FIELDS = ("job", "status", "started", "finished", "command", "host", "cwd", "error", "traceback")
_OBJECT_FIELDS = ("git", "versions", "process", "slurm")
_GOALS = ("maximize", "minimize")
_MISSING = object()


class RunFileError(ValueError):
    """A file of a run folder that is unreadable or not of the shape the tools read."""

    def __init__(self, path: str | os.PathLike, problem: str) -> None:
        super().__init__(f"{path}: {problem}")
        self.path = Path(path)
        self.problem = problem


def _kind(value: Any, mapping: str = "an object") -> str:
    """A JSON value's kind, as the messages name it (``mapping="a mapping"``: a YAML one's)."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a boolean"
    if isinstance(value, (int, float)):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return mapping
    return f"a {type(value).__name__}"


def _shown(value: Any) -> str:
    text = json.dumps(value, default=str)
    return text if len(text) <= 40 else text[:39] + "…"


def _one_line(error: Exception) -> str:
    text = " ".join(str(error).split())
    return text if len(text) <= 160 else text[:159] + "…"


def _read_text(path: Path) -> str:
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as err:
        raise RunFileError(path, f"not UTF-8 text ({err.reason})") from None
    except OSError as err:
        raise RunFileError(path, f"unreadable ({err.strerror or err})") from None
    if not text.strip():
        raise RunFileError(path, "empty file")
    return text


def load_json_object(path: str | os.PathLike) -> dict[str, Any]:
    """A JSON file that must hold an object."""
    path = Path(path)
    try:
        data = json.loads(_read_text(path))
    except ValueError as err:
        if isinstance(err, RunFileError):
            raise
        raise RunFileError(path, f"not valid JSON ({_one_line(err)})") from None
    if not isinstance(data, dict):
        raise RunFileError(path, f"a JSON {_kind(data).split()[-1]}, expected an object")
    return data


def _run_file(path: str | os.PathLike) -> Path:
    path = Path(path)
    return path / RUN_FILE if path.is_dir() else path


def load_run_info(run_dir: str | os.PathLike) -> dict[str, Any]:
    """The run.json of ``run_dir`` (or the run.json file itself), checked; RunFileError if not."""
    path = _run_file(run_dir)
    info = load_json_object(path)
    for key in _TEXT_FIELDS:
        value = info.get(key)
        if value is not None and not isinstance(value, str):
            raise RunFileError(path, f'"{key}" is {_shown(value)} ({_kind(value)}), expected a string')
    for key in _OBJECT_FIELDS:
        value = info.get(key)
        if value is not None and not isinstance(value, dict):
            raise RunFileError(path, f'"{key}" is {_shown(value)} ({_kind(value)}), expected an object')
    main = info.get("main_metric")
    if main is not None:
        if not isinstance(main, dict):
            raise RunFileError(path, f'"main_metric" is {_shown(main)} ({_kind(main)}), expected an object')
        name, value, goal = main.get("name"), main.get("value"), main.get("goal")
        if name is not None and not isinstance(name, str):
            raise RunFileError(path, f'"main_metric.name" is {_shown(name)} ({_kind(name)}), expected a string')
        if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
            raise RunFileError(path, f'"main_metric.value" is {_shown(value)} ({_kind(value)}), expected a number')
        if goal is not None and goal not in _GOALS:
            raise RunFileError(path, f'"main_metric.goal" is {_shown(goal)}, expected "maximize" or "minimize"')
    process = info.get("process") or {}
    pid = process.get("pid")
    if pid is not None and (isinstance(pid, bool) or not isinstance(pid, int)):
        raise RunFileError(path, f'"process.pid" is {_shown(pid)} ({_kind(pid)}), expected a number')
    return info


def load_metrics(run_dir: str | os.PathLike) -> dict[str, Any]:
    """The metrics.json of ``run_dir``: an object; RunFileError if not (or missing)."""
    path = Path(run_dir) / METRICS_FILE
    if not path.is_file():
        raise RunFileError(path, "missing")
    return load_json_object(path)


def _load_yaml(path: Path) -> Any:
    try:
        return yaml.safe_load(_read_text(path))
    except yaml.YAMLError as err:
        mark, problem = getattr(err, "problem_mark", None), getattr(err, "problem", None)
        where = f" at line {mark.line + 1}, column {mark.column + 1}" if mark is not None else ""
        raise RunFileError(path, f"not valid YAML ({problem or _one_line(err)}{where})") from None


def load_overrides(run_dir: str | os.PathLike) -> list[str]:
    """The run's Hydra overrides (``.hydra/overrides.yaml``), [] when the file is absent."""
    path = Path(run_dir) / OVERRIDES_FILE
    if not path.exists():
        return []
    data = _load_yaml(path)
    if not isinstance(data, list):
        raise RunFileError(path, f"{_kind(data, 'a mapping')}, expected a list of overrides")
    bad = next((item for item in data if isinstance(item, (list, dict)) or item is None), _MISSING)
    if bad is not _MISSING:
        raise RunFileError(path, f"an entry is {_shown(bad)} ({_kind(bad, 'a mapping')}), expected an override "
                                 "such as key=value")
    return [str(item) for item in data]


def load_config(run_dir: str | os.PathLike) -> dict[str, Any]:
    """The run's resolved config (``.hydra/config.yaml``), {} when the file is absent."""
    path = Path(run_dir) / CONFIG_FILE
    if not path.exists():
        return {}
    data = _load_yaml(path)
    if not isinstance(data, dict):
        raise RunFileError(path, f"{_kind(data, 'a mapping')}, expected a mapping")
    return data


def warn(error: RunFileError, consequence: str) -> None:
    """The one warning line of a damaged file: the file, what is wrong, what the tool does."""
    log.warning("warning: %s; %s", error, consequence)


def _or_warning(load: Any, run_dir: str | os.PathLike, consequence: str) -> Any:
    """``load(run_dir)``, or None after one warning line naming the damaged file."""
    try:
        return load(run_dir)
    except RunFileError as err:
        warn(err, consequence)
        return None


def read_run_info(run_dir: str | os.PathLike, consequence: str = "run skipped") -> dict[str, Any] | None:
    """:func:`load_run_info`, or None after a warning naming the file."""
    return _or_warning(load_run_info, run_dir, consequence)


def read_metrics(run_dir: str | os.PathLike, consequence: str = "run skipped") -> dict[str, Any] | None:
    """:func:`load_metrics`, or None after a warning naming the file."""
    return _or_warning(load_metrics, run_dir, consequence)


def read_overrides(run_dir: str | os.PathLike, consequence: str = "its overrides left out") -> list[str] | None:
    """:func:`load_overrides`, or None after a warning naming the file."""
    return _or_warning(load_overrides, run_dir, consequence)


def read_config(run_dir: str | os.PathLike, consequence: str = "its config left out") -> dict[str, Any] | None:
    """:func:`load_config`, or None after a warning naming the file."""
    return _or_warning(load_config, run_dir, consequence)


def resume_origin(checkpoint: str | os.PathLike, steps: int) -> dict[str, Any]:
    """Where a resumed run's first ``steps`` were trained: the run folder that wrote ``checkpoint``
    (``<run>/checkpoints/<file>``), its machine and its learner's device, and, if that run was itself
    resumed, its own origin (``resumed_from``, a chain). A checkpoint outside a run folder, or a
    folder whose files are damaged, gives what can be read (the checkpoint and the steps at least)."""
    checkpoint = Path(checkpoint)
    run_dir = checkpoint.parent.parent
    origin: dict[str, Any] = {"checkpoint": str(checkpoint), "steps": int(steps)}
    info = read_run_info(run_dir, "its machine is not recorded") if (run_dir / RUN_FILE).is_file() else None
    if info:
        versions = info.get("versions") or {}
        origin.update({"run": str(run_dir), "host": info.get("host"), "platform": info.get("platform"),
                       "python": versions.get("python"), "torch": versions.get("torch"),
                       "started": info.get("started"), "finished": info.get("finished")})
    metrics = read_metrics(run_dir, "its device is not recorded") if (run_dir / METRICS_FILE).is_file() else None
    if metrics:
        origin["device"] = metrics.get("device")
        if isinstance(metrics.get("resumed_from"), dict):
            origin["resumed_from"] = metrics["resumed_from"]
    return origin

