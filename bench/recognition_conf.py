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


PRIMARY_GROUPS = {"data": "asllex2", "pose": "mediapipe_pose", "split": "phoneme", "trainer": None}
_BY_PROPERTY = re.compile(r"^\$\{classifier\.by_property\.\$\{property\.name\}\.(\w+)\}$")
_SELECT_BATCH = re.compile(r"^\$\{oc\.select:classifier\.batch_size,(\d+)\}$")


def _experiment_layers(name: str) -> tuple[dict[str, str], list[dict[str, Any]]]:
    """Group overrides and value layers of conf/experiment/<name>.yaml and what it includes."""
    raw = read_yaml(CONF / "experiment" / f"{name}.yaml")
    overrides: dict[str, str] = {}
    layers: list[dict[str, Any]] = []
    for entry in raw.pop("defaults", []) or []:
        if isinstance(entry, str):  # another overlay of the group, e.g. thesis_ch3_protocol
            included_overrides, included_layers = _experiment_layers(entry)
            overrides.update(included_overrides)
            layers += included_layers
        else:
            for key, value in entry.items():
                overrides[key.replace("override", "").strip().strip("/").split("@")[0]] = str(value)
    layers.append(raw)
    return overrides, layers


def resolve_classifier(name: str, prop: str) -> tuple[str, dict[str, Any], str, int | None]:
    """(model, params, trainer preset, batch size or None) of a classifier config for a property,
    resolving the per-property interpolations the *_thesis_ch3 configs use."""
    raw = read_yaml(CONF / "classifier" / f"{name}.yaml")
    model, params, preset = classifier_config(name)

    def resolve(value: Any) -> Any:
        if isinstance(value, str) and value.startswith("${"):
            match = _BY_PROPERTY.match(value)
            if not match:
                raise ValueError(f"conf/classifier/{name}.yaml: {value!r} needs Hydra to resolve")
            return raw["by_property"][prop][match.group(1)]
        return value

    batch = raw.get("batch_size")
    return model, {k: resolve(v) for k, v in params.items()}, preset, None if batch is None else int(resolve(batch))


def experiment_plan(name: str) -> dict[str, Any]:
    """What `aslexp recognize experiment=<name>` composes, without Hydra: the group choices, the
    values the overlay sets, and the multirun's lists (classifier, property, split)."""
    overrides, layers = _experiment_layers(name)
    choices = {**PRIMARY_GROUPS, **overrides}
    values: dict[str, Any] = {}
    for layer in layers:
        for key, value in layer.items():
            if key == "hydra":
                values["sweep"] = {**values.get("sweep", {}), **(value.get("sweeper", {}).get("params") or {})}
            elif isinstance(value, dict):
                values[key] = {**values.get(key, {}), **value}
            else:
                values[key] = value
    sweep = values.pop("sweep", {})

    def listed(key: str, default: str) -> list[str]:
        return [item.strip() for item in str(sweep.get(key, default)).split(",")]

    return {
        "choices": choices,
        "data": {**read_yaml(CONF / "data" / f"{choices['data']}.yaml"), **values.get("data", {})},
        "pose": {**read_yaml(CONF / "pose" / f"{choices['pose']}.yaml"), **values.get("pose", {})},
        "split_values": values.get("split", {}),
        "trainer_preset": choices.get("trainer"),
        "trainer_values": values.get("trainer", {}),
        "n_seeds": int(values.get("n_seeds", 1)),
        "classifiers": listed("classifier", "stgcn"),
        "properties": listed("property", "sign_type"),
        "splits": listed("split", choices["split"]),
    }


def trainer_for(plan: dict[str, Any], classifier_preset: str, batch_size: int | None) -> dict[str, Any]:
    """The trainer of one cell: the experiment's /trainer override wins over the classifier's own
    (as Hydra composes it), then the experiment's trainer values."""
    trainer = trainer_config(plan["trainer_preset"] or classifier_preset)
    trainer.update(plan["trainer_values"])
    match = _SELECT_BATCH.match(str(trainer.get("batch_size")))
    if match:
        trainer["batch_size"] = batch_size if batch_size is not None else int(match.group(1))
    return trainer
