"""SL-GCN's 27-point keypoint layout and how other keypoint layouts map onto it: one block.

SL-GCN (Jiang et al. 2021, "Skeleton Aware Multi-modal Sign Language Recognition", public code
jackyjsy/CVPR21Chal-SLR, ``SL-GCN/data_gen/sign_gendata.py`` selection ``'27'`` and
``SL-GCN/graph/sign_27.py``), which the thesis' chapter 4 runs (tfederico/ASLPhoneticClassification,
``SL-GCN/``), reads 27 of the 133 COCO-WholeBody points (HRNet):

    0 nose, 1-2 shoulders, 3-4 elbows, 5-6 wrists (left before right), then per hand (left
    7-16, right 17-26): the hand root (the hand model's own wrist), the thumb tip, and the
    MCP knuckle and the tip of the index, middle, ring and little fingers.

``EDGES`` is SL-GCN's ``sign_27`` graph (its ``inward_ori_index`` minus 5), each pair written
(parent, child) from the nose outwards, as there. THESIS.md G6: the thesis' prose ("nose, eyes,
shoulders, ..., thumbs, first/last knuckles") is a loose description of this set, which has no eyes
but has the hand roots; the published arrays and the code define the truth.

``MAPS[source layout][node] = (index into the source layout or None, quality)`` says where each of
the 27 points comes from in another layout; quality is

    exact        the same anatomical point
    approximate  a nearby point standing in for it (named in ``NOTES``)
    duplicate    the same point as another kept node (Pose has one wrist for body and hand)
    missing      the source has no such point

:func:`slgcn27_subset` restricts a source layout to the points it really has (exact and
approximate ones), in SL-GCN order, with SL-GCN's edges contracted through the points it lacks:
an honest layout, not 27 nodes of which some are always zero. What the 27 points become:

- ``sign27`` (the thesis' published HRNet arrays) and ``mediapipe_holistic`` (MediaPipe Holistic,
  75 nodes, written by ``aslexp extract``): all 27, exact.
- ``mediapipe_holistic_reduced`` (pose-format's ``reduce_holistic``, read from ``.pose`` files):
  26, exact; no nose, so the centre is the left shoulder and the two shoulders are joined.
- ``mediapipe_hands`` (two hands, e.g. a hands-only ``.pose``): the 20 hand points, exact; the
  centre is the left hand root, joined to the right one.
- OpenPose ``.pose`` files read with their header's own layout (:mod:`aslexp.keypoints.posefile`),
  found by component and point name as pose-format writes them (:data:`HEADER_POINTS`): BODY_25 +
  both hands (``pose_keypoints_2d``, ``hand_left_keypoints_2d``, ``hand_right_keypoints_2d``;
  pose-format's ``load_openpose``): all 27, exact; BODY_135 (``load_openpose_135_directory``): 25,
  the hand roots being the body wrists (duplicate). :func:`register_header_map` offers the subset
  on such a layout.
- ``mediapipe_pose`` (the shared data's 291 clips: 33 body landmarks, no fingers): 13 points.
  Exact: nose, shoulders, elbows, wrists (7). Approximate: per hand the index MCP (Pose's "index",
  the first knuckle), the little-finger MCP (Pose's "pinky", the first knuckle) and the thumb tip
  (Pose's "thumb", a thumb knuckle, not the tip) (6). Duplicate, dropped: the hand roots (= the
  wrists). Missing: per hand the index, middle, ring and little fingertips and the middle and ring
  MCPs (12 of 27). So on Pose no model sees finger shape: flexion and selected fingers cannot be
  read from these keypoints.
"""

from __future__ import annotations

from aslexp.errors import DataError
from aslexp.keypoints import holistic as H
from aslexp.keypoints.layout import KeypointLayout
from aslexp.keypoints.registry import register_layout
from aslexp.keypoints.subsets import register_subset_builder

NAME = "slgcn27"

HAND_POINTS = ("root", "thumb_tip", "index_mcp", "index_tip", "middle_mcp", "middle_tip",
               "ring_mcp", "ring_tip", "little_mcp", "little_tip")  # fmt: skip
NAMES: tuple[str, ...] = (
    "nose", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    *(f"left_hand_{p}" for p in HAND_POINTS),
    *(f"right_hand_{p}" for p in HAND_POINTS),
)  # fmt: skip
# The COCO-WholeBody index of each node (SL-GCN's selection '27').
COCO_WHOLEBODY = (0, 5, 6, 7, 8, 9, 10, 91, 95, 96, 99, 100, 103, 104, 107, 108, 111,
                  112, 116, 117, 120, 121, 124, 125, 128, 129, 132)  # fmt: skip
# SL-GCN's sign_27 inward_ori_index, minus 5, as (parent, child).
EDGES: tuple[tuple[int, int], ...] = (
    (0, 1), (0, 2), (1, 3), (3, 5), (2, 4), (4, 6),
    (7, 8), (7, 9), (7, 11), (7, 13), (7, 15), (9, 10), (11, 12), (13, 14), (15, 16),
    (17, 18), (17, 19), (17, 21), (17, 23), (17, 25), (19, 20), (21, 22), (23, 24), (25, 26),
    (5, 7), (6, 17),
)  # fmt: skip
CENTER = 0  # the nose

# The full 27-point layout as the thesis' published HRNet arrays hold it (x, y, score).
SIGN27 = register_layout(KeypointLayout(name="sign27", names=NAMES, edges=EDGES, center=CENTER,
                                         channels=("x", "y", "score")))

_POSE_INDEX = {"nose": 0, "left_shoulder": 11, "right_shoulder": 12, "left_elbow": 13, "right_elbow": 14,
               "left_wrist": 15, "right_wrist": 16}  # fmt: skip
_POSE_HAND = {"left": {"thumb_tip": 21, "index_mcp": 19, "little_mcp": 17},
              "right": {"thumb_tip": 22, "index_mcp": 20, "little_mcp": 18}}  # fmt: skip
_HOLISTIC_HAND = {"root": 0, "thumb_tip": 4, "index_mcp": 5, "index_tip": 8, "middle_mcp": 9, "middle_tip": 12,
                  "ring_mcp": 13, "ring_tip": 16, "little_mcp": 17, "little_tip": 20}  # fmt: skip
_HOLISTIC_HAND_OFFSET = {"left": 33, "right": 54}  # aslexp.keypoints.holistic: 33 pose, left hand, right hand


def _pose_map() -> dict[str, tuple[int | None, str]]:
    mapping: dict[str, tuple[int | None, str]] = {n: (i, "exact") for n, i in _POSE_INDEX.items()}
    for side in ("left", "right"):
        for point in HAND_POINTS:
            name = f"{side}_hand_{point}"
            if point == "root":
                mapping[name] = (None, "duplicate")
            elif point in _POSE_HAND[side]:
                mapping[name] = (_POSE_HAND[side][point], "approximate")
            else:
                mapping[name] = (None, "missing")
    return mapping


def _holistic_map() -> dict[str, tuple[int | None, str]]:
    mapping: dict[str, tuple[int | None, str]] = {n: (i, "exact") for n, i in _POSE_INDEX.items()}
    for side, offset in _HOLISTIC_HAND_OFFSET.items():
        mapping.update({f"{side}_hand_{p}": (offset + i, "exact") for p, i in _HOLISTIC_HAND.items()})
    return mapping


def _by_name(names: tuple[str, ...]) -> dict[str, tuple[int | None, str]]:
    """The holistic map onto a layout whose nodes are some of the holistic ones (same names)."""
    position = {name: k for k, name in enumerate(names)}
    mapping: dict[str, tuple[int | None, str]] = {}
    for node, (index, _) in _holistic_map().items():
        k = position.get(H.NAMES[index])
        mapping[node] = (k, "exact") if k is not None else (None, "missing")
    return mapping


MAPS: dict[str, dict[str, tuple[int | None, str]]] = {
    "sign27": {name: (i, "exact") for i, name in enumerate(NAMES)},
    "mediapipe_holistic": _holistic_map(),
    "mediapipe_pose": _pose_map(),
    # Read from .pose files by name (aslexp.keypoints.posefile): pose-format's reduced Holistic has
    # no nose; hands-only files have no body.
    "mediapipe_holistic_reduced": _by_name(tuple(H.NAMES[i] for i in H.REDUCED_BODY + H.HAND_NODES)),
    "mediapipe_hands": _by_name(tuple(H.NAMES[i] for i in H.HAND_NODES)),
}
# SL-GCN's points in the headers pose-format writes for OpenPose, by (component, point) name;
# components are matched without case and without a _2d / _3d suffix, points without case.
# OpenPose's hand points are the same 21 as MediaPipe's, in the same order; pose-format names them
# one joint off the anatomy (its I_CMC is OpenPose's point 5, the index knuckle; I_DIP point 8,
# the tip), so the names below are pose-format's for those points. None: the point is another
# kept node (BODY_135's hands have no root of their own: the body wrist is it).
_OPENPOSE_BODY = {"nose": "Nose", "left_shoulder": "LShoulder", "right_shoulder": "RShoulder",
                  "left_elbow": "LElbow", "right_elbow": "RElbow", "left_wrist": "LWrist", "right_wrist": "RWrist"}  # fmt: skip
_OPENPOSE_HAND = {"root": "BASE", "thumb_tip": "T_IP", "index_mcp": "I_CMC", "index_tip": "I_DIP",
                  "middle_mcp": "M_CMC", "middle_tip": "M_DIP", "ring_mcp": "R_CMC", "ring_tip": "R_DIP",
                  "little_mcp": "P_CMC", "little_tip": "P_DIP"}  # fmt: skip
_BODY135_HAND = {"root": None, "thumb_tip": "Thumb4FingerTip", "index_mcp": "Index1Knuckles",
                 "index_tip": "Index4FingerTip", "middle_mcp": "Middle1Knuckles", "middle_tip": "Middle4FingerTip",
                 "ring_mcp": "Ring1Knuckles", "ring_tip": "Ring4FingerTip", "little_mcp": "Pinky1Knuckles",
                 "little_tip": "Pinky4FingerTip"}  # fmt: skip
HEADER_POINTS: dict[str, dict[str, tuple[str, str] | None]] = {
    "openpose": {
        **{node: ("pose_keypoints", point) for node, point in _OPENPOSE_BODY.items()},
        **{f"{side}_hand_{node}": (f"hand_{side}_keypoints", point)
           for side in ("left", "right") for node, point in _OPENPOSE_HAND.items()},
    },
    "openpose_135": {
        **{node: ("body_135", point) for node, point in _OPENPOSE_BODY.items()},
        **{f"{side}_hand_{node}": (("body_135", side[0].upper() + point) if point else None)
           for side in ("left", "right") for node, point in _BODY135_HAND.items()},
    },
}  # fmt: skip
ARMS = NAMES[1:7]  # shoulders, elbows, wrists


def _component_key(name: str) -> str:
    key = name.lower()
    return key[:-3] if key.endswith(("_2d", "_3d")) else key


def header_map(names: tuple[str, ...]) -> tuple[str, dict[str, tuple[int | None, str]]] | None:
    """The SL-GCN map onto a layout read from a ``.pose`` header (node names ``COMPONENT:POINT``):
    the format of :data:`HEADER_POINTS` it fits best and the map, or None when no format gives
    the arms (both shoulders, elbows, wrists) or a whole hand (its 10 points): fewer is no
    skeleton to sign with."""
    position = {}
    for k, name in enumerate(names):
        component, _, point = name.partition(":")
        position.setdefault((_component_key(component), point.lower()), k)
    hands = [{f"{side}_hand_{p}" for p in HAND_POINTS} - {f"{side}_hand_root"} for side in ("left", "right")]
    best = None
    for fmt, points in HEADER_POINTS.items():
        mapping: dict[str, tuple[int | None, str]] = {}
        for node in NAMES:
            where = points.get(node)
            k = None if where is None else position.get((where[0], where[1].lower()))
            quality = "exact" if k is not None else ("duplicate" if node in points and where is None else "missing")
            mapping[node] = (k, quality)
        exact = {node for node, (_, quality) in mapping.items() if quality == "exact"}
        usable = set(ARMS) <= exact or any(hand <= exact for hand in hands)
        if usable and (best is None or len(exact) > best[0]):
            best = (len(exact), fmt, mapping)
    return None if best is None else (best[1], best[2])


def register_header_map(layout: KeypointLayout) -> str | None:
    """Offer ``pose.subset=slgcn27`` on a layout read from a ``.pose`` header when its names fit
    :data:`HEADER_POINTS`; returns the format's name (None: not offered)."""
    found = header_map(layout.names)
    if found is None:
        return None
    MAPS[layout.name] = found[1]
    register_subset_builder(NAME, MAPS, slgcn27_subset)  # the builder's layouts, with this one
    return found[0]


NOTES = {
    "mediapipe_pose": {
        "thumb_tip": "Pose 'thumb' (a thumb knuckle, BlazePose topology), not the tip",
        "index_mcp": "Pose 'index' (the index finger's first knuckle)",
        "little_mcp": "Pose 'pinky' (the little finger's first knuckle)",
        "root": "the hand root is the wrist itself: Pose has one wrist for body and hand",
    },
}


def coverage(layout_name: str) -> dict[str, list[str]]:
    """The 27 node names grouped by quality (exact, approximate, duplicate, missing) for a source."""
    mapping = _map(layout_name)
    groups: dict[str, list[str]] = {"exact": [], "approximate": [], "duplicate": [], "missing": []}
    for name in NAMES:
        groups[mapping[name][1]].append(name)
    return groups


def _map(layout_name: str) -> dict[str, tuple[int | None, str]]:
    try:
        return MAPS[layout_name]
    except KeyError:
        raise DataError(f"keypoint subset {NAME!r}: no map from layout {layout_name!r} to SL-GCN's 27 points; "
                        f"known: {sorted(MAPS)}") from None  # fmt: skip


def contracted_edges(kept: list[int]) -> tuple[tuple[int, int], ...]:
    """SL-GCN's (parent, child) edges among the ``kept`` node ids (into NAMES), re-indexed to
    positions in ``kept``: a kept node hangs from its nearest kept ancestor."""
    parent = {child: par for par, child in EDGES}
    position = {node: k for k, node in enumerate(kept)}
    roots = _roots(kept)  # without the nose SL-GCN's tree falls apart: join its branches at the first
    edges = [(position[roots[0]], position[node]) for node in roots[1:]]
    for node in kept:
        ancestor = parent.get(node)
        while ancestor is not None and ancestor not in position:
            ancestor = parent.get(ancestor)
        if ancestor is not None:
            edges.append((position[ancestor], position[node]))
    return tuple(edges)


def _roots(kept: list[int]) -> list[int]:
    """The kept nodes with no kept ancestor: the nose alone when it is kept (the first is the centre)."""
    parent = {child: par for par, child in EDGES}
    roots = []
    for node in kept:
        ancestor = parent.get(node)
        while ancestor is not None and ancestor not in kept:
            ancestor = parent.get(ancestor)
        if ancestor is None:
            roots.append(node)
    return roots


def slgcn27_subset(layout: KeypointLayout) -> tuple[KeypointLayout, tuple[int, ...]]:
    """``layout`` restricted to the SL-GCN points it has (exact or approximate), in SL-GCN order.

    Returns the restricted layout (named ``<layout>_slgcn27``, SL-GCN node names, contracted SL-GCN
    edges, centre = the nose) and the kept indices into ``layout``.
    """
    mapping = _map(layout.name)
    kept = [k for k, name in enumerate(NAMES) if mapping[name][1] in ("exact", "approximate")]
    indices = tuple(int(mapping[NAMES[k]][0]) for k in kept)  # type: ignore[arg-type]
    if max(indices) >= layout.num_nodes:
        raise DataError(f"layout {layout.name!r} has {layout.num_nodes} nodes; the SL-GCN map needs index {max(indices)}")
    restricted = KeypointLayout(
        name=f"{layout.name}_{NAME}",
        names=tuple(NAMES[k] for k in kept),
        edges=contracted_edges(kept),
        center=kept.index(_roots(kept)[0]),  # the nose, or where there is none the first root
        channels=layout.channels,
    )
    return restricted, indices


register_subset_builder(NAME, MAPS, slgcn27_subset)  # pose.subset=slgcn27 on every mapped layout
