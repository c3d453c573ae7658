"""conf/ is the one source of the recognition settings: its files equal the code's defaults."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from aslexp.recognition.models import DEFAULT_PARAMS
from aslexp.recognition.train import TrainerConfig

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("name", sorted(DEFAULT_PARAMS))
def test_classifier_files_list_every_default(name):
    raw = yaml.safe_load((ROOT / "conf" / "classifier" / f"{name}.yaml").read_text())
    assert raw["name"] == name and raw["params"] == DEFAULT_PARAMS[name]


def test_trainer_default_file_is_the_config_default():
    raw = yaml.safe_load((ROOT / "conf" / "trainer" / "default.yaml").read_text())
    assert TrainerConfig.parse(raw) == TrainerConfig()
