"""Keypoint layouts, their registry, and keypoint sources: the bottom of the house.

This package imports nothing of aslexp but the leaf modules ``errors`` and ``files``, so the
data layer, extraction and retargeting all build on it. Importing it registers the built-in
layouts (``mediapipe_pose``, ``mediapipe_holistic``, ``mediapipe_holistic_reduced``,
``mediapipe_hands``, ``sign27``) and sources (``mediapipe_pose_npy``, ``array_folder``, ``directory``,
``published``, ``pose_format``); see :mod:`aslexp.keypoints.registry` for registering more.
"""

from aslexp.keypoints.layout import KeypointLayout, generic_layout, induced_edges
from aslexp.keypoints.layouts import (
    MEDIAPIPE_HANDS,
    MEDIAPIPE_HOLISTIC,
    MEDIAPIPE_HOLISTIC_REDUCED,
    MEDIAPIPE_POSE,
    SIGN27,
)
from aslexp.keypoints.registry import (
    get_layout,
    get_source,
    layout_names,
    open_source,
    register_layout,
    register_source,
    resolve_layout,
    source_names,
)
from aslexp.keypoints.source import KeypointSource, SubsetSource, check_clip
from aslexp.keypoints.subsets import register_subsets, subset_indices, subset_layout, subset_names

# Sources register themselves on import.
from aslexp.keypoints import arrays, posefile, published  # noqa: E402,F401  isort: skip
from aslexp.keypoints.arrays import ArrayFolderSource, DirectoryKeypointSource, read_layout, write_layout  # noqa: E402

__all__ = [
    "ArrayFolderSource", "DirectoryKeypointSource", "KeypointLayout", "KeypointSource", "MEDIAPIPE_HANDS",
    "MEDIAPIPE_HOLISTIC", "MEDIAPIPE_HOLISTIC_REDUCED", "MEDIAPIPE_POSE", "SIGN27", "SubsetSource",
    "check_clip", "generic_layout", "get_layout", "get_source", "induced_edges", "layout_names", "open_source",
    "read_layout", "register_layout", "register_source", "register_subsets", "resolve_layout", "source_names",
    "subset_indices", "subset_layout", "subset_names", "write_layout",
]  # fmt: skip
