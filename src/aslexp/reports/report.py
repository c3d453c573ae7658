"""Tables of imitation runs: reading a sweep's runs and their configs, the letter summaries (their
curves drawn by :mod:`aslexp.viz.imitation`), a spherical joint's trajectory as one column per joint.

Reads and writes plain files only (run folders: ``progress.csv``, ``metrics.json``,
``.hydra/config.yaml``), so it works the same after a run, after a sweep, or from a notebook.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.quaternion import IDENTITY as IDENTITY_WXYZ, angle as quat_angle


def per_joint_trajectory(trajectory: dict[str, np.ndarray], layout) -> dict[str, np.ndarray]:
    """One column per joint for :func:`aslexp.viz.imitation.plot_tracking`: a revolute joint's angle
    and speed, a spherical joint's rotation angle from the identity, 2 acos|w| (rad), and angular
    speed |w|."""
    out = dict(trajectory)
    for q_key, v_key in (("q_sim", "qd_sim"), ("q_ref", "qd_ref")):
        q, qd = np.asarray(trajectory[q_key]), np.asarray(trajectory[v_key])
        pos, vel, offset, voffset = [], [], 0, 0
        for joint in layout.joints:
            if joint.dof == 1:
                pos.append(q[:, offset])
                vel.append(qd[:, voffset])
                offset, voffset = offset + 1, voffset + 1
            else:
                pos.append(quat_angle(q[:, offset:offset + 4], IDENTITY_WXYZ))
                vel.append(np.linalg.norm(qd[:, voffset:voffset + 3], axis=1))
                offset, voffset = offset + 4, voffset + 3
        out[q_key], out[v_key] = np.stack(pos, axis=1), np.stack(vel, axis=1)
    return out


def read_progress(run_dir: str | Path) -> list[dict[str, float]]:
    path = Path(run_dir) / "progress.csv"
    if not path.is_file():
        return []
    with open(path, newline="", encoding="utf-8") as fh:
        return [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(fh)]


def first_above(progress: list[dict[str, Any]], value: float) -> tuple[int, float] | None:
    """(steps, seconds) of the first evaluation whose reward is above ``value``, or None."""
    for row in progress:
        if "eval_reward" in row and row["eval_reward"] > value:
            return int(row["step"]), float(row["seconds"])
    return None


# The hand's time-to-imitate goal: every letter above 0.95 within 30 minutes and 2M steps.
LETTERS_TARGET = 0.95


def mean_std(values) -> str:
    """``mean ± std`` (population std over seeds) with 3 decimals, or ``-`` for no values."""
    values = np.asarray([v for v in values if v is not None and math.isfinite(v)], dtype=float)
    if not len(values):
        return "-"
    return f"{values.mean():.3f} ± {values.std():.3f}" if len(values) > 1 else f"{values[0]:.3f}"


def run_config(run_dir: str | Path) -> dict[str, Any]:
    """A run's composed config (``.hydra/config.yaml``), interpolations resolved. ``${hydra:...}``
    values (e.g. ``resume=SWEEP/${hydra:job.num}``) are the run's own, from its ``.hydra/hydra.yaml``:
    outside that run, Hydra's resolver has nothing (or another job) to answer from."""
    from omegaconf import OmegaConf

    path = Path(run_dir) / ".hydra" / "config.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"{run_dir}: no .hydra/config.yaml (needed to rebuild the run's environment)")
    config = OmegaConf.to_container(OmegaConf.load(path), resolve=False)
    hydra_path = path.parent / "hydra.yaml"
    if hydra_path.is_file():
        own = OmegaConf.load(hydra_path).hydra

        def substitute(value):
            if isinstance(value, dict):
                return {k: substitute(v) for k, v in value.items()}
            if isinstance(value, list):
                return [substitute(v) for v in value]
            if isinstance(value, str) and "${hydra:" in value:
                return re.sub(r"\$\{hydra:([^}]+)\}", lambda m: str(OmegaConf.select(own, m.group(1).strip())), value)
            return value

        config = substitute(config)
    return OmegaConf.to_container(OmegaConf.create(config), resolve=True)


def ended_early(row: dict[str, Any]) -> str:
    """How a baseline row's episodes ended early, for a mark beside its number: "diverged", "fell",
    both, or "" (the row's ``diverged`` count and ``fell`` flag)."""
    return ", ".join(end for end in ("diverged", "fell") if row.get(end))


def best_so_far(trained: list[dict[str, Any]]) -> str:
    """The best-so-far column over seeds; a re-evaluated run (``stopped: evaluated``) has one
    evaluation under its protocol, so there is no best-so-far to show."""
    if any(m.get("stopped") == "evaluated" for m in trained):
        return "n/a (re-evaluated)"
    return mean_std(m.get("best_eval") for m in trained)


def read_runs(sweep_dir: str | Path) -> dict[str, list[dict[str, Any]]]:
    """Every imitation run (metrics.json with a motion) under ``sweep_dir``, by motion, with its
    progress rows and, if present, its composed config (``.hydra/config.yaml``)."""
    runs: dict[str, list[dict[str, Any]]] = defaultdict(list)
    for metrics_path in sorted(Path(sweep_dir).glob("**/metrics.json")):
        metrics = json.loads(metrics_path.read_text())
        if "motion" not in metrics:
            continue
        metrics["progress"] = read_progress(metrics_path.parent)
        if metrics.get("stopped") == "evaluated" and not metrics["progress"]:
            # A re-evaluated checkpoint: its one evaluation under this protocol is its curve (a point).
            metrics["progress"] = [{"step": float(metrics["steps"]), "seconds": float(metrics.get("seconds") or 0.0),
                                    "eval_reward": float(metrics["last_eval"])}]
        metrics["run_dir"] = str(metrics_path.parent)
        runs[str(metrics["motion"])].append(metrics)
    if not runs:
        raise FileNotFoundError(f"no imitation runs (metrics.json with a motion) under {sweep_dir}")
    return runs


def learned(metrics: dict[str, Any]) -> bool:
    """True for a trained policy's run: one that trained, or re-evaluated a trained checkpoint
    (``stopped: evaluated``); a run with ppo.total_steps=0 only measured its baselines."""
    return metrics.get("steps", 0) > 0


def summarize_letters(sweep_dir: str | Path, out_dir: str | Path | None = None,
                      targets: float | dict[str, float] | str | None = LETTERS_TARGET,
                      stem: str = "letters", lines: tuple[str, ...] | None = None) -> dict[str, Any]:
    """Per motion over seeds: the LAST evaluation (mean ± std; the headline), the best-so-far one
    (secondary: a maximum over evaluations is biased upward), every no-learning baseline the runs
    measured, and how many seeds end above EVERY one of them; curves in ``<stem>_curves.png``,
    the table in ``<stem>_table.{md,csv}``. ``targets`` (one value, one per motion, or the name of a
    baseline: each motion's own) adds how many seeds reached it and the median steps and minutes
    until they did. ``lines``: the baselines drawn on the curves (default: the first three)."""
    runs = read_runs(sweep_dir)
    out_dir = Path(out_dir or sweep_dir)
    rows = []
    for letter, items in sorted(runs.items()):
        names = list(dict.fromkeys(k for m in items for k in m["baselines"]))
        base = {k: float(np.mean([m["baselines"][k] for m in items if k in m["baselines"]])) for k in names}
        strongest = max(base, key=base.get) if base else None
        trained = [m for m in items if learned(m)]
        row = {"motion": letter, "seeds": " ".join(str(m.get("seed")) for m in items),
               "last_eval": mean_std(m.get("last_eval") for m in trained) if trained else "pending",
               "best_eval (secondary)": best_so_far(trained) if trained else "pending",
               **{f"baseline_{k}": round(v, 4) for k, v in base.items()}}
        if strongest is not None and trained:
            last = [m.get("last_eval") for m in trained]
            row["last - strongest baseline"] = round(float(np.mean(last)) - base[strongest], 4)
            row["above every baseline"] = (f"{sum(1 for v in last if v is not None and v > base[strongest])}"
                                           f"/{len(trained)}")
        row["steps_mean"] = int(np.mean([m["steps"] for m in items]))
        row["minutes_mean"] = round(float(np.mean([m["seconds"] for m in items])) / 60, 1)
        target = (targets.get(str(letter)) if isinstance(targets, dict) else
                  round(base[targets], 4) if isinstance(targets, str) else targets)
        if target is not None:
            reached = [p for p in (first_above(m["progress"], target) for m in trained) if p is not None]
            row.update({
                "target": target, "reached_target": f"{len(reached)}/{len(trained)}",
                "median_steps_to_target": int(np.median([p[0] for p in reached])) if reached else None,
                "median_minutes_to_target": round(float(np.median([p[1] for p in reached])) / 60, 2) if reached else None,
            })
        rows.append(row)
    drawn = {m: {k: float(np.mean([r["baselines"][k] for r in items if k in r["baselines"]]))
                 for k in (lines or list(dict.fromkeys(k for r in items for k in r["baselines"]))[:3])}
             for m, items in runs.items()}
    from aslexp.viz.imitation import plot_curves

    plot_curves(runs, out_dir / f"{stem}_curves.png",
                f"evaluation reward per motion (lines: no-learning baselines{', ' + ', '.join(lines) if lines else ''})",
                drawn)
    table = write_table(rows, out_dir, f"{stem}_table")
    return {"rows": rows, "table": table}


def write_table(rows: list[dict], out_dir: Path, stem: str) -> str:
    """Write ``rows`` as ``<stem>.csv`` and ``<stem>.md`` in ``out_dir``; return the Markdown."""
    keys = list(dict.fromkeys(k for row in rows for k in row))  # rows may lack optional columns
    rows = [{k: row.get(k) for k in keys} for row in rows]
    with open(out_dir / f"{stem}.csv", "w", newline="", encoding="utf-8") as fh:
        writer = csv.DictWriter(fh, fieldnames=keys)
        writer.writeheader()
        writer.writerows(rows)
    header = "| " + " | ".join(rows[0]) + " |\n|" + "---|" * len(rows[0]) + "\n"
    table = header + "".join("| " + " | ".join(str(v) for v in r.values()) + " |\n" for r in rows)
    (out_dir / f"{stem}.md").write_text(table, encoding="utf-8")
    return table


def finite_or_none(value: float | None) -> float | None:
    return None if value is None or not math.isfinite(value) else float(value)


if __name__ == "__main__":  # python -m aslexp.reports.report FOLDER
    from aslexp.reports.folder_main import folder_main

    raise SystemExit(folder_main(summarize_letters, __spec__.name, __doc__))
