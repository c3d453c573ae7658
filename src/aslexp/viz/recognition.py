"""The plots of ``aslexp report RUN_OR_SWEEP_DIR``: the model chosen by validation against the chance
baseline, the paired differences to the strongest simple baseline (a forest plot) and the validation
curves against the feature baselines (matplotlib, Agg). The recognition wing passes its orders."""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402


def _finite(value: Any, default: float) -> float:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return default
    return value if math.isfinite(value) else default


def interval_label(units: list[int]) -> str:
    """What the whiskers of bars over ``units`` (splits or seeds per bar) show: an interval
    needs two units or more."""
    spread = [u >= 2 for u in units]
    return "95% CI" if all(spread) else "95% CI where 2+ units" if any(spread) else "one unit: no interval"


def plot_best_vs_baseline(rows: list[dict[str, Any]], path: Path) -> None:
    """Per split, two panels (test MCC, balanced accuracy): the model chosen by validation per property
    with its interval, beside the chance baseline."""
    splits = sorted({r["split"] for r in rows})
    fig, axes = plt.subplots(len(splits), 2, figsize=(12, 3.4 * len(splits)), squeeze=False, layout="constrained")
    for i, split in enumerate(splits):
        sub = [r for r in rows if r["split"] == split]
        x = np.arange(len(sub))
        for j, (metric, label) in enumerate((("mcc", "test MCC"), ("balanced_accuracy", "test balanced accuracy"))):
            ax = axes[i, j]
            best = np.array([_finite(r[f"test_{metric}"], 0.0) for r in sub])
            low = np.array([_finite(r[f"test_{metric}_low"], b) for r, b in zip(sub, best)])
            high = np.array([_finite(r[f"test_{metric}_high"], b) for r, b in zip(sub, best)])
            base = [_finite(r[f"baseline_{metric}"], 0.0) for r in sub]
            # An interval needs two units (splits or seeds) or more: one run gets a bar, no whisker.
            spread = np.array([(r.get("units") or 0) >= 2 for r in sub])
            yerr = [np.where(spread, best - low, 0.0), np.where(spread, high - best, 0.0)]
            what = interval_label([r.get("units") or 0 for r in sub])
            ax.bar(x - 0.2, best, 0.4, yerr=yerr if spread.any() else None, capsize=3,
                   label=f"best model (by validation), {what}")
            ax.bar(x + 0.2, base, 0.4, label="chance baseline", color="0.6")
            ax.set_xticks(x, [f"{r['property']}\n({r['model']})" for r in sub], fontsize=7)
            ax.set_title(f"{split} split: {label}")
            ax.axhline(0, color="k", lw=0.5)
            if i == 0 and j == 0:
                ax.legend(fontsize=7)
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)


def plot_comparisons(rows: list[dict[str, Any]], path: Path, order: Callable[[tuple[str, str]], Any] | None = None
                     ) -> bool:
    """Per (split, property) with a learned model paired against the strongest simple baseline: each
    model's mean difference in test MCC with its 95% t interval (a forest plot), the panels sorted by
    ``order`` (a (split, property) key; None: as sorted). False if none."""
    panels: dict[tuple[str, str], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        if r.get("vs_simple"):
            panels[(r["split"], r["property"])].append(r)
    if not panels:
        return False
    keys = sorted(panels, key=order)
    columns = min(2, len(keys))
    lines = (len(keys) + columns - 1) // columns
    fig, axes = plt.subplots(lines, columns, figsize=(6.2 * columns, 0.5 + 0.32 * max(len(v) for v in panels.values())
                                                          * lines + 1.1 * lines), squeeze=False, layout="constrained")
    for ax, key in zip(axes.flat, keys):
        members = sorted(panels[key], key=lambda r: r["vs_simple"]["diff"]["mean"])
        for y, r in enumerate(members):
            diff = r["vs_simple"]["diff"]
            low, high = _finite(diff["low"], diff["mean"]), _finite(diff["high"], diff["mean"])
            color = {1: "tab:green", -1: "tab:red", 0: "0.3"}[r["vs_simple"]["resolved"]]
            ax.errorbar(diff["mean"], y, xerr=[[diff["mean"] - low], [high - diff["mean"]]], fmt="o", color=color, capsize=3)
        ax.set_yticks(range(len(members)), [f"{r['model']} (n={r['vs_simple']['diff']['n']})" for r in members], fontsize=8)
        ax.set_ylim(-0.6, len(members) - 0.4)
        ax.axvline(0, color="k", lw=0.8)
        reference = members[0]["strongest_simple"]
        ax.set_title(f"{key[1]}, {key[0]} split: minus {reference}", fontsize=9)
        ax.set_xlabel(f"test MCC minus {reference} (same splits), 95% CI", fontsize=8)
        ax.grid(axis="x", alpha=0.3)
    for ax in list(axes.flat)[len(keys):]:
        ax.axis("off")
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return True


def plot_validation_curves(members: list[dict[str, Any]], path: Path,
                           order: Callable[[tuple[str, str]], Any] | None = None,
                           model_order: Sequence[str] = (), baselines: Sequence[str] = ()) -> bool:
    """Per (split, property) with a model trained over epochs: its validation MCC per epoch, the mean
    over the validation runs (splits x seeds) still training at that epoch, drawn while at least half
    are; dashed, the validation MCC of each feature baseline of ``baselines`` (mean over its runs,
    fitted once). Panels sorted by ``order`` (a (split, property) key), models in the order and the
    colours of ``model_order``. False when no run was trained over epochs."""
    panels: dict[tuple[str, str], dict[str, dict[str, Any]]] = defaultdict(dict)
    for run in members:
        panels[(run["split"], run["property"])][run["classifier"]] = run["metrics"]

    def trained(metrics: dict[str, Any]) -> bool:
        return any(len(h) > 1 for h in metrics.get("history", {}).values())

    keys = [k for k in panels if any(trained(m) for m in panels[k].values())]
    if not keys:
        return False
    keys.sort(key=order)
    columns = min(2, len(keys))
    lines = (len(keys) + columns - 1) // columns
    fig, axes = plt.subplots(lines, columns, figsize=(6.4 * columns, 3.6 * lines), squeeze=False, layout="constrained")
    for ax, key in zip(axes.flat, keys):
        models = sorted(panels[key], key=lambda m: model_order.index(m) if m in model_order else 99)
        for index, model in enumerate(models):
            metrics = panels[key][model]
            # One colour per model in every panel (its place in model_order).
            color = f"C{(model_order.index(model) if model in model_order else index) % 10}"
            if trained(metrics):
                curves = [[_finite(r.get("val_mcc"), math.nan) for r in h] for h in metrics["history"].values()]
                length = max(len(c) for c in curves)
                grid = np.full((len(curves), length), np.nan)
                for row, curve in enumerate(curves):
                    grid[row, :len(curve)] = curve
                running = np.sum(np.isfinite(grid), axis=0)
                shown = running >= max(1, len(curves) / 2)
                with np.errstate(all="ignore"):
                    mean = np.where(shown, np.nanmean(np.where(np.isfinite(grid), grid, np.nan), axis=0), np.nan)
                ax.plot(np.arange(1, length + 1), mean, color=color, label=f"{model} ({len(curves)} runs)")
            elif model in baselines:
                ax.axhline(_finite(metrics.get("val_mcc"), math.nan), color=color, ls="--", lw=1.2,
                           label=f"{model} (fitted once)")  # fmt: skip
        ax.set_title(f"{key[1]}, {key[0]} split", fontsize=9)
        ax.set_xlabel("epoch", fontsize=8)
        ax.set_ylabel("validation MCC (mean over runs)", fontsize=8)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=6, ncol=2)
    for ax in list(axes.flat)[len(keys):]:
        ax.axis("off")
    fig.suptitle("Validation MCC per epoch (mean over the runs still training, shown while at least half are) "
                 "against the feature baselines' validation MCC (dashed)", fontsize=9)  # fmt: skip
    fig.savefig(path, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return True
