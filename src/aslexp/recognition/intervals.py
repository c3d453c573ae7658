"""The test sets of recognition rows and the intervals that hold at their sizes: the test clips and
all clips of a run (its metrics.json) or of a config's split recomputed from the data, the 95%
Wilson interval of a proportion on one test set (a Wald interval is too narrow and can leave [0, 1]
at n = 30), the 95% t interval over several splits, a percentile bootstrap of MCC over the clips of
one test set, and the n behind a stored 95% Wald half-width.

* ``n_test`` / ``n_all``: the test clips and all clips of the property and split (after the
  rare-class rule), with ``n_test_source`` saying where the number comes from (:data:`FROM_RUN`,
  :data:`RECOMPUTED`);
* ``majority``: the majority class's test value (accuracy; MCC is 0 by definition);
* ``rare_dropped`` and ``keypoints``: the classes the rare-class rule dropped and the keypoint layout.
"""

from __future__ import annotations

import json
import logging
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)

Z_95 = 1.959963984540054  # as aslexp.recognition.metrics.Z_95 (the Wald intervals metrics.json stores)
PROPORTIONS = ("accuracy", "f1_micro", "precision_micro", "recall_micro")  # single-label: all = accuracy
BOOTSTRAP_RESAMPLES = 2000
RECOMPUTED = "the split recomputed from the data (aslexp.data.splits, as the run's config composes it)"
FROM_RUN = "the run's metrics.json (split sizes)"
TOLERANCE = 1e-9


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
        at_mean = varied if varied is not None else len(units) > 1 and float(np.std(units)) > TOLERANCE
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
    """Per row of a recognition snapshot, from the chosen run (:func:`aslexp.runs.completed.find_runs`'s
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


def stored_interval(metric: str, learned: dict[str, Any], n_test: Any) -> tuple[dict[str, Any] | None, str | None]:
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
    varied = "over seeds" in kind and spread is not None and abs(float(spread)) > TOLERANCE
    return interval_for(metric, mean, [mean] if mean is not None else [], n_test, "seed", varied=varied)
