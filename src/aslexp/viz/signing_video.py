"""The person and the simulated signer side by side (a run's signing.mp4 / signing.gif).

Panels, left to right, each in the source's own image frame: the source video's frame (when the
video is known), the person's keypoints drawn as a skeleton (on that frame, else on a blank canvas
of the source's size), the agent's keypoints drawn the same way over a faint grey copy of the
person's, and a close-up of each signing hand (the person's beside the agent's, at one zoom).

Everything is arrays in, frames out (numpy and PIL): the caller says which points are what
(:class:`BodyLayout`) and which source frame each output frame shows. The framing comes from the
body: the top of the head (the face points, raised by the ears' distance), the waist (the hips)
and the hands' reach, over the whole clip and both signers.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFont

BACKGROUND = (26, 28, 32)  # a blank canvas
OFF_FRAME = (12, 12, 14)  # a video panel beyond the video's edge
GHOST = (98, 102, 110)  # the person's skeleton under the agent's
COLOURS = {"left": (66, 165, 245), "right": (255, 152, 0), "centre": (236, 236, 236)}  # the signer's sides
HEADER = 24  # pixels of the label strip above the panels
HAND_FILL = 136  # pixels the smaller of the two hands spans in its close-up (at least 128)
MIN_VISIBILITY = 0.5  # MediaPipe's own threshold: a body point below it counts as not seen


@dataclass(frozen=True)
class BodyLayout:
    """Which of the keypoints' points are what (indices into V)."""

    edges: tuple[tuple[int, int], ...]
    drawn: tuple[int, ...]  # the points drawn and framed (no legs)
    face: tuple[int, ...]
    ears: tuple[int, int]
    shoulders: tuple[int, int]
    hips: tuple[int, ...]
    sides: Mapping[str, tuple[int, ...]]  # "left"/"right" -> that side's arm and hand points (their colour)
    hands: Mapping[str, tuple[int, ...]]  # side -> the hand's own points (a hand tracker's)
    # side -> a body tracker's wrist, then its rough hand points (knuckles, thumb)
    body_hands: Mapping[str, tuple[int, ...]] = field(default_factory=dict)


@dataclass(frozen=True)
class Geometry:
    """Where the panels cut the source image: the main box (source pixels) and each hand's zoom."""

    box: tuple[float, float, float, float]  # left, top, right, bottom
    panel: tuple[int, int]  # width, height
    hands: tuple[str, ...]  # the signing hands, the signer's right first
    zoom: float  # close-up pixels per source pixel
    tile: int  # close-up side, pixels
    hand_size: Mapping[str, Mapping[str, float]]  # side -> who -> median extent, source pixels


def seen_points(keypoints: np.ndarray, layout: BodyLayout) -> np.ndarray:
    """(T, V) which points are there: finite, and a body point at MediaPipe's visibility or above
    (a hand tracker's points have visibility 1 where detected)."""
    points = np.asarray(keypoints, dtype=float)
    seen = np.isfinite(points[..., :2]).all(axis=-1)
    if points.shape[-1] > 3:
        hand = np.zeros(points.shape[1], dtype=bool)
        hand[[i for side in layout.hands.values() for i in side]] = True
        seen &= hand[None, :] | ~(points[..., 3] < MIN_VISIBILITY)
    for side, nodes in layout.hands.items():  # a hand tracker's hand: the body tracker's rough one is not drawn
        rough = list(layout.body_hands.get(side, ())[1:])
        if rough:
            seen[:, rough] &= ~seen[:, list(nodes)].any(axis=1, keepdims=True)
    return seen


def _hand_points(px: np.ndarray, seen: np.ndarray, layout: BodyLayout, side: str) -> np.ndarray:
    """(T, 2) a hand's centre per frame (NaN where not seen): its own points, else the body's."""
    out = np.full((len(px), 2), np.nan)
    for nodes in (layout.body_hands.get(side, ()), layout.hands[side]):  # the hand's own points win
        if not nodes:
            continue
        mask = seen[:, list(nodes)]
        have = mask.any(axis=1)
        values = np.where(mask[..., None], px[:, list(nodes)], 0.0).sum(axis=1)
        out[have] = values[have] / mask[have].sum(axis=1, keepdims=True)
    return out


def _hand_extent(px: np.ndarray, seen: np.ndarray, nodes: tuple[int, ...]) -> float:
    """Median over frames of a hand's bounding box's larger side (source pixels); NaN when never seen."""
    sizes = []
    for t in range(len(px)):
        points = px[t, list(nodes)][seen[t, list(nodes)]]
        if len(points) >= 3:
            sizes.append(float(np.max(points.max(axis=0) - points.min(axis=0))))
    return float(np.median(sizes)) if sizes else float("nan")


def signing_hands(person_seen: np.ndarray, layout: BodyLayout) -> tuple[str, ...]:
    """The hands that sign, the signer's right first: those the person's hand tracker saw in a tenth
    of the frames (a hand out of view can be "found" in a few: MediaPipe's detections differ by CPU);
    for a body-only source, those whose wrist the body tracker sees in a quarter of the frames."""
    order = [s for s in ("right", "left") if s in layout.hands]
    tracked = [s for s in order if person_seen[:, list(layout.hands[s])].any(axis=1).mean() >= 0.1]
    if tracked:
        return tuple(tracked)
    return tuple(s for s in order if layout.body_hands.get(s)
                 and person_seen[:, layout.body_hands[s][0]].mean() >= 0.25)  # fmt: skip


def _median_distance(points: np.ndarray, pair: tuple[int, int]) -> float:
    """Median over frames of the distance between two points (NaN where either is missing)."""
    d = np.linalg.norm(points[:, pair[0]] - points[:, pair[1]], axis=-1)
    return float(np.nanmedian(d)) if np.isfinite(d).any() else float("nan")


def body_box(person: np.ndarray, agent: np.ndarray, person_seen: np.ndarray, agent_seen: np.ndarray,
             layout: BodyLayout) -> tuple[float, float, float, float]:  # fmt: skip
    """(left, top, right, bottom) source pixels: every drawn point of both signers over the clip
    (the hands' reach), up to the top of the head (the face's highest point raised by the ears'
    distance: the eyes sit about that far below the crown) and down to the waist (the hips' median
    height: the person's where seen, else the agent's; without either, 1.4 shoulder widths below
    the shoulders), with a 6% margin."""
    person = np.where(person_seen[..., None], person, np.nan)  # what is not seen does not frame
    agent = np.where(agent_seen[..., None], agent, np.nan)
    both = np.concatenate([person, agent])
    drawn = both[:, list(layout.drawn)].reshape(-1, 2)
    if not np.isfinite(drawn).all(axis=1).any():
        raise ValueError("no point of either signer to frame")
    (left, top), (right, bottom) = np.nanmin(drawn, axis=0), np.nanmax(drawn, axis=0)
    shoulders = next((w for w in (_median_distance(p, layout.shoulders) for p in (person, agent)) if np.isfinite(w)),
                     right - left)  # fmt: skip
    ears = _median_distance(both, layout.ears)
    face = both[:, list(layout.face), 1]
    if np.isfinite(face).any():
        top = min(top, float(np.nanmin(face)) - (ears if np.isfinite(ears) else 0.4 * shoulders) * 0.8)
    hips = [p[:, list(layout.hips), 1] for p in (person, agent)]
    waist = next((float(np.nanmedian(h)) for h in hips if np.isfinite(h).any()),
                 float(np.nanmedian(both[:, list(layout.shoulders), 1])) + 1.4 * shoulders)  # fmt: skip
    bottom = max(bottom, waist)
    margin = 0.06 * max(right - left, bottom - top)
    return (float(left - margin), float(top - margin), float(right + margin), float(bottom + margin))


def frame_geometry(person: np.ndarray, agent: np.ndarray, person_seen: np.ndarray, agent_seen: np.ndarray,
                   layout: BodyLayout, panel_height: int = 360) -> Geometry:  # fmt: skip
    """The main box (:func:`body_box`, widened or heightened to an aspect within 0.5-2), its panel
    size (``panel_height`` high), the signing hands and the close-ups' one zoom: the smaller of
    the two hands (person, agent; the median of its box's larger side) spans HAND_FILL pixels."""
    left, top, right, bottom = body_box(person, agent, person_seen, agent_seen, layout)
    hands = signing_hands(person_seen, layout)
    sizes = {side: {who: _hand_extent(px, seen, layout.hands[side]) for who, px, seen in
                    (("person", person, person_seen), ("agent", agent, agent_seen))} for side in hands}  # fmt: skip
    known = [v for s in sizes.values() for v in s.values() if np.isfinite(v) and v > 0]
    smallest = min(known) if known else 0.1 * (bottom - top)  # no hand points at all: a tenth of the body
    zoom = HAND_FILL / smallest
    tile = int(np.clip(2 * round(max(known, default=smallest) * zoom / 0.8 / 2), 160, 320))  # the larger hand: 80%
    panel_height = max(int(panel_height), len(hands) * tile)  # the close-ups stack beside the panels
    aspect = float(np.clip((right - left) / (bottom - top), 0.5, 2.0))
    panel_w = 2 * int(round(panel_height * aspect / 2))
    middle, half = (left + right) / 2, (bottom - top) * panel_w / panel_height / 2  # the panel's exact aspect
    if 2 * half < right - left:  # wider than 2: heighten about the middle instead
        centre, rise = (top + bottom) / 2, (right - left) * panel_height / panel_w / 2
        half, top, bottom = (right - left) / 2, centre - rise, centre + rise
    box = (middle - half, top, middle + half, bottom)
    return Geometry(box, (panel_w, panel_height), hands, float(zoom), tile, sizes)


def _smooth(centres: np.ndarray, window: int = 5) -> np.ndarray:
    """(T, 2) a close-up's centre: gaps filled from the nearest seen frames, then a moving average
    (the crop follows the hand without shaking with the tracker)."""
    out = centres.copy()
    have = np.isfinite(out).all(axis=1)
    if not have.any():
        return out
    frames = np.arange(len(out))
    for k in range(2):
        out[:, k] = np.interp(frames, frames[have], out[have, k])
    pad = np.pad(out, ((window // 2, window // 2), (0, 0)), mode="edge")
    kernel = np.ones(window) / window
    return np.stack([np.convolve(pad[:, k], kernel, mode="valid") for k in range(2)], axis=1)


def _crop(image: Image.Image, box: tuple[float, float, float, float], size: tuple[int, int]) -> Image.Image:
    """``box`` (source pixels, may reach past the frame's edge) of a frame, resampled to ``size``."""
    return image.transform(size, Image.Transform.EXTENT, box, resample=Image.Resampling.BILINEAR,
                           fillcolor=OFF_FRAME)  # fmt: skip


def _edge_colour(layout: BodyLayout, i: int, j: int) -> tuple[int, int, int]:
    for side, nodes in layout.sides.items():
        if i in nodes and j in nodes:
            return COLOURS[side]
    return COLOURS["centre"]


def draw_skeleton(draw: ImageDraw.ImageDraw, px: np.ndarray, seen: np.ndarray, layout: BodyLayout,
                  origin: tuple[float, float], scale: float, width: int = 2, radius: float = 2.0,
                  colour: tuple[int, int, int] | None = None, nodes: Iterable[int] | None = None) -> None:  # fmt: skip
    """One frame's skeleton: ``px`` (V, 2) source pixels mapped by ``(px - origin) * scale``; each
    edge in its side's colour (or ``colour``), only between points seen (and among ``nodes``)."""
    keep = np.zeros(len(px), dtype=bool)
    keep[list(layout.drawn if nodes is None else nodes)] = True
    keep &= seen
    at = (px - np.asarray(origin)) * scale
    for i, j in layout.edges:
        if keep[i] and keep[j]:
            draw.line([tuple(at[i]), tuple(at[j])], fill=colour or _edge_colour(layout, i, j), width=width)
    for i in np.flatnonzero(keep):
        x, y = at[i]
        draw.ellipse([x - radius, y - radius, x + radius, y + radius], fill=colour or (250, 250, 250))


def read_video_frames(path: str | Path, first: int, wanted: Iterable[int], size: tuple[int, int]):
    """Yield (k, frame as a PIL image at ``size``) for each k in ``wanted`` of the video's frames
    ``first + k`` (0-based), decoded in order by imageio-ffmpeg's ffmpeg; a frame the video does
    not have is not yielded (a frame of another size is resized: the keypoints are normalised)."""
    import imageio_ffmpeg

    wanted = set(int(k) for k in wanted)
    frames = imageio_ffmpeg.read_frames(str(path))
    meta = next(frames)
    video_size = tuple(int(v) for v in meta["size"])
    try:
        for index, raw in enumerate(frames):
            k = index - int(first)
            if k in wanted:
                image = Image.frombuffer("RGB", video_size, raw, "raw", "RGB", 0, 1)
                yield k, image if video_size == tuple(size) else image.resize(size, Image.Resampling.BILINEAR)
                wanted.discard(k)
            if not wanted:
                break
    finally:
        frames.close()


def _label(pen: ImageDraw.ImageDraw, at: tuple[int, int], text: str, colour: tuple[int, int, int]) -> None:
    """Text on a dark box: readable over a video frame."""
    font = _font(13)
    left, top, right, bottom = pen.textbbox(at, text, font=font)
    pen.rectangle([left - 3, top - 2, right + 3, bottom + 2], fill=BACKGROUND)
    pen.text(at, text, fill=colour, font=font)


@dataclass
class SideBySide:
    """The frames and where each panel sits in them (x, y, width, height)."""

    frames: list[np.ndarray]
    panels: dict[str, list[int]]
    hands: dict[str, dict]  # side -> {"person": [x, y, w, h], "agent": ..., "person_px"/"agent_px": its size drawn}
    geometry: Geometry

    def describe(self) -> dict:
        height, width = self.frames[0].shape[:2]
        return {"size": [width, height], "frames": len(self.frames), "panels": self.panels, "hands": self.hands,
                "box": [round(v, 1) for v in self.geometry.box], "zoom": round(self.geometry.zoom, 3)}  # fmt: skip


@lru_cache(maxsize=4)
def _font(size: int):
    try:
        return ImageFont.load_default(size=size)
    except (TypeError, OSError):  # a Pillow without FreeType: its bitmap font
        return ImageFont.load_default()


def _backgrounds(video, person_px: np.ndarray, person_seen: np.ndarray, geometry: Geometry, layout: BodyLayout,
                 wanted: Iterable[int], size: tuple[int, int]):  # fmt: skip
    """Per wanted source frame k: the main panel's crop of the video and each signing hand's
    close-up crop (around the person's hand), both None without a video; and the hands' centres."""
    centres = {side: _smooth(_hand_points(person_px, person_seen, layout, side)) for side in geometry.hands}
    main: dict[int, Image.Image] = {}
    hands: dict[str, dict[int, Image.Image]] = {side: {} for side in geometry.hands}
    if video is not None:
        half = geometry.tile / geometry.zoom / 2
        for k, frame in read_video_frames(video[0], video[1], wanted, size):
            main[k] = _crop(frame, geometry.box, geometry.panel)
            for side in geometry.hands:
                cx, cy = centres[side][k]
                if np.isfinite(cx):
                    hands[side][k] = _crop(frame, (cx - half, cy - half, cx + half, cy + half), (geometry.tile,) * 2)
    return main, hands, centres


def side_by_side(person: np.ndarray, agent: np.ndarray, width: int, height: int, source_index: np.ndarray,
                 layout: BodyLayout, *, video: tuple[str | Path, int] | None = None, agent_label: str = "agent",
                 panel_height: int = 360) -> SideBySide:  # fmt: skip
    """The frames of the side-by-side video: one per agent frame (``agent`` (Ta, V, >= 2) normalised
    image keypoints), each beside the person's frame ``source_index[k]`` (``person`` (Ts, V, >= 2)
    normalised, on a ``width`` x ``height`` frame). ``video``: (the source video, the frame index of
    the person's frame 0 in it), or None: no video panel, the person on a blank canvas."""
    scale_px = np.array([float(width), float(height)])
    person_px, agent_px = np.asarray(person, float)[..., :2] * scale_px, np.asarray(agent, float)[..., :2] * scale_px
    person_seen, agent_seen = seen_points(person, layout), seen_points(agent, layout)
    source_index = np.clip(np.asarray(source_index, dtype=int), 0, len(person_px) - 1)
    geometry = frame_geometry(person_px, agent_px, person_seen, agent_seen, layout, panel_height)
    main, hand_bg, centres = _backgrounds(video, person_px, person_seen, geometry, layout, np.unique(source_index),
                                          (int(width), int(height)))  # fmt: skip
    if video is not None and not main:
        video = None  # the video holds none of the frames: no panel of it
    panel_w, panel_h = geometry.panel
    names = (["video"] if video is not None else []) + ["person", "agent"]
    panels = {name: [k * panel_w, HEADER, panel_w, panel_h] for k, name in enumerate(names)}
    x0, tile = len(names) * panel_w, geometry.tile
    hands = {side: {"person": [x0, HEADER + r * tile, tile, tile], "agent": [x0 + tile, HEADER + r * tile, tile, tile],
                    **{f"{who}_px": round(extent * geometry.zoom, 1)
                       for who, extent in geometry.hand_size[side].items() if np.isfinite(extent)}}
             for r, side in enumerate(geometry.hands)}  # fmt: skip
    agent_centres = {side: _smooth(_hand_points(agent_px, agent_seen, layout, side)) for side in geometry.hands}
    size = (x0 + 2 * tile * bool(geometry.hands), HEADER + panel_h)
    scale = panel_w / (geometry.box[2] - geometry.box[0])
    line = max(2, int(round(panel_h / 180)))
    font = _font(14)
    frames = []
    for k, s in enumerate(source_index):
        canvas = Image.new("RGB", size, BACKGROUND)
        draw = ImageDraw.Draw(canvas)
        texts = {"video": f"video, frame {s + 1}/{len(person_px)}", "person": "person's keypoints",
                 "agent": f"{agent_label}, step {k + 1}/{len(agent_px)}"}  # fmt: skip
        for name in names:
            x, y, w, h = panels[name]
            on_video = name in ("video", "person") and s in main
            image = main[s].copy() if on_video else Image.new("RGB", (w, h), BACKGROUND)
            pen = ImageDraw.Draw(image)
            if name == "person":
                draw_skeleton(pen, person_px[s], person_seen[s], layout, geometry.box[:2], scale, line)
            elif name == "agent":
                draw_skeleton(pen, person_px[s], person_seen[s], layout, geometry.box[:2], scale, line, 1.5, GHOST)
                draw_skeleton(pen, agent_px[k], agent_seen[k], layout, geometry.box[:2], scale, line)
            canvas.paste(image, (x, y))
            draw.text((x + 6, 4), texts[name], fill=(220, 220, 220), font=font)
        for side in geometry.hands:
            person_hand = (person_px[s], person_seen[s], centres[side][s])
            agent_hand = (agent_px[k], agent_seen[k], agent_centres[side][k])
            _draw_close_ups(canvas, hands[side], side, hand_bg[side].get(s), person_hand, agent_hand, layout, geometry)
        if geometry.hands:
            draw.text((x0 + 6, 4), "hands: person | agent", fill=(220, 220, 220), font=font)
        frames.append(np.asarray(canvas))
    return SideBySide(frames, panels, hands, geometry)


def _draw_close_ups(canvas: Image.Image, where: dict, side: str, background: Image.Image | None, person: tuple,
                    agent: tuple, layout: BodyLayout, geometry: Geometry) -> None:  # fmt: skip
    """One hand's two close-ups, ``person`` and ``agent`` each (points (V, 2), seen (V,), the
    close-up's centre): the person's (on the video's crop when there is one) and the agent's, with
    the person's hand in grey under it (moved onto the agent's: handshape against handshape), at
    one zoom."""
    tile, zoom = geometry.tile, geometry.zoom
    nodes = layout.sides[side]  # the arm and the hand: no face lines across the close-up
    for who, (px, seen, centre) in (("person", person), ("agent", agent)):
        image = background.copy() if who == "person" and background is not None else None
        image = image or Image.new("RGB", (tile, tile), BACKGROUND)
        pen = ImageDraw.Draw(image)
        if who == "agent" and np.isfinite(person[2]).all():
            draw_skeleton(pen, person[0], person[1], layout, person[2] - tile / 2 / zoom, zoom, 2, 2.0, GHOST, nodes)
        if np.isfinite(centre).all():
            draw_skeleton(pen, px, seen, layout, centre - tile / 2 / zoom, zoom, 3, 3.0, nodes=nodes)
        pen.rectangle([0, 0, tile - 1, tile - 1], outline=(60, 62, 68))
        _label(pen, (5, tile - 21), f"{side} hand, {who}", COLOURS[side])
        canvas.paste(image, tuple(where[who][:2]))
