"""The signer-against-the-person figure (``aslexp signing``'s signing.png): the keypoint error's
distribution per stage, each property's agreement with ASL-LEX per reading (the person's clip
first), and the lexicon rank's distribution per reading."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402

COLOURS = {"source": "0.35", "reference": "tab:blue", "controller": "tab:orange", "policy": "tab:green"}


def _colour(name: str) -> str:
    return COLOURS.get(name, "tab:purple")


def plot_signing_table(errors: Mapping[str, np.ndarray], ranks: Mapping[str, Sequence[float]],
                       table: Mapping[str, Any], properties: Sequence[str], path: str | Path,
                       handshapes: Mapping[str, Mapping[str, float]] | None = None) -> Path:  # fmt: skip
    """Save the figure of :func:`aslexp.signing.table.build_table`'s ``table``: ``errors`` (stage ->
    per-clip body keypoint error), ``ranks`` (reading -> per-clip lexicon rank of the true gloss)
    and, when given, ``handshapes`` (clip -> stage -> handshape error): a last panel of bars per clip."""
    stages = list(table["stages"])
    read = table.get("read_back") or {}
    panels = (3 if read else 1) + bool(handshapes)
    fig, axes = plt.subplots(1, panels, figsize=(5.2 * panels, 4.2), squeeze=False)
    if handshapes:
        _handshape_panel(axes[0, -1], handshapes)
    ax = axes[0, 0]
    data = [np.asarray(errors[s], dtype=float) for s in stages]
    data = [d[np.isfinite(d)] for d in data]
    parts = ax.violinplot([d if len(d) else [np.nan] for d in data], showmedians=True, showextrema=False)
    for body, stage in zip(parts["bodies"], stages):
        body.set_facecolor(_colour(stage))
        body.set_alpha(0.45)
    for i, d in enumerate(data, 1):
        ax.scatter(np.full(len(d), i) + np.random.default_rng(i).uniform(-0.08, 0.08, len(d)), d, s=5,
                   color=_colour(stages[i - 1]), alpha=0.6)
    ax.set_xticks(range(1, len(stages) + 1), [f"{s}\n(median {np.median(d):.3f})" if len(d) else s
                                              for s, d in zip(stages, data)])
    ax.set_ylabel("body keypoint error after DTW (shoulder widths)")
    ax.set_title(f"Keypoint error to the person ({table['clips']} clips)")
    ax.grid(axis="y", alpha=0.3)
    if read:
        names = [n for n in ("source", *stages) if n in read]
        ax = axes[0, 1]
        width = 0.8 / len(names)
        for k, name in enumerate(names):
            cells = [read[name]["properties"][p]["agreement"] for p in properties]
            values = np.array([100 * c["value"] for c in cells])
            errors = np.array([[100 * (c["value"] - c["low"]), 100 * (c["high"] - c["value"])] for c in cells]).T
            ax.bar(np.arange(len(properties)) + (k - (len(names) - 1) / 2) * width, values, width, yerr=errors,
                   color=_colour(name), label=name, capsize=2)
        majority = [100 * read[names[0]]["properties"][p]["majority"]["value"] for p in properties]
        ax.scatter(np.arange(len(properties)), majority, marker="_", s=400, color="k", label="majority value", zorder=3)
        ax.set_xticks(range(len(properties)), [p.replace("_", " ") for p in properties])
        ax.set_ylabel("agreement with ASL-LEX (%, 95% CI over glosses)")
        ax.set_ylim(0, 100)
        ax.set_title("Phonology read back")
        ax.legend(fontsize=8)
        ax.grid(axis="y", alpha=0.3)
        ax = axes[0, 2]
        shown = [list(ranks.get(n, [])) for n in names]
        box = ax.boxplot(shown, patch_artist=True, showfliers=True)
        for patch, name in zip(box["boxes"], names):
            patch.set_facecolor(_colour(name))
            patch.set_alpha(0.6)
        ax.set_xticks(range(1, len(names) + 1), [f"{n}\n(median {np.median(r):.0f})" if r else n
                                                 for n, r in zip(names, shown)])
        ax.set_yscale("log")
        ax.set_ylabel(f"rank of the true gloss among {read[names[0]]['lexicon_size']} entries (log)")
        ax.set_title("Lexicon lookup")
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


HANDSHAPE_COLOURS = ("tab:blue", "tab:orange", "tab:red", "0.6")


def _handshape_panel(ax, handshapes: Mapping[str, Mapping[str, float]]) -> None:
    """Per clip a bar per stage: the handshape error in hand sizes (lower is closer to the person)."""
    clips = list(handshapes)
    names = list(dict.fromkeys(n for c in clips for n in handshapes[c]))
    width = 0.8 / max(len(names), 1)
    for k, name in enumerate(names):
        values = [handshapes[c].get(name, np.nan) for c in clips]
        ax.bar(np.arange(len(clips)) + (k - (len(names) - 1) / 2) * width, values, width,
               color=HANDSHAPE_COLOURS[k % len(HANDSHAPE_COLOURS)], label=name)
    ax.set_xticks(range(len(clips)), clips, fontsize=8)
    ax.set_ylabel("handshape error after DTW (hand sizes)")
    ax.set_title("The signing hand's shape, per clip")
    ax.legend(fontsize=7)
    ax.grid(axis="y", alpha=0.3)


def plot_fold_differences(folds: Sequence[Mapping[str, Any]], path: str | Path) -> Path:
    """Save the leave-glosses-out figure: per held-out fold (``label``; ``differences``: per clip the
    policy's reward minus its controller's; ``value``, ``low``, ``high``: their mean and interval) a
    row of the clips' differences, the mean with its interval, and the line of no difference."""
    fig, ax = plt.subplots(figsize=(7.5, 0.7 + 0.75 * len(folds)))
    rng = np.random.default_rng(0)  # the vertical jitter of the dots only
    for row, fold in enumerate(folds):
        values = np.asarray(fold["differences"], dtype=float)
        ax.scatter(values, row + rng.uniform(-0.18, 0.18, len(values)), s=10, alpha=0.5, color=_colour("policy"),
                   label="a clip" if row == 0 else None)
        ax.errorbar(fold["value"], row, xerr=[[fold["value"] - fold["low"]], [fold["high"] - fold["value"]]], fmt="D",
                    color="black", capsize=4, label="mean, 95% interval over glosses" if row == 0 else None)
    ax.axvline(0.0, color=_colour("controller"), linestyle="--", label="the controller alone")
    ax.set_yticks(range(len(folds)), [f["label"] for f in folds])
    ax.invert_yaxis()
    ax.set_xlabel("per clip: the pool policy's reward minus its controller's (one pass)")
    ax.legend(loc="lower left", bbox_to_anchor=(0.0, 1.0), ncol=3, fontsize=8, frameon=False)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")  # long fold labels: nothing cut off
    plt.close(fig)
    return path
