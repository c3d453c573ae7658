import json

import numpy as np
import pytest

from aslexp.data.dataset import DataError
from aslexp.data.keypoints import open_keypoint_source
from aslexp.keypoints import (MEDIAPIPE_POSE, SIGN27, DirectoryKeypointSource, KeypointSource, SubsetSource,
                              induced_edges, subset_layout, subset_names, write_layout)
from aslexp.keypoints.published import PublishedArraySource, write_published_arrays

KEYPOINT_DIR = "keypoints/wlasl-mediapipe-pose"


@pytest.fixture(scope="module")
def mediapipe(data_root):
    return open_keypoint_source("mediapipe_pose_npy", data_root)


def test_mediapipe_source_marks_no_detection_frames(mediapipe):
    assert isinstance(mediapipe, KeypointSource)
    ids = sorted(mediapipe.available())
    assert len(ids) == 291
    frames = 0
    for video_id in ids:
        clip = mediapipe.load(video_id)
        assert clip.dtype == np.float32 and clip.shape[1:] == (33, 4)
        frames += int(np.isnan(clip).all(axis=(1, 2)).sum())
        assert not np.any(np.all(clip == 0, axis=(1, 2)))  # no all-zero frame survives
    assert frames == 753 == sum(mediapipe.zero_frames.values())


def test_mediapipe_bad_shapes(tmp_path, data_root):
    np.save(tmp_path / "wrong.npy", np.zeros((10, 99)))
    np.save(tmp_path / "empty.npy", np.zeros((0, 132)))
    source = open_keypoint_source("mediapipe_pose_npy", path=tmp_path)
    with pytest.raises(DataError) as error:
        source.load("wrong")
    assert "wrong.npy" in str(error.value) and "(T, 132)" in str(error.value)
    assert source.load("empty").shape == (0, 33, 4)
    with pytest.raises(FileNotFoundError, match="absent.npy"):
        source.load("absent")


def test_subsets_and_edges():
    layout, keep = subset_layout(MEDIAPIPE_POSE, "slgcn27")  # a subset with SL-GCN's own graph
    assert keep == (0, 11, 12, 13, 14, 15, 16, 21, 19, 17, 22, 20, 18) and layout.num_nodes == 13
    assert "slgcn27" in subset_names(MEDIAPIPE_POSE) and "slgcn27" in subset_names(SIGN27)
    assert all(0 <= i < 13 and 0 <= j < 13 for i, j in layout.edges) and len(layout.edges) == 12
    upper, keep = subset_layout(MEDIAPIPE_POSE, "upper_body")
    assert upper.num_nodes == 23 and max(max(e) for e in upper.edges) < 23
    assert len(SIGN27.names) == 27 and len(SIGN27.edges) == 26
    assert induced_edges(((0, 1), (1, 2)), (0, 2)) == ((0, 1),)
    with pytest.raises(DataError, match="hands"):
        subset_layout(MEDIAPIPE_POSE, "hands")


def test_directory_source_roundtrip(tmp_path, mediapipe):
    video_id = sorted(mediapipe.available())[0]
    clip = mediapipe.load(video_id)
    subset = SubsetSource(mediapipe, "slgcn27")
    write_layout(tmp_path, subset.layout)
    np.save(tmp_path / f"{video_id}.npy", subset.load(video_id))
    source = DirectoryKeypointSource(tmp_path)
    assert source.layout == subset.layout and source.available() == {video_id}
    np.testing.assert_array_equal(source.load(video_id), clip[:, list(subset.indices)])
    np.save(tmp_path / "bad.npy", np.zeros((5, 14, 4), np.float32))
    with pytest.raises(DataError, match="bad.npy"):
        source.load("bad")
    (tmp_path / "layout.json").write_text(json.dumps({"name": "x"}))
    with pytest.raises(DataError, match="layout.json"):
        DirectoryKeypointSource(tmp_path)


@pytest.mark.parametrize("ids_format", ["txt", "json", "slgcn_json", "csv"])
def test_published_importer_roundtrip(tmp_path, mediapipe, ids_format):
    ids = sorted(mediapipe.available())[:6]
    clips = [mediapipe.load(i)[:, :27, :3] for i in ids]  # 27 nodes x 3 channels, like HRNet
    length = max(len(c) for c in clips)
    array = write_published_arrays(tmp_path / "data.npy", clips, ids, length)
    ids_path = tmp_path / f"ids.{ids_format}"
    if ids_format == "txt":
        ids_path = tmp_path / "file_list.txt"
    elif ids_format == "json":
        ids_path.write_text(json.dumps(ids))
    elif ids_format == "slgcn_json":  # SL-GCN's (sample_names, labels), as JSON
        ids_path = tmp_path / "labels.json"
        ids_path.write_text(json.dumps([[f"{i}.mp4" for i in ids], list(range(len(ids)))]))
    else:
        ids_path.write_text("video_id,label\n" + "".join(f"{i},{n}\n" for n, i in enumerate(ids)))
    source = PublishedArraySource(array, ids_path)
    assert source.layout is SIGN27 and source.available() == set(ids)
    for video_id, clip in zip(ids, clips):
        loaded = source.load(video_id)
        assert loaded.shape == (length, 27, 3)
        np.testing.assert_array_equal(loaded[: len(clip)], clip)  # NaN where missing, both sides
        assert np.isnan(loaded[len(clip):]).all()  # zero padding -> missing
    frankmocap = PublishedArraySource(array, ids, layout=None)
    assert frankmocap.layout.name == "sign27"
    with pytest.raises(DataError, match="rows"):
        PublishedArraySource(array, ids[:3])


def test_registering_a_layout_and_a_source(tmp_path):
    """A new format from Python: a layout, a source factory, opened by name like the built-ins."""
    from aslexp.keypoints import KeypointLayout, get_layout, register_layout, register_source, source_names

    layout = register_layout(KeypointLayout.from_spec(
        {"name": "test_three_points", "nodes": ["a", "b", "c"], "edges": [["a", "b"], [1, 2]], "center": "b",
         "channels": ["x", "y"]}), subsets={"ends": (0, 2)})  # fmt: skip
    assert get_layout("test_three_points") is layout and layout.center == 1 and layout.edges == ((0, 1), (1, 2))
    assert subset_layout(layout, "ends")[0].edges == ((0, 1),)  # a-c through the dropped b

    @register_source("test_csv", summary="<dir>/<id>.csv: T rows of x0, y0, x1, y1, x2, y2")
    def open_csv(path, scale: float = 1.0):
        from aslexp.keypoints import ArrayFolderSource

        class CsvSource(ArrayFolderSource):
            def available(self):
                return {p.stem for p in self.directory.glob("*.csv")}

            def load(self, video_id):
                rows = np.loadtxt(self.directory / f"{video_id}.csv", delimiter=",", ndmin=2)
                return (rows.reshape(len(rows), 3, 2) * scale).astype(np.float32)

        return CsvSource(path, "test_three_points")

    np.savetxt(tmp_path / "v1.csv", np.arange(12.0).reshape(2, 6), delimiter=",")
    source = open_keypoint_source("test_csv", path=tmp_path, scale=2.0)
    assert "test_csv" in source_names() and source.available() == {"v1"}
    assert source.load("v1")[1, 2].tolist() == [20.0, 22.0]
    with pytest.raises(DataError, match="already registered"):
        register_layout(KeypointLayout("test_three_points", ("a",), (), 0, ("x",)))
    with pytest.raises(DataError, match="do not fit"):
        open_keypoint_source("test_csv", path=tmp_path, scael=2.0)
    with pytest.raises(DataError, match="unknown keypoint source 'nope'.*array_folder"):
        open_keypoint_source("nope", path=tmp_path)


@pytest.mark.parametrize("spec, field", [
    ({"name": "x", "nodes": ["a", "a"], "channels": ["x"]}, "repeats"),
    ({"name": "x", "nodes": 2, "edges": [[0, 5]], "channels": ["x"]}, "'edges' refers to node 5"),
    ({"name": "x", "nodes": 2, "edges": [["a", "b"]], "channels": ["x"]}, "'edges' refers to node 'a'"),
    ({"name": "x", "nodes": 2, "channels": []}, "'channels'"),
    ({"name": "x", "nodes": 0, "channels": ["x"]}, "'nodes'"),
    ({"nodes": 2, "channels": ["x"]}, "'name'"),
])  # fmt: skip
def test_yaml_layout_mistakes_name_the_field(spec, field):
    from aslexp.keypoints import KeypointLayout

    with pytest.raises(DataError, match=field) as error:
        KeypointLayout.from_spec(spec, "conf/pose/mine.yaml")
    assert str(error.value).startswith("conf/pose/mine.yaml: ")


def test_a_plug_in_registers_through_its_entry_point(tmp_path, monkeypatch):
    """An installed package that declares `[aslexp.keypoints]` in its entry points (a real
    dist-info on sys.path here) is loaded the first time an unknown name is asked for."""
    import sys

    from aslexp import plugins
    from aslexp.keypoints import get_layout

    (tmp_path / "aslexp_test_plugin.py").write_text(
        "from aslexp.keypoints import KeypointLayout, register_layout\n"
        "def register():\n"
        "    register_layout(KeypointLayout('plugin_pair', ('p', 'q'), ((0, 1),), 0, ('x', 'y')))\n")  # fmt: skip
    info = tmp_path / "aslexp_test_plugin-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: aslexp-test-plugin\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text("[aslexp.keypoints]\npair = aslexp_test_plugin:register\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setattr(plugins, "_loaded_groups", set())  # entry points are read once per process
    assert get_layout("plugin_pair").names == ("p", "q")
    sys.modules.pop("aslexp_test_plugin", None)
