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
import queue
import subprocess
import sys
import tempfile
import threading
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.files import atomic_write_text
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


def video_files(directory: Path) -> list[Path]:
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
    available = {p.stem: p for p in video_files(video_dir)}
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
            for p in video_files(d):
                jobs.setdefault(p.stem, VideoJob(p.stem, str(p)))
            for p in sorted(set(d.iterdir()) - set(video_files(d))):  # counted, so that "no videos" says why
                if p.is_file():
                    skipped[f"{p.suffix or 'no suffix'} file in a folder (not a video)"] += 1
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


def parse_frames(text: str, given: str | None = None) -> tuple[str | None, int, int]:
    """``START:END`` or ``VIDEO_ID=START:END`` -> (video id or None, start, end): 1-based and
    inclusive like WLASL's frame_start/frame_end; END empty or -1 means to the end. ``given`` is
    how an error names the value (default ``--frames 'TEXT'``; `aslexp lookup` says ``frames=TEXT``)."""
    given = given or f"--frames {text!r}"
    video_id, _, span = text.rpartition("=") if "=" in text else (None, "", text)
    try:
        start_text, end_text = span.split(":")
        start = int(start_text) if start_text.strip() else 1
        end = int(end_text) if end_text.strip() else -1
    except ValueError:
        raise ExtractionError(f"{given}: expected START:END or VIDEO_ID=START:END "
                              "(1-based, inclusive; END -1 or empty = to the end), e.g. 1:60") from None  # fmt: skip
    if start < 1 or (end != -1 and end < start):
        raise ExtractionError(f"{given}: expected 1 <= START <= END (or END = -1)")
    return (video_id or None), start, end


def apply_frame_ranges(jobs: list[VideoJob], ranges: list[tuple[str | None, int, int]]) -> list[VideoJob]:
    """Cut jobs to ``--frames`` ranges: a range with a video id applies to that video (over any
    WLASL range); one without applies to every video taken whole (WLASL clips keep theirs)."""
    if not ranges:
        return jobs
    by_id = {vid: (start, end) for vid, start, end in ranges if vid is not None}
    everyone = [(start, end) for vid, start, end in ranges if vid is None]
    if len(everyone) > 1:
        raise ExtractionError("--frames START:END given twice without a video id; use VIDEO_ID=START:END")
    unknown = sorted(set(by_id) - {job.video_id for job in jobs})
    if unknown:
        raise ExtractionError(f"--frames names video id(s) {unknown} that are not among the inputs")
    result = []
    for job in jobs:
        span = by_id.get(job.video_id) or (everyone[0] if everyone and job.frame_start is None else None)
        result.append(replace(job, frame_start=span[0], frame_end=span[1]) if span else job)
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
    """One status line with videos done, frames, rate and ETA (on stderr); thread-safe, one slot
    per worker for the video it is on."""

    def __init__(self, total_videos: int, stream=None, enabled: bool = True):
        self.total_videos = total_videos
        self.stream = stream or sys.stderr
        self.enabled = enabled
        self.videos_done = 0
        self.frames_done = 0  # frames of finished videos
        self.current: dict[int, tuple[int, int]] = {}  # worker -> (frames done, frames in its video)
        self.start = time.perf_counter()
        self._last = 0.0
        self._lock = threading.Lock()
        # A terminal gets one rewritten line; a log file a new line every few seconds.
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.interval = 0.5 if self.tty else 5.0

    def video_started(self, frames: int, worker: int = 0) -> None:
        with self._lock:
            self.current[worker] = (0, frames)

    def frames(self, done: int, worker: int = 0) -> None:
        with self._lock:
            self.current[worker] = (done, self.current.get(worker, (0, 0))[1])
            self._print()

    def video_done(self, worker: int = 0) -> None:
        with self._lock:
            self.frames_done += self.current.pop(worker, (0, 0))[0]
            self.videos_done += 1
            self._print(force=True)

    def _print(self, force: bool = False) -> None:
        now = time.perf_counter()
        if not self.enabled or (not force and now - self._last < self.interval):
            return
        self._last = now
        elapsed = now - self.start
        frames = self.frames_done + sum(done for done, _ in self.current.values())
        rate = frames / elapsed if elapsed > 0 else 0.0
        progress = self.videos_done + sum(done / total for done, total in self.current.values() if total)
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


def _run_worker(command: str, spec: dict, log_path: Path, on_event, next_job=None) -> int:
    """Run the worker on ``spec``; call ``on_event(dict)`` for each event line; return its rc.

    With ``next_job`` (a callable returning a job dict, or None when there is none left) the
    jobs are fed one at a time on the worker's stdin: one when it starts and one after each
    'done' event, so that several workers share one queue and stay busy until it is empty.
    """
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
                stdin=subprocess.PIPE if next_job else subprocess.DEVNULL,
                stdout=subprocess.PIPE, stderr=log, text=True, env=env,
            )  # fmt: skip
            assert proc.stdout is not None

            def feed() -> None:
                job = next_job()
                try:
                    if job is None:
                        proc.stdin.close()
                    else:
                        proc.stdin.write(json.dumps(job) + "\n")
                        proc.stdin.flush()
                except (BrokenPipeError, OSError):  # the worker died: its exit code tells
                    pass

            if next_job:
                feed()
            for line in proc.stdout:
                line = line.strip()
                if not line.startswith("{"):
                    continue
                try:
                    event = json.loads(line)
                except json.JSONDecodeError:
                    continue
                on_event(event)
                if next_job and event.get("event") == "done":
                    feed()
            return proc.wait()
    finally:
        os.unlink(jobs_file)


def remove_temporaries(out_dir: str | os.PathLike, video_ids: list[str]) -> list[Path]:
    """Remove what a killed worker left of these videos' files (the worker's temporary names:
    ``mediapipe_worker.temporary_path``); returns the paths removed. Only videos about to be
    extracted: their temporaries belong to no running worker (shards share --out, not videos)."""
    from aslexp.pose.mediapipe_worker import temporary_path

    out = Path(out_dir)
    removed = []
    for vid in video_ids:
        for final in (out / f"{vid}.npy", out / "world" / f"{vid}.npy", out / "face" / f"{vid}.npy",
                      out / "status" / f"{vid}.json"):  # fmt: skip
            tmp = temporary_path(final)
            if tmp.is_file():
                tmp.unlink(missing_ok=True)
                removed.append(tmp)
    return removed


def write_layout_json(out_dir: str | os.PathLike) -> Path:
    return atomic_write_text(Path(out_dir) / "layout.json", json.dumps(holistic.layout_json(), indent=1))


def select_shard(jobs: list[VideoJob], index: int, count: int) -> list[VideoJob]:
    """Task ``index`` of ``count`` (0-based): the jobs whose position in video-id order is
    ``index`` modulo ``count``. Every task sees the same order, so the shards are disjoint and
    together cover every job, whatever each task finds already done in the shared output."""
    if count < 1 or not 0 <= index < count:
        raise ExtractionError(f"--shard {index}/{count}: expected i/n with 0 <= i < n")
    ordered = sorted(jobs, key=lambda job: job.video_id)
    return ordered[index::count]


def parse_shard(text: str) -> tuple[int, int]:
    """'i/n' -> (i, n), 0 <= i < n (e.g. ``$SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT``)."""
    try:
        index, count = (int(part) for part in text.split("/"))
    except ValueError:
        raise ExtractionError(f"--shard {text!r}: expected i/n, e.g. 0/4 (task 0 of 4)") from None
    if count < 1 or not 0 <= index < count:
        raise ExtractionError(f"--shard {text}: expected i/n with 0 <= i < n")
    return index, count


def _core_sets(workers: int, cpus: int | None) -> list[list[int] | None]:
    """Disjoint cores per worker when ``cpus`` per worker is given (wrapping round when there are
    not enough), else None (each worker may use every core)."""
    if not cpus or not hasattr(os, "sched_getaffinity"):
        return [None] * workers
    allowed = sorted(os.sched_getaffinity(0))
    return [[allowed[(k * cpus + c) % len(allowed)] for c in range(cpus)] for k in range(workers)]


def extract_videos(
    jobs: list[VideoJob],
    out_dir: str | os.PathLike,
    options: ExtractOptions | None = None,
    force: bool = False,
    progress: bool = True,
    max_worker_restarts: int = 3,
    workers: int = 1,
    summary_name: str = "summary.json",
) -> ExtractSummary:
    """Extract every job's keypoints into ``out_dir``, skipping finished videos.

    ``workers`` MediaPipe processes (each loads the models once) share one queue of pending
    videos; with ``options.cpus`` each gets its own ``cpus`` cores. A video that makes a worker
    crash is marked failed ('worker_crash') and that worker restarts on the rest of the queue.
    """
    options = options or ExtractOptions()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    write_layout_json(out)
    summary = ExtractSummary(out_dir=str(out))
    pending: queue.Queue[VideoJob] = queue.Queue()
    for job in jobs:
        status = None if force else _is_finished(job, out, options)
        if status is None:
            pending.put(job)
        elif status.get("status") == "ok":
            summary.cached.append(job.video_id)
            if status.get("warnings"):
                summary.warnings[job.video_id] = status["warnings"]
        else:
            summary.failed[job.video_id] = {"reason": status.get("reason"), "error": status.get("error")}
    if not pending.empty():
        mediapipe_python()  # no worker environment: say so here, not in a worker thread
        remove_temporaries(out, [job.video_id for job in list(pending.queue)])
    workers = max(1, min(int(workers), pending.qsize()))
    bar = Progress(pending.qsize(), enabled=progress and not pending.empty())
    lock = threading.Lock()
    started = time.perf_counter()
    threads = [
        threading.Thread(target=_worker_loop, name=f"mediapipe-worker-{k}", daemon=True,
                         args=(k, pending, out, options, cores, summary, lock, bar, max_worker_restarts))
        for k, cores in enumerate(_core_sets(workers, options.cpus))
    ] if not pending.empty() else []  # fmt: skip
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    bar.close()
    summary.seconds = time.perf_counter() - started
    atomic_write_text(out / summary_name, json.dumps(summary.to_dict(), indent=1))
    return summary


def _worker_loop(k: int, pending: queue.Queue, out: Path, options: ExtractOptions, cores: list[int] | None,
                 summary: ExtractSummary, lock: threading.Lock, bar: Progress, max_restarts: int) -> None:  # fmt: skip
    """One worker slot: run a worker process on the shared queue, restart it after a crash."""
    restarts = 0
    spec = {"options": {**asdict(options), "cpu_set": cores}}

    def fail(job: VideoJob, reason: str, error: str) -> None:
        with lock:
            summary.failed[job.video_id] = {"reason": reason, "error": error}

    while not pending.empty():
        state: dict[str, Any] = {"job": None, "ready": False}

        def next_job(state=state) -> dict | None:
            try:
                job = pending.get_nowait()
            except queue.Empty:
                state["job"] = None
                return None
            state["job"] = job
            return {**asdict(job), "out_dir": str(out), "cache_key": _cache_key(job, options)}

        def on_event(event: dict, state=state) -> None:
            kind = event.get("event")
            if kind == "ready":
                state["ready"] = True
            elif kind == "start":
                bar.video_started(int(event.get("frames", 0)), k)
            elif kind == "progress":
                bar.frames(int(event.get("done", 0)), k)
            elif kind == "done":
                vid, status = event["video_id"], event["status"]
                with lock:
                    if status.get("status") == "ok":
                        summary.extracted.append(vid)
                        summary.frames += int(status.get("frames", 0))
                        if status.get("warnings"):
                            summary.warnings[vid] = status["warnings"]
                    else:
                        summary.failed[vid] = {"reason": status.get("reason"), "error": status.get("error")}
                state["job"] = None
                bar.video_done(k)

        rc = _run_worker("extract", spec, out / "worker.log", on_event, next_job)
        crashed = state["job"]
        if crashed is None and rc == 0:
            return  # the queue is empty
        if crashed is not None and rc == 0:  # ended cleanly without doing it: should not happen
            fail(crashed, "worker", "the worker skipped this video")
            continue
        if crashed is None or not state["ready"] or restarts >= max_restarts:
            # It could not start, or keeps dying: fail what it holds and what is left, with the log.
            error = f"the MediaPipe worker exited with code {rc}; log: {_tail(out / 'worker.log')}"
            for job in ([crashed] if crashed is not None else []) + _drain(pending):
                fail(job, "worker_crash", error)
            return
        fail(crashed, "worker_crash", f"the MediaPipe worker died (exit code {rc}) on this video")
        bar.video_done(k)
        restarts += 1


def _drain(pending: queue.Queue) -> list[VideoJob]:
    jobs = []
    while True:
        try:
            jobs.append(pending.get_nowait())
        except queue.Empty:
            return jobs


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
        if fmt == "mp4":
            for result in results.values():
                if result.get("status") == "ok":
                    result["codec"] = to_h264(Path(result["overlay"]))
    return results


def to_h264(path: Path) -> str:
    """Re-encode an MP4 to H.264 (browsers do not play OpenCV's mp4v) with the ffmpeg the main
    environment has (imageio-ffmpeg); returns the codec the file ends with."""
    import subprocess

    from aslexp.files import atomic_path
    from aslexp.viz.video import ffmpeg_executable

    exe = ffmpeg_executable()
    if exe is None:
        return "mp4v"
    with atomic_path(path) as tmp:
        done = subprocess.run([exe, "-y", "-loglevel", "error", "-i", str(path), "-c:v", "libx264",
                               "-pix_fmt", "yuv420p", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2",
                               "-movflags", "+faststart", "-f", "mp4", str(tmp)], capture_output=True)
        if done.returncode != 0:
            raise ExtractionError(f"{path}: ffmpeg could not re-encode it to H.264: "
                                  f"{done.stderr.decode(errors='replace')[-300:]}")
    return "h264"


# ----------------------------------------------------------------------------- .pose files


def write_pose_files(out_dir: str | os.PathLike, video_ids: list[str], force: bool = False) -> dict[str, str]:
    """``<out>/<id>.pose`` (pose-format, MediaPipe Holistic as the library lays it out) for each
    extracted video, from its arrays and status; a file newer than the video's status is kept.
    Returns {video_id: path or 'failed: reason'}."""
    from aslexp.keypoints.posefile import write_holistic_pose

    out = Path(out_dir)
    written = {}
    for vid in video_ids:
        status = read_status(out, vid)
        target = out / f"{vid}.pose"
        if not status or status.get("status") != "ok":
            written[vid] = "failed: no successful extraction"
            continue
        if not force and target.is_file() and target.stat().st_mtime >= (out / "status" / f"{vid}.json").stat().st_mtime:
            written[vid] = str(target)
            continue
        world = out / "world" / f"{vid}.npy"
        face = out / "face" / f"{vid}.npy"
        write_holistic_pose(target, np.load(out / f"{vid}.npy"), float(status.get("fps") or 25.0),
                            int(status["width"]), int(status["height"]),
                            world=np.load(world) if world.is_file() else None,
                            face=np.load(face) if face.is_file() else None)  # fmt: skip
        written[vid] = str(target)
    return written
