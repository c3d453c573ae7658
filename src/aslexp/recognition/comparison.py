"""What a recognition run concludes: the model beside its simple and chance baselines on the same
units, one sentence that says what the model adds, and the cautions that say what the numbers
cannot carry.

Three rules keep the sentence honest:

- the reference simple baseline is chosen by validation, never by test; when the best validation
  scores *tie* (:func:`validation_tie`), the sentence says so instead of naming a winner;
- a test set under :data:`SMALL_TEST_SET` clips gets a caution with what one clip weighs;
- a model that draws no random number (logreg with lbfgs, svm, hgb on a few hundred clips) gets a
  caution when it ran with several seeds: their runs are one run repeated, their spread no spread.

:func:`comparison_block` is what ``metrics.json`` keeps under ``comparison`` and what
:func:`aslexp.recognition.report.comparison_text` prints at the end of a job.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from aslexp.recognition.metrics import mean_interval, paired_comparison

COMPARED = ("mcc", "balanced_accuracy")  # the comparison's columns
CHANCE_WORDS = {"majority": "majority class", "stratified": "stratified chance baseline"}
# Validation scores are printed with 3 decimals: two closer than that are not told apart.
VALIDATION_DIGITS = 3
# Fewer test clips than this get a caution: below 30, one clip moves accuracy by more than 3.3
# points and the 95% interval of an accuracy near 0.5 (Wald, 1.96 * sqrt(0.25 / n)) is wider than
# +-0.18, more than the gaps between the simple models on this data (docs/recognition.md).
SMALL_TEST_SET = 30


def validation_tie(scores: Sequence[float], other: Sequence[float]) -> tuple[bool, str]:
    """Whether two candidates' validation scores (one per unit, the same units, paired) tie, and
    why: their means are equal at the printed precision (``VALIDATION_DIGITS``), or, with two or
    more units, the 95% t interval of the paired difference includes 0, so the splits (or seeds)
    cannot tell them apart. With one unit there is no spread to judge by: only the rounding."""
    a, b = np.asarray(scores, dtype=np.float64), np.asarray(other, dtype=np.float64)
    if round(float(a.mean()), VALIDATION_DIGITS) == round(float(b.mean()), VALIDATION_DIGITS):
        return True, f"equal to {VALIDATION_DIGITS} decimals"
    if len(a) >= 2 and len(a) == len(b):
        paired = paired_comparison(a, b)
        if paired["resolved"] == 0:
            diff = paired["diff"]
            return True, (f"the 95% interval of their difference over {diff['n']} paired units, "
                          f"[{diff['low']:+.3f}, {diff['high']:+.3f}], includes 0")  # fmt: skip
    return False, ""


def comparison_block(name: str, metric: str, unit: str, units: Sequence[Mapping[str, float]], val_score: float,
                     simple: Mapping[str, Mapping[str, Any]], chance: str,
                     chance_units: Sequence[Mapping[str, float]]) -> dict[str, Any]:  # fmt: skip
    """The model beside the simple baselines ``simple`` and the chance baseline ``chance`` on the same
    units (splits, or seeds of one split): test MCC and balanced accuracy (mean, std, n) per row, the
    paired differences model minus the reference (the simple baseline with the best validation
    score, never chosen by test) and model minus chance, a verdict on test MCC and one sentence
    saying what the model adds. Rows: the model, each simple baseline that is not the model itself
    (the reference first, ``reference: true``), the chance baseline. ``validation_tie``: the
    candidates whose validation score ties the reference's (the reference first; empty: none),
    with ``validation_tie_reason``; ``model_minus_tied`` the paired test difference to the first
    other one when the model is the reference."""

    def row(role: str, row_name: str, per_unit: Sequence[Mapping[str, float]], **extra) -> dict[str, Any]:
        test = {key: {k: v for k, v in mean_interval([u[key] for u in per_unit]).items() if k in ("mean", "std", "n")}
                for key in COMPARED}  # fmt: skip
        return {"role": role, "name": row_name, **extra, "test": test}

    def paired(per_unit: Sequence[Mapping[str, float]]) -> dict[str, Any]:
        return {key: paired_comparison([u[key] for u in units], [u[key] for u in per_unit]) for key in COMPARED}

    order = sorted(simple, key=lambda b: -simple[b]["val_score"])  # stable: ties keep the order listed
    reference = order[0] if order else None
    tied, reason = _tied_with(reference, order, simple)
    selected_by = f"validation {metric}" if len(simple) > 1 else "the only one"
    model_is_reference = reference is not None and bool(simple[reference]["same_as_model"])
    rows = [row("model", name, units, val_score=val_score, reference=model_is_reference,
                tied=bool(tied) and any(simple[b]["same_as_model"] for b in tied))]  # fmt: skip
    for baseline in order:
        if not simple[baseline]["same_as_model"]:
            rows.append(row("simple_baseline", baseline, simple[baseline]["test_per_split"],
                            val_score=simple[baseline]["val_score"], reference=baseline == reference,
                            selected_by=selected_by, tied=baseline in tied))  # fmt: skip
    rows.append(row("chance_baseline", chance, chance_units, selected_by="validation accuracy"))
    vs_simple = paired(simple[reference]["test_per_split"]) if reference is not None else None
    if reference is None:
        verdict = "no_simple_baseline"
    elif model_is_reference:
        verdict = "model_is_simple_baseline"
    else:
        difference = vs_simple["mcc"]["diff"]["mean"]
        verdict = "above" if difference > 0 else "below" if difference < 0 else "equal"
    block = {"metrics": list(COMPARED), "unit": unit, "n": len(units), "candidates": list(simple),
             "simple_baseline": reference, "simple_baseline_selected_by": selected_by, "chance_baseline": chance,
             "validation_tie": tied, "validation_tie_reason": reason,
             "val_scores": {b: simple[b]["val_score"] for b in order},
             "rows": rows, "model_minus_simple_baseline": vs_simple, "model_minus_chance_baseline": paired(chance_units),
             "model_minus_tied": paired(simple[tied[1]]["test_per_split"]) if model_is_reference and tied else None,
             "verdict": verdict}  # fmt: skip
    block["sentence"] = _comparison_sentence(name, block)
    return block


def _tied_with(reference: str | None, order: Sequence[str],
               simple: Mapping[str, Mapping[str, Any]]) -> tuple[list[str], str]:  # fmt: skip
    """The candidates tied with the reference on validation (the reference first), and why."""
    if reference is None:
        return [], ""
    mine = simple[reference].get("val_per_unit") or [simple[reference]["val_score"]]
    tied, reasons = [], []
    for other in order[1:]:
        tie, reason = validation_tie(mine, simple[other].get("val_per_unit") or [simple[other]["val_score"]])
        if tie:
            tied.append(other)
            reasons.append(reason)
    return ([reference, *tied], reasons[0]) if tied else ([], "")


def _signed(value: float) -> str:
    return f"{value:+.3f}"


def _comparison_sentence(name: str, block: Mapping[str, Any]) -> str:
    vs_chance, vs_simple = block["model_minus_chance_baseline"], block["model_minus_simple_baseline"]
    reference, verdict, tied = block["simple_baseline"], block["verdict"], block.get("validation_tie") or []
    chance = CHANCE_WORDS.get(block["chance_baseline"], f"chance baseline {block['chance_baseline']}")

    def gains(paired: Mapping[str, Any]) -> str:
        return (f"{_signed(paired['mcc']['diff']['mean'])} test MCC and "
                f"{_signed(paired['balanced_accuracy']['diff']['mean'])} balanced accuracy")

    def interval(paired: Mapping[str, Any]) -> str:
        diff = paired["mcc"]["diff"]
        if block["unit"] != "split":
            return " on one split (split.repeats=10 gives an interval over splits)"
        state = {1: "resolved above 0", -1: "resolved below 0", 0: "not resolved: it includes 0"}[paired["mcc"]["resolved"]]
        return f" (MCC 95% interval [{diff['low']:+.3f}, {diff['high']:+.3f}] over {diff['n']} paired splits, {state})"

    def tie_words() -> str:
        scores = block["val_scores"]
        listed = ", ".join(f"{b} {scores[b]:.3f}" for b in tied)
        return f"tied on validation: {listed}, {block['validation_tie_reason']}"

    if verdict == "no_simple_baseline":
        return f"{name} adds {gains(vs_chance)} over the {chance} (no simple baseline: simple_baseline=null)."
    if verdict == "model_is_simple_baseline" and tied:
        other = tied[1]
        return (f"{name} and {'/'.join(tied[1:])} are {tie_words()}; so neither is the strongest simple baseline: "
                f"on test {name} minus {other} is {gains(block['model_minus_tied'])}"
                f"{interval(block['model_minus_tied'])}; {name} adds {gains(vs_chance)} over the {chance}.")  # fmt: skip
    if verdict == "model_is_simple_baseline":
        best = (f"the strongest simple baseline itself (the best of {'/'.join(block['candidates'])} by validation)"
                if len(block["candidates"]) > 1 else "the simple baseline itself")  # fmt: skip
        return (f"{name} is {best}; it adds {gains(vs_chance)} over the {chance}; "
                f"classifier=stgcn (or another model) is compared with it.")  # fmt: skip
    if reference == name:
        reference = f"{reference} at its defaults"
    if tied:
        strongest = f"{reference} ({tie_words()}; the first listed is the reference)"
    elif len(block["candidates"]) > 1:
        strongest = f"{reference} (the strongest simple baseline by validation)"
    else:
        strongest = f"the simple baseline {reference}"
    if verdict == "below":
        text = f"{name} is below {strongest}: {gains(vs_simple)}{interval(vs_simple)}"
    else:
        text = f"{name} adds {gains(vs_simple)} over {strongest}{interval(vs_simple)}"
    if vs_chance["mcc"]["diff"]["mean"] <= 0:
        text += f"; it is not above the {chance}"
    return text + "."


def cautions(name: str, seeds: Sequence[int], uses_seed: bool, test_clips: Sequence[int]) -> list[str]:
    """The lines that say what a run's numbers cannot carry: a small test set (fewer than
    ``SMALL_TEST_SET`` clips in a split), model seeds that cannot differ (``uses_seed`` false)."""
    lines = []
    smallest = min(test_clips) if test_clips else 0
    if 0 < smallest < SMALL_TEST_SET:
        where = " in the smallest split" if len(set(test_clips)) > 1 else ""
        lines.append(f"caution: {smallest} test clips{where} (fewer than {SMALL_TEST_SET}): one clip is "
                     f"{100 / smallest:.1f} points of accuracy and the 95% interval of an accuracy near 0.5 is "
                     f"±{1.96 * math.sqrt(0.25 / smallest):.2f}; a larger split.test_fraction or split.repeats=10 "
                     "says more")  # fmt: skip
    if not uses_seed and len(seeds) > 1:
        lines.append(identical_seeds_caution(name, seeds))
    return lines


def identical_seeds_caution(name: str, seeds: Sequence[int]) -> str:
    """Several model seeds of a model that draws no random number: one result, repeated."""
    return (f"caution: {name} draws no random number with these settings, so its model seeds "
            f"{', '.join(str(s) for s in seeds)} gave identical runs on each split (their spread is 0, not a "
            "measurement); vary the split instead (split.repeats=10 or split.seed)")  # fmt: skip
