"""Landmarks filtered in time before inverse kinematics, and the flicker of a held handshape.

MediaPipe's landmarks jitter from frame to frame; retargeted one frame at a time, a hand the person
holds still becomes fingers that open and close. :class:`LandmarkFilter` smooths each landmark's
trajectory with a maintained linear filter from scipy (Savitzky-Golay, which keeps a movement's
peaks better than a Gaussian of the same width, or a Gaussian), over each run of frames where the
point is seen (a gap is never bridged: the retargeting fills gaps afterwards). Being linear, the
filter smooths the fingers relative to the wrist exactly as it smooths the points themselves.

:func:`held_handshape_flicker` measures what the filter is for: the finger angles' spread over
frames where the source hand holds its shape (the distances between its points change by less
than 8% of the hand's size within 0.2 s either side). Zero is a held handshape held still.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

KINDS = ("none", "savgol", "gaussian")

# A held handshape: within the STILL_WINDOW_S seconds around a frame, the distances between the hand's
# points differ from that frame's, on average, by less than STILL_SHARE of the hand's size (wrist to
# middle knuckle) at every frame; runs of at least STILL_MIN_FRAMES such frames are measured. On the six WLASL videos MediaPipe's world hands
# jitter by 0.015-0.056 hand sizes a frame (median), so a held hand reads about 0.02-0.07 over 0.4 s.
STILL_WINDOW_S = 0.4
STILL_SHARE = 0.08
STILL_MIN_FRAMES = 5


@dataclass(frozen=True)
class LandmarkFilter:
    """``kind`` none | savgol | gaussian; ``window`` the Savitzky-Golay window or twice the Gaussian's
    sigma, in seconds (so one setting serves 25 and 30 fps); ``order`` the Savitzky-Golay polynomial."""

    kind: str
    window: float
    order: int

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"retargeting.filter.kind={self.kind!r}: expected one of {', '.join(KINDS)}")
        if not np.isfinite(self.window) or self.window < 0:
            raise ValueError(f"retargeting.filter.window={self.window}: expected seconds >= 0")
        if self.kind == "savgol" and not 0 <= int(self.order) <= 5:
            raise ValueError(f"retargeting.filter.order={self.order}: expected a polynomial order of 0 to 5")

    @classmethod
    def parse(cls, section: dict | None) -> "LandmarkFilter":
        section = dict(section or {})
        unknown = set(section) - {"kind", "window", "order"}
        if unknown:
            raise ValueError(f"retargeting.filter: unknown keys {sorted(unknown)}; expected kind, window, order")
        return cls(str(section.get("kind", "none")), float(section.get("window", 0.0)), int(section.get("order", 2)))

    def frames(self, fps: float) -> int:
        """The Savitzky-Golay window in frames (odd, at least order + 2)."""
        n = max(int(round(self.window * fps)), int(self.order) + 2)
        return n if n % 2 else n + 1

    def apply(self, points: np.ndarray, fps: float) -> np.ndarray:
        """(T, K, D) landmarks (NaN where unseen) -> the same, filtered along time per point."""
        points = np.asarray(points, dtype=float)
        if self.kind == "none" or self.window <= 0 or len(points) < 3:
            return points
        out = points.copy()
        seen = np.isfinite(points).all(axis=-1)  # (T, K)
        # points seen in the same frames (a MediaPipe hand comes whole or not at all) are filtered together
        patterns: dict[bytes, list[int]] = {}
        for k in range(points.shape[1]):
            patterns.setdefault(seen[:, k].tobytes(), []).append(k)
        for columns in patterns.values():
            mask = seen[:, columns[0]]
            for start, stop in _runs(mask):
                out[start:stop, columns] = self._filter(points[start:stop, columns], fps)
        return out

    def _filter(self, run: np.ndarray, fps: float) -> np.ndarray:
        if self.kind == "gaussian":
            from scipy.ndimage import gaussian_filter1d

            return gaussian_filter1d(run, sigma=self.window * fps / 2, axis=0, mode="nearest")
        from scipy.signal import savgol_filter

        window = min(self.frames(fps), len(run) if len(run) % 2 else len(run) - 1)
        if window <= int(self.order):  # a run too short to fit the polynomial: left as seen
            return run
        return savgol_filter(run, window, int(self.order), axis=0, mode="interp")


def retargeting_options(section: dict) -> dict:
    """The ``retargeting`` section (conf/retargeting/) -> the keyword arguments of
    :func:`aslexp.pose.retarget.retarget_landmarks`; ValueError naming the key on a bad value."""
    section = dict(section)
    unknown = set(section) - {"hand", "torso", "sigma", "filter", "pose_hand_points"}
    if unknown:
        raise ValueError(f"retargeting: unknown keys {sorted(unknown)}; expected hand, torso, sigma, filter, "
                         "pose_hand_points")
    if not isinstance(section.get("pose_hand_points", False), bool):
        raise ValueError(f"retargeting.pose_hand_points={section.get('pose_hand_points')!r}: expected true or false")
    if section.get("hand") not in ("dominant", "right", "left"):
        raise ValueError(f"retargeting.hand={section.get('hand')!r}: expected dominant, right or left")
    if section.get("torso") not in ("vertical", "hips"):
        raise ValueError(f"retargeting.torso={section.get('torso')!r}: expected vertical or hips")
    try:
        sigma = float(section.get("sigma"))
    except (TypeError, ValueError):
        sigma = float("nan")
    if not np.isfinite(sigma) or sigma < 0:
        raise ValueError(f"retargeting.sigma={section.get('sigma')}: expected frames >= 0")
    try:
        landmark_filter = LandmarkFilter.parse(section.get("filter"))
    except TypeError as error:
        raise ValueError(f"retargeting.filter: {error}") from None
    return {"hand": section["hand"], "torso": section["torso"], "sigma": sigma, "landmark_filter": landmark_filter,
            "pose_hand_points": bool(section.get("pose_hand_points", False))}


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, stop) of each run of True in a (T,) mask."""
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    edges = np.flatnonzero(np.diff(padded))
    return list(zip(edges[0::2].tolist(), edges[1::2].tolist()))


def still_frames(hand: np.ndarray, fps: float) -> np.ndarray:
    """(T,) frames where a (T, 21, 3) hand (wrist first, NaN where unseen) holds its shape: its shape
    alone (the distances between its points: turning or moving the hand is no change of shape)."""
    hand = np.asarray(hand, dtype=float)
    upper = np.triu_indices(hand.shape[1], 1)
    distances = np.linalg.norm(hand[:, :, None] - hand[:, None, :], axis=-1)[:, upper[0], upper[1]]
    size = np.nanmedian(np.linalg.norm(hand[:, 9] - hand[:, 0], axis=-1)) if np.isfinite(hand).any() else np.nan
    half = max(int(round(STILL_WINDOW_S * fps / 2)), 1)
    still = np.zeros(len(hand), dtype=bool)
    if not np.isfinite(size) or size <= 0 or len(hand) <= 2 * half:
        return still
    centre = distances[half:len(hand) - half]
    # the largest change of shape from each frame to any frame within the window around it
    changed = np.max([np.abs(distances[half + k:len(hand) - half + k] - centre).mean(axis=-1)
                      for k in range(-half, half + 1)], axis=0) / size
    with np.errstate(invalid="ignore"):
        still[half:len(hand) - half] = changed < STILL_SHARE  # NaN (unseen in the window) is never still
    return still


def held_handshape_flicker(angles: np.ndarray, still: np.ndarray) -> dict:
    """The finger angles' (T, J) standard deviation over each run of held frames (``still``), averaged
    over joints and weighted by the runs' lengths: radians; None without a run long enough."""
    runs = [(a, b) for a, b in _runs(np.asarray(still, dtype=bool)) if b - a >= STILL_MIN_FRAMES]
    if not runs:
        return {"flicker_rad": None, "held_frames": 0, "runs": 0}
    spread = [np.asarray(angles[a:b], dtype=float).std(axis=0).mean() for a, b in runs]
    weights = [b - a for a, b in runs]
    return {"flicker_rad": round(float(np.average(spread, weights=weights)), 5), "held_frames": int(sum(weights)),
            "runs": len(runs), "held": [[a, b] for a, b in runs]}
