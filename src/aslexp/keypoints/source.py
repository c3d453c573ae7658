"""The keypoint-source protocol: anything that yields per-video keypoint arrays.

A source returns ``(T, V, C)`` float32 arrays with NaN where a keypoint was not observed, laid out
as ``source.layout`` says (node names, skeleton edges, channel names). Extractors, array folders,
``.pose`` files and importers of published arrays all look the same to the dataset builder.
"""

from __future__ import annotations

from typing import Protocol, runtime_checkable

import numpy as np

from aslexp.errors import DataError
from aslexp.keypoints.layout import KeypointLayout
from aslexp.keypoints.subsets import subset_layout


@runtime_checkable
class KeypointSource(Protocol):
    @property
    def layout(self) -> KeypointLayout: ...

    def load(self, video_id: str) -> np.ndarray:
        """(T, V, C) float32, NaN where missing."""
        ...

    def available(self) -> set[str]:
        """The video ids this source can load."""
        ...


class SubsetSource:
    """A view of another source restricted to a named keypoint subset of its layout."""

    def __init__(self, source: KeypointSource, subset: str | None):
        self.source = source
        self._layout, self.indices = subset_layout(source.layout, subset)

    @property
    def layout(self) -> KeypointLayout:
        return self._layout

    def load(self, video_id: str) -> np.ndarray:
        return self.source.load(video_id)[:, list(self.indices), :]

    def available(self) -> set[str]:
        return self.source.available()


def check_clip(array: np.ndarray, layout: KeypointLayout, origin: str) -> np.ndarray:
    """Validate a (T, V, C) clip against ``layout`` and return it as float32."""
    expected = (layout.num_nodes, len(layout.channels) or array.shape[-1])
    if array.ndim != 3 or array.shape[1:] != expected:
        raise DataError(f"{origin}: keypoint array has shape {array.shape}, expected (T, "
                        f"{expected[0]}, {expected[1]}) for layout {layout.name!r}")  # fmt: skip
    return np.asarray(array, dtype=np.float32)
