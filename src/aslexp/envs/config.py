"""Config groups without Hydra: ``gym.make`` and tests name a group file or pass a dict.

A name (``"hand15"``) reads ``conf/<group>/<name>.yaml`` (following a group file's own
``defaults`` list of same-group names, as Hydra would; a body's choices of other groups are
:func:`body_groups`); a dict is merged over the group's
default file, so a partial dict changes only what it names. The jobs pass fully composed
dicts from Hydra, so both paths read the same YAML: the configuration lives in one place.
"""

from __future__ import annotations

import copy
from typing import Any

import yaml

from aslexp import paths

CONF_DIR = paths.CONF_DIR


def job_defaults(job: str) -> dict[str, str]:
    """The group choices of ``conf/<job>.yaml``'s defaults list (``{"engine": "pybullet", ...}``):
    the defaults below Hydra are the job's own, written once."""
    with open(CONF_DIR / f"{job}.yaml", encoding="utf-8") as fh:
        entries = (yaml.safe_load(fh) or {}).get("defaults") or []
    return {key: value for entry in entries if isinstance(entry, dict) for key, value in entry.items()
            if isinstance(value, str) and "/" not in key and " " not in key}


def body_groups(body: str) -> dict[str, str]:
    """The groups a body brings (``{"controller": "upper_body", ...}``): its file's ``override
    /GROUP@_global_.GROUP: NAME`` defaults, its same-group parents' first (as Hydra composes them)."""
    path = CONF_DIR / "body" / f"{body}.yaml"
    if not path.is_file():
        return {}
    with open(path, encoding="utf-8") as fh:
        entries = (yaml.safe_load(fh) or {}).get("defaults") or []
    groups: dict[str, str] = {}
    for entry in entries:
        if isinstance(entry, str) and entry != "_self_":
            groups.update(body_groups(entry))
        elif isinstance(entry, dict):
            for key, value in entry.items():
                if key.startswith("override /"):
                    groups[key.removeprefix("override /").split("@", 1)[0]] = value
    return groups


_JOB = job_defaults("imitate")
DEFAULTS = {**_JOB, **body_groups(_JOB["body"]), "ppo": "base"}  # ppo: every key's default (ppo/base)


def deep_merge(base: dict[str, Any], override: dict[str, Any]) -> dict[str, Any]:
    """``override`` over ``base`` (nested dicts merged, everything else replaced)."""
    out = copy.deepcopy(base)
    for key, value in override.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict) and value:
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def load_group_file(group: str, name: str) -> dict[str, Any]:
    """Read ``conf/<group>/<name>.yaml`` with its same-group ``defaults`` list applied."""
    path = CONF_DIR / group / f"{name}.yaml"
    if not path.is_file():
        available = sorted(p.stem for p in (CONF_DIR / group).glob("*.yaml"))
        raise FileNotFoundError(f"no {group} config {name!r} ({path}); available: {available}")
    with open(path, encoding="utf-8") as fh:
        values = yaml.safe_load(fh) or {}
    defaults = values.pop("defaults", None)
    if not defaults:
        return values
    merged: dict[str, Any] = {}
    for entry in defaults:
        if isinstance(entry, dict):  # another group's choice (a body's controller): body_groups reads it
            continue
        merged = deep_merge(merged, values if entry == "_self_" else load_group_file(group, entry))
    if "_self_" not in defaults:
        merged = deep_merge(merged, values)
    return merged


def resolve_group(group: str, value: str | dict[str, Any] | None, default: str | None = None) -> dict[str, Any]:
    """A group's config from a name, a (partial) dict or None (``default``, else the group default)."""
    default = default or DEFAULTS[group]
    if value is None:
        return load_group_file(group, default)
    if isinstance(value, str):
        return load_group_file(group, value)
    if isinstance(value, dict):
        return deep_merge(load_group_file(group, default), value)
    raise TypeError(f"{group} config must be a name, a dict or None, got {type(value).__name__}")
