"""``aslexp retarget``'s retarget.png: per video, the retargeted finger angles of the hand MediaPipe saw
most, over time, the frames where the person holds the handshape shaded: a held handshape should be
flat lines there."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402


def plot_finger_angles(panels: list[dict[str, Any]], path: str | Path) -> Path | None:
    """Save the figure; each panel: ``title``, ``angles`` (T, J) radians, ``dt`` seconds a frame and
    ``held`` [[start, stop), ...] frames. None when there is no panel."""
    if not panels:
        return None
    fig, axes = plt.subplots(len(panels), 1, figsize=(9, 1.9 * len(panels) + 0.4), squeeze=False)
    for ax, panel in zip(axes[:, 0], panels):
        angles = np.asarray(panel["angles"], dtype=float)
        seconds = np.arange(len(angles)) * float(panel["dt"])
        for a, b in panel.get("held", []):
            ax.axvspan(seconds[a], seconds[min(b, len(seconds)) - 1], color="0.88", zorder=0)
        ax.plot(seconds, angles, lw=0.8)
        ax.set_title(panel["title"], fontsize=8)
        ax.set_ylabel("angle (rad)", fontsize=8)
        ax.tick_params(labelsize=7)
    axes[-1, 0].set_xlabel("time (s); shaded: the person holds the handshape", fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return Path(path)
