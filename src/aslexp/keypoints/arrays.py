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
from aslexp.keypoints.layout import KeypointLayout
from aslexp.keypoints.layouts import MEDIAPIPE_POSE
from aslexp.keypoints.registry import register_source, register_subsets, resolve_layout

log = logging.getLogger(__name__)

LAYOUT_FILE = "layout.json"
ZERO_RULES = ("node", "frame", "keep")
MEDIAPIPE_POSE_DIR = "keypoints/wlasl-mediapipe-pose"


def npy_ids(directory: Path) -> set[str]:
    return {path.stem for path in directory.glob("*.npy")}


def load_npy(path: Path) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"keypoint file not found: {path}")
    try:
        return np.load(path, allow_pickle=False)
    except EOFError:  # numpy's word for a 0-byte file (a truncated one is a ValueError)
        raise DataError(f"{path}: empty file ({path.stat().st_size} bytes), not a .npy array") from None
    except ValueError as error:
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
    """

    def __init__(self, directory: str | Path, layout: KeypointLayout | str | Mapping[str, Any],
                 zeros: str = "node"):  # fmt: skip
        self.directory = _folder(directory, "keypoint")
        self._layout = resolve_layout(layout, f"{self.directory}: pose.options.layout")
        if zeros not in ZERO_RULES:
            raise DataError(f"{self.directory}: pose.options.zeros = {zeros!r}; expected one of {ZERO_RULES}")
        self.zeros = zeros
        self.zero_frames: dict[str, int] = {}
        self.zero_nodes: dict[str, int] = {}

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


@register_source("array_folder", summary="<dir>/<id>.npy (T, V*C) or (T, V, C), layout from the config")
def open_array_folder(path, layout, zeros: str = "node") -> ArrayFolderSource:
    return ArrayFolderSource(path, layout, zeros)


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
