"""Which videos and frames an extraction takes (no MediaPipe needed)."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from aslexp.pose.extract import collect_jobs
from aslexp.pose.mediapipe_worker import VideoError, assign_hands, resolve_range


def test_wlasl_json_gives_cut_jobs_for_the_videos_present(data_root, videos):
    skipped = Counter()
    jobs = collect_jobs([data_root / "wlasl" / "WLASL_v0.3.json"], video_dir=videos, skipped=skipped)
    by_id = {j.video_id: j for j in jobs}
    assert sorted(by_id) == ["63048", "63185", "68011", "68012", "70212", "70266"]
    assert (by_id["70266"].frame_start, by_id["70266"].frame_end, by_id["70266"].gloss) == (3732, 3852, "book")
    assert skipped["wlasl instance without a video file"] == 21083 - 6


def test_folders_and_files_are_taken_whole(videos, tmp_path):
    jobs = collect_jobs([videos, tmp_path / "elsewhere.mp4"], ids=["63185", "elsewhere", "nope"],
                        skipped=(skipped := Counter()))
    assert [(j.video_id, j.frame_start) for j in jobs] == [("63185", None), ("elsewhere", None)]
    assert skipped["requested id without a video"] == 1


@pytest.mark.parametrize("start, end, expected, warned", [
    (1, -1, (0, 57), False),            # WLASL: whole video
    (None, None, (0, 57), False),
    (11, 20, (10, 20), False),          # 1-based, inclusive
    (50, 80, (49, 57), True),           # partly beyond: clamped
    (2055, 2111, (0, 57), True),        # already cut to the sign (the sample clips)
])
def test_frame_ranges(start, end, expected, warned):
    first, stop, warnings = resolve_range(start, end, 57)
    assert (first, stop) == expected
    assert bool(warnings) == warned


@pytest.mark.parametrize("start, end, reason", [(500, 520, "range_beyond_video"), (500, -1, "range_beyond_video"),
                                                (20, 10, "bad_range"), (0 - 3, 5, "bad_range")])
def test_bad_frame_ranges(start, end, reason):
    with pytest.raises(VideoError) as info:
        resolve_range(start, end, 57)
    assert info.value.reason == reason


def test_hands_are_matched_by_position_not_by_label():
    left_ref, right_ref = np.array([0.7, 0.5]), np.array([0.3, 0.5])
    dets = [np.array([[0.31, 0.52]]), np.array([[0.69, 0.49]])]
    # MediaPipe Hands' mirrored labels say "Left" for the signer's right hand: both agree here ...
    assert assign_hands(dets, {"left": left_ref, "right": right_ref}, ["Left", "Right"]) == {"right": 0, "left": 1}
    # ... and position wins when the labels are wrong.
    assert assign_hands(dets, {"left": left_ref, "right": right_ref}, ["Right", "Left"]) == {"right": 0, "left": 1}
    # Without a body to match against, the mirrored label decides.
    assert assign_hands(dets[:1], {"left": None, "right": None}, ["Left"]) == {"right": 0}
