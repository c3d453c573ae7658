"""The recognition entries of the results page (``docs/results.md``): test-set sizes, intervals
that hold at those sizes, the "no better than chance" mark and the line of differences from the
thesis. :mod:`aslexp.reports.results_page` renders every entry; this module adds, per recognition row:

* ``n_test`` / ``n_all``: the test clips and all clips of the property and split (after the
  rare-class rule), with ``n_test_source`` saying where the number comes from: a run's metrics.json
  (:func:`run_fields`, used by ``aslexp.tools.report.results_summary``), or, for a snapshot whose run
  folders are gone, the split recomputed from the data by the code's own split functions
  (:func:`split_facts`), cross-checked against the n that the stored 95% Wald half-width implies
  (:func:`recover_n`);
* ``learned.interval``: for a proportion (accuracy, micro-F1 = accuracy for single-label) on one
  test set the 95% Wilson score interval (:func:`wilson`; a Wald interval is too narrow and can
  leave [0, 1] at n = 30); over several splits the 95% t interval of the mean over the splits; for
  MCC on one test set a percentile bootstrap over the test clips where the confusion matrix is at
  hand (:func:`mcc_bootstrap`), else none, and ``interval_none`` says why;
* ``majority``: the majority class's test value (accuracy; MCC is 0 by definition), so that the page
  marks a row whose chosen model is not above it ("majority class / no better than chance");
* ``rare_dropped`` and ``keypoints``: the classes the rare-class rule dropped and the keypoint
  layout, for the line "Differences from the thesis" (:func:`differences`), which also takes the
  thesis' own sizes and keypoints from the catalogue entry's ``thesis.data`` and says whether the
  command tunes the models.

``aslexp report --results --add-test-clips`` fills these fields into recognition snapshots that lack
them (:func:`add_test_clips`); the page is then rendered from the snapshots alone, as before.
"""

from __future__ import annotations

import copy
import json
import logging
import math
import re
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

Z_95 = 1.959963984540054  # as aslexp.recognition.metrics.Z_95 (the Wald intervals metrics.json stores)
PROPORTIONS = ("accuracy", "f1_micro", "precision_micro", "recall_micro")  # single-label: all = accuracy
BOOTSTRAP_RESAMPLES = 2000
CHANCE_MARK = "▼ majority class / no better than chance"
RECOMPUTED = "the split recomputed from the data (aslexp.data.splits, as the run's config composes it)"
FROM_RUN = "the run's metrics.json (split sizes)"
_TOLERANCE = 1e-9


# --------------------------------------------------------------------------- intervals


def wilson(p: float, n: int, z: float = Z_95) -> tuple[float, float]:
    """The Wilson score interval of a proportion ``p`` observed on ``n`` trials (95% for the default z)."""
    if n <= 0 or not math.isfinite(p):
        return math.nan, math.nan
    z2 = z * z
    denominator = 1.0 + z2 / n
    centre = (p + z2 / (2 * n)) / denominator
    half = z * math.sqrt(p * (1.0 - p) / n + z2 / (4 * n * n)) / denominator
    return max(0.0, centre - half), min(1.0, centre + half)


def wald_n(p: float, half_width: float, z: float = Z_95) -> float:
    """The n at which the Wald half-width z * sqrt(p(1-p)/n) of ``p`` equals ``half_width``."""
    return z * z * p * (1.0 - p) / (half_width * half_width)


def recover_n(p: float | None, half_width: float | None, z: float = Z_95, tolerance: float = 0.05) -> int | None:
    """The test-set size behind a stored 95% Wald half-width of a proportion ``p``: n = z^2 p(1-p)/hw^2,
    accepted only when it is within ``tolerance`` of an integer n and p * n is a whole number of clips
    (None otherwise, e.g. for p = 0 or 1, where the Wald width says nothing, or a clipped interval)."""
    if p is None or half_width is None or not (math.isfinite(p) and math.isfinite(half_width)):
        return None
    if half_width <= 0 or not 0.0 < p < 1.0:
        return None
    estimate = wald_n(p, half_width, z)
    n = round(estimate)
    if n < 1 or abs(estimate - n) > tolerance or abs(p * n - round(p * n)) > 1e-6 * n:
        return None
    return int(n)


def mcc_from_confusion(matrix: np.ndarray) -> float:
    """Multiclass MCC (Gorodkin's R_K, as sklearn's matthews_corrcoef) of a confusion matrix
    (rows true, columns predicted); 0 where it is undefined."""
    matrix = np.asarray(matrix, dtype=np.float64)
    true, predicted = matrix.sum(axis=1), matrix.sum(axis=0)
    correct, total = np.trace(matrix), matrix.sum()
    denominator = math.sqrt(max(total**2 - predicted @ predicted, 0.0)) * math.sqrt(max(total**2 - true @ true, 0.0))
    return 0.0 if denominator == 0 else float((correct * total - true @ predicted) / denominator)


def mcc_bootstrap(matrix: Sequence[Sequence[int]], resamples: int = BOOTSTRAP_RESAMPLES, seed: int = 0,
                  confidence: float = 0.95) -> tuple[float, float]:
    """The percentile bootstrap interval of the MCC of one test set, from its confusion matrix: the
    test clips (the matrix's cells) resampled with replacement ``resamples`` times, seeded."""
    counts = np.asarray(matrix, dtype=np.int64)
    n = int(counts.sum())
    if n == 0:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    draws = rng.multinomial(n, counts.ravel() / n, size=resamples)
    values = np.array([mcc_from_confusion(d.reshape(counts.shape)) for d in draws])
    tail = (1.0 - confidence) / 2
    return float(np.quantile(values, tail)), float(np.quantile(values, 1.0 - tail))


def interval_for(metric: str, mean: float | None, units: Sequence[float], n_test: int | list[int] | None,
                 unit: str, confusion: Sequence[Sequence[int]] | None = None,
                 varied: bool | None = None) -> tuple[dict[str, Any] | None, str | None]:
    """(interval, why none) of the chosen model's test ``metric``: over several splits the 95% t
    interval of the mean over them; on one test set the 95% Wilson interval for a proportion, a
    percentile bootstrap over the clips for MCC where the confusion matrix is given."""
    from aslexp.recognition.metrics import mean_interval

    if mean is None or not math.isfinite(mean):
        return None, "no test value"
    if unit.startswith("split") and len(units) >= 2:
        spread = mean_interval(units)
        return ({"low": spread["low"], "high": spread["high"],
                 "kind": f"95% t interval of the mean over {spread['n']} splits (re-splits of the same clips "
                         f"overlap: read it as too narrow)"}, None)
    n = n_test if isinstance(n_test, int) else None
    if metric in PROPORTIONS:
        if n is None:
            return None, "the number of test clips is not known"
        low, high = wilson(float(mean), n)
        at_mean = varied if varied is not None else len(units) > 1 and float(np.std(units)) > _TOLERANCE
        kind = f"95% Wilson score interval of the one test set ({n} clips)"
        return {"low": low, "high": high, "kind": kind + (" at the mean over seeds" if at_mean else "")}, None
    if metric == "mcc":
        if confusion is not None and len(units) <= 1:
            low, high = mcc_bootstrap(confusion)
            return ({"low": low, "high": high,
                     "kind": f"95% percentile bootstrap of the MCC over the {n or 'test'} clips of the one test set "
                             f"({BOOTSTRAP_RESAMPLES} resamples, seed 0; approximate at this size)"}, None)
        return None, ("one test set and no confusion matrix kept: a Wald interval on MCC is not valid at "
                      "this size, and nothing else can be computed from what is stored")
    return None, f"no interval for {metric} on one test set"


# --------------------------------------------------------------------------- facts from a run folder


def _one_or_list(values: Sequence[int]) -> int | list[int] | None:
    values = [int(v) for v in values]
    if not values:
        return None
    return values[0] if len(set(values)) == 1 else values


def _unit_mean(block: dict[str, Any], metric: str, unit: str) -> float | None:
    """A baseline's test ``metric``: the mean over its splits (several splits), else its one test value."""
    per_split = [s.get(metric) for s in block.get("test_per_split") or [] if s.get(metric) is not None]
    if unit == "split" and per_split:
        return float(np.mean(per_split))
    value = (block.get("test") or {}).get(metric)
    return None if value is None else float(value)


def run_sizes(metrics: dict[str, Any]) -> dict[str, Any]:
    """A run's test clips and all clips (per split where they differ) from its metrics.json."""
    splits = metrics.get("splits") or []
    n_test = _one_or_list([s["sizes"]["test"] for s in splits if s.get("sizes")]) or \
        (metrics.get("split_sizes") or {}).get("test")
    n_all = _one_or_list([s["clips"] for s in splits if s.get("clips") is not None]) or \
        (metrics.get("context") or {}).get("num_clips")
    return {"n_test": n_test, "n_all": n_all, "n_test_source": FROM_RUN}


def run_fields(run: dict[str, Any], metric: str, mean: float | None, units: Sequence[float]) -> dict[str, Any]:
    """Per row of a recognition snapshot, from the chosen run (``aslexp.tools.report.find_runs``'s
    dict: dir, metrics): the row's fields (n_test, n_all, n_test_source, n_classes, majority,
    keypoints, rare_dropped) and the learned number's (interval, interval_none)."""
    metrics = run["metrics"]
    unit = str(metrics.get("statistics_unit", "seed"))
    sizes = run_sizes(metrics)
    n_test = sizes["n_test"]
    majority = metrics.get("baselines", {}).get("majority")
    majority_value = 0.0 if metric == "mcc" else (_unit_mean(majority, metric, unit) if majority else None)
    per_seed = metrics.get("test_per_seed") or []
    confusion = per_seed[0].get("confusion_matrix") if len(per_seed) == 1 else None
    interval, none = interval_for(metric, mean, units, n_test, unit, confusion)
    layout = metrics.get("layout") or {}
    row = {**sizes, "n_classes": len(metrics.get("label_names") or []),
           "majority": {"value": majority_value,
                        "source": "MCC of a constant prediction" if metric == "mcc" else "the run's majority baseline"},
           "keypoints": {"layout": layout.get("name"), "nodes": list(layout.get("nodes") or [])},
           "rare_dropped": _rare_of_run(run)}
    return {"row": row, "learned": {"interval": interval, **({"interval_none": none} if none else {})}}


def _rare_of_run(run: dict[str, Any]) -> dict[str, Any] | None:
    """The classes the rare-class rule dropped in a run: the split recomputed from the run's own
    config (.hydra/config.yaml); None when the data or the config is not at hand."""
    from omegaconf import OmegaConf

    path = Path(run["dir"]) / ".hydra" / "config.yaml"
    try:
        cfg = OmegaConf.load(path)
        return split_facts(cfg)["rare_dropped"]
    except Exception as err:  # the data may live elsewhere than where the runs ran
        log.info("%s: the rare classes not recomputed (%s)", run["dir"], err)
        return None


# --------------------------------------------------------------------------- facts from the data


def split_facts(cfg: Any) -> dict[str, Any]:
    """What a recognition config's split holds, recomputed from the data without training: per split
    (``split.repeats``) the test clips and all clips, the classes, the majority class's test accuracy
    (the train+val majority, as the ``majority`` baseline predicts it), the classes the rare-class
    rule dropped, and the keypoint layout."""
    from omegaconf import OmegaConf

    from aslexp.data.splits import SplitOptions, resplit
    from aslexp.data.wlasl_lex import build_or_load, params_from_config
    from aslexp.recognition.experiment import split_views

    dataset, build = build_or_load(Path(cfg.cache_dir), params_from_config(OmegaConf.to_container(cfg, resolve=True)),
                                   root=cfg.data.root)
    options = SplitOptions.parse(OmegaConf.to_container(cfg.split, resolve=True))
    views = split_views(dataset, options)
    manifest = json.loads((Path(build) / "manifest.json").read_text(encoding="utf-8"))
    unit = "glosses" if options.name == "gloss" else "clips"
    rare = {"rule": options.rare_classes, "unit": unit, "classes": dict(manifest["rare_classes"]["classes"]),
            "clips": int(manifest["skipped"].get("rare_class", 0))}
    if options.rebuilds:  # a re-split (e.g. one clip per gloss) applies the rule again to what it keeps
        labels = [dataset.label_names[int(y)] for y in dataset.y]
        again = resplit(labels, dataset.glosses, options, int(options.seed)).rare
        if again:
            rare["classes_after_resplit"] = dict(again)
            rare["unit_after_resplit"] = "clips of the one-clip-per-gloss set" if options.one_clip_per_gloss else unit
    n_test, n_all, majority = [], [], []
    for _, view in views:
        test = np.asarray(view.splits["test"], dtype=np.int64)
        train_val = np.asarray(view.splits["train+val"], dtype=np.int64)
        counts = np.bincount(view.y[train_val], minlength=view.num_classes)
        n_test.append(len(test))
        n_all.append(len(view.y))
        majority.append(float(np.mean(view.y[test] == int(np.argmax(counts)))))
    layout = views[0][1].layout
    return {"n_test": _one_or_list(n_test), "n_all": _one_or_list(n_all), "n_test_per_split": n_test,
            "classes": list(views[0][1].label_names), "majority": float(np.mean(majority)),
            "rare_dropped": rare, "keypoints": {"layout": layout.name, "nodes": list(layout.names)}}


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
    """The snapshot of a recognition entry with, per row, the fields of the module docstring, for a
    snapshot whose run folders are gone: the split recomputed from the data (``facts``, default
    :func:`split_facts` of :func:`row_config`), checked against the n the stored Wald half-width
    implies where the row has one (a mismatch raises: the data are not those the runs had)."""
    facts = facts or (lambda e, s, key: split_facts(row_config(e, s, key)))
    metric = str((entry.get("options") or {}).get("metric", "mcc"))
    out = copy.deepcopy(snapshot)
    for row in out["rows"]:
        learned = row.get("learned") or {}
        found = facts(entry, snapshot, row["key"])
        n_test = found["n_test"]
        source = RECOMPUTED
        recovered = None
        if "Wald" in str(learned.get("spread_kind")):
            recovered = recover_n(learned.get("mean"), learned.get("spread"))
            if recovered is not None and recovered != n_test:
                raise ValueError(f"{entry['id']} {row['key']}: the data give {n_test} test clips, the stored Wald "
                                 f"half-width {recovered}: not the data the runs had")
            if recovered is not None:
                source += f"; the stored 95% Wald half-width implies the same n = {recovered}"
        if metric in PROPORTIONS and isinstance(n_test, int) and learned.get("mean") is not None:
            k = learned["mean"] * n_test
            if abs(k - round(k)) > 1e-6 * n_test and float(learned.get("spread") or 0) <= _TOLERANCE:
                raise ValueError(f"{entry['id']} {row['key']}: {metric} {learned['mean']} is not a count of "
                                 f"{n_test} clips")
        chance = next((b for b in row.get("baselines", []) if b.get("name") == "majority"), None)
        if metric in PROPORTIONS and chance and chance.get("value") is not None \
                and abs(float(chance["value"]) - found["majority"]) > 1e-6:
            raise ValueError(f"{entry['id']} {row['key']}: the stored majority baseline {chance['value']} is not the "
                             f"recomputed split's {found['majority']}: not the data the runs had")
        row.update({"n_test": n_test, "n_all": found["n_all"], "n_test_source": source,
                    "n_classes": len(found["classes"]),
                    "majority": {"value": 0.0 if metric == "mcc" else found["majority"],
                                 "source": "MCC of a constant prediction" if metric == "mcc" else
                                 "the train+val majority class's share of the recomputed test set"},
                    "keypoints": found["keypoints"], "rare_dropped": found["rare_dropped"]})
        interval, none = _stored_interval(metric, learned, n_test)
        learned["interval"] = interval
        learned.pop("interval_none", None)
        if none:
            learned["interval_none"] = none
    return out


def _stored_interval(metric: str, learned: dict[str, Any], n_test: Any) -> tuple[dict[str, Any] | None, str | None]:
    """:func:`interval_for` from what a snapshot row stores (the mean, the spread and its kind; not
    the per-unit values): over several splits the 95% t interval from the stored std or t half-width."""
    from scipy import stats

    mean, spread, n = learned.get("mean"), learned.get("spread"), int(learned.get("n") or 1)
    kind = str(learned.get("spread_kind", ""))
    if str(learned.get("unit", "")).startswith("split") and n >= 2 and mean is not None and spread is not None:
        half = float(spread) if "half-width" in kind else float(stats.t.ppf(0.975, n - 1) * float(spread) / math.sqrt(n))
        return ({"low": mean - half, "high": mean + half,
                 "kind": f"95% t interval of the mean over {n} splits (re-splits of the same clips overlap: read it "
                         f"as too narrow)"}, None)
    varied = "over seeds" in kind and spread is not None and abs(float(spread)) > _TOLERANCE
    return interval_for(metric, mean, [mean] if mean is not None else [], n_test, "seed", varied=varied)


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
    return bar is not None and float(mean) <= float(bar) + _TOLERANCE


def deterministic_over_seeds(learned: dict[str, Any]) -> bool:
    """A spread over model seeds of (numerically) zero: the model is deterministic, the seeds
    measure nothing."""
    return (str(learned.get("spread_kind", "")).endswith("over seeds") and int(learned.get("n") or 0) > 1
            and learned.get("spread") is not None and abs(float(learned["spread"])) <= _TOLERANCE)


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


def _rare(snapshot: dict[str, Any]) -> str:
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
            parts.append(f"{row['label']}: {', '.join(named)}")
    if not parts and not rules:
        return "not recorded"
    rule = "/".join(sorted(rules))
    return (f"rule `{rule}`: " + "; ".join(parts)) if parts else f"none (rule `{rule}`)"


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
    from aslexp.reports.commands import command_overrides

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


def differences(entry: dict[str, Any], snapshot: dict[str, Any]) -> str:
    """The entry's line "Differences from the thesis", from the snapshot and the catalogue."""
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
    return (f"- **Differences from the thesis**: {size}; {keypoints}; classes dropped as rare: {_rare(snapshot)}; "
            f"{_tuning(entry, snapshot)}")


def legend(entry: dict[str, Any], snapshot: dict[str, Any]) -> list[str]:
    metric = str((entry.get("options") or {}).get("metric", "mcc"))
    nones = sorted({r["learned"]["interval_none"] for r in snapshot["rows"] if (r.get("learned") or {}).get("interval_none")})
    lines = [f"Intervals: [low, high] in the aslexp column (see its header); test clips: the clips of the test set "
             f"of each row (where from: the snapshot's `n_test_source`)."]
    if nones:
        lines[0] += f" No interval where: {'; '.join(nones)}."
    bar = "MCC is at most 0 (a constant prediction's)" if metric == "mcc" else \
        f"test {metric} is not above the majority class's (the train+val majority class's share of the test clips)"
    lines[0] += f" {CHANCE_MARK}: the chosen model's {bar}."
    return lines + [""]


def page_view(entry: dict[str, Any], snapshot: dict[str, Any]) -> dict[str, Any]:
    """The snapshot as the page shows a recognition entry: each row's learned number carries its
    rendered ``cell`` and ``header`` (read by results_page's ``_learned`` and ``render_entry``)."""
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


def render(entry: dict[str, Any], snapshot: dict[str, Any] | None,
           render_entry: Callable[[dict[str, Any], dict[str, Any] | None], list[str]]) -> list[str]:
    """``render_entry``'s lines for a recognition entry, from :func:`page_view`, with the line of
    differences from the thesis (before "How it was run") and the legend (after "Numbers")."""
    if snapshot is None or entry.get("report") not in ("recognition", "recognition_per_class"):
        return render_entry(entry, snapshot)
    view = page_view(entry, snapshot) if entry["report"] == "recognition" else snapshot
    lines = render_entry(entry, view)
    at = next((i for i, line in enumerate(lines) if line.startswith("- **How it was run")), None)
    if at is not None:
        lines.insert(at, differences(entry, snapshot))
    if entry["report"] == "recognition" and any("n_test" in r for r in snapshot["rows"]):
        after = next((i for i, line in enumerate(lines) if line.startswith("Numbers:")), None)
        if after is not None:
            lines[after + 2:after + 2] = legend(entry, snapshot)
    return lines
