"""Keypoint sources for the data layer: a source *name* from the config -> a source object.

The sources and layouts themselves live lower, in :mod:`aslexp.keypoints` (a registry: a new
format is a registration or a YAML layout, not a change here). This module adds what only the
data layer knows: where the data root is, for sources with a default folder under it.
"""

from __future__ import annotations

from pathlib import Path

from aslexp.data.root import resolve_data_root
from aslexp.keypoints import KeypointSource, get_source, open_source


def open_keypoint_source(
    kind: str,
    root: str | Path | None = None,
    path: str | Path | None = None,
    **options,
) -> KeypointSource:
    """Open a registered keypoint source (``aslexp.keypoints.source_names()``) by name.

    ``path`` defaults to the source's folder under the data root when it has one (the real
    MediaPipe Pose keypoints: ``keypoints/wlasl-mediapipe-pose``); ``options`` go to the source
    (e.g. ``layout``, ``zeros`` for ``array_folder``; ``ids``, ``layout`` for ``published``).
    """
    spec = get_source(kind)
    if path is None and spec.default_path is not None:
        path = resolve_data_root(root) / spec.default_path
    return open_source(kind, None if path is None else str(path), **options)
