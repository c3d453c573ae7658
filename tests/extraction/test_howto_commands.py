"""Every command of the how-to pages and the README runs, as written, on tiny budgets.

docs/howto_keypoints.md, docs/howto_imitate.md and README.md are read from their ```bash blocks, so
a command that stops working, or a new one, is caught here. The commands run in one folder, in page
order (the imitate page retargets a `.pose` file the keypoints page extracted; that `--wlasl`
extraction is made first, once, by conftest's wlasl6, which the extraction tests read too), with small budgets:
ten frames a clip (the WLASL JSON cut as in conftest.SHORT_RANGES, `--frames` on a video, one
video of a folder), one epoch, two model seeds where an overlay asks for ten (thesis_ch3),
a few hundred PPO steps, an overlay's swept lists cut to one cell with plain overrides, small
SL-GCN channels, the CPU where a GPU is named but absent. `DIR` is a folder made (conftest's ws) for
the source the command names; the README's `<date>/<time>` folder is the one its runs were written
to. The sweep and run-folder commands (`+sweeps=`, `aslexp sweep`, `aslexp runs`) are run by
tests/tuning/test_docs_commands.py.
"""

from __future__ import annotations

import json
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import job_process
from doc_commands import bash_lines

from aslexp.keypoints import holistic as H

PROJECT_ROOT = Path(__file__).resolve().parents[2]
KEYPOINTS = PROJECT_ROOT / "docs" / "howto_keypoints.md"
IMITATE = PROJECT_ROOT / "docs" / "howto_imitate.md"
README = PROJECT_ROOT / "README.md"

# One worker: the pages share one folder (conftest's ws), with the extraction tests that read the
# page's `--wlasl` extraction (conftest's wlasl6, made there once).
pytestmark = [pytest.mark.usefixtures("worker_env"), pytest.mark.slow,  # about 4 + 1 min on 2 busy cores
              pytest.mark.xdist_group("extraction")]


def documented(path: Path) -> list[str]:
    """The `aslexp` commands of every ```bash block (continuations joined, comments dropped),
    less those tests/tuning/test_docs_commands.py runs."""
    return [line for line in bash_lines(path) if line.startswith("aslexp ") and not _elsewhere(line)]


def _elsewhere(line: str) -> bool:
    """The commands tests/tuning/test_docs_commands.py runs (its `keep`)."""
    return "+sweeps=" in line or line.startswith(("aslexp sweep ", "aslexp runs "))


# A documented override -> the overrides that cut it to a test's size (plain overrides replace an
# overlay's swept lists).
CUT = {
    "experiment=recognition_table": ["classifier=logreg", "property=sign_type", "split=phoneme", "split.repeats=2"],
    "experiment=thesis_ch4": ["classifier=mlp", "property=sign_type", "split=phoneme"],
    # Ten model seeds x five folds, the model and both simple baselines: two seeds keep mean and std.
    "experiment=thesis_ch3": ["classifier=logreg_thesis_ch3", "property=sign_type", "n_seeds=2"],
    "classifier=slgcn": ["classifier.params.channels=[16,16]"],
    # DIR holds the six clips (five with a hand): rare classes go to training.
    "pose.path=DIR": ["split.rare_classes=train_only"],
    # one policy of many motions: a few bodies and generated motions
    "experiment=letters_unseen": ["ppo.num_envs=8", "train_motions.generated.count=3"],
}
RECOGNIZE = ["trainer.max_epochs=1", "data.num_frames=16"]
# The default simple baselines' forest at a test's size, where the rf baseline runs (not where an
# overlay or the command names the simple baselines itself).
SMALL_FOREST = ["++simple_baseline_params.rf.n_estimators=20"]
IMITATE_TINY = ["ppo.total_steps=256", "ppo.steps_per_rollout=256", "ppo.eval_interval=256", "ppo.eval_episodes=1",
                "ppo.eval_steps=30", "ppo.hidden_sizes=[32,32]", "render.gif=false", "render.mp4=false", "plots=false"]


def tiny(command: str, ws: dict) -> list[str]:
    words = [w.replace("../shared/data/", f"{ws['data']}/") for w in shlex.split(command)[1:]]
    job, given = words[0], {w.split("=")[0] for w in words if "=" in w}
    extra: list[str] = []
    for key, cut in CUT.items():
        if key in words:
            extra += cut
    if "pose.path=DIR" in words:
        pose = next(w.split("=")[1] for w in words if w.startswith("pose="))
        words[words.index("pose.path=DIR")] = f"pose.path={ws['dirs'][pose]}"
    if "trainer.device=cuda" in words and not _cuda():
        words[words.index("trainer.device=cuda")] = "trainer.device=cpu"
    if job == "recognize":
        extra += RECOGNIZE + ([] if "experiment" in given else ["experiment=debug"])
        if "simple_baseline" not in given and "experiment=recognition_table" not in words:
            extra += SMALL_FOREST
    elif job == "imitate" and "--help" not in words:
        extra += IMITATE_TINY
    elif job == "extract" and "--wlasl" in words:
        words[words.index("--wlasl") + 1] = str(ws["short_json"])  # ten frames of each clip
    elif job == "extract" and words[1].endswith(".mp4"):
        extra += ["--frames", "20:29"]
    elif job == "extract" and Path(words[1]).is_dir():
        extra += ["--ids", "63185", "--frames", "20:29"]  # one clip of the folder
    elif job == "report":
        words = [str(ws["tmp"] / "outputs" / "recognize") if "<date>" in w else w for w in words]
    return words + [e for e in extra if e.split("=")[0] not in given]


def _cuda() -> bool:
    import torch

    return torch.cuda.is_available()


def run(command: str, ws: dict) -> subprocess.CompletedProcess:
    args = tiny(command, ws)
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", *args], cwd=ws["tmp"], env=ws["env"],
                          capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"`{command}` as `aslexp {shlex.join(args)}` exited {proc.returncode}:\n" \
                                 f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc


def _hands_from(keypoints: Path, out: Path) -> None:
    """pose=mediapipe_hands' DIR: <id>.npy (T, 126), both hands of the extracted Holistic arrays,
    missing = 0 as hand-only pipelines write them."""
    out.mkdir()
    for path in keypoints.glob("*.npy"):
        hands = np.nan_to_num(np.load(path)[:, H.LEFT_HAND_OFFSET :, :3], nan=0.0)
        np.save(out / path.name, hands.reshape(len(hands), 126))


def test_every_keypoints_howto_command_runs(ws, wlasl6):
    commands = documented(KEYPOINTS)
    assert any(c.startswith("aslexp extract --wlasl") for c in commands) and len(commands) >= 8, commands
    for command in commands:
        if command.startswith("aslexp extract --wlasl"):  # run by conftest's wlasl6, in this folder
            out, printed = wlasl6
            assert out == ws["tmp"] / "outputs" / "keypoints" / "wlasl6" and "6 extracted" in printed, printed
            _hands_from(out, ws["dirs"]["mediapipe_hands"])
        else:
            run(command, ws)
    runs = [json.loads(p.read_text()) for p in (ws["tmp"] / "outputs").rglob("run.json")]
    assert runs and {r["status"] for r in runs} == {"completed"}
    # The grid is 6 runs; each other recognize command (the overlays cut to one cell) one.
    assert len(runs) == 6 + sum(c.startswith("aslexp recognize") for c in commands) - 1


def test_every_imitate_howto_command_runs(ws, wlasl6):  # the page retargets wlasl6's 63185.pose
    commands = documented(IMITATE)
    assert any("motion.file=" in c for c in commands) and any("--motions" in c for c in commands), commands
    before = set((ws["tmp"] / "outputs").rglob("metrics.json"))
    for command in commands:
        run(command, ws)
    made = [json.loads(p.read_text()) for p in set((ws["tmp"] / "outputs").rglob("metrics.json")) - before]
    # motion=A, the pool's policy (tuning held out), and the four motions from files, each named after
    # its file (the last one performed by that policy, nothing trained).
    assert sorted(m["motion"] for m in made) == ["63185", "63185", "63185", "63185", "A", "tuning"]
    performed = next(m for m in made if m.get("stopped") == "performed")
    assert performed["steps"] == 0 and performed["policy"]["train_motions"] == "letters_generated"


def test_every_readme_command_runs(ws):
    commands = documented(README)
    assert [c.split()[1] for c in commands] == ["--help", "recognize", "imitate", "report", "extract"], commands
    for command in commands:
        run(command, ws)
    assert list((ws["tmp"] / "outputs" / "recognize").glob("table*.md"))  # the report, beside the runs
    assert list((ws["tmp"] / "outputs" / "keypoints" / "mediapipe" / "motions").rglob("63185.txt"))
