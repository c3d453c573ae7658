"""The signer-against-the-person entry of the results page (``report: signing``): an ``aslexp signing``
run's own table (per stage the keypoint error to the person and the reward; per reading each
property's agreement with ASL-LEX and the lexicon rank of the true gloss, with intervals over
glosses) and the lines saying which bars each stage meets."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aslexp.results.kinds import ReportKind, register_report
from aslexp.results.render import render_entry, with_table
from aslexp.results.snapshots import number
from aslexp.runs.completed import find_job_runs, latest

REPORT = "signing"
JOB = "signing"


def results_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """One row per stage (the median body keypoint error) and the run's table lines, from the latest
    completed ``aslexp signing`` run under ``folders``."""
    runs, skipped = find_job_runs(folders, JOB)
    if not runs:
        return {"rows": [], "run_dirs": [], "skipped": skipped}
    run_dir, metrics = latest(runs, skipped)
    table = metrics["table"]
    rows = []
    for stage in table["stages"]:
        body = table["keypoint_error"][stage]["body"]
        rows.append({"key": stage, "label": stage, "thesis": None, "baselines": [], "steps": None,
                     "learned": {"what": "median body keypoint error after DTW (shoulder widths)",
                                 "mean": number(body["value"]), "spread": None,
                                 "spread_kind": "95% bootstrap interval over glosses", "n": body["n"], "unit": "clips",
                                 "metrics": {k: number(body.get(k)) for k in ("low", "high", "q25", "q75")}}})
    facts = {"clips": table["clips"], "glosses": table["glosses"], "left_out": metrics.get("left_out"),
             "implausible_kept": metrics.get("implausible_kept") or 0, "hand_body": "hand_body" in table,
             "unscored": metrics.get("unscored"), "table_lines": metrics.get("table_lines") or [],
             "verdict_lines": metrics.get("verdict_lines") or []}
    return {"rows": rows, "run_dirs": [run_dir], "skipped": skipped, "row_name": "stage",
            "quantity": "the simulated signer against the person, per clip", "facts": facts}


def legend(snapshot: dict[str, Any]) -> list[str]:
    facts = snapshot.get("facts") or {}
    if not facts:
        return []
    kept = f", {facts['implausible_kept']} implausible kept and marked" if facts.get("implausible_kept") else ""
    hands = ("; handshape error: the fingers' DTW mean joint error in the palm's own frame, in hand sizes (wrist to "
             "the middle finger's base), of both hands seen (the upper body's stages) or of the hand motion's side "
             "(the hand body's run, its fingers worn by the upper body's reference arm; the open hand: every finger "
             "joint at 0)") if facts.get("hand_body") else ""
    text = (f"Numbers: {facts['clips']} clips of {facts['glosses']} glosses ({facts.get('left_out')} left out as "
            f"implausible{kept}); keypoint error: the median over clips of the body's DTW mean joint error to the person's "
            "MediaPipe keypoints, in shoulder widths [95% bootstrap interval over glosses] (interquartile range)"
            f"{hands}; "
            "reward: the mean over clips of one pass from the start; readings: each property's agreement with "
            "ASL-LEX and the lookup's rank of the true gloss among 2,723 entries, read by the gloss-fold models "
            "that never saw the clip's gloss, the person's clip (source) first.")
    verdicts = facts.get("verdict_lines") or []
    return [text, "", *(["The bars a readable signer meets:", "", *verdicts, ""] if verdicts else [])]


def render(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> list[str]:
    """``render_entry``'s lines with the run's own table in place of the generic one."""
    if snapshot is None:
        return render_entry(entry, snapshot)
    return with_table(entry, snapshot, list((snapshot.get("facts") or {}).get("table_lines") or []),
                             legend(snapshot))


register_report(ReportKind(REPORT, results_summary, render, job_defaults=True))
