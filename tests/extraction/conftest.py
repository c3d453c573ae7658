"""Fixtures for the extraction tests: one real WLASL clip extracted once per session.

The MediaPipe worker runs in `.venv-mediapipe` (scripts/setup_mediapipe.sh). Without it these
tests skip, except under CI (``$CI`` set), where a missing environment is a failure.
"""

from __future__ import annotations

import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from aslexp.data.root import resolve_data_root
from aslexp.pose.extract import ExtractionError, ExtractOptions, VideoJob, extract_videos, mediapipe_python

CLIP = "63185"  # "whistle": 57 frames, 480x320, the right hand at the mouth, the left out of view
TITLE_CARD = "70212"  # frames 18..68 show only the word PENCIL: no person
POSE_DIR = "keypoints/wlasl-mediapipe-pose"


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


@pytest.fixture(scope="session")  # xdist interleaves modules: a module fixture would be made twice
def ws(data_root, tmp_path_factory) -> dict:
    """The folder the how-to pages' commands run in (tests/extraction/test_howto_commands.py), the
    environment, the short WLASL JSON and the DIR folders."""
    from aslexp.data.wlasl import load_wlasl

    tmp = tmp_path_factory.mktemp("howto")
    short = short_wlasl_json(tmp / "wlasl_short.json")
    # pose=mediapipe_pose with names=gloss: the 291 shared clips as <gloss>_<n>.npy.
    by_gloss = tmp / "by_gloss"
    by_gloss.mkdir()
    by_id, count = load_wlasl(data_root).by_video_id(), {}
    for path in sorted((data_root / POSE_DIR).glob("*.npy")):
        gloss = by_id[path.stem].gloss.replace(" ", "_")
        count[gloss] = count.get(gloss, 0) + 1
        shutil.copy(path, by_gloss / f"{gloss}_{count[gloss]}.npy")
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg",
           "ASLEXP_CACHE_DIR": str(tmp / "cache")}
    return {"tmp": tmp, "env": env, "data": data_root, "short_json": short,
            "dirs": {"mediapipe_pose": by_gloss, "mediapipe_hands": tmp / "hands"}}


@pytest.fixture(scope="session")
def wlasl6(worker_env, ws):
    """docs/howto_keypoints.md's `aslexp extract --wlasl JSON --videos DIR --out outputs/keypoints/wlasl6
    --workers 2 --format pose`, run in the how-to folder as tests/extraction/test_howto_commands.py runs
    the page's commands (ten frames of each of the six clips, SHORT_RANGES): (out_dir, printed summary).
    Made once: that test takes it as the page's step, and the tests here read its files."""
    import shlex

    from .test_howto_commands import KEYPOINTS, documented, run  # that test's reading of the page and its runner

    command = next(c for c in documented(KEYPOINTS) if c.startswith("aslexp extract --wlasl"))
    words = shlex.split(command)
    proc = run(command, ws)
    return ws["tmp"] / words[words.index("--out") + 1], proc.stdout


def hand_frames(keypoint_folder, video_id: str, side: str) -> int:
    """The frames of an extraction whose ``side`` hand MediaPipe found. Its detections differ by CPU
    (XNNPACK's kernels): on some machines 63185's out-of-view left hand is "found" in a few frames,
    so tests that rely on a hand being absent ask the extraction instead of assuming it."""
    from aslexp.keypoints import holistic as H

    offset = H.LEFT_HAND_OFFSET if side == "left" else H.RIGHT_HAND_OFFSET
    world = np.load(Path(keypoint_folder) / "world" / f"{video_id}.npy")
    return int(np.isfinite(world[:, offset:offset + 21]).all(axis=(1, 2)).sum())
