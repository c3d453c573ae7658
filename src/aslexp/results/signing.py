"""The signer-against-the-person entries of the results page. ``report: signing``: an ``aslexp signing``
run's own table (per stage the keypoint error to the person and the reward; per reading each
property's agreement with ASL-LEX and the lexicon rank of the true gloss, with intervals over
glosses) and the lines saying which bars each stage meets. ``report: signing_folds``: the
leave-glosses-out table, one row per held-out fold (a signing run of a pool policy on its fold's clips)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.results.kinds import ReportKind, register_report
from aslexp.results.render import render_entry, with_table
from aslexp.results.snapshots import number
from aslexp.runs.completed import find_job_runs, latest, read_json
from aslexp.runs.listing import read_config
from aslexp.signing.table import gloss_bootstrap, rewards

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


def renderer(legend_of):
    """A kind's render: ``render_entry``'s lines with the snapshot's own table (``facts.table_lines``)
    and ``legend_of(snapshot)`` in place of the generic ones."""
    def render(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> list[str]:
        if snapshot is None:
            return render_entry(entry, snapshot)
        return with_table(entry, snapshot, list((snapshot.get("facts") or {}).get("table_lines") or []),
                          legend_of(snapshot))
    return render


register_report(ReportKind(REPORT, results_summary, renderer(legend), job_defaults=True))


# -- report: signing_folds -- the leave-glosses-out table: one row per held-out fold --------------------
FOLDS_REPORT = "signing_folds"


def _policy_fold(run_dir: Path) -> dict[str, Any]:
    """The policy a signing run performed (``policy=``, as the run was given it) and the fold its
    pool held out, from the policy run's metrics.json (``train_motions.signs``); what is missing
    stays out (the row is then named by the policy)."""
    policy = str(read_config(run_dir).get("policy") or "")
    found = {"policy": policy}
    metrics = read_json(Path(policy) / "metrics.json") if policy and (Path(policy) / "metrics.json").is_file() else None
    if isinstance(metrics, dict):
        signs = (metrics.get("train_motions") or {}).get("signs") or {}
        found.update({k: signs.get(k) for k in ("fold", "folds", "held_out", "held_out_gloss")})
        found["seed"] = metrics.get("seed")
    return found


def folds_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """Per completed ``aslexp signing`` run under ``folders`` (the latest per policy), the held-out
    fold's clips: the policy's and the controller's mean reward over one pass and their paired
    difference (95% bootstrap over glosses, clips where the policy is better / worse), and the median
    body keypoint error to the person of each; the entry's first figure drawn from the same clips
    (:func:`aslexp.viz.signing.plot_fold_differences`)."""
    runs, skipped = find_job_runs(folders, JOB)
    chosen: dict[str, tuple[Path, dict[str, Any], dict[str, Any]]] = {}
    for run_dir, metrics in sorted(runs, key=lambda r: ((read_json(r[0] / "run.json") or {}).get("finished") or "")):
        fold = _policy_fold(run_dir)
        if fold["policy"] in chosen:
            skipped["earlier runs of the same policy"] = skipped.get("earlier runs of the same policy", 0) + 1
        chosen[fold["policy"]] = (run_dir, metrics, fold)
    rows, lines, drawn = [], [], []
    header = ["held out (fold)", "clips (glosses)", "reward: controller", "reward: policy",
              "policy - controller [95% CI] (better/worse clips)", "keypoint error: controller", "policy"]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    # a fold's row per policy: its seed named where one fold has policies of several seeds
    seeds_of: dict[Any, set] = {}
    for _, _, fold in chosen.values():
        seeds_of.setdefault(fold.get("fold"), set()).add(fold.get("seed"))
    for run_dir, metrics, fold in sorted(chosen.values(), key=lambda c: (c[2].get("fold") is None, c[2].get("fold") or 0,
                                                                          c[2].get("seed") or 0)):
        seeded = fold.get("held_out") and len(seeds_of[fold.get("fold")]) > 1 and fold.get("seed") is not None
        seed = f", seed {fold['seed']}" if seeded else ""
        records = [json.loads(line) for line in (run_dir / "clips.jsonl").read_text().splitlines() if line.strip()]
        records = [r for r in records if "policy" in (r.get("rewards") or {}) and "controller" in (r.get("rewards") or {})]
        glosses = [r["gloss"] for r in records]
        policy, controller = rewards(records, "policy"), rewards(records, "controller")
        gap = gloss_bootstrap(policy - controller, glosses, "mean", 2000, 0.95, 0)
        short = f"{fold['held_out']} ({fold['held_out_gloss']})'s fold" if fold.get("held_out") else run_dir.name
        short += seed
        drawn.append({"label": f"{short}: {len(records)} clips", "differences": policy - controller, **gap})
        table = metrics["table"]
        reward, error = table["reward"], table["keypoint_error"]
        label = (f"{fold['held_out']} ({fold['held_out_gloss']}), fold {fold['fold']} of {fold['folds']}"
                 + seed if fold.get("held_out") else fold["policy"] or run_dir.name)
        lines.append("| " + " | ".join([
            label, f"{table['clips']} ({table['glosses']})",
            _interval(reward["controller"]), _interval(reward["policy"]),
            f"{gap['value']:+.4f} [{gap['low']:+.4f}, {gap['high']:+.4f}] "
            f"({int(np.sum(policy > controller))}/{int(np.sum(policy < controller))})",
            _interval(error["controller"]["body"]), _interval(error["policy"]["body"])]) + " |")
        rows.append({"key": str(fold.get("fold", label)) + seed.replace(", ", "/"), "label": label, "thesis": None, "baselines": [],
                     "steps": None, "learned": {"what": "mean reward minus the controller's, per clip",
                                                "mean": number(gap["value"]), "spread": None,
                                                "spread_kind": "95% bootstrap interval over glosses",
                                                "n": gap["n"], "unit": "clips",
                                                "metrics": {k: number(gap[k]) for k in ("low", "high")}}})
    if entry.get("figures") and drawn:  # the entry's first figure, drawn from the same clips
        from aslexp.viz.signing import plot_fold_differences

        plot_fold_differences(drawn, entry["figures"][0]["path"])
    return {"rows": rows, "run_dirs": [c[0] for c in chosen.values()], "skipped": skipped, "row_name": "fold",
            "quantity": "a pool policy on its held-out fold's clips, beside its controller",
            "facts": {"table_lines": lines}}


def _interval(cell: dict[str, Any]) -> str:
    return f"{cell['value']:.3f} [{cell['low']:.3f}, {cell['high']:.3f}]"


def folds_legend(snapshot: dict[str, Any]) -> list[str]:
    return ["Numbers: per held-out fold, its plausible clips each performed once from the start by the pool "
            "policy that never saw their glosses and by its controller alone: the mean reward [95% bootstrap "
            "interval over glosses], the paired difference per clip, and the median body keypoint error to the "
            "person (DTW mean joint error, shoulder widths).", ""]


register_report(ReportKind(FOLDS_REPORT, folds_summary, renderer(folds_legend), job_defaults=True))
