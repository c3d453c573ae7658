"""Keypoint layouts (node names, skeleton edges, channels) and named keypoint subsets.

Layouts
- ``mediapipe_pose``: the 33 MediaPipe Pose landmarks, channels (x, y, z, visibility); edges are
  MediaPipe's ``POSE_CONNECTIONS`` plus nose-shoulders and nose-mouth corners: in
  POSE_CONNECTIONS the face and the mouth pair are separate components, which would leave the body
  unreachable from the centre node (the nose) in ST-GCN's spatial partition.
- ``sign27``: SL-GCN's 27-point subset of COCO-WholeBody (HRNet), channels (x, y, score), the
  thesis' published HRNet arrays. Node order = COCO-WholeBody indices
  [0, 5, 6, 7, 8, 9, 10, 91, 95, 96, 99, 100, 103, 104, 107, 108, 111,
   112, 116, 117, 120, 121, 124, 125, 128, 129, 132]: nose, shoulders, elbows, wrists (left before
  right), then per hand (left, then right): hand root, thumb tip, and MCP knuckle + tip of the
  index, middle, ring and little fingers. Edges are SL-GCN's ``sign_27`` graph
  (``inward_ori_index`` minus 5).

Subsets (``SUBSETS[layout][name]``, node indices into the layout), for ST-GCN on fewer nodes:
- mediapipe_pose ``all`` (33); ``upper_body`` = 0..22 (face, shoulders, arms, hands; the hips
  23-24 are left out because WLASL framing cuts at the waist: their mean visibility on the 291
  real clips is 0.33 against >= 0.63 for every arm and hand landmark); ``thesis`` = 0, 2, 5,
  11..22 (nose, eye centres, shoulders, elbows, wrists, and the pinky/index knuckles and thumbs
  that Pose provides: the keypoints of the thesis' 27-point set that exist in Pose).
- sign27 ``all`` (27).
The edges of a subset connect two kept nodes when the full graph links them directly or through
dropped nodes only (so nose-eye survives dropping the inner eye corners: 0-1-2 becomes 0-2).
"""

from __future__ import annotations

from collections import deque

from aslexp.data.dataset import DataError, KeypointLayout
from aslexp.pose.slgcn27 import NAME as SLGCN27_SUBSET, SIGN27, slgcn27_subset

MEDIAPIPE_POSE = KeypointLayout(
    name="mediapipe_pose",
    names=(
        "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
        "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right",
        "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
        "right_wrist", "left_pinky", "right_pinky", "left_index", "right_index", "left_thumb",
        "right_thumb", "left_hip", "right_hip", "left_knee", "right_knee", "left_ankle",
        "right_ankle", "left_heel", "right_heel", "left_foot_index", "right_foot_index",
    ),
    edges=(
        (0, 1), (1, 2), (2, 3), (3, 7), (0, 4), (4, 5), (5, 6), (6, 8), (9, 10),
        (11, 12), (11, 13), (13, 15), (15, 17), (15, 19), (15, 21), (17, 19),
        (12, 14), (14, 16), (16, 18), (16, 20), (16, 22), (18, 20),
        (11, 23), (12, 24), (23, 24), (23, 25), (24, 26), (25, 27), (26, 28),
        (27, 29), (28, 30), (29, 31), (30, 32), (27, 31), (28, 32),
        (0, 11), (0, 12), (0, 9), (0, 10),  # connect face, mouth and body (not in MediaPipe's list)
    ),
    center=0,
    channels=("x", "y", "z", "visibility"),
)  # fmt: skip

# SL-GCN's 27 points live in their own block (pose/slgcn27.py) with the maps onto other layouts.
LAYOUTS: dict[str, KeypointLayout] = {layout.name: layout for layout in (MEDIAPIPE_POSE, SIGN27)}

SUBSETS: dict[str, dict[str, tuple[int, ...]]] = {
    "mediapipe_pose": {
        "all": tuple(range(33)),
        "upper_body": tuple(range(23)),
        "thesis": (0, 2, 5, *range(11, 23)),
    },
    "sign27": {"all": tuple(range(27))},
}


def get_layout(name: str) -> KeypointLayout:
    try:
        return LAYOUTS[name]
    except KeyError:
        raise DataError(f"unknown keypoint layout {name!r}; expected one of {sorted(LAYOUTS)}") from None


def generic_layout(num_nodes: int, channels: tuple[str, ...], name: str = "generic") -> KeypointLayout:
    """A layout without a skeleton (no edges), for arrays whose node order is not known here."""
    return KeypointLayout(name=name, names=tuple(f"node_{i}" for i in range(num_nodes)),
                          edges=(), center=0, channels=tuple(channels))  # fmt: skip


def register_subsets(layout_name: str, subsets: dict[str, tuple[int, ...]]) -> None:
    """Offer named subsets for a layout described elsewhere (e.g. a self-describing layout.json)."""
    SUBSETS.setdefault(layout_name, {}).update(
        {name: tuple(int(i) for i in indices) for name, indices in subsets.items() if name != "all"}
    )


def subset_names(layout: KeypointLayout) -> tuple[str, ...]:
    """Names of the subsets offered for ``layout`` ('all' always exists; 'slgcn27' for any layout
    that pose/slgcn27.py maps onto SL-GCN's 27 points)."""
    return tuple(SUBSETS.get(layout.name, {"all": ()})) + (SLGCN27_SUBSET,)


def subset_indices(layout: KeypointLayout, subset: str | None) -> tuple[int, ...]:
    if subset in (None, "all"):
        return tuple(range(layout.num_nodes))
    options = SUBSETS.get(layout.name, {})
    if subset not in options:
        raise DataError(f"layout {layout.name!r} has no keypoint subset {subset!r}; "
                        f"expected one of {['all', *[s for s in options if s != 'all']]}")  # fmt: skip
    return options[subset]


def induced_edges(edges, keep: tuple[int, ...]) -> tuple[tuple[int, int], ...]:
    """Edges among ``keep`` (re-indexed 0..len(keep)-1), contracting paths through dropped nodes."""
    position = {node: i for i, node in enumerate(keep)}
    neighbours: dict[int, set[int]] = {}
    for i, j in edges:
        neighbours.setdefault(i, set()).add(j)
        neighbours.setdefault(j, set()).add(i)
    result = set()
    for start in keep:
        seen, queue = {start}, deque(neighbours.get(start, ()))
        while queue:
            node = queue.popleft()
            if node in seen:
                continue
            seen.add(node)
            if node in position:
                a, b = sorted((position[start], position[node]))
                result.add((a, b))
            else:  # a dropped node: walk through it
                queue.extend(neighbours.get(node, ()))
    return tuple(sorted(result))


def subset_layout(layout: KeypointLayout, subset: str | None) -> tuple[KeypointLayout, tuple[int, ...]]:
    """The layout restricted to a named subset, and the kept node indices into ``layout``."""
    if subset == SLGCN27_SUBSET:  # SL-GCN's own graph over the points the layout has
        return slgcn27_subset(layout)
    keep = subset_indices(layout, subset)
    if subset in (None, "all"):
        return layout, keep
    center = keep.index(layout.center) if layout.center in keep else 0
    restricted = KeypointLayout(
        name=f"{layout.name}_{subset}",
        names=tuple(layout.names[i] for i in keep),
        edges=induced_edges(layout.edges, keep),
        center=center,
        channels=layout.channels,
    )
    return restricted, keep
