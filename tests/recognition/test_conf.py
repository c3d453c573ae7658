"""conf/ is the one source of the recognition settings: a built-in classifier's defaults are its
conf/classifier file's params (the code declares none), and the trainer's file is the code's default."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

from aslexp.recognition import registry
from aslexp.recognition.models import DEFAULT_PARAMS, build_classifier
from aslexp.recognition.train import TrainerConfig

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", registry.BUILT_IN)
def test_a_built_in_classifiers_defaults_live_in_its_conf_file_only(name):
    entry = registry.get_classifier(name)
    assert entry.declared is None  # the registration holds no second copy
    raw = yaml.safe_load((ROOT / "conf" / "classifier" / f"{name}.yaml").read_text())
    assert raw["name"] == name and dict(DEFAULT_PARAMS[name]) == raw["params"]


def test_editing_the_conf_file_changes_the_default_and_the_model(tmp_path):
    conf = tmp_path / "conf"
    shutil.copytree(ROOT / "conf", conf, ignore=shutil.ignore_patterns("sweeps"))
    path = conf / "classifier" / "logreg.yaml"
    path.write_text(path.read_text().replace("C: 1.0", "C: 0.25"))
    params = registry.conf_defaults("logreg", conf_dir=conf)
    assert params == {**DEFAULT_PARAMS["logreg"], "C": 0.25}
    assert build_classifier("logreg", params, 3, 8, 5, 4).C == 0.25  # the builder takes what the config gives


def test_trainer_default_file_is_the_config_default():
    raw = yaml.safe_load((ROOT / "conf" / "trainer" / "default.yaml").read_text())
    assert TrainerConfig.parse(raw) == TrainerConfig()
