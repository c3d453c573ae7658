"""Rollout videos: a GIF small enough to open anywhere, an H.264 MP4 where an encoder exists."""

from __future__ import annotations

import subprocess

import pytest

from aslexp.envs.imitation import ImitationEnv
from aslexp.viz.video import ffmpeg_executable, save_gif, save_mp4


@pytest.fixture(scope="module")
def frames(motion_a, data_root):
    env = ImitationEnv(motion_a, render_mode="rgb_array", render_size=(240, 240), data_root=data_root)
    env.reset(options={"time": 0.0})
    out = []
    for k in range(300):  # 10 s at 30 Hz, a frame every 2 steps: what the imitate job renders
        env.step(env.reference_action(1))
        if k % 2 == 0:
            out.append(env.render())
    env.close()
    return out


def test_gif_is_small_and_keeps_the_duration(frames, tmp_path):
    from PIL import Image

    path = save_gif(frames, tmp_path / "a.gif", fps=15.0)
    assert path.stat().st_size < 1_500_000, path.stat().st_size  # full-colour frames: 7-8.5 MB
    with Image.open(path) as gif:
        assert gif.size == (480, 240) and gif.n_frames == len(frames)
        duration = sum(gif.seek(i) or gif.info["duration"] for i in range(gif.n_frames))
    assert duration == pytest.approx(1000 * len(frames) / 15.0, rel=0.05)
    capped = save_gif(frames, tmp_path / "b.gif", fps=15.0, max_frames=50)
    with Image.open(capped) as gif:
        assert gif.n_frames == 50


def test_mp4_is_h264(frames, tmp_path):
    exe = ffmpeg_executable()
    if exe is None:
        pytest.skip("no ffmpeg (pip install imageio-ffmpeg): save_mp4 writes nothing, the job logs it")
    path = save_mp4(frames, tmp_path / "a.mp4", fps=15.0)
    assert path is not None and 0 < path.stat().st_size < 1_000_000
    probe = subprocess.run([exe, "-hide_banner", "-i", str(path)], capture_output=True, text=True)
    assert "Video: h264" in probe.stderr and "yuv420p" in probe.stderr, probe.stderr[-500:]
