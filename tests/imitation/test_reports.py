"""Experiment summaries: last evaluations as the headline, every baseline compared, time to a target."""

from __future__ import annotations

import csv
import json
from pathlib import Path

from aslexp.reports.report import summarize_letters
from aslexp.reports.upper_body_report import summarize_signs
from aslexp.viz.imitation import plot_seed_curves, seeds_on_common_steps


def _run(folder: Path, motion: str, seed: int, evals: list[tuple[int, float, float]], strong: float | None = None):
    """A run folder as the imitate job writes it: metrics.json and progress.csv (step, seconds, eval)."""
    folder.mkdir(parents=True)
    baselines = {"reference": 0.8, "lookahead": 0.9} | ({"reference_velocity_pd": strong} if strong else {})
    folder.joinpath("metrics.json").write_text(json.dumps({
        "motion": motion, "seed": seed, "baselines": baselines, "best_eval": max(r for *_, r in evals),
        "last_eval": evals[-1][2], "steps": evals[-1][0], "seconds": evals[-1][1], "stopped": "total_steps"}))
    with open(folder / "progress.csv", "w", newline="") as fh:
        writer = csv.DictWriter(fh, fieldnames=["step", "seconds", "eval_reward"])
        writer.writeheader()
        writer.writerows({"step": s, "seconds": t, "eval_reward": r} for s, t, r in evals)


def test_letters_table_headlines_the_last_evaluation_and_compares_with_every_baseline(tmp_path):
    _run(tmp_path / "0", "A", 0, [(100, 10, 0.94), (200, 20, 0.96)], strong=0.95)
    _run(tmp_path / "1", "A", 1, [(100, 12, 0.951), (200, 24, 0.97)], strong=0.95)
    # Above the thesis-controller bars (0.8, 0.9) but below its own controller's 0.95: never "passed".
    _run(tmp_path / "2", "D", 0, [(100, 10, 0.96), (200, 20, 0.93)], strong=0.95)
    rows = {r["motion"]: r for r in summarize_letters(tmp_path)["rows"]}
    assert rows["A"]["last_eval"] == "0.965 ± 0.005" and rows["A"]["best_eval (secondary)"] == "0.965 ± 0.005"
    assert rows["A"]["above every baseline"] == "2/2" and rows["A"]["baseline_reference_velocity_pd"] == 0.95
    assert rows["A"]["reached_target"] == "2/2" and rows["A"]["median_steps_to_target"] == 150
    assert rows["A"]["median_minutes_to_target"] == round(16 / 60, 2)
    assert rows["D"]["last_eval"] == "0.930" and rows["D"]["best_eval (secondary)"] == "0.960"
    assert rows["D"]["above every baseline"] == "0/1" and rows["D"]["last - strongest baseline"] == -0.02
    table = (tmp_path / "letters_table.md").read_text()
    assert table.count("\n") == 4 and (tmp_path / "letters_curves.png").stat().st_size > 0


def test_a_run_with_one_evaluation_is_drawn(tmp_path):
    import matplotlib.image as mpimg
    import numpy as np

    _run(tmp_path / "0", "A", 0, [(4096, 10, 0.5)])
    summarize_letters(tmp_path, targets=None)
    image = mpimg.imread(tmp_path / "letters_curves.png")[:, :, :3]
    blue = np.all(np.abs(image - np.array([0.12, 0.47, 0.71])) < 0.08, axis=-1)  # C0, the curve's colour
    assert blue.sum() > 20  # the one evaluation is a visible point, not an empty axes


def test_each_seeds_curve_and_kept_policy_are_drawn_in_its_own_colour(tmp_path):
    """plot_seed_curves: a validated run's last row (its kept policy re-evaluated, same step as the one
    before) is a star in the seed's colour at the kept step, not a point of the curve."""
    import matplotlib.image as mpimg
    import numpy as np

    kept = [{"step": s, "eval_reward": r} for s, r in ((0, 0.5), (100, 0.9), (200, 0.4))]
    kept.append({"step": 200, "eval_reward": 0.9, "selected_step": 100})
    plain = [{"step": s, "eval_reward": r} for s, r in ((0, 0.45), (100, 0.6), (200, 0.7))]
    path = plot_seed_curves({"seed 0": kept, "seed 1": plain}, {"controller": 0.5}, tmp_path / "seeds.png", "t")
    image = mpimg.imread(path)[:, :, :3]
    for colour in ([0.12, 0.47, 0.71], [1.0, 0.5, 0.05]):  # C0 and C1: both seeds drawn
        assert np.all(np.abs(image - np.array(colour)) < 0.08, axis=-1).sum() > 50


def test_seeds_are_averaged_at_the_steps_they_share_not_by_evaluation_index():
    # two seeds every 100 steps; seed 0 stopped and was resumed at 150 (an extra evaluation there)
    seed0 = [(100, 0.1), (150, 0.9), (200, 0.2), (300, 0.3)]
    seed1 = [(100, 0.3), (200, 0.4), (300, 0.5)]
    steps, values = seeds_on_common_steps([seed0, seed1])
    assert steps.tolist() == [100, 200, 300] and values.tolist() == [[0.1, 0.2, 0.3], [0.3, 0.4, 0.5]]
    # schedules that do not line up (other intervals): by index, up to the shortest curve
    steps, values = seeds_on_common_steps([[(64, 0.1), (128, 0.2)], [(100, 0.3), (200, 0.4), (300, 0.5)]])
    assert steps.tolist() == [64, 128] and values.tolist() == [[0.1, 0.2], [0.3, 0.4]]


def test_signs_table_times_each_sign_to_the_thesis_reward(tmp_path):
    _run(tmp_path / "0", "00433", 0, [(4096, 50, 0.86), (8192, 100, 0.87)])   # thesis 0.868
    _run(tmp_path / "1", "69318", 0, [(4096, 45, 0.88)])                        # thesis 0.745
    rows = {r["sign"]: r for r in summarize_signs(tmp_path)["rows"]}
    assert rows["00433 (above)"]["thesis_table_6_7_run2"] == 0.868
    assert rows["00433 (above)"]["median_steps_to_thesis"] == 8192 and rows["00433 (above)"]["reached_thesis"] == "1/1"
    assert rows["69318 (father)"]["median_steps_to_thesis"] == 4096
    assert (tmp_path / "signs_table.md").is_file()
