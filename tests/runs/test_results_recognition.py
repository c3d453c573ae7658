"""The recognition entries of the results page: per row the test clips and all
clips, Wilson intervals for proportions (a bootstrap or none for MCC), the "no better than chance"
mark, no spread over the seeds of a deterministic model, and a generated line of differences from
the thesis; on the committed snapshots, the real data and real tiny runs."""

from __future__ import annotations

import copy
import json
import math
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import job_process

from aslexp.recognition import intervals as ri
from aslexp.recognition.metrics import accuracy_ci
from aslexp.results import recognition as rr
from aslexp.results.catalogue import load_catalogue
from aslexp.results.snapshots import write_snapshot

ROOT = Path(__file__).resolve().parents[2]
CATALOGUE = {e["id"]: e for e in load_catalogue(ROOT / "conf" / "results.yaml")}
SNAPSHOTS = ROOT / "docs" / "results"
RECOGNITION = [i for i, e in CATALOGUE.items() if e["report"] == "recognition" and (SNAPSHOTS / f"{i}.json").is_file()]


def _snapshot(entry_id: str) -> dict:
    return json.loads((SNAPSHOTS / f"{entry_id}.json").read_text(encoding="utf-8"))


def _data_root() -> Path:
    from aslexp.data.root import resolve_data_root

    return resolve_data_root(None, must_exist=False)


# --------------------------------------------------------------------------- intervals


def test_the_wilson_interval_is_the_hand_computed_one():
    # 18 of 33 (phoneme sign_type's chosen model): z = 1.959964, z^2 = 3.841459
    # centre = (18/33 + z^2/66) / (1 + z^2/33) = 0.603658 / 1.116408 = 0.540716
    # half = z * sqrt((18/33)(15/33)/33 + z^2/(4*33^2)) / 1.116408 = 0.160855
    low, high = ri.wilson(18 / 33, 33)
    assert low == pytest.approx(0.540716 - 0.160855, abs=2e-6) and high == pytest.approx(0.540716 + 0.160855, abs=2e-6)
    # the textbook case where Wald fails: 0 of 10 gives Wald [0, 0] and Wilson [0, 0.2775]
    assert ri.wilson(0.0, 10) == (0.0, pytest.approx(0.27754, abs=1e-5))
    assert accuracy_ci(0, 10)[1:] == (0.0, 0.0)
    # 3 of 5 (Table 3.4's sign type test set): wider than the Wald interval, inside [0, 1]
    low, high = ri.wilson(0.6, 5)
    assert (round(low, 4), round(high, 4)) == (0.2307, 0.8824)


def test_n_is_recovered_from_a_stored_wald_half_width_and_refused_where_it_cannot_be():
    for correct, n in ((18, 33), (4, 15), (29, 39), (3, 6)):
        p, low, high = accuracy_ci(correct, n)
        assert ri.recover_n(p, (high - low) / 2) == n
    assert ri.recover_n(0.6, 0.1) is None          # n = 92.2: not an integer
    assert ri.recover_n(1.0, 0.0) is None          # p = 1: the Wald width is 0 and says nothing
    p, low, high = accuracy_ci(1, 10)              # clipped at 0: the half-width is not the Wald one
    assert ri.recover_n(p, (high - low) / 2) is None


@pytest.mark.parametrize("entry_id", RECOGNITION)
def test_every_committed_recognition_row_has_its_test_clips_consistent_with_what_is_stored(entry_id):
    snapshot = _snapshot(entry_id)
    metric = CATALOGUE[entry_id]["options"]["metric"]
    for row in snapshot["rows"]:
        learned = row["learned"]
        assert isinstance(row["n_test"], int) and row["n_all"] >= row["n_test"] and row["n_test_source"], row["key"]
        if "Wald" in learned["spread_kind"]:  # the recovered n is the stored one
            assert ri.recover_n(learned["mean"], learned["spread"]) == row["n_test"], row["key"]
            assert "Wald half-width implies the same n" in row["n_test_source"]
        if metric in ri.PROPORTIONS and learned["unit"] == "seeds":
            k = learned["mean"] * row["n_test"]  # a count of clips
            assert k == pytest.approx(round(k), abs=1e-6), row["key"]
            assert learned["interval"]["low"] == pytest.approx(ri.wilson(learned["mean"], row["n_test"])[0])
        if metric == "mcc" and learned["n"] == 1:
            assert learned["interval"] is None and "not valid" in learned["interval_none"]


def test_the_same_split_and_property_have_the_same_test_clips_in_every_snapshot():
    seen: dict[str, int] = {}
    for entry_id in RECOGNITION:
        for row in _snapshot(entry_id)["rows"]:
            assert seen.setdefault(row["key"], row["n_test"]) == row["n_test"], (entry_id, row["key"])
    assert seen["phoneme/sign_type"] == 33 and seen["gloss/flexion"] == 15


def test_mcc_from_a_confusion_matrix_is_sklearns_and_its_bootstrap_is_seeded():
    from sklearn.metrics import matthews_corrcoef

    rng = np.random.default_rng(3)
    y, p = rng.integers(0, 4, 40), rng.integers(0, 4, 40)
    p[:25] = y[:25]
    matrix = np.zeros((4, 4), dtype=int)
    np.add.at(matrix, (y, p), 1)
    assert ri.mcc_from_confusion(matrix) == pytest.approx(matthews_corrcoef(y, p))
    low, high = ri.mcc_bootstrap(matrix)
    assert low < ri.mcc_from_confusion(matrix) < high and (low, high) == ri.mcc_bootstrap(matrix)
    assert ri.mcc_from_confusion([[5, 0], [3, 0]]) == 0.0  # constant prediction


# --------------------------------------------------------------------------- the split, from the data


def test_the_test_clips_are_those_the_codes_own_split_gives_on_the_real_data():
    if not (_data_root() / "keypoints" / "wlasl-mediapipe-pose").is_dir():
        pytest.skip("the shared MediaPipe Pose keypoints are not here")
    entry, snapshot = CATALOGUE["table_4_3"], _snapshot("table_4_3")
    facts = ri.split_facts(rr.row_config(entry, snapshot, "gloss/minor_location"))
    [row] = [r for r in snapshot["rows"] if r["key"] == "gloss/minor_location"]
    assert (facts["n_test"], facts["n_all"]) == (row["n_test"], row["n_all"]) == (41, 155)
    assert facts["majority"] == pytest.approx(row["majority"]["value"]) == pytest.approx(33 / 41)
    assert facts["rare_dropped"]["classes"]["Chin"] == 2 and facts["rare_dropped"]["unit"] == "glosses"
    # the keypoints: 13 of SL-GCN's 27 on MediaPipe Pose, no fingertips
    from aslexp.keypoints import slgcn27

    nodes = facts["keypoints"]["nodes"]
    assert len(nodes) == 13 and set(nodes) <= set(slgcn27.NAMES) and len(slgcn27.NAMES) == 27
    assert not [n for n in nodes if re.search(r"(index|middle|ring|little)_tip", n)]


def test_adding_test_clips_to_a_snapshot_without_them_recovers_the_committed_ones():
    entry = CATALOGUE["table_4_2"]
    committed = _snapshot("table_4_2")
    bare = copy.deepcopy(committed)
    for row in bare["rows"]:
        for key in ("n_test", "n_all", "n_test_source", "n_classes", "majority", "keypoints", "rare_dropped"):
            row.pop(key)
        row["learned"].pop("interval")
    facts = {r["key"]: {"n_test": r["n_test"], "n_all": r["n_all"], "classes": ["a"] * r["n_classes"],
                        "majority": r["majority"]["value"], "keypoints": r["keypoints"],
                        "rare_dropped": r["rare_dropped"]} for r in committed["rows"]}
    again = rr.add_test_clips(entry, bare, lambda e, s, key: facts[key])
    assert again == committed
    facts["phoneme/sign_type"]["n_test"] = 34  # the data disagree with the stored Wald half-width
    with pytest.raises(ValueError, match="not the data the runs had"):
        rr.add_test_clips(entry, bare, lambda e, s, key: facts[key])


# --------------------------------------------------------------------------- the page


def _row(metric_mean: float, majority: float, **learned) -> dict:
    return {"key": "phoneme/x", "label": "phoneme, x", "n_test": 30, "n_all": 200, "majority": {"value": majority},
            "learned": {"mean": metric_mean, "spread": None, "spread_kind": "one seed: no spread", "n": 1,
                        "unit": "seeds", "model": "lstm", "interval": None, **learned}}


def test_a_row_no_better_than_the_majority_class_is_marked():
    assert rr.CHANCE_MARK in rr.learned_cell(_row(0.6, 0.6), "accuracy", True)       # equal: not above
    assert rr.CHANCE_MARK in rr.learned_cell(_row(0.5, 0.6), "accuracy", True)
    assert rr.CHANCE_MARK not in rr.learned_cell(_row(0.7, 0.6), "accuracy", True)
    assert rr.CHANCE_MARK in rr.learned_cell(_row(0.0, 0.0), "mcc", True)            # MCC 0 = constant prediction
    assert rr.CHANCE_MARK in rr.learned_cell(_row(-0.29, 0.0), "mcc", True)
    assert rr.CHANCE_MARK not in rr.learned_cell(_row(0.31, 0.0), "mcc", True)
    page = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    [flexion] = [line for line in page.splitlines() if line.startswith("| gloss, flexion") and "accuracy" not in line
                 and "[10.9, 52.0]" in line]
    assert f"{rr.CHANCE_MARK} (the majority class 53.3)" in flexion


def test_a_deterministic_models_zero_spread_over_seeds_is_not_shown_as_a_measurement():
    row = _row(0.6, 0.4, spread=1e-16, spread_kind="std over seeds", n=10,
               interval={"low": 0.2307, "high": 0.8824, "kind": "95% Wilson"})
    row["n_test"] = 5
    cell = rr.learned_cell(row, "f1_micro", True)
    assert "± 0.0" not in cell and "deterministic model: no spread over seeds (10 seeds); n test clips = 5" in cell
    assert cell.startswith("60.0 [23.1, 88.2]")


def test_the_committed_cells_show_the_wilson_interval_and_the_test_clips():
    page = (ROOT / "docs" / "results.md").read_text(encoding="utf-8")
    assert "| phoneme, sign_type | 84.5 ± 1.8 (STGCN_H; thesis baseline 39.3) | 42.4 (majority) | 63.6 (rf) | " \
           "**54.5 [38.0, 70.2] (lstm; 33 test clips of 216)** |" in page
    assert "95% Wald" not in page.split('<a id="table_4_2">')[1].split('<a id="table_4_4">')[0]
    assert page.count("- **Differences from the thesis**") == len(RECOGNITION)


def test_the_differences_line_follows_the_snapshot():
    entry, snapshot = CATALOGUE["table_4_2"], _snapshot("table_4_2")
    line = "\n".join(rr.differences(entry, snapshot))
    assert "32-34 test clips of 214-218 per property and split (the thesis: 1,503 (phoneme split) test clips of 10,017)" in line
    assert "13 of SL-GCN's 27 points (7 exact, 6 approximate; 14 absent, no fingertips)" in line
    assert "phoneme, minor_location: Other (2 clips), TorsoTop (2 clips)" in line
    assert "models untuned: the command runs no hyper-parameter sweep" in line
    changed = copy.deepcopy(snapshot)
    changed["rows"][0]["n_test"], changed["rows"][0]["n_all"] = 1500, 10000
    changed["rows"][0]["rare_dropped"]["classes"] = {"Rare": 1}
    changed["rows"][0]["keypoints"]["nodes"] += ["left_hand_index_tip"]
    other = "\n".join(rr.differences(entry, changed))
    assert "32-1500 test clips of 214-10000" in other and "Rare (1 clip)" in other
    # the changed row's keypoints are a second group: with a fingertip, which Pose does not give
    assert "`mediapipe_pose_slgcn27`: 14 of SL-GCN's 27 points (7 exact, 6 approximate; 13 absent)" in other
    tuned = {**entry, "command": entry["command"] + " +sweeps=classifier_gru_thesis_ch4"}
    tuned_lines = "\n".join(rr.differences(tuned, snapshot))
    assert "models tuned by the command's sweep (+sweeps=classifier_gru_thesis_ch4)" in tuned_lines


def test_the_catalogues_thesis_sizes_are_thesis_mds():
    path = _data_root().parent / "THESIS.md"
    if not path.is_file():
        pytest.skip(f"THESIS.md not found beside the data root ({path})")
    text = path.read_text(encoding="utf-8")
    assert "(derived) Test-set sizes: Phoneme 1,503 clips (15.0 % of 10,017), Gloss 1,484 (14.8 %)." in text
    assert "**10,017 videos, 800 glosses**" in text and "**725 unique entries**" in text
    assert "**85 % train / 15 % test**" in text
    for entry_id in ("table_4_2", "table_4_3", "table_4_4", "table_c_2"):
        data = CATALOGUE[entry_id]["thesis"]["data"]
        assert data["clips"] == 10017 and set(data["test_clips"].items()) <= {("phoneme", 1503), ("gloss", 1484)}
    assert CATALOGUE["table_3_4"]["thesis"]["data"]["clips"] == 725
    assert CATALOGUE["table_3_4"]["thesis"]["data"]["test_share"] == 0.15


# --------------------------------------------------------------------------- from a real run


def test_the_summarizer_stores_the_test_clips_and_the_interval_of_a_real_run(tmp_path):
    from aslexp.results.recognition import results_summary

    env = {**os.environ, "MPLBACKEND": "Agg"}
    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.recognize", "-m", "experiment=debug",
                           "classifier=logreg", "property=sign_type", f"hydra.sweep.dir={tmp_path / 'runs'}"],
                          cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    [path] = list((tmp_path / "runs").rglob("metrics.json"))
    metrics = json.loads(path.read_text(encoding="utf-8"))
    base = {"id": "x", "command": "aslexp recognize -m experiment=debug", "thesis": {}, "report": "recognition"}
    for metric in ("accuracy", "mcc"):
        [row] = results_summary({**base, "options": {"metric": metric, "spread": "ci95"}}, [tmp_path / "runs"])["rows"]
        assert row["n_test"] == metrics["split_sizes"]["test"] == metrics["test_per_seed"][0]["n"]
        assert row["n_all"] == metrics["context"]["num_clips"] and row["n_test_source"] == ri.FROM_RUN
        interval = row["learned"]["interval"]
        if metric == "accuracy":
            assert (interval["low"], interval["high"]) == ri.wilson(metrics["test"]["accuracy"], row["n_test"])
            assert row["majority"]["value"] == pytest.approx(metrics["baselines"]["majority"]["test"]["accuracy"])
        else:  # one test set with its confusion matrix: the bootstrap over its clips
            assert "bootstrap" in interval["kind"] and interval["low"] <= metrics["test"]["mcc"] <= interval["high"]
            assert math.isclose(ri.mcc_from_confusion(metrics["test_per_seed"][0]["confusion_matrix"]),
                                metrics["test"]["mcc"], abs_tol=1e-9)


def test_the_cli_adds_the_test_clips_to_bare_snapshots_from_the_real_data_as_committed(tmp_path):
    if not (_data_root() / "keypoints" / "wlasl-mediapipe-pose").is_dir():
        pytest.skip("the shared MediaPipe Pose keypoints are not here")
    from aslexp.tools.report import report_main

    (tmp_path / "snapshots").mkdir()
    for entry_id in ("table_4_3", "table_c_2"):
        bare = _snapshot(entry_id)
        for row in bare["rows"]:
            for key in ("n_test", "n_all", "n_test_source", "n_classes", "majority", "keypoints", "rare_dropped"):
                row.pop(key)
            row["learned"].pop("interval")
            row["learned"].pop("interval_none", None)
        write_snapshot(tmp_path / "snapshots" / f"{entry_id}.json", bare)
    assert report_main(["--results", "--render-only", "--add-test-clips", "--snapshots", str(tmp_path / "snapshots"),
                        "--page", str(tmp_path / "results.md")]) == 0
    for entry_id in ("table_4_3", "table_c_2"):
        assert (tmp_path / "snapshots" / f"{entry_id}.json").read_text(encoding="utf-8") == \
            (SNAPSHOTS / f"{entry_id}.json").read_text(encoding="utf-8")


def test_a_stored_spread_over_splits_gives_a_t_interval_and_one_over_seeds_a_wilson_interval():
    over_splits = {"mean": 0.5, "spread": 0.1, "spread_kind": "std over splits", "n": 10, "unit": "splits"}
    interval, none = ri.stored_interval("accuracy", over_splits, 6)
    assert none is None and interval["high"] - 0.5 == pytest.approx(2.262157 * 0.1 / math.sqrt(10), abs=1e-6)
    seeds = {"mean": 0.6, "spread": 1e-16, "spread_kind": "std over seeds", "n": 10, "unit": "seeds"}
    interval, _ = ri.stored_interval("f1_micro", seeds, 5)
    assert (interval["low"], interval["high"]) == ri.wilson(0.6, 5) and "at the mean" not in interval["kind"]
    interval, _ = ri.stored_interval("f1_micro", {**seeds, "spread": 0.05}, 5)
    assert interval["kind"].endswith("at the mean over seeds")
