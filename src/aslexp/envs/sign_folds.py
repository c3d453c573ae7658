"""Real signs as a training pool, folded by gloss (``train_motions.folder``: conf/train_motions/wlasl_signs.yaml).

What for: one upper-body policy trained on many real signs and scored on signs it never saw. A folder
that ``aslexp extract --motions --wlasl WLASL_v0.3.json`` wrote holds one upper-body motion per clip
(``motions/upper_body/<video_id>.txt``) and its report (``motions/reports/<video_id>.json``: the gloss
in ``pose_array.gloss``, ``upper_body.plausibility``). The thesis' signs (``conf/motion`` names, WLASL
video ids too) may join them with their glosses. The glosses are sorted, shuffled by the seed and dealt
round-robin into K folds (:func:`gloss_folds`): fold k's test set is its glosses, its training pool every
plausible motion of any other gloss, so no sign of a test gloss is ever trained on. With validation
motions asked for, fold k+1's glosses (or those of the thesis' other signs) are taken out of the pool too
and some of their motions score the policy during training (a checkpoint is chosen on glosses that
neither train nor test). The run's own motion picks its fold (``fold: null``) and its gloss is always
a test gloss. Motions their report marks implausible (a tracking jump, arms out of view) are left out
and counted.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aslexp.errors import ConfigError, DataError


@dataclass(frozen=True)
class SignClip:
    """One sign's motion: its name (the WLASL video id), gloss, file and whether it is plausible."""

    name: str
    gloss: str | None
    file: Path
    plausible: bool = True
    reasons: tuple[str, ...] = ()  # why not plausible (the report's plausibility reasons)
    thesis: bool = False  # one of the thesis' signs (conf/motion), not the folder's


def reports_folder(folder: Path) -> Path:
    """The reports of an ``aslexp extract --motions`` output folder (``DIR`` or ``DIR/motions``)."""
    for reports in (folder / "motions" / "reports", folder / "reports"):
        if reports.is_dir():
            return reports
    raise DataError(f"train_motions.folder={folder}: no motions/reports/ in it; expected a folder that "
                    f"`aslexp extract --motions --wlasl WLASL_v0.3.json` wrote")


def read_sign_folder(folder: Path, gloss_of=None) -> list[SignClip]:
    """Every upper-body motion of ``folder`` (its reports, sorted by name), plausible or not.
    ``gloss_of(name)``: the gloss of a clip whose report names none (a video's, extracted without a
    pose array); without it such a report is an error."""
    reports = reports_folder(folder)
    motions = reports.parent / "upper_body"
    clips = []
    for path in sorted(reports.glob("*.json")):
        try:
            report = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as err:
            raise DataError(f"{path}: not a readable JSON report ({err})") from None
        body = report.get("upper_body") or {}
        if body.get("status") != "ok":
            continue  # no upper-body motion was written for this clip
        gloss = (report.get("pose_array") or {}).get("gloss") or (gloss_of(path.stem) if gloss_of else None)
        if not gloss:
            raise DataError(f"{path}: pose_array.gloss: expected the clip's gloss (extract with --wlasl "
                            f"WLASL_v0.3.json)")
        file = motions / f"{path.stem}.txt"
        if not file.is_file():
            raise DataError(f"{path}: upper_body: expected its motion {file}, which is missing")
        plausibility = body.get("plausibility") or {}
        clips.append(SignClip(path.stem, str(gloss), file, bool(plausibility.get("plausible", True)),
                              tuple(plausibility.get("reasons") or ())))
    if not clips:
        raise DataError(f"train_motions.folder={folder}: no upper-body motion in {reports}")
    return clips


def gloss_folds(glosses, folds: int, seed: int) -> dict[str, int]:
    """Each gloss's fold: the sorted glosses shuffled by ``seed``, dealt round-robin into ``folds``."""
    ordered = sorted(set(glosses))
    if not 2 <= folds <= len(ordered):
        raise ConfigError(f"train_motions.folds={folds}: expected 2 to {len(ordered)} (the number of glosses)")
    order = np.random.default_rng(seed).permutation(len(ordered))
    return {ordered[j]: position % folds for position, j in enumerate(order)}


@dataclass(frozen=True)
class SignFold:
    """One fold's training pool and what a run folder records of it (:meth:`summary`)."""

    train: list[SignClip]
    test_glosses: list[str]
    implausible: list[SignClip]  # of the training glosses: left out of the pool
    fold: int
    folds: int
    seed: int
    folder: str
    held_out: str | None = None  # the run's own motion, if it is one of the clips
    held_out_gloss: str | None = None
    folder_implausible: int = 0  # implausible motions in the whole folder
    assignment: dict[str, int] = field(default_factory=dict)
    validation: list[SignClip] = field(default_factory=list)  # of the validation glosses: scored, never trained
    validation_glosses: list[str] = field(default_factory=list)

    def summary(self) -> dict:
        return {"folder": self.folder, "folds": self.folds, "fold": self.fold, "seed": self.seed,
                "held_out": self.held_out, "held_out_gloss": self.held_out_gloss,
                "test_glosses": self.test_glosses, "glosses": sorted({c.gloss for c in self.train}),
                "motions": [c.name for c in self.train], "thesis_signs": [c.name for c in self.train if c.thesis],
                "implausible_left_out": {"count": len(self.implausible),
                                         "motions": {c.name: list(c.reasons) for c in self.implausible}},
                "implausible_in_folder": self.folder_implausible, "gloss_folds": self.assignment,
                **({"validation_glosses": self.validation_glosses,
                    "validation_motions": [c.name for c in self.validation]} if self.validation else {})}


def fold_pool(clips: list[SignClip], folds: int, fold: int | None, seed: int, folder: str,
              evaluated: Path | None = None, validation_motions: int = 0,
              validation_from: str = "next_fold") -> SignFold:
    """Fold ``fold`` of ``clips`` (None: the fold of ``evaluated``'s gloss). ``evaluated``: the run's
    motion file; a clip of that name or file, and every clip of its gloss, is never in the pool.
    ``validation_motions``: that many plausible clips validate, of fold ``fold + 1``'s glosses (one gloss
    after another, drawn by ``seed``) or, ``validation_from="thesis_signs"``, the thesis' signs outside
    the test glosses (by name); every clip of those glosses leaves the pool."""
    assignment = gloss_folds([c.gloss for c in clips], folds, seed)
    own = None
    if evaluated is not None:
        target = Path(evaluated).resolve()
        own = next((c for c in clips if c.file.resolve() == target), None) or \
            next((c for c in clips if c.name == Path(evaluated).stem), None)
    if fold is None:
        if own is None:
            raise ConfigError(f"train_motions.fold=null: it takes the fold of the run's motion's gloss, but "
                              f"{evaluated} is no sign of the pool (a thesis sign joins it with "
                              f"include_thesis_signs); expected a fold 0-{folds - 1}")
        fold = assignment[own.gloss]
    if not 0 <= fold < folds:
        raise ConfigError(f"train_motions.fold={fold}: expected 0 to {folds - 1} (train_motions.folds={folds})")
    test = sorted({g for g, k in assignment.items() if k == fold} | ({own.gloss} if own else set()))
    if validation_from == "thesis_signs":
        validation = sorted((c for c in clips if c.thesis and c is not own and c.gloss not in test),
                            key=lambda c: c.name)[:validation_motions]
        held = sorted({str(c.gloss) for c in validation})
        if validation_motions and not validation:
            raise ConfigError(f"train_motions.validation_from=thesis_signs: no thesis sign outside the test glosses "
                              f"{test} to validate on; expected include_thesis_signs: true and a thesis sign in another fold")
    else:
        held = sorted({g for g, k in assignment.items() if k == (fold + 1) % folds} - set(test)) \
            if validation_motions else []
        validation = validation_clips([c for c in clips if c.gloss in held and c.plausible and c is not own],
                                      validation_motions, seed)
        if validation_motions and not validation:
            raise ConfigError(f"train_motions.validation_motions={validation_motions}: fold {(fold + 1) % folds}'s "
                              f"glosses {held} have no plausible motion to validate on")
    kept = [c for c in clips if c.gloss not in test and c.gloss not in held and c is not own]
    if not any(c.plausible for c in kept):
        raise ConfigError(f"train_motions: fold {fold} of {folds} leaves no plausible motion to train on")
    return SignFold(train=[c for c in kept if c.plausible], test_glosses=test,
                    implausible=[c for c in kept if not c.plausible], fold=fold, folds=folds, seed=seed,
                    folder=folder, held_out=own.name if own else None, held_out_gloss=own.gloss if own else None,
                    folder_implausible=sum(not c.plausible for c in clips), assignment=dict(sorted(assignment.items())),
                    validation=validation, validation_glosses=held)


def validation_clips(clips: list[SignClip], count: int, seed: int) -> list[SignClip]:
    """``count`` of ``clips``, the glosses taken in turn (each gloss's clips and the glosses' order
    shuffled by ``seed``), so a few motions still span many glosses; sorted by name."""
    if not count:
        return []
    rng = np.random.default_rng(seed)
    by_gloss: dict[str, list[SignClip]] = {}
    for clip in clips:
        by_gloss.setdefault(str(clip.gloss), []).append(clip)
    queues = [[group[i] for i in rng.permutation(len(group))] for _, group in sorted(by_gloss.items())]
    queues = [queues[i] for i in rng.permutation(len(queues))]
    chosen: list[SignClip] = []
    while len(chosen) < count and any(queues):
        for queue in queues:
            if queue and len(chosen) < count:
                chosen.append(queue.pop(0))
    return sorted(chosen, key=lambda c: c.name)


def with_thesis_signs(clips: list[SignClip], thesis: Mapping[str, tuple[str, Path]]) -> list[SignClip]:
    """``clips`` and the thesis' signs (name -> (gloss, file)); a thesis sign stands for the folder's
    clip of the same video id (the thesis' own retargeting of it), never both."""
    theirs = [SignClip(name, gloss, Path(file), thesis=True) for name, (gloss, file) in thesis.items()]
    names = {c.name for c in theirs}
    return sorted([c for c in clips if c.name not in names] + theirs, key=lambda c: c.name)
