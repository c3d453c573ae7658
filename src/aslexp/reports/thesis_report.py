"""Learned results beside the thesis' numbers, under the same reward: the report of the overlays
``experiment=letters_thesis``, ``signs_thesis_run1`` and ``signs_thesis_run2``.

Per letter or sign: the thesis' number, every no-learning baseline of the overlay's ``report.baselines``
(the reference as the PD target and one control step ahead, for each controller; aslexp's own
controllers as labelled aslexp rows), all scored under the runs' reward from phase 0, and the
learned policy's LAST evaluation as mean ± std over seeds (the best-so-far evaluation only as a
secondary column: a maximum over evaluations is biased upward). A row whose runs did not train
(``ppo.total_steps=0``) shows its learned cells as pending.

    python -m aslexp.reports.thesis_report outputs/imitate-multirun/<sweep>      # the table again
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.reports.report import best_so_far, ended_early, learned, mean_std, read_runs, run_config, write_table

# Thesis Table 6.7 (THESIS.md 4.8): sign -> (Run 1 mean, std, Run 2 mean, std), 10 seeds, 50 M steps.
THESIS_TABLE_6_7 = {"00433": (0.827, 0.020, 0.868, 0.007), "52861": (0.832, 0.022, 0.853, 0.017),
                    "69318": (0.297, 0.166, 0.745, 0.018), "69402": (0.243, 0.304, 0.791, 0.032),
                    "69546": (0.830, 0.020, 0.842, 0.018)}
GLOSSES = {"00433": "above", "52861": "snow", "69318": "father", "69402": "mother", "69546": "yes"}
# Fig. 5.9 gives no per-letter numbers: the prose says the normalised reward ends at 0.8-0.95 (THESIS.md 3.1).
THESIS_LETTERS = "0.8-0.95 (all letters, Fig. 5.9)"


def thesis_number(kind: str, motion: str) -> tuple[str, float | None]:
    """The thesis' cell for ``motion`` in the comparison ``kind`` (letters | signs_run1 | signs_run2)
    and a value to draw (None: a range)."""
    if kind == "letters":  # the default: the hand's letters (a sign has no number under it)
        return (THESIS_LETTERS, None) if motion not in GLOSSES else ("-", None)
    if kind in ("signs_run1", "signs_run2") and motion in THESIS_TABLE_6_7:
        mean, std = THESIS_TABLE_6_7[motion][0:2] if kind == "signs_run1" else THESIS_TABLE_6_7[motion][2:4]
        return f"{mean:.3f} ± {std:.3f} (Table 6.7 {'Run 1' if kind == 'signs_run1' else 'Run 2'})", mean
    return "-", None


def motion_baselines(cfg: dict[str, Any], cache: Path, items: list[dict[str, Any]] = ()) -> list[dict[str, Any]]:
    """The no-learning rows of ``cfg["report"]`` for the run config's motion, as the runs (``items``:
    their metrics.json) measured them under their own evaluation protocol (``report_baselines``),
    else as this report measured them for older runs (``cache``, the same
    config); never simulated here."""
    measured = next((m["report_baselines"] for m in items if m.get("report_baselines")), None)
    if measured is not None:
        return measured
    if not (cfg.get("report") or {}).get("baselines"):
        return []  # the overlay names none
    if cache.is_file():  # written by this report, in these runs' own folder, when it still simulated
        return json.loads(cache.read_text())["rows"]
    where = Path(items[0]["run_dir"]).parent if items else cache.parent.parent
    raise ValueError(f"the runs of {cfg['motion']['name']} ({where}) measured no report.baselines (metrics.json "
                     f"report_baselines: runs older than that record); re-evaluate them, which measures them: "
                     f"aslexp imitate -m <the sweep's overrides> 'resume=SWEEP/${{hydra:job.num}}'")


def _marked(row: dict[str, Any]) -> float | str:
    """A baseline's reward, with how its episodes ended where one ended early."""
    ends = ended_early(row)
    return round(row["reward"], 3) if not ends else f"{row['reward']:.3f} ({ends})"


def baseline_column(row: dict[str, Any]) -> str:
    where = "reference" if row["lookahead"] == 0 else f"{row['lookahead']} step ahead"
    return f"{'aslexp: ' if row['aslexp'] else ''}{row['label']}, {where}"


SATURATED = 0.005  # a ceiling this close to the controller it plans on leaves nothing to learn


def ceiling(planned: list[dict[str, Any]]) -> dict[str, Any]:
    """A motion's ceiling from its planner runs (metrics.json ``planner``): the planner's settings,
    its score (mean and std over seeds), the run's own controller alone under the same protocol, the
    difference (saturated below :data:`SATURATED`), the cost per control step and blow-ups."""
    scores = [float(m["last_eval"]) for m in planned]
    alone = float(np.mean([m["planner"]["controller_alone"] for m in planned]))
    mean = float(np.mean(scores))
    return {"spec": planned[0]["planner"], "scores": scores, "mean": mean, "spread": float(np.std(scores)),
            "n": len(scores), "controller_alone": alone, "gain": mean - alone, "saturated": mean - alone < SATURATED,
            "seconds_per_step": float(np.mean([m["planner"]["seconds_per_step"] for m in planned])),
            "diverged": sum(int(m.get("last_eval_diverged") or 0) for m in planned),
            "fell": sum(int(m["planner"].get("fell") or 0) for m in planned)}


def ceiling_columns(planned: list[dict[str, Any]]) -> dict[str, Any]:
    """The thesis table's columns of a planner's runs (:func:`ceiling`)."""
    found = ceiling(planned)
    spec = found["spec"]
    label = f"ceiling: {spec['name']} ({spec['method']}, horizon {spec['horizon']}, {spec['samples']} samples)"
    return {label: f"{mean_std(found['scores'])} (n={found['n']})",
            "its controller alone": round(found["controller_alone"], 4),
            "ceiling - controller": f"{found['gain']:+.4f}" + (" (saturated)" if found["saturated"] else ""),
            "s per control step": round(found["seconds_per_step"], 3)}


def summarize_thesis(sweep_dir: str | Path, out_dir: str | Path | None = None) -> dict[str, Any]:
    """``thesis_table.{md,csv}``, ``thesis_baselines.json`` and ``thesis_curves.png`` for the runs under
    ``sweep_dir`` (see the module docstring); returns the rows and the Markdown table."""
    sweep_dir = Path(sweep_dir)
    out_dir = Path(out_dir or sweep_dir)
    runs = read_runs(sweep_dir)
    rows, lines, all_baselines = [], {}, {}
    for motion, items in sorted(runs.items()):
        cfg = run_config(items[0]["run_dir"])
        kind = (cfg.get("report") or {}).get("thesis", "letters")
        baselines = motion_baselines(cfg, out_dir / "baselines" / f"{motion}.json", items)
        all_baselines[motion] = baselines
        text, value = thesis_number(kind, motion)
        trained = [m for m in items if learned(m)]
        planned = [m for m in items if m.get("planner")]
        last = [m.get("last_eval") for m in trained]
        row = {"motion": f"{motion} ({GLOSSES[motion]})" if motion in GLOSSES else motion, "thesis": text,
               **{baseline_column(b): _marked(b) for b in baselines}}
        if planned:  # planner runs (aslexp.control.mpc): the ceiling beside the controller it plans on
            row.update(ceiling_columns(planned))
        if trained or not planned:
            row["learned, last evaluation"] = f"{mean_std(last)} (n={len(trained)})" if trained else "pending"
            row["learned, best so far (secondary)"] = best_so_far(trained) if trained else "pending"
        for name in dict.fromkeys(k for m in trained for k in m.get("last_eval_scores") or {}):
            values = [m["last_eval_scores"][name] for m in trained if name in (m.get("last_eval_scores") or {})]
            row[f"learned, last evaluation under reward={name}"] = f"{mean_std(values)} (n={len(values)})"
            row[f"strongest baseline under reward={name}"] = round(max(b["scores"][name] for b in baselines), 3) \
                if baselines and all(name in (b.get("scores") or {}) for b in baselines) else "-"
        diverged = [m.get("last_eval_diverged") for m in trained]
        if any(diverged):
            row["episodes diverged (last evaluations)"] = sum(int(d or 0) for d in diverged)
        scored = [b for b in baselines if not b.get("diverged")]  # a blown-up simulation is not a score
        if trained and scored:
            strongest = max(scored, key=lambda b: b["reward"])
            row["strongest baseline"] = baseline_column(strongest)
            row["last - strongest"] = round(float(np.mean(last)) - strongest["reward"], 3)
            row["seeds above every baseline"] = f"{sum(1 for v in last if v > strongest['reward'])}/{len(trained)}"
        rows.append(row)
        lines[motion] = {**({"thesis": value} if value is not None else {}),
                         **{baseline_column(b): b["reward"] for b in scored},  # diverged rows: the table marks them
                         **({"ceiling (MPC)": ceiling(planned)["mean"]} if planned else {})}
    (out_dir / "thesis_baselines.json").write_text(json.dumps(all_baselines, indent=1))
    from aslexp.viz.imitation import plot_levels, plot_panels

    if any(learned(m) for items in runs.values() for m in items) or not any(
            m.get("planner") for items in runs.values() for m in items):
        plot_panels(runs, lines, out_dir / "thesis_curves.png",
                    "evaluation reward over training (mean ± std over seeds; step 0: the untrained policy) "
                    "beside every no-learning baseline (one that diverged is not drawn)")
    else:  # planner runs only: nothing trains, so no curve: each motion's numbers side by side
        plot_levels(lines, out_dir / "ceiling_levels.png",
                    "the planner's score (the ceiling) beside every no-learning baseline, per motion\n"
                    "(a baseline whose simulation diverged is not a score: not drawn; the table marks it)")
    table = write_table(rows, out_dir, "thesis_table")
    return {"rows": rows, "table": table}


if __name__ == "__main__":  # python -m aslexp.reports.thesis_report FOLDER
    from aslexp.reports.folder_main import folder_main

    raise SystemExit(folder_main(summarize_thesis, __spec__.name, __doc__))
