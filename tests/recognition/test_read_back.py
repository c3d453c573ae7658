"""Reading a performed sign back (aslexp.recognition.read_back): gloss folds, the property classifiers
and the lookup model per fold, the cache, and the table, on a small real slice: the 61 clips of nine
glosses of the shared MediaPipe Pose keypoints, 24 frames, three folds, two properties, logistic
regression for both models."""

from __future__ import annotations

import dataclasses
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from aslexp.compose import compose
from aslexp.errors import ConfigError, DataError
from aslexp.recognition import read_back as RB
from aslexp.recognition import retrieval as R

GLOSSES = ["can", "eat", "table", "time", "need", "will", "again", "coffee", "have"]
PROPERTIES = "retrieval.properties=[sign_type,major_location]"  # two of the four: half the fits


def _setup(tmp: Path, **changes) -> RB.ReadBackSetup:
    values = compose("read_back")
    values.update({"folds": 3, "glosses": GLOSSES, "model_cache": str(tmp / "models"),
                   "overrides": ["data.num_frames=24", f"cache_dir={tmp / 'datasets'}"],
                   "lookup": {"job": "retrieve", "overrides": ["classifier=logreg", PROPERTIES]},
                   "interval": {"resamples": 300, "confidence": 0.95, "seed": 0}, **changes})
    return RB.setup_from_config(values)


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("read_back")


@pytest.fixture(scope="module")
def setup(work) -> RB.ReadBackSetup:
    return _setup(work)


@pytest.fixture(scope="module")
def data(setup):
    return RB.training_clips(setup)


@pytest.fixture(scope="module")
def models(setup, data) -> RB.ReadBackModels:
    return RB.fit_fold_models(setup, data)


def _source_folder(setup) -> Path:
    from aslexp.data.root import resolve_data_root
    from aslexp.keypoints.arrays import MEDIAPIPE_POSE_DIR

    return resolve_data_root(setup.keypoints["data"]["root"]) / MEDIAPIPE_POSE_DIR


def test_the_folds_are_disjoint_and_no_fold_trains_on_its_own_glosses(setup, data, models):
    clips, table, _ = data
    everything = sorted(set(clips.glosses))
    assert everything == sorted(GLOSSES)
    folds = RB.gloss_folds(clips.glosses, 3, 0)
    assert sorted(g for fold in folds for g in fold) == everything  # every gloss in exactly one fold
    assert all(not set(a) & set(b) for i, a in enumerate(folds) for b in folds[i + 1:])
    assert max(map(len, folds)) - min(map(len, folds)) <= 1
    assert RB.gloss_folds(clips.glosses, 3, 0) == folds and RB.gloss_folds(clips.glosses, 3, 1) != folds
    glosses = np.asarray(clips.glosses, dtype=object)
    for fold in models.folds:
        assert fold.test_glosses == folds[fold.index]
        others = np.flatnonzero(~np.isin(glosses, fold.test_glosses))
        # the models were fitted on exactly the other folds' clips: their identity is those clips'
        assert fold.training == RB._identity(clips, table, others)
        assert fold.training["glosses"] == len(everything) - len(fold.test_glosses)
        assert fold.training["clips"] == len(others) < len(clips.glosses)
    with pytest.raises(ConfigError, match="read_back.folds=10"):
        RB.gloss_folds(clips.glosses, 10, 0)


def test_a_five_clip_folder_is_read_by_the_property_classifiers(setup, data, models, work):
    clips, table, lexicon = data
    chosen = [clips.video_ids[clips.glosses.index(g)] for g in GLOSSES[:5]]  # five clips of five glosses
    folder = work / "five"
    folder.mkdir()
    for video_id in chosen:
        shutil.copy(_source_folder(setup) / f"{video_id}.npy", folder / f"{video_id}.npy")
    items = RB.folder_items(folder, models)
    assert [g for _, g in items] == [clips.glosses[clips.video_ids.index(v)] for v in sorted(chosen)]
    results = RB.read_back_many(items, models)
    entries = {e.entry_id: e for e in lexicon.entries}
    for (path, gloss), result in zip(items, results):
        fold = models.folds[result["fold"]]
        assert gloss in fold.test_glosses and result["gloss_in_folds"]  # read by the fold that held it out
        entry = entries[result["entry_id"]]
        assert set(result["properties"]) == set(setup.properties)
        row = clips.video_ids.index(path.stem)
        for j, prop in enumerate(table.properties):
            read = result["properties"][prop]
            assert read["asllex"] == entry.properties[prop]
            assert read["agrees"] == (read["predicted"] == entry.properties[prop])
            # the read-back input is the builder's own row for this clip: the same prediction
            direct = fold.phonology[prop].proba(clips.X[row:row + 1], clips.mask[row:row + 1], table.vocab[j])[0]
            assert read["predicted"] == table.vocab[j][int(direct.argmax())]
            assert read["probability"] == pytest.approx(direct.max())


def test_the_lexicon_rank_of_a_real_clip_comes_from_its_fold_model(setup, data, models):
    clips, table, _ = data
    row = clips.glosses.index("coffee")
    path = _source_folder(setup) / f"{clips.video_ids[row]}.npy"
    result = RB.read_back(path, "coffee", models)
    fold = models.folds[result["fold"]]
    assert "coffee" in fold.test_glosses
    true = table.index(result["entry_id"])
    proba = [fold.lookup[p].proba(clips.X[row:row + 1], clips.mask[row:row + 1], table.vocab[j])
             for j, p in enumerate(table.properties)]
    score = R.phonology_scores(table, proba, fold.smoothing, fold.value_priors)[0] + fold.prior_weight * table.log_prior
    assert result["lexicon_rank"] == R.rank_of_true(score, true).expected
    assert result["lexicon_size"] == len(table) == 2723
    assert 1 <= result["lexicon_rank"] <= len(table)
    # the prior alone ranks by SignFrequency(Z): entries more frequent than coffee's come first
    z = table.frequency_z
    assert result["ranks"]["prior"]["above"] == int(np.sum(z > z[true]))
    # the smoothing and weight were chosen on the inner validation fold, from the retrieve job's grids
    assert fold.smoothing in setup.selection["smoothing"] and fold.prior_weight in setup.selection["prior_weights"]
    assert fold.plan["validation"]["clips"] == int(np.isin(clips.glosses, models.folds[(fold.index + 1) % 3].test_glosses).sum())


def test_keypoints_from_another_source_are_read_in_the_same_layout(setup, data, models):
    clips, _, _ = data
    row = clips.glosses.index("eat")
    raw = np.load(_source_folder(setup) / f"{clips.video_ids[row]}.npy")  # (T, 132) as MediaPipe wrote it
    as_points = raw.reshape(len(raw), 33, 4)
    perturbed = as_points.copy()
    perturbed[..., :2] += np.random.default_rng(0).normal(0, 0.02, perturbed[..., :2].shape)
    flat, points, moved = RB.read_back_many([(raw, "eat"), (as_points, "eat"), (perturbed, "eat")], models)
    assert flat["properties"] == points["properties"] and flat["lexicon_rank"] == points["lexicon_rank"]
    assert moved["fold"] == flat["fold"] and set(moved["properties"]) == set(flat["properties"])
    prepared = RB.prepare_keypoints([raw, perturbed], setup)
    assert np.array_equal(prepared.X[0], clips.X[row]) and not np.array_equal(prepared.X[1], clips.X[row])


def test_a_gloss_of_no_fold_is_read_by_a_model_that_never_saw_it(setup, models):
    from aslexp.data.wlasl import load_wlasl

    by_video = load_wlasl(setup.keypoints["data"]["root"]).by_video_id()
    other = next(p for p in sorted(_source_folder(setup).glob("*.npy"))
                 if by_video[p.stem].gloss == "water")  # in the lexicon, not among the slice's glosses
    result = RB.read_back(other, "water", models)
    assert result["fold"] == 0 and result["gloss_in_folds"] is False
    assert "no fold's models saw it" in result["fold_note"]


def test_the_cache_is_reused_and_refused_when_stale(setup, data, models, work):
    again = RB.fit_fold_models(setup, data)
    assert again.cache["fitted"] == 0 and again.cache["reused"] == models.cache["fitted"] + models.cache["reused"]
    clip = data[0].X[0:1]
    assert np.array_equal(again.folds[0].phonology["sign_type"].proba(clip, data[0].mask[0:1], data[1].vocab[0]),
                          models.folds[0].phonology["sign_type"].proba(clip, data[0].mask[0:1], data[1].vocab[0]))
    # one training clip changed: every fold that trains on it refuses its entries and fits again
    clips = data[0]
    changed = dataclasses.replace(clips, X=clips.X.copy())
    changed.X[0, 0, 0, 0, 0] += 0.5
    stale_folds = [f.index for f in models.folds if clips.glosses[0] not in f.test_glosses]
    refit = RB.fit_fold_models(setup, (changed, data[1], data[2]))
    assert refit.cache["fitted"] == len(stale_folds) * models.cache["fitted"] // 3
    assert refit.cache["refused"] and all("stale: training changed" in line for line in refit.cache["refused"])
    assert {line.split("/fold")[1][0] for line in refit.cache["refused"]} == {str(k) for k in stale_folds}
    # a damaged entry is refused too, never read
    entry = next(Path(refit.cache["folder"]).glob("fold0/sign_type-*.json"))
    entry.write_text("{not json", encoding="utf-8")
    mended = RB.fit_fold_models(setup, (changed, data[1], data[2]))
    assert mended.cache["fitted"] == 1 and "unreadable" in mended.cache["refused"][0]
    assert json.loads(entry.read_text(encoding="utf-8"))["fields"]["property"] == "sign_type"


def test_the_table_gives_agreement_and_ranks_with_intervals(setup, data, models):
    clips, _, _ = data
    items, origins = RB.source_items(setup, clips)
    scored = RB.score_clips(items, models, origins)
    table, results = scored["table"], scored["clips"]
    assert table["clips"] == len(clips.glosses) and table["glosses"] == len(GLOSSES)
    for prop in setup.properties:
        cell = table["properties"][prop]["agreement"]
        known = [r["properties"][prop]["agrees"] for r in results if r["properties"][prop]["agrees"] is not None]
        assert cell["value"] == pytest.approx(np.mean(known)) and cell["n"] == len(known)
        assert cell["low"] <= cell["value"] <= cell["high"]
    ranks = [r["lexicon_rank"] for r in results]
    lookup = table["lookup"]["phonology+prior"]
    assert lookup["median_rank"]["value"] == np.median(ranks)
    assert lookup["median_rank"]["low"] <= lookup["median_rank"]["value"] <= lookup["median_rank"]["high"]
    assert 0 <= lookup["recall@10"]["value"] <= lookup["recall@50"]["value"] <= 1
    lines = RB.table_lines(table, setup.settings.recall_at)
    assert any(line.startswith("| sign_type | ") for line in lines)


def test_wilson_intervals_are_the_textbook_ones():
    cell = RB.wilson_interval(8, 10)  # Newcombe (1998): 8/10 -> 0.490 to 0.943
    assert (round(cell["low"], 3), round(cell["high"], 3)) == (0.49, 0.943)
    assert RB.wilson_interval(0, 20)["low"] == 0.0 and RB.wilson_interval(0, 20)["high"] == pytest.approx(0.161, abs=1e-3)


def test_bad_input_is_one_line_naming_it(setup, models, work):
    with pytest.raises(DataError, match=r"keypoints\[0\] \(xyzzy\): gloss 'xyzzy' has no asllex2 entry"):
        RB.read_back_many([(np.zeros((5, 132)), "xyzzy")], models)
    with pytest.raises(DataError, match=r"keypoints\[0\] \(eat\).*shape \(5, 130\)"):
        RB.read_back_many([(np.ones((5, 130)), "eat")], models)
    with pytest.raises(DataError, match="none of its 4 frames has an observed keypoint"):
        RB.read_back(np.zeros((4, 33, 4)), "eat", models)
    with pytest.raises(FileNotFoundError, match="no such keypoint file"):
        RB.read_back(work / "absent.npy", "eat", models)
    (work / "clip.pose").write_bytes(b"")
    with pytest.raises(DataError, match=r"clip.pose: a .pose file; expected a .npy keypoint array"):
        RB.read_back(work / "clip.pose", "eat", models)
    with pytest.raises(ConfigError, match="read_back: data of conf/recognize.yaml"):
        _setup(work, phonology={"job": "recognize", "overrides": ["data.num_frames=30"]})
    with pytest.raises(ConfigError, match="read_back.glosses: 'zebra'"):
        RB.training_clips(_setup(work, glosses=["zebra"]))
