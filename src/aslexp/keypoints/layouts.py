"""The built-in keypoint layouts and their named subsets (registered on import).

- ``mediapipe_pose``: the 33 MediaPipe Pose landmarks, channels (x, y, z, visibility); edges are
  MediaPipe's ``POSE_CONNECTIONS`` plus nose-shoulders and nose-mouth corners: in
  POSE_CONNECTIONS the face and the mouth pair are separate components, which would leave the body
  unreachable from the centre node (the nose) in ST-GCN's spatial partition.
  Subsets: ``all`` (33); ``upper_body`` = 0..22 (face, shoulders, arms, hands; the hips 23-24 are
  left out because WLASL framing cuts at the waist: their mean visibility on the 291 real clips
  is 0.33 against >= 0.63 for every arm and hand landmark); ``slgcn27`` (13: the points of
  SL-GCN's 27 that Pose has, :mod:`aslexp.keypoints.slgcn27`).
- ``mediapipe_holistic``: the 75 nodes of ``aslexp extract`` (33 body, the signer's left hand,
  the right hand; :mod:`aslexp.keypoints.holistic`), channels (x, y, z, visibility); subsets
  ``upper_body`` (61) and ``slgcn27`` (all 27 of SL-GCN's points).
- ``mediapipe_holistic_reduced``: what pose-format's ``reduce_holistic`` keeps of Holistic for the
  body and hands: 8 body landmarks (shoulders, elbows, wrists, hips; no face, no feet, no pose
  "hand" points) then both hands (21 each), 50 nodes, channels (x, y, z, visibility); edges those of
  ``mediapipe_holistic`` contracted through the dropped nodes; centre the left shoulder (there is
  no nose). Subset ``slgcn27``: 26 of SL-GCN's 27 points (all but the nose).
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
from aslexp.keypoints.layout import KeypointLayout, restrict
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
    subsets={"upper_body": tuple(range(23))},
)  # fmt: skip

MEDIAPIPE_HOLISTIC = register_layout(
    KeypointLayout.from_spec({**H.holistic_layout("all"), "channels": list(H.CHANNELS)}, "holistic.py"),
    subsets={name: tuple(H.holistic_subset(name)) for name in H.SUBSETS},
)

MEDIAPIPE_HOLISTIC_REDUCED = register_layout(
    restrict(MEDIAPIPE_HOLISTIC, H.REDUCED_BODY + H.HAND_NODES, "mediapipe_holistic_reduced"))  # fmt: skip

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

# SL-GCN's 27 points (the thesis' published HRNet arrays) and the maps onto them: one block.
from aslexp.keypoints.slgcn27 import SIGN27  # noqa: E402  (registers sign27 and pose.subset=slgcn27)
