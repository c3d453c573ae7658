"""A run says only what its numbers carry: model seeds that cannot differ are named (in the run and
in the job, for ``-m seed=0,1``), a validation tie reads as a tie and not as a winner, a small test
set gets a caution, and the shipped logreg search space cannot draw the every-frame input."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from aslexp.recognition.comparison import SMALL_TEST_SET, validation_tie
from aslexp.recognition.experiment import run_recognition
from aslexp.recognition.models import build_classifier
from aslexp.recognition.report import comparison_text

ROOT = Path(__file__).resolve().parents[2]
TRAINER = {"max_epochs": 2, "batch_size": 32, "num_threads": 1}
# Two simple models that cannot split a node (a leaf needs more clips than there are): both predict
# one class, so both validate at MCC 0 exactly, a tie by construction.
CONSTANT = {"rf": {"n_estimators": 1, "min_samples_leaf": 100000}, "hgb": {"max_iter": 1, "min_samples_leaf": 100000}}


def test_a_deterministic_model_says_its_seeds_gave_one_result(lex_dataset, tmp_path, caplog):
    result = run_recognition(lex_dataset, {"name": "logreg"}, TRAINER, [0, 1], tmp_path / "logreg", simple_baseline=None)
    first, second = result["test_per_seed"]
    assert first["confusion_matrix"] == second["confusion_matrix"] and result["val"][0]["score"] == result["val"][1]["score"]
    assert result["seed_changes_result"] is False
    caution = next(c for c in result["comparison"]["cautions"] if "model seeds 0, 1 gave identical runs" in c)
    assert caution.startswith("caution: logreg draws no random number") and "split.repeats" in caution
    assert caution in caplog.text and caution in comparison_text(result["comparison"]).splitlines()

    # A seeded model's seeds differ: no such caution.
    seeded = run_recognition(lex_dataset, {"name": "rf", "params": {"n_estimators": 10}}, TRAINER, [0, 1],
                             tmp_path / "rf", simple_baseline=None)  # fmt: skip
    assert seeded["seed_changes_result"] is True
    assert not any("identical runs" in c for c in seeded["comparison"]["cautions"])
    # Which settings draw random numbers is the model's to say: logreg's saga solver shuffles.
    shape = (3, 8, 5, 4)
    assert build_classifier("logreg", {"solver": "saga"}, *shape).uses_seed
    assert not build_classifier("svm", {}, *shape).uses_seed and build_classifier("stratified", {}, *shape).uses_seed


def test_the_job_warns_when_seed_cannot_change_the_result_and_not_when_seed_moves_the_split(run_cli, tmp_path):
    alone = ["experiment=debug", "simple_baseline=null", "~simple_baseline_params.rf"]  # the model and chance only
    sweep = tmp_path / "sweep"
    proc = run_cli("recognize", "-m", *alone, "seed=0,1", f"hydra.sweep.dir={sweep}")
    output = proc.stdout + proc.stderr
    for seed in (0, 1):
        assert f"seed={seed} cannot change logreg's result: logreg draws no random number" in output
    runs = [json.loads(path.read_text()) for path in sorted(sweep.glob("*/metrics.json"))]
    assert len(runs) == 2 and runs[0]["test"] == runs[1]["test"] and runs[0]["seeds"] != runs[1]["seeds"]

    # A split that follows seed is another split per seed: no warning.
    proc = run_cli("recognize", *alone, "seed=1", "split.seed=${seed}", f"hydra.run.dir={tmp_path / 'moved'}")
    assert "cannot change" not in proc.stdout + proc.stderr
    assert json.loads((tmp_path / "moved" / "metrics.json").read_text())["splits"][0]["seed"] == 1


def test_a_validation_tie_reads_as_a_tie(lex_dataset, tmp_path):
    # The model beside two tied simple baselines: the reference is the first listed, and said to be tied.
    result = run_recognition(lex_dataset, {"name": "mlp", "params": {"hidden_sizes": [16]}}, TRAINER, [0],
                             tmp_path / "mlp", simple_baseline=["rf", "hgb"], simple_baseline_overrides=CONSTANT)  # fmt: skip
    block = result["comparison"]
    assert result["simple_baselines"]["rf"]["val_score"] == result["simple_baselines"]["hgb"]["val_score"] == 0.0
    assert block["simple_baseline"] == "rf" and block["validation_tie"] == ["rf", "hgb"]
    assert "rf (tied on validation: rf 0.000, hgb 0.000, equal to 3 decimals; the first listed" in block["sentence"]
    assert "strongest" not in block["sentence"]
    text = comparison_text(block)
    assert "rf (simple baseline, tied best by validation)" in text and "hgb (simple baseline, tied best" in text

    # The model tied with another simple baseline is not "the strongest": the sentence says the tie
    # and gives the test difference between the two.
    params = CONSTANT["rf"]
    result = run_recognition(lex_dataset, {"name": "rf", "params": params}, TRAINER, [0], tmp_path / "rf",
                             simple_baseline=["rf", "hgb"], simple_baseline_overrides=CONSTANT)  # fmt: skip
    block = result["comparison"]
    assert block["verdict"] == "model_is_simple_baseline" and block["validation_tie"] == ["rf", "hgb"]
    assert block["sentence"].startswith("rf and hgb are tied on validation: rf 0.000, hgb 0.000, equal to 3 decimals;")
    assert "neither is the strongest simple baseline" in block["sentence"] and "on test rf minus hgb is" in block["sentence"]
    assert "rf (this run, tied best simple model by validation)" in comparison_text(block)


def test_the_tie_rule_rounding_or_the_paired_interval():
    assert validation_tie([0.5121], [0.5124])[0]  # equal at the 3 decimals the report prints
    assert not validation_tie([0.512], [0.507])[0]  # one unit: no spread, so a gap is a gap
    # Several units: a tie while the 95% interval of the paired difference includes 0.
    tie, why = validation_tie([0.50, 0.62, 0.41, 0.55], [0.52, 0.58, 0.45, 0.50])
    assert tie and "includes 0" in why and "4 paired units" in why
    assert not validation_tie([0.50, 0.62, 0.41, 0.55], [0.45, 0.57, 0.37, 0.49])[0]  # always ahead: resolved


def test_a_small_test_set_gets_a_caution(lex_dataset, tmp_path):
    split = {"name": "phoneme", "repeats": 2, "test_fraction": 0.05}
    result = run_recognition(lex_dataset, {"name": "logreg"}, TRAINER, [0], tmp_path, split=split, simple_baseline=None)
    clips = result["comparison"]["test_clips"]
    assert min(clips) < SMALL_TEST_SET
    caution = next(c for c in result["comparison"]["cautions"] if "test clips" in c)
    assert caution.startswith(f"caution: {min(clips)} test clips") and f"fewer than {SMALL_TEST_SET}" in caution
    assert f"one clip is {100 / min(clips):.1f} points of accuracy" in caution
    assert comparison_text(result["comparison"]).splitlines()[-1] == caution

    # The default share of the same data (42 clips) gets none.
    full = run_recognition(lex_dataset, {"name": "logreg"}, TRAINER, [0], tmp_path / "full", simple_baseline=None)
    assert full["split_sizes"]["test"] >= SMALL_TEST_SET and full["comparison"]["cautions"] == []


def test_the_shipped_logreg_search_space_cannot_draw_every_frame():
    space = yaml.safe_load((ROOT / "sweeps" / "classifier_logreg.yaml").read_text())["hydra"]["sweeper"]["params"]
    choices = space["classifier.params.pooling"]
    assert choices.startswith("choice(") and "none" not in choices
    assert {"mean_std", "summary"} == {c.strip() for c in choices[len("choice("):-1].split(",")}
