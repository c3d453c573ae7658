"""The imitation wing's plots: tracking (reference against simulation per joint), the reward curve of
one run, the evaluation curves of a sweep over seeds (one axis, or one panel per motion with its
named levels; or each seed's own curve and kept policy) and the levels of many baselines side by side
(matplotlib, Agg)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402  (after choosing the backend)
import numpy as np  # noqa: E402

from aslexp.files import naming_errors  # noqa: E402


def plot_tracking(trajectory: dict[str, np.ndarray], joint_names: list[str], path: str | Path,
                  title: str = "") -> Path:
    """Per-joint reference vs simulated position and velocity (thesis figures 5.6 and 5.10); a spherical
    joint as :func:`aslexp.reports.report.per_joint_trajectory` gives it."""
    n = len(joint_names)
    fig, axes = plt.subplots(n, 2, figsize=(10, 1.6 * n), sharex=True, squeeze=False)
    t = trajectory["time"]
    for j, name in enumerate(joint_names):
        for col, (sim_key, ref_key, unit) in enumerate((("q_sim", "q_ref", "rad"), ("qd_sim", "qd_ref", "rad/s"))):
            ax = axes[j, col]
            ax.plot(t, trajectory[ref_key][:, j], color="tab:blue", lw=1, label="reference")
            ax.plot(t, trajectory[sim_key][:, j], color="tab:orange", lw=1, label="simulation")
            ax.set_ylabel(f"{name}\n{unit}", fontsize=7)
            ax.tick_params(labelsize=6)
    axes[0, 0].set_title("position", fontsize=9)
    axes[0, 1].set_title("velocity", fontsize=9)
    axes[0, 0].legend(fontsize=6, loc="upper right")
    axes[-1, 0].set_xlabel("time (s)")
    axes[-1, 1].set_xlabel("time (s)")
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    with naming_errors(path):  # a full disk names the file
        fig.savefig(path, dpi=80)
    plt.close(fig)
    return Path(path)


def plot_reward_curve(history: list[dict[str, Any]], baselines: dict[str, float], path: str | Path,
                      title: str = "") -> Path:
    """Evaluation (and training) reward against environment steps, with the baselines as lines; a
    validated run's validation reward too, and the policy it kept (its last row re-evaluates it)."""
    fig, ax = plt.subplots(figsize=(6, 3.5))
    evaluated, kept = _evaluations(history)
    ev = [(h["step"], h["eval_reward"]) for h in evaluated]
    tr = [(h["step"], h["train_reward"]) for h in history if "train_reward" in h]
    va = [(h["step"], h["validation_reward"]) for h in evaluated if "validation_reward" in h]
    if tr:
        ax.plot(*zip(*tr), color="tab:gray", lw=1, alpha=0.6, label="training (stochastic)")
    if ev:
        ax.plot(*zip(*ev), color="tab:green", marker="o", ms=3, label="evaluation (deterministic)")
    if va:
        ax.plot(*zip(*va), color="tab:purple", marker=".", ms=3, lw=1, label="validation motions (deterministic)")
    if kept is not None:
        ax.axvline(kept["selected_step"], color="tab:purple", ls=":", lw=1)
        ax.plot([kept["selected_step"]], [kept["eval_reward"]], "*", color="tab:red", ms=10,
                label=f"kept: step {kept['selected_step']:,} ({kept['eval_reward']:.3f})")
    for (name, value), style in zip(baselines.items(), ("--", ":", "-.")):
        ax.axhline(value, color="black", ls=style, lw=1, label=f"baseline: {name} ({value:.3f})")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("mean reward per step")
    ax.set_title(title)
    if va:  # the validation line runs along the top: the legend goes below the axes
        fig.set_size_inches(6, 4.6)
        ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18), ncol=2)
    else:
        ax.legend(fontsize=7)
    fig.tight_layout()
    with naming_errors(path):  # a full disk names the file
        fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def _evaluations(history: list[dict[str, Any]]) -> tuple[list[dict[str, Any]], dict[str, Any] | None]:
    """A run's evaluation rows and, for a validated run that ended on its selected policy (its last row
    re-evaluates it), that row apart."""
    evaluated = [h for h in history if "eval_reward" in h]
    if len(evaluated) > 1 and evaluated[-1].get("selected_step") is not None \
            and evaluated[-1]["step"] == evaluated[-2]["step"]:
        return evaluated[:-1], evaluated[-1]
    return evaluated, None


def plot_seed_curves(runs: dict[str, list[dict[str, Any]]], lines: dict[str, float], path: str | Path,
                     title: str) -> Path:
    """Each run's evaluation curve (``runs``: label -> its progress rows) and the policy it kept, on one
    axis, beside named levels (baselines, the ceiling): where seeds part, which a mean hides."""
    fig, ax = plt.subplots(figsize=(7, 4.2))
    for i, (label, history) in enumerate(runs.items()):
        evaluated, kept = _evaluations(history)
        color = f"C{i % 10}"
        ax.plot([h["step"] for h in evaluated], [h["eval_reward"] for h in evaluated], color=color, marker="o",
                ms=2, lw=1.2, label=f"{label}: evaluations")
        if kept is not None:
            ax.plot([kept["selected_step"]], [kept["eval_reward"]], "*", color=color, ms=12, mec="black",
                    label=f"{label}: kept, step {kept['selected_step']:,.0f} ({kept['eval_reward']:.3f})")
    for (name, value), style in zip(lines.items(), ("--", ":", "-.", (0, (1, 3)))):
        ax.axhline(value, color="black", ls=style, lw=1, label=f"{name} ({value:.3f})")
    ax.set_xlabel("environment steps")
    ax.set_ylabel("mean reward per step")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=2)
    fig.tight_layout()
    with naming_errors(path):
        fig.savefig(path, dpi=90)
    plt.close(fig)
    return Path(path)


def seeds_on_common_steps(curves: list[list[tuple[int, float]]]) -> tuple[np.ndarray, np.ndarray]:
    """(steps, values: seeds x steps) of several seeds' (step, evaluation) curves, to average.
    Seeds evaluate on one schedule (every eval_interval steps) plus once where each stopped or
    resumed: the steps every seed evaluated at, not evaluation indices, which would pair a stop's
    evaluation with another seed's scheduled one. Schedules that share under half their points
    (different intervals) fall back to indices, up to the shortest curve."""
    by_step = [dict(c) for c in curves]
    common = sorted(set.intersection(*(set(d) for d in by_step)))
    if len(common) >= min(len(c) for c in curves) / 2:
        return np.asarray(common), np.asarray([[d[s] for s in common] for d in by_step])
    length = min(len(c) for c in curves)
    return (np.asarray([s for s, _ in curves[0][:length]]),
            np.asarray([[v for _, v in c[:length]] for c in curves]))


def plot_curves(runs: dict[str, list[dict[str, Any]]], path: Path, title: str,
                lines: dict[str, dict[str, float]] | None = None) -> Path:
    """Mean ± std evaluation reward per motion over seeds; a run with one evaluation is a point.
    ``lines``: per motion, named horizontal lines (baselines, the thesis' number)."""
    fig, ax = plt.subplots(figsize=(7.5, 4.2))
    styles = ("--", ":", "-.", (0, (1, 3)), (0, (5, 2, 1, 2)))  # the first line (the bar) dashed
    for i, (motion, items) in enumerate(sorted(runs.items())):
        color = f"C{i % 10}"
        curves = [[(p["step"], p["eval_reward"]) for p in m["progress"] if "eval_reward" in p] for m in items]
        curves = [c for c in curves if c]
        if curves:
            steps, values = seeds_on_common_steps(curves)
            length = len(steps)
            mean, std = values.mean(0), values.std(0)
            ax.plot(steps, mean, color=color, marker="o", ms=3 if length > 1 else 6,
                    label=f"{motion} (n={len(curves)})")
            ax.fill_between(steps, mean - std, mean + std, color=color, alpha=0.2)
        for (name, value), style in zip((lines or {}).get(motion, {}).items(), styles):
            ax.axhline(value, color=color, ls=style, lw=1)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("evaluation reward (mean ± std over seeds)")
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    with naming_errors(path):  # a full disk names the file
        fig.savefig(path, dpi=90)
    plt.close(fig)
    return path


def plot_panels(runs: dict[str, list[dict[str, Any]]], lines: dict[str, dict[str, float]], path: Path,
                title: str) -> Path:
    """One panel per motion: the evaluation curve over seeds (mean ± std; a run's step-0 evaluation is
    the untrained level, marked) and every named line (the thesis' number, each baseline) labelled."""
    motions = sorted(runs)
    columns = min(len(motions), 3)
    rows = -(-len(motions) // columns)
    fig, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.2 * rows), squeeze=False)
    styles = ("--", ":", "-.", (0, (1, 3)), (0, (5, 2, 1, 2)), (0, (3, 1, 1, 1, 1, 1)), (0, (6, 2)))
    for ax, motion in zip(axes.flat, motions):
        curves = [[(p["step"], p["eval_reward"]) for p in m["progress"] if "eval_reward" in p] for m in runs[motion]]
        curves = [c for c in curves if c]
        if curves:
            length = min(len(c) for c in curves)
            steps = np.asarray([st for st, _ in curves[0][:length]], dtype=float)
            values = np.asarray([[v for _, v in c[:length]] for c in curves], dtype=float)
            mean, std = values.mean(0), values.std(0)
            ax.plot(steps, mean, color="k", marker="o", ms=3, label=f"PPO evaluations, mean ± std (n={len(curves)} seed{'s' if len(curves) != 1 else ''})")
            ax.fill_between(steps, mean - std, mean + std, color="k", alpha=0.15)
            if steps[0] == 0:
                ax.plot([0], [mean[0]], marker="s", ms=7, color="C3", ls="none", label="untrained policy")
        for k, ((name, value), style) in enumerate(zip(lines.get(motion, {}).items(), styles)):
            ax.axhline(value, color=f"C{k % 10}", ls=style, lw=1.2, label=name)
        ax.set_ylim(0, 1.02)
        ax.set_title(motion, fontsize=9)
        ax.set_xlabel("environment steps", fontsize=8)
        ax.set_ylabel("mean reward per step", fontsize=8)
        ax.tick_params(labelsize=7)
    # One legend for all panels (the same lines in each; their values are in the table), in a spare
    # panel when there is one, else below the panels.
    handles, labels = axes.flat[0].get_legend_handles_labels()
    spare = list(axes.flat)[len(motions):]
    for ax in spare:
        ax.axis("off")
    if spare:
        spare[0].legend(handles, labels, fontsize=7, loc="center")
        fig.suptitle(title, fontsize=9)
        fig.tight_layout()
    else:
        fig.suptitle(title, fontsize=9)
        fig.legend(handles, labels, fontsize=7, loc="lower center", ncol=2)
        fig.tight_layout(rect=(0, 0.06 + 0.035 * (len(labels) // 2), 1, 1))
    with naming_errors(path):
        fig.savefig(path, dpi=100)
    plt.close(fig)
    return path


def plot_levels(lines: dict[str, dict[str, float]], path: Path, title: str) -> Path:
    """One row per motion, one marker per named level (each baseline, the ceiling): differences of a
    few thousandths stay visible, which a panel from 0 to 1 hides."""
    motions = sorted(lines)
    names = list(dict.fromkeys(name for motion in motions for name in lines[motion]))
    values = [v for motion in motions for v in lines[motion].values()]
    fig, ax = plt.subplots(figsize=(9.5, 1.0 + 0.55 * len(motions) + 0.22 * len(names)))
    markers = "osD^v<>p*hX"
    for k, name in enumerate(names):
        ys = [i for i, motion in enumerate(motions) if name in lines[motion]]
        xs = [lines[motions[i]][name] for i in ys]
        ax.plot(xs, ys, ls="none", marker=markers[k % len(markers)], ms=7 if "ceiling" in name else 5,
                color="k" if "ceiling" in name else f"C{k % 10}", label=name, alpha=0.85)
    ax.set_yticks(range(len(motions)), motions)
    ax.invert_yaxis()
    ax.set_xlim(max(0.0, min(values) - 0.01), min(1.0, max(values) + 0.005) + 0.001)
    ax.set_xlabel("mean reward per step", fontsize=8)
    ax.grid(axis="x", alpha=0.3)
    ax.set_title(title, fontsize=9)
    ax.tick_params(labelsize=7)
    ax.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.18 - 0.04 * len(motions)), ncol=2)
    fig.tight_layout()
    with naming_errors(path):
        fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
