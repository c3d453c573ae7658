"""Plots for run folders (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

import math
import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402
from matplotlib.ticker import MaxNLocator  # noqa: E402

from aslexp.files import naming_errors  # noqa: E402


def plot_confusion_matrix(
    matrix: Sequence[Sequence[float]] | np.ndarray,
    label_names: Sequence[str],
    path: str | Path,
    *,
    normalize: bool = True,
    title: str = "Confusion matrix",
) -> Path:
    """Save a labelled confusion matrix (rows = true, columns = predicted). Every cell shows its
    count; with ``normalize`` the colour (and a second line) is the share of the row's true items
    (rows without items stay 0). The title wraps to the figure's width."""
    matrix = np.asarray(matrix, dtype=np.float64)
    shown = matrix
    if normalize:
        totals = matrix.sum(axis=1, keepdims=True)
        shown = np.divide(matrix, totals, out=np.zeros_like(matrix), where=totals > 0)
    size = max(5.0, 0.55 * len(label_names) + 3.0)
    fig, ax = plt.subplots(figsize=(size + 1.0, size), layout="constrained")
    image = ax.imshow(shown, cmap="Blues", vmin=0.0, vmax=1.0 if normalize else None)
    colorbar = fig.colorbar(image, ax=ax, fraction=0.046, pad=0.04)
    colorbar.set_label("share of the true class" if normalize else "count")
    ticks = np.arange(len(label_names))
    ax.set_xticks(ticks, labels=label_names, rotation=45, ha="right", fontsize=8)
    ax.set_yticks(ticks, labels=[f"{name} (n={int(n)})" for name, n in zip(label_names, matrix.sum(axis=1))], fontsize=8)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    characters = max(30, int(9 * (size + 1.0)))  # about 9 characters per inch at 10 pt
    ax.set_title(textwrap.fill(title, characters), fontsize=10)
    if len(label_names) <= 25:
        threshold = 0.5 * (shown.max() if shown.size and shown.max() > 0 else 1.0)
        font = 8 if len(label_names) <= 10 else 6
        for i in range(shown.shape[0]):
            for j in range(shown.shape[1]):
                text = f"{int(matrix[i, j])}\n{shown[i, j]:.2f}" if normalize else f"{int(matrix[i, j])}"
                ax.text(j, i, text, ha="center", va="center", fontsize=font,
                        color="white" if shown[i, j] > threshold else "black")  # fmt: skip
    path = Path(path)
    with naming_errors(path):  # a full disk names the file
        fig.savefig(path, dpi=120, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path


NO_EPOCHS_NOTE = ("fitted once (no epochs): no curve over training time.\n"
                  "The learning curve over data (score against training clips) is drawn when the run has one.")  # fmt: skip


def plot_learning_curves(
    histories: Mapping[str, Sequence[Mapping[str, float]]],
    path: str | Path,
    *,
    title: str = "Learning curves",
    data_curve: Sequence[Mapping[str, float]] | None = None,
    metric: str = "mcc",
) -> Path:
    """Save learning curves.

    Models trained over epochs (``histories``: run label -> per-epoch dicts): train loss (left)
    and validation MCC, accuracy and, when it is another metric, the selection metric (right), one
    colour per run. Models fitted once (one record per run, no loss) have no curve over time;
    with ``data_curve`` (dicts of train_size, train_score, val_score) they get the learning curve
    over data instead: the selection metric on the training subset and on validation against the
    number of training clips; without one the figure says why there is no curve.
    """
    epochs_trained = any(len(h) > 1 or any(math.isfinite(r.get("train_loss", math.nan)) for r in h)
                         for h in histories.values())  # fmt: skip
    if not epochs_trained:
        fig, ax = plt.subplots(figsize=(7, 4.5), layout="constrained")
        if data_curve:
            sizes = [row["train_size"] for row in data_curve]
            ax.plot(sizes, [row["train_score"] for row in data_curve], "o-", label=f"training subset {metric}")
            ax.plot(sizes, [row["val_score"] for row in data_curve], "s-", label=f"validation {metric}")
            ax.set_xlabel("training clips (stratified subsets of the training split)")
            ax.set_ylabel(metric)
            ax.grid(alpha=0.3)
            ax.legend(fontsize=8)
            ax.set_title(textwrap.fill(f"{title}: learning curve over data (fitted once, no epochs)", 70), fontsize=10)
        else:
            ax.axis("off")
            ax.text(0.5, 0.5, NO_EPOCHS_NOTE, ha="center", va="center", fontsize=10, wrap=True)
            ax.set_title(textwrap.fill(title, 70), fontsize=10)
        path = Path(path)
        with naming_errors(path):  # a full disk names the file
            fig.savefig(path, dpi=120, bbox_inches="tight", pad_inches=0.15)
        plt.close(fig)
        return path

    fig, (loss_ax, val_ax) = plt.subplots(1, 2, figsize=(11, 4.5), layout="constrained")
    extra = f"val_{metric}" if metric not in ("mcc", "accuracy") else None
    for index, (label, history) in enumerate(histories.items()):
        color = f"C{index % 10}"
        epochs = [row["epoch"] for row in history]
        marker = "." if len(epochs) < 3 else None
        loss_ax.plot(epochs, [row.get("train_loss", math.nan) for row in history], color=color, marker=marker, label=label)
        val_ax.plot(epochs, [row.get("val_mcc", math.nan) for row in history], color=color, marker=marker, label=f"{label} MCC")
        val_ax.plot(epochs, [row.get("val_accuracy", math.nan) for row in history], color=color, linestyle="--",
                    label=f"{label} accuracy")  # fmt: skip
        if extra:
            val_ax.plot(epochs, [row.get(extra, math.nan) for row in history], color=color, linestyle=":",
                        label=f"{label} {metric}")  # fmt: skip
    loss_ax.set_xlabel("epoch")
    loss_ax.set_ylabel("train loss")
    val_ax.set_xlabel("epoch")
    val_ax.set_ylabel("validation MCC (solid) / accuracy (dashed)" + (f" / {metric} (dotted)" if extra else ""))
    for ax in (loss_ax, val_ax):
        ax.xaxis.set_major_locator(MaxNLocator(integer=True))
        ax.grid(alpha=0.3)
        if histories:
            ax.legend(fontsize=7)
    fig.suptitle(textwrap.fill(title, 110), fontsize=11)
    path = Path(path)
    with naming_errors(path):  # a full disk names the file
        fig.savefig(path, dpi=120, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path
