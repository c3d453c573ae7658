"""`aslexp recognize` end to end on the real 291-clip keypoint set (tiny budgets)."""

from __future__ import annotations

import json
import math
import shutil

import numpy as np
import pytest
import yaml
from platform_helpers import error_lines, folder_hashes

FAST = ["experiment=debug", "classifier=logreg", "classifier.params.max_iter=200"]


@pytest.fixture(scope="module")
def finished_run(aslexp, tmp_path_factory):
    """A finished FAST run (seed 3): its folder is checked whole, and a copy of it is run over (one job
    for both: tests/conftest.py runs the tests of a module fixture on one worker)."""
    run_dir = tmp_path_factory.mktemp("recognize_job") / "run"
    aslexp("recognize", *FAST, "seed=3", f"hydra.run.dir={run_dir}")
    return run_dir


def test_single_run_writes_its_whole_directory(finished_run):
    run_dir = finished_run
    for name in ("run.json", "metrics.json", "per_class.csv", "predictions.csv",
                 "confusion_matrix.png", "learning_curves.png", "recognize.log",
                 ".hydra/config.yaml", ".hydra/overrides.yaml", ".hydra/hydra.yaml"):
        assert (run_dir / name).is_file(), name
    assert any(run_dir.glob("model.*")), "model checkpoint"

    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "completed" and info["job"] == "recognize"
    assert info["seed"] == 3 and "seed=3" in info["command"]
    assert set(info["git"]) == {"commit", "dirty"}
    assert info["versions"]["torch"].startswith("2.13.0")
    assert info["main_metric"]["name"] == "val_mcc"

    metrics = json.loads((run_dir / "metrics.json").read_text())
    test = metrics["test"]
    for key in ("accuracy", "balanced_accuracy", "precision_micro", "recall_micro", "f1_micro",
                "precision_macro", "recall_macro", "f1_macro", "mcc"):
        assert math.isfinite(test[key]), key
    run = metrics["test_per_seed"][0]  # a run's own Wald interval (never averaged over runs)
    assert run["accuracy_ci_low"] <= run["accuracy"] <= run["accuracy_ci_high"]
    assert metrics["context"]["property"] == "sign_type"
    assert metrics["context"]["num_clips"] == 283  # 285 clips in ASL-LEX 2.0, 2 in a rare class
    assert metrics["baseline"]["name"] in ("majority", "stratified")
    overrides = yaml.safe_load((run_dir / ".hydra/overrides.yaml").read_text())
    assert "seed=3" in overrides


def test_a_refused_rerun_leaves_the_finished_run_byte_identical(aslexp, finished_run, tmp_path):
    """The refusal comes before Hydra writes .hydra/*.yaml or the log."""
    run_dir = tmp_path / "run"
    shutil.copytree(finished_run, run_dir)  # the run as it finished, in a folder of this test's
    before = folder_hashes(run_dir)
    assert ".hydra/config.yaml" in before and "recognize.log" in before
    again = aslexp("recognize", "experiment=debug", "classifier=majority", "property=flexion",
                   "seed=5", f"hydra.run.dir={run_dir}", check=False)
    assert again.returncode == 2
    assert folder_hashes(run_dir) == before  # config, overrides, log, run.json: not a byte changed
    lines = error_lines(again.stderr)
    assert len(lines) == 1 and "holds a finished run" in lines[0] and "nothing was changed" in lines[0]
    assert "add overwrite=true" in lines[0] and "+overwrite" not in lines[0]
    assert "Traceback" not in again.stderr + again.stdout


def test_multirun_goes_on_past_a_failing_job_and_reports(aslexp, tmp_path):
    sweep_dir = tmp_path / "sweep"
    # mlp does not accept C: that job fails, is recorded as failed, and the others complete.
    aslexp("recognize", "-m", "experiment=debug", "classifier=logreg,mlp",
           "++classifier.params.C=0.5", "property=sign_type,movement", "trainer.max_epochs=1",
           f"hydra.sweep.dir={sweep_dir}")
    states = {}
    for run_file in sweep_dir.rglob("run.json"):
        info = json.loads(run_file.read_text())
        cfg = yaml.safe_load((run_file.parent / ".hydra/config.yaml").read_text())
        states[(cfg["classifier"]["name"], cfg["property"]["name"])] = info
    assert {k: v["status"] for k, v in states.items()} == {
        ("logreg", "sign_type"): "completed", ("logreg", "movement"): "completed",
        ("mlp", "sign_type"): "failed", ("mlp", "movement"): "failed",
    }
    assert "unknown params ['C']" in states[("mlp", "movement")]["error"]

    out = aslexp("report", str(sweep_dir))
    assert "| phoneme | logreg |" in out.stdout and "| phoneme | baseline |" in out.stdout
    for name in ("table.md", "table.csv", "best_vs_baseline.md", "best_vs_baseline.png", "agreement.json"):
        assert (sweep_dir / name).is_file(), name
    agreement = json.loads((sweep_dir / "agreement.json").read_text())
    rates = agreement["pairwise_error_overlap"]["phoneme/logreg"]["rate"]
    assert set(rates) == {"sign_type", "movement"}


def test_optuna_sweep_keeps_its_study_and_trial_directories(aslexp, tmp_path):
    sweep_dir = tmp_path / "optuna"
    # The shipped space with pooling=none left out (it fits on every frame and takes minutes).
    aslexp("recognize", "-m", "+sweeps=classifier_logreg", "experiment=debug",
           "classifier.params.max_iter=200", "hydra.sweeper.n_trials=3",
           "++hydra.sweeper.params={classifier.params.C:'tag(log, interval(1e-4, 1e2))',"
           "classifier.params.pooling:'choice(mean_std, summary)'}", f"hydra.sweep.dir={sweep_dir}")
    storage = [p for p in sweep_dir.iterdir() if p.suffix in (".journal", ".db")]
    assert storage, f"no study storage in {sorted(p.name for p in sweep_dir.iterdir())}"
    trial_runs = [json.loads(p.read_text()) for p in sweep_dir.rglob("run.json")]
    assert len(trial_runs) == 3
    assert all(r["status"] == "completed" for r in trial_runs)

    import optuna

    journal = sweep_dir / "optuna.journal"
    if journal.exists():
        from optuna.storages.journal import JournalFileBackend, JournalStorage

        storage_obj = JournalStorage(JournalFileBackend(str(journal)))
    else:
        storage_obj = f"sqlite:///{sweep_dir / 'optuna.db'}"
    summaries = optuna.get_all_study_summaries(storage_obj)
    assert len(summaries) == 1
    study = optuna.load_study(study_name=summaries[0].study_name, storage=storage_obj)
    finished = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    assert len(finished) == 3
    assert all(-1.0 <= t.value <= 1.0 for t in finished)
    assert {"classifier.params.C", "classifier.params.pooling"} <= set(finished[0].params)
    assert {t.params["classifier.params.pooling"] for t in finished} <= {"mean_std", "summary"}

    # `aslexp report` on the sweep folder: one table row per model, property and
    # split, the trial with the best validation objective, named in a log line.
    best = max(finished, key=lambda t: t.value)
    out = aslexp("report", str(sweep_dir), "--out", str(tmp_path / "report"))
    assert "| phoneme | logreg |" in out.stdout and "1 runs (the best by validation of 3)" in out.stdout
    best_dir = next(p.parent for p in sweep_dir.rglob("run.json")
                    if json.loads(p.read_text())["main_metric"]["value"] == best.value)
    assert f"3 runs (e.g. a sweep's trials); the tables show the best by validation val_mcc: {best_dir}" in out.stderr
    # ... and with one trial's metrics.json emptied: named in one warning line, the others reported.
    emptied = next(p.parent for p in sweep_dir.rglob("run.json") if p.parent != best_dir) / "metrics.json"
    emptied.write_text("")
    out = aslexp("report", str(sweep_dir), "--out", str(tmp_path / "report2"))
    assert [ln for ln in out.stderr.splitlines() if str(emptied) in ln] == [f"warning: {emptied}: empty file; run skipped"]
    assert "1 runs (the best by validation of 2)" in out.stdout and "Traceback" not in out.stderr


def test_simple_baselines_are_measured_once_and_reused_with_the_same_numbers(aslexp, tmp_path):
    """Two trials of a sweep over the model's C: the second reads the forest's numbers the first
    measured; a run that measures its own (simple_baseline_cache=null) gets the same numbers."""
    cache, sweep, fresh = tmp_path / "baselines", tmp_path / "sweep", tmp_path / "fresh"
    small = [*FAST, "++simple_baseline_params.rf.n_estimators=20", f"simple_baseline_cache={cache}"]
    ran = aslexp("recognize", "-m", *small, "classifier.params.C=0.1,0.2", f"hydra.sweep.dir={sweep}")
    first, second = (json.loads(next(sweep.glob(f"{k}_*/metrics.json")).read_text()) for k in "01")
    assert first["simple_baselines"]["rf"]["splits_from_cache"] == 0
    assert second["simple_baselines"]["rf"]["splits_from_cache"] == 1
    assert (ran.stdout + ran.stderr).count("measured by an earlier run") == 2  # rf and logreg (C differs from it)
    assert second["simple_baselines"]["rf"]["test"] == first["simple_baselines"]["rf"]["test"]
    assert {p.name.split("-")[0] for p in cache.iterdir()} == {"rf", "logreg"}
    aslexp("recognize", *small[:-1], "classifier.params.C=0.2", "simple_baseline_cache=null", f"hydra.run.dir={fresh}")
    own = json.loads((fresh / "metrics.json").read_text())
    assert own["simple_baselines"]["rf"]["splits_from_cache"] == 0
    for key in ("test", "val_score", "val_mcc", "test_per_split"):
        assert own["simple_baselines"]["rf"][key] == second["simple_baselines"]["rf"][key], key
    assert own["comparison"] == second["comparison"]
    # Another forest is another key: measured, not read.
    other = tmp_path / "other"
    aslexp("recognize", *FAST, "++simple_baseline_params.rf.n_estimators=21", f"simple_baseline_cache={cache}",
           f"hydra.run.dir={other}")
    assert json.loads((other / "metrics.json").read_text())["simple_baselines"]["rf"]["splits_from_cache"] == 0


def test_a_baseline_cache_that_cannot_be_written_or_read_costs_time_only(tmp_path, caplog):
    from aslexp.recognition import baseline_cache

    measured = []

    def measure():
        measured.append(1)
        return [{"score": np.float64(0.25), "mcc": 0.5}], [{"mcc": 0.5, "confusion_matrix": np.eye(2, dtype=int)}]

    blocked = tmp_path / "a_file"
    blocked.write_text("not a folder")
    val, tests, reused = baseline_cache.cached(blocked, "k" * 64, "rf", measure)
    assert not reused and val == [{"score": 0.25, "mcc": 0.5}] and tests[0]["confusion_matrix"] == [[1, 0], [0, 1]]
    assert "not written" in caplog.text
    folder = tmp_path / "cache"
    baseline_cache.cached(folder, "k" * 64, "rf", measure)
    [stored] = folder.iterdir()
    assert baseline_cache.cached(folder, "k" * 64, "rf", measure) == (val, tests, True) and len(measured) == 2
    stored.write_text("{damaged")
    assert baseline_cache.cached(folder, "k" * 64, "rf", measure) == (val, tests, False) and len(measured) == 3
    assert "unreadable" in caplog.text and json.loads(stored.read_text())["val"] == val
