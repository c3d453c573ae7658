"""Phonology as help for seen signs: gloss classification on glosses seen in
training, with and without auxiliary ASL-LEX property heads, paired over K seeded splits.

Kezar et al. (2023) add phonological property heads to a sign classifier as an auxiliary loss and
report about +9 points of top-1 on WLASL. This module asks the same question on aslexp's data, with
the multi-task encoder of :mod:`aslexp.recognition.models.multitask`:

* **The split** (per seed ``split.seed + k``, k < ``split.repeats``): the clips are split 70/15/15 per
  gloss (:func:`aslexp.data.splits.resplit`, a ``phoneme`` split whose label is the gloss), so every
  tested gloss has clips in training. A gloss with fewer clips than a split needs (``rare_classes``:
  ``train_only`` by default) stays in training only: a class the models can predict, never tested.
* **Two networks, the same everything else.** ``gloss``: the encoder with one head over the training
  glosses. ``gloss+phonology``: the same encoder and gloss head plus a head per auxiliary property
  (loss weight ``aux_weight``; a clip whose value is unknown is masked for that head). Both start
  from the same seed, train on the same clips and keep the epoch of the best validation MCC of the
  **gloss head** (the property heads never choose), and are tested on the same clips: the paired
  difference is the auxiliary heads' effect.
* **Beside them**, computed on the same split: chance (top-k = k / number of training glosses), the
  majority baseline (the k most frequent training glosses for every clip) and the strongest simple
  baseline, a feature classifier (rf on summary features by default) fitted on the training clips.

Per split: top-k accuracy on the test clips for every method; over splits: the mean with its 95% t
interval and the paired differences (with minus without, and each network minus the simple baseline).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.config_schema import Float, Int, List, Section, Text, key
from aslexp.data.lexicon import PROPERTIES
from aslexp.data.splits import SplitOptions, resplit
from aslexp.recognition.metrics import mean_interval, paired_comparison

log = logging.getLogger(__name__)

TABLE_FILE = "glosses.md"
PREDICTIONS_FILE = "predictions.csv"
PLOT_FILE = "top_k_by_split.png"
GLOSS = "gloss"
WITHOUT, WITH = "gloss", "gloss+phonology"
# The rows of the table, in order, with their labels (the simple baseline's label names its model).
REFERENCES = ("chance", "majority", "simple")
PAIRED = ((WITH, WITHOUT), (WITHOUT, "simple"), (WITH, "simple"))


@dataclass(frozen=True)
class SeenGlossOptions(Section):
    """The job's ``glosses`` section (``conf/glosses.yaml`` documents each key)."""

    SECTION = "glosses"

    auxiliary: list[str] = field(default_factory=lambda: list(PROPERTIES), metadata=key(List(Text(), nonempty=True)))
    aux_weight: float = field(default=1.0, metadata=key(Float(0, low_open=True)))
    top_k: list[int] = field(default_factory=lambda: [1, 5], metadata=key(List(Int(1), nonempty=True)))
    fit: dict[str, Any] = field(default_factory=dict)
    simple_baseline: str | None = "rf"
    simple_baseline_params: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        from aslexp.errors import ConfigError

        bad = [p for p in self.auxiliary if p not in PROPERTIES]
        if bad:
            raise ConfigError(f"auxiliary: unknown property {bad[0]!r}; expected some of {list(PROPERTIES)}")
        if len(set(self.auxiliary)) != len(self.auxiliary):
            raise ConfigError(f"auxiliary={self.auxiliary}: a property is given twice")
        if 1 not in self.top_k:
            raise ConfigError(f"top_k={self.top_k}: must include 1 (the table's headline)")
        from aslexp.recognition.models.multitask import FIT_DEFAULTS, check_params

        wrong = sorted(set(self.fit) - (set(FIT_DEFAULTS) - {"head_weights", "gloss_head"}))
        if wrong:
            raise ConfigError(f"fit.{wrong[0]}: unknown key; expected some of "
                              f"{sorted(set(FIT_DEFAULTS) - {'head_weights', 'gloss_head'})}")
        try:
            check_params(self.fit)
        except ValueError as error:
            raise ConfigError(f"fit: {error}") from None


def seen_gloss_split(glosses: Sequence[str], split: SplitOptions, seed: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """train, val, test clip indices of one split stratified by gloss (every tested gloss is trained on)."""
    result = resplit(list(glosses), list(glosses), dataclasses.replace(split, name="phoneme"), seed)
    return tuple(np.sort(result.keep[np.asarray(result.splits[n], dtype=np.int64)]) for n in ("train", "val", "test"))


def top_k_accuracy(scores: np.ndarray, truth: np.ndarray, k: int) -> float:
    """Share of rows whose true column (-1: a class the scorer never saw, always wrong) is among the
    ``k`` highest scores; ties broken by column order (stable)."""
    if len(truth) == 0:
        return math.nan
    order = np.argsort(-np.asarray(scores, dtype=np.float64), axis=1, kind="stable")[:, :k]
    return float(np.mean([(t >= 0) and (t in row) for t, row in zip(np.asarray(truth), order)]))


def _simple_scores(classifier: Mapping[str, Any], clips, codes: np.ndarray, classes: np.ndarray,
                   train: np.ndarray, test: np.ndarray, seed: int) -> np.ndarray:
    """The simple baseline's class probabilities (test clips x training glosses)."""
    from aslexp.recognition.models import build_classifier

    _, channels, frames, nodes, _ = clips.X.shape
    model = build_classifier(str(classifier["name"]), dict(classifier.get("params") or {}), channels, frames, nodes,
                             len(classes), clips.layout, module=classifier.get("module"))
    model.fit(clips.X[train], clips.mask[train], np.searchsorted(classes, codes[train]), seed=seed)
    return np.asarray(model.predict_proba(clips.X[test], clips.mask[test]), dtype=np.float64)


def _format_seconds(seconds: float) -> str:
    seconds = max(0.0, float(seconds))
    return f"{seconds / 60:.1f} min" if seconds >= 90 else f"{seconds:.0f} s"


def _network_scores(scores: dict[str, np.ndarray], clips, gloss_codes: np.ndarray, aux_codes: np.ndarray,
                    options: SeenGlossOptions, params: Mapping[str, Any], split, seed: int) -> dict[str, dict]:  # fmt: skip
    """The two networks of one split, fitted on its train clips (validated on val) and scored on its
    test clips into ``scores``: the gloss head alone, and with the auxiliary property heads. Returns
    each one's epochs (best, ran, validation MCC)."""
    from aslexp.recognition.models.multitask import fit_multitask

    train, val, test = split
    epochs = {}
    for method, codes, names, weights in (
            (WITHOUT, gloss_codes[:, None], [GLOSS], [1.0]),
            (WITH, np.concatenate([gloss_codes[:, None], aux_codes], axis=1), [GLOSS, *options.auxiliary],
             [1.0] + [float(options.aux_weight)] * len(options.auxiliary))):
        model = fit_multitask(clips.X, clips.mask, codes, names, train, val, {**params, "head_weights": weights},
                              seed=seed, calibrate=False, select=[GLOSS])
        scores[method] = model.logits(clips.X[test], clips.mask[test])[0]
        epochs[method] = {"best": model.best_epoch, "ran": len(model.history),
                          "val_mcc": model.history[model.best_epoch - 1]["val_mcc"]}
    return epochs


def _prediction_rows(k: int, split_seed: int, method: str, scores: np.ndarray, truth: np.ndarray, test: np.ndarray,
                     clips, vocabulary: Sequence[str], classes: np.ndarray) -> list[dict[str, Any]]:  # fmt: skip
    """One row per test clip of a method: its predicted gloss and the rank of the true one ("" when no
    training clip had it)."""
    predicted = np.argmax(scores, axis=1)
    return [{"split": k, "split_seed": split_seed, "method": method, "video_id": clips.video_ids[clip],
             "gloss": clips.glosses[clip], "predicted": vocabulary[int(classes[predicted[row]])],
             "rank_of_true": (int((scores[row] > scores[row][truth[row]]).sum()) + 1 if truth[row] >= 0 else "")}
            for row, clip in enumerate(test)]


def run_seen_glosses(clips, property_codes: np.ndarray, options: SeenGlossOptions, encoder: Mapping[str, Any],
                     split: SplitOptions, *, simple: Mapping[str, Any] | None, seed: int = 0,
                     property_names: Sequence[str] = PROPERTIES) -> dict[str, Any]:
    """Every split's top-k accuracies for chance, majority, the simple baseline and the two networks,
    and the summary over splits. ``clips``: :class:`aslexp.recognition.retrieval_run.RetrievalClips`;
    ``property_codes`` (N, P): each clip's value code per property of ``property_names`` (-1: unknown);
    ``encoder``: the multitask classifier's params; ``simple``: ``{name, params[, module]}`` or None."""
    glosses = list(clips.glosses)
    vocabulary = sorted(set(glosses))
    gloss_codes = np.array([vocabulary.index(g) for g in glosses], dtype=np.int64)
    columns = [list(property_names).index(p) for p in options.auxiliary]
    aux_codes = np.asarray(property_codes, dtype=np.int64)[:, columns]
    params = {**dict(encoder), **options.fit}
    methods = {"chance": "chance (k / training glosses)", "majority": "majority (most frequent training glosses)"}
    if simple is not None:
        methods["simple"] = f"{simple['name']} (simple baseline)"
    methods[WITHOUT] = "gloss head alone"
    methods[WITH] = f"gloss head + {len(options.auxiliary)} property heads (auxiliary)"
    per_split, rows = [], []
    start = time.perf_counter()
    for k in range(int(split.repeats)):
        split_seed = int(split.seed) + k
        t0 = time.perf_counter()
        train, val, test = seen_gloss_split(glosses, split, split_seed)
        classes = np.unique(gloss_codes[train])
        truth = np.searchsorted(classes, gloss_codes[test])
        truth = np.where(classes[np.clip(truth, 0, len(classes) - 1)] == gloss_codes[test], truth, -1)
        scores: dict[str, np.ndarray] = {}
        rng = np.random.default_rng(split_seed)
        # chance: a random order of the training glosses per clip (its expectation is k / |classes|)
        scores["chance"] = rng.random((len(test), len(classes)))
        counts = np.bincount(np.searchsorted(classes, gloss_codes[train]), minlength=len(classes)).astype(np.float64)
        scores["majority"] = np.tile(counts, (len(test), 1))
        if simple is not None:
            scores["simple"] = _simple_scores(simple, clips, gloss_codes, classes, train, test, seed)
        epochs = _network_scores(scores, clips, gloss_codes, aux_codes, options, params, (train, val, test), seed)
        metrics = {m: {f"top{kk}": top_k_accuracy(scores[m], truth, kk) for kk in options.top_k} for m in methods}
        # chance's expectation, not one random draw
        metrics["chance"] = {f"top{kk}": min(1.0, kk / len(classes)) for kk in options.top_k}
        for m in (WITHOUT, WITH, *(["simple"] if simple is not None else [])):
            rows += _prediction_rows(k, split_seed, m, scores[m], truth, test, clips, vocabulary, classes)
        elapsed = time.perf_counter() - t0
        per_split.append({
            "index": k, "seed": split_seed, "clips": {"train": len(train), "val": len(val), "test": len(test)},
            "glosses": {"train": len(classes), "tested": len(set(gloss_codes[test].tolist()))},
            "epochs": epochs, "metrics": metrics, "time_s": elapsed,
        })
        rate = (time.perf_counter() - start) / (k + 1)
        log.info("split %d/%d (seed %d): %d test clips of %d glosses; top-1 gloss %.3f, gloss+phonology %.3f%s; "
                 "%.1f s/split, ETA %s", k + 1, split.repeats, split_seed, len(test), per_split[-1]["glosses"]["tested"],
                 metrics[WITHOUT]["top1"], metrics[WITH]["top1"],
                 f", {simple['name']} {metrics['simple']['top1']:.3f}" if simple is not None else "",
                 rate, _format_seconds(rate * (int(split.repeats) - k - 1)))
    keys = [f"top{kk}" for kk in options.top_k]
    summary = {m: {kk: mean_interval([s["metrics"][m][kk] for s in per_split]) for kk in keys} for m in methods}
    paired = [{"method": a, "reference": b, "metric": kk,
               **paired_comparison([s["metrics"][a][kk] for s in per_split], [s["metrics"][b][kk] for s in per_split])}
              for a, b in PAIRED if a in methods and b in methods for kk in keys]
    return {
        "methods": methods, "auxiliary": list(options.auxiliary), "aux_weight": float(options.aux_weight),
        "params": params, "simple_baseline": dict(simple) if simple is not None else None,
        "num_clips": len(glosses), "num_glosses": len(vocabulary), "top_k": list(options.top_k),
        "split": {"kind": "phoneme (stratified by gloss)", "seed": int(split.seed), "repeats": int(split.repeats),
                  "rare_classes": split.rare_classes, "val_fraction": split.val_fraction,
                  "test_fraction": split.test_fraction},
        "per_split": per_split, "table": summary, "paired": paired, "predictions": rows,
        "time_s": time.perf_counter() - start,
    }


# --------------------------------------------------------------------------- the outputs


def _cell(interval: Mapping[str, float]) -> str:
    mean = interval["mean"]
    if not math.isfinite(mean):
        return "-"
    if not (math.isfinite(interval["low"]) and math.isfinite(interval["high"])):
        return f"{100 * mean:.1f}"
    return f"{100 * mean:.1f} [{100 * interval['low']:.1f}, {100 * interval['high']:.1f}]"


def table_lines(result: Mapping[str, Any]) -> list[str]:
    keys = [f"top{k}" for k in result["top_k"]]
    lines = ["| method | " + " | ".join(f"top-{k} (%)" for k in result["top_k"]) + " |",
             "|---|" + "---|" * len(keys)]
    for method, label in result["methods"].items():
        lines.append(f"| {label} | " + " | ".join(_cell(result["table"][method][kk]) for kk in keys) + " |")
    return lines


def paired_lines(result: Mapping[str, Any]) -> list[str]:
    lines = []
    for item in result["paired"]:
        diff = item["diff"]
        interval = (f" [{100 * diff['low']:+.1f}, {100 * diff['high']:+.1f}]"
                    if math.isfinite(diff["low"]) and math.isfinite(diff["high"]) else "")
        p = item["wilcoxon_p"]
        lines.append(f"- {result['methods'][item['method']]} minus {result['methods'][item['reference']]}, "
                     f"{item['metric'].replace('top', 'top-')} (points): {100 * diff['mean']:+.1f}{interval}; splits "
                     f"higher/equal/lower {item['wins']}/{item['ties']}/{item['losses']}, Wilcoxon p = "
                     f"{'-' if not math.isfinite(p) else format(p, '.3g')}")
    return lines


def span(values: Sequence[int]) -> str:
    """``"50"`` when every value is 50, else ``"48-52"``."""
    low, high = min(values), max(values)
    return f"{low}" if low == high else f"{low}-{high}"


def describe(result: Mapping[str, Any]) -> str:
    splits = result["per_split"]
    tests = [s["clips"]["test"] for s in splits]
    tested = [s["glosses"]["tested"] for s in splits]
    return (f"Gloss classification on glosses seen in training: {len(splits)} split(s) stratified by gloss "
            f"(70/15/15 per gloss; glosses too rare to split stay in training), {result['num_clips']} clips of "
            f"{result['num_glosses']} glosses, {span(tests)} test clips of {span(tested)} glosses per split. Auxiliary heads: {', '.join(result['auxiliary'])} (loss weight "
            f"{result['aux_weight']:g}); both networks keep the epoch of the best validation MCC of the gloss head. "
            "Mean over splits [95% t interval].")


def write_outputs(result: Mapping[str, Any], out_dir: str | Path) -> dict[str, str]:
    """The run folder's files beside metrics.json: the table (Markdown), the per-clip predictions
    (CSV) and the per-split plot. Returns name -> file."""
    from aslexp.files import write_rows_csv, write_text

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_text(out / TABLE_FILE, "# Phonology as help for seen signs\n\n" + describe(result) + "\n\n"
               + "\n".join(table_lines(result)) + "\n\nPaired over the same splits:\n\n"
               + "\n".join(paired_lines(result)) + "\n")
    write_rows_csv(out / PREDICTIONS_FILE, result["predictions"],
                   ["split", "split_seed", "method", "video_id", "gloss", "predicted", "rank_of_true"])
    files = {"table": TABLE_FILE, "predictions": PREDICTIONS_FILE}
    try:
        from aslexp.viz.seen_glosses import plot_top_k_by_split
    except ImportError as error:  # a node without matplotlib: every number is in metrics.json
        log.warning("no plot (%s); the numbers are in metrics.json", error)
        return files
    plot_top_k_by_split(result["per_split"], result["table"], result["methods"], result["top_k"], out / PLOT_FILE,
                        title=f"Glosses seen in training, {len(result['per_split'])} split(s): with and without "
                              f"auxiliary phonology heads")
    files["plot"] = PLOT_FILE
    return files
