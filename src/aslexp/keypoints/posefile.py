"""``.pose`` files, the field's shared keypoint container (PyPI ``pose-format``).

A ``.pose`` holds a header (width, height, and components: named point lists, limbs, a point
format such as ``XYZC``) and a body (fps, data (frames, people, points, dims) masked where the
confidence is 0, confidence (frames, people, points)). Files are read with pose-format's own
``Pose.read``, so every header version it reads (0.0, 0.1, 0.2) is read here.

MediaPipe Holistic, as pose-format writes it (``video_to_pose``), is five components:
``POSE_LANDMARKS`` (33), ``FACE_LANDMARKS`` (468), ``LEFT_HAND_LANDMARKS`` (21),
``RIGHT_HAND_LANDMARKS`` (21) and ``POSE_WORLD_LANDMARKS`` (33), point format ``XYZC``, x and y
in pixels (MediaPipe's normalised x times the width, y times the height), z MediaPipe's relative
depth as is, confidence = pose visibility (hands: 1), 0 where a part was not found. The world
component is MediaPipe's metric pose with the same x*width, y*height scaling (pose-format's
convention, undone on reading). pose-format's ``reduce_holistic`` keeps 8 of the 33 body points
(shoulders, elbows, wrists, hips), the face contour and both hands, and drops the world component.

Points are found BY NAME (component name, point name), never by position: a file with extra,
fewer or reordered components maps as long as the points a layout needs are there. The MediaPipe
layouts a file can map onto, richest first (the ``auto`` choice):

- ``mediapipe_holistic`` (75): all 33 ``POSE_LANDMARKS`` points, ``LEFT_HAND_LANDMARKS`` and
  ``RIGHT_HAND_LANDMARKS`` (21 each); channels x, y, z, visibility (the confidence);
- ``mediapipe_holistic_reduced`` (50): pose-format's reduced Holistic: the 8 body points it keeps
  and both hands;
- ``mediapipe_pose`` (33): ``POSE_LANDMARKS`` only;
- ``mediapipe_hands`` (42): both hands only (a hands-only file); channels x, y, z.

Each mapped component needs x, y and z in its point format. Values: x / width, y / height, z as
is, a masked point (confidence 0) -> NaN. ``FACE_LANDMARKS`` and other components are not used.
Files written by aslexp add two components of their own, ``LEFT_HAND_WORLD_LANDMARKS`` and
``RIGHT_HAND_WORLD_LANDMARKS`` (the metric MediaPipe Hands, same scaling), so that retargeting
from a ``.pose`` is as exact as from the ``.npy`` folder; other readers ignore components they do
not use. ``FACE_LANDMARKS`` is written only when the face was extracted (its mesh tesselation is
not available without mediapipe, so its limbs are left empty).

The ``pose_format`` keypoint source reads a folder of ``<video_id>.pose`` files. ``layout``:
``auto`` (default) takes the first of the layouts above that the first file has everything for
(every file must then have it too) and, when none fits (OpenPose, AlphaPose, ...), the file's own
layout, as ``header`` does, saying in the log which it chose and why; a layout name forces that
layout (or is one line saying which components the file has and what the layout needs);
``header`` builds the layout from the file's own header: every point of the non-world components,
``COMPONENT:POINT`` names, limbs as edges, channels the components' x, y (z) and ``visibility``
(pose-format's per-point confidence, the same channel name as in the MediaPipe layouts, so that
``pose.channels=[x, y, visibility]`` means position and confidence whatever the file). An OpenPose
header (BODY_25 + hands, or BODY_135, as pose-format writes them) also offers
``pose.subset=slgcn27`` (:mod:`aslexp.keypoints.slgcn27`), so ``conf/pose/pose_format.yaml``'s
defaults read such a folder as they read a MediaPipe one: ``aslexp recognize pose=pose_format
pose.path=DIR`` needs no other override.

For retargeting, :func:`holistic_arrays` takes whatever MediaPipe points a file has (NaN for the
rest) and says which parts are missing and why.

pose-format is imported only when a file is read or written.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.errors import DataError
from aslexp.keypoints import holistic as H
from aslexp.keypoints.layout import KeypointLayout
from aslexp.keypoints.layouts import MEDIAPIPE_HANDS, MEDIAPIPE_HOLISTIC, MEDIAPIPE_HOLISTIC_REDUCED, MEDIAPIPE_POSE
from aslexp.keypoints.registry import get_layout, register_layout, register_source
from aslexp.keypoints.slgcn27 import register_header_map
from aslexp.keypoints.subsets import subset_names

log = logging.getLogger(__name__)

SUFFIX = ".pose"
POSE, FACE, LEFT, RIGHT = "POSE_LANDMARKS", "FACE_LANDMARKS", "LEFT_HAND_LANDMARKS", "RIGHT_HAND_LANDMARKS"
POSE_WORLD = "POSE_WORLD_LANDMARKS"
LEFT_WORLD, RIGHT_WORLD = "LEFT_HAND_WORLD_LANDMARKS", "RIGHT_HAND_WORLD_LANDMARKS"
# MediaPipe's own point names (mp.solutions.holistic.PoseLandmark / HandLandmark member names),
# which pose-format writes; aslexp's names are the same, lower-case, with shorter finger names.
POSE_POINTS = tuple(name.upper() for name in H.POSE_NAMES)
HAND_POINTS = (
    "WRIST", "THUMB_CMC", "THUMB_MCP", "THUMB_IP", "THUMB_TIP",
    "INDEX_FINGER_MCP", "INDEX_FINGER_PIP", "INDEX_FINGER_DIP", "INDEX_FINGER_TIP",
    "MIDDLE_FINGER_MCP", "MIDDLE_FINGER_PIP", "MIDDLE_FINGER_DIP", "MIDDLE_FINGER_TIP",
    "RING_FINGER_MCP", "RING_FINGER_PIP", "RING_FINGER_DIP", "RING_FINGER_TIP",
    "PINKY_MCP", "PINKY_PIP", "PINKY_DIP", "PINKY_TIP",
)  # fmt: skip
REDUCED_POSE_POINTS = tuple(POSE_POINTS[i] for i in H.REDUCED_BODY)  # what reduce_holistic keeps
HOLISTIC_PARTS = ((POSE, POSE_POINTS, 0), (LEFT, HAND_POINTS, H.LEFT_HAND_OFFSET),
                  (RIGHT, HAND_POINTS, H.RIGHT_HAND_OFFSET))  # fmt: skip
WORLD_PARTS = ((POSE_WORLD, POSE_POINTS, 0), (LEFT_WORLD, HAND_POINTS, H.LEFT_HAND_OFFSET),
               (RIGHT_WORLD, HAND_POINTS, H.RIGHT_HAND_OFFSET))  # fmt: skip


def _sources(parts) -> dict[str, tuple[str, str]]:
    """aslexp holistic node name -> (component, point) in a .pose."""
    return {H.NAMES[offset + k]: (component, point) for component, points, offset in parts
            for k, point in enumerate(points)}  # fmt: skip


IMAGE_SOURCES = _sources(HOLISTIC_PARTS)
WORLD_SOURCES = _sources(WORLD_PARTS)
# The MediaPipe layouts a .pose maps onto by name, richest first: layout auto takes the first that fits.
AUTO_LAYOUTS: tuple[KeypointLayout, ...] = (MEDIAPIPE_HOLISTIC, MEDIAPIPE_HOLISTIC_REDUCED, MEDIAPIPE_POSE,
                                            MEDIAPIPE_HANDS)  # fmt: skip
NEEDS = {
    MEDIAPIPE_HOLISTIC.name: f"{POSE} (MediaPipe's 33 Pose points) + {LEFT} + {RIGHT} (its 21 hand points each)",
    MEDIAPIPE_HOLISTIC_REDUCED.name: f"both hands + the shoulders, elbows, wrists and hips of {POSE} "
                                     "(pose-format's reduce_holistic)",
    MEDIAPIPE_POSE.name: POSE,
    MEDIAPIPE_HANDS.name: "both hands",
}
LAYOUT_MODES = ("auto", "header", *(layout.name for layout in AUTO_LAYOUTS))


class LayoutMismatch(DataError):
    """A readable ``.pose`` without the components or points a layout needs."""


@dataclass
class PoseFile:
    """One ``.pose`` read into aslexp's terms."""

    path: Path
    layout: KeypointLayout
    keypoints: np.ndarray  # (T, V, C) float32, x and y in [0, 1] of the frame, NaN = missing
    fps: float
    width: int
    height: int
    world: np.ndarray | None = None  # (T, 75, 3) metres for Holistic files with a world component
    # holistic_arrays only: part ('body', 'left_hand', 'right_hand') -> why the file cannot give it
    missing: dict[str, str] = field(default_factory=dict)
    components: list[str] = field(default_factory=list)  # the file's components, described


def _pose_format():
    try:
        import pose_format
        from pose_format.numpy import NumPyPoseBody
        from pose_format.pose_header import PoseHeader, PoseHeaderComponent, PoseHeaderDimensions
    except ImportError as error:  # a dependency; only a broken install gets here
        raise ImportError("reading or writing .pose files needs pose-format: pip install pose-format") from error
    return pose_format.Pose, NumPyPoseBody, PoseHeader, PoseHeaderComponent, PoseHeaderDimensions


def read_pose(path: str | Path):
    """The pose-format ``Pose`` in ``path``, read by pose-format itself (any header version it
    reads); a DataError naming the file when it is not one."""
    Pose = _pose_format()[0]
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"pose file not found: {path}")
    buffer = path.read_bytes()
    try:
        pose = Pose.read(buffer)
    except Exception as error:  # noqa: BLE001 - any parse failure of a foreign file is bad input
        short = _cut_short(path, buffer)  # a truncated body says so, not as a reader's TypeError
        if short:
            raise DataError(short) from None
        raise DataError(f"{path}: not a readable .pose file: pose-format's reader says "
                        f"{type(error).__name__}: {error}".rstrip(": ")) from None  # fmt: skip
    short = _cut_short(path, buffer)
    if short:
        raise DataError(short)
    return pose


def _cut_short(path: Path, buffer: bytes) -> str | None:
    """Why a ``.pose`` body is shorter than its header says (None when it is whole, or of format
    0.0, whose frames differ in size and which pose-format's reader checks itself). Format 0.1
    reads as many frames as the bytes hold: a cut file would read as a shorter clip, its
    confidences taken from the coordinates; 0.2 stops with a TypeError."""
    import struct

    from pose_format.pose_header import PoseHeader
    from pose_format.utils.reader import BufferReader

    try:
        reader = BufferReader(buffer)
        header = PoseHeader.read(reader)
        version = round(float(header.version), 3)
        if version not in (0.1, 0.2):
            return None
        fmt = "<HHH" if version == 0.1 else "<fIH"  # fps, frames, people
        fps, frames, people = struct.unpack_from(fmt, buffer, reader.read_offset)
        points = sum(len(c.points) for c in header.components)
        per_frame = people * points * (header.num_dims() + 1) * 4  # float32 coordinates + confidence
        body = len(buffer) - reader.read_offset - struct.calcsize(fmt)
    except Exception:  # noqa: BLE001 - not even a header: pose-format's own message says more
        return None
    if per_frame <= 0:
        return None
    whole, rest = divmod(body, per_frame)
    # 0.1 stores the frame count in 16 bits (pose-format's reader ignores it for that reason)
    cut = (rest or whole % 65536 != frames) if version == 0.1 else body < frames * per_frame
    if not cut:
        return None
    return (f"{path}: cut short (truncated): its header says {frames} frames of {people} person(s) x {points} "
            f"points, {frames * per_frame} bytes; the file holds {max(body, 0)} ({whole} whole frames): "
            "copy or write it again")  # fmt: skip


def _offsets(header) -> dict[str, tuple[int, Any]]:
    """Component name -> (its first point's index in the body, the component); the first of
    two components with one name."""
    offsets: dict[str, tuple[int, Any]] = {}
    start = 0
    for component in header.components:
        offsets.setdefault(component.name, (start, component))
        start += len(component.points)
    return offsets


def describe_components(header) -> list[str]:
    """``NAME (points, FORMAT)`` for each component of a header."""
    return [f"{c.name} ({len(c.points)} points, {c.format})" for c in header.components]


def known_format(header) -> str:
    """pose-format's own name for the header's layout ('holistic', 'openpose', ...), or ''."""
    try:
        from pose_format.utils.generic import detect_known_pose_format

        return f"pose-format calls it {detect_known_pose_format(header)!r}"
    except Exception:  # noqa: BLE001 - unknown to pose-format too
        return "unknown to pose-format"


def _locate(header, wanted: list[tuple[str, str]], dims: str = "XYZ"):
    """Where each wanted (component, point) is: (body point index, index of each of ``dims`` in
    the data's last axis), or None; and the reasons the missing ones are missing (one per
    component: absent, without a dimension, or lacking points)."""
    components = _offsets(header)
    found: list[tuple[int, list[int]] | None] = []
    lacking: dict[str, list[str]] = {}
    reasons: dict[str, str] = {}
    for component_name, point in wanted:
        if component_name not in components:
            reasons[component_name] = f"no component {component_name}"
            found.append(None)
            continue
        start, component = components[component_name]
        spatial = component.format.upper().replace("C", "")
        if any(d not in spatial for d in dims):
            reasons[component_name] = (f"component {component_name} has point format {component.format}, "
                                       f"not {dims}C")  # fmt: skip
            found.append(None)
            continue
        try:
            k = list(component.points).index(point)
        except ValueError:
            lacking.setdefault(component_name, []).append(point)
            found.append(None)
            continue
        found.append((start + k, [spatial.index(d) for d in dims]))
    for component_name, points in lacking.items():
        total = len(components[component_name][1].points)
        shown = ", ".join(points[:4]) + (", ..." if len(points) > 4 else "")
        reasons[component_name] = (f"component {component_name} ({total} points) lacks {len(points)} "
                                   f"needed point(s): {shown}")  # fmt: skip
    return found, reasons


def _fit(header, layout: KeypointLayout):
    """(locations, reasons) of a MediaPipe layout's nodes in a header (reasons empty when it fits)."""
    dims = "".join(c.upper() for c in layout.channels if c in ("x", "y", "z"))
    try:
        wanted = [IMAGE_SOURCES[name] for name in layout.names]
    except KeyError:
        raise DataError(f"layout {layout.name!r} has nodes that are not MediaPipe Holistic points; "
                        f"a .pose maps onto {[lay.name for lay in AUTO_LAYOUTS]} or layout=header") from None
    return _locate(header, wanted, dims)


def choose_layout(header, origin: str, mode: str = "auto") -> KeypointLayout:
    """The MediaPipe layout a header maps onto: ``mode`` (a layout name) or, for ``auto``, the
    first of :data:`AUTO_LAYOUTS` that it has everything for; else the one-line DataError."""
    candidates = AUTO_LAYOUTS if mode == "auto" else (get_layout(mode),)
    results = []
    for layout in candidates:
        reasons = _fit(header, layout)[1]
        if not reasons:
            return layout
        results.append((layout, reasons))
    has = f"the file has components {', '.join(describe_components(header)) or 'none'} ({known_format(header)})"
    if mode != "auto":
        layout, reasons = results[0]
        raise LayoutMismatch(f"{origin}: layout {mode} needs {NEEDS.get(mode, 'its nodes')}: "
                        f"{'; '.join(reasons.values())}; {has}")  # fmt: skip
    mediapipe = {POSE, LEFT, RIGHT} & {c.name for c in header.components}
    closest = ""
    if mediapipe:  # MediaPipe components with something missing: say what, for the nearest layout
        layout, reasons = min(results, key=lambda r: len(r[1]))
        closest = f" (nearest: {layout.name}: {'; '.join(reasons.values())})"
    needs = "; ".join(f"{name}: {text}" for name, text in NEEDS.items())
    raise LayoutMismatch(f"{origin}: no MediaPipe layout fits: {has}{closest}; the layouts need, by component and "
                    f"point name, with x, y and z: {needs}; set pose.options.layout=header to use the file's "
                    "own layout instead")  # fmt: skip


def auto_layout(header, origin: str) -> KeypointLayout | None:
    """``layout=auto``: the first MediaPipe layout the header has everything for, or None when
    none fits (the file's own layout is then read: :func:`header_layout`)."""
    try:
        return choose_layout(header, origin, "auto")
    except LayoutMismatch:
        return None


def nearest_mediapipe_layout(header) -> str:
    """For a header with MediaPipe components that no MediaPipe layout fits: the nearest layout
    and what it lacks (``name: reasons``); '' when the header has no MediaPipe component."""
    if not {POSE, LEFT, RIGHT} & {c.name for c in header.components}:
        return ""
    fits = [(lay, *_fit(header, lay)) for lay in AUTO_LAYOUTS]
    layout, _, reasons = min(fits, key=lambda fit: sum(where is None for where in fit[1]))  # fewest points missing
    return f"{layout.name}: {'; '.join(reasons.values())}"


def header_layout(header, origin: str) -> tuple[KeypointLayout, list[int]]:
    """A layout made from a header's own components (world components left out), and the point
    indices it takes from the body."""
    names, edges, take = [], [], []
    channels = None
    for start, component in _offsets(header).values():
        if "WORLD" in component.name:
            continue
        base = len(names)
        names += [f"{component.name}:{p}" for p in component.points]
        edges += [(base + int(i), base + int(j)) for i, j in component.limbs if int(i) != int(j)]
        take += range(start, start + len(component.points))
        # pose-format keeps a confidence per point whatever the point format: the visibility channel
        component_channels = [c.lower() for c in component.format.upper().replace("C", "")] + ["visibility"]
        if channels is None:
            channels = component_channels
        elif channels != component_channels:
            raise DataError(f"{origin}: component {component.name!r} has point format {component.format!r}, "
                            f"unlike the others ({channels}): one layout needs one set of channels; keep the "
                            "components of one format (pose-format's Pose.get_components)")  # fmt: skip
    if not names:
        raise DataError(f"{origin}: no (non-world) component in the header")
    signature = "|".join(f"{c.name}:{','.join(c.points)}" for c in header.components)
    name = "pose_header_" + hashlib.sha1(signature.encode()).hexdigest()[:8]
    layout = KeypointLayout(name=name, names=tuple(names), edges=tuple(sorted(set(edges))), center=0,
                            channels=tuple(channels))  # fmt: skip
    return layout, take


def register_header_layout(header, origin: str) -> tuple[KeypointLayout, str | None]:
    """Register a header's own layout (:func:`header_layout`) with the subsets its names allow
    (``slgcn27`` on OpenPose headers); returns it and the known format it was matched to (or None)."""
    layout = register_layout(header_layout(header, origin)[0])
    return layout, register_header_map(layout)


def _scaled(data: np.ndarray, width: int, height: int) -> np.ndarray:
    out = data.astype(np.float32).copy()
    out[..., 0] /= float(width or 1)
    out[..., 1] /= float(height or 1)
    return out


def _person(pose, origin: str, person: int) -> tuple[np.ndarray, np.ndarray]:
    """One person's (T, P, D) data (masked values kept as written) and (T, P) confidence."""
    data = np.ma.getdata(pose.body.data)
    confidence = np.asarray(np.ma.getdata(pose.body.confidence), dtype=np.float32)
    if data.ndim != 4:
        raise DataError(f"{origin}: body data has shape {data.shape}, expected (frames, people, points, dims)")
    if not 0 <= person < data.shape[1]:
        if data.shape[0] == 0:  # an empty file: no frames, no people
            return np.zeros((0, *data.shape[2:]), np.float32), np.zeros((0, data.shape[2]), np.float32)
        raise DataError(f"{origin}: person {person} requested, the file has {data.shape[1]}")
    return data[:, person], confidence[:, person]


def _gather(data, confidence, found, width: int, height: int, with_confidence: bool) -> np.ndarray:
    """(T, len(found), D) float32 from located points (NaN for None and for masked frames):
    x / width, y / height, other dimensions as they are, then the confidence if asked."""
    T = len(data)
    dims = next((len(f[1]) for f in found if f is not None), 3)
    out = np.full((T, len(found), dims + with_confidence), np.nan, np.float32)
    for k, where in enumerate(found):
        if where is None:
            continue
        point, axes = where
        values = data[:, point][:, axes].astype(np.float32)
        values[:, 0] /= float(width or 1)
        if dims > 1:
            values[:, 1] /= float(height or 1)
        out[:, k, :dims] = values
        if with_confidence:
            out[:, k, dims] = confidence[:, point]
        out[confidence[:, point] <= 0, k] = np.nan
    return out


def pose_to_arrays(pose, origin: str, layout: str = "auto", person: int = 0) -> PoseFile:
    """A pose-format ``Pose`` -> aslexp arrays in a MediaPipe layout found by name (``auto`` or a
    layout name), or in the header's own layout (``header``); see the module doc."""
    if layout not in LAYOUT_MODES:
        raise DataError(f"{origin}: pose.options.layout = {layout!r}; expected one of {list(LAYOUT_MODES)}")
    header = pose.header
    width, height = int(header.dimensions.width), int(header.dimensions.height)
    data, confidence = _person(pose, origin, person)
    fps = float(pose.body.fps)
    chosen = auto_layout(header, origin) if layout == "auto" else None
    if layout == "auto" and chosen is None:
        layout = "header"  # no MediaPipe layout fits: the file's own, as the folder source reads it
    if layout != "header":
        chosen = chosen or choose_layout(header, origin, layout)
        found, _ = _fit(header, chosen)
        clip = _gather(data, confidence, found, width, height, with_confidence="visibility" in chosen.channels)
        world = None
        if chosen is MEDIAPIPE_HOLISTIC and POSE_WORLD in _offsets(header):
            world_found = _locate(header, [WORLD_SOURCES[n] for n in H.NAMES])[0]
            world = _gather(data, confidence, world_found, width, height, with_confidence=False)
        return PoseFile(Path(origin), chosen, clip, fps, width, height, world,
                        components=describe_components(header))  # fmt: skip
    layout_obj, take = header_layout(header, origin)
    dims = len(layout_obj.channels) - 1  # the spatial ones, then visibility
    clip = np.concatenate([_scaled(data[:, take, :dims], width, height), confidence[:, take, None]], axis=-1)
    clip[confidence[:, take] <= 0] = np.nan
    return PoseFile(Path(origin), layout_obj, clip, fps, width, height, components=describe_components(header))


def read_pose_file(path: str | Path, layout: str = "auto", person: int = 0) -> PoseFile:
    """Read one ``.pose`` into aslexp arrays (layout ``auto``, a MediaPipe layout name, or ``header``)."""
    return pose_to_arrays(read_pose(path), str(path), layout, person)


def holistic_arrays(path: str | Path, person: int = 0) -> PoseFile:
    """Whatever MediaPipe points a ``.pose`` has, by name, in aslexp's 75-node Holistic arrays
    (NaN for the rest), the world landmarks it has (or None), and in ``missing`` why a part
    ('body', 'left_hand', 'right_hand') is not in the file: for retargeting, which takes what is
    there. A file with none of them is the one-line DataError saying what is needed."""
    pose = read_pose(path)
    origin = str(path)
    header = pose.header
    width, height = int(header.dimensions.width), int(header.dimensions.height)
    data, confidence = _person(pose, origin, person)
    _check_retargetable(origin, float(pose.body.fps), len(data))
    found, reasons = _locate(header, [IMAGE_SOURCES[n] for n in H.NAMES])
    clip = _gather(data, confidence, found, width, height, with_confidence=True)
    world = None
    if POSE_WORLD in _offsets(header):  # the metric pose, with aslexp's metric hands where the file has them
        world_found, _ = _locate(header, [WORLD_SOURCES[n] for n in H.NAMES])
        world = _gather(data, confidence, world_found, width, height, with_confidence=False)
    missing = {}
    body = ("left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist")
    if any(found[H.NAMES.index(n)] is None for n in body):
        missing["body"] = f"not in the file: {reasons[POSE]}"
    for side, component, offset in (("left_hand", LEFT, H.LEFT_HAND_OFFSET),
                                    ("right_hand", RIGHT, H.RIGHT_HAND_OFFSET)):  # fmt: skip
        if any(found[offset + k] is None for k in range(H.NUM_HAND)):
            missing[side] = f"not in the file: {reasons[component]}"
    result = PoseFile(Path(origin), MEDIAPIPE_HOLISTIC, clip, float(pose.body.fps), width, height, world,
                      missing, describe_components(header))  # fmt: skip
    if len(missing) == 3:
        # Hands without depth (OpenPose's are 2D): the reason a hand motion cannot come from them
        flat_hands = [c for c in header.components if "hand" in c.name.lower() and "Z" not in c.format.upper()]
        flat = (f"; its {', '.join(c.name for c in flat_hands)} are 2D ({flat_hands[0].format}): finger angles "
                "need depth" if flat_hands else "")  # fmt: skip
        raise DataError(f"{origin}: nothing to retarget: the file has components "
                        f"{', '.join(result.components) or 'none'} ({known_format(header)}){flat}; by name, "
                        f"the hand motion needs {LEFT} or {RIGHT} (21 MediaPipe hand points), the upper "
                        f"body {POSE} with both shoulders, elbows and wrists (MediaPipe Pose names), each "
                        "with x, y, z; make MediaPipe keypoints from the video with "
                        "`aslexp extract VIDEO --motions`")  # fmt: skip
    return result


def _check_retargetable(origin: str, fps: float, frames: int) -> None:
    """A motion needs frames and a frame rate: one line saying which the file lacks."""
    if frames == 0:
        raise DataError(f"{origin}: 0 frames: the file has a header and no keypoints; a motion needs at least one "
                        "frame")  # fmt: skip
    if not (np.isfinite(fps) and fps > 0):
        raise DataError(f"{origin}: frame rate {fps:g} in the file: expected a positive fps (frames per second); "
                        "write it again with its video's frame rate")  # fmt: skip


class PoseFormatSource:
    """A folder of ``<video_id>.pose`` files, all in one layout (chosen from the first file)."""

    file_suffix = SUFFIX

    def __init__(self, directory: str | Path, layout: str = "auto", person: int = 0):
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise FileNotFoundError(f".pose folder not found: {self.directory}")
        if layout not in LAYOUT_MODES:
            raise DataError(f"{self.directory}: pose.options.layout = {layout!r}; expected one of {list(LAYOUT_MODES)}")
        self.mode, self.person = layout, int(person)
        self._layout: KeypointLayout | None = None
        self._from_header = layout == "header"  # the folder's layout is its first file's own

    def available(self) -> set[str]:
        return {path.stem for path in self.directory.glob(f"*{SUFFIX}")}

    @property
    def layout(self) -> KeypointLayout:
        if self._layout is None:
            files = sorted(self.directory.glob(f"*{SUFFIX}"))
            if not files:
                raise DataError(f"{self.directory}: no {SUFFIX} files")
            header = None
            for first in files:  # the first readable file: a damaged one is skipped here and when loaded
                try:
                    header = read_pose(first).header  # pose-format's reader: every version it knows
                    break
                except DataError as error:
                    log.warning("%s (the folder's layout is read from the next file)", error)
            if header is None:
                raise DataError(f"{self.directory}: none of its {len(files)} {SUFFIX} files is readable")
            self._first = first
            why, chosen = "", None
            if self.mode == "auto":
                chosen = auto_layout(header, str(first))
                self._from_header = chosen is None
            if self.mode == "auto" and chosen is None:
                why = (f": no MediaPipe layout fits its components {', '.join(describe_components(header))} "
                       f"({known_format(header)}), so the header's own")  # fmt: skip
                nearest = nearest_mediapipe_layout(header)
                if nearest:  # MediaPipe components that lack points: likely not what was meant, say it louder
                    log.warning("%s: its MediaPipe components lack points every MediaPipe layout needs (nearest: "
                                "%s); reading the header's own layout instead (pose.options.layout=%s names what "
                                "one needs)", first, nearest, nearest.split(":")[0])  # fmt: skip
            if self._from_header:
                try:
                    self._layout, known = register_header_layout(header, str(first))
                except DataError as error:
                    if self.mode != "auto":
                        raise
                    raise DataError(f"{error}; nor does a MediaPipe layout fit: pose.options.layout=<one of "
                                    f"{[lay.name for lay in AUTO_LAYOUTS]}> says what it needs") from None  # fmt: skip
                why += (f" ({self._layout.num_nodes} nodes, channels {', '.join(self._layout.channels)}, subsets "
                        f"{', '.join(subset_names(self._layout))}"
                        + (f"; slgcn27 mapped by {known} point names" if known else "") + ")")  # fmt: skip
            else:
                self._layout = chosen or choose_layout(header, str(first), self.mode)
            unused = [] if self._from_header else [
                c.name for c in header.components if c.name in (POSE, LEFT, RIGHT) and c.name not in self._uses()]
            log.info("%s: .pose layout %s (pose.options.layout=%s, read from %s)%s%s", self.directory,
                     self._layout.name, self.mode, first.name, why,
                     f"; components {unused} not used" if unused else "")  # fmt: skip
        return self._layout

    def _uses(self) -> set[str]:
        return {IMAGE_SOURCES[name][0] for name in self.layout.names}

    def load(self, video_id: str) -> np.ndarray:
        path = self.directory / f"{video_id}{SUFFIX}"
        layout = self.layout
        try:
            result = read_pose_file(path, "header" if self._from_header else layout.name, self.person)
        except DataError as error:
            if self.mode != "auto" or not isinstance(error, LayoutMismatch):
                raise
            raise DataError(f"{error} (the folder's layout, chosen from its first file {self._first.name}: "
                            "set pose.options.layout to one that every file has)") from None  # fmt: skip
        if result.layout.names != layout.names or result.layout.channels != layout.channels:
            raise DataError(f"{path}: layout {result.layout.name!r} differs from the folder's "
                            f"{layout.name!r} (read from its first file)")  # fmt: skip
        return result.keypoints


register_source("pose_format", PoseFormatSource,
                summary="<dir>/<id>.pose (pose-format): MediaPipe layouts by name, or the header's own "
                        "(options: layout, person)")  # fmt: skip


# ----------------------------------------------------------------------------- writing


def _component(PoseHeaderComponent, name: str, points, limbs, color) -> Any:
    limbs = [(int(i), int(j)) for i, j in limbs]
    return PoseHeaderComponent(name=name, points=list(points), limbs=limbs,
                               colors=[color] * max(1, len(limbs)), point_format="XYZC")  # fmt: skip


def holistic_pose(keypoints: np.ndarray, fps: float, width: int, height: int,
                  world: np.ndarray | None = None, face: np.ndarray | None = None):  # fmt: skip
    """aslexp's (T, 75, 4) Holistic arrays (and optionally (T, 75, 3) world metres and (T, 468, 3)
    normalised face points) -> a pose-format ``Pose`` laid out as pose-format's own Holistic."""
    Pose, NumPyPoseBody, PoseHeader, PoseHeaderComponent, PoseHeaderDimensions = _pose_format()
    keypoints = np.asarray(keypoints, dtype=np.float32)
    if keypoints.ndim != 3 or keypoints.shape[1:] != (H.NUM_NODES, 4):
        raise DataError(f"holistic keypoints have shape {keypoints.shape}, expected (T, {H.NUM_NODES}, 4)")
    T = len(keypoints)
    scale = np.array([width, height, 1.0], np.float32)
    components, blocks, confidences = [], [], []

    def add(name, points, limbs, color, xyz, conf):
        components.append(_component(PoseHeaderComponent, name, points, limbs, color))
        seen = np.isfinite(xyz).all(axis=-1) & np.isfinite(conf)
        blocks.append(np.where(seen[..., None], xyz * scale, 0.0))
        confidences.append(np.where(seen, conf, 0.0))

    body, left, right = (slice(o, o + len(p)) for _, p, o in HOLISTIC_PARTS)
    add(POSE, POSE_POINTS, H.POSE_EDGES, (255, 0, 0), keypoints[:, body, :3], keypoints[:, body, 3])
    if face is not None:
        face = np.asarray(face, dtype=np.float32)
        add(FACE, [str(i) for i in range(face.shape[1])], [], (128, 0, 0), face, np.ones(face.shape[:2], np.float32))
    for name, part, color in ((LEFT, left, (0, 128, 255)), (RIGHT, right, (255, 128, 0))):
        add(name, HAND_POINTS, H.HAND_EDGES, color, keypoints[:, part, :3], keypoints[:, part, 3])
    if world is not None:
        world = np.asarray(world, dtype=np.float32)
        if world.shape != (T, H.NUM_NODES, 3):
            raise DataError(f"holistic world landmarks have shape {world.shape}, expected ({T}, {H.NUM_NODES}, 3)")
        visible = keypoints[:, body, 3]
        add(POSE_WORLD, POSE_POINTS, H.POSE_EDGES, (255, 0, 0), world[:, body], visible)
        for name, part in ((LEFT_WORLD, left), (RIGHT_WORLD, right)):
            add(name, HAND_POINTS, H.HAND_EDGES, (0, 0, 0), world[:, part], np.ones((T, 21), np.float32))
    data = np.concatenate(blocks, axis=1)[:, None].astype(np.float32)
    confidence = np.concatenate(confidences, axis=1)[:, None].astype(np.float32)
    header = PoseHeader(version=0.2, dimensions=PoseHeaderDimensions(width=int(width), height=int(height), depth=0),
                        components=components)  # fmt: skip
    return Pose(header, NumPyPoseBody(fps=float(fps), data=data, confidence=confidence))


def write_holistic_pose(path: str | Path, keypoints: np.ndarray, fps: float, width: int, height: int,
                        world: np.ndarray | None = None, face: np.ndarray | None = None) -> Path:  # fmt: skip
    """Write a ``.pose`` (see :func:`holistic_pose`) atomically; returns the path."""
    from aslexp.files import atomic_path

    pose = holistic_pose(keypoints, fps, width, height, world, face)
    path = Path(path)
    with atomic_path(path) as tmp, open(tmp, "wb") as handle:
        pose.write(handle)
    return path
