"""A motion from elsewhere, given by file: named after the file unless named."""

from __future__ import annotations

import json
import shutil
import sys
from pathlib import Path

import pytest
import job_process

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
QUICK = ["ppo.total_steps=0", "plots=false", "render.gif=false", "render.mp4=false"]


@pytest.mark.parametrize("extra, name", [([], "my_letter"), (["motion.name=B_copy"], "B_copy")])
def test_a_motion_file_names_the_run_after_the_file_unless_named(tmp_path, extra, name):
    motion = tmp_path / "my_letter.txt"
    shutil.copy(DATA / "motions" / "hand" / "B.txt", motion)
    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.imitate", f"motion.file={motion}", *extra,
                           *QUICK, f"hydra.run.dir={tmp_path}/run_${{motion.name}}"], cwd=ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    run = tmp_path / f"run_{name}"
    assert json.loads((run / "metrics.json").read_text())["motion"] == name
    assert f"motion {name}: baselines" in (run / "imitate.log").read_text()


def _frames(path: Path) -> list[list[float]]:
    return json.loads(path.read_text())["Frames"]


def test_a_motion_of_another_body_s_width_names_the_body_that_runs_it(tmp_path):
    from aslexp.envs.imitation import ImitationEnv
    from aslexp.sim.motion import MotionFormatError

    # DeepMimic's humanoid3d layout: dt, root position and rotation, then 36 joint values (43).
    frame = [0.0333, 0, 0.9, 0, 1, 0, 0, 0] + [1, 0, 0, 0] * 8 + [0] * 4
    frame = frame[:44] + [0] * (44 - len(frame))
    walk = tmp_path / "humanoid_walk.txt"
    walk.write_text(json.dumps({"Loop": "wrap", "Frames": [frame] * 5}))
    with pytest.raises(MotionFormatError) as err:
        ImitationEnv(str(walk), body="upper_body", data_root=str(DATA))
    assert str(err.value).startswith(f"{walk}: the model expects 75 values per frame")
    assert str(err.value).endswith("; body=upper_body_humanoid runs motions of that width")


def test_a_travelling_root_on_a_held_root_is_warned_about(tmp_path, caplog):
    from aslexp.envs.imitation import ImitationEnv

    frames = _frames(DATA / "motions" / "hand" / "B.txt")
    for i, frame in enumerate(frames):
        frame[1] += 0.02 * i  # the root walks along x
    walking = tmp_path / "walking_B.txt"
    walking.write_text(json.dumps({"Loop": "wrap", "Frames": frames}))
    with caplog.at_level("WARNING", logger="aslexp.envs.imitation"):
        ImitationEnv(str(walking), data_root=str(DATA)).close()
        ImitationEnv(str(DATA / "motions" / "hand" / "B.txt"), data_root=str(DATA)).close()
    warnings = [r.getMessage() for r in caplog.records if "the root travels" in r.getMessage()]
    assert len(warnings) == 1 and warnings[0].startswith(f"{walking}: the root travels")
    assert "body.base=fixed holds it at its first pose" in warnings[0]
