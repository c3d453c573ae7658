"""Video -> MediaPipe Holistic keypoints, cached per video, via a worker in its own environment.

MediaPipe 0.10.21 needs numpy<2; the main environment keeps numpy 2. This module therefore
never imports mediapipe: it runs :mod:`aslexp.pose.mediapipe_worker` with the python of
``.venv-mediapipe`` (made by ``scripts/setup_mediapipe.sh``) and reads the files it writes.

Output folder (a ``directory`` keypoint source for the recognition data layer)::

    layout.json                  the holistic layout (name, names, edges, center, channels, subsets)
    <video_id>.npy               float32 (T, 75, 4): x, y, z, visibility; NaN where missing
    world/<video_id>.npy         float32 (T, 75, 3): metres (MediaPipe world axes)
    face/<video_id>.npy          float32 (T, 468, 3): only with ``face=True``
    status/<video_id>.json       per-video status (ok/failed, reason, counts, frame range, fps)
    summary.json                 the last run's summary
    worker.log                   MediaPipe's own log lines

A video is finished when its status says ok and matches the video file (size, mtime) and the
requested frame range; re-runs skip finished videos, so an interrupted run resumes.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from collections import Counter
from dataclasses import asdict, dataclass, field
from pathlib import Path

from aslexp.keypoints import holistic

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg")
WORKER = Path(__file__).resolve().parent / "mediapipe_worker.py"
PROJECT_ROOT = Path(__file__).resolve().parents[3]
VENV_ENV_VAR = "ASLEXP_MEDIAPIPE_VENV"
DEFAULT_VENV = ".venv-mediapipe"
CACHE_VERSION = 1  # bump when the arrays' meaning changes, so old caches are redone


class ExtractionError(RuntimeError):
    """Extraction cannot start (no worker environment, bad inputs)."""


@dataclass(frozen=True)
class VideoJob:
    """One video to extract: where it is and which frames (WLASL 1-based, inclusive, -1 = end)."""

    video_id: str
    path: str
    frame_start: int | None = None
    frame_end: int | None = None
    gloss: str | None = None


@dataclass
class ExtractOptions:
    face: bool = False
    hands_model: bool = True  # MediaPipe Hands for metric 3D hands (and to fill Holistic's gaps)
    cpus: int | None = None  # pin the worker to this many cores (None: all)
    min_detection_confidence: float = 0.5
    min_tracking_confidence: float = 0.5

    def cache_fields(self) -> dict:
        return {"version": CACHE_VERSION, "face": self.face, "hands_model": self.hands_model,
                "det": self.min_detection_confidence, "track": self.min_tracking_confidence}  # fmt: skip


@dataclass
class ExtractSummary:
    """What happened to every requested video."""

    out_dir: str
    extracted: list[str] = field(default_factory=list)
    cached: list[str] = field(default_factory=list)
    failed: dict[str, dict] = field(default_factory=dict)  # video_id -> {reason, error}
    warnings: dict[str, list[str]] = field(default_factory=dict)
    frames: int = 0
    seconds: float = 0.0
    skipped_inputs: dict[str, int] = field(default_factory=dict)

    @property
    def ok(self) -> list[str]:
        return self.cached + self.extracted

    @property
    def fps(self) -> float:
        return self.frames / self.seconds if self.seconds > 0 else 0.0

    def failure_counts(self) -> dict[str, int]:
        return dict(Counter(f["reason"] for f in self.failed.values()))

    def to_dict(self) -> dict:
        data = asdict(self)
        data.update(fps=round(self.fps, 2), failure_counts=self.failure_counts())
        return data

    def report(self) -> str:
        lines = [
            f"extraction into {self.out_dir}: {len(self.extracted)} extracted, "
            f"{len(self.cached)} already done (cached), {len(self.failed)} failed",
        ]
        if self.frames:
            lines.append(f"  {self.frames} frames in {self.seconds:.1f} s = {self.fps:.1f} frames/s")
        for reason, n in sorted(self.failure_counts().items()):
            lines.append(f"  failed ({reason}): {n}")
        for key, n in sorted(self.skipped_inputs.items()):
            lines.append(f"  skipped inputs ({key}): {n}")
        for vid, failure in sorted(self.failed.items()):
            lines.append(f"  FAILED {vid}: {failure['error']}")
        for vid, warns in sorted(self.warnings.items()):
            for w in warns:
                lines.append(f"  warning {vid}: {w}")
        return "\n".join(lines)


# ----------------------------------------------------------------------------- inputs


def _video_files(directory: Path) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES and p.is_file())


def jobs_from_wlasl(
    wlasl_json: str | os.PathLike, video_dir: str | os.PathLike, skipped: Counter | None = None
) -> list[VideoJob]:
    """One job per WLASL instance whose ``<video_id>.mp4`` is in ``video_dir``, cut to its
    frame_start..frame_end. Instances without a video file are counted in ``skipped``."""
    path = Path(wlasl_json)
    try:
        entries = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, json.JSONDecodeError) as err:
        raise ExtractionError(f"{path}: cannot read the WLASL json ({err})") from None
    if not isinstance(entries, list):
        raise ExtractionError(f"{path}: expected a list of {{'gloss', 'instances': [...]}} entries")
    video_dir = Path(video_dir)
    if not video_dir.is_dir():
        raise ExtractionError(f"video folder not found: {video_dir}")
    available = {p.stem: p for p in _video_files(video_dir)}
    jobs = []
    for entry in entries:
        for inst in entry.get("instances", []):
            vid = str(inst.get("video_id", ""))
            if vid not in available:
                if skipped is not None:
                    skipped["wlasl instance without a video file"] += 1
                continue
            jobs.append(VideoJob(vid, str(available[vid]), inst.get("frame_start"),
                                 inst.get("frame_end"), entry.get("gloss")))  # fmt: skip
    return jobs


def collect_jobs(
    inputs: list[str | os.PathLike],
    wlasl_json: str | os.PathLike | None = None,
    video_dir: str | os.PathLike | None = None,
    ids: list[str] | None = None,
    skipped: Counter | None = None,
) -> list[VideoJob]:
    """Jobs from video files, folders of videos, and/or a WLASL json (with ``video_dir``).

    A ``.json`` among ``inputs`` is read as WLASL json; its videos come from ``video_dir`` or, if
    not given, from the folders among ``inputs``. Without WLASL information a video is taken
    whole; with it, a video in a listed folder is cut to its instance's frame range.
    """
    skipped = skipped if skipped is not None else Counter()
    files, folders, jsons = [], [], []
    for item in inputs:
        p = Path(item)
        if p.suffix.lower() == ".json":
            jsons.append(p)
        elif p.is_dir():
            folders.append(p)
        else:  # a missing file is reported by the worker like any unreadable video
            files.append(p)
    if wlasl_json is not None:
        jsons.append(Path(wlasl_json))
    jobs: dict[str, VideoJob] = {}
    for js in jsons:
        dirs = [Path(video_dir)] if video_dir else folders
        if not dirs:
            raise ExtractionError(f"{js}: a WLASL json needs a video folder (--videos DIR)")
        for d in dirs:
            for job in jobs_from_wlasl(js, d, skipped):
                jobs.setdefault(job.video_id, job)
    if not jsons:
        for d in folders:
            for p in _video_files(d):
                jobs.setdefault(p.stem, VideoJob(p.stem, str(p)))
    for p in files:
        jobs.setdefault(p.stem, VideoJob(p.stem, str(p)))
    result = list(jobs.values())
    if ids:
        wanted = {str(i) for i in ids}
        result = [j for j in result if j.video_id in wanted]
        missing = wanted - {j.video_id for j in result}
        if missing:
            skipped["requested id without a video"] += len(missing)
    return result


# ----------------------------------------------------------------------------- worker


def mediapipe_python() -> Path:
    """The python of the MediaPipe environment (``$ASLEXP_MEDIAPIPE_VENV`` or .venv-mediapipe)."""
    venv = Path(os.environ.get(VENV_ENV_VAR) or PROJECT_ROOT / DEFAULT_VENV)
    python = venv / "bin" / "python"
    if not python.exists():
        raise ExtractionError(
            f"MediaPipe environment not found at {venv} (mediapipe 0.10.21 needs numpy<2, so it "
            f"lives in its own venv): run `bash scripts/setup_mediapipe.sh` or set ${VENV_ENV_VAR}"
        )
    return python


def _cache_key(job: VideoJob, options: ExtractOptions) -> dict:
    return {"frame_start": job.frame_start, "frame_end": job.frame_end, **options.cache_fields()}


def read_status(out_dir: str | os.PathLike, video_id: str) -> dict | None:
    path = Path(out_dir) / "status" / f"{video_id}.json"
    try:
        return json.loads(path.read_text())
    except (OSError, json.JSONDecodeError):
        return None


def _is_finished(job: VideoJob, out_dir: Path, options: ExtractOptions) -> dict | None:
    """The cached status if this video is done for these options and this file, else None."""
    status = read_status(out_dir, job.video_id)
    if not status or status.get("cache_key") != _cache_key(job, options):
        return None
    try:
        same_file = (os.path.getsize(job.path) == status.get("video_size")
                     and abs(os.path.getmtime(job.path) - (status.get("video_mtime") or 0)) < 1e-3)  # fmt: skip
    except OSError:
        same_file = status.get("video_size") is None  # still missing: the failure stands
    if not same_file:
        return None
    if status.get("status") == "ok" and not (out_dir / f"{job.video_id}.npy").is_file():
        return None
    return status


class Progress:
    """One status line with videos done, frames, rate and ETA (on stderr)."""

    def __init__(self, total_videos: int, stream=None, enabled: bool = True):
        self.total_videos = total_videos
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.videos_done = 0
        self.frames_done = 0  # frames of finished videos
        self.frames_current = 0
        self.current_total = 0
        self.start = time.perf_counter()
        self._last = 0.0
        # A terminal gets one rewritten line; a log file a new line every few seconds.
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = 0.5 if self.tty else 5.0

    def video_started(self, frames: int) -> None:
        self.current_total, self.frames_current = frames, 0

    def frames(self, done: int) -> None:
        self.frames_current = done
        self._print()

    def video_done(self) -> None:
        self.frames_done += self.frames_current
        self.frames_current = self.current_total = 0
        self.videos_done += 1
        self._print(force=True)

    def _print(self, force: bool = False) -> None:
        now = time.perf_counter()
        if not self.enabled or (not force and now - self._last < self.interval):
            return
        self._last = now
        elapsed = now - self.start
        frames = self.frames_done + self.frames_current
        rate = frames / elapsed if elapsed > 0 else 0.0
        progress = self.videos_done + (self.frames_current / self.current_total if self.current_total else 0)
        eta = elapsed / progress * (self.total_videos - progress) if progress > 0 else float("nan")
        eta_text = time.strftime("%H:%M:%S", time.gmtime(eta)) if eta == eta else "?"
        self.stream.write(
            ("\r" if self.tty else "")
            + f"[extract] {self.videos_done}/{self.total_videos} videos, {frames} frames, "
            f"{rate:.1f} frames/s, elapsed {elapsed:.0f} s, ETA {eta_text}"
            + ("   " if self.tty else "\n")
        )
        self.stream.flush()

    def close(self) -> None:
        if self.enabled and self.tty:
            self.stream.write("\n")
            self.stream.flush()


def _run_worker(command: str, spec: dict, log_path: Path, on_event) -> int:
    """Run the worker on ``spec``; call ``on_event(dict)`` for each event line; return its rc."""
    python = mediapipe_python()
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as fh:
        json.dump(spec, fh)
        jobs_file = fh.name
    env = dict(os.environ)
    env.update(GLOG_minloglevel="2", TF_CPP_MIN_LOG_LEVEL="2", PYTHONNOUSERSITE="1")
    env.pop("PYTHONPATH", None)  # the worker must not see the main environment's numpy 2
    try:
        with open(log_path, "a") as log:
            proc = subprocess.Popen(
                [str(python), str(WORKER), command, jobs_file],
                stdout=subprocess.PIPE, stderr=log, text=True, env=env,
            )  # fmt: skip
            assert proc.stdout is not None
            for line in proc.stdout:
                line = line.strip()
                if not line.startswith("{"):
                    continue
                try:
                    on_event(json.loads(line))
                except json.JSONDecodeError:
                    continue
            return proc.wait()
    finally:
        os.unlink(jobs_file)


def write_layout_json(out_dir: str | os.PathLike) -> Path:
    path = Path(out_dir) / "layout.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(holistic.layout_json(), indent=1))
    return path


def extract_videos(
    jobs: list[VideoJob],
    out_dir: str | os.PathLike,
    options: ExtractOptions | None = None,
    force: bool = False,
    progress: bool = True,
    max_worker_restarts: int = 3,
) -> ExtractSummary:
    """Extract every job's keypoints into ``out_dir``, skipping finished videos.

    One worker process handles all pending videos (the models load once). A video that makes
    the worker crash is marked failed ('worker_crash') and the worker restarts on the rest.
    """
    options = options or ExtractOptions()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_layout_json(out)
    summary = ExtractSummary(out_dir=str(out))
    pending = []
    for job in jobs:
        status = None if force else _is_finished(job, out, options)
        if status is None:
            pending.append(job)
        elif status.get("status") == "ok":
            summary.cached.append(job.video_id)
            if status.get("warnings"):
                summary.warnings[job.video_id] = status["warnings"]
        else:
            summary.failed[job.video_id] = {"reason": status.get("reason"), "error": status.get("error")}
    bar = Progress(len(pending), enabled=progress and bool(pending))
    started = time.perf_counter()
    restarts = 0
    while pending:
        current: dict[str, str | None] = {"video": None}
        finished: set[str] = set()

        def on_event(event: dict, current=current, finished=finished) -> None:
            kind = event.get("event")
            if kind == "start":
                current["video"] = event["video_id"]
                bar.video_started(int(event.get("frames", 0)))
            elif kind == "progress":
                bar.frames(int(event.get("done", 0)))
            elif kind == "done":
                vid = event["video_id"]
                finished.add(vid)
                status = event["status"]
                if status.get("status") == "ok":
                    summary.extracted.append(vid)
                    summary.frames += int(status.get("frames", 0))
                    if status.get("warnings"):
                        summary.warnings[vid] = status["warnings"]
                else:
                    summary.failed[vid] = {"reason": status.get("reason"), "error": status.get("error")}
                current["video"] = None
                bar.video_done()

        spec = {
            "options": {**asdict(options)},
            "jobs": [{**asdict(j), "out_dir": str(out), "cache_key": _cache_key(j, options)} for j in pending],
        }
        rc = _run_worker("extract", spec, out / "worker.log", on_event)
        pending = [j for j in pending if j.video_id not in finished]
        if not pending:
            break
        crashed = current["video"]
        if rc == 0 and crashed is None:
            # The worker ended cleanly without handling these: should not happen; do not loop.
            for j in pending:
                summary.failed[j.video_id] = {"reason": "worker", "error": "the worker skipped this video"}
            break
        if crashed is None or restarts >= max_worker_restarts:
            log_tail = _tail(out / "worker.log")
            for j in pending:
                summary.failed[j.video_id] = {"reason": "worker_crash",
                                              "error": f"the MediaPipe worker exited with code {rc}; log: {log_tail}"}  # fmt: skip
            break
        summary.failed[crashed] = {"reason": "worker_crash",
                                   "error": f"the MediaPipe worker died (exit code {rc}) on this video"}  # fmt: skip
        pending = [j for j in pending if j.video_id != crashed]
        restarts += 1
    bar.close()
    summary.seconds = time.perf_counter() - started
    (out / "summary.json").write_text(json.dumps(summary.to_dict(), indent=1))
    return summary


def _tail(path: Path, lines: int = 5) -> str:
    try:
        return " | ".join(path.read_text(errors="replace").strip().splitlines()[-lines:])
    except OSError:
        return "(no log)"


# ----------------------------------------------------------------------------- overlay


def render_overlays(
    video_ids: list[str],
    keypoint_dir: str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    fmt: str = "mp4",
    max_width: int = 640,
    cpus: int | None = None,
) -> dict[str, dict]:
    """Draw the extracted skeleton on each video (MP4 or GIF) plus one PNG still per video.

    Returns ``{video_id: {status, overlay, still, ...}}``; drawing happens in the worker
    environment (OpenCV ships with mediapipe there).
    """
    if fmt not in ("mp4", "gif"):
        raise ValueError(f"overlay format {fmt!r}: expected 'mp4' or 'gif'")
    kdir = Path(keypoint_dir)
    odir = Path(out_dir) if out_dir else kdir / "overlay"
    odir.mkdir(parents=True, exist_ok=True)
    results: dict[str, dict] = {}
    jobs = []
    for vid in video_ids:
        status = read_status(kdir, vid)
        if not status or status.get("status") != "ok":
            results[vid] = {"status": "failed", "error": "no successful extraction to draw"}
            continue
        jobs.append({"video_id": vid, "video": status["video"], "keypoints": str(kdir / f"{vid}.npy"),
                     "status": str(kdir / "status" / f"{vid}.json"), "out": str(odir / f"{vid}.{fmt}"),
                     "format": fmt, "max_width": max_width})  # fmt: skip
    if jobs:

        def on_event(event: dict) -> None:
            if event.get("event") == "done":
                results[event["video_id"]] = event["status"]

        _run_worker("overlay", {"options": {"cpus": cpus}, "jobs": jobs}, kdir / "worker.log", on_event)
        for job in jobs:
            results.setdefault(job["video_id"], {"status": "failed", "error": "worker crashed"})
    return results
