"""The catalogue of the results page, ``conf/results.yaml``: its entries read and checked, and what an
entry's command sweeps against what its runs carried (overrides the command does not give, swept
values no run carries). Reads the command and the overlays as text: no composition.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Any

from aslexp.paths import CONF_DIR
from aslexp.results import kinds

CATALOGUE = CONF_DIR / "results.yaml"
_REQUIRED = ("id", "title", "beside", "thesis", "overlay", "job", "command", "engine", "reward", "report",
             "runs", "earlier")
# Overrides that name where a run goes or how it is watched, not what it runs.
NOT_WHAT = ("hydra.", "hydra/")


def command_overrides(command: str) -> tuple[str, list[str]]:
    """(job, overrides) of ``aslexp JOB [-m] OVERRIDE...`` (shell words; ``-m`` dropped)."""
    words = shlex.split(command)
    if len(words) < 2 or words[0] != "aslexp":
        raise ValueError(f"not an aslexp command: {command!r}")
    return words[1], [w for w in words[2:] if w not in ("-m", "--multirun")]


def load_catalogue(path: str | Path = CATALOGUE) -> list[dict[str, Any]]:
    """The entries of ``conf/results.yaml``, checked: every key present, ids unique and usable as
    file names, a known report (an entry's ``module:`` is imported first: it registers its kind),
    ``runs`` a list of ``{folders: [...], machine: ...}``."""
    import yaml

    data = yaml.safe_load(Path(path).read_text(encoding="utf-8")) or {}
    entries = data.get("entries")
    if not isinstance(entries, list) or not entries:
        raise ValueError(f"{path}: no 'entries' list")
    seen: set[str] = set()
    for entry in entries:
        missing = [key for key in _REQUIRED if key not in entry]
        where = f"{path}: entry {entry.get('id', '?')}"
        if missing:
            raise ValueError(f"{where}: missing {missing}")
        if not re.fullmatch(r"[a-z0-9_]+", str(entry["id"])) or entry["id"] in seen:
            raise ValueError(f"{where}: the id must be unique, lower case, digits and _")
        seen.add(entry["id"])
        if entry.get("module"):  # the module that registers the entry's report kind
            kinds.import_kind(str(entry["report"]), str(entry["module"]))
        if entry["report"] not in kinds.known():
            raise ValueError(f"{where}: unknown report {entry['report']!r} (known: {', '.join(kinds.known())})")
        runs = entry["runs"]
        if not isinstance(runs, list) or not all(isinstance(r, dict) and isinstance(r.get("folders"), list)
                                                 for r in runs):
            raise ValueError(f"{where}: runs must be a list of {{folders: [...], machine: ...}}")
        earlier = entry["earlier"]
        if not isinstance(earlier, dict) or not str(earlier.get("link", "")).startswith("docs/"):
            raise ValueError(f"{where}: earlier must be {{link: docs/...#anchor, section: title}}")
        figures = entry.get("figures") or []
        if not isinstance(figures, list) or not all(
                isinstance(f, dict) and str(f.get("path", "")).startswith("docs/") and f.get("caption")
                for f in figures):
            raise ValueError(f"{where}: figures must be a list of {{path: docs/..., caption: text}}")
        entry["options"] = entry.get("options") or {}
    return entries


def _split_values(value: str) -> list[str]:
    """A sweep value's choices (``a,b,'c,d'`` -> a, b, c,d), quotes taken off; one value unchanged."""
    parts, depth, quote, current = [], 0, "", ""
    for char in value:
        if quote:
            if char == quote:
                quote = ""
            else:
                current += char
            continue
        if char in "'\"":
            quote = char
        elif char in "[(" or char == "{":
            depth += 1
            current += char
        elif char in "])}":
            depth -= 1
            current += char
        elif char == "," and depth == 0:
            parts.append(current)
            current = ""
        else:
            current += char
    parts.append(current)
    # Hydra's multirun records a boolean as Python writes it (False); the command as YAML does (false)
    return [{"True": "true", "False": "false"}.get(p.strip(), p.strip()) for p in parts]


def _key_values(overrides: list[str]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for override in overrides:
        key, _, value = override.partition("=")
        key = key.lstrip("+~")
        if key.startswith(NOT_WHAT):
            continue
        out[key] = _split_values(value)
    return out


def uncovered_overrides(command: str, ran: dict[str, Any]) -> list[str]:
    """The runs' overrides that the command does not give: a key it sets to other values (a key
    it leaves to the overlay, as the swept motion and seed, is covered)."""
    _, words = command_overrides(command)
    given = _key_values(words)
    missing = []
    for override in ran.get("common", []):
        key, _, value = override.partition("=")
        key = key.lstrip("+~")
        if key.startswith(NOT_WHAT):
            continue
        if key not in given or _split_values(value) != given[key]:
            missing.append(override)
    for key, values in sorted((ran.get("varied") or {}).items()):
        if key in given and not set(values) <= set(given[key]):
            missing.append(f"{key}={','.join(values)}")
    return missing


def swept_values(command: str, overlay: str, conf_dir: Path = CONF_DIR) -> dict[str, list[str]]:
    """Per key the values the command sweeps: its own comma lists, else the overlay's
    ``hydra.sweeper.params`` (read from ``conf/experiment/<overlay>.yaml`` and the overlays it lists
    in its defaults, the later winning; no composition)."""
    from omegaconf import OmegaConf

    swept: dict[str, list[str]] = {}
    for path in _overlay_chain(Path(conf_dir) / "experiment", overlay):
        params = OmegaConf.select(OmegaConf.load(path), "hydra.sweeper.params", default=None)
        for key, value in (OmegaConf.to_container(params) if params else {}).items():
            values = _split_values(str(value))
            if len(values) > 1:
                swept[key] = values
    _, words = command_overrides(command)
    for key, values in _key_values(words).items():
        if len(values) > 1:
            swept[key] = values
        else:
            swept.pop(key, None)
    return swept


def _overlay_chain(folder: Path, overlay: str, seen: tuple[str, ...] = ()) -> list[Path]:
    """``folder/<overlay>.yaml`` after the overlays its defaults list names (parents first)."""
    from omegaconf import OmegaConf

    path = folder / f"{overlay}.yaml"
    if not path.is_file() or overlay in seen:
        return []
    chain: list[Path] = []
    for item in OmegaConf.to_container(OmegaConf.load(path)).get("defaults") or []:
        if isinstance(item, str) and item != "_self_" and (folder / f"{item}.yaml").is_file():
            chain += _overlay_chain(folder, item, (*seen, overlay))
    return chain + [path]


def unrun_values(command: str, overlay: str, ran: dict[str, Any], conf_dir: Path = CONF_DIR) -> list[str]:
    """``key=value`` for each value the command sweeps that no run carries (the runs' overrides:
    those all share and those that vary); a swept key the runs never set is not judged."""
    common = _key_values(ran.get("common") or [])
    varied = {k.lstrip("+~"): set(v) for k, v in (ran.get("varied") or {}).items()}
    missing = []
    for key, values in swept_values(command, overlay, conf_dir).items():
        if key not in common and key not in varied:
            continue
        unquoted = {str(v).strip("'\"") for v in set(common.get(key, [])) | varied.get(key, set())}  # '00433' is 00433
        missing += [f"{key}={v}" for v in values if str(v).strip("'\"") not in unquoted]
    return missing
