"""Lexicon retrieval over K gloss splits: per-property classifiers trained on the training glosses
rank every lexicon entry for each clip of the unseen test glosses (:mod:`aslexp.recognition.retrieval`
defines the scores, ranks and metrics; the job ``aslexp retrieve`` calls :func:`run_retrieval`).

Per split (``split.seed + k``, k < ``split.repeats``):

1. **One gloss split for every property.** The glosses of all clips are split once, 70/15/15 by
   default, with :func:`aslexp.data.splits.resplit` on a single label (a gloss split stratified by
   one property would be arbitrary for the others); every property's classifier then trains on the
   same training glosses, and the validation and test glosses are never seen in training.
2. **Validation.** Each property's classifier (any registered one with ``predict_proba``) is fitted
   on the training clips whose value is known, as :func:`aslexp.recognition.train.fit` fits it (a
   torch model early-stops on the validation clips whose value is among its classes), and predicts
   the validation clips. On those clips the smoothing ``eps`` (phonology alone) and ``eps`` with the
   prior weight ``w`` (combined) are chosen from the config's grids by ``select_by``; test clips
   never choose.
3. **Test.** Each classifier is fitted again on train+val (a torch model for the validated epoch
   budget), predicts the test clips, and every method of :data:`~aslexp.recognition.retrieval.METHODS`
   ranks all lexicon entries for every test clip.

Per split the metrics are means over its test clips; the table is the mean over splits with the
95% t interval (:func:`split_interval`: clipped to the metric's range, none below 3 splits). The
splits are drawn independently, so they reuse test glosses (``split_overlap`` in the result counts
how often): the interval treats them as independent samples and is too narrow. ``frequency`` in
the result gives recall by the frequency band of the true sign (:func:`aslexp.recognition.retrieval.frequency_bands`).
"""

from __future__ import annotations

import logging
import math
import time
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.data.splits import SplitOptions, resplit
from aslexp.keypoints.layout import KeypointLayout
from aslexp.recognition import retrieval as R
from aslexp.recognition.metrics import mean_interval, paired_comparison

log = logging.getLogger(__name__)

RANKS_FILE = "ranks.csv"
TABLE_FILE = "retrieval.md"
PLOT_FILE = "recall_at_k.png"
TABLE_METRICS = ("recall@1", "recall@10", "recall@50", "mrr", "median_rank")
# The paired comparisons over the same splits that the issue's targets ask about: (method, reference, metric).
PAIRED = (("phonology", "chance", "recall@50"), ("phonology+prior", "prior", "recall@50"),
          ("phonology+prior", "prior", "median_rank"))
# A t interval from 2 splits is the mean +- 12.7 standard deviations: none is given below 3.
MIN_SPLITS_FOR_INTERVAL = 3
NO_INTERVAL = "n/a (fewer than 3 splits)"


@dataclass
class RetrievalClips:
    """The clips retrieval works on: keypoints as :class:`~aslexp.data.dataset.RecognitionDataset`
    holds them, each clip's gloss and the row of its lexicon entry in the table."""

    X: np.ndarray  # (N, C, T, V, 1)
    mask: np.ndarray  # (N, T, V)
    video_ids: list[str]
    glosses: list[str]
    entry_rows: np.ndarray  # (N,) rows of the LexiconTable
    layout: KeypointLayout | None = None

    def __post_init__(self) -> None:
        n = len(self.X)
        if not (len(self.mask) == len(self.video_ids) == len(self.glosses) == len(self.entry_rows) == n):
            raise ValueError("retrieval clips: X, mask, video_ids, glosses and entry_rows differ in length")


def metric_range(metric: str, entries: int) -> tuple[float, float]:
    """The values ``metric`` can take with a lexicon of ``entries``: a rate in [0, 1], a rank in
    [1, entries], the mean log rank in [0, log entries]."""
    if metric in ("median_rank", "mean_rank"):
        return 1.0, float(entries)
    if metric == "mean_log_rank":
        return 0.0, math.log(entries)
    return 0.0, 1.0  # recall@k, mrr


def split_interval(values: Sequence[float], bounds: tuple[float, float]) -> dict[str, Any]:
    """:func:`mean_interval` over splits with the bounds clipped to ``bounds``; below
    :data:`MIN_SPLITS_FOR_INTERVAL` splits no interval (low, high and half_width None, and
    ``interval`` says why)."""
    interval = mean_interval(values)
    if interval["n"] < MIN_SPLITS_FOR_INTERVAL:
        return {**interval, "low": None, "high": None, "half_width": None, "interval": NO_INTERVAL}
    low, high = bounds
    return {**interval, "low": min(max(interval["low"], low), high), "high": max(min(interval["high"], high), low)}


def split_overlap(test_glosses: Sequence[Sequence[str]]) -> dict[str, int]:
    """How often the splits' test glosses recur: ``test_slots`` (test glosses summed over splits),
    ``distinct_test_glosses``, ``recurring`` (the slots whose gloss is a test gloss of another split
    too), ``recurring_glosses`` and ``most_tested`` (the most splits one gloss is tested in)."""
    counts = Counter(g for glosses in test_glosses for g in set(glosses))
    return {"test_slots": sum(counts.values()), "distinct_test_glosses": len(counts),
            "recurring": sum(n for n in counts.values() if n > 1),
            "recurring_glosses": sum(1 for n in counts.values() if n > 1),
            "most_tested": max(counts.values(), default=0)}


def gloss_split(glosses: Sequence[str], options: SplitOptions, seed: int) -> tuple[np.ndarray, ...]:
    """One gloss split of the clips (one label for all: see the module docstring): the clip
    indices of train, val and test."""
    result = resplit(["all"] * len(glosses), glosses, options, seed)
    return tuple(result.keep[np.asarray(result.splits[name], dtype=np.int64)] for name in ("train", "val", "test"))


def _format_seconds(seconds: float) -> str:
    seconds = max(0.0, float(seconds))
    return f"{seconds / 60:.1f} min" if seconds >= 90 else f"{seconds:.0f} s"


def _fit_predict(classifier: Mapping[str, Any], params: Mapping[str, Any], config, clips: RetrievalClips,
                 codes: np.ndarray, vocab_size: int, train_idx: np.ndarray, val_idx: np.ndarray | None,
                 predict_idx: np.ndarray, seed: int, epochs: int | None) -> tuple[np.ndarray, int, int]:
    """Fit on the clips of ``train_idx`` whose value is known and predict ``predict_idx``: (probabilities
    over the whole vocabulary (n, vocab_size), the validated epoch budget, the classes seen). With
    ``epochs`` None this is the validation fit (:func:`fit`, early stopping on ``val_idx``), else the
    final one (:func:`fit_final` for ``epochs``)."""
    from aslexp.recognition.models import build_classifier
    from aslexp.recognition.train import ArraySplit, fit, fit_final, smoothed_best_epoch

    labelled = train_idx[codes[train_idx] >= 0]
    classes = np.unique(codes[labelled])
    proba = np.zeros((len(predict_idx), vocab_size), dtype=np.float64)
    if len(classes) == 0:
        proba[:] = 1.0 / vocab_size
        return proba, 1, 0
    if len(classes) == 1:  # nothing to learn: the one value seen
        proba[:, classes[0]] = 1.0
        return proba, 1, 1
    _, channels, frames, nodes, _ = clips.X.shape
    model = build_classifier(str(classifier["name"]), dict(params), channels, frames, nodes, len(classes),
                             clips.layout, module=classifier.get("module"))
    train = ArraySplit(clips.X[labelled], clips.mask[labelled], np.searchsorted(classes, codes[labelled]))
    target = ArraySplit(clips.X[predict_idx], clips.mask[predict_idx], np.zeros(len(predict_idx), dtype=np.int64))
    if epochs is None:
        known = val_idx[np.isin(codes[val_idx], classes)] if val_idx is not None else np.array([], dtype=np.int64)
        # early stopping needs validation clips of known classes; none: the training clips stand in
        val = ArraySplit(clips.X[known], clips.mask[known], np.searchsorted(classes, codes[known])) if len(known) else train
        result = fit(model, train, val, config, seed=seed)
        budget = result.best_epoch
        if config.retrain_epochs == "smoothed" and config.early_stopping:
            key = "val_mcc" if config.selection_metric == "mcc" else f"val_{config.selection_metric}"
            budget = smoothed_best_epoch(result.history, key, config.smoothing_window)
        proba[:, classes] = model.predict_proba(target.X, target.mask)
        return proba, max(1, int(budget)), len(classes)
    final = fit_final(model, train, target, config, epochs=max(1, int(epochs)), seed=seed)
    proba[:, classes] = final.proba
    return proba, int(epochs), len(classes)


def _check_settings(classifier: Mapping[str, Any], options: SplitOptions, likelihood: str, select_by: str,
                    smoothing: Sequence[float], prior_weights: Sequence[float]) -> None:
    """One line naming the setting that cannot run, before any fit."""
    if "name" not in classifier:
        raise ValueError(f"classifier config needs a 'name' (got keys {sorted(classifier)})")
    if options.name != "gloss":
        raise ValueError(f"retrieval needs a gloss split (unseen glosses), got split={options.name}")
    if likelihood not in R.LIKELIHOODS:
        raise ValueError(f"retrieval.likelihood={likelihood!r}; expected one of {list(R.LIKELIHOODS)}")
    if select_by not in R.SELECT_BY:
        raise ValueError(f"retrieval.select_by={select_by!r}; expected one of {sorted(R.SELECT_BY)}")
    if not smoothing or not all(0.0 < float(e) <= 1.0 for e in smoothing):
        raise ValueError(f"retrieval.smoothing must be a non-empty list of numbers in (0, 1], got {list(smoothing)}")
    if not prior_weights or not all(float(w) >= 0.0 for w in prior_weights):
        raise ValueError(f"retrieval.prior_weights must be a non-empty list of numbers >= 0, got {list(prior_weights)}")


def _fit_properties(classifier, params, config, clips: RetrievalClips, table: R.LexiconTable, codes_all: np.ndarray,
                    split: tuple[np.ndarray, np.ndarray, np.ndarray], seed: int):  # fmt: skip
    """Per property a classifier validated on ``val`` (its epoch budget), then refitted on train+val
    for that budget: (validation probabilities, test probabilities, budgets, classes seen)."""
    train, val, test = split
    train_val = np.sort(np.concatenate([train, val]))
    val_proba, test_proba, budgets, seen = [], [], {}, {}
    for j, prop in enumerate(table.properties):
        codes = codes_all[:, j]
        size = len(table.vocab[j])
        p_val, budget, _ = _fit_predict(classifier, params, config, clips, codes, size, train, val, val, seed, None)
        p_test, _, n_classes = _fit_predict(classifier, params, config, clips, codes, size, train_val, None, test,
                                            seed, budget)
        val_proba.append(p_val)
        test_proba.append(p_test)
        budgets[prop] = budget
        seen[prop] = n_classes
    return val_proba, test_proba, budgets, seen


def _property_accuracy(table: R.LexiconTable, codes_all: np.ndarray, train_val: np.ndarray, test: np.ndarray,
                       test_proba: Sequence[np.ndarray]) -> tuple[dict[str, float], dict[str, float]]:  # fmt: skip
    """Per property the test accuracy, and the share of test clips whose true value no training clip has."""
    accuracy = {}
    for j, prop in enumerate(table.properties):
        truth = codes_all[test, j]
        known = truth >= 0
        predicted = test_proba[j].argmax(axis=1)
        accuracy[prop] = float(np.mean(predicted[known] == truth[known])) if known.any() else math.nan
    unseen = {prop: float(np.mean([c >= 0 and c not in set(codes_all[train_val, j].tolist()) for c in codes_all[test, j]]))
              for j, prop in enumerate(table.properties)}
    return accuracy, unseen


def _clip_records(k: int, split_seed: int, clips: RetrievalClips, table: R.LexiconTable, test: np.ndarray,
                  ranks: Mapping[str, Sequence[R.Rank]], test_proba: Sequence[np.ndarray]) -> list[dict[str, Any]]:  # fmt: skip
    """One row per test clip of split ``k``: its gloss, each method's rank, each property's truth and reading."""
    rows = []
    for row, clip in enumerate(test):
        entry = int(clips.entry_rows[clip])
        record = {"split": k, "split_seed": split_seed, "video_id": clips.video_ids[clip],
                  "gloss": clips.glosses[clip], "entry_id": table.entry_ids[entry]}
        record.update({f"rank_{m}": round(ranks[m][row].expected, 3) for m in R.METHODS})
        for j, prop in enumerate(table.properties):
            code = table.codes[entry, j]
            record[f"true_{prop}"] = table.vocab[j][code] if code >= 0 else ""
            record[f"predicted_{prop}"] = table.vocab[j][int(test_proba[j][row].argmax())]
            record[f"p_true_{prop}"] = round(float(test_proba[j][row][code]), 4) if code >= 0 else ""
        rows.append(record)
    return rows


def _rank_test_clips(table: R.LexiconTable, clips: RetrievalClips, codes_all: np.ndarray,
                     split: tuple[np.ndarray, np.ndarray, np.ndarray], val_proba, test_proba, smoothing, prior_weights,
                     select_by: str, likelihood: str):  # fmt: skip
    """The smoothing and prior weight chosen on the validation glosses, then every method's rank of
    each test clip's entry: (the choice, method -> ranks)."""
    train, val, test = split
    # pi of the ratio: the values' shares among the clips each classifier trained on
    val_priors = test_priors = None
    if likelihood == "ratio":
        train_val = np.sort(np.concatenate([train, val]))
        val_priors = [R.value_prior(codes_all[train, j], len(v)) for j, v in enumerate(table.vocab)]
        test_priors = [R.value_prior(codes_all[train_val, j], len(v)) for j, v in enumerate(table.vocab)]
    chosen = R.choose(table, val_proba, clips.entry_rows[val], smoothing, prior_weights, select_by, val_priors)
    both = chosen["phonology+prior"]
    ranks = R.method_ranks(table, test_proba, clips.entry_rows[test], chosen["phonology"]["smoothing"],
                           both["smoothing"], both["weight"], test_priors)
    return chosen, ranks


def _log_split(record: Mapping[str, Any], repeats: int, rate: float) -> None:
    """One split's line: recall@50 per method, the choice, the rate and what is left."""
    metrics, both = record["metrics"], record["chosen"]["phonology+prior"]
    k = int(record["index"])
    log.info("split %d/%d (seed %d): %d test clips of %d unseen glosses; recall@50 phonology %.3f, prior %.3f, "
             "phonology+prior %.3f (eps %g, w %g), oracle %.3f; %.1f s/split, ETA %s",
             k + 1, repeats, record["seed"], record["clips"]["test"], len(record["glosses"]["test"]),
             metrics["phonology"].get("recall@50", math.nan), metrics["prior"].get("recall@50", math.nan),
             metrics["phonology+prior"].get("recall@50", math.nan), both["smoothing"], both["weight"],
             metrics["oracle"].get("recall@50", math.nan), rate, _format_seconds(rate * (repeats - k - 1)))


def run_retrieval(
    clips: RetrievalClips,
    table: R.LexiconTable,
    classifier: Mapping[str, Any],
    trainer: Mapping[str, Any] | None,
    split: Mapping[str, Any] | SplitOptions,
    *,
    seed: int = 0,
    smoothing: Sequence[float] = (0.001, 0.01, 0.05, 0.2),
    prior_weights: Sequence[float] = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0),
    select_by: str = "mean_log_rank",
    recall_at: Sequence[int] = R.RECALL_AT,
    likelihood: str = "ratio",
) -> dict[str, Any]:
    """Retrieval over ``split.repeats`` gloss splits (see the module docstring); returns a JSON-ready
    dict: ``table`` (per method and metric: mean, std, 95% t interval over splits), ``per_split``,
    ``clips`` (one row per test clip and split), ``curves`` (recall@k per method, mean over splits),
    ``oracle_lexicon`` (the oracle over every lexicon entry), the settings and the timing."""
    from aslexp.recognition.models import resolve_params
    from aslexp.recognition.train import TrainerConfig

    options = split if isinstance(split, SplitOptions) else SplitOptions.parse(split)
    _check_settings(classifier, options, likelihood, select_by, smoothing, prior_weights)
    params = resolve_params(str(classifier["name"]), classifier.get("params"), classifier.get("module"))
    config = TrainerConfig.parse(trainer)
    recall_at = tuple(int(k) for k in recall_at)
    codes_all = table.codes[clips.entry_rows]  # (n_clips, P)
    ks = R.curve_ks(len(table))
    repeats = int(options.repeats)
    start = time.perf_counter()
    per_split, clip_rows = [], []
    pooled_entries: list[int] = []  # every split's test clips, for recall by frequency band
    pooled_ranks: dict[str, list[R.Rank]] = {m: [] for m in R.BAND_METHODS}
    curves: dict[str, list[list[float]]] = {m: [] for m in R.METHODS}
    log.info("retrieval: %d clips of %d glosses, %d lexicon entries, properties %s, classifier %s, %d gloss split(s)",
             len(clips.X), len(set(clips.glosses)), len(table), list(table.properties), classifier["name"], repeats)
    for k in range(repeats):
        record, test, ranks, rows = _one_split(k, int(options.seed) + k, options, clips, table, codes_all,
                                               (classifier, params, config, seed),
                                               (smoothing, prior_weights, select_by, likelihood), recall_at)
        per_split.append(record)
        clip_rows += rows
        pooled_entries.extend(int(e) for e in clips.entry_rows[test])
        for method in R.BAND_METHODS:
            pooled_ranks[method].extend(ranks[method])
        for method in R.METHODS:
            curves[method].append(R.recall_curve(ranks[method], ks))
        _log_split(per_split[-1], repeats, (time.perf_counter() - start) / (k + 1))
    overlap = split_overlap([s["glosses"]["test"] for s in per_split])
    log.info("the %d splits' %d test-gloss slots hold %d distinct glosses; %d slots recur in another split",
             repeats, overlap["test_slots"], overlap["distinct_test_glosses"], overlap["recurring"])
    return {
        "properties": list(table.properties),
        "classifier": str(classifier["name"]),
        "params": params,
        "trainer": config.to_dict(),
        "split_options": dict(options.__dict__),
        "seed": int(seed),
        "lexicon_entries": len(table),
        "num_clips": int(len(clips.X)),
        "num_glosses": len(set(clips.glosses)),
        "recall_at": list(recall_at),
        "likelihood": likelihood,
        "selection": {"select_by": select_by, "smoothing": [float(e) for e in smoothing],
                      "prior_weights": [float(w) for w in prior_weights], "on": "validation glosses"},
        "methods": {m: R.METHOD_LABELS[m] for m in R.METHODS},
        "table": _summary(per_split, recall_at, len(table)),
        "paired": _paired(per_split, len(table)),
        "split_overlap": overlap,
        "frequency": _frequency(table, clips, pooled_entries, pooled_ranks, recall_at),
        "per_split": per_split,
        "curves": {"k": ks, **{m: list(np.mean(np.array(v), axis=0)) if v else [] for m, v in curves.items()}},
        "oracle_lexicon": R.oracle_lexicon(table, recall_at),
        "clips": clip_rows,
        "time_s": time.perf_counter() - start,
    }


def _one_split(k: int, split_seed: int, options: SplitOptions, clips: RetrievalClips, table: R.LexiconTable,
               codes_all: np.ndarray, model: tuple, selection: tuple, recall_at: tuple[int, ...]):
    """Split ``k``: the properties fitted on its training glosses, its test clips ranked (the prior's
    smoothing and weight chosen on its validation glosses). Returns its record, its test clips' rows
    (indices into ``clips``), the ranks per method and its clip rows."""
    classifier, params, config, seed = model
    smoothing, prior_weights, select_by, likelihood = selection
    split_start = time.perf_counter()
    train, val, test = gloss_split(clips.glosses, options, split_seed)
    train_val = np.sort(np.concatenate([train, val]))
    val_proba, test_proba, budgets, seen = _fit_properties(classifier, params, config, clips, table, codes_all,
                                                           (train, val, test), seed)
    chosen, ranks = _rank_test_clips(table, clips, codes_all, (train, val, test), val_proba, test_proba,
                                     smoothing, prior_weights, select_by, likelihood)
    metrics = {m: R.rank_metrics(ranks[m], recall_at) for m in R.METHODS}
    property_accuracy, unseen = _property_accuracy(table, codes_all, train_val, test, test_proba)
    rows = _clip_records(k, split_seed, clips, table, test, ranks, test_proba)
    record = {
        "index": k, "seed": split_seed, **_split_sizes(clips.glosses, train, val, test),
        "chosen": {"phonology": {"smoothing": chosen["phonology"]["smoothing"]},
                   "phonology+prior": {key: chosen["phonology+prior"][key] for key in ("smoothing", "weight")}},
        "validation": {"phonology": chosen["phonology"], "phonology+prior": chosen["phonology+prior"]},
        "epochs": budgets, "classes_seen": seen, "property_accuracy": property_accuracy,
        "test_value_unseen_in_training": unseen, "metrics": metrics, "time_s": time.perf_counter() - split_start,
    }
    return record, test, ranks, rows


def _split_sizes(glosses: Sequence[str], train, val, test) -> dict[str, Any]:
    """A split's glosses (the test ones by name) and clips per part."""
    return {"glosses": {"train": len({glosses[i] for i in train}), "val": len({glosses[i] for i in val}),
                        "test": sorted({glosses[i] for i in test})},
            "clips": {"train": len(train), "val": len(val), "test": len(test)}}


def _summary(per_split: Sequence[Mapping[str, Any]], recall_at: Sequence[int], entries: int) -> dict[str, Any]:
    """Per method and metric: mean, std and 95% t interval over the splits."""
    keys = [f"recall@{k}" for k in recall_at] + ["mrr", "median_rank", "mean_rank", "mean_log_rank"]
    return {m: {key: split_interval([s["metrics"][m][key] for s in per_split], metric_range(key, entries))
                for key in keys} for m in R.METHODS}


def _paired(per_split: Sequence[Mapping[str, Any]], entries: int) -> list[dict[str, Any]]:
    """:data:`PAIRED` over the same splits; the difference's interval clipped to the range a
    difference can take, and none (resolved 0) below :data:`MIN_SPLITS_FOR_INTERVAL` splits."""
    out = []
    for a, b, key in PAIRED:
        item = paired_comparison([s["metrics"][a][key] for s in per_split], [s["metrics"][b][key] for s in per_split])
        low, high = metric_range(key, entries)
        span = high - low
        diff = item["diff"]
        if diff["n"] < MIN_SPLITS_FOR_INTERVAL:
            item["diff"] = {**diff, "low": None, "high": None, "half_width": None, "interval": NO_INTERVAL}
            item["resolved"] = 0
        else:
            item["diff"] = {**diff, "low": max(diff["low"], -span), "high": min(diff["high"], span)}
        out.append({"method": a, "reference": b, "metric": key, **item})
    return out


def _frequency(table: R.LexiconTable, clips: RetrievalClips, entries: Sequence[int],
               ranks: Mapping[str, Sequence[R.Rank]], recall_at: Sequence[int]) -> dict[str, Any]:
    """How frequent the glosses are in the lexicon (the prior's rank of their entries; the lexicon
    terciles of SignFrequency(Z) they fall in) and recall by frequency band of the true sign,
    pooled over every split's test clips (a clip tested in several splits counts each time)."""
    all_entries = sorted(set(int(e) for e in clips.entry_rows))
    tested = sorted(set(int(e) for e in entries))
    return {
        "rank_by": "SignFrequency(Z) among all lexicon entries (1 = most frequent; the prior's rank)",
        "median_prior_rank": {"test_glosses": float(np.median(R.frequency_rank(table, tested))) if tested else None,
                              "all_glosses": float(np.median(R.frequency_rank(table, all_entries)))},
        "glosses_by_lexicon_tercile": R.lexicon_terciles(table, all_entries),
        "band_edges": list(R.FREQUENCY_BAND_EDGES),
        "bands": R.frequency_bands(table, entries, ranks, recall_at),
    }


# --------------------------------------------------------------------------- outputs


def _finite(*values: Any) -> bool:
    return all(v is not None and math.isfinite(v) for v in values)


def _cell(interval: Mapping[str, float], percent: bool) -> str:
    scale, digits = (100.0, 1) if percent else (1.0, 3)
    mean = interval.get("mean", math.nan)
    if not _finite(mean):
        return "-"
    text = f"{scale * mean:.{digits}f}"
    low, high = interval.get("low"), interval.get("high")
    if _finite(low, high):
        text += f" [{scale * low:.{digits}f}, {scale * high:.{digits}f}]"
    return text


def _metric_cell(metric: str, interval: Mapping[str, float]) -> str:
    if metric.startswith("recall@"):
        return _cell(interval, percent=True)
    if metric in ("median_rank", "mean_rank"):
        mean, low, high = interval.get("mean"), interval.get("low"), interval.get("high")
        if not _finite(mean):
            return "-"
        return f"{mean:.0f}" + (f" [{low:.0f}, {high:.0f}]" if _finite(low, high) else "")
    return _cell(interval, percent=False)


METRIC_HEADERS = {"mrr": "MRR", "median_rank": "median rank", "mean_rank": "mean rank"}


def table_lines(result: Mapping[str, Any]) -> list[str]:
    """The retrieval table as Markdown lines: one row per method, recall@k in %, MRR and the median
    rank, each the mean over splits with its 95% t interval (none below 3 splits)."""
    metrics = [f"recall@{k}" for k in result["recall_at"]] + ["mrr", "median_rank"]
    header = ["method", *[METRIC_HEADERS.get(m, m + " (%)") for m in metrics]]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for method in R.METHODS:
        row = result["table"][method]
        lines.append("| " + " | ".join([result["methods"][method], *[_metric_cell(m, row[m]) for m in metrics]]) + " |")
    return lines


def interval_text(splits: int, overlap: Mapping[str, int] | None) -> str:
    """What the table's brackets are: the 95% t interval over splits, or none below 3 splits; and,
    when the splits reuse test glosses, that the interval is too narrow."""
    if splits < MIN_SPLITS_FOR_INTERVAL:
        text = f"mean over splits; 95% t interval: {NO_INTERVAL}."
    else:
        text = "mean over splits with the 95% t interval, clipped to the metric's range."
    if overlap and overlap.get("recurring"):
        text += (f" The splits are drawn independently and reuse test glosses: {overlap['recurring']} of the "
                 f"{overlap['test_slots']} test-gloss slots hold a gloss tested in another split too "
                 f"({overlap['distinct_test_glosses']} distinct test glosses)")
        text += (", so the intervals, which treat the splits as independent, are too narrow."
                 if splits >= MIN_SPLITS_FOR_INTERVAL else ".")
    return text


def describe(result: Mapping[str, Any]) -> str:
    """One paragraph: what the table is over."""
    splits = result["per_split"]
    tests = [s["clips"]["test"] for s in splits]
    test_glosses = [len(s["glosses"]["test"]) for s in splits]
    chosen = [s["chosen"]["phonology+prior"]["weight"] for s in splits]
    oracle = result["oracle_lexicon"]
    return (f"Unseen glosses ranked among all {result['lexicon_entries']:,} ASL-LEX entries; properties used: "
            f"{', '.join(result['properties'])}; classifier {result['classifier']} (phonology scored as "
            f"{'the likelihood ratio' if result['likelihood'] == 'ratio' else 'the posterior'}); {len(splits)} gloss split(s) of "
            f"{result['num_glosses']} glosses / {result['num_clips']} clips (test per split: {min(test_glosses)}-"
            f"{max(test_glosses)} glosses, {min(tests)}-{max(tests)} clips); "
            f"{interval_text(len(splits), result.get('split_overlap'))} Smoothing and prior weight chosen on the "
            f"validation glosses by {result['selection']['select_by']} (prior weight per split: "
            f"{', '.join(f'{w:g}' for w in chosen)}). "
            f"The oracle over every lexicon entry with these properties: recall@10 {100 * oracle['recall@10']:.1f}%, "
            f"recall@50 {100 * oracle['recall@50']:.1f}% (chance {100 * oracle['chance_recall@10']:.2f}% and "
            f"{100 * oracle['chance_recall@50']:.2f}%).")


BAND_KS = (10, 50)
BAND_LABELS = {"prior": "prior", "phonology": "phonology", "phonology+prior": "phonology + prior"}


def _percent(value: Any) -> str:
    return f"{100 * value:.1f}" if _finite(value) else "-"


def frequency_lines(frequency: Mapping[str, Any], recall_at: Sequence[int], entries: int, glosses: int) -> list[str]:
    """Why the prior is strong (how common the glosses are) and recall by the frequency band of the
    true sign, as Markdown lines (``frequency`` as :func:`run_retrieval` gives it; the results page
    passes its snapshot's copy)."""
    ks = [k for k in BAND_KS if k in recall_at]
    median, terciles = frequency["median_prior_rank"], frequency["glosses_by_lexicon_tercile"]
    tested = f"{median['test_glosses']:.0f}" if _finite(median.get("test_glosses")) else "-"
    lines = [f"The frequency prior is strong because WLASL's glosses are common words: the median rank by "
             f"SignFrequency(Z) of the test glosses is {tested} of {entries:,} ({median['all_glosses']:.0f} over all "
             f"{glosses} glosses), and {terciles['high']} of the {glosses} glosses are in the top third of the "
             f"lexicon's frequency ({terciles['mid']} in the middle, {terciles['low']} in the bottom third). Recall "
             f"by the true sign's frequency rank, over every split's test clips (a clip tested in several splits "
             f"counts each time):", ""]
    header = ["true sign's frequency rank", "clips (glosses)",
              *[f"{BAND_LABELS[m]} @{k} (%)" for m in R.BAND_METHODS for k in ks]]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for band in frequency["bands"]:
        cells = [_percent(band["methods"][m].get(f"recall@{k}")) for m in R.BAND_METHODS for k in ks]
        lines.append("| " + " | ".join([band["band"], f"{band['clips']} ({band['glosses']})", *cells]) + " |")
    return lines


def paired_lines(result: Mapping[str, Any]) -> list[str]:
    """One line per paired comparison: the mean difference over the same splits with its 95% t
    interval (none below 3 splits), splits won / tied / lost and the Wilcoxon p."""
    lines = []
    for item in result.get("paired", []):
        diff, percent = item["diff"], item["metric"].startswith("recall@")
        scale, unit = (100.0, " points") if percent else (1.0, "")
        interval = (f" [{scale * diff['low']:+.1f}, {scale * diff['high']:+.1f}]"
                    if _finite(diff["low"], diff["high"]) else "")
        lines.append(f"- {result['methods'][item['method']]} minus {result['methods'][item['reference']]}, "
                     f"{item['metric']}: {scale * diff['mean']:+.1f}{unit}{interval}; splits higher/equal/lower "
                     f"{item['wins']}/{item['ties']}/{item['losses']}, Wilcoxon p = {item['wilcoxon_p']:.3g}")
    return lines


def write_outputs(result: Mapping[str, Any], out_dir: str | Path) -> dict[str, str]:
    """The run folder's files beside metrics.json: the table (Markdown), the per-clip ranks (CSV) and
    the recall@k plot. Returns name -> file."""
    from aslexp.files import write_rows_csv, write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / TABLE_FILE, "# Lexicon retrieval for unseen glosses\n\n" + describe(result) + "\n\n"
               + "\n".join(table_lines(result)) + "\n\nPaired over the same splits:\n\n"
               + "\n".join(paired_lines(result)) + "\n\n"
               + "\n".join(frequency_lines(result["frequency"], result["recall_at"],
                                           result["lexicon_entries"], result["num_glosses"])) + "\n")
    write_rows_csv(out / RANKS_FILE, result["clips"], ["split", "split_seed", "video_id", "gloss", "entry_id"])
    files = {"table": TABLE_FILE, "ranks": RANKS_FILE}
    try:
        from aslexp.viz.retrieval import plot_recall_curves
    except ImportError as error:  # a node without matplotlib: every number is in metrics.json
        log.warning("no plot (%s); the numbers are in metrics.json", error)
        return files
    title = (f"Unseen glosses among {result['lexicon_entries']:,} ASL-LEX signs: {result['classifier']} on "
             f"{', '.join(result['properties'])}; mean over {len(result['per_split'])} gloss split(s)")
    plot_recall_curves(result["curves"], result["methods"], out / PLOT_FILE, title=title)
    files["plot"] = PLOT_FILE
    return files
