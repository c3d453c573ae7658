"""Tables of recognition runs laid out as in the thesis: models x properties, per split.

Plots for single runs live in :mod:`aslexp.viz.plots`; they are re-exported here.
"""

from __future__ import annotations

import csv
import io
import math
from collections.abc import Mapping, Sequence
from typing import Any

from aslexp.viz.plots import plot_confusion_matrix, plot_learning_curves

__all__ = ["collect_table", "plot_confusion_matrix", "plot_learning_curves"]


def _ordered_unique(values: Sequence[str]) -> list[str]:
    return list(dict.fromkeys(values))


def _number(value: Any) -> float:
    return math.nan if value is None else float(value)


def _fmt(value: float) -> str:
    return "-" if math.isnan(value) else f"{value:.3f}"


def collect_table(rows: Sequence[Mapping[str, Any]]) -> tuple[str, str]:
    """Lay runs out as the thesis' recognition table: (markdown, csv).

    Each row: ``{"model": str, "property": str, "split": str, "metrics": {...}}`` where metrics
    holds ``accuracy``, ``accuracy_ci_low``, ``accuracy_ci_high`` and ``balanced_accuracy``
    (e.g. ``run_recognition(...)["test"]``, or ``["baseline"]["test"]`` with model 'baseline').

    One table row per (split, model), in first-appearance order; per property two columns:
    accuracy with its 95% CI half-width ("0.512 ± 0.061") and balanced accuracy. Missing
    combinations show '-'. The CSV has the same layout with separate numeric columns
    ``<property>_accuracy``, ``_accuracy_ci_low``, ``_accuracy_ci_high``, ``_balanced_accuracy``.
    """
    cells: dict[tuple[str, str, str], Mapping[str, Any]] = {}
    for row in rows:
        missing = [key for key in ("model", "property", "split", "metrics") if key not in row]
        if missing:
            raise ValueError(f"table row lacks {missing}: {dict(row)}")
        key = (str(row["split"]), str(row["model"]), str(row["property"]))
        if key in cells:
            raise ValueError(f"two rows for split={key[0]}, model={key[1]}, property={key[2]}")
        cells[key] = row["metrics"]

    splits = _ordered_unique([key[0] for key in cells])
    models = _ordered_unique([key[1] for key in cells])
    properties = _ordered_unique([key[2] for key in cells])

    header = ["split", "model"]
    for prop in properties:
        header += [f"{prop} acc (95% CI)", f"{prop} bal. acc"]
    markdown = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]

    csv_header = ["split", "model"]
    for prop in properties:
        csv_header += [f"{prop}_accuracy", f"{prop}_accuracy_ci_low", f"{prop}_accuracy_ci_high", f"{prop}_balanced_accuracy"]
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(csv_header)

    for split in splits:
        for model in models:
            if not any((split, model, prop) in cells for prop in properties):
                continue
            md_cells, csv_cells = [split, model], [split, model]
            for prop in properties:
                metrics = cells.get((split, model, prop), {})
                accuracy = _number(metrics.get("accuracy"))
                low, high = _number(metrics.get("accuracy_ci_low")), _number(metrics.get("accuracy_ci_high"))
                balanced = _number(metrics.get("balanced_accuracy"))
                if math.isnan(accuracy):
                    md_cells.append("-")
                elif math.isnan(low) or math.isnan(high):
                    md_cells.append(_fmt(accuracy))
                else:
                    md_cells.append(f"{accuracy:.3f} ± {(high - low) / 2:.3f}")
                md_cells.append(_fmt(balanced))
                csv_cells += [repr_float(accuracy), repr_float(low), repr_float(high), repr_float(balanced)]
            markdown.append("| " + " | ".join(md_cells) + " |")
            writer.writerow(csv_cells)
    return "\n".join(markdown) + "\n", buffer.getvalue()


def repr_float(value: float) -> str:
    """A CSV cell: empty for NaN, else the shortest exact float text."""
    return "" if math.isnan(value) else repr(float(value))
