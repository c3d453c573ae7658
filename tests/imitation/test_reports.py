"""Experiment summaries: letters and signs tables with the time to a target reward."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from aslexp.rl.report import summarize_letters
from aslexp.rl.upper_body_report import summarize_signs


def _run(folder: Path, motion: str, seed: int, evals: list[tuple[int, float, float]], strong: float | None = None):
    """A run folder as the imitate job writes it: metrics.json and progress.csv (step, seconds, eval)."""
    folder.mkdir(parents=True)
    baselines = {"reference": 0.8, "lookahead": 0.9} | ({"reference_velocity_pd": strong} if strong else {})
    first_pass = next((s for s, _, r in evals if r > 0.9), None)
    folder.joinpath("metrics.json").write_text(json.dumps({
        "motion": motion, "seed": seed, "baselines": baselines, "best_eval": max(r for *_, r in evals),
        "steps": evals[-1][0], "seconds": evals[-1][1], "steps_to_lookahead": first_pass}))
    with open(folder / "progress.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=["step", "seconds", "eval_reward"])
        writer.writeheader()
        writer.writerows({"step": s, "seconds": t, "eval_reward": r} for s, t, r in evals)


def test_letters_table_counts_seeds_that_pass_the_target(tmp_path):
    _run(tmp_path / "0", "A", 0, [(100, 10, 0.94), (200, 20, 0.96)], strong=0.95)
    _run(tmp_path / "1", "A", 1, [(100, 12, 0.951), (200, 24, 0.97)], strong=0.95)
    _run(tmp_path / "2", "D", 0, [(100, 10, 0.91), (200, 20, 0.93)])
    rows = {r["motion"]: r for r in summarize_letters(tmp_path)["rows"]}
    assert rows["A"]["passed_target"] == "2/2" and rows["A"]["target"] == 0.95
    assert rows["A"]["median_steps_to_target"] == 150 and rows["A"]["median_minutes_to_target"] == round(16 / 60, 2)
    assert rows["A"]["baseline_reference_velocity_pd"] == 0.95 and rows["A"]["best_eval_mean"] == 0.965
    assert rows["D"]["passed_target"] == "0/1" and rows["D"]["median_steps_to_target"] is None
    assert "baseline_reference_velocity_pd" not in rows["D"] or rows["D"]["baseline_reference_velocity_pd"] is None
    table = (tmp_path / "letters_table.md").read_text()
    assert table.count("\n") == 4 and (tmp_path / "letters_curves.png").stat().st_size > 0


def test_signs_table_times_each_sign_to_the_thesis_reward(tmp_path):
    _run(tmp_path / "0", "00433", 0, [(4096, 50, 0.86), (8192, 100, 0.87)])   # thesis 0.868
    _run(tmp_path / "1", "69318", 0, [(4096, 45, 0.88)])                        # thesis 0.745
    rows = {r["sign"]: r for r in summarize_signs(tmp_path)["rows"]}
    assert rows["00433 (above)"]["thesis_table_6_7"] == 0.868
    assert rows["00433 (above)"]["median_steps_to_thesis"] == 8192 and rows["00433 (above)"]["passed_thesis"] == "1/1"
    assert rows["69318 (father)"]["median_steps_to_thesis"] == 4096
    assert "signs_table" in str(list(tmp_path.glob("signs_table.md"))[0])
