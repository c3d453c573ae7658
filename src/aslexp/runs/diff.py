"""The difference of two runs: ``aslexp runs diff RUN_A RUN_B``.

Compares the resolved configs key by key (nested paths such as ``model.layers[1].units``),
the overrides, the recorded context (git commit, seed, host, library versions) and the main
metrics. Works on any two run directories, including trials of a sweep.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from aslexp.runs.read import load_config, load_overrides, load_run_info
from aslexp.runs.record import RUN_FILE

_MISSING = object()


class NotARunError(ValueError):
    """A path that is not a run directory."""


@dataclass
class RunDiff:
    a: Path
    b: Path
    changed: dict[str, tuple[Any, Any]] = field(default_factory=dict)
    added: dict[str, Any] = field(default_factory=dict)      # in B only
    removed: dict[str, Any] = field(default_factory=dict)    # in A only
    overrides_a_only: list[str] = field(default_factory=list)
    overrides_b_only: list[str] = field(default_factory=list)
    context: dict[str, tuple[Any, Any]] = field(default_factory=dict)
    metric: dict[str, Any] = field(default_factory=dict)

    @property
    def same_config(self) -> bool:
        return not (self.changed or self.added or self.removed)

    def as_dict(self) -> dict[str, Any]:
        return {"a": str(self.a), "b": str(self.b),
                "changed": {k: list(v) for k, v in self.changed.items()},
                "added": self.added, "removed": self.removed,
                "overrides": {"a_only": self.overrides_a_only, "b_only": self.overrides_b_only},
                "context": {k: list(v) for k, v in self.context.items()},
                "metric": self.metric}


def flatten(node: Any, prefix: str = "") -> dict[str, Any]:
    """Nested dicts and lists as ``{"a.b[0].c": leaf}``; empty containers are leaves."""
    flat: dict[str, Any] = {}
    if isinstance(node, dict) and node:
        for key, value in node.items():
            flat.update(flatten(value, f"{prefix}.{key}" if prefix else str(key)))
    elif isinstance(node, list) and node:
        for index, value in enumerate(node):
            flat.update(flatten(value, f"{prefix}[{index}]"))
    else:
        flat[prefix] = node
    return flat


def diff_mappings(a: dict[str, Any], b: dict[str, Any]) -> tuple[dict, dict, dict]:
    """(changed, added, removed) between two nested mappings, keyed by flattened path."""
    fa, fb = flatten(a), flatten(b)
    changed = {k: (fa[k], fb[k]) for k in fa.keys() & fb.keys() if not _equal(fa[k], fb[k])}
    added = {k: fb[k] for k in fb.keys() - fa.keys()}
    removed = {k: fa[k] for k in fa.keys() - fb.keys()}
    return dict(sorted(changed.items())), dict(sorted(added.items())), dict(sorted(removed.items()))


def _equal(x: Any, y: Any) -> bool:
    if isinstance(x, float) and isinstance(y, float) and math.isnan(x) and math.isnan(y):
        return True
    return type(x) is type(y) and x == y or (
        isinstance(x, (int, float)) and isinstance(y, (int, float))
        and not isinstance(x, bool) and not isinstance(y, bool) and x == y)


def _load_run(path: str | os.PathLike) -> tuple[Path, dict[str, Any]]:
    path = Path(path)
    if not path.is_dir():
        raise NotARunError(f"{path}: no such directory")
    if not (path / RUN_FILE).exists() and not (path / ".hydra" / "config.yaml").exists():
        raise NotARunError(f"{path} is not a run directory (no {RUN_FILE}, no .hydra/config.yaml)")
    info = load_run_info(path) if (path / RUN_FILE).exists() else {}
    return path, info


def _context(info: dict[str, Any]) -> dict[str, Any]:
    git = info.get("git") or {}
    flat = {"job": info.get("job"), "status": info.get("status"), "seed": info.get("seed"),
            "host": info.get("host"), "git.commit": git.get("commit"), "git.dirty": git.get("dirty")}
    for name, version in (info.get("versions") or {}).items():
        flat[f"versions.{name}"] = version
    return flat


def _metric(info_a: dict[str, Any], info_b: dict[str, Any]) -> dict[str, Any]:
    ma, mb = info_a.get("main_metric") or {}, info_b.get("main_metric") or {}
    result: dict[str, Any] = {"name_a": ma.get("name"), "name_b": mb.get("name"),
                              "a": ma.get("value"), "b": mb.get("value"),
                              "goal": ma.get("goal") or mb.get("goal"), "delta": None,
                              "better": None}
    va, vb = ma.get("value"), mb.get("value")
    if (ma.get("name") == mb.get("name") and isinstance(va, (int, float))
            and isinstance(vb, (int, float)) and math.isfinite(va) and math.isfinite(vb)):
        result["delta"] = vb - va
        if vb == va:
            result["better"] = "same"
        else:
            maximise = (result["goal"] or "maximize") == "maximize"
            result["better"] = "b" if (vb > va) == maximise else "a"
    return result


# Config keys that define what a main metric measures (the data, the task, the protocol): runs
# that differ in one are not comparable by that number.
EVALUATION_KEYS = ("split", "property", "data.root", "data.lexicon", "data.movement_none_as_missing",
                   "pose", "motion", "body", "reward", "engine",
                   "tuning.motion", "tuning.random", "tuning.objective", "tuning.steps",
                   "ppo.eval_steps", "ppo.eval_episodes", "ppo.phases")


def not_comparable(keys: list[str]) -> list[str]:
    """The keys among ``keys`` (dotted) that change what the main metric measures."""
    return [k for k in keys if any(k == e or k.startswith(e + ".") for e in EVALUATION_KEYS)]


def diff_runs(a: str | os.PathLike, b: str | os.PathLike) -> RunDiff:
    path_a, info_a = _load_run(a)
    path_b, info_b = _load_run(b)
    changed, added, removed = diff_mappings(load_config(path_a), load_config(path_b))
    over_a, over_b = load_overrides(path_a), load_overrides(path_b)
    ctx_a, ctx_b = _context(info_a), _context(info_b)
    context = {k: (ctx_a.get(k), ctx_b.get(k)) for k in sorted(ctx_a.keys() | ctx_b.keys())
               if ctx_a.get(k) != ctx_b.get(k)}
    result = RunDiff(a=path_a, b=path_b, changed=changed, added=added, removed=removed,
                   overrides_a_only=[o for o in over_a if o not in over_b],
                   overrides_b_only=[o for o in over_b if o not in over_a],
                   context=context, metric=_metric(info_a, info_b))
    differs = not_comparable([*changed, *added, *removed])
    if differs and result.metric.get("better") is not None:
        result.metric["better"] = None
        result.metric["not_comparable"] = differs
    return result


def _show(value: Any) -> str:
    return json.dumps(value, default=str) if not isinstance(value, str) else value


def format_diff(d: RunDiff) -> str:
    lines = [f"A: {d.a}", f"B: {d.b}", ""]
    if d.same_config:
        lines.append("config: identical")
    else:
        lines.append(f"config: {len(d.changed)} changed, {len(d.added)} added, "
                     f"{len(d.removed)} removed")
        lines += [f"  ~ {k}: {_show(va)} -> {_show(vb)}" for k, (va, vb) in d.changed.items()]
        lines += [f"  + {k}: {_show(v)}" for k, v in d.added.items()]
        lines += [f"  - {k}: {_show(v)}" for k, v in d.removed.items()]
    if d.overrides_a_only or d.overrides_b_only:
        lines.append("overrides:")
        lines += [f"  A only: {o}" for o in d.overrides_a_only]
        lines += [f"  B only: {o}" for o in d.overrides_b_only]
    if d.context:
        lines.append("recorded context:")
        lines += [f"  ~ {k}: {_show(va)} -> {_show(vb)}" for k, (va, vb) in d.context.items()]
    m = d.metric
    if m.get("name_a") or m.get("name_b"):
        name = m["name_a"] if m["name_a"] == m["name_b"] else f"{m['name_a']} / {m['name_b']}"
        text = f"main metric {name} ({m.get('goal') or '?'}): A {_show(m['a'])}  B {_show(m['b'])}"
        if m.get("not_comparable"):
            shown = ", ".join(m["not_comparable"][:4]) + (", ..." if len(m["not_comparable"]) > 4 else "")
            text += f"  (not comparable: they differ in {shown})"
        elif m["delta"] is not None:
            text += f"  delta {m['delta']:+.6g}"
            text += "  (same)" if m["better"] == "same" else f"  ({m['better'].upper()} is better)"
        lines.append(text)
    else:
        lines.append("main metric: not recorded")
    return "\n".join(lines)
