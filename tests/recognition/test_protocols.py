"""The thesis' protocols end to end through the real CLI on a tiny slice (seconds), and the report
laying them out as the thesis' tables."""

from __future__ import annotations

import json

from omegaconf import OmegaConf


def _runs(sweep_dir):
    """(model, property, split) -> (resolved config, metrics.json) of every run of a multirun."""
    runs = {}
    for metrics_file in sweep_dir.rglob("metrics.json"):
        cfg = OmegaConf.to_container(OmegaConf.load(metrics_file.parent / ".hydra" / "config.yaml"), resolve=True)
        runs[(cfg["classifier"]["name"], cfg["property"]["name"], cfg["split"]["name"])] = (
            cfg, json.loads(metrics_file.read_text()))
    return runs


# One simple baseline (logreg) where the job's default runs two: the 500-tree rf beside logreg is most of
# these slices' time (fitted on every fold of every seed) and nothing here is about which baseline is run.
ONE_SIMPLE_BASELINE = "simple_baseline=logreg"


def test_thesis_ch3_protocol_on_a_tiny_slice(run_cli, tmp_path):
    sweep = tmp_path / "ch3"
    run_cli("recognize", "experiment=thesis_ch3", "classifier=logreg_thesis_ch3,mlp_thesis_ch3", "n_seeds=2",
            "property=major_location", "trainer.max_epochs=2", "data.num_frames=32", ONE_SIMPLE_BASELINE,
            f"hydra.sweep.dir={sweep}")
    runs = _runs(sweep)
    assert {(m, p) for m, p, _ in runs} == {("logreg", "major_location"), ("mlp", "major_location")}
    cfg, metrics = runs[("logreg", "major_location", "cv5")]
    # Table 3.3's logistic regression for major location, the ch. 3 data and training.
    assert cfg["classifier"]["params"] == {"C": 3.16e-3, "max_iter": 100, "solver": "lbfgs", "multi_class": "ovr",
                                           "pooling": "none", "standardize": False}  # fmt: skip
    assert cfg["data"]["lexicon"] == "asllex1" and cfg["data"]["padding"] == "zero"
    assert cfg["trainer"]["selection_metric"] == "f1_micro" and cfg["trainer"]["optimizer"] == "adam"
    assert cfg["trainer"]["lr"] == 1e-4 and not cfg["trainer"]["early_stopping"]
    assert runs[("mlp", "major_location", "cv5")][0]["trainer"]["batch_size"] == 64  # Table 3.3, per property
    assert metrics["validation"] == "cv5" and metrics["num_folds"] == 5 and metrics["seeds"] == [0, 1]
    assert metrics["objective"]["name"] == "val_f1_micro" and metrics["statistics_unit"] == "seed"
    assert metrics["split_options"]["one_clip_per_gloss"]
    mlp = runs[("mlp", "major_location", "cv5")][1]
    assert all(len(h) == 2 for h in mlp["final_history"].values())  # fixed budget: every epoch

    report = run_cli("report", str(sweep))
    table = (sweep / "table_thesis_ch3.md").read_text()
    assert "| model | major_location micro-F1 | major_location macro-F1 |" in table
    assert "| Baseline |" in table and "| logreg |" in table and "| mlp |" in table
    assert "runs ->" in report.stdout


def test_thesis_ch4_protocol_on_a_tiny_slice(run_cli, tmp_path):
    sweep = tmp_path / "ch4"
    run_cli("recognize", "experiment=thesis_ch4", "classifier=mlp,slgcn_small", "property=sign_type",
            "split=phoneme,gloss", "trainer.max_epochs=1", "data.num_frames=16", ONE_SIMPLE_BASELINE,
            f"hydra.sweep.dir={sweep}")
    runs = _runs(sweep)
    assert len(runs) == 4
    cfg, metrics = runs[("slgcn", "sign_type", "phoneme")]
    # SL-GCN brings the authors' training; the thesis' 27 points are 13 on MediaPipe Pose.
    assert cfg["trainer"]["optimizer"] == "sgd" and cfg["trainer"]["nesterov"] and cfg["trainer"]["lr"] == 0.1
    assert cfg["trainer"]["lr_milestones"] == [120, 140] and cfg["trainer"]["warmup_epochs"] == 20
    assert metrics["layout"]["name"] == "mediapipe_pose_slgcn27" and len(metrics["layout"]["nodes"]) == 13
    assert metrics["objective"]["name"] == "val_mcc" and cfg["data"]["lexicon"] == "asllex1"
    assert runs[("mlp", "sign_type", "gloss")][0]["trainer"]["optimizer"] == "adam"

    run_cli("report", str(sweep))
    tables = (sweep / "table_thesis_ch4.md").read_text()
    assert "| model | SignType A | SignType Ā |" in tables
    assert "**gloss split**" in tables and "| task | metric | Baseline | mlp | slgcn |" in tables
    agreement = json.loads((sweep / "agreement.json").read_text())
    for kind in ("phoneme", "gloss"):
        assert set(agreement["fleiss_kappa_all_wrong"][kind]["tasks"]) == {"sign_type"}
        assert set(agreement["mutual_misclassification"][kind]) >= {"2", "3", "per_split"}
