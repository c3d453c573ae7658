"""Which clip each keypoint file holds: file names -> WLASL video ids, or -> glosses.

``pose.options.names`` (popped by the builder before the source is opened, so it works with every
source):

- ``null`` (default): files are named by WLASL ``video_id`` (``<video_id>.npy``, e.g.
  ``63185.npy``); the gloss, signer and split come from ``wlasl/WLASL_v0.3.json``. Files that
  match no video id are skipped, counted (``keypoints_not_in_wlasl``) and named in one warning;
  when *none* matches, the build stops with one line saying how many, a few names, the naming
  expected and the remedies (a hint too when the names look like glosses or like the YouTube ids
  of WLASL's urls).
- ``gloss``: files named ``<gloss>.npy`` or ``<gloss>_<n>.npy`` (``book.npy``, ``book_2.npy``,
  ``thank_you_3.npy``). The name's key is the project's gloss key (:func:`normalise_gloss`:
  lower-case, one trailing ``_<digits>`` dropped, ``_`` -> space), so matching to ASL-LEX is
  case-insensitive and follows the same rule as WLASL's glosses (including the choice among
  several rows, e.g. ``candy`` -> ``candy_1``): the ``_<n>`` suffix is always a clip number,
  never an ASL-LEX EntryID suffix. **Each file is its own clip** with that gloss's labels (WLASL
  has several videos per gloss; a gloss-named file is none of them in particular): its clip id is
  the file name (``book_2``), its gloss the WLASL spelling when one matches the key (else the key),
  its signer unknown (-1). Files whose gloss has no ASL-LEX row are skipped, counted
  (``gloss_not_in_lexicon``) and named in one warning.
- ``FILE.csv``: a mapping with the header ``file,video_id`` (a WLASL clip per file) or
  ``file,gloss`` (as ``gloss`` above, the gloss from the CSV). ``file`` is the file name with or
  without its suffix. Folder files without a row are skipped (``keypoints_not_named``) and named in
  a warning; rows naming absent files are named in a warning; a file given twice, or two files
  given one video id, is an error naming the CSV line.
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path

from aslexp.data.matching import normalise_gloss
from aslexp.data.wlasl import WLASL_JSON, Wlasl, WlaslInstance
from aslexp.errors import DataError

NAMES_GLOSS = "gloss"
CSV_KINDS = ("video_id", "gloss")
EXAMPLE_VIDEO_ID = "63185"
EXAMPLES = 3
_YOUTUBE = re.compile(r"(?:[?&]v=|youtu\.be/|/embed/|/v/)([A-Za-z0-9_-]{11})")


@dataclass
class ClipFiles:
    """The clips a keypoint source holds: (WLASL instance, or one made for a gloss-named file;
    the id the source loads it by), the skip counts of naming, and warning lines."""

    clips: list[tuple[WlaslInstance, str]]
    skipped: dict[str, int] = field(default_factory=dict)
    warnings: list[str] = field(default_factory=list)


def _spread(stems, limit: int = EXAMPLES) -> list[str]:
    """Up to ``limit`` of ``stems``, spread over their sorted order (first, middle, last)."""
    stems = sorted(stems)
    if len(stems) <= limit:
        return stems
    return [stems[round(i * (len(stems) - 1) / (limit - 1))] for i in range(limit)]


def _shown(stems, suffix: str, limit: int = EXAMPLES) -> str:
    text = ", ".join(f"{s}{suffix}" for s in _spread(stems, limit))
    return text + (", ..." if len(stems) > limit else "")


def youtube_ids(wlasl: Wlasl) -> dict[str, list[str]]:
    """YouTube id -> the WLASL video ids cut from that YouTube video."""
    ids: dict[str, list[str]] = {}
    for instance in wlasl.instances:
        match = _YOUTUBE.search(instance.url)
        if match:
            ids.setdefault(match.group(1), []).append(instance.video_id)
    return ids


def _gloss_instance(stem: str, gloss: str, number: int) -> WlaslInstance:
    return WlaslInstance(gloss=gloss, video_id=stem, split="", signer_id=-1, fps=0, frame_start=1,
                         frame_end=-1, bbox=(), url="", instance_id=number, variation_id=-1,
                         source="file name")  # fmt: skip


def resolve_clip_files(available: set[str], names, wlasl: Wlasl, lexicon_keys: dict, *, where: str,
                       suffix: str = ".npy", lexicon_name: str = "ASL-LEX") -> ClipFiles:  # fmt: skip
    """The clips of a source whose files (ids without suffix) are ``available``, named as
    ``names`` says (module docstring). ``lexicon_keys``: gloss key -> lexicon rows
    (:func:`aslexp.data.matching.lexicon_keys`). ``where`` names the folder in messages."""
    expected = f"<video_id>{suffix} with the video_id of {WLASL_JSON}, e.g. {EXAMPLE_VIDEO_ID}{suffix}"
    if not available:
        raise DataError(f"{where}: no keypoint files found; expected {expected}")
    if names in (None, ""):
        return _by_video_id(available, wlasl, lexicon_keys, where, suffix, expected, lexicon_name)
    if names == NAMES_GLOSS:
        pairs = {stem: stem for stem in available}
        return _by_gloss(pairs, wlasl, lexicon_keys, where, suffix, lexicon_name, "pose.options.names=gloss")
    if not isinstance(names, (str, Path)):
        raise DataError(f"pose.options.names = {names!r}; expected null (files named <video_id>{suffix}), "
                        "'gloss' or a CSV file with the header file,video_id or file,gloss")  # fmt: skip
    kind, mapping = read_names_csv(Path(names), suffix)
    missing = sorted(set(mapping) - available)
    unnamed = available - set(mapping)
    warnings = []
    if missing:
        warnings.append(f"{names}: {len(missing)} of its {len(mapping)} rows name files that are not in "
                        f"{where} (e.g. {_shown(missing, suffix)})")  # fmt: skip
    if unnamed:
        warnings.append(f"{where}: {len(unnamed)} of its {len(available)} files have no row in {names} and are "
                        f"skipped (e.g. {_shown(unnamed, suffix)})")  # fmt: skip
    present = {stem: value for stem, value in mapping.items() if stem in available}
    if not present:
        raise DataError(f"{names}: none of its {len(mapping)} rows names a file of {where} (rows e.g. "
                        f"{_shown(mapping, suffix)}; files e.g. {_shown(available, suffix)})")  # fmt: skip
    if kind == "gloss":
        result = _by_gloss(present, wlasl, lexicon_keys, where, suffix, lexicon_name, f"{names} (file,gloss)")
    else:
        by_id = wlasl.by_video_id()
        file_of = {value: stem for stem, value in present.items()}
        unknown = sorted(stem for stem, value in present.items() if value not in by_id)
        zeros = ""
        if any(present[s].isdigit() and present[s].zfill(5) in by_id for s in unknown):
            zeros = "; WLASL video ids keep their leading zeros (01457, not 1457: a spreadsheet may drop them)"
        if len(unknown) == len(present):
            raise DataError(f"{names}: none of the {len(present)} video ids it gives is a WLASL video_id (e.g. "
                            f"{', '.join(present[s] for s in _spread(unknown))}); expected the video_id of "
                            f"{WLASL_JSON}, e.g. {EXAMPLE_VIDEO_ID}{zeros}")  # fmt: skip
        if unknown:
            examples = ", ".join(f"{s}{suffix} -> {present[s]}" for s in _spread(unknown))
            warnings.append(f"{names}: {len(unknown)} of its files are given a video_id that is not in {WLASL_JSON} "
                            f"and are skipped (e.g. {examples}){zeros}")  # fmt: skip
        result = ClipFiles(
            clips=[(i, file_of[i.video_id]) for i in wlasl.instances if i.video_id in file_of],
            skipped={"no_keypoints": len(by_id) - (len(present) - len(unknown)),
                     "keypoints_not_in_wlasl": len(unknown)},  # fmt: skip
        )
    result.skipped["keypoints_not_named"] = len(unnamed)
    result.warnings[:0] = warnings
    return result


def _by_video_id(available, wlasl, lexicon_keys, where, suffix, expected, lexicon_name) -> ClipFiles:
    by_id = wlasl.by_video_id()
    unmatched = sorted(available - by_id.keys())
    clips = [(i, i.video_id) for i in wlasl.instances if i.video_id in available]
    if not clips:
        raise DataError(f"{where}: none of its {len(available)} keypoint files is named by a WLASL video id "
                        f"(e.g. {_shown(unmatched, suffix)}); expected {expected}; "
                        f"{_remedy(unmatched, wlasl, lexicon_keys, suffix, lexicon_name)}")  # fmt: skip
    warnings = []
    if unmatched:
        warnings.append(f"{where}: {len(unmatched)} of its {len(available)} keypoint files match no WLASL video id "
                        f"and are skipped (e.g. {_shown(unmatched, suffix)}); expected {expected}")  # fmt: skip
    return ClipFiles(clips=clips, warnings=warnings,
                     skipped={"no_keypoints": len(by_id) - len(clips), "keypoints_not_in_wlasl": len(unmatched)})


def _remedy(stems, wlasl, lexicon_keys, suffix, lexicon_name) -> str:
    """What to do about files named by no video id, led by what the names look like."""
    csv_any = "map them with pose.options.names=FILE.csv (header file,video_id or file,gloss)"
    tube = youtube_ids(wlasl)
    on_youtube = [s for s in stems if s in tube]
    glossy = [s for s in stems if normalise_gloss(s) in lexicon_keys]
    if on_youtube and len(on_youtube) >= len(glossy):
        shared = sum(1 for s in on_youtube if len(tube[s]) > 1)
        return (f"{len(on_youtube)} of them are YouTube ids of WLASL urls, and one YouTube video can hold several "
                f"WLASL clips ({shared} of these do, each clip its own frame range and video_id): say which clip "
                "each file holds in a CSV, pose.options.names=FILE.csv with the header file,video_id, or rename "
                f"each file to its clip's <video_id>{suffix}")  # fmt: skip
    if glossy:
        examples = ", ".join(f"{s}{suffix} -> {normalise_gloss(s)!r}" for s in _spread(glossy))
        return (f"{len(glossy)} of them name {lexicon_name} glosses ({examples}): set pose.options.names=gloss to "
                f"read <gloss>{suffix} and <gloss>_<n>{suffix} as clips of that gloss, or rename them to "
                f"<video_id>{suffix}, or {csv_any}")  # fmt: skip
    return (f"rename them to <video_id>{suffix}, {csv_any}, or set pose.options.names=gloss for files named "
            f"<gloss>{suffix} or <gloss>_<n>{suffix}")


def _by_gloss(pairs: dict[str, str], wlasl, lexicon_keys, where, suffix, lexicon_name, how) -> ClipFiles:
    """``pairs``: file id -> its gloss name (the file name itself, or a CSV's gloss)."""
    spelling = {}
    for gloss in wlasl.glosses:
        spelling.setdefault(normalise_gloss(gloss), gloss)
    clips, unmatched = [], []
    for number, stem in enumerate(sorted(pairs)):
        key = normalise_gloss(pairs[stem])
        if key not in lexicon_keys:
            unmatched.append(stem)
        clips.append((_gloss_instance(stem, spelling.get(key, key), number), stem))
    def shown(stems):
        return ", ".join(f"{s}{suffix} -> {normalise_gloss(pairs[s])!r}" for s in _spread(stems))
    if len(unmatched) == len(pairs):
        raise DataError(f"{where}: none of its {len(pairs)} files names a gloss of {lexicon_name} ({how}: "
                        f"<gloss>{suffix} or <gloss>_<n>{suffix}, matched case-insensitively; e.g. "
                        f"{shown(unmatched)}); files named by WLASL video id need no pose.options.names")  # fmt: skip
    warnings = []
    if unmatched:
        warnings.append(f"{where}: {len(unmatched)} of its {len(pairs)} gloss-named files name no {lexicon_name} "
                        f"gloss and are skipped (e.g. {shown(unmatched)})")  # fmt: skip
    return ClipFiles(clips=clips, warnings=warnings, skipped={"no_keypoints": 0, "keypoints_not_in_wlasl": 0})


def read_names_csv(path: Path, suffix: str = ".npy") -> tuple[str, dict[str, str]]:
    """A names CSV: (``"video_id"`` or ``"gloss"``, {file id: value}). Mistakes are one line
    naming the CSV, the line and what was expected."""
    if not path.is_file():
        raise FileNotFoundError(f"pose.options.names: mapping file not found: {path} (expected a CSV with the "
                                "header file,video_id or file,gloss, or 'gloss')")  # fmt: skip
    try:
        with open(path, newline="", encoding="utf-8-sig") as handle:
            rows = list(csv.reader(handle))
    except (UnicodeDecodeError, csv.Error) as error:
        raise DataError(f"{path}: not a UTF-8 CSV ({error}); expected the header file,video_id or file,gloss") from None
    header = [h.strip().lower() for h in rows[0]] if rows else []
    kinds = [k for k in CSV_KINDS if k in header]
    if "file" not in header or len(kinds) != 1:
        raise DataError(f"{path}: header {rows[0] if rows else []}; expected the columns file,video_id (a WLASL "
                        "clip per file) or file,gloss (a gloss per file), one of video_id and gloss")  # fmt: skip
    kind = kinds[0]
    col_file, col_value = header.index("file"), header.index(kind)
    mapping: dict[str, str] = {}
    line_of: dict[str, int] = {}
    given: dict[str, tuple[str, int]] = {}
    for number, row in enumerate(rows[1:], start=2):
        if not any(cell.strip() for cell in row):
            continue
        cells = [row[i].strip() if i < len(row) else "" for i in (col_file, col_value)]
        if not all(cells):
            raise DataError(f"{path}: line {number}: {row}; expected a file name and a {kind}")
        stem, value = cells
        if suffix and stem.lower().endswith(suffix):
            stem = stem[: -len(suffix)]
        if stem in mapping:
            raise DataError(f"{path}: line {number}: file {stem}{suffix} is already given on line {line_of[stem]}")
        if kind == "video_id":
            if value in given:
                raise DataError(f"{path}: line {number}: video_id {value} is already given to file "
                                f"{given[value][0]}{suffix} on line {given[value][1]} (one file per clip)")  # fmt: skip
            given[value] = (stem, number)
        mapping[stem], line_of[stem] = value, number
    if not mapping:
        raise DataError(f"{path}: no rows after the header; expected one row per file: file,{kind}")
    return kind, mapping
