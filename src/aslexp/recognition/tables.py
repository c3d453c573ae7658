"""The tables of ``aslexp report RUN_OR_SWEEP_DIR`` beyond :mod:`aslexp.recognition.report`'s: one run
per split, model and property (the best by validation where a sweep ran several), the model chosen
by validation per split and property against the chance baseline, and the thesis' section 4.4
(Fleiss' kappa over the clips every model misclassifies, the mutual misclassification, the error
overlap). Every function takes runs as :func:`aslexp.runs.completed.find_runs` gives them; test
numbers never choose.
"""

from __future__ import annotations

import csv
import io
import logging
import math
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


def panel_order(key: tuple[str, str]) -> tuple:
    """A (split, property) pair in the tables' order: the known splits and properties first."""
    from aslexp.recognition.report import PROPERTY_ORDER, SPLIT_ORDER

    split, second = key
    return (SPLIT_ORDER.index(split) if split in SPLIT_ORDER else len(SPLIT_ORDER),
            PROPERTY_ORDER.index(second) if second in PROPERTY_ORDER else len(PROPERTY_ORDER), key)


def validation_key(run: dict[str, Any]) -> float:
    """A run's validation objective, larger is better (run.json's main metric and goal, else
    metrics.json's objective, maximised); -inf when it has none."""
    main = run["info"].get("main_metric") or {}
    value = main.get("value")
    if value is None:
        value = (run["metrics"].get("objective") or {}).get("value")
    value = finite(value, -math.inf)
    return -value if main.get("goal") == "minimize" and math.isfinite(value) else value


def best_by_validation(members: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """One run per (split, model, property): where a folder holds several (an Optuna sweep's
    trials, repeated runs), the one with the best validation objective, with a log line; test
    numbers never choose."""
    groups: dict[tuple[str, str, str], list[dict[str, Any]]] = defaultdict(list)
    for run in members:
        groups[(str(run["split"]), str(run["classifier"]), str(run["property"]))].append(run)
    chosen = []
    for (split, model, prop), group in groups.items():
        best = max(group, key=validation_key)
        if len(group) > 1:
            name = (best["info"].get("main_metric") or {}).get("name") or "objective"
            log.info("%s split, %s, %s: %d runs (e.g. a sweep's trials); the tables show the best by validation "
                     "%s: %s", split, model, prop, len(group), name, best["dir"])
        chosen.append(best)
    return chosen


def finite(value: Any, default: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return default
    return value if math.isfinite(value) else default


def fmt(value: Any, digits: int = 3) -> str:
    value = finite(value, math.nan)
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def best_vs_baseline(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (split, property): the model with the best mean *validation* objective, its test MCC
    and balanced accuracy (mean and 95% t interval over the units) beside the chance baseline's."""
    groups: dict[tuple, list[dict[str, Any]]] = defaultdict(list)
    for run in runs:
        groups[(run["split"], run["property"])].append(run)
    rows = []
    for (split, prop), members in sorted(groups.items()):
        best = max(members, key=lambda r: finite(r["metrics"]["objective"]["value"], -math.inf))
        m = best["metrics"]
        base = m["baseline"]
        rows.append({
            "split": split, "property": prop, "model": best["classifier"], "models_compared": len(members),
            "selected_by": m["objective"]["name"], "num_classes": best["num_classes"],
            "n_test": int(m["split_sizes"]["test"]), "units": m["test_interval"]["mcc"]["n"],
            "unit": m["statistics_unit"], "val_objective": m["objective"]["value"],
            "test_mcc": m["test_interval"]["mcc"]["mean"], "test_mcc_low": m["test_interval"]["mcc"]["low"],
            "test_mcc_high": m["test_interval"]["mcc"]["high"],
            "test_balanced_accuracy": m["test_interval"]["balanced_accuracy"]["mean"],
            "test_balanced_accuracy_low": m["test_interval"]["balanced_accuracy"]["low"],
            "test_balanced_accuracy_high": m["test_interval"]["balanced_accuracy"]["high"],
            "baseline": base["name"], "baseline_mcc": base["test"]["mcc"],
            "baseline_balanced_accuracy": base["test"]["balanced_accuracy"],
            "paired_mcc_diff": m["paired_vs_baseline"]["mcc"]["diff"]["mean"],
            "paired_mcc_resolved": m["paired_vs_baseline"]["mcc"]["resolved"],
            "run": str(best["dir"]),
        })  # fmt: skip
    return rows


def best_vs_baseline_markdown(rows: list[dict[str, Any]]) -> str:
    header = ("| split | property | classes | n test | units | best model (by validation) | test MCC [95% CI] | "
              "test bal. acc [95% CI] | baseline | baseline MCC | baseline bal. acc |")  # fmt: skip
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {r['split']} | {r['property']} | {r['num_classes']} | {r['n_test']} | {r['units']} {r['unit']}(s) | "
            f"{r['model']} | {fmt(r['test_mcc'])} [{fmt(r['test_mcc_low'])}, {fmt(r['test_mcc_high'])}] | "
            f"{fmt(r['test_balanced_accuracy'])} [{fmt(r['test_balanced_accuracy_low'])}, "
            f"{fmt(r['test_balanced_accuracy_high'])}] | {r['baseline']} | {fmt(r['baseline_mcc'])} | "
            f"{fmt(r['baseline_balanced_accuracy'])} |"
        )
    return "\n".join(lines) + "\n"


def rows_csv(rows: list[dict[str, Any]]) -> str:
    if not rows:
        return ""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def agreement(runs: list[dict[str, Any]], read_predictions: Callable[[Path], dict]) -> dict[str, Any]:
    """The thesis' section 4.4 on the report's models, per split kind (phoneme, gloss):

    - ``fleiss_kappa``: per task (property) and split repeat, Fleiss' kappa over the test clips that
      every model misclassifies (raters = models, categories = the wrong classes they chose; first
      model seed), its mean over repeats per task, and mean ± std over the tasks (the thesis:
      0.09 ± 0.06 phoneme, 0.11 ± 0.09 gloss);
    - ``mutual_misclassification``: per repeat, the share of clips in exactly 2 (3) test sets that
      all models misclassify on all those tasks, and the mean over repeats (thesis: 1% (0.7%)
      phoneme, 3% (0%) gloss);
    - ``pairwise_error_overlap``: per model, of the clips wrong for property a, the share also wrong
      for property b (first split and seed).

    ``read_predictions``: a run folder's predictions.csv as (split, seed) -> clip -> (true, predicted).
    """
    from aslexp.recognition.metrics import mean_interval, misclassification_agreement, mutual_misclassification
    from aslexp.recognition.metrics import pairwise_error_overlap

    predictions = {id(run): read_predictions(run["dir"]) for run in runs}
    by_kind: dict[str, dict[str, list[dict[str, Any]]]] = defaultdict(lambda: defaultdict(list))
    for run in runs:
        by_kind[run["split"]][run["property"]].append(run)
    kappa: dict[str, Any] = {}
    mutual: dict[str, Any] = {}
    for kind, tasks in sorted(by_kind.items()):
        task_kappas: dict[str, Any] = {}
        repeats_mutual: dict[int, dict[str, dict[str, dict[str, bool]]]] = defaultdict(dict)
        for prop, members in sorted(tasks.items()):
            per_repeat = []
            splits = sorted({key[0] for r in members for key in predictions[id(r)]})
            for split_index in splits:
                first = {}
                for r in members:
                    keys = sorted(k for k in predictions[id(r)] if k[0] == split_index)
                    if keys:
                        first[r["classifier"]] = predictions[id(r)][keys[0]]
                if len(first) < 2:
                    continue
                common = sorted(set.intersection(*(set(p) for p in first.values())))
                labels = sorted({p[v][0] for p in first.values() for v in common} | {p[v][1] for p in first.values() for v in common})
                position = {label: i for i, label in enumerate(labels)}
                any_model = next(iter(first.values()))
                y_true = [position[any_model[v][0]] for v in common]
                preds = {name: [position[p[v][1]] for v in common] for name, p in first.items()}
                result = misclassification_agreement(y_true, preds, len(labels))
                result["split"] = split_index
                per_repeat.append(result)
                repeats_mutual[split_index][prop] = {name: {v: p[v][0] == p[v][1] for v in common} for name, p in first.items()}
            values = [r["kappa"] for r in per_repeat]
            task_kappas[prop] = {"per_split": per_repeat, "mean": mean_interval(values)["mean"]}
        summary = mean_interval([t["mean"] for t in task_kappas.values()])
        kappa[kind] = {"tasks": task_kappas, "over_tasks": summary}
        per_repeat_mutual = {k: mutual_misclassification(v) for k, v in sorted(repeats_mutual.items())}
        mutual[kind] = {
            "per_split": per_repeat_mutual,
            **{size: {"share_mean": mean_interval([r[size]["share"] for r in per_repeat_mutual.values()])["mean"],
                      "clips_mean": mean_interval([r[size]["clips"] for r in per_repeat_mutual.values()])["mean"]}
               for size in ("2", "3")},
        }  # fmt: skip
    overlap: dict[str, Any] = {}
    by_model: dict[tuple, dict[str, tuple[list[str], list[bool]]]] = defaultdict(dict)
    for run in runs:
        preds = predictions[id(run)]
        if preds:
            first = preds[min(preds)]
            vids = sorted(first)
            by_model[(run["split"], run["classifier"])][run["property"]] = (vids, [first[v][0] == first[v][1] for v in vids])
    for (split, model), results in sorted(by_model.items()):
        if len(results) >= 2:
            overlap[f"{split}/{model}"] = pairwise_error_overlap(results)
    return {"fleiss_kappa_all_wrong": kappa, "mutual_misclassification": mutual, "pairwise_error_overlap": overlap}
