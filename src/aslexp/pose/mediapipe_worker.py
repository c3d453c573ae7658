"""MediaPipe extraction worker: runs INSIDE the separate `.venv-mediapipe` environment.

mediapipe 0.10.21 needs numpy<2 while the main aslexp environment is on numpy 2, so the main
process never imports mediapipe: :mod:`aslexp.pose.extract` starts this file as a subprocess
with the MediaPipe environment's python and the two exchange files only:

    python mediapipe_worker.py extract JOBS.json     # one JSON event per line on stdout; jobs from
                                                     # JOBS.json or, without a "jobs" key, one per stdin line
    python mediapipe_worker.py overlay JOBS.json

This file imports nothing from aslexp except ``keypoints/holistic.py`` (standard library only,
loaded by path) so that it runs without the package being installed in this environment.

Per video it writes, atomically (temporary name, then rename; the status JSON last):

    <out>/<video_id>.npy          float32 (T, 75, 4) x, y, z, visibility in image coordinates
    <out>/world/<video_id>.npy    float32 (T, 75, 3) metres, MediaPipe world axes (x right,
                                  y down, z away from the camera), origin between the hips;
                                  each hand is MediaPipe Hands' world hand moved so that its
                                  wrist sits on the pose wrist
    <out>/face/<video_id>.npy     float32 (T, 468, 3), only with "face": true
    <out>/status/<video_id>.json  status: ok/failed, reason, counts, frame range, fps, ...

Only keypoint arrays lie directly in <out> (the data layer lists <out>/*.npy as videos).

Missing parts are NaN in every channel (never zero).
"""

from __future__ import annotations

import importlib.util
import json
import os
import sys
import time
import traceback
from pathlib import Path

import numpy as np

_HERE = Path(__file__).resolve().parent


def _load_holistic():
    spec = importlib.util.spec_from_file_location("_aslexp_holistic", _HERE.parent / "keypoints" / "holistic.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


H = _load_holistic()

HAND_WORLD_SCALE_M = 0.09  # wrist -> middle MCP of an adult hand, for the image fallback
PROGRESS_EVERY = 10  # frames between progress events


def emit(event: str, **fields) -> None:
    """One JSON event per line on stdout: the parent process parses these."""
    fields["event"] = event
    sys.stdout.write(json.dumps(fields) + "\n")
    sys.stdout.flush()


class VideoError(Exception):
    """A video that cannot be extracted; ``reason`` is a short code counted in the summary."""

    def __init__(self, reason: str, message: str):
        super().__init__(message)
        self.reason = reason


def temporary_path(path: Path) -> Path:
    """Where a file is written before its rename. The name must not end in .npy: readers list
    <dir>/*.npy as finished videos. The parent removes a killed worker's (extract.remove_temporaries)."""
    return path.with_name(f".{path.name}.tmp")


def _atomic_save_npy(path: Path, array: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_path(path)
    try:
        with open(tmp, "wb") as fh:
            np.save(fh, array)
        os.replace(tmp, path)
    except BaseException:  # a full disk, SIGTERM, Ctrl-C: no half file left behind
        tmp.unlink(missing_ok=True)
        raise


def _atomic_write_json(path: Path, data: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = temporary_path(path)
    try:
        tmp.write_text(json.dumps(data, indent=1))
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def _open_video(path: str):
    import cv2

    if not os.path.isfile(path):
        raise VideoError("missing", f"{path}: no such file")
    if os.path.getsize(path) == 0:
        raise VideoError("empty", f"{path}: empty file (0 bytes)")
    cap = cv2.VideoCapture(path)
    if not cap.isOpened():
        raise VideoError("unreadable", f"{path}: cannot be opened as a video (corrupt or unknown format)")
    return cap


def _count_frames(path: str) -> tuple[int, float, int, int]:
    """Frame count by decoding (container counts lie), fps, width, height."""
    import cv2

    cap = _open_video(path)
    fps = float(cap.get(cv2.CAP_PROP_FPS) or 0.0)
    width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
    height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    count = 0
    while cap.grab():
        count += 1
    cap.release()
    if count == 0:
        raise VideoError("empty", f"{path}: no decodable frames")
    return count, fps, width, height


def resolve_range(
    frame_start: int | None, frame_end: int | None, num_frames: int
) -> tuple[int, int, list[str]]:
    """0-based [first, stop) from WLASL's 1-based inclusive frame_start/frame_end (-1 = end).

    A clip that was already cut to the sign (WLASL range beyond the file, but of the file's own
    length, as in the published sample clips) is taken whole; a range that only partly
    overlaps the video is clamped with a warning; a range wholly beyond it is an error.
    """
    warnings: list[str] = []
    start = 1 if frame_start in (None, 0) else int(frame_start)
    end = -1 if frame_end in (None,) else int(frame_end)
    if start < 1:
        raise VideoError("bad_range", f"frame_start={start}: expected >= 1 (1-based)")
    if end != -1 and end < start:
        raise VideoError("bad_range", f"frame_end={end} < frame_start={start}")
    if start > num_frames:
        length = (end - start + 1) if end != -1 else None
        if length is not None and abs(length - num_frames) <= 2:
            warnings.append(
                f"frame range {start}..{end} lies beyond the video's {num_frames} frames but has "
                "its length: taken as a clip already cut to the sign"
            )
            return 0, num_frames, warnings
        raise VideoError(
            "range_beyond_video",
            f"frame range {start}..{end} lies beyond the video's {num_frames} frames",
        )
    stop = num_frames if end == -1 else end
    if stop > num_frames:
        warnings.append(f"frame_end={end} beyond the video's {num_frames} frames: clamped")
        stop = num_frames
    return start - 1, stop, warnings


def _landmarks_xyzv(landmarks, with_visibility: bool) -> np.ndarray:
    arr = np.array(
        [(p.x, p.y, p.z, p.visibility if with_visibility else 1.0) for p in landmarks.landmark],
        dtype=np.float32,
    )
    return arr


def _landmarks_xyz(landmarks) -> np.ndarray:
    return np.array([(p.x, p.y, p.z) for p in landmarks.landmark], dtype=np.float32)


def assign_hands(detections, references, mirrored_labels) -> dict[str, int]:
    """Match MediaPipe Hands detections to the signer's sides.

    detections:      list of (21, 2) image xy of each detected hand
    references:      {"left": xy or None, "right": xy or None} where each side's hand should be
                     (Holistic's own hand wrist, else the pose wrist)
    mirrored_labels: Hands' "Left"/"Right" labels. Hands assumes a mirrored (selfie) image, so
                     on ordinary video its "Left" is the signer's RIGHT hand; used only when
                     there is no reference to match against.
    Returns {side: detection index}.
    """
    sides = ("left", "right")
    if any(references[s] is not None for s in sides):
        best, best_cost = {}, float("inf")
        for order in ([0, 1], [1, 0]):
            assignment = {}
            cost = 0.0
            for side, det in zip(sides, order):
                if det >= len(detections):
                    continue
                ref = references[side]
                if ref is None:
                    # the side without a reference takes what is left, at a neutral cost
                    cost += 0.25
                else:
                    cost += float(np.linalg.norm(detections[det][0] - ref))
                assignment[side] = det
            if cost < best_cost:
                best, best_cost = assignment, cost
        return best
    result = {}
    for det, label in enumerate(mirrored_labels):
        side = "right" if label == "Left" else "left"
        result.setdefault(side, det)
    return result


def image_hand_to_world(hand_xyz: np.ndarray, width: int, height: int) -> np.ndarray:
    """Metric-ish 3D hand from image landmarks (pixels, z on the x scale), for frames where
    Holistic saw a hand but MediaPipe Hands did not. Scaled to an adult hand; centred at 0."""
    pts = hand_xyz[:, :3].astype(np.float64) * np.array([width, height, width])
    length = np.linalg.norm(pts[9] - pts[0])
    if not np.isfinite(length) or length < 1e-6:
        return np.full((21, 3), np.nan, np.float32)
    pts = (pts - pts[0]) * (HAND_WORLD_SCALE_M / length)
    return pts.astype(np.float32)


HAND_OFFSETS = {"left": H.LEFT_HAND_OFFSET, "right": H.RIGHT_HAND_OFFSET}  # a hand's first node
POSE_WRIST = {"left": 15, "right": 16}  # the pose's wrist nodes


def _holistic_frame(res, image: np.ndarray, world: np.ndarray, face: np.ndarray | None,
                    counts: dict[str, int]) -> None:
    """One frame's Holistic result written into its rows of the image, world and face arrays."""
    if res.pose_landmarks is not None:
        counts["pose"] += 1
        image[: H.NUM_POSE] = _landmarks_xyzv(res.pose_landmarks, True)
    if res.pose_world_landmarks is not None:
        world[: H.NUM_POSE] = _landmarks_xyz(res.pose_world_landmarks)
    for side, lm in {"left": res.left_hand_landmarks, "right": res.right_hand_landmarks}.items():
        if lm is not None:
            image[HAND_OFFSETS[side] : HAND_OFFSETS[side] + 21] = _landmarks_xyzv(lm, False)
    if face is not None and res.face_landmarks is not None:
        counts["face"] += 1
        face[:] = _landmarks_xyz(res.face_landmarks)[:468]


def _hands_model_frame(hres, image: np.ndarray, counts: dict[str, int]) -> dict[str, np.ndarray]:
    """The Hands model's detections in one frame, each assigned to a side by its nearness to that
    side's Holistic wrist (else the pose's wrist) and its label: a hand Holistic missed is filled in
    ``image`` (one frame, written in place); returns the world landmarks per side it found."""
    world_hands: dict[str, np.ndarray] = {}
    if not hres.multi_hand_landmarks:
        return world_hands
    dets = [_landmarks_xyz(h) for h in hres.multi_hand_landmarks]
    labels = [h.classification[0].label for h in hres.multi_handedness]
    refs = {}
    for side in ("left", "right"):
        o = HAND_OFFSETS[side]
        if np.isfinite(image[o, 0]):
            refs[side] = image[o, :2]
        elif np.isfinite(image[POSE_WRIST[side], 0]):
            refs[side] = image[POSE_WRIST[side], :2]
        else:
            refs[side] = None
    assignment = assign_hands([d[:, :2] for d in dets], refs, labels)
    for side, det in assignment.items():
        o = HAND_OFFSETS[side]
        if not np.isfinite(image[o, 0]):
            counts["hand_filled_by_hands_model"] += 1
            image[o : o + 21, :3] = dets[det]
            image[o : o + 21, 3] = 1.0
        world_hands[side] = _landmarks_xyz(hres.multi_hand_world_landmarks[det])
    return world_hands


def _hands_in_world(image: np.ndarray, world: np.ndarray, world_hands: dict[str, np.ndarray],
                    counts: dict[str, int], width: int, height: int) -> None:
    """One frame's seen hands placed in the world array (in place) at the pose's wrist: the Hands
    model's world landmarks, else the image landmarks lifted to metres."""
    for side in ("left", "right"):
        o = HAND_OFFSETS[side]
        if not np.isfinite(image[o, 0]):
            continue
        counts[f"{side}_hand"] += 1
        hand_world = world_hands.get(side)
        if hand_world is None:
            hand_world = image_hand_to_world(image[o : o + 21], width, height)
            counts["hand_world_from_image"] += 1
        anchor = world[POSE_WRIST[side]]
        if np.all(np.isfinite(anchor)) and np.all(np.isfinite(hand_world)):
            world[o : o + 21] = hand_world - hand_world[0] + anchor
            counts[f"{side}_hand_world"] += 1


def extract_video(job: dict, options: dict, models) -> dict:
    """Run Holistic (+ Hands) over one video's frame range; write arrays and status."""
    import cv2

    holistic, hands = models
    path = job["path"]
    out = Path(job["out_dir"])
    vid = job["video_id"]
    t0 = time.perf_counter()
    num_frames, fps, width, height = _count_frames(path)
    first, stop, warnings = resolve_range(job.get("frame_start"), job.get("frame_end"), num_frames)
    total = stop - first
    emit("start", video_id=vid, frames=total)

    image = np.full((total, H.NUM_NODES, 4), np.nan, np.float32)
    world = np.full((total, H.NUM_NODES, 3), np.nan, np.float32)
    face = np.full((total, 468, 3), np.nan, np.float32) if options.get("face") else None
    counts = dict.fromkeys(
        ["pose", "left_hand", "right_hand", "left_hand_world", "right_hand_world",
         "hand_filled_by_hands_model", "hand_world_from_image", "face"], 0)  # fmt: skip

    holistic.reset()
    if hands is not None:
        hands.reset()
    cap = _open_video(path)
    for _ in range(first):
        cap.grab()
    decoded = 0
    for t in range(total):
        ok, frame = cap.read()
        if not ok:
            warnings.append(f"decoding stopped at frame {first + t} of {num_frames}")
            break
        decoded += 1
        rgb = cv2.cvtColor(frame, cv2.COLOR_BGR2RGB)
        rgb.flags.writeable = False
        _holistic_frame(holistic.process(rgb), image[t], world[t], None if face is None else face[t], counts)
        world_hands = _hands_model_frame(hands.process(rgb), image[t], counts) if hands is not None else {}
        _hands_in_world(image[t], world[t], world_hands, counts, width, height)
        if (t + 1) % PROGRESS_EVERY == 0 or t + 1 == total:
            emit("progress", video_id=vid, done=t + 1, total=total)
    cap.release()

    if decoded < total:
        image, world = image[:decoded], world[:decoded]
        face = face[:decoded] if face is not None else None
    status = {
        "video_id": vid,
        "video": os.path.abspath(path),
        "video_size": os.path.getsize(path),
        "video_mtime": os.path.getmtime(path),
        "cache_key": job.get("cache_key"),
        "frames": int(decoded),
        "frame_range": [first, first + decoded],
        "video_frames": num_frames,
        "fps": fps,
        "width": width,
        "height": height,
        "counts": counts,
        "warnings": warnings,
        "seconds": round(time.perf_counter() - t0, 3),
        "worker_pid": os.getpid(),
        "extractor": {"name": "mediapipe_holistic", "mediapipe": _mediapipe_version(), "model_complexity": 1,
                      "hands_model": hands is not None},
        "status": "ok", "error": None, "reason": None,  # written only once the checks below pass
    }
    if decoded == 0:
        raise VideoError("empty", f"{path}: no frame could be decoded in range {first}..{stop}")
    if counts["pose"] == 0:
        raise VideoError("no_person", f"{path}: no person found in any of {decoded} frames")
    if counts["left_hand"] == 0 and counts["right_hand"] == 0:
        warnings.append("no hand found in any frame: hand channels are all NaN")
        status["no_hands"] = True
    # Status last: a video counts as finished only once its status file says so.
    _atomic_save_npy(out / "world" / f"{vid}.npy", world)
    if face is not None:
        _atomic_save_npy(out / "face" / f"{vid}.npy", face)
    _atomic_save_npy(out / f"{vid}.npy", image)
    _atomic_write_json(out / "status" / f"{vid}.json", status)
    return status


def _mediapipe_version() -> str:
    import mediapipe

    return mediapipe.__version__


def _limit_cpus(cpus: int | None, cpu_set: list[int] | None = None) -> None:
    """Pin this process to ``cpu_set`` (the parent gives each worker its own cores), else to the
    first ``cpus`` allowed cores."""
    if not hasattr(os, "sched_setaffinity"):
        return
    if cpu_set:
        os.sched_setaffinity(0, set(cpu_set))
    elif cpus:
        allowed = sorted(os.sched_getaffinity(0))
        os.sched_setaffinity(0, allowed[: max(1, int(cpus))])


def _jobs(spec: dict):
    """The spec's job list, or (without one) one JSON job per line on stdin until it closes: the
    parent hands out the next video when this one is done, so several workers share a queue."""
    if "jobs" in spec:
        yield from spec["jobs"]
        return
    for line in sys.stdin:
        if line.strip():
            yield json.loads(line)


def run_extract(jobs_file: str) -> int:
    spec = json.loads(Path(jobs_file).read_text())
    options = spec.get("options", {})
    _limit_cpus(options.get("cpus"), options.get("cpu_set"))
    import mediapipe as mp

    holistic = mp.solutions.holistic.Holistic(
        static_image_mode=False,
        model_complexity=1,  # the only complexity whose model ships in the 0.10.21 wheel
        smooth_landmarks=True,
        refine_face_landmarks=False,
        min_detection_confidence=options.get("min_detection_confidence", 0.5),
        min_tracking_confidence=options.get("min_tracking_confidence", 0.5),
    )
    hands = None
    if options.get("hands_model", True):
        hands = mp.solutions.hands.Hands(
            static_image_mode=False,
            max_num_hands=2,
            model_complexity=1,
            min_detection_confidence=options.get("min_detection_confidence", 0.5),
            min_tracking_confidence=options.get("min_tracking_confidence", 0.5),
        )
    emit("ready", mediapipe=mp.__version__, numpy=np.__version__)
    for job in _jobs(spec):
        vid = job["video_id"]
        status_path = Path(job["out_dir"]) / "status" / f"{vid}.json"
        try:
            status = extract_video(job, options, (holistic, hands))
        except VideoError as err:
            status = _failure(job, err.reason, str(err))
        except Exception as err:  # one bad video must not stop the others
            status = _failure(job, "error", f"{job['path']}: {type(err).__name__}: {err}")
            status["traceback"] = traceback.format_exc()
        if status["status"] != "ok":
            _atomic_write_json(status_path, status)
        emit("done", video_id=vid, status=status)
    holistic.close()
    if hands is not None:
        hands.close()
    return 0


def _failure(job: dict, reason: str, message: str) -> dict:
    path = job["path"]
    exists = os.path.isfile(path)
    return {
        "video_id": job["video_id"],
        "video": os.path.abspath(path),
        "video_size": os.path.getsize(path) if exists else None,
        "video_mtime": os.path.getmtime(path) if exists else None,
        "cache_key": job.get("cache_key"),
        "status": "failed",
        "reason": reason,
        "error": message,
    }


# ----------------------------------------------------------------------------- overlay

_COLORS = {  # BGR
    "body": (80, 220, 80),
    "left": (255, 140, 40),  # signer's left hand: blue-ish
    "right": (40, 80, 255),  # signer's right hand: red-ish
    "face": (200, 200, 200),
}


def _edge_color(i: int, j: int):
    if i >= H.RIGHT_HAND_OFFSET and j >= H.RIGHT_HAND_OFFSET:
        return _COLORS["right"]
    if i >= H.LEFT_HAND_OFFSET and j >= H.LEFT_HAND_OFFSET:
        return _COLORS["left"]
    return _COLORS["body"]


def draw_skeleton(frame: np.ndarray, keypoints: np.ndarray, label: str = "") -> np.ndarray:
    """Draw one frame's (75, 4) keypoints on a BGR frame; NaN points are skipped."""
    import cv2

    h, w = frame.shape[:2]
    thickness = max(1, round(min(h, w) / 240))
    xy = keypoints[:, :2] * np.array([w, h])
    ok = np.all(np.isfinite(xy), axis=1)
    legs = set(range(25, 33))
    for i, j in H.EDGES:
        if i in legs or j in legs or not (ok[i] and ok[j]):
            continue
        p, q = tuple(int(v) for v in xy[i]), tuple(int(v) for v in xy[j])
        cv2.line(frame, p, q, _edge_color(i, j), thickness, cv2.LINE_AA)
    for k in np.flatnonzero(ok):
        if k in legs:
            continue
        color = _edge_color(k, k)
        cv2.circle(frame, tuple(int(v) for v in xy[k]), thickness + 1, color, -1, cv2.LINE_AA)
    missing = []
    if not ok[0]:
        missing.append("no person")
    if not ok[H.LEFT_HAND_OFFSET]:
        missing.append("no left hand")
    if not ok[H.RIGHT_HAND_OFFSET]:
        missing.append("no right hand")
    text = label + ("  [" + ", ".join(missing) + "]" if missing else "")
    scale = max(0.4, min(h, w) / 700)
    cv2.putText(frame, text, (8, int(24 * scale / 0.6)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                (0, 0, 0), thickness + 2, cv2.LINE_AA)  # fmt: skip
    cv2.putText(frame, text, (8, int(24 * scale / 0.6)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                (255, 255, 255), thickness, cv2.LINE_AA)  # fmt: skip
    return frame


def render_overlay(job: dict) -> dict:
    """The video's extracted frame range with its skeleton drawn on it, as MP4 or GIF, plus
    one PNG still (the frame with the most keypoints) for a quick look."""
    import cv2

    keypoints = np.load(job["keypoints"])
    status = json.loads(Path(job["status"]).read_text())
    first, stop = status["frame_range"]
    fps = status.get("fps") or 25.0
    out = Path(job["out"])
    out.parent.mkdir(parents=True, exist_ok=True)
    max_width = int(job.get("max_width", 640))
    cap = _open_video(job["video"])
    for _ in range(first):
        cap.grab()
    frames = []
    for t in range(stop - first):
        ok, frame = cap.read()
        if not ok:
            break
        h, w = frame.shape[:2]
        if w > max_width:
            frame = cv2.resize(frame, (max_width, round(h * max_width / w)), interpolation=cv2.INTER_AREA)
        label = f"{job['video_id']}  frame {first + t + 1}"
        frames.append(draw_skeleton(frame, keypoints[t], label))
    cap.release()
    if not frames:
        raise VideoError("empty", f"{job['video']}: no frames to draw")
    h, w = frames[0].shape[:2]
    fmt = job.get("format", "mp4")
    tmp = out.with_name(out.stem + ".tmp" + out.suffix)
    if fmt == "gif":
        from PIL import Image

        images = [Image.fromarray(cv2.cvtColor(f, cv2.COLOR_BGR2RGB)) for f in frames]
        images[0].save(tmp, save_all=True, append_images=images[1:],
                       duration=round(1000 / fps), loop=0, format="GIF")  # fmt: skip
    else:
        writer = None
        for fourcc in ("avc1", "mp4v"):  # H.264 where this OpenCV build has it
            writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
            if writer.isOpened():
                break
            writer.release()
        if writer is None or not writer.isOpened():
            raise VideoError("overlay", f"{out}: no MP4 encoder available in OpenCV")
        for f in frames:
            writer.write(f)
        writer.release()
    os.replace(tmp, out)
    # The still: the frame with the most keypoints, the one nearest the middle among equals.
    seen = np.isfinite(keypoints[: len(frames), :, 0]).sum(axis=1).astype(float)
    seen -= np.abs(np.arange(len(frames)) - len(frames) / 2) / (len(frames) + 1)
    best = int(np.argmax(seen))
    still = out.with_suffix(".png")
    cv2.imwrite(str(still), frames[best])
    return {"video_id": job["video_id"], "overlay": str(out), "still": str(still),
            "still_frame": first + best + 1, "frames": len(frames)}  # fmt: skip


def run_overlay(jobs_file: str) -> int:
    spec = json.loads(Path(jobs_file).read_text())
    _limit_cpus(spec.get("options", {}).get("cpus"))
    for job in spec["jobs"]:
        try:
            result = render_overlay(job)
            result["status"] = "ok"
        except Exception as err:  # noqa: BLE001 - reported per video
            result = {"video_id": job["video_id"], "status": "failed", "error": f"{type(err).__name__}: {err}"}
        emit("done", video_id=job["video_id"], status=result)
    return 0


def main(argv: list[str]) -> int:
    if len(argv) != 2 or argv[0] not in ("extract", "overlay"):
        sys.stderr.write("usage: mediapipe_worker.py {extract|overlay} JOBS.json\n")
        return 2
    os.environ.setdefault("GLOG_minloglevel", "2")
    return run_extract(argv[1]) if argv[0] == "extract" else run_overlay(argv[1])


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
