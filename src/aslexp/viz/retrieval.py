"""The lexicon-retrieval plot: recall@k against k (log scale) per method (matplotlib, Agg)."""

from __future__ import annotations

import textwrap
from collections.abc import Mapping, Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402

from aslexp.files import naming_errors  # noqa: E402

# One look per method: the references dashed, what is learnt solid.
_STYLE = {
    "chance": {"color": "0.55", "linestyle": ":"},
    "prior": {"color": "tab:orange", "linestyle": "--"},
    "phonology": {"color": "tab:blue", "linestyle": "-"},
    "phonology+prior": {"color": "tab:green", "linestyle": "-", "linewidth": 2.2},
    "oracle": {"color": "tab:purple", "linestyle": "-."},
    "oracle+prior": {"color": "tab:red", "linestyle": "-."},
}


def plot_recall_curves(curves: Mapping[str, Sequence[float]], labels: Mapping[str, str], path: str | Path, *,
                       title: str = "Lexicon retrieval", marks: Sequence[int] = (10, 50)) -> Path:
    """Save recall@k (in %) against k for every method of ``curves`` (``curves["k"]``: the k values;
    ``curves[method]``: recall at each), with thin vertical lines at ``marks``."""
    ks = np.asarray(curves["k"], dtype=np.float64)
    fig, ax = plt.subplots(figsize=(9.0, 4.8), layout="constrained")
    for method, label in labels.items():
        values = curves.get(method)
        if values is None or len(values) != len(ks):
            continue
        ax.plot(ks, 100 * np.asarray(values, dtype=np.float64), label=label, **_STYLE.get(method, {}))
    shown = [m for m in marks if ks.size and ks.min() <= m <= ks.max()]
    for mark in shown:
        ax.axvline(mark, color="0.75", linewidth=0.8, zorder=0)
    ax.set_xscale("log")
    ax.set_xlim(1, ks.max() if ks.size else 1)
    ax.set_ylim(0, 100)
    lines = f"; grey lines at k = {', '.join(map(str, shown))}" if shown else ""
    ax.set_xlabel(f"k (rank cut-off, log scale){lines}")
    ax.set_ylabel("recall@k (%): true sign in the top k")
    ax.grid(True, which="major", alpha=0.3)
    ax.legend(fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0), borderaxespad=0.0)
    ax.set_title(textwrap.fill(title, 90), fontsize=9)
    path = Path(path)
    with naming_errors(path):  # a full disk names the file
        fig.savefig(path, dpi=120, bbox_inches="tight", pad_inches=0.15)
    plt.close(fig)
    return path
