"""conf/ is the one source of the recognition settings: its files equal the code's defaults, and the
benchmarks' Hydra-free reader composes them as Hydra does."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest
import yaml

from aslexp.recognition.models import DEFAULT_PARAMS
from aslexp.recognition.train import TrainerConfig

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "bench"))
import recognition_conf  # noqa: E402  (bench/ is not a package)


@pytest.mark.parametrize("name", sorted(DEFAULT_PARAMS))
def test_classifier_files_list_every_default(name):
    raw = yaml.safe_load((ROOT / "conf" / "classifier" / f"{name}.yaml").read_text())
    assert raw["name"] == name and raw["params"] == DEFAULT_PARAMS[name]


def test_trainer_default_file_is_the_config_default():
    raw = yaml.safe_load((ROOT / "conf" / "trainer" / "default.yaml").read_text())
    assert TrainerConfig.from_dict(raw) == TrainerConfig()


def test_the_bench_reader_matches_pyyaml_without_it(monkeypatch):
    files = sorted((ROOT / "conf").glob("trainer/*.yaml")) + sorted((ROOT / "conf").glob("classifier/*.yaml"))
    files += sorted((ROOT / "conf").glob("experiment/*.yaml")) + sorted((ROOT / "conf").glob("split/*.yaml"))
    expected = {path: yaml.safe_load(path.read_text()) for path in files}
    monkeypatch.setitem(sys.modules, "yaml", None)  # as on a node without PyYAML
    for path in files:
        assert recognition_conf.read_yaml(path) == expected[path], path


def test_the_bench_composes_overlays_as_hydra_does():
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    for experiment, classifier, prop in (("thesis_ch4", "slgcn", "sign_type"), ("thesis_ch3", "gru_thesis_ch3", "sign_type"),
                                         ("recognition_table", "slgcn", "flexion"), ("chapter3_cv5", "rf", "movement")):  # fmt: skip
        with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
            cfg = compose("recognize", [f"experiment={experiment}", f"classifier={classifier}", f"property={prop}"])
        hydra = OmegaConf.to_container(cfg, resolve=True)
        plan = recognition_conf.experiment_plan(experiment)
        model, params, preset, batch = recognition_conf.resolve_classifier(classifier, prop)
        trainer = recognition_conf.trainer_for(plan, preset, batch)
        assert (model, params) == (hydra["classifier"]["name"], hydra["classifier"]["params"]), experiment
        assert TrainerConfig.from_dict(trainer) == TrainerConfig.from_dict(hydra["trainer"]), experiment
        for key in ("lexicon", "num_frames", "padding"):
            assert plan["data"][key] == hydra["data"][key], (experiment, key)
        assert plan["pose"]["subset"] == hydra["pose"]["subset"] and plan["n_seeds"] == hydra["n_seeds"]
        assert {**hydra["split"], **plan["split_values"]} == hydra["split"]
