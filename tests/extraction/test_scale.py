"""Extraction at scale and its inputs: the WLASL JSON route, frame ranges, several workers on one
queue, cluster shards sharing one output folder, `.pose` output."""

from __future__ import annotations

import json

import numpy as np
import pytest
from pose_format import Pose

from aslexp.pose.extract import VideoJob, apply_frame_ranges, parse_frames, read_status, select_shard
from aslexp.pose.extract_cli import extract_main

from .conftest import SHORT_RANGES

pytestmark = pytest.mark.usefixtures("worker_env")
RANGES = {vid: span for clips in SHORT_RANGES.values() for vid, span in clips.items()}


def test_wlasl_route_cuts_each_clip_and_two_workers_share_the_queue(wlasl6):
    out, printed = wlasl6
    assert "6 extracted, 0 already done (cached), 0 failed" in printed
    pids = set()
    for vid, (start, end) in RANGES.items():
        status = read_status(out, vid)
        assert status["status"] == "ok" and status["frame_range"] == [start - 1, end], vid
        assert np.load(out / f"{vid}.npy").shape == (10, 75, 4)
        pids.add(status["worker_pid"])
        pose = Pose.read((out / f"{vid}.pose").read_bytes())  # --format pose
        assert pose.body.data.shape[:2] == (10, 1)
        assert (pose.header.dimensions.width, pose.header.dimensions.height) == (status["width"], status["height"])
    assert len(pids) == 2  # two MediaPipe processes took videos from one queue


def test_wlasl_alone_is_a_clear_message(data_root, capsys):
    rc = extract_main(["--wlasl", str(data_root / "wlasl" / "WLASL_v0.3.json"), "--out", "unused"])
    err = capsys.readouterr().err
    assert rc == 2 and "needs the videos: add --videos DIR" in err and "Traceback" not in err
    assert extract_main(["--out", "unused"]) == 2  # bad input
    assert "nothing to extract" in capsys.readouterr().err


def test_frame_ranges_parse_and_apply():
    assert parse_frames("11:60") == (None, 11, 60)
    assert parse_frames("68011=5:") == ("68011", 5, -1)
    jobs = [VideoJob("a", "a.mp4"), VideoJob("b", "b.mp4", 3, 9)]
    cut = apply_frame_ranges(jobs, [parse_frames("2:4")])
    assert [(j.frame_start, j.frame_end) for j in cut] == [(2, 4), (3, 9)]  # a WLASL range stays
    cut = apply_frame_ranges(jobs, [parse_frames("2:4"), parse_frames("b=1:-1")])
    assert [(j.frame_start, j.frame_end) for j in cut] == [(2, 4), (1, -1)]
    from aslexp.pose.extract import ExtractionError

    for bad in ("5", "x:3", "9:2", "0:3"):
        with pytest.raises(ExtractionError, match="--frames"):
            parse_frames(bad)
    with pytest.raises(ExtractionError, match="not among the inputs"):
        apply_frame_ranges(jobs, [parse_frames("zzz=1:2")])


def test_shards_are_disjoint_and_cover_in_sorted_order():
    jobs = [VideoJob(v, f"{v}.mp4") for v in ("70266", "63048", "68011", "63185", "70212")]
    shards = [[j.video_id for j in select_shard(jobs, i, 2)] for i in range(2)]
    assert shards == [["63048", "68011", "70266"], ["63185", "70212"]]
    shards3 = [[j.video_id for j in select_shard(jobs[::-1], i, 3)] for i in range(3)]
    assert sorted(sum(shards3, [])) == sorted(j.video_id for j in jobs)  # order of input irrelevant
    assert shards3[0] == ["63048", "70212"]  # sorted positions 0 and 3


def test_shards_share_one_output_folder_and_resume(wlasl6, videos, tmp_path, capsys):
    """Task 0 of 2 and task 1 of 2 on the same folder (as two array jobs would): each extracts
    only its videos, writes its own summary, and a re-run finds its videos done."""
    out = tmp_path / "keypoints"
    common = [str(videos / f"{v}.mp4") for v in ("63185", "68011", "70266")]
    common += ["--frames", "1:4", "--out", str(out), "--quiet"]
    assert extract_main([*common, "--shard", "1/2"]) == 0
    assert "shard 1/2: 1 of 3 videos" in capsys.readouterr().out
    assert sorted(p.stem for p in out.glob("*.npy")) == ["68011"]
    assert extract_main([*common, "--shard", "0/2"]) == 0
    assert sorted(p.stem for p in out.glob("*.npy")) == ["63185", "68011", "70266"]
    summaries = {p.name: json.loads(p.read_text()) for p in out.glob("summary.shard-*.json")}
    assert sorted(summaries) == ["summary.shard-0-of-2.json", "summary.shard-1-of-2.json"]
    assert sorted(summaries["summary.shard-0-of-2.json"]["extracted"]) == ["63185", "70266"]
    capsys.readouterr()
    assert extract_main([*common, "--shard", "0/2"]) == 0
    assert "0 extracted, 2 already done (cached)" in capsys.readouterr().out
    assert read_status(out, "70266")["frame_range"] == [0, 4]
    assert extract_main([*common, "--shard", "2/2"]) == 2  # bad input
