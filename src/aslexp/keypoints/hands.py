"""Two-hand arrays (MediaPipe Hands, ``(T, 126)``): which slot holds which of the signer's hands.

The layout ``mediapipe_hands`` reads nodes 0-20 as the signer's LEFT hand and 21-41 as the right
(``hand_order: left_right``). MediaPipe's legacy Hands solution lists the hands it found in
*detection order* instead: ``multi_hand_landmarks[0]`` is whichever hand it found first, so the
first slot is filled whenever any hand is seen, the second only when two are, and a hand changes
slot whenever tracking is lost and the hands are found again. Arrays written straight from it
(``np.concatenate`` of the two slots, zeros for a missing one) mix the sides within a clip.

``hand_order: detection`` gives each hand of each frame its side, and writes the clip back in the
``left_right`` order (a side not seen in a frame is all zeros, as before):

1. **Stored handedness** (optional): ``<video_id>.handedness.npy`` beside ``<video_id>.npy``, a
   ``(T, 2)`` array of MediaPipe's own label of each slot, as strings (``"Left"``, ``"Right"``,
   ``""`` for an empty slot) or numbers (1 = ``"Left"``, 2 = ``"Right"``, 0 or NaN = none).
   MediaPipe labels hands as if the image were mirrored (a selfie camera): in an ordinary,
   non-mirrored video its ``"Left"`` is the signer's RIGHT hand. With ``mirrored: true`` (the
   video itself is mirrored) ``"Left"`` is the signer's left. A frame whose two slots carry the
   same label, or a present hand without a label, falls back to the rules below.
2. **Two hands in a frame**: by the wrists' x. In image coordinates the signer faces the camera,
   so in a non-mirrored video the signer's left hand is on the image's RIGHT (the larger x);
   ``mirrored: true`` flips this. While both hands stay in view they are followed from frame to
   frame instead (the pairing that moves the wrists least), so hands that cross in view keep their
   sides; hands that come into view already crossed are read uncrossed unless the file stores
   handedness.
3. **One hand in a frame**: tracked by position. Each side keeps the wrist position where it was
   last seen; a lone hand takes the side whose last position is nearest (so a hand that vanishes
   and reappears keeps its side). Tracking runs forward from the first frame whose sides are
   known (rules 1-2) and backward from it to the start. A side not seen yet is placed at the
   middle of its half of the image (x = 0.75 for the signer's left in a non-mirrored video,
   x = 0.25 for the right; coordinates normalised to [0, 1] as MediaPipe writes them). A clip
   with one hand at a time and no label starts from its frame farthest from the image centre
   (x = 0.5), whose half of the image gives the side.

A slot is present in a frame when any of its x, y values is finite and non-zero; its position is its
wrist (x, y), or the mean of its landmarks where the wrist is missing.

:func:`order_fingerprint` tells detection order apart when a folder is read as ``left_right``:
in detection order the second slot is never filled while the first is empty, and the hands jump
between the slots (the first slot's wrist moves to where the second slot's wrist was).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from aslexp.errors import DataError

HAND_ORDERS = ("left_right", "detection")
HANDEDNESS_SUFFIX = ".handedness.npy"
NUM_HAND_NODES = 21
LEFT, RIGHT = 0, 1
# MediaPipe's handedness labels, as stored in a handedness file: 0 = no hand in that slot.
NO_LABEL, LABEL_LEFT, LABEL_RIGHT = 0, 1, 2
# A jump counts as a swap of slots when the crossed pairing of the wrists is at most this share
# of the straight one and shorter by at least SWAP_MIN_GAIN (in normalised image units).
SWAP_RATIO = 0.5
SWAP_MIN_GAIN = 0.05


def handedness_path(array_path: Path) -> Path:
    """``<dir>/<id>.handedness.npy`` for ``<dir>/<id>.npy``."""
    return array_path.with_name(array_path.name[: -len(".npy")] + HANDEDNESS_SUFFIX)


def read_handedness(path: Path, frames: int) -> np.ndarray:
    """A handedness file as a ``(frames, 2)`` int8 array of MediaPipe labels (0 none, 1 "Left",
    2 "Right"). Anything else is a :class:`DataError` naming the file and what was expected."""
    expected = (f"expected ({frames}, 2) = one MediaPipe label per frame and slot: 'Left', 'Right' or '' "
                "(or 1, 2, 0)")  # fmt: skip
    try:
        raw = np.load(path, allow_pickle=False)
    except (EOFError, ValueError) as error:
        raise DataError(f"{path}: not a plain .npy array ({error}); {expected}") from None
    if raw.shape != (frames, 2):
        raise DataError(f"{path}: handedness has shape {raw.shape}, {expected} (the frames of "
                        f"{path.name[: -len(HANDEDNESS_SUFFIX)]}.npy)")  # fmt: skip
    if raw.dtype.kind in "US":
        text = np.char.lower(np.char.strip(raw.astype(str)))
        labels = np.full(raw.shape, -1, dtype=np.int8)
        for value, code in (("", NO_LABEL), ("left", LABEL_LEFT), ("right", LABEL_RIGHT)):
            labels[text == value] = code
        bad = labels < 0
        if bad.any():
            t, s = np.argwhere(bad)[0]
            raise DataError(f"{path}: frame {t}, slot {s + 1}: handedness {raw[t, s].item()!r}; {expected}")
        return labels
    if raw.dtype.kind in "iufb":
        values = np.nan_to_num(raw.astype(np.float64), nan=0.0)
        bad = ~np.isin(values, (NO_LABEL, LABEL_LEFT, LABEL_RIGHT))
        if bad.any():
            t, s = np.argwhere(bad)[0]
            raise DataError(f"{path}: frame {t}, slot {s + 1}: handedness {raw[t, s].item()!r}; {expected}")
        return values.astype(np.int8)
    raise DataError(f"{path}: handedness of dtype {raw.dtype}; {expected}")


def slot_presence(clip: np.ndarray, xy: tuple[int, int] = (0, 1)) -> np.ndarray:
    """(T, 2) bool: which slot of a (T, 42, C) two-hand clip holds a hand in each frame (any
    landmark with a finite, non-zero x or y)."""
    points = clip.reshape(len(clip), 2, NUM_HAND_NODES, -1)[..., list(xy)]
    return np.any(np.isfinite(points) & (points != 0), axis=(2, 3))


def slot_positions(clip: np.ndarray, xy: tuple[int, int] = (0, 1)) -> np.ndarray:
    """(T, 2, 2): the (x, y) of each slot's wrist (the mean of its landmarks where the wrist is
    missing); NaN where the slot is empty."""
    T = len(clip)
    points = clip.reshape(T, 2, NUM_HAND_NODES, -1)[..., list(xy)].astype(np.float64)
    seen = np.any(np.isfinite(points) & (points != 0), axis=3)  # (T, 2, 21)
    points = np.where(seen[..., None], points, np.nan)
    wrist = points[:, :, 0, :]
    with warnings.catch_warnings():  # an empty slot: NaN, no "mean of empty slice" warning
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(points, axis=2)
    return np.where(np.isfinite(wrist).all(axis=2, keepdims=True), wrist, mean)


@dataclass
class SideReport:
    """How :func:`assign_sides` decided one clip (frame counts)."""

    by_label: int = 0  # frames decided by stored handedness
    by_position: int = 0  # two-hand frames decided by the wrists' x
    tracked: int = 0  # one-hand frames decided by tracking
    label_conflicts: int = 0  # frames whose two slots carried the same label (fell back)
    swapped: int = 0  # frames written with the slots exchanged


def assign_sides(clip: np.ndarray, labels: np.ndarray | None = None, *, mirrored: bool = False,
                 xy: tuple[int, int] = (0, 1)) -> tuple[np.ndarray, SideReport]:  # fmt: skip
    """Reorder a detection-order (T, 42, C) clip to the signer's left hand, then the right.

    ``labels``: (T, 2) MediaPipe handedness codes (:func:`read_handedness`) or None. The rules are
    in the module docstring. Returns the reordered clip (a side not seen: zeros) and a report.
    """
    T = len(clip)
    present = slot_presence(clip, xy)
    pos = slot_positions(clip, xy)
    side = np.full((T, 2), -1, dtype=np.int8)  # the signer's side of each slot
    known = np.zeros(T, dtype=bool)  # frames decided by label or by two hands' x
    report = SideReport()
    left_label = LABEL_RIGHT if not mirrored else LABEL_LEFT  # MediaPipe's label of the signer's left
    left_larger_x = not mirrored
    for t in range(T):
        slots = [s for s in (0, 1) if present[t, s]]
        if not slots:
            continue
        if labels is not None and all(labels[t, s] != NO_LABEL for s in slots):
            sides = [LEFT if labels[t, s] == left_label else RIGHT for s in slots]
            if len(set(sides)) == len(sides):
                side[t, slots] = sides
                known[t] = True
                report.by_label += 1
                continue
            report.label_conflicts += 1
        if len(slots) == 2:
            first_is_left = (pos[t, 0, 0] > pos[t, 1, 0]) == left_larger_x
            if t > 0 and known[t - 1] and (side[t - 1] >= 0).all():
                prev = {int(side[t - 1, s]): pos[t - 1, s] for s in (0, 1)}
                straight = np.hypot(*(pos[t, 0] - prev[LEFT])) + np.hypot(*(pos[t, 1] - prev[RIGHT]))
                crossed = np.hypot(*(pos[t, 0] - prev[RIGHT])) + np.hypot(*(pos[t, 1] - prev[LEFT]))
                first_is_left = straight <= crossed
            side[t] = (LEFT, RIGHT) if first_is_left else (RIGHT, LEFT)
            known[t] = True
            report.by_position += 1

    prior_x = (0.75, 0.25) if left_larger_x else (0.25, 0.75)

    def track(frames) -> None:
        last: list[np.ndarray | None] = [None, None]
        for t in frames:
            slots = [s for s in (0, 1) if present[t, s]]
            if not slots:
                continue
            if not known[t]:  # one hand, no usable label
                s = slots[0]
                p = pos[t, s]
                cost = [np.hypot(*(p - last[k])) if last[k] is not None else abs(p[0] - prior_x[k])
                        for k in (LEFT, RIGHT)]  # fmt: skip
                side[t, s] = LEFT if cost[LEFT] <= cost[RIGHT] else RIGHT
                report.tracked += 1
            for s in slots:
                last[side[t, s]] = pos[t, s]

    anchors = list(np.flatnonzero(known))
    if not anchors and present.any():  # one hand at a time and no label: start where it is surest
        ts, ss = np.nonzero(present)
        i = int(np.argmax(np.abs(pos[ts, ss, 0] - 0.5)))
        start, s = int(ts[i]), int(ss[i])
        side[start, s] = LEFT if (pos[start, s, 0] > 0.5) == left_larger_x else RIGHT
        known[start] = True
        report.tracked += 1
        anchors = [start]
    if anchors:
        track(range(int(anchors[0]), T))
        track(range(int(anchors[0]), -1, -1))

    out = np.zeros_like(clip)
    halves = clip.reshape(T, 2, NUM_HAND_NODES, *clip.shape[2:])
    out_halves = out.reshape(halves.shape)
    for s in (0, 1):
        for k in (LEFT, RIGHT):
            rows = present[:, s] & (side[:, s] == k)
            out_halves[rows, k] = halves[rows, s]
    report.swapped = int(np.sum(np.any(present & (side >= 0) & (side != np.arange(2)), axis=1)))
    return out, report


@dataclass(frozen=True)
class OrderFingerprint:
    """Slot statistics of one two-hand clip read as ``left_right`` (frame counts)."""

    hand_frames: int  # frames with any hand
    first_only: int  # frames with the first slot filled and the second empty
    second_only: int  # frames with the second slot filled and the first empty
    swaps: int  # frame pairs where the hands jump between the slots

    @property
    def looks_like_detection_order(self) -> bool:
        """The second slot never alone, and the hands jump between the slots or the second slot
        is empty in at least half of the frames with a hand (a left-right array of a
        right-handed signer has the right hand, the second slot, alone most often)."""
        if self.hand_frames == 0 or self.second_only > 0:
            return False
        return self.swaps > 0 or self.first_only >= 0.5 * self.hand_frames


def order_fingerprint(clip: np.ndarray, xy: tuple[int, int] = (0, 1)) -> OrderFingerprint:
    """Count the detection-order signs of a (T, 42, C) clip (missing: 0 or NaN)."""
    present = slot_presence(clip, xy)
    pos = slot_positions(clip, xy)
    swaps = 0
    for t in range(1, len(clip)):
        before = [s for s in (0, 1) if present[t - 1, s]]
        now = [s for s in (0, 1) if present[t, s]]
        if not before or not now:
            continue
        straight = [np.hypot(*(pos[t, s] - pos[t - 1, s])) for s in now if s in before]
        crossed = [np.hypot(*(pos[t, s] - pos[t - 1, 1 - s])) for s in now if 1 - s in before]
        if not straight or not crossed:
            continue
        straight_cost, crossed_cost = float(np.mean(straight)), float(np.mean(crossed))
        if crossed_cost <= SWAP_RATIO * straight_cost and straight_cost - crossed_cost >= SWAP_MIN_GAIN:
            swaps += 1
    return OrderFingerprint(
        hand_frames=int(present.any(axis=1).sum()),
        first_only=int((present[:, 0] & ~present[:, 1]).sum()),
        second_only=int((~present[:, 0] & present[:, 1]).sum()),
        swaps=swaps,
    )


def detection_order_warning(fingerprints: dict[str, OrderFingerprint], examples: int = 5) -> str | None:
    """One line when files (name -> fingerprint) look like detection order, else None.

    Only when they outnumber the files that show the second hand alone: a folder written in one
    order by one pipeline has none of those in detection order, while a left-right folder has
    them in most clips of right-handed signers (its one-handed clips of the left hand alone
    would otherwise look like detection order).
    """
    flagged = {name: f for name, f in fingerprints.items() if f.looks_like_detection_order}
    if not flagged or len(flagged) <= sum(1 for f in fingerprints.values() if f.second_only > 0):
        return None
    frames = sum(f.hand_frames for f in flagged.values())
    empty = sum(f.first_only for f in flagged.values())
    swapping = sum(1 for f in flagged.values() if f.swaps > 0)
    names = sorted(flagged)
    shown = ", ".join(names[:examples]) + (f", ... ({len(names) - examples} more)" if len(names) > examples else "")
    return (f"{len(flagged)} of {len(fingerprints)} hand files look like detection order, not the signer's "
            f"left hand first (the second slot never filled alone; slot 2 empty in {100 * empty / frames:.0f}% "
            f"of their frames with a hand; sides swap in {swapping} of them): {shown}; "
            "use pose.options.hand_order=detection")  # fmt: skip
