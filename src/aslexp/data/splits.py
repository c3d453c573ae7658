"""Deterministic, label-stratified splits of a labelled clip set.

Kinds (``SPLIT_KINDS``):
- ``phoneme``: clips are split 70/15/15 per label; one sign (gloss) may appear in train and test,
  signed by other signers.
- ``gloss``: glosses are split 70/15/15 per label and every clip follows its gloss, so no gloss
  of val/test is seen in training.
- ``cv5``: 85/15 train+val vs test per label, then ``num_folds`` stratified folds over train+val;
  'train'/'val' are fold 0's.

Per label, after a seeded shuffle: n_test = max(1, round(n * test_fraction)), n_val likewise,
train gets the rest (for cv5 the rest is dealt round-robin to the folds). A label needs
``min_units(kind)`` units (clips, or glosses for ``gloss``) to be stratified: 3, or
``num_folds + 1`` for cv5. Rarer labels follow ``rare_classes``:
- ``drop`` (default): their clips are removed;
- ``merge``: they become one label ``Other`` (joining a real 'Other' value if there is one);
  if that is still too rare it is dropped;
- ``train_only``: they are kept, in train only (for cv5 in the training part of every fold).
Every affected label is logged with its count. Label ids are dense, in sorted label order.
"""

from __future__ import annotations

import logging
from collections import defaultdict
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np

from aslexp.config_schema import Choice, Int, Section, key
from aslexp.data.dataset import DataError

log = logging.getLogger(__name__)

SPLIT_KINDS = ("phoneme", "gloss", "cv5")
RARE_RULES = ("drop", "merge", "train_only")
OTHER = "Other"


@dataclass
class SplitResult:
    keep: np.ndarray  # indices of the input samples that remain, ascending
    y: np.ndarray  # (len(keep),) dense label ids
    label_names: list[str]
    splits: dict[str, object]  # index arrays into the kept samples (+ 'folds' for cv5)
    rare: dict[str, int] = field(default_factory=dict)  # original label -> units, when rare
    rare_rule: str = "drop"
    dropped: int = 0  # samples removed by the rare-class rule


def min_units(kind: str, num_folds: int = 5) -> int:
    return num_folds + 1 if kind == "cv5" else 3


def _apply_rare_rule(labels_by_unit: dict, rare: dict[str, int], rule: str, needed: int) -> dict:
    """The units' labels after the rare-class rule: ``drop`` the rare labels' units, ``merge`` them
    into :data:`OTHER` (dropped in turn when still rare), ``train_only`` keeps them (for training)."""
    if rule == "merge" and rare:
        merged = {u: OTHER if lab in rare else lab for u, lab in labels_by_unit.items()}
        counts = _count(merged)
        if counts.get(OTHER, 0) < needed:
            log.info("merged label %r has %d unit(s) (< %d): dropped", OTHER, counts[OTHER], needed)
            merged = {u: lab for u, lab in merged.items() if lab != OTHER}
        return merged
    if rule == "drop":
        return {u: lab for u, lab in labels_by_unit.items() if lab not in rare}
    return labels_by_unit


def _assign_units(labels_by_unit: dict, label_names: Sequence[str], kind: str, seed: int, train_only: set,
                  val_fraction: float, test_fraction: float, num_folds: int) -> dict[object, str | int]:  # fmt: skip
    """Each unit's part: per label a seeded shuffle, the first share ``test``, then ``val`` and
    ``train`` (``cv5``: the rest dealt into folds 0..num_folds-1); ``train_only`` labels all train."""
    rng = np.random.default_rng(seed)
    by_label: dict[str, list] = defaultdict(list)
    for unit in sorted(labels_by_unit):  # sorted: the same order whatever the input order
        by_label[labels_by_unit[unit]].append(unit)
    assignment: dict[object, str | int] = {}
    fold_offset = 0
    for label in label_names:
        members = list(by_label[label])
        order = rng.permutation(len(members))
        members = [members[i] for i in order]
        if label in train_only:
            assignment.update({u: "train" for u in members})
            continue
        n = len(members)
        n_test = max(1, round(n * test_fraction))
        assignment.update({u: "test" for u in members[:n_test]})
        rest = members[n_test:]
        if kind == "cv5":
            for k, unit in enumerate(rest):
                assignment[unit] = (fold_offset + k) % num_folds
            fold_offset += len(rest)
        else:
            n_val = max(1, round(n * val_fraction))
            assignment.update({u: "val" for u in rest[:n_val]})
            assignment.update({u: "train" for u in rest[n_val:]})
    return assignment


def make_splits(
    labels: Sequence[str],
    kind: str,
    *,
    groups: Sequence[str] | None = None,
    seed: int = 0,
    rare_classes: str = "drop",
    val_fraction: float = 0.15,
    test_fraction: float = 0.15,
    num_folds: int = 5,
) -> SplitResult:
    """Split samples with string ``labels`` (and, for ``gloss``, their ``groups`` = glosses)."""
    if kind not in SPLIT_KINDS:
        raise DataError(f"unknown split {kind!r}; expected one of {SPLIT_KINDS}")
    if rare_classes not in RARE_RULES:
        raise DataError(f"unknown rare_classes rule {rare_classes!r}; expected one of {RARE_RULES}")
    labels = [str(label) for label in labels]
    units = _units(labels, groups if kind == "gloss" else None)  # unit -> (label, sample indices)
    labels_by_unit = {unit: label for unit, (label, _) in units.items()}
    needed = min_units(kind, num_folds)

    counts = _count(labels_by_unit)
    rare = {label: n for label, n in sorted(counts.items()) if n < needed}
    if rare:
        log.info("%s split: %d label(s) with < %d %s -> %s: %s", kind, len(rare), needed,
                 "glosses" if kind == "gloss" else "clips", rare_classes, rare)  # fmt: skip
    labels_by_unit = _apply_rare_rule(labels_by_unit, rare, rare_classes, needed)
    train_only = set(rare) if rare_classes == "train_only" else set()

    if not labels_by_unit:
        raise DataError(f"{kind} split: no label has the {needed} units needed; labels: {dict(counts)}")
    label_names = sorted(set(labels_by_unit.values()))
    keep = np.array(sorted(i for u in labels_by_unit for i in units[u][1]), dtype=np.int64)
    position = {int(sample): pos for pos, sample in enumerate(keep)}
    label_id = {name: i for i, name in enumerate(label_names)}
    y = np.empty(len(keep), dtype=np.int64)
    for unit, label in labels_by_unit.items():
        for sample in units[unit][1]:
            y[position[sample]] = label_id[label]

    assignment = _assign_units(labels_by_unit, label_names, kind, seed, train_only, val_fraction, test_fraction,
                               num_folds)

    def positions(wanted) -> np.ndarray:
        chosen = [position[i] for u, where in assignment.items() if where in wanted for i in units[u][1]]
        return np.array(sorted(chosen), dtype=np.int64)

    splits: dict[str, object] = {"test": positions({"test"})}
    if kind == "cv5":
        folds = []
        for k in range(num_folds):
            others = {"train", *(f for f in range(num_folds) if f != k)}
            folds.append((positions(others), positions({k})))
        splits["folds"] = folds
        splits["train"], splits["val"] = folds[0]
        splits["train+val"] = positions({"train", *range(num_folds)})
    else:
        splits["train"], splits["val"] = positions({"train"}), positions({"val"})
        splits["train+val"] = positions({"train", "val"})
    dropped = len(labels) - len(keep)
    if dropped:
        log.info("%s split: %d of %d clips dropped by the rare-class rule", kind, dropped, len(labels))
    return SplitResult(keep=keep, y=y, label_names=label_names, splits=splits, rare=rare,
                       rare_rule=rare_classes, dropped=dropped)  # fmt: skip


def _units(labels: list[str], groups: Sequence[str] | None) -> dict[object, tuple[str, list[int]]]:
    if groups is None:
        return {i: (label, [i]) for i, label in enumerate(labels)}
    if len(groups) != len(labels):
        raise DataError(f"{len(groups)} groups for {len(labels)} labels")
    units: dict[object, tuple[str, list[int]]] = {}
    for i, (label, group) in enumerate(zip(labels, groups)):
        known = units.setdefault(str(group), (label, []))
        if known[0] != label:
            raise DataError(f"gloss {group!r} has clips with labels {known[0]!r} and {label!r}; "
                            "a gloss split needs one label per gloss")  # fmt: skip
        known[1].append(i)
    return units


def _count(labels_by_unit: dict) -> dict[str, int]:
    counts: dict[str, int] = defaultdict(int)
    for label in labels_by_unit.values():
        counts[label] += 1
    return dict(counts)


def one_per_group(groups: Sequence[str], seed: int) -> np.ndarray:
    """Ascending indices of one sample per group (gloss), chosen at random with ``seed``: the
    thesis' chapter-3 set had one video per lemma, so no sign is in two splits."""
    rng = np.random.default_rng(seed)
    members: dict[str, list[int]] = defaultdict(list)
    for index, group in enumerate(groups):
        members[str(group)].append(index)
    return np.array(sorted(int(rng.choice(members[g])) for g in sorted(members)), dtype=np.int64)


@dataclass(frozen=True)
class SplitOptions(Section):
    """How to split a built dataset again (the ``split`` config group): ``repeats`` independent
    seeded splits (seeds ``seed`` .. ``seed + repeats - 1``), optionally on one clip per gloss."""

    SECTION = "split"

    name: str = field(default="phoneme", metadata=key(Choice(*SPLIT_KINDS)))
    seed: int = 0
    repeats: int = field(default=1, metadata=key(Int(1)))
    one_clip_per_gloss: bool = False
    rare_classes: str = "drop"
    val_fraction: float = 0.15
    test_fraction: float = 0.15
    num_folds: int = 5

    @property
    def rebuilds(self) -> bool:
        """False when the dataset's own (built) split is the one split to use."""
        return int(self.repeats) > 1 or bool(self.one_clip_per_gloss)


def resplit(labels: Sequence[str], groups: Sequence[str], options: SplitOptions, seed: int) -> SplitResult:
    """One split of samples with string ``labels`` and ``groups`` (glosses) by ``options`` with
    ``seed``; ``keep`` indexes the input samples (after the one-clip-per-gloss choice, if any)."""
    chosen = one_per_group(groups, seed) if options.one_clip_per_gloss else np.arange(len(labels))
    result = make_splits(
        [labels[i] for i in chosen], options.name, groups=[groups[i] for i in chosen], seed=seed,
        rare_classes=options.rare_classes, val_fraction=options.val_fraction,
        test_fraction=options.test_fraction, num_folds=options.num_folds,
    )
    result.keep = chosen[result.keep]
    result.dropped = len(labels) - len(result.keep)
    return result
