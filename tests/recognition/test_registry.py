"""A classifier is a module plus a YAML: one registered from the tests trains,
is evaluated and reported by `aslexp recognize` with no edit to aslexp."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

import pytest
import job_process

from aslexp.recognition import registry
from aslexp.recognition.models import DEFAULT_PARAMS, build_classifier

HERE = Path(__file__).resolve().parent


@pytest.fixture
def tiny(monkeypatch):
    monkeypatch.syspath_prepend(str(HERE))
    registry.unregister_classifier("tiny_linear")
    sys.modules.pop("tiny_classifier", None)
    yield
    registry.unregister_classifier("tiny_linear")
    sys.modules.pop("tiny_classifier", None)


def test_a_registered_classifier_builds_by_name_with_its_own_params(tiny):
    params = registry.resolve_params("tiny_linear", {"scale": 2.0}, module="tiny_classifier")
    assert params == {"scale": 2.0} and "tiny_linear" in registry.classifier_names()
    assert registry.classifier_names()[:3] == ("majority", "stratified", "logreg")  # the built-ins first
    model = build_classifier("tiny_linear", params, 3, 8, 5, 4)
    assert type(model).__name__ == "TorchClassifier" and model.module.scale == 2.0
    assert DEFAULT_PARAMS["tiny_linear"] == {"scale": 1.0}
    with pytest.raises(ValueError, match=r"unknown params \['depth'\]; accepted: \['scale'\]"):
        registry.resolve_params("tiny_linear", {"depth": 3})
    with pytest.raises(ValueError, match="unknown classifier 'warp'.*classifier.module"):
        registry.resolve_params("warp", {})
    with pytest.raises(ValueError, match="already registered"):
        registry.register_classifier("tiny_linear")(lambda spec: None)


def test_recognize_trains_and_reports_a_classifier_from_a_yaml_and_a_module(tmp_path):
    conf = tmp_path / "conf" / "classifier"
    conf.mkdir(parents=True)
    (conf / "tiny_linear.yaml").write_text("name: tiny_linear\nmodule: tiny_classifier\nparams:\n  scale: 1.0\n")
    run = tmp_path / "run"
    env = {**os.environ, "MPLBACKEND": "Agg",
           "PYTHONPATH": os.pathsep.join([str(HERE), os.environ.get("PYTHONPATH", "")])}
    done = job_process.run([sys.executable, "-m", "aslexp.cli", "recognize", "--config-dir", str(tmp_path / "conf"),
                           "experiment=debug", "classifier=tiny_linear", f"hydra.run.dir={run}"],
                          capture_output=True, text=True, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["classifier"] == "tiny_linear" and metrics["params"] == {"scale": 1.0}
    assert 0.0 <= metrics["test"]["accuracy"] <= 1.0 and metrics["num_parameters"] > 0
