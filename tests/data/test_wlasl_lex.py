import json

import numpy as np
import pytest

from aslexp.data.dataset import DataError
from aslexp.data.keypoints import open_keypoint_source
from aslexp.keypoints import write_layout
from aslexp.data.matching import match_glosses
from aslexp.data.wlasl_lex import (WlaslLexParams, build_or_load, build_wlasl_lex, cache_key,
                                   load_wlasl_lex)
from aslexp.keypoints.published import PublishedArraySource


def test_glosses_of_the_291_clips_in_each_lexicon(data_root, wlasl, lexicons):
    ids = open_keypoint_source("mediapipe_pose_npy", data_root).available()
    glosses = {i.gloss for i in wlasl.instances if i.video_id in ids}
    assert len(ids) == 291 and len(glosses) == 49
    assert len(glosses & set(match_glosses(wlasl, lexicons["asllex2"]).matches)) == 47
    assert len(glosses & set(match_glosses(wlasl, lexicons["asllex1"]).matches)) == 38


@pytest.fixture(scope="module")
def built(tmp_path_factory, data_root):
    out = tmp_path_factory.mktemp("wlasl_lex")
    params = WlaslLexParams(lexicon="asllex2", property="major_location", subset="slgcn27",
                            split="gloss", length=64, seed=0)
    return out, params, build_wlasl_lex(out, params, root=data_root)


def test_builder_artefacts(built):
    out, params, ds = built
    manifest = json.loads((out / "manifest.json").read_text())
    assert manifest["params"] == params.to_dict()
    assert ds.skipped["gloss_not_in_lexicon"] == 6  # 'food' and 'sugar' (3 clips each)
    assert not {"food", "sugar"} & set(ds.glosses)
    assert ds.skipped["no_keypoints"] == 21083 - 291
    n = len(ds.video_ids)
    assert n + sum(v for k, v in ds.skipped.items() if k != "no_keypoints") == 291
    assert ds.X.shape == (n, 4, 64, 13, 1) and ds.mask.shape == (n, 64, 13)
    assert np.abs(ds.X[:, :3]).max() <= 1.0
    assert manifest["counts"]["all_zero_frames"] > 0 and not ds.mask.all()
    assert ds.y.max() == ds.num_classes - 1 == len(json.loads((out / "label2id.json").read_text())) - 1
    split = json.loads((out / "split.json").read_text())
    gloss_of = json.loads((out / "file2gloss.json").read_text())
    train = {gloss_of[v] for v in split["train"]}
    assert not train & {gloss_of[v] for v in split["val"] + split["test"]}
    for name in ("train", "val", "train+val", "test"):
        X = np.load(out / f"{name}_data_joint_mediapipe_pose_slgcn27.npy")
        y = np.load(out / f"{name}_label.npy")
        assert X.shape[1:] == (4, 64, 13, 1) and len(X) == len(y) == len(split[name])
        assert np.load(out / f"{name}_mask.npy").shape == (len(X), 64, 13)
    assert (out / "file_list.txt").read_text().split() == ds.video_ids
    assert set(json.loads((out / "gloss2file.json").read_text())) == set(ds.glosses)


def test_reload_and_published_roundtrip(built):
    out, _, ds = built
    again = load_wlasl_lex(out)
    np.testing.assert_array_equal(again.X, ds.X)
    np.testing.assert_array_equal(again.mask, ds.mask)
    assert again.video_ids == ds.video_ids and again.layout == ds.layout
    assert all(np.array_equal(again.splits[k], ds.splits[k]) for k in ("train", "val", "test"))
    # The thesis-format test array reads back through the published-array importer.
    test_ids = json.loads((out / "split.json").read_text())["test"]
    source = PublishedArraySource(out / "test_data_joint_mediapipe_pose_slgcn27.npy", test_ids,
                                  layout=ds.layout)  # fmt: skip
    row = ds.video_ids.index(test_ids[0])
    clip = source.load(test_ids[0])
    expected = ds.X[row, :, :, :, 0].transpose(1, 2, 0)
    observed = ds.mask[row]
    np.testing.assert_array_equal(clip[observed], expected[observed])


def test_build_or_load_reuses_and_rebuilds(tmp_path, data_root):
    params = WlaslLexParams(lexicon="asllex1", property="movement", length=32)
    first, folder = build_or_load(tmp_path, params, root=data_root)
    assert folder.name.endswith(cache_key(params, data_root))
    stamp = (folder / "manifest.json").stat().st_mtime_ns
    second, again = build_or_load(tmp_path, params, root=data_root)
    assert again == folder and (folder / "manifest.json").stat().st_mtime_ns == stamp
    np.testing.assert_array_equal(first.X, second.X)
    (folder / "manifest.json").unlink()  # an interrupted build: no manifest -> rebuilt
    third, _ = build_or_load(tmp_path, params, root=data_root)
    assert (folder / "manifest.json").is_file() and np.array_equal(third.y, first.y)
    assert [p.name for p in tmp_path.iterdir()] == [folder.name]  # no staging left behind
    assert len(set(first.glosses)) <= 38


def test_directory_source_with_bad_files(tmp_path, data_root):
    mediapipe = open_keypoint_source("mediapipe_pose_npy", data_root)
    ids = sorted(mediapipe.available())[:12]
    folder = tmp_path / "kp"
    write_layout(folder, mediapipe.layout)
    for video_id in ids[:10]:
        np.save(folder / f"{video_id}.npy", mediapipe.load(video_id))
    np.save(folder / f"{ids[10]}.npy", np.zeros((7, 33, 3), np.float32))  # wrong shape
    np.save(folder / f"{ids[11]}.npy", np.zeros((0, 33, 4), np.float32))  # empty clip
    params = WlaslLexParams(source="directory", source_path=str(folder), property="movement",
                            length=20, rare_classes="train_only")  # fmt: skip
    ds = build_wlasl_lex(None, params, root=data_root)
    assert ds.skipped["bad_keypoint_file"] == 1 and ds.skipped["no_valid_frame"] == 1
    assert len(ds.video_ids) == 10 - ds.skipped["gloss_not_in_lexicon"]
    with pytest.raises(DataError, match=f"{ids[10]}.npy"):
        build_wlasl_lex(None, params, root=data_root, strict=True)


def test_bad_parameters():
    with pytest.raises(DataError, match="handshape"):
        WlaslLexParams(property="handshape")
    with pytest.raises(ValueError, match="wlasl_lex.bogus=1: unknown key"):
        WlaslLexParams.parse({"bogus": 1})
    with pytest.raises(DataError, match="split"):
        WlaslLexParams(split="random")
