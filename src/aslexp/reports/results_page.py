"""The results page, ``docs/results.md``: one table per result of the catalogue ``conf/results.yaml``,
rendered from committed snapshots (``docs/results/<id>.json``) that are made from run folders.

    aslexp report --results [--outputs outputs] [--render-only]

For each entry of the catalogue, the first of its ``runs`` alternatives whose folders (under
``--outputs``) hold completed runs is summarised by the entry's ``report``:

* ``thesis``: per motion, the thesis' number (:func:`aslexp.reports.thesis_report.thesis_number`), every
  no-learning baseline of the overlay's ``report.baselines`` (:func:`~aslexp.reports.thesis_report.motion_baselines`,
  cached beside the runs as the thesis report caches them; aslexp's own controllers are the simple
  baselines) and the learned policies' last evaluation over seeds;
* ``scratch``: the same with the baselines each run measured (metrics.json ``baselines``);
* ``residual``: the comparison rows of :func:`aslexp.reports.residual_report.residual_baselines`
  (the controller and the same on a pinned base; the best smoothed reference and constant random
  corrections as simple baselines);
* ``recognition`` and ``recognition_per_class``: given by the caller (``aslexp.tools.report``, which
  reads recognition runs); :mod:`aslexp.reports.results_recognition` adds each row's test clips, its
  interval, the "no better than chance" mark and the line "Differences from the thesis";
* ``retrieval``: an ``aslexp retrieve`` run's table (:mod:`aslexp.reports.results_retrieval`: one row
  per method, recall@k, MRR and median rank over gloss splits, and where the issue's targets land);
* ``seen_glosses``: an ``aslexp glosses`` run's table (:mod:`aslexp.reports.results_seen_glosses`: one
  row per method, top-k over splits stratified by gloss, the paired effect of the auxiliary heads).

The snapshot holds numbers (fractions; the page prints percentages where the entry says so), the
run folders it came from (relative to ``--outputs``), when the runs started and finished, where
they ran (run.json's host and platform, metrics.json's device, the catalogue's machine label where
the folders do not say), the engine and reward they composed (``.hydra/hydra.yaml``), their git
commits and their overrides. An entry whose folders are gone keeps its snapshot; one with neither
is "not run on this machine yet", with a link to where earlier numbers were typed. The page is a
function of the catalogue and the snapshots alone: rendering twice gives the same bytes.
"""

from __future__ import annotations

import datetime as _dt
import json
import logging
import math
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.files import atomic_write_text
from aslexp.paths import CONF_DIR
from aslexp.reports import results_recognition, results_retrieval, results_seen_glosses, results_signing
from aslexp.reports.job_table import read_json
from aslexp.reports.commands import command_overrides  # noqa: F401 - part of this module's interface
from aslexp.runfile import RUN_FILE, machines

log = logging.getLogger(__name__)

CATALOGUE = CONF_DIR / "results.yaml"
PAGE = Path("docs") / "results.md"
SNAPSHOTS = Path("docs") / "results"
SNAPSHOT_SCHEMA = 1
IMITATION_REPORTS = ("thesis", "scratch", "residual")
RECOGNITION_REPORTS = ("recognition", "recognition_per_class")
# One job run's own table (`aslexp retrieve`: aslexp.reports.results_retrieval; `aslexp glosses`:
# aslexp.reports.results_seen_glosses; `aslexp signing`: aslexp.reports.results_signing), each module with results_summary and render; such an entry
# may name no overlay (overlay: null): the job's defaults are its setting.
JOB_TABLE_REPORTS = {module.REPORT: module for module in (results_retrieval, results_seen_glosses, results_signing)}
_REQUIRED = ("id", "title", "beside", "thesis", "overlay", "job", "command", "engine", "reward", "report",
             "runs", "earlier")
# Overrides that name where a run goes or how it is watched, not what it runs.
_NOT_WHAT = ("hydra.", "hydra/")

Summarizer = Callable[[dict[str, Any], list[Path]], dict[str, Any]]


# --------------------------------------------------------------------------- the catalogue


def load_catalogue(path: str | Path = CATALOGUE) -> list[dict[str, Any]]:
    """The entries of ``conf/results.yaml``, checked: every key present, ids unique and usable as
    file names, a known report, ``runs`` a list of ``{folders: [...], machine: ...}``."""
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
        if entry["report"] not in IMITATION_REPORTS + RECOGNITION_REPORTS + tuple(JOB_TABLE_REPORTS):
            raise ValueError(f"{where}: unknown report {entry['report']!r}")
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
        if key.startswith(_NOT_WHAT):
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
        if key.startswith(_NOT_WHAT):
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


# --------------------------------------------------------------------------- run folders


def entry_folders(entry: dict[str, Any], outputs: Path) -> tuple[list[Path], dict[str, Any]]:
    """The folders of the first ``runs`` alternative under ``outputs`` that holds a completed run
    (globs expanded, sorted), and that alternative; ([], {}) when none does."""
    for alternative in entry["runs"]:
        folders: list[Path] = []
        for pattern in alternative["folders"]:
            folders += sorted(p for p in Path(outputs).glob(str(pattern)) if p.is_dir())
        folders = list(dict.fromkeys(folders))
        if any(_completed(path.parent) for folder in folders for path in folder.rglob(RUN_FILE)):
            return folders, alternative
    return [], {}


def _completed(run_dir: Path) -> bool:
    info = read_json(run_dir / RUN_FILE)
    return isinstance(info, dict) and info.get("status") == "completed"


def hydra_choices(run_dir: Path) -> dict[str, str]:
    """The config group options a run composed (``.hydra/hydra.yaml``: hydra.runtime.choices)."""
    import yaml

    path = Path(run_dir) / ".hydra" / "hydra.yaml"
    try:
        loaded = yaml.safe_load(path.read_text(encoding="utf-8")) or {}
    except (OSError, yaml.YAMLError):
        return {}
    choices = ((loaded.get("hydra") or {}).get("runtime") or {}).get("choices") or {}
    return {str(k): str(v) for k, v in choices.items() if not str(k).startswith("hydra/")}


def _utc(stamp: str | None) -> _dt.datetime | None:
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
    started = [t for t in (_utc(i.get("started")) for i in infos) if t]
    finished = [t for t in (_utc(i.get("finished")) for i in infos) if t]
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
    overrides = [[o for o in (i.get("overrides") or []) if not o.startswith(_NOT_WHAT)] for i in infos]
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


# --------------------------------------------------------------------------- imitation snapshots


def _round(value: Any, digits: int = 6) -> Any:
    if value is None:
        return None
    value = float(value)
    return round(value, digits) if math.isfinite(value) else None


def _imitation_runs(folders: list[Path]) -> tuple[dict[str, list[dict[str, Any]]], dict[str, int]]:
    """Completed imitation runs under ``folders`` by motion (:func:`aslexp.reports.report.read_runs`),
    and what was left out."""
    from aslexp.reports.report import read_runs

    runs: dict[str, list[dict[str, Any]]] = {}
    skipped: dict[str, int] = {}
    for folder in folders:
        try:
            found = read_runs(folder)
        except FileNotFoundError:
            continue
        for motion, items in found.items():
            for metrics in items:
                info = read_json(Path(metrics["run_dir"]) / RUN_FILE) or {}
                if info.get("status") != "completed":
                    reason = f"status {info.get('status', 'unknown')}"
                    skipped[reason] = skipped.get(reason, 0) + 1
                    continue
                runs.setdefault(motion, []).append(metrics)
    return dict(sorted(runs.items())), skipped


def _thesis_baselines(entry, cfg, motion, items, cache) -> tuple[list[dict[str, Any]], str, float | None]:
    from aslexp.reports.report import ended_early
    from aslexp.reports.thesis_report import baseline_column, motion_baselines, thesis_number

    rows = motion_baselines(cfg, cache, items)
    baselines = [{"label": re.sub(r"^aslexp: ", "aslexp's ", baseline_column(b)),
                  "kind": "simple" if b["aslexp"] else "no-learning",
                  "value": _round(b["reward"]), **({"note": ended_early(b)} if ended_early(b) else {}),
                  **({"scores": {k: _round(v) for k, v in b["scores"].items()}} if b.get("scores") else {})}
                 for b in rows]
    text, value = thesis_number((cfg.get("report") or {}).get("thesis", "letters"), motion)
    return baselines, text, value


def _scratch_baselines(entry, cfg, motion, items, cache) -> tuple[list[dict[str, Any]], str, float | None]:
    labels = (entry.get("options") or {}).get("baselines") or {}
    names = list(dict.fromkeys(k for m in items for k in m.get("baselines", {})))
    baselines = [{"label": labels.get(k, k), "kind": "no-learning",
                  "value": _round(np.mean([m["baselines"][k] for m in items if k in m["baselines"]]))} for k in names]
    return baselines, "-", None


def _residual_baselines(entry, cfg, motion, items, cache) -> tuple[list[dict[str, Any]], str, float | None]:
    from aslexp.reports.residual_report import measured_rows

    base = measured_rows(motion, items, cache)
    settings = (cfg.get("report") or {}).get("residual") or {}
    rows = [{"label": "controller (zero correction)", "kind": "no-learning", "value": _round(base["controller"])}]
    if base.get("compare") is not None:
        rows.append({"label": f"same controller, {settings.get('compare_label', 'pinned base')} (nothing slips)",
                     "kind": "no-learning", "value": _round(base["compare"])})
    smoothed = base.get("smoothed") or {}
    if smoothed:
        alpha = max(smoothed, key=smoothed.get)
        rows.append({"label": "smoothed reference, best alpha", "kind": "simple", "value": _round(smoothed[alpha]),
                     "name": f"alpha {alpha}"})
    chance = base.get("random_corrections")
    if chance:
        rows.append({"label": "constant random corrections, mean", "kind": "simple",
                     "value": _round(np.mean(chance["scores"])),
                     "name": f"RMS {chance['rms']:g}, n={len(chance['scores'])}"})
    return rows, "-", None


_BASELINES = {"thesis": _thesis_baselines, "scratch": _scratch_baselines, "residual": _residual_baselines}


def imitation_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """Per motion: the thesis' number, the baselines (see the module docstring) and the learned
    policies' last evaluation, mean ± std over seeds (population std, as the imitation reports);
    the steps of the trained runs. Baselines are cached in ``<folder>/baselines/<motion>.json`` as
    the thesis and residual reports cache theirs."""
    from aslexp.reports.report import learned, run_config
    from aslexp.reports.thesis_report import GLOSSES

    runs, skipped = _imitation_runs(folders)
    # A planner's runs (aslexp.control.mpc) give each motion its ceiling: this entry's own, and those
    # of the folders its options name (options.ceiling_folders: the same reward, controller and rate)
    options = entry.get("options") or {}
    ceilings = _imitation_runs([Path(f) for f in options.get("ceiling_folders") or []])[0]
    # The policies trained on each motion alone (options.per_motion_folders), beside a policy of many
    # motions scored on a motion it never saw (experiment=letters_unseen): the column it is measured against
    per_motion = _imitation_runs([Path(f) for f in options.get("per_motion_folders") or []])[0]
    rows, run_dirs, configs = [], [], []
    for motion, items in runs.items():
        run_dirs += [Path(m["run_dir"]) for m in items]
        configs += [run_config(Path(m["run_dir"])) for m in items]
        first = Path(items[0]["run_dir"])
        folder = next(f for f in folders if first.resolve().is_relative_to(f.resolve()))
        cfg = run_config(first)
        baselines, thesis, thesis_value = _BASELINES[entry["report"]](entry, cfg, motion, items,
                                                                     folder / "baselines" / f"{motion}.json")
        trained = sorted((m for m in items if learned(m)), key=lambda m: (m.get("seed") is None, m.get("seed")))
        last = [float(m["last_eval"]) for m in trained if m.get("last_eval") is not None]
        # The policies before any update (ppo.eval_at_start: the curve's step 0): the level learning starts from.
        untrained = [float(p["eval_reward"]) for m in trained for p in m.get("progress") or []
                     if p.get("step") == 0 and p.get("eval_reward") is not None]
        if untrained:
            baselines = [{"label": "the untrained policy (step 0 of these runs, mean over seeds)", "kind": "no-learning",
                          "value": _round(np.mean(untrained))}, *baselines]
        own = [float(m["last_eval"]) for m in per_motion.get(motion, []) if learned(m) and m.get("last_eval") is not None]
        if own:
            baselines.append({"label": options.get("per_motion_label", "the policy trained on this motion alone"),
                              "kind": "learned", "value": _round(np.mean(own)),
                              "name": f"± {np.std(own):.4f}, n={len(own)}" if len(own) > 1 else "n=1"})
        names = list(dict.fromkeys(k for m in trained for k in m.get("last_eval_scores") or {}))
        scores = {name: [float(m["last_eval_scores"][name]) for m in trained if name in (m.get("last_eval_scores") or {})]
                  for name in names}
        rows.append({
            "key": motion, "label": f"{motion} ({GLOSSES[motion]})" if motion in GLOSSES else motion,
            "thesis": thesis, "thesis_value": _round(thesis_value),
            "baselines": baselines,
            "learned": {"what": "last evaluation", "mean": _round(np.mean(last)) if last else None,
                        "spread": _round(np.std(last)) if last else None, "spread_kind": "std over seeds",
                        "n": len(last), "unit": "seeds", "values": [_round(v) for v in last],
                        "seeds": [m.get("seed") for m in trained],
                        # the last evaluations' episodes that blew up, summed over seeds (None: not recorded)
                        "diverged": (sum(int(m["last_eval_diverged"]) for m in trained)
                                     if trained and all("last_eval_diverged" in m for m in trained) else None),
                        **({"scores": {name: {"mean": _round(np.mean(v)), "spread": _round(np.std(v)), "n": len(v)}
                                       for name, v in scores.items()}} if scores else {})},
            "steps": [int(min(m["steps"] for m in trained)), int(max(m["steps"] for m in trained))] if trained else None,
            **({"ceiling": ceiling_summary(planned)} if (planned := [m for m in items + ceilings.get(motion, [])
                                                                      if m.get("planner")]) else
               {"ceiling": options["ceiling_rows"][motion]} if motion in (options.get("ceiling_rows") or {}) else {}),
        })
    return {"rows": rows, "run_dirs": run_dirs, "skipped": skipped, "quantity": "mean reward per step",
            "row_name": "motion", **thesis_differences(entry, configs, [m for items in runs.values() for m in items])}


def ceiling_summary(planned: list[dict[str, Any]]) -> dict[str, Any]:
    """A motion's ceiling (:func:`aslexp.reports.thesis_report.ceiling`) as a snapshot stores it,
    labelled with the planner and the controller it plans on."""
    from aslexp.reports.report import run_config
    from aslexp.reports.thesis_report import ceiling

    found = ceiling(planned)
    spec = found["spec"]
    controller = (run_config(Path(planned[0]["run_dir"])).get("controller") or {}).get("name", "?")
    return {"label": f"MPC ({spec['method'].replace('_', ' ')}, horizon {spec['horizon']}, {spec['samples']} "
                     f"samples) on {controller}",
            "mean": _round(found["mean"]), "spread": _round(found["spread"]), "n": found["n"],
            "controller_alone": _round(found["controller_alone"]), "gain": _round(found["gain"]),
            "saturated": bool(found["saturated"]), "seconds_per_step": _round(found["seconds_per_step"]),
            "diverged": found["diverged"], **({"fell": found["fell"]} if found["fell"] else {})}


def thesis_differences(entry: dict[str, Any], configs: list[dict[str, Any]], metrics: list[dict[str, Any]],
                       runs: dict[str, Any] | None = None) -> dict[str, Any]:
    """The snapshot's ``differences``: how the runs differ from the thesis' setting the catalogue
    names (``thesis.setting``: the overlay that composes it; ``thesis.seeds``), from their composed
    configs (:mod:`aslexp.reports.differences`). Empty for an entry that names no setting."""
    from aslexp.reports import differences

    thesis = entry.get("thesis") or {}
    if not thesis.get("setting") or not configs:
        return {}
    reference = differences.compose_overlay(command_overrides(entry["command"])[0],
                                            [f"experiment={thesis['setting']}"])
    runs = runs if runs is not None else differences.run_facts(metrics)
    return {"differences": differences.imitation_differences(configs, reference, runs, thesis.get("seeds")),
            "differences_from": f"experiment={thesis['setting']}"}


# --------------------------------------------------------------------------- snapshots


def build_snapshot(entry: dict[str, Any], outputs: Path, summarizers: dict[str, Summarizer],
                   snapshots: Path | None = None) -> dict[str, Any] | None:
    """The snapshot of ``entry`` from its run folders under ``outputs``; None when it has none.
    ``options.ceiling_snapshot`` (an entry id): the ceilings of the rows that have no planner run here,
    from that entry's snapshot in ``snapshots`` (made from its run folders; the same reward, controller,
    rate and engine)."""
    folders, alternative = entry_folders(entry, outputs)
    if not folders:
        return None
    if entry["report"] not in summarizers:
        log.warning("warning: %s: no summary for report %r here; its snapshot is kept", entry["id"], entry["report"])
        return None
    options = entry.get("options") or {}
    for key in ("ceiling_folders", "per_motion_folders"):  # other entries' runs a row reads, under outputs/ too
        if options.get(key):
            options = {**options, key: [str(outputs / f) for f in options[key]]}
    if options.get("ceiling_snapshot") and snapshots is not None:
        kept = read_snapshot(snapshot_path(snapshots, options["ceiling_snapshot"])) or {}
        options = {**options, "ceiling_rows": {r["key"]: {**r["ceiling"], "source": f"docs/results/{kept['id']}.json"}
                                               for r in kept.get("rows", []) if r.get("ceiling")}}
    entry = {**entry, "options": options}
    summary = summarizers[entry["report"]](entry, folders)
    if not summary["rows"]:
        return None
    run_dirs = sorted(set(summary.pop("run_dirs")))
    snapshot = {"schema": SNAPSHOT_SCHEMA, "id": entry["id"], "report": entry["report"],
                **provenance(run_dirs, outputs, folders, alternative)}
    snapshot.update({"skipped": dict(sorted(summary.get("skipped", {}).items())), "quantity": summary.get("quantity"),
                     "row_name": (entry.get("options") or {}).get("row_name", summary.get("row_name")),
                     "rows": summary["rows"]})
    for key in ("differences", "differences_from", "differences_source", "facts"):
        if key in summary:
            snapshot[key] = summary[key]
    return snapshot


def snapshot_path(snapshots: Path, entry_id: str) -> Path:
    return Path(snapshots) / f"{entry_id}.json"


def write_snapshot(path: Path, snapshot: dict[str, Any]) -> None:
    atomic_write_text(path, json.dumps(snapshot, indent=1, ensure_ascii=False) + "\n")


def read_snapshot(path: Path) -> dict[str, Any] | None:
    if not path.is_file():
        return None
    snapshot = json.loads(path.read_text(encoding="utf-8"))
    if snapshot.get("schema") != SNAPSHOT_SCHEMA:
        raise ValueError(f"{path}: snapshot schema {snapshot.get('schema')}, this aslexp writes {SNAPSHOT_SCHEMA}")
    return snapshot


def update(catalogue: list[dict[str, Any]], outputs: Path, snapshots: Path,
           summarizers: dict[str, Summarizer]) -> dict[str, str]:
    """Rewrite the snapshot of every entry whose run folders exist under ``outputs``; keep the others'.
    Returns id -> what happened (``from runs``, ``kept``, ``not run``)."""
    done = {}
    for entry in catalogue:
        snapshot = build_snapshot(entry, outputs, summarizers, snapshots)
        path = snapshot_path(snapshots, entry["id"])
        if snapshot is not None:
            write_snapshot(path, snapshot)
            done[entry["id"]] = f"from runs ({', '.join(snapshot['folders'])})"
        elif path.is_file():
            done[entry["id"]] = "kept"
            kept = read_snapshot(path)
            if kept is not None and entry["report"] in IMITATION_REPORTS and "differences" not in kept:
                extra = recomposed_differences(entry, kept)
                if extra:
                    write_snapshot(path, {**kept, **extra})
                    done[entry["id"]] = "kept; differences recomposed from its commits"
        else:
            done[entry["id"]] = "not run"
    return done


def recomposed_differences(entry: dict[str, Any], snapshot: dict[str, Any],
                           root: Path | None = None) -> dict[str, Any]:
    """For a kept imitation snapshot made before snapshots carried ``differences`` (its run folders
    gone): the runs' configs recomposed from ``conf/`` at their git commits with their recorded
    overrides (:func:`aslexp.reports.differences.configs_at_commits`), the budget and seeds from its
    rows, and the evaluation protocol from the recomposed config (the runs' ``report: scratch`` and
    ``residual`` baselines were measured by the runs under it; ``thesis`` ones at report time from
    phase 0). {} when it cannot be done (no commit, no git)."""
    import subprocess

    from aslexp.reports import differences

    commits = [c for c in snapshot.get("git") or [] if c and c != "-"]
    if not (entry.get("thesis") or {}).get("setting") or not commits:
        return {}
    root = root or Path(__file__).resolve().parents[3]
    job, _ = command_overrides(entry["command"])
    try:
        configs = differences.configs_at_commits(job, snapshot.get("overrides") or {}, commits, root)
    except (subprocess.CalledProcessError, OSError, ValueError) as err:
        log.warning("warning: %s: its runs' configs cannot be recomposed (%s); no differences", entry["id"], err)
        return {}
    ppo, env = configs[0]["ppo"], configs[0]["env"]
    phases = len(ppo.get("eval_phases") or []) or int(ppo.get("eval_episodes", 4))
    steps = [s for r in snapshot["rows"] if r.get("steps") for s in r["steps"]]
    measured_by_runs = entry["report"] in ("scratch", "residual")
    runs = {"steps": steps, "seeds_per_motion": sorted({r["learned"]["n"] for r in snapshot["rows"] if r["learned"].get("n")}),
            "protocols": [((phases, ppo.get("eval_steps")),
                           (phases, ppo.get("eval_steps") / env.get("control_hz", 30)) if measured_by_runs else None)]}
    extra = thesis_differences(entry, configs, [], runs)
    if extra:
        extra["differences_source"] = ("the run folders are gone: their configs recomposed from conf/ at their "
                                       f"commits ({', '.join(sorted({c.rstrip('+') for c in commits}))}) "
                                       "with their overrides")
    return extra


# --------------------------------------------------------------------------- the page


def _cell(text: Any) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def _number(value: float | None, percent: bool) -> str:
    if value is None:
        return "-"
    return f"{100 * value:.1f}" if percent else f"{value:.3f}"


def _learned(learned: dict[str, Any], percent: bool, planned: bool = False) -> str:
    if learned.get("cell"):  # a recognition row, rendered by aslexp.reports.results_recognition
        return learned["cell"]
    if learned.get("mean") is None:
        return "- (nothing trained: a planner's ceiling)" if planned else "pending (no trained run)"
    text = _number(learned["mean"], percent)
    one_seed = learned.get("n") == 1 and learned.get("spread") == 0  # a population std of one value
    if learned.get("spread") is not None and not one_seed:
        text += f" ± {_number(learned['spread'], percent)}"
    model = f"{learned['model']}, " if learned.get("model") else ""
    diverged = f"; {learned['diverged']} episode(s) diverged" if learned.get("diverged") else ""
    return f"{text} ({model}n={learned['n']}{diverged})"


def _ceiling_cell(ceiling: dict[str, Any] | None) -> str:
    if not ceiling:
        return "-"
    seeds = f" ± {ceiling['spread']:.3f}" if ceiling["n"] > 1 else ""
    diverged = f"; {ceiling['diverged']} episode(s) diverged" if ceiling.get("diverged") else ""
    diverged += f"; {ceiling['fell']} episode(s) fell" if ceiling.get("fell") else ""
    return (f"{ceiling['mean']:.3f}{seeds} (n={ceiling['n']}; its controller alone {ceiling['controller_alone']:.4f}, "
            f"{ceiling['gain']:+.4f}{', saturated' if ceiling['saturated'] else ''}; "
            f"{ceiling['seconds_per_step']:.3f} s per control step{diverged})")


def _baseline_cell(baseline: dict[str, Any] | None, percent: bool) -> str:
    if baseline is None:
        return "-"
    text = _number(baseline.get("value"), percent)
    extra = ", ".join(x for x in (baseline.get("name"), baseline.get("note")) if x)
    return f"{text} ({extra})" if extra else text


def _steps(steps: list[int] | None) -> str:
    if not steps:
        return "-"
    low, high = steps
    return f"{low:,}" if low == high else f"{low:,}-{high:,}"


def _when(snapshot: dict[str, Any]) -> str:
    start, end = _utc(snapshot.get("started")), _utc(snapshot.get("finished"))
    if not start or not end:
        return "not recorded"
    if start.date() == end.date():
        return f"{start:%Y-%m-%d %H:%M}-{end:%H:%M} UTC"
    return f"{start:%Y-%m-%d %H:%M} to {end:%Y-%m-%d %H:%M} UTC"


def _machine(snapshot: dict[str, Any]) -> str:
    parts = []
    if snapshot.get("machine_label"):
        parts.append(snapshot["machine_label"])
    recorded = []
    if snapshot.get("hosts"):
        recorded.append(f"host {', '.join(snapshot['hosts'])}")
    if snapshot.get("platforms"):
        recorded.append(", ".join(snapshot["platforms"]))
    if snapshot.get("devices"):
        recorded.append(f"device {', '.join(snapshot['devices'])}")
    versions = snapshot.get("versions") or {}
    if versions.get("python") or versions.get("torch"):
        recorded.append("Python " + "/".join(versions.get("python") or ["?"]) + ", torch "
                        + "/".join(versions.get("torch") or ["?"]))
    if recorded:
        resumed = snapshot.get("resumed")
        parts.append("run.json: " + "; ".join(recorded)
                     + (f" ({resumed} of the runs resumed another run's checkpoint: its machine is listed too)"
                        if resumed else ""))
    return ". ".join(parts) if parts else "not recorded"


def _link(earlier: dict[str, str], page_dir: Path = PAGE.parent) -> str:
    """A link from the page to ``earlier``: {link: a repository path with an optional #anchor, section}."""
    path, _, anchor = earlier["link"].partition("#")
    relative = Path(path).relative_to(page_dir) if Path(path).is_relative_to(page_dir) else Path("..") / path
    section = f', "{earlier["section"]}"' if earlier.get("section") else ""
    return f"[{path}{section}]({relative.as_posix()}{'#' + anchor if anchor else ''})"


def _engine_reward(entry: dict[str, Any]) -> str:
    if entry["engine"] is None and entry["reward"] is None:
        metric = (entry.get("options") or {}).get("metric")
        return "no engine or reward (recognition" + (f"; the metric: test {metric})" if metric else ")")
    return f"engine `engine={entry['engine']}`, reward `reward={entry['reward']}`"


def _status(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> str:
    if snapshot is None:
        return "not run on this machine yet"
    return f"{snapshot['runs']} runs, {_when(snapshot)}"


def _thesis_cell(entry: dict[str, Any], row: dict[str, Any]) -> str:
    """The thesis' number for a row: the snapshot's (imitation), else the catalogue's per-row value."""
    if row.get("thesis") not in (None, "-"):
        return str(row["thesis"])
    rows = (entry.get("thesis") or {}).get("rows") or {}
    known = rows.get(row["key"])
    if not known:
        return "-"
    baseline = f"; thesis baseline {known['baseline']}" if known.get("baseline") else ""
    return f"{known['value']} ({known['model']}{baseline})"


def render_entry(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> list[str]:
    options = entry.get("options") or {}
    percent = bool(options.get("percent"))
    beside = "T" + entry["beside"][1:] if entry["beside"].startswith("thesis") else entry["beside"]
    lines = [f'<a id="{entry["id"]}"></a>', "", f"## {beside}: {entry['title']}", ""]
    thesis = (entry.get("thesis") or {}).get("source", "-")
    job, _ = command_overrides(entry["command"])
    overlay = f"`experiment={entry['overlay']}`" if entry["overlay"] else "no overlay (the job's defaults)"
    lines += [f"- **Beside**: {entry['beside']}; the thesis' number: {thesis}",
              f"- **Overlay, engine, reward**: {overlay} (`aslexp {job}`), {_engine_reward(entry)}",
              f"- **Command** (re-runs it into the folder this page reads first): `{entry['command']}`"]
    if snapshot is None:
        lines += [f"- **Not run on this machine yet**: no run folders under outputs/ "
                  f"({', '.join('outputs/' + f for alt in entry['runs'] for f in alt['folders'])}) and no snapshot. "
                  f"Earlier numbers, typed before this page: {_link(entry['earlier'])}", ""]
        return lines
    ran_engine = ", ".join(snapshot.get("engine") or []) or "-"
    ran_reward = ", ".join(snapshot.get("reward") or []) or "-"
    differs = []
    if entry["engine"] is not None and snapshot.get("engine") != [entry["engine"]]:
        differs.append(f"engine {ran_engine}")
    if entry["reward"] is not None and snapshot.get("reward") != [entry["reward"]]:
        differs.append(f"reward {ran_reward}")
    uncovered = uncovered_overrides(entry["command"], snapshot.get("overrides") or {})
    steps = [r["steps"] for r in snapshot["rows"] if r.get("steps")]
    budget = f"; {_steps([min(s[0] for s in steps), max(s[1] for s in steps)])} steps per trained run" if steps else ""
    skipped = snapshot.get("skipped") or {}
    left = f"; left out: {', '.join(f'{n} ({why})' for why, n in skipped.items())}" if skipped else ""
    commits = ", ".join(snapshot.get("git") or ["-"])
    dirty = " (+: with uncommitted changes)" if "+" in commits else ""
    lines += [f"- **Ran**: {snapshot['runs']} runs, {_when(snapshot)}{budget}; git {commits}{dirty}{left}",
              f"- **Machine**: {_machine(snapshot)}",
              f"- **Run folders**: {', '.join('outputs/' + f for f in snapshot['folders'])} "
              f"(snapshot [docs/results/{entry['id']}.json](results/{entry['id']}.json))"]
    if differs or uncovered:
        lines.append(f"- **The runs differ from the command**: {'; '.join(differs + uncovered)}")
    if snapshot.get("differences"):  # computed when the snapshot was made (aslexp.reports.differences)
        source = f"; {snapshot['differences_source']}" if snapshot.get("differences_source") else ""
        lines.append(f"- **Differences from the thesis' setting** (`{snapshot['differences_from']}` composed alone; "
                     f"generated from the runs' configs{source}): " + "; ".join(snapshot["differences"]))
    if entry.get("note"):  # what the folders cannot say, e.g. a default changed since they ran
        lines.append(f"- **Note**: {entry['note']}")
    unrun = unrun_values(entry["command"], entry["overlay"], snapshot.get("overrides") or {})
    if unrun:
        lines.append(f"- **Not run of what the command sweeps**: {', '.join(unrun)} (the numbers below "
                     f"are of the runs that were)")
    lines.append(f"- **How it was run, and what it shows**: {_link(entry['earlier'])}")
    lines.append("")
    columns = list(dict.fromkeys((b["kind"], b["label"]) for r in snapshot["rows"] for b in r["baselines"]))
    extras = list(dict.fromkeys(k for r in snapshot["rows"] for k in (r.get("extra") or {})))
    learned = [r["learned"] for r in snapshot["rows"] if r.get("learned")]
    whats = sorted({str(x.get("what")) for x in learned})
    kinds = sorted({str(x.get("spread_kind")) for x in learned})
    what = (f"aslexp, {whats[0] if len(whats) == 1 else 'per row'} "
            f"(mean ± {kinds[0] if len(kinds) == 1 else 'spread: ' + '; '.join(kinds)})")
    what = next((x["header"] for x in learned if x.get("header")), what)  # recognition: results_recognition
    header = [snapshot.get("row_name") or "", "thesis", *[f"{kind}: {label}" for kind, label in columns], f"**{what}**",
              *extras]
    ceiling = next((r["ceiling"]["label"] for r in snapshot["rows"] if r.get("ceiling")), None)
    if ceiling:
        header.append(f"ceiling: {ceiling}")
    has_steps = any(r.get("steps") for r in snapshot["rows"])
    if has_steps:
        header.append("steps")
    lines += ["| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    for row in snapshot["rows"]:
        by_label = {(b["kind"], b["label"]): b for b in row["baselines"]}
        cells = [row["label"], _thesis_cell(entry, row), *[_baseline_cell(by_label.get(c), percent) for c in columns],
                 f"**{_learned(row['learned'], percent, planned=bool(row.get('ceiling')))}**",
                 *[_number((row.get("extra") or {}).get(k), percent) for k in extras]]
        if ceiling:
            cells.append(_ceiling_cell(row.get("ceiling")))
        if has_steps:
            cells.append(_steps(row.get("steps")))
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    quantity = snapshot.get("quantity") or ""
    lines += ["", f"Numbers: {quantity}{' in %' if percent else ''}; the thesis' in its own units.", ""]
    lines += _seeds_above(snapshot, columns)
    lines += _score_tables(snapshot, columns, percent)
    for figure in entry.get("figures") or []:  # drawn from the same run folders (its caption says how)
        lines += [f"![{figure['caption']}]({_relative_to_page(figure['path'])})", ""]
    return lines


def _seeds_above(snapshot: dict[str, Any], columns: list[tuple[str, str]]) -> list[str]:
    """Per row and baseline, how many seeds' last evaluations end above it (k/n): which baselines
    the learned policies pass, and which they fall below, seed by seed."""
    rows = [r for r in snapshot["rows"] if (r.get("learned") or {}).get("values")]
    if not rows or not columns:
        return []
    header = [snapshot.get("row_name") or "", *[f"{kind}: {label}" for kind, label in columns]]
    lines = ["Seeds whose last evaluation ends above each baseline:", "",
             "| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    for row in rows:
        values = [v for v in row["learned"]["values"] if v is not None]
        by_label = {(b["kind"], b["label"]): b for b in row["baselines"]}
        cells = [row["label"]]
        for column in columns:
            base = (by_label.get(column) or {}).get("value")
            cells.append("-" if base is None else f"{sum(v > base for v in values)}/{len(values)}")
        lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
    return lines + [""]


def _score_tables(snapshot: dict[str, Any], columns: list[tuple[str, str]], percent: bool) -> list[str]:
    """The same rows scored under each other reward the runs also scored (``report.score_rewards``:
    the same episodes, e.g. under the authors' code weights beside Table 5.2)."""
    names = list(dict.fromkeys(k for r in snapshot["rows"] for k in (r["learned"].get("scores") or {})))
    lines = []
    for name in names:
        header = [snapshot.get("row_name") or "", *[f"{kind}: {label}" for kind, label in columns],
                  f"**aslexp, last evaluation under `reward={name}` (mean ± std over seeds)**"]
        lines += [f"The same episodes scored under `reward={name}`:", "",
                  "| " + " | ".join(_cell(h) for h in header) + " |", "|" + "---|" * len(header)]
        for row in snapshot["rows"]:
            by_label = {(b["kind"], b["label"]): b for b in row["baselines"]}
            score = (row["learned"].get("scores") or {}).get(name)
            cells = [row["label"], *[_number((by_label.get(c) or {}).get("scores", {}).get(name), percent) for c in columns],
                     f"**{_learned(score, percent)}**" if score else "-"]
            lines.append("| " + " | ".join(_cell(c) for c in cells) + " |")
        lines.append("")
    return lines


def _relative_to_page(path: str, page_dir: Path = PAGE.parent) -> str:
    """A repository path (docs/img/x.png) as the page links it (img/x.png)."""
    import os

    return Path(os.path.relpath(path, page_dir)).as_posix()


HEADER = """# Results

<!-- Generated by `aslexp report --results`: do not edit (edit conf/results.yaml or the generator). -->

This page is generated, not typed: `aslexp report --results` (src/aslexp/reports/results_page.py)
reads the catalogue [conf/results.yaml](../conf/results.yaml), summarises every result whose run folders
are under `outputs/` into a snapshot `docs/results/<id>.json` (numbers, the folders, when and where they
ran), keeps the snapshots of results whose folders are not here, and renders this page from the
snapshots alone (`aslexp report --results --render-only` renders it again, byte for byte). Per result:
the thesis' number, the no-learning and simple baselines under the same reward or metric, aslexp's
number (the LAST evaluation of each trained policy, mean ± spread over seeds; for recognition the
model chosen by validation, over splits or seeds), the engine and reward, the one command that re-runs
it, and when and on what it ran. A result not run on this machine says so and links the numbers typed
before this page.
"""


def render(catalogue: list[dict[str, Any]], snapshots: Path) -> str:
    """The page from the catalogue and the snapshots (no run folder is read)."""
    found = {entry["id"]: read_snapshot(snapshot_path(snapshots, entry["id"])) for entry in catalogue}
    lines = [HEADER, "| result | beside | overlay | engine | reward | ran |", "|---|---|---|---|---|---|"]
    for entry in catalogue:
        snapshot = found[entry["id"]]
        lines.append(f"| [{_cell(entry['title'])}](#{entry['id']}) | {_cell(entry['beside'])} | "
                     f"{f'`{o}`' if (o := entry['overlay']) else '-'} | {entry['engine'] or '-'} | {entry['reward'] or '-'} | "
                     f"{_cell(_status(entry, snapshot))} |")
    lines.append("")
    for entry in catalogue:
        if entry["report"] in JOB_TABLE_REPORTS:
            lines += JOB_TABLE_REPORTS[entry["report"]].render(entry, found[entry["id"]], render_entry)
            continue
        lines += results_recognition.render(entry, found[entry["id"]], render_entry)  # others: render_entry
    return "\n".join(lines).rstrip("\n") + "\n"


def write_results(catalogue_path: Path, outputs: Path, snapshots: Path, page: Path,
                  summarizers: dict[str, Summarizer] | None = None, render_only: bool = False) -> dict[str, Any]:
    """Update the snapshots from ``outputs`` (unless ``render_only``) and write the page."""
    catalogue = load_catalogue(catalogue_path)
    summarizers = {**{kind: imitation_summary for kind in IMITATION_REPORTS},
                   **{kind: module.results_summary for kind, module in JOB_TABLE_REPORTS.items()}, **(summarizers or {})}
    done = {} if render_only else update(catalogue, outputs, snapshots, summarizers)
    text = render(catalogue, snapshots)
    atomic_write_text(page, text)
    return {"entries": done, "page": str(page), "text": text}
