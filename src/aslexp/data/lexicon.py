"""ASL-LEX 1.0 and 2.0: sign entries and their six phonological properties.

Both versions are mapped to the same six canonical properties (``PROPERTIES``). Each version has
a fixed value vocabulary per property (``LexiconSpec.vocab``); a value outside it is an error,
never a new class, so a changed or corrupted file is noticed.

Missing values. A blank cell or ``NA`` is *missing* (the clip is skipped for that property),
never a class. ``None`` in the Movement column is *a real value*: it means "no path movement".
Evidence: the lexicons' own frequency columns count it as a category (1.0:
``MovementFrequency`` = 180 on 175 of the 178 'None' rows; 2.0: ``Movement.2.0Frequency`` = 0.153 =
417/2723 on all 417 'None' rows), whereas 2.0's ``Flexion.2.0`` = ``NA`` has frequency 0 and
occurs exactly on the 156 thumb-only signs (``SelectedFingers.2.0`` = 't'), where finger flexion
does not apply. Readers that parse with pandas defaults turn 'None' into NaN (which is why some
descriptions count "178 blank" movements in 1.0); ``movement_none_as_missing=True`` reproduces
that reading when a comparison with such work needs it.
"""

from __future__ import annotations

import csv
import logging
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

from aslexp.data.dataset import DataError
from aslexp.data.root import resolve_data_root

log = logging.getLogger(__name__)

PROPERTIES: tuple[str, ...] = (
    "sign_type",
    "major_location",
    "minor_location",
    "selected_fingers",
    "flexion",
    "movement",
)

MISSING_VALUES = frozenset({"", "NA"})
# The signs' subjective frequency, z-scored over raters (both versions; 2.0: every one of its 2,723
# signs has one). Read into LexiconEntry.frequency_z when the file has the column (None otherwise).
FREQUENCY_COLUMN = "SignFrequency(Z)"

_MINOR_LOCATIONS_1 = (
    "CheekNose", "Chin", "Clavicle", "ElbowBack", "ElbowFront", "Eye", "FingerBack",
    "FingerFront", "FingerRadial", "FingerTip", "FingerUlnar", "ForearmBack", "ForearmFront",
    "ForearmUlnar", "Forehead", "HeadTop", "Heel", "Hips", "Mouth", "Neck", "Neutral", "Other",
    "Palm", "PalmBack", "Shoulder", "TorsoBottom", "TorsoMid", "TorsoTop", "UnderChin",
    "UpperArm", "UpperLip", "Waist", "WristBack",
)  # fmt: skip
_MINOR_LOCATIONS_2 = tuple(
    sorted(
        (set(_MINOR_LOCATIONS_1) - {"ElbowFront"})
        | {"ArmAway", "BodyAway", "HandAway", "HeadAway", "WristFront"}
    )
)


@dataclass(frozen=True)
class LexiconSpec:
    """Where a lexicon version lives and how its columns map to the canonical properties."""

    name: str
    relpath: str
    columns: dict[str, str]  # canonical property -> column in the file
    vocab: dict[str, tuple[str, ...]]  # canonical property -> allowed (non-missing) values


ASLLEX1 = LexiconSpec(
    name="asllex1",
    relpath="asl-lex/1.0/SignData.csv",
    columns={
        "sign_type": "SignType",
        "major_location": "MajorLocation",
        "minor_location": "MinorLocation",
        "selected_fingers": "SelectedFingers",
        "flexion": "Flexion",
        "movement": "Movement",
    },
    vocab={
        "sign_type": (
            "AsymmetricalDifferentHandshape", "AsymmetricalSameHandshape", "OneHanded",
            "Other", "SymmetricalOrAlternating",
        ),
        "major_location": ("Arm", "Body", "Hand", "Head", "Neutral", "Other"),
        "minor_location": _MINOR_LOCATIONS_1,
        "selected_fingers": ("i", "im", "imr", "imrp", "ip", "m", "mr", "mrp", "p", "thumb"),
        # 1.0 codes flexion 1..7 (1 fully open ... 7 fully closed) plus Crossed and Stacked.
        "flexion": ("1", "2", "3", "4", "5", "6", "7", "Crossed", "Stacked"),
        "movement": ("BackAndForth", "Circular", "Curved", "None", "Other", "Straight"),
    },
)  # fmt: skip

ASLLEX2 = LexiconSpec(
    name="asllex2",
    relpath="asl-lex/2.0/signdata-11-5-20.csv",
    columns={
        "sign_type": "SignType.2.0",
        "major_location": "MajorLocation.2.0",
        "minor_location": "MinorLocation.2.0",
        "selected_fingers": "SelectedFingers.2.0",
        "flexion": "Flexion.2.0",
        "movement": "Movement.2.0",
    },
    vocab={
        "sign_type": (
            "AsymmetricalDifferentHandshape", "AsymmetricalSameHandshape", "DominanceViolation",
            "OneHanded", "SymmetricalOrAlternating", "SymmetryViolation",
        ),
        "major_location": ("Arm", "Body", "Hand", "Head", "Neutral", "Other"),
        "minor_location": _MINOR_LOCATIONS_2,
        "selected_fingers": (
            "i", "im", "imp", "imr", "imrp", "ip", "m", "mr", "mrp", "p", "r", "t",
        ),
        "flexion": ("Bent", "Crossed", "Curved", "Flat", "FullyClosed", "FullyOpen", "Stacked"),
        "movement": (
            "BackAndForth", "Circular", "Curved", "None", "Other", "Straight", "X-shaped",
            "Z-shaped",
        ),
    },
)  # fmt: skip

LEXICONS: dict[str, LexiconSpec] = {spec.name: spec for spec in (ASLLEX1, ASLLEX2)}


@dataclass(frozen=True)
class LexiconEntry:
    """One row of a lexicon. ``properties`` maps each canonical property to a value or None."""

    entry_id: str
    lemma_id: str
    row: int  # 0-based data row in file order (the header is not counted)
    properties: dict[str, str | None]
    frequency_z: float | None = None  # SignFrequency(Z); None where blank/NA or the file has no such column


@dataclass(frozen=True)
class Lexicon:
    name: str
    path: Path
    entries: tuple[LexiconEntry, ...]

    def __len__(self) -> int:
        return len(self.entries)

    @property
    def spec(self) -> LexiconSpec:
        return LEXICONS[self.name]

    def vocabulary(self, prop: str) -> tuple[str, ...]:
        return self.spec.vocab[check_property(prop)]

    def value_counts(self, prop: str) -> Counter:
        """Counts of each value of ``prop``; missing values are counted under None."""
        check_property(prop)
        return Counter(entry.properties[prop] for entry in self.entries)


def check_property(prop: str) -> str:
    if prop not in PROPERTIES:
        raise DataError(f"unknown phonological property {prop!r}; expected one of {PROPERTIES}")
    return prop


def lexicon_spec(name: str) -> LexiconSpec:
    try:
        return LEXICONS[name]
    except KeyError:
        raise DataError(f"unknown lexicon {name!r}; expected one of {sorted(LEXICONS)}") from None


def load_lexicon(
    name: str,
    root: str | Path | None = None,
    *,
    path: str | Path | None = None,
    movement_none_as_missing: bool = False,
) -> Lexicon:
    """Read ASL-LEX ``name`` ('asllex1' | 'asllex2') from the data root (or an explicit ``path``).

    Returns a :class:`Lexicon` whose entries carry the six canonical properties. Raises
    :class:`DataError` naming the file, the EntryID, the column and the allowed values when a
    value is outside the version's vocabulary, and FileNotFoundError naming a missing file.
    """
    spec = lexicon_spec(name)
    csv_path = Path(path) if path is not None else resolve_data_root(root) / spec.relpath
    if not csv_path.is_file():
        raise FileNotFoundError(f"{spec.name}: lexicon file not found: {csv_path}")
    # utf-8-sig strips the BOM of the 2.0 file and is a no-op for 1.0.
    with csv_path.open(newline="", encoding="utf-8-sig") as handle:
        reader = csv.DictReader(handle)
        header = reader.fieldnames or []
        needed = ["EntryID", "LemmaID", *spec.columns.values()]
        absent = [column for column in needed if column not in header]
        if absent:
            raise DataError(f"{csv_path}: missing column(s) {absent}; expected {needed}")
        entries = tuple(_parse_row(spec, csv_path, i, row, movement_none_as_missing)
                        for i, row in enumerate(reader))  # fmt: skip
    lexicon = Lexicon(name=spec.name, path=csv_path, entries=entries)
    missing = {p: lexicon.value_counts(p).get(None, 0) for p in PROPERTIES}
    log.info("%s: %d signs from %s; missing values per property: %s",
             spec.name, len(entries), csv_path, missing)  # fmt: skip
    return lexicon


def _parse_row(
    spec: LexiconSpec, csv_path: Path, index: int, row: dict, movement_none_as_missing: bool
) -> LexiconEntry:
    entry_id = (row["EntryID"] or "").strip()
    if not entry_id:
        raise DataError(f"{csv_path}: data row {index + 1} has an empty EntryID")
    properties: dict[str, str | None] = {}
    for prop, column in spec.columns.items():
        value = (row[column] or "").strip()
        if value in MISSING_VALUES or (
            movement_none_as_missing and prop == "movement" and value == "None"
        ):
            properties[prop] = None
        elif value in spec.vocab[prop]:
            properties[prop] = value
        else:
            raise DataError(
                f"{csv_path}: EntryID {entry_id!r} (data row {index + 1}), column {column!r}: "
                f"unknown value {value!r}; expected one of {list(spec.vocab[prop])} "
                f"or blank/NA for missing"
            )
    return LexiconEntry(entry_id=entry_id, lemma_id=(row["LemmaID"] or "").strip(),
                        row=index, properties=properties,
                        frequency_z=_frequency(csv_path, entry_id, index, row.get(FREQUENCY_COLUMN)))  # fmt: skip


def _frequency(csv_path: Path, entry_id: str, index: int, value: str | None) -> float | None:
    """``SignFrequency(Z)`` as a float; None when blank/NA (or absent); another text is an error."""
    text = (value or "").strip()
    if text in MISSING_VALUES:
        return None
    try:
        return float(text)
    except ValueError:
        raise DataError(f"{csv_path}: EntryID {entry_id!r} (data row {index + 1}), column "
                        f"{FREQUENCY_COLUMN!r}: {text!r} is not a number") from None
