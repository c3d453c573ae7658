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

from aslexp.reports.report import best_so_far, learned, mean_std, plot_curves, read_runs, run_config, write_table

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
    if kind == "letters":
        return THESIS_LETTERS, None
    if kind in ("signs_run1", "signs_run2") and motion in THESIS_TABLE_6_7:
        mean, std = THESIS_TABLE_6_7[motion][0:2] if kind == "signs_run1" else THESIS_TABLE_6_7[motion][2:4]
        return f"{mean:.3f} ± {std:.3f} (Table 6.7 {'Run 1' if kind == 'signs_run1' else 'Run 2'})", mean
    return "-", None


def motion_baselines(cfg: dict[str, Any], cache: Path) -> list[dict[str, Any]]:
    """The no-learning rows of ``cfg["report"]`` for the run config's motion, cached in ``cache``
    (deterministic: computed once per motion, not per seed)."""
    report = cfg.get("report") or {}
    key = {"report": report, "body": cfg["body"], "reward": cfg["reward"], "env": cfg["env"],
           "motion": cfg["motion"]}
    if (cfg.get("engine") or {}).get("name", "pybullet") != "pybullet":  # PyBullet caches stay valid
        key["engine"] = cfg["engine"]
    if cache.is_file():
        stored = json.loads(cache.read_text())
        if stored.get("key") == json.loads(json.dumps(key)):
            return stored["rows"]
    from aslexp.data.root import resolve_data_root
    from aslexp.envs.baselines import Baseline, no_learning_baselines
    from aslexp.envs.imitation import resolve_motion_path

    data_root = resolve_data_root(cfg.get("data_root"))
    rows = no_learning_baselines(resolve_motion_path(cfg["motion"]["file"], data_root), cfg["body"], cfg["reward"],
                                 cfg["env"], [Baseline.from_dict(b) for b in report.get("baselines", [])],
                                 float(report.get("baseline_seconds", 10.0)), data_root, engine=cfg.get("engine"))
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps({"key": key, "rows": rows}, indent=1))
    return rows


def baseline_column(row: dict[str, Any]) -> str:
    where = "reference" if row["lookahead"] == 0 else f"{row['lookahead']} step ahead"
    return f"{'aslexp: ' if row['aslexp'] else ''}{row['label']}, {where}"


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
        baselines = motion_baselines(cfg, out_dir / "baselines" / f"{motion}.json")
        all_baselines[motion] = baselines
        text, value = thesis_number(kind, motion)
        trained = [m for m in items if learned(m)]
        last = [m.get("last_eval") for m in trained]
        row = {"motion": f"{motion} ({GLOSSES[motion]})" if motion in GLOSSES else motion, "thesis": text,
               **{baseline_column(b): round(b["reward"], 3) if not b["fell"] else f"{b['reward']:.3f} (fell)"
                  for b in baselines},
               "learned, last evaluation": f"{mean_std(last)} (n={len(trained)})" if trained else "pending",
               "learned, best so far (secondary)": best_so_far(trained) if trained else "pending"}
        if trained and baselines:
            strongest = max(baselines, key=lambda b: b["reward"])
            row["strongest baseline"] = baseline_column(strongest)
            row["last - strongest"] = round(float(np.mean(last)) - strongest["reward"], 3)
            row["seeds above every baseline"] = f"{sum(1 for v in last if v > strongest['reward'])}/{len(trained)}"
        rows.append(row)
        lines[motion] = {**({"thesis": value} if value is not None else {}),
                         **({"strongest baseline": max(b["reward"] for b in baselines)} if baselines else {})}
    (out_dir / "thesis_baselines.json").write_text(json.dumps(all_baselines, indent=1))
    plot_curves(runs, out_dir / "thesis_curves.png",
                "last evaluations per motion (dotted: thesis, dashed: strongest no-learning baseline)", lines)
    table = write_table(rows, out_dir, "thesis_table")
    return {"rows": rows, "table": table}


if __name__ == "__main__":  # python -m aslexp.reports.thesis_report FOLDER
    from aslexp.reports.folder_main import folder_main

    raise SystemExit(folder_main(summarize_thesis, __spec__.name, __doc__))
