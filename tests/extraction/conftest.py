"""Fixtures for the extraction tests: one real WLASL clip extracted once per session.

The MediaPipe worker runs in `.venv-mediapipe` (scripts/setup_mediapipe.sh). Without it these
tests skip, except under CI (``$CI`` set), where a missing environment is a failure.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import pytest

from aslexp.data.root import resolve_data_root
from aslexp.pose.extract import ExtractionError, ExtractOptions, VideoJob, extract_videos, mediapipe_python

CLIP = "63185"  # "whistle": 57 frames, 480x320, the right hand at the mouth, the left out of view
TITLE_CARD = "70212"  # frames 18..68 show only the word PENCIL: no person


@pytest.fixture(scope="session")
def data_root() -> Path:
    try:
        return resolve_data_root()
    except FileNotFoundError as error:
        pytest.skip(f"real data not available: {error}")


@pytest.fixture(scope="session")
def videos(data_root) -> Path:
    return data_root / "videos" / "wlasl"


@pytest.fixture(scope="session")
def worker_env():
    try:
        return mediapipe_python()
    except ExtractionError as error:
        if os.environ.get("CI"):
            pytest.fail(str(error))
        pytest.skip(str(error))


@pytest.fixture(scope="session")
def bad_inputs(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("bad_videos")
    empty = folder / "empty.mp4"
    empty.write_bytes(b"")
    garbage = folder / "garbage.mp4"
    garbage.write_bytes(b"this is not a video\n" * 100)
    return {"empty": empty, "garbage": garbage, "missing": folder / "missing.mp4"}


def session_jobs(videos: Path, bad: dict[str, Path]) -> list[VideoJob]:
    clip = str(videos / f"{CLIP}.mp4")
    return [
        VideoJob(CLIP, clip),  # whole clip, as `aslexp extract FILE` makes it
        VideoJob("part", clip, 1, 20),  # 20 frames: the resume test redoes this one
        VideoJob("nobody", str(videos / f"{TITLE_CARD}.mp4"), 31, 45),
        VideoJob("beyond", clip, 500, 520),
        VideoJob("empty", str(bad["empty"])),
        VideoJob("garbage", str(bad["garbage"])),
        VideoJob("missing", str(bad["missing"])),
    ]


@pytest.fixture(scope="session")
def extracted(worker_env, videos, bad_inputs, tmp_path_factory):
    """(out_dir, summary, jobs) after one extraction run on one core."""
    out = tmp_path_factory.mktemp("keypoints")
    jobs = session_jobs(videos, bad_inputs)
    summary = extract_videos(jobs, out, ExtractOptions(cpus=1), progress=False)
    return out, summary, jobs


@pytest.fixture()
def extracted_copy(extracted, tmp_path):
    """A private copy of the session's output folder, for tests that change it."""
    out, summary, jobs = extracted
    copy = tmp_path / "keypoints"
    shutil.copytree(out, copy)
    return copy, jobs


# Ten frames inside each of the six real clips, in WLASL's own JSON format (1-based, inclusive):
# the `--wlasl` route end to end at a test's cost. 70212 shows only a title card in frames 18-68.
SHORT_RANGES = {"book": {"68011": (20, 29), "68012": (40, 49), "70212": (75, 84), "70266": (50, 59)},
                "wheelchair": {"63048": (40, 49)}, "whistle": {"63185": (20, 29)}}


def short_wlasl_json(path: Path) -> Path:
    """SHORT_RANGES written in WLASL's JSON format, at ``path``."""
    import json

    path.write_text(json.dumps([
        {"gloss": gloss, "instances": [{"video_id": vid, "frame_start": start, "frame_end": end}
                                       for vid, (start, end) in clips.items()]}
        for gloss, clips in SHORT_RANGES.items()
    ]))  # fmt: skip
    return path


@pytest.fixture(scope="session")
def wlasl6(worker_env, videos, tmp_path_factory):
    """`aslexp extract --wlasl JSON --videos DIR --workers 2 --format pose` on ten frames of each
    of the six clips: (out_dir, printed summary)."""
    import contextlib
    import io

    from aslexp.pose.extract_cli import extract_main

    base = tmp_path_factory.mktemp("wlasl6")
    wlasl_json = short_wlasl_json(base / "wlasl_short.json")
    out = base / "keypoints"
    printed = io.StringIO()
    with contextlib.redirect_stdout(printed):
        rc = extract_main(["--wlasl", str(wlasl_json), "--videos", str(videos), "--out", str(out),
                           "--workers", "2", "--format", "pose", "--quiet"])  # fmt: skip
    assert rc == 0, printed.getvalue()
    return out, printed.getvalue()
