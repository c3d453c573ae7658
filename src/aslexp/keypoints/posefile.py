"""``.pose`` files, the field's shared keypoint container (PyPI ``pose-format``).

A ``.pose`` holds a header (width, height, and components: named point lists, limbs, a point
format such as ``XYZC``) and a body (fps, data (frames, people, points, dims) masked where the
confidence is 0, confidence (frames, people, points)).

MediaPipe Holistic, as pose-format writes it (``video_to_pose``), is five components:
``POSE_LANDMARKS`` (33), ``FACE_LANDMARKS`` (468), ``LEFT_HAND_LANDMARKS`` (21),
``RIGHT_HAND_LANDMARKS`` (21) and ``POSE_WORLD_LANDMARKS`` (33), point format ``XYZC``, x and y
in pixels (MediaPipe's normalised x times the width, y times the height), z MediaPipe's relative
depth as is, confidence = pose visibility (hands: 1), 0 where a part was not found. The world
component is MediaPipe's metric pose with the same x*width, y*height scaling (pose-format's
convention, undone on reading).

That maps exactly onto aslexp's 75-node ``mediapipe_holistic`` layout (body, left hand, right
hand): x / width, y / height, z, confidence as visibility, a masked point -> NaN. Files written
by aslexp add two components of their own, ``LEFT_HAND_WORLD_LANDMARKS`` and
``RIGHT_HAND_WORLD_LANDMARKS`` (the metric MediaPipe Hands, same scaling), so that retargeting
from a ``.pose`` is as exact as from the ``.npy`` folder; other readers ignore components they
do not use. ``FACE_LANDMARKS`` is written only when the face was extracted (its mesh tesselation
is not available without mediapipe, so its limbs are left empty).

The ``pose_format`` keypoint source reads a folder of ``<video_id>.pose`` files. ``layout``:
``auto`` (default) maps Holistic files and rejects any other header in one line naming the file
and the component; ``header`` builds the layout from the file's own header (every point of the
non-world components, ``COMPONENT:POINT`` names, limbs as edges), for OpenPose, AlphaPose or any
other layout the library writes.

pose-format is imported only when a file is read or written.
"""

from __future__ import annotations

import hashlib
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.errors import DataError
from aslexp.keypoints import holistic as H
from aslexp.keypoints.layout import KeypointLayout
from aslexp.keypoints.layouts import MEDIAPIPE_HOLISTIC
from aslexp.keypoints.registry import register_layout, register_source

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
HOLISTIC_PARTS = ((POSE, POSE_POINTS, 0), (LEFT, HAND_POINTS, H.LEFT_HAND_OFFSET),
                  (RIGHT, HAND_POINTS, H.RIGHT_HAND_OFFSET))  # fmt: skip
WORLD_PARTS = ((POSE_WORLD, POSE_POINTS, 0), (LEFT_WORLD, HAND_POINTS, H.LEFT_HAND_OFFSET),
               (RIGHT_WORLD, HAND_POINTS, H.RIGHT_HAND_OFFSET))  # fmt: skip
LAYOUT_MODES = ("auto", "header")


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


def _pose_format():
    try:
        import pose_format
        from pose_format.numpy import NumPyPoseBody
        from pose_format.pose_header import PoseHeader, PoseHeaderComponent, PoseHeaderDimensions
    except ImportError as error:  # a dependency; only a broken install gets here
        raise ImportError("reading or writing .pose files needs pose-format: pip install pose-format") from error
    return pose_format.Pose, NumPyPoseBody, PoseHeader, PoseHeaderComponent, PoseHeaderDimensions


def read_pose(path: str | Path):
    """The pose-format ``Pose`` in ``path`` (a DataError naming the file when it is not one)."""
    Pose = _pose_format()[0]
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"pose file not found: {path}")
    try:
        return Pose.read(path.read_bytes())
    except Exception as error:  # noqa: BLE001 - any parse failure of a foreign file is bad input
        raise DataError(f"{path}: not a readable .pose file ({type(error).__name__}: {error})") from None


def _offsets(header) -> dict[str, tuple[int, Any]]:
    offsets, start = {}, 0
    for component in header.components:
        offsets[component.name] = (start, component)
        start += len(component.points)
    return offsets


def holistic_mismatch(header) -> str | None:
    """None when the header is MediaPipe Holistic as pose-format writes it, else the reason,
    naming the component."""
    components = _offsets(header)
    for name, points, _ in HOLISTIC_PARTS:
        if name not in components:
            unknown = [c.name for c in header.components if c.name not in (POSE, FACE, LEFT, RIGHT, POSE_WORLD)]
            what = f"component {unknown[0]!r}" if unknown else f"no component {name!r}"
            return f"{what} (components {[c.name for c in header.components]})"
        found = tuple(components[name][1].points)
        if found != points:
            return f"component {name!r} has points {list(found[:4])}... ({len(found)}), expected MediaPipe's {len(points)}"
    return None


def check_holistic(header, origin: str) -> None:
    """Raise the one-line DataError for a header that is not MediaPipe Holistic."""
    mismatch = holistic_mismatch(header)
    if mismatch is not None:
        raise DataError(f"{origin}: unknown .pose layout: {mismatch}; aslexp maps MediaPipe Holistic "
                        f"({POSE}, {LEFT}, {RIGHT}); set pose.options.layout=header to build the "
                        "layout from the file's header")  # fmt: skip


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
        fmt = component.format.upper()
        component_channels = [c.lower() for c in fmt.replace("C", "")] + (["confidence"] if "C" in fmt else [])
        if channels is None:
            channels = component_channels
        elif channels != component_channels:
            raise DataError(f"{origin}: component {component.name!r} has point format {component.format!r}, "
                            f"unlike the others ({channels}): one layout needs one set of channels")  # fmt: skip
    if not names:
        raise DataError(f"{origin}: no (non-world) component in the header")
    signature = "|".join(f"{c.name}:{','.join(c.points)}" for c in header.components)
    name = "pose_header_" + hashlib.sha1(signature.encode()).hexdigest()[:8]
    layout = KeypointLayout(name=name, names=tuple(names), edges=tuple(sorted(set(edges))), center=0,
                            channels=tuple(channels))  # fmt: skip
    return layout, take


def _scaled(data: np.ndarray, width: int, height: int) -> np.ndarray:
    out = data.astype(np.float32).copy()
    out[..., 0] /= float(width or 1)
    out[..., 1] /= float(height or 1)
    return out


def pose_to_arrays(pose, origin: str, layout: str = "auto", person: int = 0) -> PoseFile:
    """A pose-format ``Pose`` -> aslexp arrays (see the module doc for the mapping)."""
    if layout not in LAYOUT_MODES:
        raise DataError(f"{origin}: pose.options.layout = {layout!r}; expected one of {LAYOUT_MODES}")
    header, body = pose.header, pose.body
    width, height = int(header.dimensions.width), int(header.dimensions.height)
    data = np.ma.getdata(body.data)
    confidence = np.asarray(body.confidence, dtype=np.float32)
    if data.ndim != 4:
        raise DataError(f"{origin}: body data has shape {data.shape}, expected (frames, people, points, dims)")
    if not 0 <= person < data.shape[1]:
        if data.shape[0] == 0:  # an empty file: no frames, no people
            data = np.zeros((0, person + 1, *data.shape[2:]), np.float32)
            confidence = np.zeros(data.shape[:3], np.float32)
        else:
            raise DataError(f"{origin}: person {person} requested, the file has {data.shape[1]}")
    data, confidence = data[:, person], confidence[:, person]
    missing = confidence <= 0
    components = _offsets(header)
    if layout == "auto":
        check_holistic(header, origin)
        T = len(data)
        clip = np.full((T, H.NUM_NODES, 4), np.nan, np.float32)
        world = None
        for name, points, offset in HOLISTIC_PARTS:
            start = components[name][0]
            part = slice(start, start + len(points))
            xyz = _scaled(data[:, part, :3], width, height)
            clip[:, offset : offset + len(points), :3] = xyz
            clip[:, offset : offset + len(points), 3] = confidence[:, part]
            clip[:, offset : offset + len(points)][missing[:, part]] = np.nan
        if POSE_WORLD in components:
            world = np.full((T, H.NUM_NODES, 3), np.nan, np.float32)
            for name, points, offset in WORLD_PARTS:
                if name not in components:
                    continue
                start = components[name][0]
                part = slice(start, start + len(points))
                world[:, offset : offset + len(points)] = _scaled(data[:, part, :3], width, height)
                world[:, offset : offset + len(points)][missing[:, part]] = np.nan
        return PoseFile(Path(origin), MEDIAPIPE_HOLISTIC, clip, float(body.fps), width, height, world)
    layout_obj, take = header_layout(header, origin)
    dims = len(layout_obj.channels) - (1 if layout_obj.channels[-1] == "confidence" else 0)
    clip = _scaled(data[:, take, :dims], width, height)
    if layout_obj.channels[-1] == "confidence":
        clip = np.concatenate([clip, confidence[:, take, None]], axis=-1)
    clip[missing[:, take]] = np.nan
    return PoseFile(Path(origin), layout_obj, clip, float(body.fps), width, height)


def read_pose_file(path: str | Path, layout: str = "auto", person: int = 0) -> PoseFile:
    """Read one ``.pose`` into aslexp arrays (layout ``auto``: Holistic, or ``header``)."""
    return pose_to_arrays(read_pose(path), str(path), layout, person)


class PoseFormatSource:
    """A folder of ``<video_id>.pose`` files, all in one layout (read from the first file's header)."""

    file_suffix = SUFFIX

    def __init__(self, directory: str | Path, layout: str = "auto", person: int = 0):
        self.directory = Path(directory)
        if not self.directory.is_dir():
            raise FileNotFoundError(f".pose folder not found: {self.directory}")
        if layout not in LAYOUT_MODES:
            raise DataError(f"{self.directory}: pose.options.layout = {layout!r}; expected one of {LAYOUT_MODES}")
        self.mode, self.person = layout, int(person)
        self._layout: KeypointLayout | None = None

    def available(self) -> set[str]:
        return {path.stem for path in self.directory.glob(f"*{SUFFIX}")}

    @property
    def layout(self) -> KeypointLayout:
        if self._layout is None:
            files = sorted(self.directory.glob(f"*{SUFFIX}"))
            if not files:
                raise DataError(f"{self.directory}: no {SUFFIX} files")
            Pose = _pose_format()[0]
            from pose_format.pose_body import EmptyPoseBody

            first = files[0]
            try:
                with open(first, "rb") as handle:
                    header = Pose.read(handle, pose_body=EmptyPoseBody).header
            except Exception as error:  # noqa: BLE001 - a foreign file
                raise DataError(f"{first}: not a readable .pose file ({type(error).__name__}: {error})") from None
            if self.mode == "auto":
                check_holistic(header, str(first))
                self._layout = MEDIAPIPE_HOLISTIC
            else:
                self._layout = register_layout(header_layout(header, str(first))[0])
        return self._layout

    def load(self, video_id: str) -> np.ndarray:
        path = self.directory / f"{video_id}{SUFFIX}"
        result = read_pose_file(path, self.mode, self.person)
        if result.layout.names != self.layout.names or result.layout.channels != self.layout.channels:
            raise DataError(f"{path}: layout {result.layout.name!r} differs from the folder's "
                            f"{self.layout.name!r} (read from its first file)")  # fmt: skip
        return result.keypoints


register_source("pose_format", PoseFormatSource,
                summary="<dir>/<id>.pose (pose-format); layout from the header (options: layout, person)")  # fmt: skip


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
