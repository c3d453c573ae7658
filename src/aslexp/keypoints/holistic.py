"""The MediaPipe Holistic keypoint layout: names, skeleton edges, centre and subsets.

Pure standard library on purpose: the extraction worker imports this file from the
MediaPipe environment (numpy<2) and the data layer imports it from the main one.

Node order of every extracted array (V = 75):

    0..32   the 33 MediaPipe Pose body landmarks (``NOSE`` ... ``RIGHT_FOOT_INDEX``)
    33..53  the 21 landmarks of the signer's LEFT hand (``WRIST``, ``THUMB_CMC`` ... ``PINKY_TIP``)
    54..74  the 21 landmarks of the signer's RIGHT hand

"left" and "right" are the signer's anatomical sides (videos are not mirrored).
"""

from __future__ import annotations

POSE_NAMES: tuple[str, ...] = (
    "nose", "left_eye_inner", "left_eye", "left_eye_outer", "right_eye_inner", "right_eye",
    "right_eye_outer", "left_ear", "right_ear", "mouth_left", "mouth_right", "left_shoulder",
    "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist", "left_pinky",
    "right_pinky", "left_index", "right_index", "left_thumb", "right_thumb", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle", "left_heel",
    "right_heel", "left_foot_index", "right_foot_index",
)  # fmt: skip
HAND_NAMES: tuple[str, ...] = (
    "wrist", "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip",
    "index_mcp", "index_pip", "index_dip", "index_tip",
    "middle_mcp", "middle_pip", "middle_dip", "middle_tip",
    "ring_mcp", "ring_pip", "ring_dip", "ring_tip",
    "pinky_mcp", "pinky_pip", "pinky_dip", "pinky_tip",
)  # fmt: skip

NUM_POSE = len(POSE_NAMES)  # 33
NUM_HAND = len(HAND_NAMES)  # 21
LEFT_HAND_OFFSET = NUM_POSE  # 33
RIGHT_HAND_OFFSET = NUM_POSE + NUM_HAND  # 54
NUM_NODES = NUM_POSE + 2 * NUM_HAND  # 75
HAND_NODES: tuple[int, ...] = tuple(range(LEFT_HAND_OFFSET, NUM_NODES))  # both hands, left first
# The body nodes pose-format's reduce_holistic keeps: it drops every POSE_LANDMARKS point whose name
# has EAR, NOSE, MOUTH, EYE, THUMB, PINKY, INDEX, KNEE, ANKLE, HEEL or FOOT_INDEX in it.
REDUCED_BODY: tuple[int, ...] = tuple(i for i, n in enumerate(POSE_NAMES)
                                      if n.endswith(("shoulder", "elbow", "wrist", "hip")))  # fmt: skip

NAMES: tuple[str, ...] = (
    POSE_NAMES
    + tuple(f"left_hand_{n}" for n in HAND_NAMES)
    + tuple(f"right_hand_{n}" for n in HAND_NAMES)
)

# MediaPipe's own POSE_CONNECTIONS and HAND_CONNECTIONS (mediapipe 0.10.21), copied so that
# the main environment needs no mediapipe.
POSE_EDGES: tuple[tuple[int, int], ...] = (
    (0, 1), (0, 4), (1, 2), (2, 3), (3, 7), (4, 5), (5, 6), (6, 8), (9, 10), (11, 12),
    (11, 13), (11, 23), (12, 14), (12, 24), (13, 15), (14, 16), (15, 17), (15, 19), (15, 21),
    (16, 18), (16, 20), (16, 22), (17, 19), (18, 20), (23, 24), (23, 25), (24, 26), (25, 27),
    (26, 28), (27, 29), (27, 31), (28, 30), (28, 32), (29, 31), (30, 32),
)  # fmt: skip
HAND_EDGES: tuple[tuple[int, int], ...] = (
    (0, 1), (0, 5), (0, 17), (1, 2), (2, 3), (3, 4), (5, 6), (5, 9), (6, 7), (7, 8), (9, 10),
    (9, 13), (10, 11), (11, 12), (13, 14), (13, 17), (14, 15), (15, 16), (17, 18), (18, 19),
    (19, 20),
)  # fmt: skip

# MediaPipe's graph plus links that make it one connected skeleton: the nose to the shoulders
# and to the mouth corners, and each body wrist to its hand's wrist.
EDGES: tuple[tuple[int, int], ...] = (
    POSE_EDGES
    + ((0, 11), (0, 12), (0, 9), (0, 10))
    + tuple((LEFT_HAND_OFFSET + i, LEFT_HAND_OFFSET + j) for i, j in HAND_EDGES)
    + tuple((RIGHT_HAND_OFFSET + i, RIGHT_HAND_OFFSET + j) for i, j in HAND_EDGES)
    + ((15, LEFT_HAND_OFFSET), (16, RIGHT_HAND_OFFSET))
)
CENTER = 0  # the nose: the one body landmark that is visible in every sign video

# Image channels of `<video_id>.npy`: x, y normalised to [0, 1] by the frame width and height,
# z MediaPipe's relative depth (same scale as x), visibility (pose: MediaPipe's visibility;
# hands: 1 where detected). Missing parts are NaN in every channel, never zero.
CHANNELS: tuple[str, ...] = ("x", "y", "z", "visibility")
WORLD_CHANNELS: tuple[str, ...] = ("x", "y", "z")


def _idx(name: str) -> int:
    return NAMES.index(name)


_FINGERS = ("index", "middle", "ring", "pinky")


def _upper_body_indices() -> list[int]:
    body = [i for i, n in enumerate(POSE_NAMES) if i <= 16 or n in ("left_hip", "right_hip")]
    hands = list(range(LEFT_HAND_OFFSET, NUM_NODES))
    return body + hands


# SL-GCN's 27 points are `pose.subset=slgcn27` (aslexp.keypoints.slgcn27), on this layout as on others.
SUBSETS: tuple[str, ...] = ("all", "upper_body")


def holistic_subset(name: str) -> list[int]:
    """Indices into the 75 holistic nodes of subset ``name`` ('all', 'upper_body')."""
    if name == "all":
        return list(range(NUM_NODES))
    if name == "upper_body":
        return _upper_body_indices()
    raise ValueError(f"unknown holistic keypoint subset {name!r}; expected one of {SUBSETS}")


def holistic_layout(subset: str = "all") -> dict:
    """Name, node names, edges (indices into the subset) and centre of a holistic subset.

    Plain dict with the keys of ``layout.json`` so that both environments can use it; the data
    layer turns it into its ``KeypointLayout``.
    """
    indices = holistic_subset(subset)
    position = {full: k for k, full in enumerate(indices)}
    edges = [(position[i], position[j]) for i, j in EDGES if i in position and j in position]
    name = "mediapipe_holistic" if subset == "all" else f"mediapipe_holistic_{subset}"
    return {
        "name": name,
        "names": [NAMES[i] for i in indices],
        "edges": [list(e) for e in edges],
        "center": position[CENTER],
    }


def layout_json(include_subsets: bool = True) -> dict:
    """The content of ``<out>/layout.json`` for the full 75-node arrays.

    Keys read by the data layer: name, names, edges, center, channels. Extra keys: the world
    channels of ``<video_id>.world.npy`` and each subset's indices, edges and centre.
    """
    data = holistic_layout("all")
    data["channels"] = list(CHANNELS)
    data["world_channels"] = list(WORLD_CHANNELS)
    if include_subsets:
        data["subsets"] = {
            name: {
                "indices": holistic_subset(name),
                "edges": holistic_layout(name)["edges"],
                "center": holistic_layout(name)["center"],
            }
            for name in SUBSETS
        }
    return data
