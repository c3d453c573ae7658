"""The seen-gloss plot: top-k accuracy per method (mean over splits, 95% t
interval) and the paired per-split top-1 of the gloss network without and with the auxiliary
phonology heads (matplotlib, Agg)."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402

_COLOR = {"chance": "0.6", "majority": "0.35", "simple": "tab:orange", "gloss": "tab:blue",
          "gloss+phonology": "tab:green"}


def plot_top_k_by_split(per_split: Sequence[Mapping[str, Any]], table: Mapping[str, Mapping[str, Mapping[str, float]]],
                        labels: Mapping[str, str], top_k: Sequence[int], path: str | Path, *, title: str) -> Path:
    """Left: per method, top-k (%) as bars with the 95% t interval; right: per split, top-1 (%) of
    the two networks joined by a line (the paired difference), the simple baseline as a mark."""
    path = Path(path)
    methods = list(labels)
    fig, (left, right) = plt.subplots(1, 2, figsize=(12, 4.6), gridspec_kw={"width_ratios": [1.25, 1]})
    width = 0.8 / max(1, len(methods))
    x = np.arange(len(top_k))
    for i, method in enumerate(methods):
        cells = [table[method][f"top{k}"] for k in top_k]
        means = np.array([100 * c["mean"] for c in cells])
        low = np.array([100 * c["low"] if np.isfinite(c["low"]) else np.nan for c in cells])
        high = np.array([100 * c["high"] if np.isfinite(c["high"]) else np.nan for c in cells])
        errors = np.vstack([means - np.clip(low, 0, 100), np.clip(high, 0, 100) - means])
        left.bar(x + (i - (len(methods) - 1) / 2) * width, means, width, color=_COLOR.get(method, "tab:gray"),
                 yerr=None if np.isnan(errors).all() else errors, capsize=3,
                 label=textwrap.shorten(labels[method], 48, placeholder="..."))
    left.set_xticks(x, [f"top-{k}" for k in top_k])
    left.set_ylabel("test accuracy (%)")
    left.set_title("mean over splits, 95% t interval", fontsize=10)
    left.set_ylim(0, 100)
    left.legend(fontsize=8, loc="upper left")
    left.grid(axis="y", alpha=0.3)
    splits = np.arange(1, len(per_split) + 1)
    without = np.array([100 * s["metrics"]["gloss"]["top1"] for s in per_split])
    with_aux = np.array([100 * s["metrics"]["gloss+phonology"]["top1"] for s in per_split])
    for xi, a, b in zip(splits, without, with_aux):
        right.plot([xi - 0.15, xi + 0.15], [a, b], color="0.5", linewidth=1)
    right.scatter(splits - 0.15, without, color=_COLOR["gloss"], label=labels["gloss"], zorder=3)
    right.scatter(splits + 0.15, with_aux, color=_COLOR["gloss+phonology"], label=labels["gloss+phonology"], zorder=3)
    if "simple" in labels:
        simple = np.array([100 * s["metrics"]["simple"]["top1"] for s in per_split])
        right.scatter(splits, simple, marker="x", color=_COLOR["simple"], label=labels["simple"], zorder=3)
    chance = [100 * s["metrics"]["chance"]["top1"] for s in per_split]
    right.plot(splits, chance, linestyle=":", color=_COLOR["chance"], label="chance")
    shown = [v for m in ("gloss", "gloss+phonology", "simple") if m in labels
             for v in (100 * s["metrics"][m]["top1"] for s in per_split)]
    right.set_ylim(0, 1.45 * max(shown + [1.0]))  # room above the points for the legend
    right.set_xticks(splits)
    right.set_xlabel("split")
    right.set_ylabel("top-1 (%)")
    right.set_title("per split, paired (same clips, same seed)", fontsize=10)
    right.legend(fontsize=8, ncol=2, loc="upper center")
    right.grid(alpha=0.3)
    fig.suptitle(textwrap.fill(title, 110), fontsize=11)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
