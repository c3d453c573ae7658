"""Keypoint sources on disk: the real MediaPipe Pose files and self-describing directories.

``open_keypoint_source`` is the one place that turns a source *name* into a source object.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

import numpy as np

from aslexp.data.dataset import DataError, KeypointLayout
from aslexp.data.root import resolve_data_root
from aslexp.files import atomic_write_text
from aslexp.pose.base import KeypointSource, check_clip
from aslexp.pose.layouts import register_subsets, MEDIAPIPE_POSE

log = logging.getLogger(__name__)

MEDIAPIPE_POSE_DIR = "keypoints/wlasl-mediapipe-pose"
LAYOUT_FILE = "layout.json"
SOURCE_KINDS = ("mediapipe_pose_npy", "directory", "published")


def _npy_ids(directory: Path) -> set[str]:
    return {path.stem for path in directory.glob("*.npy")}


def _load_npy(path: Path) -> np.ndarray:
    if not path.is_file():
        raise FileNotFoundError(f"keypoint file not found: {path}")
    try:
        return np.load(path, allow_pickle=False)
    except ValueError as error:
        raise DataError(f"{path}: not a plain .npy array ({error})") from None


class MediaPipePoseNpySource:
    """``<dir>/<video_id>.npy``: float64 (T, 132) = 33 landmarks x (x, y, z, visibility).

    MediaPipe writes an all-zero row when it detected no person in a frame; such frames become
    NaN (missing). Their number per video is kept in ``zero_frames`` and logged at DEBUG; the
    builder logs the total. An empty file gives a (0, 33, 4) clip (the builder skips it and
    counts it); any other shape is a :class:`DataError` naming the file and the expected shape.
    """

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise FileNotFoundError(f"MediaPipe keypoint folder not found: {self.directory}")
        self.zero_frames: dict[str, int] = {}

    @property
    def layout(self) -> KeypointLayout:
        return MEDIAPIPE_POSE

    def available(self) -> set[str]:
        return _npy_ids(self.directory)

    def load(self, video_id: str) -> np.ndarray:
        path = self.directory / f"{video_id}.npy"
        raw = _load_npy(path)
        nodes, channels = MEDIAPIPE_POSE.num_nodes, len(MEDIAPIPE_POSE.channels)
        if raw.size == 0:
            return np.empty((0, nodes, channels), dtype=np.float32)
        if raw.ndim != 2 or raw.shape[1] != nodes * channels:
            raise DataError(f"{path}: MediaPipe Pose array has shape {raw.shape}, expected "
                            f"(T, {nodes * channels}) = T frames x {nodes} landmarks x "
                            f"{MEDIAPIPE_POSE.channels}")  # fmt: skip
        clip = raw.reshape(len(raw), nodes, channels).astype(np.float32)
        no_detection = np.all(clip == 0, axis=(1, 2))
        clip[no_detection] = np.nan
        self.zero_frames[video_id] = int(no_detection.sum())
        if no_detection.any():
            log.debug("%s: %d of %d frames all-zero (no detection) -> missing",
                      path.name, int(no_detection.sum()), len(clip))  # fmt: skip
        return clip


def write_layout(directory: str | Path, layout: KeypointLayout) -> Path:
    """Write ``layout.json`` so a folder of (T, V, C) arrays describes itself."""
    path = Path(directory) / LAYOUT_FILE
    payload = {"name": layout.name, "names": list(layout.names),
               "edges": [list(edge) for edge in layout.edges], "center": layout.center,
               "channels": list(layout.channels)}  # fmt: skip
    return atomic_write_text(path, json.dumps(payload, indent=1))


def read_layout(path: str | Path) -> KeypointLayout:
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"layout file not found: {path} (a keypoint folder needs one)")
    try:
        raw = json.loads(path.read_text(encoding="utf-8"))
        names = tuple(str(n) for n in raw["names"])
        edges = tuple((int(i), int(j)) for i, j in raw["edges"])
        layout = KeypointLayout(name=str(raw["name"]), names=names, edges=edges,
                                center=int(raw["center"]), channels=tuple(raw["channels"]))  # fmt: skip
    except (KeyError, TypeError, ValueError) as error:
        raise DataError(f"{path}: expected {{'name', 'names': [...], 'edges': [[i, j], ...], "
                        f"'center': int, 'channels': [...]}} ({error!r})") from None  # fmt: skip
    bad = [edge for edge in edges if not all(0 <= k < len(names) for k in edge)]
    if bad or not 0 <= layout.center < len(names) or not layout.channels:
        raise DataError(f"{path}: edges {bad} / center {layout.center} out of range for "
                        f"{len(names)} names, or no channels")  # fmt: skip
    subsets = raw.get("subsets") or {}
    if subsets:  # optional: named keypoint subsets, e.g. written by `aslexp extract`
        try:
            indices = {name: tuple(int(i) for i in spec["indices"]) for name, spec in subsets.items()}
        except (KeyError, TypeError, ValueError) as error:
            raise DataError(f"{path}: 'subsets' must map names to {{'indices': [...]}} ({error!r})") from None
        out_of_range = {n: [i for i in idx if not 0 <= i < len(names)] for n, idx in indices.items()}
        out_of_range = {n: bad for n, bad in out_of_range.items() if bad}
        if out_of_range:
            raise DataError(f"{path}: subset indices out of range for {len(names)} names: {out_of_range}")
        register_subsets(layout.name, indices)
    return layout


class DirectoryKeypointSource:
    """``<dir>/<video_id>.npy`` float32 (T, V, C) with NaN for missing, and ``<dir>/layout.json``."""

    def __init__(self, directory: str | Path):
        self.directory = Path(directory)
        self._layout = read_layout(self.directory / LAYOUT_FILE)

    @property
    def layout(self) -> KeypointLayout:
        return self._layout

    def available(self) -> set[str]:
        return _npy_ids(self.directory)

    def load(self, video_id: str) -> np.ndarray:
        path = self.directory / f"{video_id}.npy"
        raw = _load_npy(path)
        if raw.size == 0:
            return np.empty((0, self.layout.num_nodes, len(self.layout.channels)), np.float32)
        return check_clip(raw, self.layout, str(path))


def open_keypoint_source(
    kind: str,
    root: str | Path | None = None,
    path: str | Path | None = None,
    **options,
) -> KeypointSource:
    """Open a keypoint source by name.

    - ``mediapipe_pose_npy``: ``path`` defaults to ``<data root>/keypoints/wlasl-mediapipe-pose``.
    - ``directory``: ``path`` = a folder with ``layout.json`` and ``<video_id>.npy`` files.
    - ``published``: ``path`` = the thesis' ``(N, C, T, V, 1)`` .npy; ``options`` go to
      :class:`aslexp.pose.importers.PublishedArraySource` (``ids``, ``layout``).
    """
    if kind == "mediapipe_pose_npy":
        return MediaPipePoseNpySource(path or resolve_data_root(root) / MEDIAPIPE_POSE_DIR)
    if path is None:
        raise DataError(f"keypoint source {kind!r} needs a path")
    if kind == "directory":
        return DirectoryKeypointSource(path)
    if kind == "published":
        from aslexp.pose.importers import PublishedArraySource

        return PublishedArraySource(path, **options)
    raise DataError(f"unknown keypoint source {kind!r}; expected one of {SOURCE_KINDS}")
