"""Learning where tracking fails: a residual policy on top of a controller that loses reward for a
physical reason, against that controller and the simple baselines (``experiment=signs_free_residual``).

Per sign, every number under the runs' reward AND the policy's evaluation protocol (``ppo.eval_steps``
control steps from each of ``ppo.phases``; deterministic), measured by the runs
(:mod:`aslexp.measure.residual`, metrics.json ``residual_baselines``) and only read here:

* ``controller``: the run's controller with no correction on the reference one step ahead (the
  residual policy's zero action; a variant that filters its base, ``env.residual_base_smoothing``,
  is measured against this same bar, and its zero action is a ``smoothed reference`` row);
* ``same controller, pinned``: the same with the body's base pinned (``report.residual.compare``):
  what tracking scores when nothing can slip or tip. ``loss`` = pinned - controller is what the
  physical cause costs; the issue's rule asks for a learned gain only where it exceeds
  ``report.residual.min_loss`` (0.05), and says "no gain to find" elsewhere;
* where the root goes under the controller from phase 0: its largest yaw against the reference's
  root and its largest tilt from vertical (the standing body turns on slipping feet; it does not tip);
* ``smoothed reference``: the strongest simple baseline we know for this body, the reference low-pass
  filtered (:func:`aslexp.rl.evaluate.smoothed_reference_policy`) for each ``alpha`` of
  ``report.residual.smoothing``; the best alpha is picked on these same episodes, which flatters the
  baseline, never the policy;
* ``constant random corrections`` (``report.residual.random_corrections``: count, rms, seed): the
  controller plus a fixed random correction of the size a learned one has, one per draw
  (:func:`aslexp.rl.evaluate.constant_correction_policy`): mean ± std and the best over the draws.
  The spread is how far a correction that learned nothing moves the evaluation;
* the learned policy's LAST evaluation, mean ± std over seeds (the headline); the best-so-far
  evaluation as a secondary column; and the verdict: above the controller by more than the seed
  spread (the larger of the policy's std over seeds and 0)?
* the learned correction's size at the last evaluation beside the exploration noise, both in
  half-widths of the action box (metrics.json ``last_eval_action_rms``, ``exploration_std``).

    python -m aslexp.reports.residual_report outputs/imitate-multirun/<sweep>      # the table again
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.reports.report import best_so_far, learned, mean_std, read_runs, run_config, write_table
from aslexp.reports.thesis_report import GLOSSES


def measured_rows(motion: str, items: list[dict[str, Any]], cache: Path) -> dict[str, Any]:
    """The comparison rows the runs measured (metrics.json ``residual_baselines``),
    else those this report measured for older runs (``cache``); never simulated here."""
    rows = next((m["residual_baselines"] for m in items if m.get("residual_baselines")), None)
    if rows is None and cache.is_file():
        rows = json.loads(cache.read_text()).get("rows")
    if rows is None:
        raise ValueError(f"the runs of {motion} ({Path(items[0]['run_dir']).parent}) measured no residual baselines "
                         f"(metrics.json residual_baselines: runs older than that record); re-evaluate them, which "
                         f"measures them: aslexp imitate -m <the sweep's overrides> 'resume=SWEEP/${{hydra:job.num}}'")
    return rows


def summarize_residual(sweep_dir: str | Path, out_dir: str | Path | None = None) -> dict[str, Any]:
    """``residual_table.{md,csv}``, ``residual_baselines.json`` and ``residual_curves.png`` for the
    runs under ``sweep_dir`` (see the module docstring); returns the rows and the Markdown table."""
    sweep_dir = Path(sweep_dir)
    out_dir = Path(out_dir or sweep_dir)
    runs = read_runs(sweep_dir)
    rows, lines, everything = [], {}, {}
    for motion, items in sorted(runs.items()):
        cfg = run_config(items[0]["run_dir"])
        settings = (cfg.get("report") or {}).get("residual") or {}
        trained = [m for m in items if learned(m)]
        base = measured_rows(motion, items, out_dir / "baselines" / f"{motion}.json")
        everything[motion] = base
        controller = base["controller"]
        compare = base.get("compare")
        loss = None if compare is None else compare - controller
        min_loss = float(settings.get("min_loss", 0.05))
        smoothed = base.get("smoothed") or {}
        best_alpha = max(smoothed, key=smoothed.get) if smoothed else None
        last = np.asarray([m["last_eval"] for m in trained], dtype=float)
        row: dict[str, Any] = {
            "sign": f"{motion} ({GLOSSES[motion]})" if motion in GLOSSES else motion,
            "controller": round(controller, 3),
            f"same controller, {settings.get('compare_label', 'pinned base')}": None if compare is None else round(compare, 3),
            "loss to the physical cause": None if loss is None else round(loss, 3),
            "controller from phase 0: max yaw / tilt (deg)": "{:.1f} / {:.1f}".format(
                base["controller_drift"]["max_yaw_deg"], base["controller_drift"]["max_tilt_deg"]),
            **{f"smoothed reference, alpha {a}": round(v, 3) for a, v in smoothed.items()},
            **_chance_column(base.get("random_corrections")),
            "learned, last evaluation": f"{mean_std(last)} (n={len(trained)})" if trained else "pending",
            "learned, best so far (secondary)": best_so_far(trained) if trained else "pending",
        }
        if trained:
            gain, spread = float(last.mean()) - controller, float(last.std())
            row["learned - controller"] = round(gain, 3)
            row["seed spread (std)"] = round(spread, 3)
            if loss is not None and loss <= min_loss:
                row["verdict"] = f"no gain to find (the controller loses {loss:.3f} <= {min_loss})"
            elif len(trained) < 2:
                row["verdict"] = "one seed: no spread to judge by (the rule needs several)"
            else:
                beats = gain > spread and bool(np.all(last > controller))
                row["verdict"] = ("beats the controller by more than the seed spread" if beats
                                  else "does NOT beat the controller by more than the seed spread")
            if best_alpha is not None:
                row["learned - best smoothed"] = round(float(last.mean()) - smoothed[best_alpha], 3)
            sizes = [(m["last_eval_action_rms"], m["exploration_std"]) for m in trained
                     if m.get("last_eval_action_rms") is not None and m.get("exploration_std") is not None]
            # Is the learned correction larger than the noise it was learned under? (medians over seeds)
            row["learned correction RMS / exploration std (box half-widths)"] = (
                "{:.3f} / {:.3f}".format(*np.median(np.asarray(sizes), axis=0)) if sizes else "n/a (older runs)")
            row["steps per run"] = int(np.median([m["steps"] for m in trained]))
            row["minutes per run"] = round(float(np.median([m["seconds"] for m in trained])) / 60, 1)
        rows.append(row)
        lines[motion] = {"controller": controller,
                         **({f"smoothed, alpha {best_alpha}": smoothed[best_alpha]} if best_alpha else {}),
                         **({"pinned": compare} if compare is not None else {})}
    (out_dir / "residual_baselines.json").write_text(json.dumps(everything, indent=1))
    from aslexp.viz.imitation import plot_curves

    plot_curves(runs, out_dir / "residual_curves.png",
                "every evaluation, mean ± std over seeds\n(dashed: controller, dotted: best smoothed "
                "reference, dash-dot: pinned base)",
                lines)
    table = write_table(rows, out_dir, "residual_table")
    return {"rows": rows, "table": table}


def _chance_column(chance: dict[str, Any] | None) -> dict[str, str]:
    if not chance:
        return {}
    scores = np.asarray(chance["scores"], dtype=float)
    return {f"constant random corrections, RMS {chance['rms']:g} (n={len(scores)}): mean ± std / best":
            f"{mean_std(scores)} / {scores.max():.3f}"}


if __name__ == "__main__":  # python -m aslexp.reports.residual_report FOLDER
    from aslexp.reports.folder_main import folder_main

    raise SystemExit(folder_main(summarize_residual, __spec__.name, __doc__))
