"""Keypoint distance after time alignment: how close a performance's keypoints are to a signer's.

Both sequences are image keypoints of one frame (aslexp's (T, 75, >= 2) Holistic arrays,
normalised by the frame size, NaN where missing), compared in pixels and each **normalised by its
own shoulders** as pose-format's ``Pose.normalize`` (which pose-evaluation runs first) does: the
mean shoulder midpoint over the frames moved to the origin, lengths divided by the mean shoulder
distance, so every number is in shoulder widths. The distance per frame is Euclidean in the image
plane: in a pose-format file x and y are pixels and z MediaPipe's unitless relative depth (about
1/width the scale), so the toolkit's 3-D distance is this one to a fraction of a percent.

Per part (:data:`aslexp.pose.source_frame.PARTS`: the body's nose, ears, shoulders, elbows,
wrists; each hand's 21 points):

- ``dtw_mje``: DTW mean joint error. The frames, as vectors of the part's points, are aligned by
  dynamic time warping (dtaidistance's ``dtw_ndim.warping_path``: Euclidean between frames); the
  score is the joint error averaged over the part's points and over the aligned pairs of frames.
- ``dtwp`` (both hands together): pose-evaluation's ``DTWp`` measure
  (``DTWDTAIImplementationDistanceMeasure``): for each hand point its trajectory is aligned on
  its own (``dtw_ndim.distance_fast``, the square root of the summed squared distances along the
  best path) and the distances are averaged over the points. pose-evaluation fills a point it
  lacks with 10.0 (pixels); here a point the reference never has is left out of the mean and
  counted (``points``), and frames where a point is missing are dropped from that point's
  trajectory: a hand MediaPipe lost in the source is no error of the performance.

- ``handshape`` (each hand apart, and their mean): the shape of the hand alone. Each frame's 20
  finger points, with MediaPipe's depth, are put in the palm's own frame (wrist at the origin,
  turned with the palm) and divided by the hand's size (wrist to the middle finger's base), so where
  the hand is, how it is turned and how large it is drop out; then ``dtw_mje`` as above, in hand
  sizes. The image-frame ``dtwp`` is dominated by where the hand is (the arm): retargeting settings
  that change the fingers move it by under 1%; this one sees the fingers.

Masking: frames where a part lacks a point are dropped from that part's sequence (DTW aligns what
remains); points a sequence never has are left out; a part the reference never has scores
``None`` with a ``note``. A zero means the same keypoints up to timing.
"""

from __future__ import annotations

import numpy as np

from aslexp.keypoints import holistic as H
from aslexp.pose.source_frame import LEFT_SHOULDER, PARTS, RIGHT_SHOULDER, pixels

HAND_NODES = tuple(range(H.LEFT_HAND_OFFSET, H.NUM_NODES))


def normalised(keypoints: np.ndarray, width: int, height: int) -> np.ndarray:
    """(T, V, 2) pixels, shoulder midpoint (mean over frames) at 0, mean shoulder width 1."""
    px = pixels(keypoints, width, height)
    both = np.isfinite(px[:, [LEFT_SHOULDER, RIGHT_SHOULDER]]).all(axis=(1, 2))
    if not both.any():
        raise ValueError("no frame with both shoulders: nothing to normalise by")
    left, right = px[both, LEFT_SHOULDER], px[both, RIGHT_SHOULDER]
    centre = ((left + right) / 2).mean(axis=0)
    unit = float(np.linalg.norm(left - right, axis=-1).mean())
    return (px - centre) / unit


def _part_frames(points: np.ndarray, columns: np.ndarray) -> np.ndarray:
    """The frames (rows) of ``points`` (T, J, 2) that have every point in ``columns``."""
    return points[np.isfinite(points[:, columns]).all(axis=(1, 2))][:, columns]


def dtw_mje(hypothesis: np.ndarray, reference: np.ndarray) -> dict:
    """DTW mean joint error of two (T, J, 2) normalised sequences of one part (module doc)."""
    from dtaidistance import dtw_ndim

    columns = np.isfinite(hypothesis).all(-1).any(0) & np.isfinite(reference).all(-1).any(0)
    if not columns.any():
        return {"dtw_mje": None, "note": "no point in both"}
    hyp, ref = _part_frames(hypothesis, columns), _part_frames(reference, columns)
    if not len(hyp) or not len(ref):
        return {"dtw_mje": None, "note": "no frame with all of the part's points"}
    path = np.asarray(dtw_ndim.warping_path(np.ascontiguousarray(hyp.reshape(len(hyp), -1)),
                                            np.ascontiguousarray(ref.reshape(len(ref), -1)), use_c=True))  # fmt: skip
    errors = np.linalg.norm(hyp[path[:, 0]] - ref[path[:, 1]], axis=-1)  # (path, J)
    return {"dtw_mje": round(float(errors.mean()), 5), "points": int(columns.sum()),
            "frames": [len(hyp), len(ref)], "path": len(path)}  # fmt: skip


def dtwp(hypothesis: np.ndarray, reference: np.ndarray) -> dict:
    """pose-evaluation's per-point DTW, averaged over the points both have (module doc); inputs
    (T, J, 2) normalised."""
    from dtaidistance import dtw_ndim

    distances = []
    for k in range(hypothesis.shape[1]):
        hyp = hypothesis[np.isfinite(hypothesis[:, k]).all(-1), k]
        ref = reference[np.isfinite(reference[:, k]).all(-1), k]
        if len(hyp) and len(ref):
            distances.append(dtw_ndim.distance_fast(np.ascontiguousarray(hyp, dtype=np.float64),
                                                    np.ascontiguousarray(ref, dtype=np.float64)))  # fmt: skip
    if not distances:
        return {"dtwp": None, "note": "no hand point in both"}
    return {"dtwp": round(float(np.mean(distances)), 5), "points": len(distances)}


HAND_SIZE = (0, H.HAND_NAMES.index("middle_mcp"))  # the hand's size: wrist to the middle finger's base
PALM_ACROSS = (H.HAND_NAMES.index("index_mcp"), H.HAND_NAMES.index("pinky_mcp"))


def hand_local(points: np.ndarray, width: int, height: int, flip_depth: bool = False) -> np.ndarray:
    """(T, 21, >= 3) one hand's image keypoints (x, y normalised; z MediaPipe's depth, x's scale) ->
    (T, 20, 3) its fingers in the palm's own frame, in hand sizes: origin the wrist, axes wrist to
    middle-finger base, then index base to pinky base (made orthogonal) and their cross product;
    lengths divided by the sequence's median wrist-to-middle-base distance. Where the hand is, how
    it is turned and how large it is drop out; its shape stays."""
    p = np.asarray(points, dtype=np.float64)[..., :3] * np.array([width, height, -width if flip_depth else width])
    up = p[:, HAND_SIZE[1]] - p[:, HAND_SIZE[0]]
    across = p[:, PALM_ACROSS[0]] - p[:, PALM_ACROSS[1]]
    size = np.linalg.norm(up, axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        e1 = up / size[:, None]
        e2 = across - (across * e1).sum(-1, keepdims=True) * e1
        e2 = e2 / np.linalg.norm(e2, axis=-1, keepdims=True)
        axes = np.stack([e1, e2, np.cross(e1, e2)], axis=1)  # (T, 3, 3): rows are the palm's axes
        scale = float(np.median(size[np.isfinite(size)])) if np.isfinite(size).any() else np.nan
        return np.einsum("tij,tkj->tki", axes, p[:, 1:] - p[:, :1]) / scale


def handshape(hypothesis: np.ndarray, reference: np.ndarray, width: int, height: int) -> dict:
    """The hand's shape alone (module doc): the DTW mean joint error of the fingers in the palm's
    frame (:func:`hand_local`), in hand sizes; (T, 21, >= 3) image keypoints of one hand each."""
    out = dtw_mje(hand_local(hypothesis, width, height), hand_local(reference, width, height))
    return {"handshape": out.pop("dtw_mje"), **out}


def hand_scores(hypothesis: np.ndarray, reference: np.ndarray, width: int, height: int, side: str) -> dict:
    """One hand's scores (``side``: right | left) of (T, 75, >= 2) image keypoints: its ``dtw_mje``,
    ``dtwp`` and ``handshape`` (module doc), in shoulder widths and palm lengths."""
    nodes = list(PARTS[f"{side}_hand"])
    hyp, ref = normalised(hypothesis, width, height)[:, nodes], normalised(reference, width, height)[:, nodes]
    if not np.isfinite(ref).all(-1).any():
        return {"dtw_mje": None, "dtwp": None, "handshape": None, "note": f"the {side} hand is not in the reference"}
    return {"dtw_mje": dtw_mje(hyp, ref)["dtw_mje"], "dtwp": dtwp(hyp, ref)["dtwp"],
            "handshape": handshape(hypothesis[:, nodes], reference[:, nodes], width, height)["handshape"]}


def dtw_scores(hypothesis: np.ndarray, reference: np.ndarray, width: int, height: int) -> dict:
    """Scores of a performance (``hypothesis``) against a signer (``reference``), both (T, 75, >= 2)
    normalised image keypoints of a ``width`` x ``height`` frame: per part ``dtw_mje`` and, for the
    hands, ``dtwp`` (module doc); in shoulder widths."""
    hyp, ref = normalised(hypothesis, width, height), normalised(reference, width, height)
    out: dict = {"units": "shoulder widths"}
    for part, nodes in PARTS.items():
        seen = np.isfinite(ref[:, nodes]).all(-1).any()
        out[part] = dtw_mje(hyp[:, nodes], ref[:, nodes]) if seen else {"dtw_mje": None, "note": "not in the reference"}
    out["hands"] = dtwp(hyp[:, HAND_NODES], ref[:, HAND_NODES])
    shapes = {side: handshape(hypothesis[:, list(PARTS[f"{side}_hand"])], reference[:, list(PARTS[f"{side}_hand"])],
                              width, height)
              for side in ("left", "right") if np.isfinite(ref[:, list(PARTS[f"{side}_hand"])]).all(-1).any()}
    values = [v["handshape"] for v in shapes.values() if v["handshape"] is not None]
    out["handshape"] = {"handshape": round(float(np.mean(values)), 5) if values else None,
                        **{side: v["handshape"] for side, v in shapes.items()}}
    return out
