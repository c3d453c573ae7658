"""`aslexp report RUN_OR_SWEEP_DIR... [--out DIR]`: recognition runs -> tables, comparisons, agreement.
`aslexp report --results [--outputs DIR] [--render-only] [--add-test-clips]`: the results page, docs/results.md
(aslexp.reports.results_page: one table per result of conf/results.yaml, from snapshots made of run folders;
recognition rows carry their test clips and intervals, aslexp.reports.results_recognition).

Reads only run directories (run.json + metrics.json + predictions.csv) and writes, per keypoint
layout and lexicon (a suffix names the group when a folder holds more than one):

    table.md / table.csv              models x properties: test MCC, mean ± 95% t interval over the
                                      splits (model seeds for one split), balanced accuracy; ▼ marks a
                                      mean below the chance baseline; the baseline rows
    comparisons.md / .json            every model minus the chance baseline and minus the strongest
                                      simple baseline (rf/hgb/logreg/svm, best by validation), paired
                                      on the same splits: mean difference [95% CI], W/T/L, Wilcoxon p
    best_vs_baseline.md / .csv / .png per property and split: the model chosen by validation against
                                      the chance baseline
    table_thesis_ch3.md               Table 3.4's layout (micro/macro F1, mean ± std)
    table_thesis_ch4.md               Tables 4.2/4.3's layout (A ± 95% half-width, Ā) and C.2's (P_μ, P_M, R_M, MCC)
    comparisons.png                   the paired differences to the strongest simple baseline, per
                                      property and split (95% intervals)
    validation_curves.png             per property and split, the validation MCC per epoch of the
                                      models trained over epochs (mean over runs) against the
                                      feature baselines' validation MCC
    run_plots/<split>_<property>_<model>/  confusion_matrix.png, learning_curves.png drawn from
                                      metrics.json for runs whose folder has none (a GPU node
                                      without matplotlib); the run folders are not touched
    agreement.json                    the thesis' section 4.4: Fleiss' kappa over the clips that all
                                      models misclassify, per task, with mean ± std over the six tasks;
                                      the mutual misclassification (clips in 2 (3) test sets wrong for
                                      every model on all of them); the per-model error overlap
    runs.md / runs.csv                the runs of other jobs (tune_pd, imitate, ...), per job best
                                      main metric first: folder, status, main metric, overrides

A folder with several runs of one split, model and property (an Optuna sweep's trials) is
reported by the one with the best validation objective (run.json's main metric), named in a log
line; test numbers never choose. A damaged run.json or metrics.json is named in one warning line
and its run left out (:mod:`aslexp.runs.read`).
"""

from __future__ import annotations

import argparse
import csv
import io
import logging
import math
import sys
from collections import defaultdict
from pathlib import Path
from typing import Any

from aslexp.files import write_json
from aslexp.runs import read
from aslexp.runs.record import METRICS_FILE, RUN_FILE

log = logging.getLogger(__name__)


_OBJECT_KEYS = ("context", "objective", "baseline", "split_sizes", "paired_vs_baseline")
_CONTEXT_KEYS = ("split", "property", "classifier")


def _recognition_problem(metrics: dict[str, Any]) -> str | None:
    """What a recognition run's metrics.json lacks for the tables (None: nothing)."""
    for key in _OBJECT_KEYS:
        if not isinstance(metrics.get(key), dict):
            return f'"{key}" is missing or not an object'
    for key in _CONTEXT_KEYS:
        if not isinstance(metrics["context"].get(key), str):
            return f'"context.{key}" is missing or not a string'
    return None


def find_runs(paths: list[Path]) -> tuple[list[dict[str, Any]], list[dict[str, Any]], dict[str, int]]:
    """(completed recognition runs, runs of other jobs, what was skipped and why) under ``paths``.
    A damaged run.json or metrics.json is named in one warning line and its run skipped."""
    runs, others, skipped = [], [], defaultdict(int)
    for base in paths:
        if not base.exists():
            raise FileNotFoundError(f"{base}: no such file or directory")
        for run_file in sorted(base.rglob(RUN_FILE)):
            run_dir = run_file.parent
            info = read.read_run_info(run_dir)
            if info is None:
                skipped["damaged run.json"] += 1
                continue
            if info.get("job") != "recognize":
                others.append({"dir": run_dir, "info": info})
                continue
            if info.get("status") != "completed" or not (run_dir / METRICS_FILE).exists():
                skipped[f"status {info.get('status')}"] += 1
                continue
            metrics = read.read_metrics(run_dir)
            if metrics is None:
                skipped["damaged metrics.json"] += 1
                continue
            if "test_interval" not in metrics:
                skipped["metrics.json of an older format (no test_interval)"] += 1
                continue
            problem = _recognition_problem(metrics)
            if problem:
                read.warn(read.RunFileError(run_dir / METRICS_FILE, problem), "run skipped")
                skipped["damaged metrics.json"] += 1
                continue
            layout = (metrics.get("layout") or {}).get("name", metrics["context"].get("pose"))
            runs.append({"dir": run_dir, "info": info, "metrics": metrics, **metrics["context"], "layout": layout})
    return runs, others, dict(skipped)


def find_recognition_runs(paths: list[Path]) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """Completed recognition runs under ``paths``; counts what was skipped and why."""
    runs, others, skipped = find_runs(paths)
    for run in others:
        skipped[f"job {run['info'].get('job')}"] = skipped.get(f"job {run['info'].get('job')}", 0) + 1
    return runs, skipped


def _validation_key(run: dict[str, Any]) -> float:
    """A run's validation objective, larger is better (run.json's main metric and goal, else
    metrics.json's objective, maximised); -inf when it has none."""
    main = run["info"].get("main_metric") or {}
    value = main.get("value")
    if value is None:
        value = (run["metrics"].get("objective") or {}).get("value")
    value = _finite(value, -math.inf)
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
        best = max(group, key=_validation_key)
        if len(group) > 1:
            name = (best["info"].get("main_metric") or {}).get("name") or "objective"
            log.info("%s split, %s, %s: %d runs (e.g. a sweep's trials); the tables show the best by validation "
                     "%s: %s", split, model, prop, len(group), name, best["dir"])
        chosen.append(best)
    return chosen


def read_predictions(run_dir: Path) -> dict[tuple[int, int], dict[str, tuple[str, str]]]:
    """(split, seed) -> video_id -> (true, predicted)."""
    runs: dict[tuple[int, int], dict[str, tuple[str, str]]] = defaultdict(dict)
    path = run_dir / "predictions.csv"
    if not path.exists():
        return {}
    with open(path, encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            runs[(int(row.get("split", 0) or 0), int(row["seed"]))][row["video_id"]] = (row["true"], row["predicted"])
    return runs


def _finite(value: Any, default: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return default
    return value if math.isfinite(value) else default


def _fmt(value: Any, digits: int = 3) -> str:
    value = _finite(value, math.nan)
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def best_vs_baseline(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (split, property): the model with the best mean *validation* objective, its test MCC
    and balanced accuracy (mean and 95% t interval over the units) beside the chance baseline's."""
    groups: dict[tuple, list[dict[str, Any]]] = defaultdict(list)
    for run in runs:
        groups[(run["split"], run["property"])].append(run)
    rows = []
    for (split, prop), members in sorted(groups.items()):
        best = max(members, key=lambda r: _finite(r["metrics"]["objective"]["value"], -math.inf))
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


def interval_label(units: list[int]) -> str:
    """What the whiskers of bars over ``units`` (splits or seeds per bar) show: an interval
    needs two units or more."""
    spread = [u >= 2 for u in units]
    return "95% CI" if all(spread) else "95% CI where 2+ units" if any(spread) else "one unit: no interval"


def best_vs_baseline_markdown(rows: list[dict[str, Any]]) -> str:
    header = ("| split | property | classes | n test | units | best model (by validation) | test MCC [95% CI] | "
              "test bal. acc [95% CI] | baseline | baseline MCC | baseline bal. acc |")  # fmt: skip
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {r['split']} | {r['property']} | {r['num_classes']} | {r['n_test']} | {r['units']} {r['unit']}(s) | "
            f"{r['model']} | {_fmt(r['test_mcc'])} [{_fmt(r['test_mcc_low'])}, {_fmt(r['test_mcc_high'])}] | "
            f"{_fmt(r['test_balanced_accuracy'])} [{_fmt(r['test_balanced_accuracy_low'])}, "
            f"{_fmt(r['test_balanced_accuracy_high'])}] | {r['baseline']} | {_fmt(r['baseline_mcc'])} | "
            f"{_fmt(r['baseline_balanced_accuracy'])} |"
        )
    return "\n".join(lines) + "\n"


def _rows_csv(rows: list[dict[str, Any]]) -> str:
    if not rows:
        return ""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]), lineterminator="\n")
    writer.writeheader()
    writer.writerows(rows)
    return buffer.getvalue()


def agreement(runs: list[dict[str, Any]]) -> dict[str, Any]:
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


def plot_best_vs_baseline(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    splits = sorted({r["split"] for r in rows})
    fig, axes = plt.subplots(len(splits), 2, figsize=(12, 3.4 * len(splits)), squeeze=False, layout="constrained")
    for i, split in enumerate(splits):
        sub = [r for r in rows if r["split"] == split]
        x = np.arange(len(sub))
        for j, (metric, label) in enumerate((("mcc", "test MCC"), ("balanced_accuracy", "test balanced accuracy"))):
            ax = axes[i, j]
            best = np.array([_finite(r[f"test_{metric}"], 0.0) for r in sub])
            low = np.array([_finite(r[f"test_{metric}_low"], b) for r, b in zip(sub, best)])
            high = np.array([_finite(r[f"test_{metric}_high"], b) for r, b in zip(sub, best)])
            base = [_finite(r[f"baseline_{metric}"], 0.0) for r in sub]
            # An interval needs two units (splits or seeds) or more: one run gets a bar, no whisker.
            spread = np.array([(r.get("units") or 0) >= 2 for r in sub])
            yerr = [np.where(spread, best - low, 0.0), np.where(spread, high - best, 0.0)]
            what = interval_label([r.get("units") or 0 for r in sub])
            ax.bar(x - 0.2, best, 0.4, yerr=yerr if spread.any() else None, capsize=3,
                   label=f"best model (by validation), {what}")
            ax.bar(x + 0.2, base, 0.4, label="chance baseline", color="0.6")
            ax.set_xticks(x, [f"{r['property']}\n({r['model']})" for r in sub], fontsize=7)
            ax.set_title(f"{split} split: {label}")
            ax.axhline(0, color="k", lw=0.5)
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def plot_comparisons(rows: list[dict[str, Any]], path: Path) -> bool:
    """Per (split, property) with a learned model paired against the strongest simple baseline: each
    model's mean difference in test MCC with its 95% t interval (a forest plot). False if none."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    panels: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        if r.get("vs_simple"):
            panels[(r["split"], r["property"])].append(r)
    if not panels:
        return False
    from aslexp.recognition.report import PROPERTY_ORDER, SPLIT_ORDER

    def order(key: tuple[str, str]) -> tuple:
        split, prop = key
        return (SPLIT_ORDER.index(split) if split in SPLIT_ORDER else len(SPLIT_ORDER),
                PROPERTY_ORDER.index(prop) if prop in PROPERTY_ORDER else len(PROPERTY_ORDER), key)  # fmt: skip

    keys = sorted(panels, key=order)
    columns = min(2, len(keys))
    lines = (len(keys) + columns - 1) // columns
    fig, axes = plt.subplots(lines, columns, figsize=(6.2 * columns, 0.5 + 0.32 * max(len(v) for v in panels.values())
                                                          * lines + 1.1 * lines), squeeze=False, layout="constrained")
    for ax, key in zip(axes.flat, keys):
        members = sorted(panels[key], key=lambda r: r["vs_simple"]["diff"]["mean"])
        for y, r in enumerate(members):
            diff = r["vs_simple"]["diff"]
            low, high = _finite(diff["low"], diff["mean"]), _finite(diff["high"], diff["mean"])
            color = {1: "tab:green", -1: "tab:red", 0: "0.3"}[r["vs_simple"]["resolved"]]
            ax.errorbar(diff["mean"], y, xerr=[[diff["mean"] - low], [high - diff["mean"]]], fmt="o", color=color, capsize=3)
        ax.set_yticks(range(len(members)), [f"{r['model']} (n={r['vs_simple']['diff']['n']})" for r in members], fontsize=8)
        ax.set_ylim(-0.6, len(members) - 0.4)
        ax.axvline(0, color="k", lw=0.8)
        reference = members[0]["strongest_simple"]
        ax.set_title(f"{key[1]}, {key[0]} split: minus {reference}", fontsize=9)
        ax.set_xlabel(f"test MCC minus {reference} (same splits), 95% CI", fontsize=8)
        ax.grid(axis="x", alpha=0.3)
    for ax in list(axes.flat)[len(keys):]:
        ax.axis("off")
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return True


def plot_validation_curves(members: list[dict[str, Any]], path: Path) -> bool:
    """Per (split, property) with a model trained over epochs: its validation MCC per epoch, the mean
    over the validation runs (splits x seeds) still training at that epoch, drawn while at least half
    are; dashed, the validation MCC of each feature baseline (mean over its runs, fitted once).
    False when no run was trained over epochs."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from aslexp.recognition.report import FEATURE_BASELINES, MODEL_ORDER, PROPERTY_ORDER, SPLIT_ORDER

    panels: dict[tuple[str, str], dict[str, dict[str, Any]]] = defaultdict(dict)
    for run in members:
        panels[(run["split"], run["property"])][run["classifier"]] = run["metrics"]

    def trained(metrics: dict[str, Any]) -> bool:
        return any(len(h) > 1 for h in metrics.get("history", {}).values())

    keys = [k for k in panels if any(trained(m) for m in panels[k].values())]
    if not keys:
        return False
    keys.sort(key=lambda k: (SPLIT_ORDER.index(k[0]) if k[0] in SPLIT_ORDER else 9,
                             PROPERTY_ORDER.index(k[1]) if k[1] in PROPERTY_ORDER else 9, k))  # fmt: skip
    columns = min(2, len(keys))
    lines = (len(keys) + columns - 1) // columns
    fig, axes = plt.subplots(lines, columns, figsize=(6.4 * columns, 3.6 * lines), squeeze=False, layout="constrained")
    for ax, key in zip(axes.flat, keys):
        models = sorted(panels[key], key=lambda m: MODEL_ORDER.index(m) if m in MODEL_ORDER else 99)
        for index, model in enumerate(models):
            metrics = panels[key][model]
            # One colour per model in every panel (its place in MODEL_ORDER).
            color = f"C{(MODEL_ORDER.index(model) if model in MODEL_ORDER else index) % 10}"
            if trained(metrics):
                curves = [[_finite(r.get("val_mcc"), math.nan) for r in h] for h in metrics["history"].values()]
                length = max(len(c) for c in curves)
                grid = np.full((len(curves), length), np.nan)
                for row, curve in enumerate(curves):
                    grid[row, :len(curve)] = curve
                running = np.sum(np.isfinite(grid), axis=0)
                shown = running >= max(1, len(curves) / 2)
                with np.errstate(all="ignore"):
                    mean = np.where(shown, np.nanmean(np.where(np.isfinite(grid), grid, np.nan), axis=0), np.nan)
                ax.plot(np.arange(1, length + 1), mean, color=color, label=f"{model} ({len(curves)} runs)")
            elif model in FEATURE_BASELINES:
                ax.axhline(_finite(metrics.get("val_mcc"), math.nan), color=color, ls="--", lw=1.2,
                           label=f"{model} (fitted once)")  # fmt: skip
        ax.set_title(f"{key[1]}, {key[0]} split", fontsize=9)
        ax.set_xlabel("epoch", fontsize=8)
        ax.set_ylabel("validation MCC (mean over runs)", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    for ax in list(axes.flat)[len(keys):]:
        ax.axis("off")
    fig.suptitle("Validation MCC per epoch (mean over the runs still training, shown while at least half are) "
                 "against the feature baselines' validation MCC (dashed)", fontsize=9)  # fmt: skip
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return True


def write_run_plots(members: list[dict[str, Any]], out_dir: Path) -> list[Path]:
    """run_plots/<split>_<property>_<model>/ for the runs whose folder has no plots."""
    from aslexp.recognition.experiment import CONFUSION_FILE, plots_from_metrics

    written = []
    for run in members:
        if not (run["dir"] / CONFUSION_FILE).exists():
            name = f"{run['split']}_{run['property']}_{run['classifier']}"
            written.append(plots_from_metrics(run["metrics"], out_dir / name))
    return written


def _metric_order(run: dict[str, Any]) -> tuple:
    """Completed runs with a finite main metric first, best first (by its goal); then the rest."""
    info = run["info"]
    main = info.get("main_metric") or {}
    value = _finite(main.get("value"), math.nan)
    if info.get("status") != "completed" or math.isnan(value):
        return (1, 0.0, str(run["dir"]))
    return (0, value if main.get("goal") == "minimize" else -value, str(run["dir"]))


def runs_table(others: list[dict[str, Any]], base: Path) -> tuple[str, str]:
    """The runs of jobs other than recognize (a tune_pd or imitate sweep, the quadratic job), per
    job best first: (markdown, csv) of run folder, status, main metric and overrides."""
    header = ["job", "run", "status", "main metric", "value", "goal", "overrides"]
    rows = []
    for run in sorted(others, key=lambda r: (str(r["info"].get("job")), _metric_order(r))):
        info, main = run["info"], run["info"].get("main_metric") or {}
        try:
            where = str(run["dir"].resolve().relative_to(base.resolve()))
        except ValueError:
            where = str(run["dir"])
        overrides = [o for o in read.read_overrides(run["dir"]) or [] if not o.startswith("hydra.")]
        value = main.get("value")
        rows.append([str(info.get("job") or "-"), where, str(info.get("status") or "-"), str(main.get("name") or "-"),
                     "-" if value is None else f"{value:.6g}", str(main.get("goal") or "-"), " ".join(overrides)])
    markdown = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    markdown += ["| " + " | ".join(cell.replace("|", "\\|") or "-" for cell in row) + " |" for row in rows]
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(header)
    writer.writerows(rows)
    return "\n".join(markdown) + "\n", buffer.getvalue()


def write_report(paths: list[Path], out_dir: Path) -> dict[str, Any]:
    """The recognition tables of the completed recognition runs under ``paths`` (one run per
    split, model and property: the best by validation where a sweep ran several) and runs.md /
    runs.csv for the runs of other jobs."""
    from aslexp.recognition.report import (
        collect_table,
        comparisons,
        comparisons_markdown,
        thesis_c2_table,
        thesis_ch3_table,
        thesis_ch4_table,
    )

    runs, others, skipped = find_runs(paths)
    if skipped:
        log.info("skipped run directories: %s", skipped)
    if not runs and not others:
        raise SystemExit(f"aslexp report: no completed recognition runs and no runs of other jobs under "
                         f"{', '.join(map(str, paths))}")
    out_dir.mkdir(parents=True, exist_ok=True)
    result: dict[str, Any] = {"runs": len(runs), "other_runs": len(others), "skipped": skipped, "table": "",
                              "best_vs_baseline": "", "runs_table": "", "out_dir": str(out_dir)}
    if others:
        markdown, table_csv = runs_table(others, out_dir)
        (out_dir / "runs.md").write_text(markdown, encoding="utf-8")
        (out_dir / "runs.csv").write_text(table_csv, encoding="utf-8")
        result["runs_table"] = markdown
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for run in runs:
        groups[(str(run.get("lexicon")), str(run["layout"]))].append(run)
    tables, best_md = [], []
    for (lexicon, layout), found in sorted(groups.items()):
        suffix = "" if len(groups) == 1 else f"_{lexicon}_{layout}"
        members = best_by_validation(found)
        cells = [{"model": r["classifier"], "property": r["property"], "split": r["split"], "metrics": r["metrics"]}
                 for r in members]  # fmt: skip
        chosen = "" if len(members) == len(found) else f" (the best by validation of {len(found)})"
        heading = f"{lexicon}, {layout}: {len(members)} runs{chosen}\n\n"
        markdown, table_csv = collect_table(cells)
        (out_dir / f"table{suffix}.md").write_text(heading + markdown, encoding="utf-8")
        (out_dir / f"table{suffix}.csv").write_text(table_csv, encoding="utf-8")
        compared = comparisons(cells)
        (out_dir / f"comparisons{suffix}.md").write_text(heading + comparisons_markdown(compared), encoding="utf-8")
        write_json(out_dir / f"comparisons{suffix}.json", compared)
        plot_comparisons(compared, out_dir / f"comparisons{suffix}.png")
        plot_validation_curves(members, out_dir / f"validation_curves{suffix}.png")
        plotted = write_run_plots(members, out_dir / f"run_plots{suffix}")
        if plotted:
            log.info("%d run(s) without plots: drawn from metrics.json into %s", len(plotted), out_dir / f"run_plots{suffix}")
        (out_dir / f"table_thesis_ch3{suffix}.md").write_text(heading + thesis_ch3_table(cells), encoding="utf-8")
        (out_dir / f"table_thesis_ch4{suffix}.md").write_text(
            heading + thesis_ch4_table(cells) + "\n" + thesis_c2_table(cells), encoding="utf-8")
        best = best_vs_baseline(members)
        (out_dir / f"best_vs_baseline{suffix}.md").write_text(heading + best_vs_baseline_markdown(best), encoding="utf-8")
        (out_dir / f"best_vs_baseline{suffix}.csv").write_text(_rows_csv(best), encoding="utf-8")
        plot_best_vs_baseline(best, out_dir / f"best_vs_baseline{suffix}.png")
        write_json(out_dir / f"agreement{suffix}.json", agreement(members))
        tables.append(heading + markdown)
        best_md.append(heading + best_vs_baseline_markdown(best))
    result.update({"table": "\n".join(tables), "best_vs_baseline": "\n".join(best_md)})
    return result


# --------------------------------------------------------------------------- the results page


def _selected(runs: list[dict[str, Any]], select: dict[str, list[Any]] | None) -> list[dict[str, Any]]:
    """The runs whose context matches every ``key: [values]`` of ``select`` (split, property, classifier)."""
    wanted = {key: {str(v) for v in values} for key, values in (select or {}).items()}
    return [r for r in runs if all(str(r.get(key)) in values for key, values in wanted.items())]


def _spread(values: list[float], spread: str, unit: str, wald: tuple[float, float] | None = None
            ) -> tuple[float | None, float | None, str]:
    """(mean, spread, what the spread is) of ``values`` over the units: ``std`` (sample std) or
    ``ci95`` (the 95% t half-width; for one test set, its own Wald half-width where given)."""
    from aslexp.recognition.metrics import mean_interval

    interval = mean_interval(values)
    mean = None if math.isnan(interval["mean"]) else interval["mean"]
    if interval["n"] >= 2:
        value = interval["std"] if spread == "std" else interval["half_width"]
        return mean, value, f"{'std' if spread == 'std' else '95% t half-width'} over {unit}s"
    if spread == "ci95" and wald is not None and all(math.isfinite(v) for v in wald):
        return mean, (wald[1] - wald[0]) / 2, "95% Wald half-width of the one test set"
    return mean, None, f"one {unit}: no spread"


def _order(key: tuple[str, str]) -> tuple:
    from aslexp.recognition.report import PROPERTY_ORDER, SPLIT_ORDER

    split, second = key
    return (SPLIT_ORDER.index(split) if split in SPLIT_ORDER else len(SPLIT_ORDER),
            PROPERTY_ORDER.index(second) if second in PROPERTY_ORDER else len(PROPERTY_ORDER), key)


def results_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """The results page's rows of recognition runs (``report: recognition``): per split and property,
    the model chosen by validation among all (or among ``options.learned_models``, a protocol's own
    models; one run per split, model and property: the best by validation), its test
    ``options.metric`` as mean ± ``options.spread`` over the units, the chance baseline chosen by
    validation accuracy, and the strongest simple baseline (the best of rf, hgb, logreg and svm by
    validation). Test numbers never choose."""
    from aslexp.recognition.report import FEATURE_BASELINES, unit_values
    from aslexp.reports import results_recognition

    options = entry.get("options") or {}
    metric, spread = options.get("metric", "mcc"), options.get("spread", "ci95")
    runs, _, skipped = find_runs(folders)
    runs = _selected(runs, options.get("select"))
    cells: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for run in best_by_validation(runs):
        cells[(str(run["split"]), str(run["property"]))].append(run)
    rows = []
    learned_models = options.get("learned_models")  # the protocol's models; None: every model that ran
    for split, prop in sorted(cells, key=_order):
        group = cells[(split, prop)]
        candidates = [r for r in group if learned_models is None or r["classifier"] in learned_models]
        if not candidates:  # said on the page: "left out: N (...)"
            key = f"runs of a split and property no model of {learned_models} ran on"
            skipped[key] = skipped.get(key, 0) + len(group)
            continue
        best = max(candidates, key=_validation_key)
        metrics, unit = best["metrics"], best["metrics"].get("statistics_unit", "seed")
        per_seed = metrics.get("test_per_seed") or [{}]
        wald = (_finite(per_seed[0].get(f"{metric}_ci_low"), math.nan),
                _finite(per_seed[0].get(f"{metric}_ci_high"), math.nan))
        mean, width, kind = _spread(unit_values(metrics, metric), spread, unit, wald)
        simple = [r for r in group if r["classifier"] in FEATURE_BASELINES]
        baselines = [{"label": "chance baseline (by validation)", "kind": "no-learning",
                      "name": metrics["baseline"]["name"], "value": _spread(unit_values(metrics, metric, baseline=True), spread, unit)[0]}]
        if simple:
            strongest = max(simple, key=_validation_key)
            baselines.append({"label": "strongest simple baseline (by validation)", "kind": "simple",
                              "name": strongest["classifier"],
                              "value": _spread(unit_values(strongest["metrics"], metric), spread, unit)[0]})
        # the test clips, the interval that holds at that size, the majority class's value, the data's facts
        facts = results_recognition.run_fields(best, metric, mean, unit_values(metrics, metric))
        rows.append({"key": f"{split}/{prop}", "label": f"{split}, {prop}", "thesis": None, "baselines": baselines,
                     "learned": {"what": f"test {metric} of the model chosen by validation", "mean": mean,
                                 "spread": width, "spread_kind": kind, "n": len(unit_values(metrics, metric)),
                                 "unit": f"{unit}s", "model": best["classifier"], "models_compared": len(candidates),
                                 **facts["learned"]},
                     "steps": None, **facts["row"]})
    return {"rows": rows, "run_dirs": [r["dir"] for r in runs], "skipped": skipped, "quantity": f"test {metric}",
            "row_name": "split, property"}


def _per_class_values(units: dict[Any, list[dict[str, Any]]], label: str, key: str) -> list[float]:
    """Per unit (the runs of one split, or one run), the mean over its runs of ``key`` of class ``label``."""
    out = []
    for members in units.values():
        found = [_finite(c.get(key), math.nan) for m in members for c in m.get("per_class", [])
                 if str(c.get("label")) == label]
        if found:
            out.append(float(sum(found) / len(found)))
    return out


def results_per_class_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """The results page's rows of one model on one property per split (``report: recognition_per_class``,
    Table 4.4's layout): per class the thesis' A = TP_c / N_test, precision and recall on the test
    set, mean over the units (splits, else model seeds) ± ``options.spread``."""
    from aslexp.reports import results_recognition

    options = entry.get("options") or {}
    runs, _, skipped = find_runs(folders)
    runs = _selected(runs, options.get("select"))
    rows = []
    for run in sorted(best_by_validation(runs), key=lambda r: (_order((str(r["split"]), str(r["property"]))),
                                                               str(r["classifier"]))):
        metrics = run["metrics"]
        unit = metrics.get("statistics_unit", "seed")
        sizes = results_recognition.run_sizes(metrics)
        units: dict[Any, list[dict[str, Any]]] = defaultdict(list)
        for index, test in enumerate(metrics.get("test_per_seed") or []):
            units[test.get("split") if unit == "split" else index].append(test)
        for label in metrics.get("label_names") or []:
            def values(key: str, label: str = str(label)) -> list[float]:
                return _per_class_values(units, label, key)

            mean, width, kind = _spread(values("thesis_a"), options.get("spread", "ci95"), unit)
            rows.append({"key": f"{run['split']}/{label}", "label": f"{run['split']}, {label}", "thesis": None,
                         "n_test": sizes["n_test"], "n_all": sizes["n_all"], "n_test_source": sizes["n_test_source"],
                         "baselines": [],
                         "learned": {"what": f"per-class A = TP_c / N_test, {run['classifier']} on {run['property']}",
                                     "mean": mean, "spread": width, "spread_kind": kind, "n": len(values("thesis_a")),
                                     "unit": f"{unit}s", "model": run["classifier"]},
                         "extra": {"precision": _spread(values("precision"), "std", unit)[0],
                                   "recall": _spread(values("recall"), "std", unit)[0]},
                         "steps": None})
    return {"rows": rows, "run_dirs": [r["dir"] for r in runs], "skipped": skipped,
            "quantity": "per-class test numbers", "row_name": "split, class"}


def add_test_clips_to_snapshots(catalogue_path: str | Path, snapshots: str | Path) -> dict[str, str]:
    """:func:`add_test_clips` on every ``report: recognition`` snapshot whose rows lack ``n_test``
    (written back); id -> what happened."""
    from aslexp.reports.results_page import load_catalogue, read_snapshot, snapshot_path, write_snapshot
    from aslexp.reports.results_recognition import add_test_clips

    done = {}
    for entry in load_catalogue(catalogue_path):
        if entry["report"] != "recognition":
            continue
        path = snapshot_path(Path(snapshots), entry["id"])
        snapshot = read_snapshot(path)
        if snapshot is None:
            continue
        if all("n_test" in row for row in snapshot["rows"]):
            done[entry["id"]] = "has its test clips"
            continue
        write_snapshot(path, add_test_clips(entry, snapshot))
        done[entry["id"]] = "test clips added (the split recomputed from the data)"
    return done


RESULTS_SUMMARIES = {"recognition": results_summary, "recognition_per_class": results_per_class_summary}


def results_main(args: argparse.Namespace) -> int:
    """``aslexp report --results``: the snapshots from the run folders, then docs/results.md."""
    from aslexp.reports import results_page

    if not args.catalogue.is_file():
        print(f"aslexp report: {args.catalogue}: no such file", file=sys.stderr)
        return 2
    if args.add_test_clips:
        for entry_id, what in add_test_clips_to_snapshots(args.catalogue, args.snapshots).items():
            print(f"{entry_id}: {what}")
    result = results_page.write_results(args.catalogue, args.outputs, args.snapshots, args.page,
                                        RESULTS_SUMMARIES, render_only=args.render_only)
    for entry_id, what in result["entries"].items():
        print(f"{entry_id}: {what}")
    print(f"-> {result['page']}")
    return 0


def report_main(argv: list[str]) -> int:
    from aslexp.reports import results_page

    parser = argparse.ArgumentParser(prog="aslexp report", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="*", type=Path, help="run or sweep directories")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: first path)")
    page = parser.add_argument_group("the results page (docs/results.md, from conf/results.yaml)")
    page.add_argument("--results", action="store_true",
                      help="summarise every result of the catalogue whose run folders are under --outputs into "
                           "its snapshot (docs/results/<id>.json; others keep theirs) and render the page")
    page.add_argument("--render-only", action="store_true", help="with --results: render the page from the snapshots")
    page.add_argument("--add-test-clips", action="store_true",
                      help="with --results: first add the test clips (the split recomputed from the data), intervals "
                           "and majority values to the recognition snapshots that lack them (run folders gone)")
    page.add_argument("--outputs", type=Path, default=Path("outputs"),
                      help="where the run folders are (default: outputs)")
    page.add_argument("--catalogue", type=Path, default=results_page.CATALOGUE, help="default: conf/results.yaml")
    page.add_argument("--snapshots", type=Path, default=results_page.SNAPSHOTS, help="default: docs/results")
    page.add_argument("--page", type=Path, default=results_page.PAGE, help="default: docs/results.md")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.results:
        if args.paths:
            parser.error("--results reads the catalogue's folders: give no paths")
        return results_main(args)
    if args.render_only or args.add_test_clips:
        parser.error("--render-only and --add-test-clips go with --results")
    if not args.paths:
        parser.error("give run or sweep directories, or --results")
    missing = [path for path in args.paths if not path.exists()]
    if missing:
        print(f"aslexp report: {missing[0]}: no such file or directory", file=sys.stderr)
        return 2
    result = write_report(args.paths, args.out or args.paths[0])
    if result["runs"]:
        print(f"{result['runs']} recognition runs -> {result['out_dir']}\n")
        print(result["table"])
        print(result["best_vs_baseline"])
    if result["other_runs"]:
        print(f"{result['other_runs']} runs of other jobs -> {Path(result['out_dir']) / 'runs.md'}\n")
        print(result["runs_table"])
    for path in args.paths:
        if (path / "sweep.json").is_file():
            print(f"{path} is an Optuna sweep: `aslexp sweep report {path}` draws its study (history, importances)")
    return 0
