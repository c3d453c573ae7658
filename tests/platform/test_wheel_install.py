"""A wheel built from the clone runs on its own: configs travel as package data."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT.parent / "shared" / "data"


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    wheels = tmp_path_factory.mktemp("wheel")
    built = subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
                            "-w", str(wheels), "-q"], capture_output=True, text=True, timeout=300)
    assert built.returncode == 0, built.stderr[-2000:]
    target = tmp_path_factory.mktemp("site")
    wheel = next(wheels.glob("aslexp-*.whl"))
    done = subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "--target", str(target), str(wheel),
                           "-q"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    return target


def _run(target: Path, cwd: Path, *args: str) -> subprocess.CompletedProcess:
    # The installed copy first on the path, run away from the clone: no conf/ to fall back on.
    env = {**os.environ, "PYTHONPATH": str(target), "ASLEXP_DATA_ROOT": str(DATA),
           "ASLEXP_CACHE_DIR": str(cwd / "cache"), "MPLBACKEND": "Agg"}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=600)


def test_an_installed_wheel_runs_recognize_and_gym_make(installed, tmp_path):
    where = _run(installed, tmp_path, "-c", "import aslexp.paths as p; print(p.CONF_DIR)")
    assert where.stdout.strip() == str(installed / "aslexp" / "_conf"), where.stderr[-1000:]
    job = _run(installed, tmp_path, "-m", "aslexp.cli", "recognize", "experiment=debug", "classifier=logreg")
    assert job.returncode == 0, job.stderr[-2000:]
    assert len(list((tmp_path / "outputs" / "recognize").rglob("metrics.json"))) == 1
    env = _run(installed, tmp_path, "-c",
               "import gymnasium as gym, aslexp.envs\n"
               "env = gym.make('aslexp/HandImitation-v0', motion='A')\n"
               "obs, _ = env.reset(seed=0); print(obs.shape, env.unwrapped.motion.source)")
    assert env.returncode == 0, env.stderr[-2000:]
    assert env.stdout.split()[0] == "(269,)" and env.stdout.strip().endswith("motions/hand/A.txt")
    sweeps = _run(installed, tmp_path, "-m", "aslexp.cli", "recognize", "--help")
    assert "classifier_mlp" in sweeps.stdout
    # The archived overlays and the README the help names travel too.
    archive = installed / "aslexp" / "_conf" / "experiment" / "archive"
    assert (archive / "README.md").is_file() and (archive / "chapter3_cv5.yaml").is_file()
    assert "thesis_ch3_protocol" in sweeps.stdout and "and 1 archived probe" in sweeps.stdout
