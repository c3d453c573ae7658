"""The seen-gloss entry of the results page (``report: seen_glosses``): an ``aslexp glosses`` run's
table, one row per method (chance, the majority baseline, the simple feature baseline, the gloss
network alone and with auxiliary phonology heads): top-k accuracy, the mean over splits with its
95% t interval, and the paired differences."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aslexp.results.kinds import ReportKind, register_report
from aslexp.results.render import render_entry, with_table
from aslexp.results.snapshots import number, split_table_rows
from aslexp.runs.completed import find_job_runs, latest

REPORT = "seen_glosses"
JOB = "glosses"


def results_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """The rows of the latest completed ``aslexp glosses`` run under ``folders`` and its facts; the
    earlier runs there are counted as left out."""
    runs, skipped = find_job_runs(folders, JOB)
    if not runs:
        return {"rows": [], "run_dirs": [], "skipped": skipped}
    run_dir, metrics = latest(runs, skipped)
    keys = [f"top{k}" for k in metrics["top_k"]]
    rows = split_table_rows(metrics, keys, "top1", "test top-1 over splits")
    splits = metrics["per_split"]
    tests = [s["clips"]["test"] for s in splits]
    tested = [s["glosses"]["tested"] for s in splits]
    facts = {
        "top_k": list(metrics["top_k"]), "auxiliary": list(metrics["auxiliary"]), "aux_weight": metrics["aux_weight"],
        "clips": metrics["num_clips"], "glosses": metrics["num_glosses"], "splits": len(splits),
        "test_clips": [min(tests), max(tests)], "tested_glosses": [min(tested), max(tested)],
        "training_glosses": sorted({s["glosses"]["train"] for s in splits}),
        "encoder": (metrics.get("params") or {}).get("encoder"),
        "best_epochs": {m: [s["epochs"][m]["best"] for s in splits] for m in ("gloss", "gloss+phonology")},
        "paired": [{"method": p["method"], "reference": p["reference"], "metric": p["metric"],
                    "diff": {k: number(p["diff"][k]) for k in ("mean", "low", "high")},
                    "wins": p["wins"], "ties": p["ties"], "losses": p["losses"], "wilcoxon_p": number(p["wilcoxon_p"])}
                   for p in metrics.get("paired", [])],
    }
    return {"rows": rows, "run_dirs": [run_dir], "skipped": skipped,
            "quantity": "test top-k accuracy over splits stratified by gloss", "row_name": "method", "facts": facts}


def _span(values: list[int]) -> str:
    low, high = min(values), max(values)
    return f"{low}" if low == high else f"{low}-{high}"


def _cell(cell: dict[str, Any]) -> str:
    mean, low, high = cell.get("mean"), cell.get("low"), cell.get("high")
    if mean is None:
        return "-"
    interval = f" [{100 * low:.1f}, {100 * high:.1f}]" if low is not None and high is not None else ""
    return f"{100 * mean:.1f}{interval}"


def table(snapshot: dict[str, Any]) -> list[str]:
    top_k = (snapshot.get("facts") or {}).get("top_k") or [1]
    header = [snapshot.get("row_name") or "method", *[f"top-{k} (%)" for k in top_k]]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in snapshot["rows"]:
        cells = row["learned"]["metrics"]
        lines.append("| " + " | ".join([row["label"], *[_cell(cells[f"top{k}"]) for k in top_k]]) + " |")
    return lines


def verdict(snapshot: dict[str, Any]) -> str:
    """What the paired top-1 difference (with minus without the auxiliary heads) says, in words."""
    facts = snapshot.get("facts") or {}
    item = next((p for p in facts.get("paired") or [] if p["method"] == "gloss+phonology"
                 and p["reference"] == "gloss" and p["metric"] == "top1"), None)
    if item is None or item["diff"]["mean"] is None:
        return ""
    low, high = item["diff"]["low"], item["diff"]["high"]
    if low is not None and low > 0:
        said = "the auxiliary phonology heads raise top-1: the interval of the paired difference lies above 0"
    elif high is not None and high < 0:
        said = "the auxiliary phonology heads lower top-1: the interval of the paired difference lies below 0"
    else:
        said = "no effect of the auxiliary phonology heads is resolved on this data: the interval of the paired difference holds 0"
    return (f"Kezar et al.'s question (about +9 points of top-1 on WLASL with phonology as an auxiliary loss): "
            f"{said} ({100 * item['diff']['mean']:+.1f} points).")


def legend(snapshot: dict[str, Any]) -> list[str]:
    facts = snapshot.get("facts") or {}
    if not facts:
        return []
    train = facts["training_glosses"]
    text = (f"Numbers: top-k accuracy on the test clips of glosses seen in training, mean over {facts['splits']} "
            f"splits stratified by gloss [95% t interval]; {facts['clips']} clips of {facts['glosses']} glosses, "
            f"{_span(facts['test_clips'])} test clips of {_span(facts['tested_glosses'])} glosses per split, "
            f"{_span(train)} training glosses (the classes). Both networks: the multi-task encoder ({facts['encoder']}), the same seed "
            f"and clips, the epoch chosen by the gloss head's validation MCC; auxiliary heads: "
            f"{', '.join(facts['auxiliary'])} (loss weight {facts['aux_weight']:g}).")
    labels = {r["key"]: r["label"] for r in snapshot["rows"]}
    paired = []
    for item in facts.get("paired") or []:
        diff = item["diff"]
        interval = f" [{100 * diff['low']:+.1f}, {100 * diff['high']:+.1f}]" if diff["low"] is not None else ""
        paired.append(f"{labels.get(item['method'], item['method'])} minus "
                      f"{labels.get(item['reference'], item['reference'])}, {item['metric'].replace('top', 'top-')} "
                      f"(points): {100 * diff['mean']:+.1f}{interval}, splits higher/equal/lower "
                      f"{item['wins']}/{item['ties']}/{item['losses']}, Wilcoxon p = "
                      f"{'-' if item['wilcoxon_p'] is None else format(item['wilcoxon_p'], '.3g')}")
    line = verdict(snapshot)
    return ([text, ""] + ([line, ""] if line else [])
            + ([f"Paired over the same splits: {'; '.join(paired)}.", ""] if paired else []))


def render(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> list[str]:
    """``render_entry``'s lines for a seen-gloss entry with its table (and the line of numbers) in
    place of the generic one."""
    if snapshot is None:
        return render_entry(entry, snapshot)
    return with_table(entry, snapshot, table(snapshot), legend(snapshot))


register_report(ReportKind(REPORT, results_summary, render, job_defaults=True))
