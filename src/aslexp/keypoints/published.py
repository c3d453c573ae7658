"""Importers of published keypoint arrays (the thesis' HRNet and FrankMocap arrays).

The published format is SL-GCN's: one ``.npy`` of shape (N, C, T, V, M) (M = 1 person) plus the
video ids of its rows, in a text file (one id a line, e.g. ``file_list.txt``), a CSV file or JSON
(a list of ids, or SL-GCN's ``[sample_names, labels]``); a pickle is refused (unpickling runs code:
:data:`CONVERT_PICKLE` converts a trusted SL-GCN label pickle once). Those arrays were
padded to a fixed T with zeros and store undetected keypoints as 0, so on import a keypoint whose
channels are all exactly 0 becomes NaN (missing), the same convention as every other source.
"""

from __future__ import annotations

import csv
import io
import json
import logging
from pathlib import Path

import numpy as np

from aslexp.errors import DataError
from aslexp.keypoints.layout import KeypointLayout, generic_layout
from aslexp.keypoints.layouts import SIGN27
from aslexp.keypoints.registry import register_source, resolve_layout

log = logging.getLogger(__name__)


ID_FORMATS = (".json (a list of ids, or SL-GCN's [sample_names, labels]), .csv (a video_id column, or the "
              "first) or .txt (one id a line)")
# A trusted SL-GCN label pickle, converted once (never unpickled by aslexp):
CONVERT_PICKLE = ("python -c \"import pickle,sys; d=pickle.load(open(sys.argv[1],'rb')); d=d[0] if isinstance(d,tuple) "
                  "else d; open(sys.argv[2],'w').write(''.join(str(i)+chr(10) for i in d))\" label.pkl file_list.txt")
_ID_COLUMNS = ("video_id", "id", "sample_name", "name")


def read_video_ids(path: str | Path) -> list[str]:
    """Video ids, one per array row, from a .json (a list, or SL-GCN's ``[sample_names, labels]``),
    .csv (a ``video_id``/``id``/``sample_name``/``name`` column, else the first) or text file (one
    id a line). A pickle (.pkl/.pickle, or pickle bytes under any name) is refused, never loaded:
    unpickling a file can run any code."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"video id list not found: {path}")
    with path.open("rb") as handle:
        first = handle.read(1)
    if path.suffix.lower() in (".pkl", ".pickle") or first == b"\x80":  # a pickle (protocol 2+) starts so
        raise DataError(f"{path}: a pickle is not read as an ids file (unpickling it could run code); give the "
                        f"ids as {ID_FORMATS}; a trusted SL-GCN label pickle converts with: {CONVERT_PICKLE}")
    try:
        text = path.read_text(encoding="utf-8")
    except UnicodeDecodeError as exc:
        raise DataError(f"{path}: not a UTF-8 text file ({exc.reason}); give the ids as {ID_FORMATS}") from None
    if path.suffix.lower() == ".json":
        try:
            ids = json.loads(text)
        except ValueError as exc:
            raise DataError(f"{path}: not valid JSON ({exc})") from None
        if (isinstance(ids, list) and len(ids) == 2 and all(isinstance(part, list) for part in ids)
                and len(ids[0]) == len(ids[1])):  # SL-GCN's (sample_names, labels), as JSON
            ids = ids[0]
    elif path.suffix.lower() == ".csv":
        rows = [row for row in csv.reader(io.StringIO(text)) if any(cell.strip() for cell in row)]
        header = [cell.strip().lower() for cell in rows[0]] if rows else []
        column = next((header.index(name) for name in _ID_COLUMNS if name in header), None)
        if column is not None:
            rows = rows[1:]
        column = column or 0
        short = next((n for n, row in enumerate(rows, 1) if len(row) <= column), None)
        if short is not None:
            raise DataError(f"{path}: row {short} has no column {column + 1} (the ids)")
        ids = [row[column].strip() for row in rows]
    else:
        ids = [line.strip() for line in text.splitlines() if line.strip()]
    if not isinstance(ids, list) or not all(isinstance(i, (str, int)) and not isinstance(i, bool) for i in ids):
        got = type(ids).__name__ if not isinstance(ids, list) else "a list holding other than strings and integers"
        raise DataError(f"{path}: expected a list of video ids, got {got}")
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
