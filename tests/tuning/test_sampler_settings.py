"""Every sampler setting a sweep draws with is recorded, Optuna's own defaults included: in the
study, in each trial, in each trial's run.json and in sweep.json. A later Optuna can change a default (Optuna 5's TPE is
multivariate unless told otherwise), and a seed then no longer repeats a study's sequence; a
resume with other settings says what changed. Real quadratic sweeps, real journal storage."""

from __future__ import annotations

import json
from pathlib import Path

import optuna
import pytest
from sweep_helpers import load_study, run_sweep

from aslexp.tuning.algorithms import ATTR_SAMPLER, SAMPLERS, sampler_settings


def test_the_study_each_trial_and_sweep_json_record_the_samplers_settings(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=2")  # conf/hydra/sweeper/sampler/tpe.yaml, seed 7
    study = load_study(sweep)
    recorded = study.user_attrs[ATTR_SAMPLER]
    assert recorded["class"] == "TPESampler" and recorded["optuna"] == optuna.__version__
    assert recorded["seed"] == 7 and recorded["seed_per_trial"] is True
    settings = recorded["settings"]
    # what tpe.yaml sets, and what it leaves to Optuna, decided
    assert (settings["multivariate"], settings["constant_liar"], settings["n_startup_trials"]) == (False, True, 10)
    assert settings["n_ei_candidates"] == optuna.samplers.TPESampler()._n_ei_candidates
    assert [t.user_attrs[ATTR_SAMPLER] for t in study.trials] == [recorded, recorded]
    assert json.loads((sweep / "sweep.json").read_text())["sampler_settings"] == recorded
    for number in (0, 1):  # and each trial's run.json
        run = json.loads((sweep / str(number) / "run.json").read_text())
        assert run["trial"] == {"study_name": "quadratic", "number": number, "sampler": recorded}


def test_a_resume_with_other_settings_says_what_changed_and_each_trial_keeps_its_own(tmp_path: Path) -> None:
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=2")
    # The key removed: Optuna's own default decides, as for a config written for Optuna 4.
    resumed = run_sweep(sweep, "hydra.sweeper.n_trials=3", "~hydra.sweeper.sampler.multivariate")
    assert "was sampled with other settings before (multivariate: False -> True)" in resumed.stdout + resumed.stderr
    study = load_study(sweep)
    drawn = [t.user_attrs[ATTR_SAMPLER]["settings"]["multivariate"] for t in study.trials]
    assert drawn == [False, False, True] and study.user_attrs[ATTR_SAMPLER]["settings"]["multivariate"] is True
    again = run_sweep(sweep, "hydra.sweeper.n_trials=3", "~hydra.sweeper.sampler.multivariate")
    assert "other settings before" not in again.stdout + again.stderr  # the same settings: no warning


@pytest.mark.parametrize("name", sorted(SAMPLERS))
def test_every_sampler_s_settings_are_plain_json(name: str) -> None:
    study = optuna.create_study()
    recorded = sampler_settings({"name": name, "seed": 3}, study)
    assert recorded["class"] == SAMPLERS[name] and recorded["settings"]["seed"] == 3
    assert json.loads(json.dumps(recorded)) == recorded
