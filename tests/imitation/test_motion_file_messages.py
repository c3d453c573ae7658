"""What `aslexp imitate` says about a motion file: a frame duration out of the plausible range (one
warning line), one that cannot be played (refused), and a file that is not there (every place looked at)."""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path

import pytest
import job_process

from aslexp.sim.motion import load_motion

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"
QUICK = ["ppo.total_steps=0", "ppo.eval_steps=20", "ppo.eval_episodes=1", "plots=false", "render.gif=false",
         "render.mp4=false"]


def _imitate(*overrides: str, cwd: Path = ROOT):
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(DATA)}
    return job_process.run([sys.executable, "-m", "aslexp.jobs.imitate", *overrides], cwd=cwd, env=env,
                           capture_output=True, text=True, timeout=300)


def _with_frame_duration(path: Path, dt: float) -> Path:
    """Letter A with every frame's duration set to ``dt``."""
    payload = json.loads((DATA / "motions" / "hand" / "A.txt").read_text())
    for frame in payload["Frames"]:
        frame[0] = dt
    path.write_text(json.dumps(payload))
    return path


def _error_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.strip() and not line.startswith("[20")]


def test_the_thesis_motions_load_without_a_warning(caplog):
    files = sorted((DATA / "motions").glob("*/*.txt"))
    assert len(files) == 11
    with caplog.at_level("WARNING", logger="aslexp.motion"):
        for path in files:
            load_motion(path)
    assert not [r for r in caplog.records if "frame duration" in r.getMessage()]


def test_a_motion_ten_times_slower_runs_with_one_warning_line(tmp_path):
    slow = _with_frame_duration(tmp_path / "slow_A.txt", 0.3)
    run = tmp_path / "run"
    proc = _imitate(f"motion.file={slow}", *QUICK, f"hydra.run.dir={run}")
    assert proc.returncode == 0, proc.stderr[-2000:]
    said = [line for line in (proc.stdout + proc.stderr).splitlines() if "frame duration" in line]
    assert len(said) == 1, said  # the edge check loads the motion too, silently (the console log is stdout)
    assert "[aslexp.motion][WARNING]" in said[0]
    assert f"{slow}: frame duration 0.3 s is outside the expected range 0.004167-0.1 s" in said[0]
    assert "as given the motion lasts 12 s" in said[0]  # 40 intervals of 0.3 s
    logged = [line for line in (run / "imitate.log").read_text().splitlines() if "frame duration" in line]
    assert len(logged) == 1 and logged[0].endswith(said[0].split(" - ", 1)[1])


@pytest.mark.parametrize("dt", [0.0, -0.03, math.nan, math.inf])
def test_a_frame_duration_that_cannot_be_played_is_refused_in_one_line(tmp_path, dt):
    bad = _with_frame_duration(tmp_path / "bad_dt.txt", dt)
    run = tmp_path / "run"
    proc = _imitate(f"motion.file={bad}", *QUICK, f"hydra.run.dir={run}")
    assert proc.returncode == 2, proc.stderr[-2000:]
    [line] = _error_lines(proc.stderr)
    assert line == f"aslexp imitate: MotionFormatError: {bad}: frame 0 has duration dt={dt!r}; " \
                   f"expected a finite dt > 0 (seconds)"
    assert not run.exists()


def test_a_missing_motion_file_names_every_place_it_looked(tmp_path):
    given = "my_clips/walk.txt"
    proc = _imitate(f"motion.file={given}", *QUICK, cwd=tmp_path)
    assert proc.returncode == 2, proc.stderr[-2000:]
    [line] = _error_lines(proc.stderr)
    assert line.startswith(f"aslexp imitate: FileNotFoundError: motion file {given} not found; looked at ")
    assert f"{tmp_path / given} (as given, relative to the current directory {tmp_path})" in line
    assert f"{DATA.resolve() / given} (under the data root {DATA.resolve()};" in line
    assert not (tmp_path / "outputs").exists()


def test_a_missing_file_of_a_motion_name_or_an_absolute_path_says_so(tmp_path):
    from aslexp.envs.assembly import find_motion_file

    empty_root = tmp_path / "data"
    empty_root.mkdir()
    with pytest.raises(FileNotFoundError) as err:
        find_motion_file("A", empty_root)
    assert "motion file A (conf/motion/A.yaml names file motions/hand/A.txt) not found" in str(err.value)
    assert f"{empty_root / 'motions/hand/A.txt'} (under the data root {empty_root};" in str(err.value)
    absent = tmp_path / "absent.txt"
    with pytest.raises(FileNotFoundError, match=r"absent\.txt not found \(an absolute path: looked nowhere else\)"):
        find_motion_file(absent, empty_root)
    assert find_motion_file("A", DATA) == DATA / "motions" / "hand" / "A.txt"
