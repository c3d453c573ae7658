"""`aslexp report RUN_OR_SWEEP_DIR... [--out DIR]`: recognition runs -> the thesis' tables.

Reads only run directories (run.json + metrics.json + predictions.csv) and writes:

    table.md / table.csv              models x properties: test accuracy (95% CI), balanced acc.
    best_vs_baseline.md / .csv        per property and split: the model chosen by validation MCC
                                      against the better of the majority/stratified baselines
    best_vs_baseline.png              the same as a bar chart (test MCC, balanced accuracy)
    agreement.json                    Fleiss' kappa on clips that all models misclassify, and the
                                      mutual misclassification rate across properties (thesis 4.4)
"""

from __future__ import annotations

import argparse
import csv
import io
import json
import logging
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

from aslexp.runs.record import METRICS_FILE, RUN_FILE, read_json, write_json

log = logging.getLogger(__name__)


def find_recognition_runs(paths: list[Path]) -> tuple[list[dict[str, Any]], dict[str, int]]:
    """Completed recognition runs under ``paths``; counts what was skipped and why."""
    runs, skipped = [], defaultdict(int)
    for base in paths:
        if not base.exists():
            raise FileNotFoundError(f"aslexp report: {base} does not exist")
        for run_file in sorted(base.rglob(RUN_FILE)):
            run_dir = run_file.parent
            try:
                info = read_json(run_file)
            except (OSError, json.JSONDecodeError):
                skipped["unreadable run.json"] += 1
                continue
            if info.get("job") != "recognize":
                skipped[f"job {info.get('job')}"] += 1
                continue
            if info.get("status") != "completed" or not (run_dir / METRICS_FILE).exists():
                skipped[f"status {info.get('status')}"] += 1
                continue
            metrics = read_json(run_dir / METRICS_FILE)
            runs.append({"dir": run_dir, "info": info, "metrics": metrics, **metrics["context"]})
    return runs, dict(skipped)


def _read_predictions(run_dir: Path) -> dict[int, dict[str, tuple[str, str]]]:
    """seed -> video_id -> (true, predicted)."""
    by_seed: dict[int, dict[str, tuple[str, str]]] = defaultdict(dict)
    path = run_dir / "predictions.csv"
    if not path.exists():
        return {}
    with open(path, encoding="utf-8") as fh:
        for row in csv.DictReader(fh):
            by_seed[int(row["seed"])][row["video_id"]] = (row["true"], row["predicted"])
    return by_seed


def _key(run: dict[str, Any]) -> tuple[str, str, str, str]:
    return (run["lexicon"], run["pose"], run["split"], run["property"])


def best_vs_baseline(runs: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per (lexicon, pose, split, property): the model with the best *validation* MCC."""
    groups: dict[tuple, list[dict[str, Any]]] = defaultdict(list)
    for run in runs:
        groups[_key(run)].append(run)
    rows = []
    for (lexicon, pose, split, prop), members in sorted(groups.items()):
        best = max(members, key=lambda r: _finite(r["metrics"]["val_mcc"], -math.inf))
        test, test_std = best["metrics"]["test"], best["metrics"].get("test_std", {})
        base = best["metrics"]["baseline"]
        rows.append({
            "lexicon": lexicon, "pose": pose, "split": split, "property": prop,
            "model": best["classifier"], "models_compared": len(members),
            "num_classes": best["num_classes"], "n_test": int(test.get("n", 0)),
            "seeds": len(best["seeds"]), "val_mcc": best["metrics"]["val_mcc"],
            "test_mcc": test["mcc"], "test_mcc_std": test_std.get("mcc", math.nan),
            "test_balanced_accuracy": test["balanced_accuracy"],
            "test_balanced_accuracy_std": test_std.get("balanced_accuracy", math.nan),
            "test_accuracy": test["accuracy"],
            "test_accuracy_ci_low": test["accuracy_ci_low"],
            "test_accuracy_ci_high": test["accuracy_ci_high"],
            "baseline": base["name"], "baseline_mcc": base["test"]["mcc"],
            "baseline_balanced_accuracy": base["test"]["balanced_accuracy"],
            "baseline_accuracy": base["test"]["accuracy"],
            "run": str(best["dir"]),
        })
    return rows


def _finite(value: Any, default: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return default
    return value if math.isfinite(value) else default


def _fmt(value: Any, digits: int = 3) -> str:
    value = _finite(value, math.nan)
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def best_vs_baseline_markdown(rows: list[dict[str, Any]]) -> str:
    header = ("| split | property | classes | n test | best model (by val MCC) | test MCC | "
              "test bal. acc | test acc (95% CI) | baseline | baseline MCC | baseline bal. acc |")
    lines = [header, "|" + "---|" * (header.count("|") - 1)]
    for r in rows:
        lines.append(
            f"| {r['split']} | {r['property']} | {r['num_classes']} | {r['n_test']} | {r['model']} | "
            f"{_fmt(r['test_mcc'])} ± {_fmt(r['test_mcc_std'])} | "
            f"{_fmt(r['test_balanced_accuracy'])} ± {_fmt(r['test_balanced_accuracy_std'])} | "
            f"{_fmt(r['test_accuracy'])} [{_fmt(r['test_accuracy_ci_low'])}, {_fmt(r['test_accuracy_ci_high'])}] | "
            f"{r['baseline']} | {_fmt(r['baseline_mcc'])} | {_fmt(r['baseline_balanced_accuracy'])} |"
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
    """Fleiss' kappa across models per (split, property); mutual misclassification per model."""
    from aslexp.recognition.metrics import misclassification_agreement, mutual_misclassification

    predictions = {id(run): _read_predictions(run["dir"]) for run in runs}
    kappa: dict[str, Any] = {}
    groups: dict[tuple, list[dict[str, Any]]] = defaultdict(list)
    for run in runs:
        groups[_key(run)].append(run)
    for (lexicon, pose, split, prop), members in sorted(groups.items()):
        first_seed = {r["classifier"]: predictions[id(r)].get(min(predictions[id(r)], default=0), {})
                      for r in members}
        first_seed = {name: preds for name, preds in first_seed.items() if preds}
        common = sorted(set.intersection(*(set(p) for p in first_seed.values()))) if first_seed else []
        if len(first_seed) < 2 or not common:
            continue
        labels = sorted({p[vid][0] for p in first_seed.values() for vid in common}
                        | {p[vid][1] for p in first_seed.values() for vid in common})
        index = {label: i for i, label in enumerate(labels)}
        y_true = [index[next(iter(first_seed.values()))[vid][0]] for vid in common]
        preds = {name: [index[p[vid][1]] for vid in common] for name, p in first_seed.items()}
        kappa[f"{split}/{prop}"] = misclassification_agreement(y_true, preds, len(labels))
    mutual: dict[str, Any] = {}
    by_model: dict[tuple, dict[str, tuple[list[str], list[bool]]]] = defaultdict(dict)
    for run in runs:
        preds = predictions[id(run)]
        if not preds:
            continue
        seed_preds = preds[min(preds)]
        vids = sorted(seed_preds)
        by_model[(run["split"], run["classifier"])][run["property"]] = (
            vids, [seed_preds[v][0] == seed_preds[v][1] for v in vids])
    for (split, model), results in sorted(by_model.items()):
        if len(results) >= 2:
            mutual[f"{split}/{model}"] = mutual_misclassification(results)
    return {"fleiss_kappa_all_wrong": kappa, "mutual_misclassification": mutual}


def plot_best_vs_baseline(rows: list[dict[str, Any]], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    splits = sorted({r["split"] for r in rows})
    fig, axes = plt.subplots(len(splits), 2, figsize=(12, 3.2 * len(splits)), squeeze=False)
    for i, split in enumerate(splits):
        sub = [r for r in rows if r["split"] == split]
        x = np.arange(len(sub))
        for j, (metric, label) in enumerate((("mcc", "test MCC"), ("balanced_accuracy", "test balanced accuracy"))):
            ax = axes[i, j]
            best = [_finite(r[f"test_{metric}"], 0.0) for r in sub]
            err = [_finite(r[f"test_{metric}_std"], 0.0) for r in sub]
            base = [_finite(r[f"baseline_{metric}"], 0.0) for r in sub]
            ax.bar(x - 0.2, best, 0.4, yerr=err, capsize=3, label="best model (by val MCC)")
            ax.bar(x + 0.2, base, 0.4, label="baseline", color="0.6")
            ax.set_xticks(x, [f"{r['property']}\n({r['model']})" for r in sub], fontsize=7)
            ax.set_title(f"{split} split: {label}")
            ax.axhline(0, color="k", lw=0.5)
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)


def write_report(paths: list[Path], out_dir: Path) -> dict[str, Any]:
    from aslexp.recognition.report import collect_table

    runs, skipped = find_recognition_runs(paths)
    if skipped:
        log.info("skipped run directories: %s", skipped)
    if not runs:
        raise SystemExit(f"aslexp report: no completed recognition runs under {', '.join(map(str, paths))}")
    out_dir.mkdir(parents=True, exist_ok=True)
    table_rows = [
        {"model": r["classifier"], "property": r["property"], "split": r["split"], "metrics": r["metrics"]["test"]}
        for r in runs
    ]
    baselines = {}
    for r in runs:
        baselines.setdefault((r["split"], r["property"]), r["metrics"]["baseline"]["test"])
    table_rows += [{"model": "baseline", "property": p, "split": s, "metrics": m} for (s, p), m in baselines.items()]
    markdown, table_csv = collect_table(table_rows)
    (out_dir / "table.md").write_text(markdown, encoding="utf-8")
    (out_dir / "table.csv").write_text(table_csv, encoding="utf-8")
    best = best_vs_baseline(runs)
    best_md = best_vs_baseline_markdown(best)
    (out_dir / "best_vs_baseline.md").write_text(best_md, encoding="utf-8")
    (out_dir / "best_vs_baseline.csv").write_text(_rows_csv(best), encoding="utf-8")
    plot_best_vs_baseline(best, out_dir / "best_vs_baseline.png")
    write_json(out_dir / "agreement.json", agreement(runs))
    return {"runs": len(runs), "skipped": skipped, "table": markdown, "best_vs_baseline": best_md,
            "out_dir": str(out_dir)}


def report_main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="aslexp report", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="+", type=Path, help="run or sweep directories")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: first path)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    result = write_report(args.paths, args.out or args.paths[0])
    print(f"{result['runs']} recognition runs -> {result['out_dir']}\n")
    print(result["table"])
    print(result["best_vs_baseline"])
    return 0
