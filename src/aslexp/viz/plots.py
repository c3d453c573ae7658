"""Plots for run folders (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402


def plot_confusion_matrix(
    matrix: Sequence[Sequence[float]] | np.ndarray,
    label_names: Sequence[str],
    path: str | Path,
    *,
    normalize: bool = True,
    title: str = "Confusion matrix",
) -> Path:
    """Save a labelled confusion matrix (rows = true, columns = predicted); with ``normalize``
    every row is divided by its total (rows without items stay 0)."""
    matrix = np.asarray(matrix, dtype=np.float64)
    shown = matrix
    if normalize:
        totals = matrix.sum(axis=1, keepdims=True)
        shown = np.divide(matrix, totals, out=np.zeros_like(matrix), where=totals > 0)
    size = max(4.0, 0.45 * len(label_names) + 2.5)
    fig, ax = plt.subplots(figsize=(size, size))
    image = ax.imshow(shown, cmap="Blues", vmin=0.0, vmax=1.0 if normalize else None)
    fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04)
    ticks = np.arange(len(label_names))
    ax.set_xticks(ticks, labels=label_names, rotation=60, ha="right", fontsize=8)
    ax.set_yticks(ticks, labels=label_names, fontsize=8)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title)
    if len(label_names) <= 20:
        threshold = 0.5 * (shown.max() if shown.size else 1.0)
        for i in range(shown.shape[0]):
            for j in range(shown.shape[1]):
                text = f"{shown[i, j]:.2f}" if normalize else f"{int(shown[i, j])}"
                ax.text(j, i, text, ha="center", va="center", fontsize=7, color="white" if shown[i, j] > threshold else "black")
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path


def plot_learning_curves(histories: Mapping[str, Sequence[Mapping[str, float]]], path: str | Path, *, title: str = "Learning curves") -> Path:
    """Save train loss (left) and validation MCC / accuracy (right) per epoch, one line per run
    (``histories``: run label -> list of per-epoch dicts with train_loss, val_mcc, val_accuracy)."""
    fig, (loss_ax, val_ax) = plt.subplots(1, 2, figsize=(10, 4))
    for index, (label, history) in enumerate(histories.items()):
        color = f"C{index % 10}"
        epochs = [row["epoch"] for row in history]
        losses = [row.get("train_loss", math.nan) for row in history]
        loss_ax.plot(epochs, losses, color=color, marker="." if len(epochs) < 3 else None, label=label)
        val_ax.plot(epochs, [row.get("val_mcc", math.nan) for row in history], color=color, marker="." if len(epochs) < 3 else None, label=f"{label} MCC")
        val_ax.plot(epochs, [row.get("val_accuracy", math.nan) for row in history], color=color, linestyle="--", label=f"{label} accuracy")
    loss_ax.set_xlabel("epoch")
    loss_ax.set_ylabel("train loss")
    val_ax.set_xlabel("epoch")
    val_ax.set_ylabel("validation MCC (solid) / accuracy (dashed)")
    for ax in (loss_ax, val_ax):
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
        if histories:
            ax.legend(fontsize=7)
    fig.suptitle(title)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
