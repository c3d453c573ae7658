"""The snapshots of the results page, ``docs/results/<id>.json``: made from an entry's run folders by
its report kind with their provenance, kept when the folders are gone, read back by the page.

A snapshot holds numbers (fractions; the page prints percentages where the entry says so), the run
folders it came from (relative to ``--outputs``), when the runs started and finished, where they
ran (run.json's host and platform, metrics.json's device, the catalogue's machine label where the
folders do not say), the engine and reward they composed (``.hydra/hydra.yaml``), their git commits
and their overrides.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from aslexp.files import atomic_write_text
from aslexp.results.kinds import report_kind
from aslexp.results.provenance import entry_folders, provenance

SNAPSHOTS = Path("docs") / "results"
SNAPSHOT_SCHEMA = 1


def number(value: Any, digits: int = 6) -> float | None:
    """A finite number rounded for a snapshot; None for a missing or non-finite one."""
    if value is None:
        return None
    value = float(value)
    return round(value, digits) if math.isfinite(value) else None


def split_table_rows(metrics: dict[str, Any], keys: list[str], headline: str, what: str) -> list[dict[str, Any]]:
    """One row per method of a job whose metrics.json holds ``table[method][key]`` = mean, interval
    and half-width over splits (retrieval, seen glosses): every key's cells, ``headline`` the learned cell."""
    rows = []
    for method, label in metrics["methods"].items():
        cells = {key: {k: number(metrics["table"][method][key].get(k)) for k in ("mean", "low", "high", "half_width")}
                 for key in keys}
        rows.append({"key": method, "label": label, "thesis": None, "baselines": [], "steps": None,
                     "learned": {"what": what, "mean": cells[headline]["mean"],
                                 "spread": cells[headline]["half_width"], "spread_kind": "95% t half-width over splits",
                                 "n": len(metrics["per_split"]), "unit": "splits", "metrics": cells}})
    return rows


def build_snapshot(entry: dict[str, Any], outputs: Path, snapshots: Path | None = None) -> dict[str, Any] | None:
    """The snapshot of ``entry`` from its run folders under ``outputs``, summarised by its report kind
    (:mod:`aslexp.results.kinds`); None when it has none.
    ``options.ceiling_snapshot`` (an entry id): the ceilings of the rows that have no planner run here,
    from that entry's snapshot in ``snapshots`` (made from its run folders; the same reward, controller,
    rate and engine)."""
    folders, alternative = entry_folders(entry, outputs)
    if not folders:
        return None
    options = entry.get("options") or {}
    for key in ("ceiling_folders", "per_motion_folders"):  # other entries' runs a row reads, under outputs/ too
        if options.get(key):
            options = {**options, key: [str(outputs / f) for f in options[key]]}
    if options.get("ceiling_snapshot") and snapshots is not None:
        options = {**options, "ceiling_rows": ceiling_rows(options["ceiling_snapshot"], snapshots)}
    entry = {**entry, "options": options}
    summary = report_kind(entry["report"]).summarize(entry, folders)
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


def ceiling_rows(entry_id: str, snapshots: Path) -> dict[str, dict[str, Any]]:
    """The planner's ceiling per row key in ``entry_id``'s snapshot, each naming its source."""
    kept = read_snapshot(snapshot_path(snapshots, entry_id)) or {}
    return {r["key"]: {**r["ceiling"], "source": f"docs/results/{kept['id']}.json"}
            for r in kept.get("rows", []) if r.get("ceiling")}


def snapshot_path(snapshots: Path, entry_id: str) -> Path:
    """Where ``entry_id``'s snapshot is: ``<snapshots>/<id>.json``."""
    return Path(snapshots) / f"{entry_id}.json"


def write_snapshot(path: Path, snapshot: dict[str, Any]) -> None:
    atomic_write_text(path, json.dumps(snapshot, indent=1, ensure_ascii=False) + "\n")


def read_snapshot(path: Path) -> dict[str, Any] | None:
    """The snapshot at ``path``, None where there is none; one of another schema is refused."""
    if not path.is_file():
        return None
    snapshot = json.loads(path.read_text(encoding="utf-8"))
    if snapshot.get("schema") != SNAPSHOT_SCHEMA:
        raise ValueError(f"{path}: snapshot schema {snapshot.get('schema')}, this aslexp writes {SNAPSHOT_SCHEMA}")
    return snapshot


def update(catalogue: list[dict[str, Any]], outputs: Path, snapshots: Path) -> dict[str, str]:
    """Rewrite the snapshot of every entry whose run folders exist under ``outputs``; keep the others'
    (with what their kind's ``refresh`` adds). Returns id -> what happened (``from runs``, ``kept``,
    ``not run``)."""
    done = {}
    # An entry that reads another's ceiling comes after it, so it reads the new one.
    for entry in sorted(catalogue, key=lambda e: bool((e.get("options") or {}).get("ceiling_snapshot"))):
        snapshot = build_snapshot(entry, outputs, snapshots)
        path = snapshot_path(snapshots, entry["id"])
        if snapshot is not None:
            snapshot, earlier = with_earlier_rows(entry, snapshot, read_snapshot(path))
            write_snapshot(path, snapshot)
            done[entry["id"]] = f"from runs ({', '.join(snapshot['folders'])})" + (
                f"; rows {', '.join(earlier)} kept from earlier runs" if earlier else "")
        elif path.is_file():
            done[entry["id"]] = "kept"
            kept = read_snapshot(path)
            kind = report_kind(entry["report"])
            extra = kind.refresh(entry, kept) if kept is not None and kind.refresh else {}
            notes = [kind.refreshed] if extra else []
            ceilings = _newer_ceilings(entry, kept, snapshots) if kept is not None else None
            if ceilings is not None:
                extra["rows"] = ceilings
                notes.append(f"ceilings from {entry['options']['ceiling_snapshot']}")
            if extra:
                write_snapshot(path, {**kept, **extra})
                done[entry["id"]] = "; ".join(["kept", *notes])
        else:
            done[entry["id"]] = "not run"
    return {e["id"]: done[e["id"]] for e in catalogue}


def with_earlier_rows(entry: dict[str, Any], snapshot: dict[str, Any],
                      kept: dict[str, Any] | None) -> tuple[dict[str, Any], list[str]]:
    """``snapshot`` (from the runs here) with the rows of ``kept`` (the entry's snapshot before it) that
    it has no row for, where the entry says ``options.keep_earlier_rows``: rows whose runs ran in
    another checkout or on another machine stay on the page, while the rows run here are made anew.
    Each group of kept rows says where it came from (``earlier_rows``: keys, folders, when, commits,
    machine), carried on through later rebuilds. Returns the snapshot and the keys kept."""
    if not (entry.get("options") or {}).get("keep_earlier_rows") or not kept:
        return snapshot, []
    here = {row["key"] for row in snapshot["rows"]}
    rows = [row for row in kept["rows"] if row["key"] not in here]
    if not rows:
        return snapshot, []
    groups = [{**group, "keys": [k for k in group["keys"] if k not in here]} for group in kept.get("earlier_rows", [])]
    grouped = {k for group in groups for k in group["keys"]}
    own = [row["key"] for row in rows if row["key"] not in grouped]  # the kept snapshot's own runs' rows
    if own:
        groups.append({"keys": own, **{key: kept.get(key) for key in
                                       ("folders", "started", "finished", "git", "machine_label", "hosts")}})
    return ({**snapshot, "rows": snapshot["rows"] + rows, "earlier_rows": [g for g in groups if g["keys"]]},
            [row["key"] for row in rows])


def _newer_ceilings(entry: dict[str, Any], kept: dict[str, Any], snapshots: Path) -> list[dict[str, Any]] | None:
    """A kept snapshot's rows with the ceilings its ``options.ceiling_snapshot`` holds now (the planner
    run again, more seeds), or None where nothing changed: a row's ceiling is that entry's, not a copy
    frozen when the row was made."""
    source = (entry.get("options") or {}).get("ceiling_snapshot")
    if not source:
        return None
    ceilings = ceiling_rows(source, snapshots)
    rows = [{**r, "ceiling": ceilings[r["key"]]} if r["key"] in ceilings and r.get("ceiling") else r
            for r in kept.get("rows", [])]
    return rows if rows != kept.get("rows", []) else None
