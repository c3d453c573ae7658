"""A small figure of one keypoint sequence (matplotlib, Agg): a few skeleton frames and the wrists'
paths over time, drawn from the model's input (normalised coordinates, y down as in the image)."""

from __future__ import annotations

import textwrap
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402

from aslexp.files import naming_errors  # noqa: E402

_SIDES = {"left": "tab:blue", "right": "tab:orange"}


def _tracked(names: Sequence[str]) -> list[tuple[str, int, str]]:
    """(label, node, colour) of the points whose paths are drawn: the wrists, else the hands' first
    points, else the first node."""
    out = []
    for side, colour in _SIDES.items():
        for wanted in (f"{side}_wrist", f"{side}_hand_wrist"):
            if wanted in names:
                out.append((f"{side} wrist", list(names).index(wanted), colour))
                break
    return out or [(names[0], 0, "tab:blue")]


def plot_keypoint_sequence(X: np.ndarray, mask: np.ndarray, names: Sequence[str], edges: Sequence[tuple[int, int]],
                           channels: Sequence[str], path: str | Path, *, frames: int | None = None,
                           snapshots: int = 5, title: str = "") -> Path:
    """Save the figure of one clip: ``X`` (C, T, V) the model's input, ``mask`` (T, V) the observed
    keypoints, ``frames`` the clip's own length (the input may loop it to a fixed length: only the
    first ``frames`` are drawn). ``snapshots`` skeletons at evenly spaced frames, then x and y of the
    wrists against the frame."""
    X = np.asarray(X, dtype=np.float64)
    mask = np.asarray(mask, dtype=bool)
    if X.ndim == 4:  # (C, T, V, 1)
        X = X[..., 0]
    total = X.shape[1] if frames is None else max(1, min(int(frames), X.shape[1]))
    x, y = X[list(channels).index("x"), :total], X[list(channels).index("y"), :total]
    seen = mask[:total]
    picks = np.unique(np.linspace(0, total - 1, min(snapshots, total)).round().astype(int))
    tracked = _tracked(names)
    fig = plt.figure(figsize=(2.0 * len(picks) + 4.2, 2.9), layout="constrained")
    grid = fig.add_gridspec(1, len(picks) + 2)
    for k, t in enumerate(picks):
        ax = fig.add_subplot(grid[0, k])
        for i, j in edges:
            if seen[t, i] and seen[t, j]:
                ax.plot([x[t, i], x[t, j]], [y[t, i], y[t, j]], color="0.35", linewidth=1.2)
        ax.scatter(x[t][seen[t]], y[t][seen[t]], s=6, color="0.15", zorder=3)
        for label, node, colour in tracked:
            if seen[t, node]:
                ax.scatter([x[t, node]], [y[t, node]], s=28, color=colour, zorder=4)
        ax.set_xlim(-1.05, 1.05)
        ax.set_ylim(1.05, -1.05)  # image coordinates: y grows downwards
        ax.set_aspect("equal")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.set_title(f"frame {t + 1}/{total}", fontsize=8)
    ax = fig.add_subplot(grid[0, len(picks):])
    steps = np.arange(1, total + 1)
    for label, node, colour in tracked:
        ax.plot(steps, np.where(seen[:, node], x[:, node], np.nan), color=colour, label=f"{label} x")
        ax.plot(steps, np.where(seen[:, node], y[:, node], np.nan), color=colour, linestyle="--", label=f"{label} y")
    ax.set_xlabel("frame")
    ax.set_ylabel("normalised x, y (y down)")
    ax.set_ylim(-1.05, 1.05)
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    if title:
        fig.suptitle(textwrap.fill(title, 130), fontsize=9)
    path = Path(path)
    with naming_errors(path):  # a full disk names the file
        fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
