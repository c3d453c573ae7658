"""Files from elsewhere never run code: a PPO checkpoint is read with
``torch.load(weights_only=True)`` and an ids file of published keypoints is never unpickled.

Each hostile file is a real pickle whose ``__reduce__`` creates a marker file when unpickled; a
control loads one the unsafe way to show that the payload works, so a missing marker means the
loader refused it, not that the payload was harmless.
"""

from __future__ import annotations

import json
import pickle
import random
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from platform_helpers import error_lines

from aslexp.data.root import resolve_data_root
from aslexp.errors import DataError
from aslexp.keypoints.published import CONVERT_PICKLE, PublishedArraySource, read_video_ids, write_published_arrays
from aslexp.rl.checkpoint import FORMAT, CheckpointError, load_checkpoint, save_checkpoint


class Touch:
    """Unpickling this creates ``marker`` (pathlib.Path.touch, no shell needed)."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (self.marker,))


def hostile_checkpoint(path: Path, marker: Path, fmt: str = FORMAT) -> Path:
    """What a real checkpoint looks like (format, steps, a tensor) plus the payload."""
    torch.save({"format": fmt, "steps": 512, "agent": {"w": torch.zeros(3)}, "numpy_rng": Touch(marker)}, path)
    return path


def test_the_hostile_payload_runs_when_loaded_unsafely(tmp_path):
    """The control: with weights_only=False (what aslexp did before) the payload runs."""
    marker = tmp_path / "control_marker"
    path = hostile_checkpoint(tmp_path / "evil.pt", marker)
    torch.load(path, weights_only=False)
    assert marker.exists()
    marker.unlink()
    (tmp_path / "evil.pkl").write_bytes(pickle.dumps(Touch(marker)))
    pickle.loads((tmp_path / "evil.pkl").read_bytes())
    assert marker.exists()


@pytest.mark.parametrize("fmt", [FORMAT, "aslexp-ppo-1"])
def test_a_hostile_checkpoint_is_refused_and_runs_nothing(tmp_path, fmt):
    marker = tmp_path / "marker"
    path = hostile_checkpoint(tmp_path / "last.pt", marker, fmt)
    with pytest.raises(CheckpointError) as err:
        load_checkpoint(path)
    message = str(err.value)
    assert not marker.exists()
    assert "\n" not in message and str(path) in message and "refused" in message
    assert "needs the Python object" in message and "older aslexp" in message and "weights_only" not in message


def test_imitate_resume_from_a_hostile_checkpoint_stops_in_one_line_and_runs_nothing(aslexp, tmp_path):
    if not (resolve_data_root(None, must_exist=False) / "motions" / "hand" / "B.txt").is_file():
        pytest.skip("thesis motions not found")
    marker = tmp_path / "marker"
    run = tmp_path / "trained"  # a run folder: +resume=DIR reads DIR/checkpoints/last.pt
    (run / "checkpoints").mkdir(parents=True)
    hostile_checkpoint(run / "checkpoints" / "last.pt", marker)
    proc = aslexp("imitate", "motion=B", "env=residual", "ppo=fast", "ppo.total_steps=256", "plots=false",
                  "render.gif=false", f"+resume={run}", f"hydra.run.dir={tmp_path / 'resumed'}", check=False)
    assert proc.returncode == 2 and not marker.exists()  # bad input
    lines = error_lines(proc.stderr)
    assert len(lines) == 1 and "Traceback" not in proc.stderr + proc.stdout, proc.stderr
    assert f"{run / 'checkpoints' / 'last.pt'} refused" in lines[0] and "older aslexp" in lines[0]
    info = json.loads((tmp_path / "resumed" / "run.json").read_text())
    assert info["status"] == "failed" and "refused" in info["error"]


def test_a_checkpoint_round_trips_exactly_and_only_plain_data_is_written(tmp_path):
    """Everything a resume restores comes back equal under weights_only (numpy and Python RNG
    state, torch RNG state, tensors, nested history); numpy values come back as numbers and
    tensors; anything else is refused at save, before a file is written."""
    rng = np.random.default_rng(7)
    rng.random(3)
    state = {
        "agent": torch.nn.Linear(3, 2).state_dict(), "torch_rng": torch.get_rng_state(),
        "numpy_rng": rng.bit_generator.state, "python_rng": random.Random(3).getstate(),
        "history": [{"step": 128, "eval_reward": np.float64(0.5), "count": np.int64(2)}],
        "stats": {"mean": np.arange(4.0)}, "best_eval": -float("inf"), "config": {"hidden_sizes": (32, 32)},
    }
    path = save_checkpoint(tmp_path / "last.pt", state)
    loaded = load_checkpoint(path)
    assert loaded["format"] == FORMAT
    assert all(torch.equal(a, b) for a, b in zip(state["agent"].values(), loaded["agent"].values()))
    assert torch.equal(loaded["torch_rng"], state["torch_rng"]) and loaded["config"] == {"hidden_sizes": (32, 32)}
    again = np.random.default_rng(0)
    again.bit_generator.state = loaded["numpy_rng"]
    assert np.array_equal(again.random(5), rng.random(5))
    python = random.Random()
    python.setstate(loaded["python_rng"])
    assert python.random() == random.Random(3).random()
    assert loaded["history"] == [{"step": 128, "eval_reward": 0.5, "count": 2}]
    assert type(loaded["history"][0]["eval_reward"]) is float and loaded["best_eval"] == -float("inf")
    assert torch.equal(loaded["stats"]["mean"], torch.arange(4.0, dtype=torch.float64))

    with pytest.raises(TypeError, match=r"payload\['extra'\].*pathlib"):
        save_checkpoint(tmp_path / "other.pt", {"extra": tmp_path})
    assert not (tmp_path / "other.pt").exists()


def test_an_older_plain_checkpoint_still_loads(tmp_path):
    torch.save({"format": "aslexp-ppo-1", "steps": 512, "agent": {"w": torch.ones(2)}}, tmp_path / "old.pt")
    assert load_checkpoint(tmp_path / "old.pt")["steps"] == 512
    torch.save({"format": "something-else"}, tmp_path / "foreign.pt")
    with pytest.raises(CheckpointError, match="not an aslexp-ppo-2 checkpoint"):
        load_checkpoint(tmp_path / "foreign.pt")


def published(tmp_path: Path) -> tuple[Path, list[str]]:
    ids = ["00001", "00002", "00003"]
    clips = [np.random.default_rng(i).random((4, 27, 3)).astype(np.float32) for i in range(3)]
    return write_published_arrays(tmp_path / "data.npy", clips, ids, 4), ids


@pytest.mark.parametrize("name", ["ids.pkl", "label.pickle", "file_list.txt"])
def test_a_pickled_ids_file_is_refused_unread(tmp_path, name):
    array, _ = published(tmp_path)
    marker = tmp_path / "marker"
    ids_path = tmp_path / name  # a pickle under a text name is refused too (its first byte says so)
    ids_path.write_bytes(pickle.dumps(Touch(marker)))
    with pytest.raises(DataError) as err:
        PublishedArraySource(array, ids_path)
    message = str(err.value)
    assert not marker.exists()
    assert "\n" not in message and message.startswith(f"{ids_path}: a pickle is not read")
    assert ".json" in message and ".csv" in message and ".txt" in message and "python -c" in message


def test_the_conversion_in_the_refusal_turns_a_trusted_label_pickle_into_ids(tmp_path):
    array, ids = published(tmp_path)
    label = tmp_path / "label.pkl"
    label.write_bytes(pickle.dumps(([f"{i}.mp4" for i in ids], np.arange(3))))  # SL-GCN's (names, labels)
    command = CONVERT_PICKLE.replace("label.pkl", str(label)).replace("file_list.txt", str(tmp_path / "ids.txt"))
    subprocess.run(["bash", "-c", command.replace("python", sys.executable, 1)], check=True, timeout=60)
    assert read_video_ids(tmp_path / "ids.txt") == ids
    assert PublishedArraySource(array, tmp_path / "ids.txt").video_ids == ids
    docs = (Path(__file__).resolve().parents[2] / "docs" / "recognition.md").read_text(encoding="utf-8")
    assert CONVERT_PICKLE in docs  # the documented command is the one tested here
