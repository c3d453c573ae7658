"""Importers of published keypoint arrays (the thesis' HRNet and FrankMocap arrays).

The published format is SL-GCN's: one ``.npy`` of shape (N, C, T, V, M) (M = 1 person) plus the
video ids of its rows, in a text file (one id a line, e.g. ``file_list.txt``), a JSON list, or a
pickle (a list of ids, or SL-GCN's ``(sample_names, labels)`` label pickle). Those arrays were
padded to a fixed T with zeros and store undetected keypoints as 0, so on import a keypoint whose
channels are all exactly 0 becomes NaN (missing), the same convention as every other source.
"""

from __future__ import annotations

import json
import logging
import pickle
from pathlib import Path

import numpy as np

from aslexp.errors import DataError
from aslexp.keypoints.layout import KeypointLayout, generic_layout
from aslexp.keypoints.layouts import SIGN27
from aslexp.keypoints.registry import register_source, resolve_layout

log = logging.getLogger(__name__)


def read_video_ids(path: str | Path) -> list[str]:
    """Video ids, one per array row, from a .txt (one a line), .json (list) or .pkl file."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video id list not found: {path}")
    if path.suffix == ".json":
        ids = json.loads(path.read_text(encoding="utf-8"))
    elif path.suffix in (".pkl", ".pickle"):
        with path.open("rb") as handle:
            ids = pickle.load(handle)  # a trusted, published file
        if isinstance(ids, tuple) and len(ids) == 2:  # SL-GCN label pickle: (names, labels)
            ids = ids[0]
    else:
        ids = [line.strip() for line in path.read_text(encoding="utf-8").splitlines() if line.strip()]
    if not isinstance(ids, (list, tuple)):
        raise DataError(f"{path}: expected a list of video ids, got {type(ids).__name__}")
    return [str(Path(str(i)).stem) if str(i).endswith((".mp4", ".npy")) else str(i) for i in ids]


def _default_layout(num_nodes: int, num_channels: int) -> KeypointLayout:
    if (num_nodes, num_channels) == (SIGN27.num_nodes, len(SIGN27.channels)):
        return SIGN27
    channels = ("x", "y", "z") if num_channels == 3 else tuple(f"c{i}" for i in range(num_channels))
    return generic_layout(num_nodes, channels, name=f"published_{num_nodes}")


class PublishedArraySource:
    """A (N, C, T, V, 1) array and its row ids, served as a :class:`KeypointSource`.

    ``layout`` may be a KeypointLayout, a layout name, or None: then 27 nodes x 3 channels is
    taken as SL-GCN's ``sign27`` (HRNet x, y, score) and anything else (e.g. FrankMocap x, y, z)
    gets a generic layout without edges; pass the right layout when you know it.
    """

    def __init__(self, array_path: str | Path, ids: str | Path | list[str],
                 layout: KeypointLayout | str | None = None, mmap: bool = True):  # fmt: skip
        self.array_path = Path(array_path)
        if not self.array_path.is_file():
            raise FileNotFoundError(f"published keypoint array not found: {self.array_path}")
        self.array = np.load(self.array_path, mmap_mode="r" if mmap else None, allow_pickle=False)
        if self.array.ndim != 5 or self.array.shape[-1] != 1:
            raise DataError(f"{self.array_path}: shape {self.array.shape}, expected (N, C, T, V, 1)")
        n, c, _, v, _ = self.array.shape
        self.video_ids = list(ids) if isinstance(ids, (list, tuple)) else read_video_ids(ids)
        if len(self.video_ids) != n:
            raise DataError(f"{self.array_path}: {n} rows but {len(self.video_ids)} video ids in {ids!r}")
        self.row_of = {video_id: row for row, video_id in enumerate(self.video_ids)}
        if len(self.row_of) != n:
            raise DataError(f"{ids!r}: duplicate video ids")
        if layout is not None:
            layout = resolve_layout(layout, f"{self.array_path}: pose.options.layout")
        self._layout = layout or _default_layout(v, c)
        if self._layout.num_nodes != v or len(self._layout.channels) != c:
            raise DataError(f"{self.array_path}: {v} nodes x {c} channels do not fit layout "
                            f"{self._layout.name!r} ({self._layout.num_nodes} nodes, channels "
                            f"{self._layout.channels})")  # fmt: skip
        log.info("published array %s: %d clips, layout %s", self.array_path, n, self._layout.name)

    @property
    def layout(self) -> KeypointLayout:
        return self._layout

    def available(self) -> set[str]:
        return set(self.video_ids)

    def load(self, video_id: str) -> np.ndarray:
        try:
            row = self.row_of[video_id]
        except KeyError:
            raise DataError(f"{self.array_path}: no row for video {video_id!r}") from None
        clip = np.array(self.array[row, :, :, :, 0].transpose(1, 2, 0), dtype=np.float32)  # T, V, C
        clip[np.all(clip == 0, axis=-1)] = np.nan
        return clip


register_source("published", PublishedArraySource,
                summary="the thesis' (N, C, T, V, 1) .npy and its video ids (options: ids, layout)")


def write_published_arrays(array_path: str | Path, clips: list[np.ndarray], video_ids: list[str],
                           length: int, ids_path: str | Path | None = None) -> Path:  # fmt: skip
    """Write (T, V, C) clips (NaN = missing) in the published (N, C, T, V, 1) format.

    Clips are cut or zero-padded to ``length``; missing keypoints are written as 0. The ids go to
    ``ids_path`` (default: ``file_list.txt`` next to the array). The inverse of the importer.
    """
    if len(clips) != len(video_ids) or not clips:
        raise DataError(f"need one video id per clip, got {len(clips)} clips, {len(video_ids)} ids")
    v, c = clips[0].shape[1:]
    out = np.zeros((len(clips), c, length, v, 1), dtype=np.float32)
    for i, clip in enumerate(clips):
        part = np.nan_to_num(clip[:length], nan=0.0, posinf=0.0, neginf=0.0)
        out[i, :, : len(part), :, 0] = part.transpose(2, 0, 1)
    array_path = Path(array_path)
    np.save(array_path, out)
    ids_path = Path(ids_path) if ids_path else array_path.with_name("file_list.txt")
    ids_path.write_text("".join(f"{i}\n" for i in video_ids), encoding="utf-8")
    return array_path
