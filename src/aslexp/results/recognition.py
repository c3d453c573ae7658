"""The recognition entries of the results page (``report: recognition``, ``recognition_per_class``).

``recognition``: per split and property, the model chosen by validation (among all, or among the
protocol's ``options.learned_models``), its test ``options.metric`` with the interval that holds at
its test-set size, the chance baseline and the strongest simple baseline chosen by validation, the
test clips, the "no better than chance" mark, and the generated differences from the thesis (its
sizes and keypoints from the catalogue's ``thesis.data``; whether the command tunes the models).
``recognition_per_class``: one model on one property, per class (Table 4.4's layout). Test numbers
never choose. ``aslexp report --results --add-test-clips`` fills the test clips into snapshots whose
run folders are gone (:func:`add_test_clips_to_snapshots`), the split recomputed from the data.
"""

from __future__ import annotations

import copy
import math
import re
from collections import defaultdict
from collections.abc import Callable
from pathlib import Path
from typing import Any

from aslexp.recognition import intervals
from aslexp.recognition.tables import best_by_validation, finite, panel_order, validation_key
from aslexp.results.catalogue import command_overrides, load_catalogue
from aslexp.results.kinds import ReportKind, register_report
from aslexp.results.render import difference_lines, render_entry
from aslexp.results.snapshots import read_snapshot, snapshot_path, write_snapshot
from aslexp.runs.completed import find_runs

CHANCE_MARK = "▼ majority class / no better than chance"


# --------------------------------------------------------------------------- the snapshot's rows


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


def results_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """The results page's rows of recognition runs (``report: recognition``): per split and property,
    the model chosen by validation among all (or among ``options.learned_models``, a protocol's own
    models; one run per split, model and property: the best by validation), its test
    ``options.metric`` as mean ± ``options.spread`` over the units, the chance baseline chosen by
    validation accuracy, and the strongest simple baseline (the best of rf, hgb, logreg and svm by
    validation). Test numbers never choose."""
    from aslexp.recognition.report import FEATURE_BASELINES, unit_values

    options = entry.get("options") or {}
    metric, spread = options.get("metric", "mcc"), options.get("spread", "ci95")
    runs, _, skipped = find_runs(folders)
    runs = _selected(runs, options.get("select"))
    cells: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for run in best_by_validation(runs):
        cells[(str(run["split"]), str(run["property"]))].append(run)
    rows = []
    learned_models = options.get("learned_models")  # the protocol's models; None: every model that ran
    for split, prop in sorted(cells, key=panel_order):
        group = cells[(split, prop)]
        candidates = [r for r in group if learned_models is None or r["classifier"] in learned_models]
        if not candidates:  # said on the page: "left out: N (...)"
            key = f"runs of a split and property no model of {learned_models} ran on"
            skipped[key] = skipped.get(key, 0) + len(group)
            continue
        best = max(candidates, key=validation_key)
        metrics, unit = best["metrics"], best["metrics"].get("statistics_unit", "seed")
        per_seed = metrics.get("test_per_seed") or [{}]
        wald = (finite(per_seed[0].get(f"{metric}_ci_low"), math.nan),
                finite(per_seed[0].get(f"{metric}_ci_high"), math.nan))
        mean, width, kind = _spread(unit_values(metrics, metric), spread, unit, wald)
        simple = [r for r in group if r["classifier"] in FEATURE_BASELINES]
        baselines = [{"label": "chance baseline (by validation)", "kind": "no-learning",
                      "name": metrics["baseline"]["name"], "value": _spread(unit_values(metrics, metric, baseline=True), spread, unit)[0]}]
        if simple:
            strongest = max(simple, key=validation_key)
            baselines.append({"label": "strongest simple baseline (by validation)", "kind": "simple",
                              "name": strongest["classifier"],
                              "value": _spread(unit_values(strongest["metrics"], metric), spread, unit)[0]})
        # the test clips, the interval that holds at that size, the majority class's value, the data's facts
        facts = intervals.run_fields(best, metric, mean, unit_values(metrics, metric))
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
        found = [finite(c.get(key), math.nan) for m in members for c in m.get("per_class", [])
                 if str(c.get("label")) == label]
        if found:
            out.append(float(sum(found) / len(found)))
    return out


def results_per_class_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """The results page's rows of one model on one property per split (``report: recognition_per_class``,
    Table 4.4's layout): per class the thesis' A = TP_c / N_test, precision and recall on the test
    set, mean over the units (splits, else model seeds) ± ``options.spread``."""
    options = entry.get("options") or {}
    runs, _, skipped = find_runs(folders)
    runs = _selected(runs, options.get("select"))
    rows = []
    for run in sorted(best_by_validation(runs), key=lambda r: (panel_order((str(r["split"]), str(r["property"]))),
                                                               str(r["classifier"]))):
        metrics = run["metrics"]
        unit = metrics.get("statistics_unit", "seed")
        sizes = intervals.run_sizes(metrics)
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


def row_config(entry: dict[str, Any], snapshot: dict[str, Any], key: str) -> Any:
    """The recognize config of one row (``split/property``): the entry's overlay, the overrides all
    its runs shared (the snapshot's), the row's split and property."""
    from omegaconf import OmegaConf

    from aslexp.compose import compose

    split, prop = key.split("/", 1)
    common = [o for o in (snapshot.get("overrides") or {}).get("common", [])
              if not o.startswith(("hydra.", "hydra/", "split=", "property=", "experiment=", "classifier="))]
    overrides = [f"experiment={entry['overlay']}", *common, f"property={prop}", f"split={split}"]
    return OmegaConf.create(compose("recognize", overrides))


def add_test_clips(entry: dict[str, Any], snapshot: dict[str, Any],
                   facts: Callable[[dict[str, Any], dict[str, Any], str], dict[str, Any]] | None = None) -> dict[str, Any]:
    """The snapshot of a recognition entry with, per row, the test clips and the interval fields
    (:mod:`aslexp.recognition.intervals`), for a snapshot whose run folders are gone: the split
    recomputed from the data (``facts``, default :func:`~aslexp.recognition.intervals.split_facts` of
    :func:`row_config`), checked against the n the stored Wald half-width implies where the row has
    one (a mismatch raises: the data are not those the runs had)."""
    facts = facts or (lambda e, s, key: intervals.split_facts(row_config(e, s, key)))
    metric = str((entry.get("options") or {}).get("metric", "mcc"))
    out = copy.deepcopy(snapshot)
    for row in out["rows"]:
        learned = row.get("learned") or {}
        found = facts(entry, snapshot, row["key"])
        n_test = found["n_test"]
        source = intervals.RECOMPUTED
        recovered = None
        if "Wald" in str(learned.get("spread_kind")):
            recovered = intervals.recover_n(learned.get("mean"), learned.get("spread"))
            if recovered is not None and recovered != n_test:
                raise ValueError(f"{entry['id']} {row['key']}: the data give {n_test} test clips, the stored Wald "
                                 f"half-width {recovered}: not the data the runs had")
            if recovered is not None:
                source += f"; the stored 95% Wald half-width implies the same n = {recovered}"
        if metric in intervals.PROPORTIONS and isinstance(n_test, int) and learned.get("mean") is not None:
            k = learned["mean"] * n_test
            if abs(k - round(k)) > 1e-6 * n_test and float(learned.get("spread") or 0) <= intervals.TOLERANCE:
                raise ValueError(f"{entry['id']} {row['key']}: {metric} {learned['mean']} is not a count of "
                                 f"{n_test} clips")
        chance = next((b for b in row.get("baselines", []) if b.get("name") == "majority"), None)
        if metric in intervals.PROPORTIONS and chance and chance.get("value") is not None \
                and abs(float(chance["value"]) - found["majority"]) > 1e-6:
            raise ValueError(f"{entry['id']} {row['key']}: the stored majority baseline {chance['value']} is not the "
                             f"recomputed split's {found['majority']}: not the data the runs had")
        row.update({"n_test": n_test, "n_all": found["n_all"], "n_test_source": source,
                    "n_classes": len(found["classes"]),
                    "majority": {"value": 0.0 if metric == "mcc" else found["majority"],
                                 "source": "MCC of a constant prediction" if metric == "mcc" else
                                 "the train+val majority class's share of the recomputed test set"},
                    "keypoints": found["keypoints"], "rare_dropped": found["rare_dropped"]})
        interval, none = intervals.stored_interval(metric, learned, n_test)
        learned["interval"] = interval
        learned.pop("interval_none", None)
        if none:
            learned["interval_none"] = none
    return out


# --------------------------------------------------------------------------- the page


def _percent(value: float | None, percent: bool) -> str:
    if value is None or not math.isfinite(value):
        return "-"
    return f"{100 * value:.1f}" if percent else f"{value:.3f}"


def _count(value: int | list[int] | None) -> str:
    if value is None:
        return "?"
    if isinstance(value, list):
        return f"{min(value)}-{max(value)}" if min(value) != max(value) else str(value[0])
    return str(value)


def no_better_than_chance(row: dict[str, Any], metric: str) -> bool:
    """The chosen model's test value is not above the majority class's (MCC: not above 0)."""
    mean = (row.get("learned") or {}).get("mean")
    if mean is None:
        return False
    bar = 0.0 if metric == "mcc" else (row.get("majority") or {}).get("value")
    return bar is not None and float(mean) <= float(bar) + intervals.TOLERANCE


def deterministic_over_seeds(learned: dict[str, Any]) -> bool:
    """A spread over model seeds of (numerically) zero: the model is deterministic, the seeds
    measure nothing."""
    return (str(learned.get("spread_kind", "")).endswith("over seeds") and int(learned.get("n") or 0) > 1
            and learned.get("spread") is not None and abs(float(learned["spread"])) <= intervals.TOLERANCE)


def learned_cell(row: dict[str, Any], metric: str, percent: bool) -> str:
    """The aslexp cell of a recognition row: value [interval], the model, the test clips; the
    deterministic-seeds note and the chance mark where they apply."""
    learned = row["learned"]
    text = _percent(learned.get("mean"), percent)
    units = int(learned.get("n") or 0)
    unit = str(learned.get("unit", "seeds"))
    several_splits = unit.startswith("split") and units > 1
    if several_splits and learned.get("spread") is not None:
        text += f" ± {_percent(learned['spread'], percent)}"
    interval = learned.get("interval")
    text += f" [{_percent(interval['low'], percent)}, {_percent(interval['high'], percent)}]" if interval else ", no interval"
    clips = f"{_count(row.get('n_test'))} test clips of {_count(row.get('n_all'))}"
    if several_splits:
        clips = f"{units} splits of {clips}"
    notes = [learned["model"]] if learned.get("model") else []
    if deterministic_over_seeds(learned):
        notes.append(f"deterministic model: no spread over seeds ({units} seeds); n test clips = {_count(row.get('n_test'))}")
    else:
        if units > 1 and not several_splits:
            notes.append(f"{units} {unit}")
        notes.append(clips)
    cell = f"{text} ({'; '.join(notes)})"
    if no_better_than_chance(row, metric):
        bar = "MCC 0" if metric == "mcc" else f"the majority class {_percent(row['majority']['value'], percent)}"
        cell += f" {CHANCE_MARK} ({bar})"
    return cell


def header(snapshot: dict[str, Any]) -> str:
    learned = [r["learned"] for r in snapshot["rows"] if r.get("learned")]
    whats = sorted({str(x.get("what")) for x in learned})
    kinds = sorted({re.sub(r" \(\d+ clips\)", "", x["interval"]["kind"]) for x in learned if x.get("interval")})
    what = whats[0] if len(whats) == 1 else "per row"
    spread = " ± std over splits" if any(str(x.get("unit", "")).startswith("split") and int(x.get("n") or 0) > 1
                                         for x in learned) else ""
    return f"aslexp, {what}{spread} [{'; '.join(kinds) if kinds else 'no interval'}]"


def _thousands(value: Any) -> str:
    return f"{value:,}" if isinstance(value, int) else str(value)


def _keypoints(snapshot: dict[str, Any]) -> str:
    from aslexp.keypoints import slgcn27

    found = {(r["keypoints"]["layout"], len(r["keypoints"]["nodes"])): r["keypoints"]["nodes"]
             for r in snapshot["rows"] if r.get("keypoints") and r["keypoints"].get("layout")}
    parts = []
    for (layout, count), nodes in sorted(found.items()):
        tips = [n for n in nodes if re.search(r"(index|middle|ring|little|pinky)_tip", n)]
        fingers = "" if tips else ", no fingertips"
        source = layout[: -len("_" + slgcn27.NAME)] if layout.endswith("_" + slgcn27.NAME) else None
        if source in slgcn27.MAPS:  # the nodes as the source gives them (slgcn27.coverage: exact, approximate)
            groups = slgcn27.coverage(source)
            exact = len(set(nodes) & set(groups["exact"]))
            near = len(set(nodes) & set(groups["approximate"]))
            absent = len(set(slgcn27.NAMES) - set(nodes))
            parts.append(f"`{layout}`: {count} of SL-GCN's {len(slgcn27.NAMES)} points ({exact} exact, {near} approximate; "
                         f"{absent} absent{fingers})")
        else:
            parts.append(f"`{layout}`: {count} points{fingers}")
    return "; ".join(parts) if parts else "not recorded"


def _units(count: int, unit: str) -> str:
    """``3 clips``, ``1 gloss``, ``1 clip (one per gloss)``: the unit's first word singular for 1."""
    first, _, rest = unit.partition(" ")
    if int(count) == 1:
        first = re.sub(r"(ss)es$", r"\1", first) if first.endswith("sses") else re.sub(r"s$", "", first)
    return f"{count} {first}{' ' + rest if rest else ''}"


def _rare(snapshot: dict[str, Any]) -> list[str]:
    """The classes dropped as rare: one line per row that dropped any, or one line saying none were."""
    parts, rules = [], set()
    for row in snapshot["rows"]:
        rare = row.get("rare_dropped")
        if not rare:
            continue
        rules.add(str(rare.get("rule")))
        named = [f"{k} ({_units(v, rare.get('unit', 'clips'))})" for k, v in (rare.get("classes") or {}).items()]
        named += [f"{k} ({_units(v, rare.get('unit_after_resplit', 'clips'))})" for k, v in
                  (rare.get("classes_after_resplit") or {}).items()]
        if named:
            parts.append((row["label"], named))
    if not parts and not rules:
        return ["classes dropped as rare: not recorded"]
    rule = "/".join(sorted(rules))
    if not parts:
        return [f"classes dropped as rare: none (rule `{rule}`)"]
    return [f"dropped as rare (rule `{rule}`) in {label}: {', '.join(named)}" for label, named in parts]


def _thesis_sizes(entry: dict[str, Any], snapshot: dict[str, Any]) -> str:
    """The thesis' test clips (per split, or its test share of its clips) and clips, from the
    catalogue entry's ``thesis.data``."""
    data = (entry.get("thesis") or {}).get("data") or {}
    splits = list(dict.fromkeys(r["key"].split("/", 1)[0] for r in snapshot["rows"]))
    tests = data.get("test_clips") or {}
    share, clips = data.get("test_share"), data.get("clips")
    if isinstance(tests, dict) and tests:
        known = [f"{_thousands(tests[s])} ({s} split)" for s in splits if s in tests]
        test = ", ".join(known) if known else "not given"
    elif tests:
        test = _thousands(tests)
    elif share and isinstance(clips, int):
        test = f"about {round(share * clips):,} ({share:.0%}; the thesis gives the share, not the number)"
    else:
        test = "not given"
    return f"the thesis: {test} test clips of {_thousands(clips if clips is not None else '?')}"


def _tuning(entry: dict[str, Any], snapshot: dict[str, Any]) -> str:
    _, words = command_overrides(entry["command"])
    sweeps = [w for w in words if w.lstrip("+").startswith(("sweeps=", "hydra/sweeper="))]
    data = (entry.get("thesis") or {}).get("data") or {}
    thesis = f" (the thesis: {data['tuning']})" if data.get("tuning") else ""
    if sweeps:
        return f"models tuned by the command's sweep ({', '.join(sweeps)}){thesis}"
    ran = sorted((snapshot.get("overrides") or {}).get("varied", {}).get("classifier", []))
    fixed = [c for c in ran if c.endswith("_thesis_ch3")]
    given = f"; {', '.join(fixed)} carry Table 3.3's hyper-parameters" if fixed else ""
    return f"models untuned: the command runs no hyper-parameter sweep{given}{thesis}"


def differences(entry: dict[str, Any], snapshot: dict[str, Any]) -> list[str]:
    """The entry's list "Differences from the thesis", from the snapshot and the catalogue: the test
    clips, the keypoints, the classes dropped as rare (one line per row that dropped any) and the tuning."""
    rows = snapshot["rows"]
    tests = [r.get("n_test") for r in rows if r.get("n_test") is not None]
    alls = [r.get("n_all") for r in rows if r.get("n_all") is not None]

    def span(values: list[Any]) -> str:
        flat = [v for x in values for v in (x if isinstance(x, list) else [x])]
        return _count(flat if flat else None)

    data = (entry.get("thesis") or {}).get("data") or {}
    size = (f"{span(tests)} test clips of {span(alls)} per property and split ({_thesis_sizes(entry, snapshot)})"
            if tests else "the number of test clips is not in the snapshot")
    keypoints = f"keypoints {_keypoints(snapshot)}" + (f" (the thesis: {data['keypoints']})" if data.get("keypoints") else "")
    return difference_lines("**Differences from the thesis**", [size, keypoints, *_rare(snapshot),
                                                                 _tuning(entry, snapshot)])


def legend(entry: dict[str, Any], snapshot: dict[str, Any]) -> list[str]:
    metric = str((entry.get("options") or {}).get("metric", "mcc"))
    nones = sorted({r["learned"]["interval_none"] for r in snapshot["rows"] if (r.get("learned") or {}).get("interval_none")})
    lines = ["Intervals: [low, high] in the aslexp column (see its header); test clips: the clips of the test set "
             "of each row (where from: the snapshot's `n_test_source`)."]
    if nones:
        lines[0] += f" No interval where: {'; '.join(nones)}."
    bar = "MCC is at most 0 (a constant prediction's)" if metric == "mcc" else \
        f"test {metric} is not above the majority class's (the train+val majority class's share of the test clips)"
    lines[0] += f" {CHANCE_MARK}: the chosen model's {bar}."
    return lines + [""]


def page_view(entry: dict[str, Any], snapshot: dict[str, Any]) -> dict[str, Any]:
    """The snapshot as the page shows a recognition entry: each row's learned number carries its
    rendered ``cell`` and ``header`` (read by :func:`aslexp.results.render.render_entry`)."""
    view = copy.deepcopy(snapshot)
    if not any("n_test" in r for r in view["rows"]):
        return view
    metric = str((entry.get("options") or {}).get("metric", "mcc"))
    percent = bool((entry.get("options") or {}).get("percent"))
    title = header(view)
    for row in view["rows"]:
        if row.get("learned") and "n_test" in row:
            row["learned"]["cell"] = learned_cell(row, metric, percent)
            row["learned"]["header"] = title
    return view


def render(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> list[str]:
    """The entry's lines (:func:`aslexp.results.render.render_entry`) from :func:`page_view`, with the
    list of differences from the thesis (before "How it was run") and the legend (after "Numbers")."""
    if snapshot is None:
        return render_entry(entry, snapshot)
    view = page_view(entry, snapshot) if entry["report"] == "recognition" else snapshot
    lines = render_entry(entry, view)
    at = next((i for i, line in enumerate(lines) if line.startswith("- **How it was run")), None)
    if at is not None:
        lines[at:at] = differences(entry, snapshot)
    if entry["report"] == "recognition" and any("n_test" in r for r in snapshot["rows"]):
        after = next((i for i, line in enumerate(lines) if line.startswith("Numbers:")), None)
        if after is not None:
            lines[after + 2:after + 2] = legend(entry, snapshot)
    return lines


register_report(ReportKind("recognition", results_summary, render))
register_report(ReportKind("recognition_per_class", results_per_class_summary, render))
