"""Retargeting that holds a handshape: landmarks filtered in time before inverse kinematics, the
flicker of a held handshape, and `aslexp retarget` scoring a folder end to end (real clip: "whistle",
a bent-V hand held at the lips)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from aslexp.keypoints import holistic as H
from aslexp.pose.extract_cli import extract_main
from aslexp.pose.landmark_filter import LandmarkFilter, held_handshape_flicker, retargeting_options, still_frames
from aslexp.pose.landmarks import load_world
from aslexp.pose.retarget import retarget_landmarks

from .conftest import CLIP, hand_frames

SAVGOL = LandmarkFilter("savgol", 0.3, 2)


def test_a_filter_smooths_each_seen_run_and_never_bridges_a_gap():
    rng = np.random.default_rng(0)
    t = np.arange(60) / 30.0
    clean = np.stack([np.sin(t), np.cos(t), t], axis=-1)[:, None, :].repeat(4, axis=1)  # (60, 4, 3)
    whole = clean + rng.normal(scale=0.02, size=clean.shape)
    noisy = whole.copy()
    noisy[20:25, 2:] = np.nan  # two points unseen for five frames
    for kind in ("savgol", "gaussian"):
        out = LandmarkFilter(kind, 0.3, 2).apply(noisy, 30.0)
        assert np.isnan(out[20:25, 2:]).all() and np.isfinite(out[20:25, :2]).all()  # the gap stays a gap
        seen = np.isfinite(noisy).all(-1)
        if kind == "gaussian":  # its edges hold the nearest value, which biases a trend: the interior
            seen[:30] = seen[50:] = False
        assert np.abs(out - clean)[seen].mean() < 0.6 * np.abs(noisy - clean)[seen].mean()
        # linear: the fingers relative to the wrist are smoothed as the points are
        both = LandmarkFilter(kind, 0.3, 2).apply(whole, 30.0)
        np.testing.assert_allclose(LandmarkFilter(kind, 0.3, 2).apply(whole - whole[:, :1], 30.0),
                                   both - both[:, :1], atol=1e-9)
    np.testing.assert_array_equal(LandmarkFilter("none", 0.3, 2).apply(noisy, 30.0), noisy)
    assert SAVGOL.frames(30.0) == 9 and SAVGOL.frames(25.0) == 9 and LandmarkFilter("savgol", 0.05, 3).frames(25) == 5


def test_bad_retargeting_settings_are_refused_in_one_line(tmp_path, capsys):
    base = {"hand": "dominant", "torso": "vertical", "sigma": 1.0, "filter": {"kind": "none", "window": 0, "order": 2}}
    for change, said in [({"sigma": -1}, "retargeting.sigma=-1"), ({"hand": "both"}, "retargeting.hand='both'"),
                         ({"filter": {"kind": "kalman"}}, "retargeting.filter.kind='kalman'"),
                         ({"filter": {"kind": "savgol", "window": -0.1}}, "retargeting.filter.window=-0.1"),
                         ({"filter": {"kind": "savgol", "window": 0.2, "order": 9}}, "retargeting.filter.order=9"),
                         ({"filter": {"size": 3}}, "unknown keys ['size']"),
                         ({"pose_hand_points": "yes"}, "retargeting.pose_hand_points='yes': expected true or false")]:
        with pytest.raises(ValueError, match=said.replace("[", r"\[").replace("(", r"\(")):
            retargeting_options({**base, **change})
    folder = tmp_path / "none"
    assert extract_main([str(folder), "--motions", "--filter", "savgol", "--filter-window", "-1", "--out",
                         str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "--filter-window=-1" in err and "seconds >= 0" in err


@pytest.mark.usefixtures("worker_env")
def test_on_whistle_the_filter_holds_the_handshape_steadier(extracted, tmp_path, data_root):
    """The person holds the bent V still for a few frames; the retargeted fingers flicker there less
    with the landmarks filtered (the angles' own smoothing off in both, to see the filter alone)."""
    out, _, _ = extracted
    landmarks = load_world(out, CLIP)
    hand = landmarks.world[:, H.RIGHT_HAND_OFFSET:H.RIGHT_HAND_OFFSET + 21].astype(float)
    held = held_handshape_flicker(np.zeros((len(hand), 1)), still_frames(hand, landmarks.fps))["held_frames"]
    assert 5 <= held < len(hand) / 2  # a few held frames, most of the sign moves
    flicker = {}
    for name, landmark_filter in (("none", None), ("savgol", SAVGOL)):
        result = retarget_landmarks(landmarks, tmp_path / name, sigma=0.0, data_root=data_root,
                                    landmark_filter=landmark_filter)
        report = result["upper_body"]["right_hand"]["handshape_flicker"]
        assert report["held_frames"] == held  # held frames read from the unfiltered person
        assert result["hand"]["handshape_flicker"]["held_frames"] == held
        flicker[name] = report["flicker_rad"]
        assert result["landmark_filter"]["kind"] == name
    assert 0 < flicker["savgol"] < 0.8 * flicker["none"], flicker
    # a hand held perfectly still does not flicker
    angles = np.tile(np.linspace(0, 1, 15), (30, 1))
    assert held_handshape_flicker(angles, np.ones(30, bool))["flicker_rad"] == 0.0


@pytest.mark.usefixtures("worker_env")
def test_the_retarget_job_scores_a_folder_end_to_end(extracted, tmp_path, data_root):
    out, _, _ = extracted
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg"}
    run = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-m", "aslexp.cli", "retarget", f"retarget.keypoints={out}",
                           "retargeting.filter.kind=savgol", "retargeting.filter.window=0.3", f"hydra.run.dir={run}"],
                          capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads((run / "retarget.json").read_text())
    whistle = next(c for c in result["clips"] if c["video"] == CLIP)
    assert whistle["flicker"]["right"]["held_frames"] >= 5
    if not hand_frames(out, CLIP, "left"):  # out of view (MediaPipe "finds" it in a few frames on some CPUs)
        assert "left" not in whistle["flicker"]
    assert all(0 < whistle["hands_dtwp"][s] < 20 for s in ("reference", "controller"))
    assert (run / "motions" / "upper_body" / f"{CLIP}.txt").is_file() and (run / "retarget.png").stat().st_size > 0
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["objective"] == result["hands_dtwp"]["controller"] > 0 and metrics["stage"] == "controller"
    report = json.loads((run / "motions" / "reports" / f"{CLIP}.json").read_text())
    assert report["landmark_filter"] == {"kind": "savgol", "window_s": 0.3, "order": 2} and report["source"]
    bad = subprocess.run([sys.executable, "-m", "aslexp.cli", "retarget", f"retarget.keypoints={tmp_path}",
                          f"hydra.run.dir={tmp_path / 'bad'}"], capture_output=True, text=True, timeout=300, env=env)
    assert bad.returncode != 0 and "no world/ folder" in bad.stderr.strip().splitlines()[-1]
