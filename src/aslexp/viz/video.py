"""Rollout videos: a small GIF always, an H.264 MP4 (browsers play it) where an encoder exists.

GIF: frames quantised to one shared adaptive palette and written with Pillow's optimiser, at most
``max_frames`` frames (evenly subsampled): a 10 s, 240x480 rollout is a few hundred kB, not the
7-8.5 MB of full-colour frames. MP4: H.264 (``libx264``, yuv420p, ``+faststart``) through the ffmpeg
binary of the ``imageio-ffmpeg`` package or an ``ffmpeg`` on PATH; without either no MP4 is written
and :func:`save_mp4` returns None (``pip install imageio-ffmpeg`` adds one).
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import numpy as np

from aslexp.files import atomic_path


def save_gif(frames, path: str | Path, fps: float = 15.0, max_frames: int = 150, colors: int = 64) -> Path:
    """Animated GIF of RGB frames; ``max_frames`` caps the length (the frame rate drops to keep the
    duration), ``colors`` the palette size."""
    from PIL import Image

    frames = [np.asarray(f, dtype=np.uint8) for f in frames]
    if not frames:
        raise ValueError(f"{path}: no frames to write")
    keep = np.unique(np.linspace(0, len(frames) - 1, min(len(frames), max_frames)).round().astype(int))
    # GIF delays are whole centiseconds: spread the rounding so the clip keeps its duration.
    step_ms = 1000.0 / fps * len(frames) / len(keep)
    ends = np.round(np.arange(1, len(keep) + 1) * step_ms / 10.0).astype(int) * 10
    durations = np.diff(np.concatenate([[0], ends])).tolist()
    # One palette for the whole clip (from a strip of sampled frames): no per-frame palettes, no flicker.
    sample = np.concatenate([frames[i] for i in keep[:: max(1, len(keep) // 8)]], axis=0)
    palette = Image.fromarray(sample).quantize(colors=colors, method=Image.Quantize.MEDIANCUT)
    images = [Image.fromarray(frames[i]).quantize(palette=palette, dither=Image.Dither.NONE) for i in keep]
    path = Path(path)
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:], duration=durations,
                       loop=0, optimize=True)
    return path


def ffmpeg_executable() -> str | None:
    """An ffmpeg binary: imageio-ffmpeg's, else one on PATH, else None."""
    try:
        import imageio_ffmpeg

        return imageio_ffmpeg.get_ffmpeg_exe()
    except (ImportError, RuntimeError):
        return shutil.which("ffmpeg")


def save_mp4(frames, path: str | Path, fps: float = 30.0, crf: int = 28) -> Path | None:
    """H.264 MP4 of RGB frames (even sizes are padded), or None when no ffmpeg is available."""
    exe = ffmpeg_executable()
    frames = [np.asarray(f, dtype=np.uint8) for f in frames]
    if exe is None or not frames:
        return None
    height, width = frames[0].shape[:2]
    path = Path(path)
    with atomic_path(path) as tmp:
        cmd = [exe, "-y", "-loglevel", "error", "-f", "rawvideo", "-pix_fmt", "rgb24", "-s", f"{width}x{height}",
               "-r", f"{fps:g}", "-i", "-", "-vf", "pad=ceil(iw/2)*2:ceil(ih/2)*2", "-c:v", "libx264",
               "-pix_fmt", "yuv420p", "-crf", str(crf), "-movflags", "+faststart", "-f", "mp4", str(tmp)]
        proc = subprocess.run(cmd, input=b"".join(f.tobytes() for f in frames), capture_output=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{path}: ffmpeg failed ({exe}): {proc.stderr.decode(errors='replace')[-500:]}")
    return path
