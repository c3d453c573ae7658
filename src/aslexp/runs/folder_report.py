"""``aslexp report RUN_OR_SWEEP_DIR... [--out DIR]``: the files of the recognition runs under the folders
(tables, comparisons, plots, the thesis' agreement; :mod:`aslexp.recognition.report`,
:mod:`aslexp.recognition.tables`, :mod:`aslexp.viz.recognition`) and the table of the runs of other
jobs. What each file holds: ``aslexp report --help``.
"""

from __future__ import annotations

import csv
import io
import logging
import math
from collections import defaultdict
from pathlib import Path
from typing import Any

from aslexp.files import write_json
from aslexp.recognition.tables import (agreement, best_by_validation, best_vs_baseline, best_vs_baseline_markdown,
                                       finite, panel_order, rows_csv)
from aslexp.runs import read
from aslexp.runs.completed import find_runs, read_predictions

log = logging.getLogger(__name__)


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
    value = finite(main.get("value"), math.nan)
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
    from aslexp.recognition.report import (FEATURE_BASELINES, MODEL_ORDER, collect_table, comparisons,
                                           comparisons_markdown, thesis_c2_table, thesis_ch3_table, thesis_ch4_table)

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
        # matplotlib only where there are recognition runs to draw (runs.md needs none)
        from aslexp.viz.recognition import plot_best_vs_baseline, plot_comparisons, plot_validation_curves

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
        plot_comparisons(compared, out_dir / f"comparisons{suffix}.png", order=panel_order)
        plot_validation_curves(members, out_dir / f"validation_curves{suffix}.png", order=panel_order,
                               model_order=MODEL_ORDER, baselines=FEATURE_BASELINES)
        plotted = write_run_plots(members, out_dir / f"run_plots{suffix}")
        if plotted:
            log.info("%d run(s) without plots: drawn from metrics.json into %s", len(plotted), out_dir / f"run_plots{suffix}")
        (out_dir / f"table_thesis_ch3{suffix}.md").write_text(heading + thesis_ch3_table(cells), encoding="utf-8")
        (out_dir / f"table_thesis_ch4{suffix}.md").write_text(
            heading + thesis_ch4_table(cells) + "\n" + thesis_c2_table(cells), encoding="utf-8")
        best = best_vs_baseline(members)
        (out_dir / f"best_vs_baseline{suffix}.md").write_text(heading + best_vs_baseline_markdown(best), encoding="utf-8")
        (out_dir / f"best_vs_baseline{suffix}.csv").write_text(rows_csv(best), encoding="utf-8")
        plot_best_vs_baseline(best, out_dir / f"best_vs_baseline{suffix}.png")
        write_json(out_dir / f"agreement{suffix}.json", agreement(members, read_predictions))
        tables.append(heading + markdown)
        best_md.append(heading + best_vs_baseline_markdown(best))
    result.update({"table": "\n".join(tables), "best_vs_baseline": "\n".join(best_md)})
    return result
