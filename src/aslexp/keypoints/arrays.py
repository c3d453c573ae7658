"""Folders of ``<video_id>.npy`` keypoint arrays.

- ``array_folder``: the generic reader. ``(T, V*C)`` or ``(T, V, C)`` arrays whose layout comes
  from configuration: a registered layout name or a mapping ``{name, nodes, edges, center,
  channels}`` (see :meth:`KeypointLayout.from_spec`). ``zeros`` says what an exact 0 means:
  ``node`` (default: a node whose channels are all 0 was not detected -> NaN; the usual
  zero-filling of MediaPipe pipelines), ``frame`` (only an all-zero frame is missing) or ``keep``.
- ``mediapipe_pose_npy``: the same reader fixed to the 33-landmark MediaPipe Pose layout with
  ``zeros: frame`` (the real keypoints of 291 WLASL clips under the data root).
- ``directory``: ``(T, V, C)`` float32 arrays with NaN for missing and a ``layout.json`` that
  describes them (``aslexp extract`` writes such folders).
"""

from __future__ import annotations

import json
import logging
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.errors import DataError
from aslexp.files import atomic_write_text
from aslexp.keypoints import hands
from aslexp.keypoints.layout import KeypointLayout
from aslexp.keypoints.layouts import MEDIAPIPE_HANDS, MEDIAPIPE_POSE
from aslexp.keypoints.registry import register_source, resolve_layout
from aslexp.keypoints.subsets import register_subsets

log = logging.getLogger(__name__)

LAYOUT_FILE = "layout.json"
ZERO_RULES = ("node", "frame", "keep")
MEDIAPIPE_POSE_DIR = "keypoints/wlasl-mediapipe-pose"


def npy_ids(directory: Path) -> set[str]:
    """The ids of ``<dir>/<id>.npy`` (handedness companions ``<id>.handedness.npy`` are not clips)."""
    return {path.stem for path in directory.glob("*.npy") if not path.name.endswith(hands.HANDEDNESS_SUFFIX)}


# dtype kinds a keypoint array may hold: bool, signed and unsigned integers, floats
NUMERIC_KINDS = "biuf"
KIND_WORDS = {"U": "text", "S": "bytes", "O": "Python objects", "c": "complex numbers", "V": "records",
              "M": "dates", "m": "time spans"}  # fmt: skip


def _check_npy_header(path: Path) -> None:
    """Compare what a .npy header promises with the bytes the file holds, before reading any data:
    a header that claims (10**12, 132) over 64 bytes would otherwise make numpy allocate terabytes
    (a MemoryError that names no file), and a wrong dtype would fail later without naming it."""
    with path.open("rb") as handle:
        version = np.lib.format.read_magic(handle)  # ValueError: not a .npy file
        read_header = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
            np.lib.format.read_array_header_2_0  # fmt: skip
        shape, _, dtype = read_header(handle)
        data_bytes = path.stat().st_size - handle.tell()
    if dtype.hasobject or dtype.kind not in NUMERIC_KINDS:
        raise DataError(f"{path}: array of dtype {dtype} ({KIND_WORDS.get(dtype.kind, dtype.kind)}); expected "
                        "numbers (float or integer keypoint coordinates)")  # fmt: skip
    expected = int(np.prod(shape, dtype=object)) * dtype.itemsize
    if data_bytes < expected:  # "Failed to read all data": the phrase numpy uses for a short file
        raise DataError(f"{path}: not a plain .npy array (Failed to read all data: its header says shape "
                        f"{tuple(shape)} of {dtype} = {expected} bytes, the file holds {data_bytes} bytes after "
                        "the header; truncated, or a header that does not describe the file)")  # fmt: skip


def load_npy(path: Path) -> np.ndarray:
    """A numeric .npy array; an empty, truncated or lying file, or one of strings or objects, is a
    :class:`DataError` naming the file (the dataset build skips it and counts it)."""
    if not path.is_file():
        raise FileNotFoundError(f"keypoint file not found: {path}")
    if path.stat().st_size == 0:
        raise DataError(f"{path}: empty file (0 bytes), not a .npy array")
    try:
        _check_npy_header(path)
        return np.load(path, allow_pickle=False)
    except DataError:
        raise
    except (ValueError, SyntaxError) as error:  # SyntaxError: a header dict that is not a literal
        raise DataError(f"{path}: not a plain .npy array ({error})") from None


def _folder(directory: str | Path, what: str) -> Path:
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"{what} folder not found: {directory}")
    return directory


class ArrayFolderSource:
    """``<dir>/<video_id>.npy`` arrays of shape (T, V*C) or (T, V, C) in a configured layout.

    All-zero frames (``zeros: frame``) or nodes (``zeros: node``) become NaN (missing); their
    count per video is kept in ``zero_frames`` / ``zero_nodes``. An empty file gives a
    (0, V, C) clip (the builder skips it and counts it); any other shape is a :class:`DataError`
    naming the file, the shape and the layout expected.

    With the two-hand layout ``mediapipe_hands``: ``hand_order`` (``left_right`` | ``detection``)
    and ``mirrored`` (see :mod:`aslexp.keypoints.hands`); per video, ``side_reports`` (detection:
    how each clip's sides were decided) or ``order_fingerprints`` (left_right: the signs of
    detection order), summed up by :meth:`build_messages`.
    """

    file_suffix = ".npy"

    def __init__(self, directory: str | Path, layout: KeypointLayout | str | Mapping[str, Any],
                 zeros: str = "node", hand_order: str = "left_right", mirrored: bool = False):  # fmt: skip
        self.directory = _folder(directory, "keypoint")
        self._layout = resolve_layout(layout, f"{self.directory}: pose.options.layout")
        if zeros not in ZERO_RULES:
            raise DataError(f"{self.directory}: pose.options.zeros = {zeros!r}; expected one of {ZERO_RULES}")
        if hand_order not in hands.HAND_ORDERS:
            raise DataError(f"{self.directory}: pose.options.hand_order = {hand_order!r}; expected one of "
                            f"{hands.HAND_ORDERS}")  # fmt: skip
        if not isinstance(mirrored, bool):
            raise DataError(f"{self.directory}: pose.options.mirrored = {mirrored!r}; expected true or false")
        self.two_hands = (self._layout.names == MEDIAPIPE_HANDS.names
                          and {"x", "y"} <= set(self._layout.channels))  # fmt: skip
        if (hand_order != "left_right" or mirrored) and not self.two_hands:
            raise DataError(f"{self.directory}: pose.options.hand_order / mirrored apply to the two-hand layout "
                            f"'mediapipe_hands' (the 21 landmarks of each hand, channels with x and y); "
                            f"layout {self._layout.name!r} has {self._layout.num_nodes} nodes")  # fmt: skip
        self.zeros = zeros
        self.hand_order = hand_order
        self.mirrored = mirrored
        self.zero_frames: dict[str, int] = {}
        self.zero_nodes: dict[str, int] = {}
        self.side_reports: dict[str, hands.SideReport] = {}
        self.order_fingerprints: dict[str, hands.OrderFingerprint] = {}

    @property
    def layout(self) -> KeypointLayout:
        return self._layout

    def available(self) -> set[str]:
        return npy_ids(self.directory)

    def load(self, video_id: str) -> np.ndarray:
        path = self.directory / f"{video_id}.npy"
        raw = load_npy(path)
        nodes, channels = self.layout.num_nodes, len(self.layout.channels)
        if raw.size == 0:
            return np.empty((0, nodes, channels), dtype=np.float32)
        if raw.ndim == 2 and raw.shape[1] == nodes * channels:
            clip = raw.reshape(len(raw), nodes, channels).astype(np.float32)
        elif raw.ndim == 3 and raw.shape[1:] == (nodes, channels):
            clip = raw.astype(np.float32)
        else:
            raise DataError(f"{path}: array has shape {raw.shape}, expected (T, {nodes * channels}) or "
                            f"(T, {nodes}, {channels}) = T frames x {nodes} nodes of layout "
                            f"{self.layout.name!r} x channels {list(self.layout.channels)}")  # fmt: skip
        if self.two_hands:
            clip = self._hand_sides(video_id, path, clip)
        if self.zeros == "frame":
            missing = np.all(clip == 0, axis=(1, 2))
            clip[missing] = np.nan
            self.zero_frames[video_id] = int(missing.sum())
        elif self.zeros == "node":
            missing = np.all(clip == 0, axis=2)
            clip[missing] = np.nan
            self.zero_nodes[video_id] = int(missing.sum())
            self.zero_frames[video_id] = int(missing.all(axis=1).sum())
        if self.zero_frames.get(video_id):
            log.debug("%s: %d of %d frames all-zero (no detection) -> missing",
                      path.name, self.zero_frames[video_id], len(clip))  # fmt: skip
        return clip

    def _hand_sides(self, video_id: str, path: Path, clip: np.ndarray) -> np.ndarray:
        xy = (self.layout.channels.index("x"), self.layout.channels.index("y"))
        if self.hand_order == "left_right":
            self.order_fingerprints[video_id] = hands.order_fingerprint(clip, xy)
            return clip
        companion = hands.handedness_path(path)
        labels = hands.read_handedness(companion, len(clip)) if companion.is_file() else None
        clip, report = hands.assign_sides(clip, labels, mirrored=self.mirrored, xy=xy)
        self.side_reports[video_id] = report
        return clip

    def build_messages(self, video_ids) -> list[tuple[int, str]]:
        """(logging level, line) about the clips ``video_ids`` one build loaded: how the hands got
        their sides (hand_order=detection), or the one warning naming files that look like
        detection order (left_right)."""
        video_ids = list(video_ids)
        messages: list[tuple[int, str]] = []
        reports = [self.side_reports[v] for v in video_ids if v in self.side_reports]
        if reports:
            total = {k: sum(getattr(r, k) for r in reports) for k in vars(reports[0])}
            with_labels = sum(1 for v in video_ids if hands.handedness_path(self.directory / f"{v}.npy").is_file())
            messages.append((logging.INFO, (
                f"{self.directory}: hand_order=detection on {len(reports)} clips ({with_labels} with a handedness "
                f"file, mirrored={self.mirrored}): frames decided by handedness {total['by_label']}, by the two "
                f"wrists' x {total['by_position']}, by tracking one hand {total['tracked']}; "
                f"{total['label_conflicts']} frames with one label on both slots; {total['swapped']} frames "
                "had a hand moved to the other slot")))  # fmt: skip
        prints = {f"{v}.npy": self.order_fingerprints[v] for v in video_ids if v in self.order_fingerprints}
        line = hands.detection_order_warning(prints)
        if line:
            messages.append((logging.WARNING, f"{self.directory}: {line}"))
        elif prints:
            flagged = sum(f.looks_like_detection_order for f in prints.values())
            if flagged:
                messages.append((logging.INFO, (
                    f"{self.directory}: {flagged} of {len(prints)} hand files have only the first slot filled, "
                    f"but {sum(f.second_only > 0 for f in prints.values())} show the second hand alone: read as "
                    "left_right (the signer's left hand first)")))  # fmt: skip
        return messages


@register_source("array_folder", summary="<dir>/<id>.npy (T, V*C) or (T, V, C), layout from the config")
def open_array_folder(path, layout, zeros: str = "node", hand_order: str = "left_right",
                      mirrored: bool = False) -> ArrayFolderSource:  # fmt: skip
    return ArrayFolderSource(path, layout, zeros, hand_order, mirrored)


@register_source("mediapipe_pose_npy", default_path=MEDIAPIPE_POSE_DIR,
                 summary="<dir>/<id>.npy (T, 132): 33 MediaPipe Pose landmarks x (x, y, z, visibility)")  # fmt: skip
def open_mediapipe_pose_npy(path) -> ArrayFolderSource:
    """MediaPipe writes an all-zero row when it detected no person in a frame: such frames are missing."""
    return ArrayFolderSource(_folder(path, "MediaPipe keypoint"), MEDIAPIPE_POSE, zeros="frame")


def write_layout(directory: str | Path, layout: KeypointLayout) -> Path:
    """Write ``layout.json`` so a folder of (T, V, C) arrays describes itself."""
    return atomic_write_text(Path(directory) / LAYOUT_FILE, json.dumps(layout.to_spec(), indent=1))


def read_layout(path: str | Path) -> KeypointLayout:
    """A ``layout.json``: the layout keys of :meth:`KeypointLayout.from_spec` and, optionally,
    ``subsets: {name: {indices: [...]}}`` (registered for the layout's name)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"layout file not found: {path} (a keypoint folder needs one)")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise DataError(f"{path}: not JSON ({error})") from None
    layout = KeypointLayout.from_spec(raw, str(path))
    subsets = raw.get("subsets") or {}
    if subsets:  # optional: named keypoint subsets, e.g. written by `aslexp extract`
        try:
            indices = {name: tuple(int(i) for i in spec["indices"]) for name, spec in subsets.items()}
        except (KeyError, TypeError, ValueError, AttributeError) as error:
            raise DataError(f"{path}: 'subsets' must map names to {{'indices': [...]}} ({error!r})") from None
        try:
            register_subsets(layout.name, indices, num_nodes=layout.num_nodes)
        except DataError as error:
            raise DataError(f"{path}: {error}") from None
    return layout


class DirectoryKeypointSource(ArrayFolderSource):
    """``<dir>/<video_id>.npy`` float32 (T, V, C) with NaN for missing, and ``<dir>/layout.json``."""

    def __init__(self, directory: str | Path):
        directory = Path(directory)
        super().__init__(directory, read_layout(directory / LAYOUT_FILE), zeros="keep")


register_source("directory", DirectoryKeypointSource,
                summary="<dir>/<id>.npy (T, V, C), NaN = missing, described by <dir>/layout.json")  # fmt: skip
