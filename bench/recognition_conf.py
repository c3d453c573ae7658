"""The recognition settings of conf/ for the benchmarks, read without Hydra (a GPU node may have
neither Hydra, OmegaConf nor PyYAML): the same YAML files, so conf/ stays the one source.

``classifier_config(name)`` -> (model name, params, trainer preset); ``trainer_config(preset)`` ->
the trainer dict with its ``defaults`` applied. PyYAML is used when installed; otherwise a reader
of the plain subset these files use (mappings by indentation, scalars, inline [lists] and {maps},
comments). Interpolations (``${...}``) are not resolved: configs that use them (the *_thesis_ch3
ones) need Hydra.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path
from typing import Any

CONF = Path(__file__).resolve().parents[1] / "conf"


def _scalar(text: str) -> Any:
    text = text.strip()
    if text == "" or text in ("null", "~"):
        return None
    if text in ("true", "false"):
        return text == "true"
    if text[0] in "[{":
        inner = text[1:-1].strip()
        if not inner:
            return [] if text[0] == "[" else {}
        parts = _split(inner)
        if text[0] == "[":
            return [_scalar(part) for part in parts]
        return {key.strip(): _scalar(value) for key, value in (part.split(":", 1) for part in parts)}
    if text[0] in "'\"":
        return ast.literal_eval(text)
    try:
        return int(text)
    except ValueError:
        pass
    try:
        return float(text)
    except ValueError:
        return text


def _split(text: str) -> list[str]:
    """Comma-separated parts at bracket depth 0."""
    parts, depth, current = [], 0, ""
    for char in text:
        depth += char in "[{"
        depth -= char in "]}"
        if char == "," and depth == 0:
            parts.append(current)
            current = ""
        else:
            current += char
    return parts + [current]


def read_yaml(path: Path) -> dict[str, Any]:
    try:
        import yaml
    except ImportError:
        yaml = None
    text = path.read_text(encoding="utf-8")
    if yaml is not None:
        return yaml.safe_load(text) or {}
    root: dict[str, Any] = {}
    stack: list[tuple[int, Any]] = [(-1, root)]
    for raw in text.splitlines():
        line = re.sub(r"\s+#.*$", "", raw) if not raw.lstrip().startswith("#") else ""
        if not line.strip():
            continue
        indent = len(line) - len(line.lstrip())
        while stack[-1][0] >= indent:
            stack.pop()
        parent = stack[-1][1]
        body = line.strip()
        if body.startswith("- "):
            parent.append(_scalar(body[2:]) if ":" not in body[2:] else dict([_pair(body[2:])]))
            continue
        key, value = _pair(body)
        if value is None and not body.rstrip().endswith(("null", "~")):
            child: Any = [] if _next_is_list(text, raw) else {}
            parent[key] = child
            stack.append((indent, child))
        else:
            parent[key] = value
    return root


def _pair(body: str) -> tuple[str, Any]:
    key, _, value = body.partition(":")
    return key.strip(), _scalar(value)


def _next_is_list(text: str, line: str) -> bool:
    lines = text.splitlines()
    index = lines.index(line)
    following = [entry for entry in lines[index + 1 :] if entry.strip() and not entry.strip().startswith("#")]
    return bool(following) and following[0].strip().startswith("- ")


def trainer_config(preset: str) -> dict[str, Any]:
    """conf/trainer/<preset>.yaml with its defaults list applied (``- default`` first)."""
    raw = read_yaml(CONF / "trainer" / f"{preset}.yaml")
    merged: dict[str, Any] = {}
    for entry in raw.pop("defaults", []) or []:
        if isinstance(entry, str) and entry != "_self_":
            merged.update(trainer_config(entry))
    merged.update(raw)
    return merged


def classifier_config(name: str) -> tuple[str, dict[str, Any], str]:
    """(model name, params, trainer preset) of conf/classifier/<name>.yaml."""
    raw = read_yaml(CONF / "classifier" / f"{name}.yaml")
    preset = "default"
    for entry in raw.get("defaults", []) or []:
        if isinstance(entry, dict):
            for key, value in entry.items():
                if "/trainer" in key:
                    preset = str(value)
    return str(raw["name"]), dict(raw.get("params") or {}), preset
