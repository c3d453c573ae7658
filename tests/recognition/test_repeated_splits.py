"""K repeated splits on the real WLASL-Lex set: every model on the same splits, intervals over
splits, the baseline chosen by validation, paired comparisons and the tables built from them."""

from __future__ import annotations

import json

import numpy as np
import pytest

from aslexp.data.splits import SplitOptions
from aslexp.recognition.experiment import split_views
from aslexp.recognition.experiment import run_recognition
from aslexp.recognition.metrics import mean_interval
from aslexp.viz.recognition import plot_comparisons, plot_validation_curves
from aslexp.recognition.report import (
    BELOW_BASELINE,
    collect_table,
    comparisons,
    paired_on_shared_splits,
    thesis_ch3_table,
    thesis_ch4_table,
)

SPLIT = {"name": "phoneme", "repeats": 3, "seed": 0}
MODELS = {"logreg": {}, "rf": {"n_estimators": 30, "n_jobs": 1}, "mlp": {"hidden_sizes": [16]}}
TRAINER = {"max_epochs": 2, "patience": 2, "batch_size": 32, "num_threads": 1}


pytestmark = pytest.mark.xdist_group("repeated_splits")  # one worker trains the module's runs once

@pytest.fixture(scope="module")
def runs(lex_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("runs")
    return {name: run_recognition(lex_dataset, {"name": name, "params": params}, TRAINER, [0], out / name, split=SPLIT)
            for name, params in MODELS.items()}  # fmt: skip


def test_repeated_splits_are_independent_and_shared(lex_dataset, runs):
    views = split_views(lex_dataset, SplitOptions.parse(SPLIT))
    tests = [set(np.asarray(view.video_ids)[view.splits["test"]]) for _, view in views]
    assert len(tests) == 3 and tests[0] != tests[1] != tests[2]
    # The first repeat with the built split's seed reproduces the dataset's own split.
    assert tests[0] == set(np.asarray(lex_dataset.video_ids)[lex_dataset.splits["test"]])
    for result in runs.values():
        assert [s["seed"] for s in result["splits"]] == [0, 1, 2] and result["statistics_unit"] == "split"
        assert len(result["test_per_split"]) == 3
        interval = result["test_interval"]["mcc"]
        assert interval["n"] == 3
        assert interval["mean"] == pytest.approx(np.mean([u["mcc"] for u in result["test_per_split"]]))
        assert interval["low"] < interval["mean"] < interval["high"]
        json.dumps(result)


def test_baseline_is_chosen_by_validation_and_compared_paired(runs):
    result = runs["logreg"]
    baseline = result["baseline"]
    assert baseline["selected_by"] == "validation accuracy"
    assert baseline["name"] == max(baseline["val_accuracy"], key=baseline["val_accuracy"].get)
    paired = result["paired_vs_baseline"]["mcc"]
    diffs = [m["mcc"] - b["mcc"] for m, b in zip(result["test_per_split"], baseline["test_per_split"])]
    assert paired["diff"] == mean_interval(diffs)
    assert paired["wins"] + paired["ties"] + paired["losses"] == 3
    assert result["below_baseline"]["mcc"] == (result["test"]["mcc"] < baseline["test"]["mcc"])


def test_feature_baseline_learns_sign_type(runs):
    # Pooled summary statistics into a forest: clearly above chance on every split of the phoneme split.
    assert all(u["mcc"] > 0.2 for u in runs["rf"]["test_per_split"])
    assert runs["rf"]["paired_vs_baseline"]["mcc"]["wins"] == 3


def test_tables_show_intervals_flags_and_paired_comparisons(runs, tmp_path):
    cells = [{"model": name, "property": "sign_type", "split": "phoneme", "metrics": m} for name, m in runs.items()]
    markdown, table_csv = collect_table(cells)
    lines = markdown.splitlines()
    rf = runs["rf"]["test_interval"]["mcc"]
    assert f"| phoneme | rf | {rf['mean']:.3f} ± {rf['half_width']:.3f} (3) |" in lines[3]
    assert lines[-3].startswith("| phoneme | baseline | 0.000") and "[majority]" in lines[-3]
    flagged = [name for name, m in runs.items() if m["below_baseline"]["mcc"]]
    for name in flagged:
        assert BELOW_BASELINE in next(line for line in lines if f"| {name} |" in line)
    header = table_csv.splitlines()[0].split(",")
    assert header[:6] == ["split", "model", "sign_type_mcc", "sign_type_mcc_ci_low", "sign_type_mcc_ci_high", "sign_type_n"]

    rows = {r["model"]: r for r in comparisons(cells)}
    reference = rows["mlp"]["strongest_simple"]
    assert reference in ("logreg", "rf")
    expected = np.subtract([u["mcc"] for u in runs["mlp"]["test_per_split"]],
                           [u["mcc"] for u in runs[reference]["test_per_split"]])  # fmt: skip
    assert rows["mlp"]["vs_simple"]["diff"]["mean"] == pytest.approx(expected.mean())
    assert rows[reference]["vs_simple"] is None  # the reference is not compared with itself
    # Every learned model against each feature baseline, the strongest among them included.
    assert set(rows["mlp"]["vs_feature"]) == {"logreg", "rf"}
    assert rows["mlp"]["vs_feature"][reference] == rows["mlp"]["vs_simple"]
    assert plot_comparisons(list(rows.values()), tmp_path / "comparisons.png")
    members = [{"split": "phoneme", "property": "sign_type", "classifier": name, "metrics": m} for name, m in runs.items()]
    assert plot_validation_curves(members, tmp_path / "validation_curves.png")  # mlp: 2 epochs per run
    for name in ("comparisons.png", "validation_curves.png"):
        assert (tmp_path / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name

    ch4 = thesis_ch4_table(cells)
    assert "| model | SignType A | SignType Ā |" in ch4
    accuracy = runs["logreg"]["test_interval"]["accuracy"]
    assert f"| logreg | {100 * accuracy['mean']:.1f} ± {100 * accuracy['half_width']:.1f} |" in ch4
    ch3 = thesis_ch3_table(cells)
    assert "| model | sign_type micro-F1 | sign_type macro-F1 |" in ch3 and "| Baseline |" in ch3


def test_one_clip_per_gloss_cross_validation(lex_dataset):
    options = SplitOptions.parse({"name": "cv5", "one_clip_per_gloss": True, "repeats": 2, "seed": 4})
    views = split_views(lex_dataset, options)
    for _, view in views:
        assert len(set(view.glosses)) == len(view.glosses)  # one clip per gloss
        assert len(view.splits["folds"]) == 5
        test = set(view.splits["test"].tolist())
        for train, val in view.splits["folds"]:
            assert not test & set(train.tolist()) and not test & set(val.tolist())
    assert views[0][1].video_ids != views[1][1].video_ids  # each split draws its own clip per gloss


def test_a_run_over_fewer_splits_is_paired_on_the_splits_it_shares(runs):
    # A run over the first 2 of the 3 splits (as SL-GCN's K = 3 against K = 10): paired on those 2.
    mlp, rf = runs["mlp"], runs["rf"]
    shorter = dict(mlp, splits=mlp["splits"][:2], test_per_split=mlp["test_per_split"][:2])
    paired = paired_on_shared_splits(shorter, rf)
    expected = [m["mcc"] - r["mcc"] for m, r in zip(mlp["test_per_split"][:2], rf["test_per_split"][:2])]
    assert paired["diff"]["n"] == 2 and paired["diff"]["mean"] == pytest.approx(np.mean(expected))
    # Splits of another data set (other sizes) are not the same splits: nothing to pair.
    other = dict(shorter, splits=[dict(s, sizes={"train": 1, "val": 1, "test": 1}) for s in shorter["splits"]])
    assert paired_on_shared_splits(other, rf) is None
