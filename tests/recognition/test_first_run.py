"""The first run tells the truth fast: the default `aslexp recognize` composes with the
classifier chosen by measurement (docs/recognition.md, "The default run"), and every run ends with
its test metrics beside the strongest simple baseline and the majority class on the same splits,
in metrics.json (``comparison``) and on the terminal."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import job_process
from hydra import compose, initialize_config_dir

from aslexp.recognition import experiment
from aslexp.recognition.comparison import validation_tie
from aslexp.recognition.experiment import run_recognition
from aslexp.recognition.models import DEFAULT_PARAMS
from aslexp.recognition.report import comparison_text

CONF = Path(__file__).resolve().parents[2] / "conf"
DEFAULT_CLASSIFIER = "logreg"  # chosen by measurement over 10 phoneme splits (docs/recognition.md)
TRAINER = {"max_epochs": 2, "batch_size": 32, "num_threads": 1}
SPLIT = {"name": "phoneme", "repeats": 2}  # two seeded splits of the real sign-type set: split is the unit


def _compose(*overrides: str):
    with initialize_config_dir(str(CONF), version_base="1.3"):
        return compose("recognize", overrides=list(overrides))


def test_the_default_composes_with_the_chosen_classifier_and_the_deep_model_is_one_override_away():
    cfg = _compose()
    assert cfg.classifier.name == DEFAULT_CLASSIFIER
    assert dict(cfg.classifier.params) == DEFAULT_PARAMS[DEFAULT_CLASSIFIER]
    assert (cfg.property.name, cfg.split.name, cfg.trainer.max_epochs) == ("sign_type", "phoneme", 50)
    assert list(cfg.simple_baseline) == ["logreg", "rf"]
    deep = _compose("classifier=stgcn")
    assert deep.classifier.name == "stgcn" and dict(deep.classifier.params) == DEFAULT_PARAMS["stgcn"]
    small = _compose("classifier=stgcn_small")
    assert small.classifier.name == "stgcn" and set(small.classifier.params) == set(DEFAULT_PARAMS["stgcn"])
    assert _compose("simple_baseline=null").simple_baseline is None
    assert _compose("simple_baseline=rf").simple_baseline == "rf"


def _rows(result: dict) -> dict[str, dict]:
    return {row["role"]: row for row in result["comparison"]["rows"]}


def test_a_run_records_and_prints_the_model_beside_the_simple_baseline_and_the_majority_class(lex_dataset, tmp_path):
    # A torch model beside logreg (seconds; the job's default list also has rf, 500 trees).
    result = run_recognition(lex_dataset, {"name": "mlp", "params": {"hidden_sizes": [16]}}, TRAINER, [0], tmp_path,
                             split=SPLIT, simple_baseline="logreg")  # fmt: skip
    json.dumps(result)
    block = result["comparison"]
    rows = _rows(result)
    assert [row["role"] for row in block["rows"]] == ["model", "simple_baseline", "chance_baseline"]
    assert (rows["model"]["name"], rows["simple_baseline"]["name"]) == ("mlp", "logreg")
    assert rows["chance_baseline"]["name"] == result["baseline"]["name"] == "majority"
    assert block["unit"] == "split" and block["n"] == 2 and block["split_seeds"] == [0, 1]
    # The rows are the run's own numbers on the same two splits.
    assert rows["model"]["test"]["mcc"]["mean"] == pytest.approx(result["test"]["mcc"])
    simple = result["simple_baselines"]["logreg"]
    assert not simple["same_as_model"] and len(simple["test_per_split"]) == 2
    assert rows["simple_baseline"]["test"]["balanced_accuracy"]["mean"] == pytest.approx(simple["test"]["balanced_accuracy"])
    assert rows["chance_baseline"]["test"]["mcc"]["mean"] == 0.0
    difference = block["model_minus_simple_baseline"]["mcc"]["diff"]["mean"]
    assert difference == pytest.approx(result["test"]["mcc"] - simple["test"]["mcc"])
    assert block["verdict"] == ("above" if difference > 0 else "below" if difference < 0 else "equal")
    assert ("adds" in block["sentence"]) == (difference >= 0) and "logreg" in block["sentence"]
    assert "2 paired splits" in block["sentence"]

    text = comparison_text(block, "sign_type", "phoneme").splitlines()
    assert text[0].startswith("sign_type, phoneme split: test, mean ± std over 2 splits")
    assert [line.split()[0] for line in text[2:5]] == ["mlp", "logreg", "majority"]
    assert "(simple baseline)" in text[3] and "(chance)" in text[4] and " ± " in text[2]
    assert text[-1] == block["sentence"]


def test_simple_baseline_null_skips_it(lex_dataset, tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(experiment, "_simple_baseline_runs", lambda *a, **k: calls.append(a) or ([], []))
    result = run_recognition(lex_dataset, {"name": "logreg"}, TRAINER, [0], tmp_path, simple_baseline=None)
    assert calls == [] and result["simple_baselines"] == {}
    block = result["comparison"]
    assert [row["role"] for row in block["rows"]] == ["model", "chance_baseline"]
    assert block["verdict"] == "no_simple_baseline" and "simple_baseline=null" in block["sentence"]
    assert block["unit"] == "seed" and "one split (seed 0)" in comparison_text(block)


def test_the_model_that_is_the_simple_baseline_is_not_run_twice(lex_dataset, tmp_path, monkeypatch):
    calls = []
    real = experiment._simple_baseline_runs
    monkeypatch.setattr(experiment, "_simple_baseline_runs", lambda view, name, *a: calls.append(name) or real(view, name, *a))
    result = run_recognition(lex_dataset, {"name": "logreg"}, TRAINER, [0], tmp_path, split=SPLIT,
                             simple_baseline="logreg")  # fmt: skip
    assert calls == []
    simple = result["simple_baselines"]["logreg"]
    assert simple["same_as_model"] and simple["test_per_split"] == result["test_per_split"]
    block = result["comparison"]
    assert block["verdict"] == "model_is_simple_baseline" and "logreg is the simple baseline itself" in block["sentence"]
    lines = comparison_text(block).splitlines()
    assert [line.split()[0] for line in lines[2:4]] == ["logreg", "majority"] and len(lines) == 5
    assert "(this run = the simple baseline)" in lines[2]

    # In a list, only the others run; the model is the reference when its validation score is the best.
    result = run_recognition(lex_dataset, {"name": "logreg"}, TRAINER, [0], tmp_path / "list",
                             simple_baseline=["logreg", "svm"])  # fmt: skip
    assert calls == ["svm"]
    simple = result["simple_baselines"]
    model_best = simple["logreg"]["val_score"] >= simple["svm"]["val_score"]
    assert (result["comparison"]["verdict"] == "model_is_simple_baseline") == model_best
    assert [row["name"] for row in result["comparison"]["rows"]] == ["logreg", "svm", "majority"]

    # The same name with other settings is another model: it runs, and the sentence says which.
    result = run_recognition(lex_dataset, {"name": "logreg", "params": {"C": 0.01}}, TRAINER, [0], tmp_path / "c",
                             simple_baseline="logreg")  # fmt: skip
    assert calls == ["svm", "logreg"] and not result["simple_baselines"]["logreg"]["same_as_model"]
    assert "logreg at its defaults" in result["comparison"]["sentence"]


def test_of_several_simple_baselines_validation_chooses_never_test(lex_dataset, tmp_path):
    result = run_recognition(lex_dataset, {"name": "mlp", "params": {"hidden_sizes": [16]}}, TRAINER, [0], tmp_path,
                             split=SPLIT, simple_baseline=["logreg", "svm"])  # fmt: skip
    simple = result["simple_baselines"]
    chosen = max(simple, key=lambda name: simple[name]["val_score"])
    block = result["comparison"]
    assert block["simple_baseline"] == chosen and block["simple_baseline_selected_by"] == "validation mcc"
    names = [row["name"] for row in block["rows"]]
    assert names == ["mlp", chosen, ({"logreg", "svm"} - {chosen}).pop(), "majority"]
    assert [row.get("reference") for row in block["rows"][1:3]] == [True, False]
    # Two splits resolve little: a tie by the rule is said as one, else the best is named.
    tie, _ = validation_tie(*(simple[name]["val_per_unit"] for name in (chosen, names[2])))
    assert block["validation_tie"] == ([chosen, names[2]] if tie else [])
    if tie:
        assert f"{chosen} (tied on validation: " in block["sentence"]
        assert f"{chosen} (simple baseline, tied best by validation)" in comparison_text(block)
    else:
        assert f"{chosen} (the strongest simple baseline by validation)" in block["sentence"]
        assert f"{chosen} (simple baseline, best by validation)" in comparison_text(block)


@pytest.mark.parametrize("value, message", [("majority", "chance baselines"), ("forest", "simple_baseline=forest")])
def test_a_bad_simple_baseline_is_refused_before_training(lex_dataset, tmp_path, value, message):
    with pytest.raises(ValueError, match=message):
        run_recognition(lex_dataset, {"name": "logreg"}, TRAINER, [0], tmp_path, simple_baseline=value)
    assert not (tmp_path / "predictions.csv").exists()


def test_the_default_job_ends_with_the_comparison(run_cli, tmp_path):
    """The README's first command as it is (the real data, T = 150): seconds with the default."""
    run_dir = tmp_path / "run"
    proc = run_cli("recognize", f"hydra.run.dir={run_dir}")
    lines = (proc.stdout + proc.stderr).splitlines()
    start = next(i for i, line in enumerate(lines) if "logreg vs the baselines on the same split(s):" in line)
    assert lines[start + 1] == "sign_type, phoneme split: test, one split (seed 0), 42 test clips"
    assert lines[start + 2].split() == ["model", "test", "MCC", "balanced", "acc."]
    # The model is one of the two simple baselines: three rows, whichever wins validation.
    assert [line.split()[0] for line in lines[start + 3:start + 6]] == ["logreg", "rf", "majority"]
    sentence = lines[start + 6]
    assert sentence.startswith("logreg ")
    assert "over the majority class" in sentence or "rf (the strongest simple baseline by validation)" in sentence
    assert "recognize completed: run folder" in lines[start + 7]  # the job's last word
    metrics = json.loads((run_dir / "metrics.json").read_text())
    comparison = metrics["comparison"]
    assert metrics["classifier"] == "logreg" and comparison["candidates"] == ["logreg", "rf"]
    assert comparison["sentence"] == sentence and comparison["chance_baseline"] == "majority"
    assert [row["name"] for row in comparison["rows"]] == ["logreg", "rf", "majority"]
    assert not metrics["simple_baselines"]["rf"]["same_as_model"] and metrics["simple_baselines"]["logreg"]["same_as_model"]


def test_the_job_refuses_a_bad_simple_baseline_in_one_line(tmp_path):
    import os
    import sys

    root = Path(__file__).resolve().parents[2]
    env = dict(os.environ, ASLEXP_CACHE_DIR=str(tmp_path / "cache"), MPLBACKEND="Agg")
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", "recognize", "simple_baseline=[rf,forest]",
                           f"hydra.run.dir={tmp_path / 'run'}"], cwd=root, env=env, capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "simple_baseline=forest: unknown classifier 'forest'" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "cache").exists()  # refused before the dataset was built


def test_a_simple_baselines_params_are_overridden_by_name_and_a_stray_or_unknown_one_is_one_line():
    from aslexp.errors import ConfigError
    from aslexp.recognition.experiment import simple_baseline_params

    params = simple_baseline_params(["logreg", "rf"], {"rf": {"n_estimators": 20}})
    assert params["rf"] == {**DEFAULT_PARAMS["rf"], "n_estimators": 20} and params["logreg"] == DEFAULT_PARAMS["logreg"]
    assert simple_baseline_params(None) == {}
    with pytest.raises(ConfigError, match=r"simple_baseline_params.rf: rf is not a simple baseline of this run"):
        simple_baseline_params("logreg", {"rf": {"n_estimators": 20}})
    with pytest.raises(ConfigError, match=r"simple_baseline_params.rf: classifier 'rf': unknown params \['trees'\]"):
        simple_baseline_params(["rf"], {"rf": {"trees": 20}})
    assert _compose("+simple_baseline_params.rf.n_estimators=20").simple_baseline_params.rf.n_estimators == 20
