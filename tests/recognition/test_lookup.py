"""`aslexp lookup`: a tiny retrieval model (1 gloss split, 2 properties, a forest of
10 trees) saved by `aslexp retrieve retrieval.save_model=all` looks up a repository keypoint file and a
`.pose` file made from it: the card, metrics.json and the figure are written, the top 10 are lexicon
signs with their values, every property's probabilities sum to 1, the clip's own sign gets a rank (said,
not asserted to be first), and the two files give the same model input. Bad input is one line naming
the file, exit 2, refused before any run folder. The documented commands (docs/recognition.md,
"Looking up one clip") run here as written, the model and the hypothetical clip substituted."""

from __future__ import annotations

import json
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import job_process
from doc_commands import bash_lines

from aslexp.errors import DataError
from aslexp.jobs.lookup import check_inputs, positional_input

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("ASLEXP_DATA_ROOT", ROOT.parent / "shared" / "data"))
KEYPOINTS = DATA / "keypoints" / "wlasl-mediapipe-pose"
CLIP = "01457"  # "again": 40 frames
PROPERTIES = ["sign_type", "major_location"]
# The documented retrieve command cut to a test's size (these keys replace the command's own).
CUT = ["split.repeats=1", f"retrieval.properties=[{','.join(PROPERTIES)}]", "retrieval.smoothing=[0.01]",
       "retrieval.prior_weights=[0,4]", "classifier.params.n_estimators=10", "classifier.params.n_jobs=1"]

pytestmark = [pytest.mark.skipif(not (KEYPOINTS / f"{CLIP}.npy").is_file(), reason=f"shared data not found under {DATA}"),
              pytest.mark.xdist_group("lookup_model")]  # one worker trains the module's model once


def _cli(args: list[str], cache: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, ASLEXP_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    return job_process.run([sys.executable, "-m", "aslexp.cli", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)


def _documented(job: str) -> list[list[str]]:
    return [shlex.split(line)[2:] for line in bash_lines(ROOT / "docs" / "recognition.md")
            if line.startswith(f"aslexp {job} ") and (job != "retrieve" or "save_model" in line)]


def write_pose(npy: Path, path: Path) -> Path:
    """A repository keypoint file as a `.pose` (pose-format's MediaPipe Holistic, the body only; an
    all-zero row, MediaPipe's "nobody found", masked), as `aslexp extract --format pose` writes one."""
    from aslexp.keypoints import holistic as H
    from aslexp.keypoints.posefile import write_holistic_pose

    body = np.load(npy).reshape(-1, 33, 4).astype(np.float32)
    body[np.all(body == 0, axis=(1, 2))] = np.nan
    keypoints = np.full((len(body), H.NUM_NODES, 4), np.nan, np.float32)
    keypoints[:, :33] = body
    return write_holistic_pose(path, keypoints, 25.0, 640, 480)


@pytest.fixture(scope="module")
def cache(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("lookup_cache")


@pytest.fixture(scope="module")
def model_dir(tmp_path_factory, cache) -> Path:
    """The documented `aslexp retrieve ... retrieval.save_model=all`, cut: a lookup model in tmp."""
    commands = _documented("retrieve")
    assert commands, "docs/recognition.md documents `aslexp retrieve retrieval.save_model=all`"
    run = tmp_path_factory.mktemp("lookup_model") / "run"
    keys = {c.split("=")[0] for c in CUT}
    words = [w for w in commands[0] if w.split("=")[0] not in keys] + CUT + [f"hydra.run.dir={run}"]
    proc = _cli(["retrieve", *words], cache)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return run


@pytest.fixture(scope="module")
def pose_file(tmp_path_factory) -> Path:
    return write_pose(KEYPOINTS / f"{CLIP}.npy", tmp_path_factory.mktemp("pose") / f"{CLIP}.pose")


def _lexicon():
    from aslexp.data.lexicon import load_lexicon

    return {e.entry_id: e for e in load_lexicon("asllex2", DATA).entries}


def _check_run(run: Path, card: str, lexicon) -> dict:
    assert json.loads((run / "run.json").read_text())["status"] == "completed"
    text = (run / card).read_text(encoding="utf-8")
    png = (run / "keypoints.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 10_000 and "keypoints.png" in text
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["model"]["properties"] == PROPERTIES and metrics["lexicon_entries"] == 2723
    for prop in PROPERTIES:
        info = metrics["properties"][prop]
        assert sum(info["probabilities"].values()) == pytest.approx(1.0)
        assert info["predicted"] == next(iter(info["probabilities"])) and info["predicted"] in text
    top = metrics["top"]
    assert [t["rank"] for t in top] == list(range(1, 11)) and len({t["entry_id"] for t in top}) == 10
    assert all(top[k]["score"] >= top[k + 1]["score"] for k in range(9))
    for item in top:  # lexicon signs, with their own values and frequency
        entry = lexicon[item["entry_id"]]
        assert item["values"] == {p: entry.properties[p] for p in PROPERTIES}
        assert item["frequency_z"] == pytest.approx(entry.frequency_z) and item["entry_id"] in text
    truth = metrics["truth"]
    assert truth["gloss"] == "again" and truth["entry_id"] == "again" and truth["clip_fitted"]
    assert 1 <= truth["rank"]["phonology+prior"] <= 2723 and 1 <= truth["rank"]["prior"] <= 2723
    print(f"{run.name}: own sign {truth['entry_id']} ranked {truth['rank']}")
    return metrics


def test_lookup_writes_its_card_for_a_repository_keypoint_file_and_a_pose_file(model_dir, pose_file, cache, tmp_path):
    commands = _documented("lookup")
    assert len(commands) >= 2, "docs/recognition.md documents `aslexp lookup` for a keypoint file and a .pose"
    lexicon = _lexicon()
    runs = []
    for number, words in enumerate(commands):
        given = next(w.split("=", 1)[1] for w in words if w.startswith("input="))
        if given.startswith("../shared/data/"):
            given = str(DATA / given.removeprefix("../shared/data/"))
        elif given.endswith(".pose"):
            given = str(pose_file)  # the page's clip.pose: a real one
        words = [f"input={given}" if w.startswith("input=") else f"model={model_dir}" if w.startswith("model=") else w
                 for w in words] + [f"hydra.run.dir={tmp_path / f'doc{number}'}"]
        proc = _cli(["lookup", *words], cache)
        assert proc.returncode == 0, f"{words}: exit {proc.returncode}\n{proc.stderr[-3000:]}"
        card = "card.html" if "format=html" in words else "card.md"
        runs.append(_check_run(tmp_path / f"doc{number}", card, lexicon))
        # the terminal's short table: the properties with probabilities, then the top 10
        out = proc.stdout
        assert "predicted properties (probability)" in out and "top 10 of 2,723 ASL-LEX signs" in out
        assert runs[-1]["top"][0]["entry_id"] in out and "own sign again: rank" in out
    # `aslexp lookup FILE model=...`: the first plain word is the input
    proc = _cli(["lookup", str(pose_file), f"model={model_dir}", f"hydra.run.dir={tmp_path / 'positional'}"], cache)
    assert proc.returncode == 0, proc.stderr[-3000:]
    pose = _check_run(tmp_path / "positional", "card.md", lexicon)
    npy = next(r for r in runs if r["input"]["file"].endswith(".npy"))
    assert pose["input"]["file"].endswith(".pose") and "pose" in pose["input"]["kind"]
    # the .pose made from the keypoint file is the same model input: the same lookup
    assert [t["entry_id"] for t in pose["top"]] == [t["entry_id"] for t in npy["top"]]
    for prop in PROPERTIES:
        assert pose["properties"][prop]["probabilities"] == pytest.approx(npy["properties"][prop]["probabilities"])


def test_the_pose_file_and_the_keypoint_file_are_the_same_model_input(model_dir, pose_file, cache, tmp_path):
    from aslexp.recognition.lookup import load_lookup_model, read_clip

    model = load_lookup_model(model_dir)
    npy, pose = read_clip(KEYPOINTS / f"{CLIP}.npy", model, root=DATA), read_clip(pose_file, model, root=DATA)
    assert npy.X.shape == (1, 3, 150, 23, 1) and npy.frames == pose.frames == 40  # the build's T, subset, channels
    np.testing.assert_array_equal(npy.mask, pose.mask)
    np.testing.assert_allclose(npy.X, pose.X, atol=1e-5)
    # an `aslexp extract` folder (Holistic (T, 75, 4), NaN = missing, its layout.json): nodes by name
    from aslexp.keypoints import holistic as H
    from aslexp.pose.extract import write_layout_json

    folder = tmp_path / "extracted"
    folder.mkdir()
    write_layout_json(folder)
    body = np.load(KEYPOINTS / f"{CLIP}.npy").reshape(-1, 33, 4).astype(np.float32)
    body[np.all(body == 0, axis=(1, 2))] = np.nan
    holistic = np.full((len(body), H.NUM_NODES, 4), np.nan, np.float32)
    holistic[:, :33] = body
    np.save(folder / f"{CLIP}.npy", holistic)
    extracted = read_clip(folder / f"{CLIP}.npy", model, root=DATA)
    assert "layout.json" in extracted.kind
    np.testing.assert_array_equal(npy.X, extracted.X)
    # exactly the dataset builder's preprocessing: the clip's row of the cached WLASL-Lex build
    from aslexp.data.wlasl_lex import load_wlasl_lex

    build = next(cache.glob("wlasl_lex-asllex2-sign_type-*"))
    dataset = load_wlasl_lex(build)
    row = dataset.video_ids.index(CLIP)
    np.testing.assert_array_equal(npy.X[0], dataset.X[row])
    np.testing.assert_array_equal(npy.mask[0], dataset.mask[row])


def test_a_first_split_model_ranks_an_unseen_clip_as_the_retrieval_did(cache, tmp_path):
    """retrieval.save_model=first_split: the classifiers fitted on the first split's train+val glosses
    with its eps and w, so a lookup of one of its test clips gives the rank that run's ranks.csv has."""
    import csv

    from aslexp.recognition.lookup import load_lookup_model, load_table, lookup_clip, read_clip

    run = tmp_path / "first_split"
    proc = _cli(["retrieve", *CUT, "retrieval.save_model=first_split", f"hydra.run.dir={run}"], cache)
    assert proc.returncode == 0, proc.stderr[-3000:]
    model = load_lookup_model(run)
    assert model.meta["fit_on"] == "first_split" and model.meta["fitted_glosses"] == 40  # 33 train + 7 val
    table, lexicon = load_table(model, DATA)
    with (run / "ranks.csv").open() as handle:
        rows = list(csv.DictReader(handle))
    for row in rows[:: max(1, len(rows) // 3)]:
        result = lookup_clip(model, read_clip(KEYPOINTS / f"{row['video_id']}.npy", model, root=DATA), table, lexicon)
        truth = result["truth"]
        assert truth["entry_id"] == row["entry_id"] and not truth["clip_fitted"] and not truth["gloss_fitted"]
        assert truth["rank"]["phonology+prior"] == float(row["rank_phonology+prior"])
        assert truth["rank"]["phonology"] == float(row["rank_phonology"])
        assert truth["rank"]["prior"] == float(row["rank_prior"])
        for prop in PROPERTIES:
            assert result["properties"][prop]["predicted"] == row[f"predicted_{prop}"]


def test_bad_input_is_one_line_naming_the_file(model_dir, cache, tmp_path):
    good = str(KEYPOINTS / f"{CLIP}.npy")

    def refused(given, model=str(model_dir)) -> str:
        with pytest.raises((DataError, FileNotFoundError, ValueError)) as error:
            check_inputs({"input": given, "model": model, "top_k": 10, "format": "md", "data_root": str(DATA)})
        message = str(error.value)
        assert "\n" not in message
        return message

    assert refused(str(tmp_path / "missing.npy")) == (f"input={tmp_path / 'missing.npy'}: no such file; expected a "
                                                      "keypoint array (.npy), a .pose file or a video")
    (tmp_path / "notes.txt").write_text("not keypoints\n")
    assert "notes.txt: unknown file type '.txt'" in refused(str(tmp_path / "notes.txt"))
    no_model = tmp_path / "plain_run"
    no_model.mkdir()
    message = refused(good, str(no_model))
    assert f"model={no_model}: no model/model.json" in message and "retrieval.save_model=all" in message
    # keypoints of another layout: the upper body's 23 points alone, a hands-only .pose, a damaged .pose
    np.save(tmp_path / "upper.npy", np.load(good).reshape(-1, 33, 4)[:, :23].reshape(-1, 92))
    message = refused(str(tmp_path / "upper.npy"))
    assert "upper.npy: keypoints of layout none known (a (40, 92) array)" in message
    assert "expects layout mediapipe_pose (33 nodes" in message  # and the ways on: the video, or a model of this layout
    assert "aslexp extract VIDEO" in message and "aslexp retrieve pose=array_folder pose.path=FOLDER" in message
    np.save(tmp_path / "hands.npy", np.zeros((40, 42, 3), np.float32))  # MediaPipe Hands' two hands
    message = refused(str(tmp_path / "hands.npy"))
    assert "hands.npy: keypoints of layout mediapipe_hands (a (40, 42, 3) array)" in message
    assert "aslexp retrieve pose=mediapipe_hands pose.path=FOLDER retrieval.save_model=all" in message
    from aslexp.keypoints.posefile import LEFT, RIGHT, read_pose

    hands = read_pose(write_pose(Path(good), tmp_path / "whole.pose")).get_components([LEFT, RIGHT])
    with open(tmp_path / "hands.pose", "wb") as handle:
        hands.write(handle)
    message = refused(str(tmp_path / "hands.pose"))
    assert "hands.pose: keypoints of layout" in message and "expects layout mediapipe_pose" in message
    assert "aslexp retrieve pose=pose_format" in message
    (tmp_path / "damaged.pose").write_bytes(b"not a pose file")
    assert "damaged.pose: not a readable .pose file" in refused(str(tmp_path / "damaged.pose"))
    # on the command line: the line, exit 2, no traceback, no run folder
    folder = tmp_path / "refused"
    proc = _cli(["lookup", str(tmp_path / "upper.npy"), f"model={model_dir}", f"hydra.run.dir={folder}"], cache)
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert proc.returncode == 2 and lines == [lines[-1]] and "Traceback" not in proc.stderr, proc.stderr
    assert lines[-1].startswith(f"aslexp lookup: input={tmp_path / 'upper.npy'}: keypoints of layout none known")
    assert not folder.exists()


def test_frames_cut_the_clip_and_a_range_outside_it_is_refused(model_dir, cache, tmp_path):
    """`frames=START:END` (as `aslexp extract --frames`): the model reads frames 11..30 of the 40, the
    card and metrics.json say so; a range past the clip's end or unparsable is one line, exit 2."""
    from aslexp.errors import ConfigError

    good = str(KEYPOINTS / f"{CLIP}.npy")
    base = {"input": good, "model": str(model_dir), "top_k": 10, "format": "md", "data_root": str(DATA)}
    for frames, expected in (("30:50", f"frames=30:50: input={good} has 40 frames; expected 1 <= START <= END <= 40"),
                             ("ten", "frames=ten: expected START:END or VIDEO_ID=START:END"),
                             ("99999=1:10", "frames=99999=1:10: names video id '99999', not the input's '01457'")):
        with pytest.raises((DataError, ConfigError)) as error:
            check_inputs({**base, "frames": frames})
        assert str(error.value).startswith(expected) and "\n" not in str(error.value), str(error.value)
    check_inputs({**base, "frames": "11:30"})
    run = tmp_path / "cut"
    proc = _cli(["lookup", good, f"model={model_dir}", "frames=11:30", f"hydra.run.dir={run}"], cache)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["input"]["span"] == [11, 30] and metrics["input"]["frames"] == 20
    assert "frames 11..30 of 40" in metrics["input"]["notes"][0] and "frames 11..30 of 40" in (run / "card.md").read_text()
    whole = _cli(["lookup", good, f"model={model_dir}", f"hydra.run.dir={tmp_path / 'whole'}"], cache)
    assert whole.returncode == 0 and json.loads((tmp_path / "whole" / "metrics.json").read_text())["input"]["span"] is None
    cut = _cli(["lookup", good, f"model={model_dir}", "frames=30:50", f"hydra.run.dir={tmp_path / 'past'}"], cache)
    assert cut.returncode == 2 and "has 40 frames" in cut.stderr.strip().splitlines()[-1] and "Traceback" not in cut.stderr


def test_a_video_goes_through_mediapipe_or_says_it_is_missing(model_dir, cache, tmp_path):
    from aslexp.pose.extract import ExtractionError, mediapipe_python

    video = DATA / "videos" / "wlasl" / "63185.mp4"
    try:
        mediapipe_python()
    except ExtractionError:
        with pytest.raises(DataError) as error:
            check_inputs({"input": str(video), "model": str(model_dir), "top_k": 10, "format": "md", "data_root": None})
        message = str(error.value)
        assert message.startswith(f"input={video}: a video needs MediaPipe") and "\n" not in message
        return
    proc = _cli(["lookup", f"input={video}", f"model={model_dir}", f"hydra.run.dir={tmp_path / 'video'}"], cache)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((tmp_path / "video" / "metrics.json").read_text())
    assert len(metrics["top"]) == 10 and (tmp_path / "video" / "keypoints" / "63185.npy").is_file()
    assert metrics["truth"] is None or metrics["truth"]["gloss"] == "whistle"  # WLASL's, not the model's clips


def test_the_first_plain_word_is_the_input():
    assert positional_input(["a/clip.npy", "model=run", "--cfg", "job"]) == ["input='a/clip.npy'", "model=run", "--cfg",
                                                                           "job"]
    assert positional_input(["--cfg", "job", "model=run"]) == ["--cfg", "job", "model=run"]
    assert positional_input(["input=x.pose", "-m", "top_k=5,10"]) == ["input=x.pose", "-m", "top_k=5,10"]
    assert positional_input(["it's.npy"]) == ['input="it\'s.npy"']
