"""The built-in keypoint layouts and their named subsets (registered on import).

- ``mediapipe_pose``: the 33 MediaPipe Pose landmarks, channels (x, y, z, visibility); edges are
  MediaPipe's ``POSE_CONNECTIONS`` plus nose-shoulders and nose-mouth corners: in
  POSE_CONNECTIONS the face and the mouth pair are separate components, which would leave the body
  unreachable from the centre node (the nose) in ST-GCN's spatial partition.
  Subsets: ``all`` (33); ``upper_body`` = 0..22 (face, shoulders, arms, hands; the hips 23-24 are
  left out because WLASL framing cuts at the waist: their mean visibility on the 291 real clips
  is 0.33 against >= 0.63 for every arm and hand landmark); ``thesis`` = 0, 2, 5, 11..22 (nose,
  eye centres, shoulders, elbows, wrists, and the pinky/index knuckles and thumbs that Pose
  provides: the keypoints of the thesis' 27-point set that exist in Pose).
- ``mediapipe_holistic``: the 75 nodes of ``aslexp extract`` (33 body, the signer's left hand,
  the right hand; :mod:`aslexp.keypoints.holistic`), channels (x, y, z, visibility); subsets
  ``upper_body`` (61) and ``thesis27``.
- ``mediapipe_hands``: MediaPipe Hands, two hands x 21 landmarks, the signer's LEFT hand first
  (nodes 0-20), then the right (21-41), channels (x, y, z): the usual ``(T, 126)`` arrays of
  hand-only pipelines. Edges: MediaPipe's ``HAND_CONNECTIONS`` per hand plus wrist-wrist, so that
  one skeleton connects both hands (the spatial partition measures hops from one centre, the left
  wrist). Subsets ``left`` and ``right`` (21 each).
- ``sign27``: SL-GCN's 27-point subset of COCO-WholeBody (HRNet), channels (x, y, score), the
  thesis' published HRNet arrays. Node order = COCO-WholeBody indices
  [0, 5, 6, 7, 8, 9, 10, 91, 95, 96, 99, 100, 103, 104, 107, 108, 111,
   112, 116, 117, 120, 121, 124, 125, 128, 129, 132]: nose, shoulders, elbows, wrists (left before
  right), then per hand (left, then right): hand root, thumb tip, and MCP knuckle + tip of the
  index, middle, ring and little fingers. Edges are SL-GCN's ``sign_27`` graph
  (``inward_ori_index`` minus 5).

The edges of a subset connect two kept nodes when the full graph links them directly or through
dropped nodes only (so nose-eye survives dropping the inner eye corners: 0-1-2 becomes 0-2).
"""

from __future__ import annotations

from aslexp.keypoints import holistic as H
from aslexp.keypoints.layout import KeypointLayout
from aslexp.keypoints.registry import register_layout

MEDIAPIPE_POSE = register_layout(
    KeypointLayout(
        name="mediapipe_pose",
        names=H.POSE_NAMES,
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
    ),
    subsets={"upper_body": tuple(range(23)), "thesis": (0, 2, 5, *range(11, 23))},
)  # fmt: skip

MEDIAPIPE_HOLISTIC = register_layout(
    KeypointLayout.from_spec({**H.holistic_layout("all"), "channels": list(H.CHANNELS)}, "holistic.py"),
    subsets={name: tuple(H.holistic_subset(name)) for name in H.SUBSETS},
)

MEDIAPIPE_HANDS = register_layout(
    KeypointLayout(
        name="mediapipe_hands",
        names=tuple(f"{side}_hand_{n}" for side in ("left", "right") for n in H.HAND_NAMES),
        edges=(*H.HAND_EDGES, *((i + H.NUM_HAND, j + H.NUM_HAND) for i, j in H.HAND_EDGES), (0, H.NUM_HAND)),
        center=0,
        channels=("x", "y", "z"),
    ),
    subsets={"left": tuple(range(H.NUM_HAND)), "right": tuple(range(H.NUM_HAND, 2 * H.NUM_HAND))},
)

_HAND_POINTS = ("root", "thumb_tip", "index_mcp", "index_tip", "middle_mcp", "middle_tip",
                "ring_mcp", "ring_tip", "little_mcp", "little_tip")  # fmt: skip
SIGN27_COCO_WHOLEBODY = (0, 5, 6, 7, 8, 9, 10, 91, 95, 96, 99, 100, 103, 104, 107, 108, 111,
                         112, 116, 117, 120, 121, 124, 125, 128, 129, 132)  # fmt: skip
_SIGN27_EDGES_ORIGINAL = (
    (5, 6), (5, 7), (6, 8), (8, 10), (7, 9), (9, 11),
    (12, 13), (12, 14), (12, 16), (12, 18), (12, 20), (14, 15), (16, 17), (18, 19), (20, 21),
    (22, 23), (22, 24), (22, 26), (22, 28), (22, 30), (24, 25), (26, 27), (28, 29), (30, 31),
    (10, 12), (11, 22),
)  # fmt: skip
SIGN27 = register_layout(
    KeypointLayout(
        name="sign27",
        names=(
            "nose", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist",
            "right_wrist",
            *(f"left_hand_{p}" for p in _HAND_POINTS),
            *(f"right_hand_{p}" for p in _HAND_POINTS),
        ),
        edges=tuple((i - 5, j - 5) for i, j in _SIGN27_EDGES_ORIGINAL),
        center=0,
        channels=("x", "y", "score"),
    )
)
