"""Tables of recognition runs: the platform's table with intervals and paired comparisons, and the
thesis' layouts (Table 3.4, Tables 4.2/4.3, Table C.2).

Every function takes *cells*: ``{"model", "property", "split", "metrics"}`` with ``metrics`` a run's
metrics.json (as :func:`aslexp.recognition.experiment.run_recognition` returns it). Numbers are
fractions (the thesis prints percentages; the thesis layouts here print percentages too).

Intervals. With K > 1 splits the unit is the split: mean over splits, 95% t interval of the mean.
With one split the thesis' own interval is shown where it has one (Tables 4.2/4.3: the Wald
interval of that split's accuracy) and mean ± std over model seeds where it reports that
(Table 3.4). An interval is never an average of per-run intervals.
"""

from __future__ import annotations

import csv
import io
import math
from collections import defaultdict
from collections.abc import Mapping, Sequence
from typing import Any

from aslexp.recognition.metrics import mean_interval, paired_comparison
from aslexp.recognition.registry import BUILT_IN

__all__ = [
    "BELOW_BASELINE",
    "collect_table",
    "comparison_text",
    "comparisons",
    "comparisons_markdown",
    "thesis_c2_table",
    "thesis_ch3_table",
    "thesis_ch4_table",
]

BELOW_BASELINE = "▼"  # the model's mean is below its chance baseline's mean on the same splits
FEATURE_BASELINES = ("rf", "hgb", "logreg", "svm")  # candidates for the strongest simple baseline
THESIS_PROPERTY_ORDER = ("flexion", "major_location", "minor_location", "movement", "selected_fingers", "sign_type")
THESIS_NAMES = {"flexion": "Flexion", "major_location": "MajLoc", "minor_location": "MinLoc", "movement": "Movement",
                "selected_fingers": "Fingers", "sign_type": "SignType"}  # fmt: skip


MODEL_ORDER = BUILT_IN  # the registry's table order (aslexp.recognition.registry)
SPLIT_ORDER = ("phoneme", "gloss", "cv5")
PROPERTY_ORDER = ("sign_type", "major_location", "minor_location", "selected_fingers", "flexion", "movement")


def _ordered_unique(values: Sequence[str]) -> list[str]:
    """Distinct values, the known ones (splits, models, properties) in their usual order first."""
    unique = list(dict.fromkeys(values))
    for order in (SPLIT_ORDER, MODEL_ORDER, PROPERTY_ORDER, THESIS_PROPERTY_ORDER):
        if any(value in order for value in unique):
            known = [v for v in order if v in unique]
            return known + [v for v in unique if v not in known]
    return unique


def _number(value: Any) -> float:
    try:
        return math.nan if value is None else float(value)
    except (TypeError, ValueError):
        return math.nan


def _fmt(value: float, digits: int = 3) -> str:
    return "-" if math.isnan(value) else f"{value:.{digits}f}"


def repr_float(value: float) -> str:
    """A CSV cell: empty for NaN, else the shortest exact float text."""
    return "" if math.isnan(value) else repr(float(value))


def _index(cells: Sequence[Mapping[str, Any]]) -> dict[tuple[str, str, str], Mapping[str, Any]]:
    index: dict[tuple[str, str, str], Mapping[str, Any]] = {}
    for cell in cells:
        missing = [key for key in ("model", "property", "split", "metrics") if key not in cell]
        if missing:
            raise ValueError(f"table cell lacks {missing}: {dict(cell)}")
        key = (str(cell["split"]), str(cell["model"]), str(cell["property"]))
        if key in index:
            raise ValueError(f"two runs for split={key[0]}, model={key[1]}, property={key[2]}")
        index[key] = cell["metrics"]
    return index


def unit_values(metrics: Mapping[str, Any], key: str, baseline: bool = False) -> list[float]:
    """The per-unit test values of ``key``: per split (K > 1) or per model seed (one split)."""
    source = metrics["baseline"] if baseline else metrics
    if metrics.get("statistics_unit", "seed") == "split":
        return [_number(unit.get(key)) for unit in source.get("test_per_split", [])]
    if baseline:
        return [_number(unit.get(key)) for unit in source.get("test_per_split", [])] or [_number(source["test"].get(key))]
    return [_number(run.get(key)) for run in metrics.get("test_per_seed", [])]


def _interval(metrics: Mapping[str, Any], key: str, baseline: bool = False) -> dict[str, float]:
    return mean_interval(unit_values(metrics, key, baseline))


def collect_table(cells: Sequence[Mapping[str, Any]], metric: str = "mcc") -> tuple[str, str]:
    """The platform's table: one row per (split, model), then the chance baseline (the one chosen by
    validation in each run) per split; per property ``metric`` as "mean ± t half-width (n)" over
    the units and the balanced accuracy; ▼ marks a mean below the baseline's. Returns (markdown, csv).
    """
    index = _index(cells)
    splits = _ordered_unique([k[0] for k in index])
    models = _ordered_unique([k[1] for k in index])
    properties = _ordered_unique([k[2] for k in index])
    header = ["split", "model"]
    for prop in properties:
        header += [f"{prop} {metric} (95% CI)", f"{prop} bal. acc"]
    markdown = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    csv_header = ["split", "model"]
    for prop in properties:
        csv_header += [f"{prop}_{metric}", f"{prop}_{metric}_ci_low", f"{prop}_{metric}_ci_high", f"{prop}_n",
                       f"{prop}_balanced_accuracy", f"{prop}_below_baseline"]  # fmt: skip
    buffer = io.StringIO()
    writer = csv.writer(buffer, lineterminator="\n")
    writer.writerow(csv_header)

    def cell_texts(metrics: Mapping[str, Any] | None, baseline: bool) -> tuple[list[str], list[str]]:
        if metrics is None:
            return ["-", "-"], ["", "", "", "", "", ""]
        interval = _interval(metrics, metric, baseline)
        balanced = _interval(metrics, "balanced_accuracy", baseline)["mean"]
        below = (not baseline) and bool(metrics.get("below_baseline", {}).get(metric, False))
        text = _fmt(interval["mean"])
        if not math.isnan(interval["half_width"]):
            text += f" ± {interval['half_width']:.3f}"
        text += f" ({interval['n']})" + (f" {BELOW_BASELINE}" if below else "")
        return ([text, _fmt(balanced)],
                [repr_float(interval["mean"]), repr_float(interval["low"]), repr_float(interval["high"]),
                 str(interval["n"]), repr_float(balanced), str(int(below))])  # fmt: skip

    for split in splits:
        rows = [(model, False) for model in models if any((split, model, p) in index for p in properties)]
        rows.append(("baseline", True))
        for model, is_baseline in rows:
            md_cells, csv_cells = [split, model], [split, model]
            for prop in properties:
                if is_baseline:
                    metrics = next((index[(split, m, prop)] for m in models if (split, m, prop) in index), None)
                    name = metrics["baseline"]["name"] if metrics else "-"
                else:
                    metrics = index.get((split, model, prop))
                texts, values = cell_texts(metrics, is_baseline)
                if is_baseline and metrics is not None:
                    texts[0] += f" [{name}]"
                md_cells += texts
                csv_cells += values
            markdown.append("| " + " | ".join(md_cells) + " |")
            writer.writerow(csv_cells)
    note = (f"\n{metric} on the test sets: mean ± the half-width of the 95% t interval of the mean over the units "
            f"(splits; model seeds when there is one split), (n) units; bal. acc = mean balanced accuracy; "
            f"{BELOW_BASELINE} = mean below the chance baseline (chosen by validation accuracy, [name]).\n")  # fmt: skip
    return "\n".join(markdown) + "\n" + note, buffer.getvalue()


def _strongest_simple(index, split: str, prop: str) -> str | None:
    """The feature/linear model with the best mean validation objective on (split, property)."""
    candidates = [m for m in FEATURE_BASELINES if (split, m, prop) in index]
    if not candidates:
        return None
    return max(candidates, key=lambda m: _number(index[(split, m, prop)].get("objective", {}).get("value",
                                                  index[(split, m, prop)].get("val_mcc"))))  # fmt: skip


def _split_keys(metrics: Mapping[str, Any]) -> list[tuple[int, str]]:
    """Per unit of a run with repeated splits: (split seed, its sizes); a split seed gives the same
    split in every run of one dataset (K only says how many), the sizes guard against another data set."""
    return [(int(s["seed"]), repr(sorted(s.get("sizes", {}).items()))) for s in metrics.get("splits", [])]


def paired_on_shared_splits(metrics: Mapping[str, Any], reference: Mapping[str, Any], metric: str = "mcc"
                            ) -> dict[str, Any] | None:  # fmt: skip
    """``metrics`` minus ``reference`` in ``metric`` on the splits both runs have (e.g. a run over 3
    splits against one over 10: the first 3 are the same splits), or None when they share fewer
    than 2. Runs over one split pair their model seeds when both ran the same split and seeds."""
    values, other = unit_values(metrics, metric), unit_values(reference, metric)
    if metrics.get("statistics_unit", "seed") != "split" or reference.get("statistics_unit", "seed") != "split":
        same = _split_keys(metrics) == _split_keys(reference) and metrics.get("seeds") == reference.get("seeds")
        return paired_comparison(values, other) if same and len(values) == len(other) else None
    keys, other_keys = _split_keys(metrics), _split_keys(reference)
    if len(keys) != len(values) or len(other_keys) != len(other):
        return None
    position = {key: i for i, key in enumerate(other_keys)}
    shared = [(values[i], other[position[key]]) for i, key in enumerate(keys) if key in position]
    if len(shared) < 2:
        return None
    return paired_comparison([a for a, _ in shared], [b for _, b in shared])


def comparisons(cells: Sequence[Mapping[str, Any]], metric: str = "mcc") -> list[dict[str, Any]]:
    """Per (split, property, model): the paired difference in ``metric`` to the run's chance baseline,
    to the strongest simple baseline (the best of rf/hgb/logreg/svm by validation) and to each of
    those four (``vs_feature``), on the splits both share: mean difference, 95% t interval,
    wins/ties/losses, Wilcoxon p (``diff.n`` = the number of shared splits)."""
    index = _index(cells)
    rows = []
    for split, model, prop in index:
        metrics = index[(split, model, prop)]
        values = unit_values(metrics, metric)
        chance = paired_comparison(values, unit_values(metrics, metric, baseline=True)) if len(values) == len(
            unit_values(metrics, metric, baseline=True)) else None  # fmt: skip
        feature = {other: paired_on_shared_splits(metrics, index[(split, other, prop)], metric)
                   for other in FEATURE_BASELINES if other != model and (split, other, prop) in index}  # fmt: skip
        reference = _strongest_simple(index, split, prop)
        rows.append({"split": split, "property": prop, "model": model, "n": len(values),
                     "mean": mean_interval(values)["mean"], "chance_baseline": metrics["baseline"]["name"],
                     "vs_chance": chance, "strongest_simple": reference, "vs_simple": feature.get(reference),
                     "vs_feature": feature})  # fmt: skip
    rows.sort(key=lambda r: (r["split"], r["property"], -_number(r["mean"])))
    return rows


def _diff_text(comparison: Mapping[str, Any] | None) -> str:
    if comparison is None:
        return "-"
    diff = comparison["diff"]
    text = f"{diff['mean']:+.3f}"
    if not math.isnan(diff["low"]):
        text += f" [{diff['low']:+.3f}, {diff['high']:+.3f}]"
    mark = {1: " ▲", -1: " ▼", 0: ""}[comparison["resolved"]]
    return f"{text}{mark} ({comparison['wins']}/{comparison['ties']}/{comparison['losses']}, p={_fmt(comparison['wilcoxon_p'], 2)})"


def comparisons_markdown(rows: Sequence[Mapping[str, Any]], metric: str = "mcc") -> str:
    lines = [f"| split | property | model | n | mean {metric} | vs chance baseline | vs strongest simple baseline |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    for r in rows:
        simple = f"{r['strongest_simple']}: {_diff_text(r['vs_simple'])}" if r["vs_simple"] else (r["strongest_simple"] or "-")
        lines.append(f"| {r['split']} | {r['property']} | {r['model']} | {r['n']} | {_fmt(r['mean'])} | "
                     f"{r['chance_baseline']}: {_diff_text(r['vs_chance'])} | {simple} |")  # fmt: skip
    lines.append(f"\nModel minus reference in test {metric} on the same splits: mean [95% t interval] "
                 "(wins/ties/losses over splits, Wilcoxon signed-rank p); ▲/▼: the interval lies above/below 0. "
                 "The strongest simple baseline is the best of rf, hgb, logreg, svm by validation score; a run "
                 "over fewer splits is paired on the splits it shares with the reference (n = its splits).\n")  # fmt: skip
    learned = [r for r in rows if r["model"] not in FEATURE_BASELINES and r.get("vs_feature")]
    if learned:
        references = [m for m in FEATURE_BASELINES if any(m in r["vs_feature"] for r in learned)]
        lines += ["**Every learned model against each feature baseline** (same splits)", "",
                  "| split | property | model | n | " + " | ".join(f"vs {m}" for m in references) + " |",
                  "|" + "---|" * (4 + len(references))]  # fmt: skip
        for r in learned:
            cells = [_diff_text(r["vs_feature"].get(m)) for m in references]
            lines.append(f"| {r['split']} | {r['property']} | {r['model']} | {r['n']} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


ROLE_WORDS = {"model": "this run", "simple_baseline": "simple baseline", "chance_baseline": "chance"}


def comparison_text(block: Mapping[str, Any], prop: str | None = None, split: str | None = None) -> str:
    """A run's ``comparison`` (metrics.json) as the lines the job prints at its end: a header, one
    row per model (this run, the simple baselines, the best by validation first, the chance
    baseline) with test MCC and balanced accuracy (mean ± std over the splits when there are
    several), the sentence, then its cautions (:func:`aslexp.recognition.comparison.cautions`)."""
    n, unit = int(block["n"]), str(block["unit"])
    seeds, clips = block.get("split_seeds") or [], block.get("test_clips") or []
    where = ", ".join(x for x in (prop, f"{split} split" if split else None) if x)
    if unit == "split":
        over = f"mean ± std over {n} splits (seeds {seeds[0]}..{seeds[-1]})" if seeds else f"mean ± std over {n} splits"
    else:
        over = f"one split (seed {seeds[0]})" if seeds else "one split"
        over += f", mean ± std over {n} model seeds" if n > 1 else ""
    if clips:
        over += f", {min(clips)}-{max(clips)} test clips" if min(clips) != max(clips) else f", {clips[0]} test clips"
    several = len(block.get("candidates", [])) > 1
    rows = []
    for row in block["rows"]:
        words = ROLE_WORDS.get(row["role"], row["role"])
        if row["role"] == "model" and row.get("tied"):
            words = "this run, tied best simple model by validation"
        elif row["role"] == "model" and row.get("reference"):
            words = "this run, best simple model by validation" if several else "this run = the simple baseline"
        elif row["role"] == "simple_baseline" and row.get("tied"):
            words = "simple baseline, tied best by validation"
        elif row["role"] == "simple_baseline" and several and row.get("reference"):
            words = "simple baseline, best by validation"
        label = f"{row['name']} ({words})"
        cells = []
        for key in block["metrics"]:
            value = row["test"][key]
            text = _fmt(value["mean"])
            if n > 1 and math.isfinite(_number(value.get("std"))):
                text += f" ± {_fmt(value['std'])}"
            cells.append(text)
        rows.append((label, *cells))
    header = ("model", *("test MCC" if key == "mcc" else "balanced acc." if key == "balanced_accuracy" else key
                         for key in block["metrics"]))  # fmt: skip
    widths = [max(len(r[i]) for r in [header, *rows]) for i in range(len(header))]
    lines = [f"{where}: test, {over}" if where else f"test, {over}"]
    for r in [header, *rows]:
        lines.append("  " + r[0].ljust(widths[0]) + "".join("   " + c.rjust(w) for c, w in zip(r[1:], widths[1:])))
    lines.append(str(block["sentence"]))
    lines += [str(caution) for caution in block.get("cautions") or []]  # a small test set, seeds that cannot differ
    return "\n".join(lines)


def _pct(value: float, digits: int = 1) -> str:
    return "-" if math.isnan(value) else f"{100 * value:.{digits}f}"


def _model_by_property_tables(index, props: list[str], columns: Sequence[str], label, cell) -> list[str]:
    """Per split: a 'Baseline' row (the chance baseline of the runs) then one row per model; per
    property the ``columns`` (headed ``label(prop) column``) filled by ``cell(metrics, is_baseline)``."""
    lines = []
    for split in _ordered_unique([k[0] for k in index]):
        header = ["model"] + [f"{label(p)} {c}" for p in props for c in columns]
        lines += [f"**{split} split**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        models = _ordered_unique([k[1] for k in index if k[0] == split])
        for model in ["Baseline", *models]:
            is_base = model == "Baseline"
            row = [model]
            for prop in props:
                metrics = index.get((split, model, prop)) if not is_base else next(
                    (index[(split, m, prop)] for m in models if (split, m, prop) in index), None)  # fmt: skip
                row += ["-"] * len(columns) if metrics is None else cell(metrics, is_base)
            lines.append("| " + " | ".join(row) + " |")
        lines.append("")
    return lines


def thesis_ch3_table(cells: Sequence[Mapping[str, Any]]) -> str:
    """Table 3.4's layout: per model, micro-F1 and macro-F1 (%) as mean ± std over the units, for
    major location and sign type (the properties present), with the Baseline row first."""
    index = _index(cells)
    props = [p for p in ("major_location", "sign_type") if any(k[2] == p for k in index)]

    def cell(metrics: Mapping[str, Any], is_base: bool) -> list[str]:
        texts = []
        for key in ("f1_micro", "f1_macro"):
            interval = _interval(metrics, key, baseline=is_base)
            texts.append(f"{_pct(interval['mean'])} ± {_pct(0.0 if interval['n'] == 1 else interval['std'])}")
        return texts

    lines = _model_by_property_tables(index, props, ("micro-F1", "macro-F1"), str, cell)
    lines.append("Mean ± std (%) over the units (model seeds on one split, as the thesis; splits when "
                 "split.repeats > 1). Baseline = the chance baseline chosen by validation accuracy.\n")  # fmt: skip
    return "\n".join(lines)


def thesis_ch4_table(cells: Sequence[Mapping[str, Any]]) -> str:
    """Tables 4.2/4.3's layout per split: accuracy A ± 95% half-width and the per-class averaged
    accuracy Ā (= balanced accuracy), in %, the six properties in the thesis' order."""
    index = _index(cells)
    props = [p for p in THESIS_PROPERTY_ORDER if any(k[2] == p for k in index)]

    def cell(metrics: Mapping[str, Any], is_base: bool) -> list[str]:
        accuracy = _interval(metrics, "accuracy", is_base)
        half = accuracy["half_width"]
        if accuracy["n"] == 1 and not is_base:  # one run: the thesis' Wald interval of its accuracy
            run = metrics["test_per_seed"][0]
            half = (run["accuracy_ci_high"] - run["accuracy_ci_low"]) / 2
        text = _pct(accuracy["mean"]) + ("" if is_base or math.isnan(half) else f" ± {_pct(half)}")
        return [text, _pct(_interval(metrics, "balanced_accuracy", is_base)["mean"])]

    lines = _model_by_property_tables(index, props, ("A", "Ā"), THESIS_NAMES.get, cell)
    lines.append("A = test accuracy (%) ± 95% half-width: the normal-approximation (Wald) interval of the one "
                 "test set for one split and seed (as the thesis), the t interval of the mean over splits "
                 "when split.repeats > 1; Ā = per-class averaged accuracy (balanced accuracy, over the "
                 "classes present in the test set).\n")  # fmt: skip
    return "\n".join(lines)


def thesis_c2_table(cells: Sequence[Mapping[str, Any]]) -> str:
    """Table C.2's layout: per task and metric (P_μ, P_M, R_M, MCC, in %) one column per model
    (Baseline first), per split."""
    index = _index(cells)
    props = [p for p in THESIS_PROPERTY_ORDER if any(k[2] == p for k in index)]
    metrics_shown = (("P_μ", "precision_micro"), ("P_M", "precision_macro"), ("R_M", "recall_macro"), ("MCC", "mcc"))
    lines = []
    for split in _ordered_unique([k[0] for k in index]):
        models = _ordered_unique([k[1] for k in index if k[0] == split])
        header = ["task", "metric", "Baseline", *models]
        lines += [f"**{split} split**", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for prop in props:
            first = next((index[(split, m, prop)] for m in models if (split, m, prop) in index), None)
            for label, key in metrics_shown:
                row = [THESIS_NAMES[prop] if label == "P_μ" else "", label]
                row.append(_pct(_interval(first, key, True)["mean"]) if first else "-")
                for model in models:
                    metrics = index.get((split, model, prop))
                    row.append(_pct(_interval(metrics, key)["mean"]) if metrics else "-")
                lines.append("| " + " | ".join(row) + " |")
        lines.append("")
    lines.append("Means (%) over the units. Macro averages run over the classes present in the test set or "
                 "the predictions (the thesis' baseline P_M divides by all label values, THESIS.md 7).\n")  # fmt: skip
    return "\n".join(lines)


def group_cells(runs: Sequence[Mapping[str, Any]]) -> dict[tuple[str, str], list[dict[str, Any]]]:
    """Cells grouped by (lexicon, pose): tables never mix keypoint sources or lexicons."""
    groups: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for run in runs:
        groups[(str(run.get("lexicon")), str(run.get("pose")))].append(
            {"model": run["classifier"], "property": run["property"], "split": run["split"], "metrics": run["metrics"]})
    return dict(groups)
