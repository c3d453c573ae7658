"""Every command of docs/engines.md runs, as written, on tiny budgets (read from its ```bash blocks,
so a command that stops working, or a new one, is caught here)."""

from __future__ import annotations

import shlex
import subprocess
import sys
from pathlib import Path

import pytest
import job_process
from doc_commands import bash_lines

PROJECT_ROOT = Path(__file__).resolve().parents[2]
DOC = PROJECT_ROOT / "docs" / "engines.md"
VENV_BIN = Path(sys.executable).parent

# Documented command prefix -> what it gains to run in seconds (budgets, sizes, output folders).
TINY = {
    "aslexp imitate -m": ["motion=A", "ppo.total_steps=512", "ppo.steps_per_rollout=256", "ppo.eval_interval=512",
                          "ppo.eval_episodes=1", "ppo.eval_steps=30", "render.gif=false", "plots=false",
                          "hydra.sweep.dir={tmp}/sweep"],
    "aslexp imitate": ["ppo.total_steps=512", "ppo.steps_per_rollout=256", "ppo.eval_interval=512",
                       "ppo.eval_steps=30", "ppo.hidden_sizes=[32,32]", "render.gif=false", "plots=false",
                       "hydra.run.dir={tmp}/run"],
    "aslexp tune_pd": ["tuning.random.seconds=1.0", "hydra.run.dir={tmp}/tune"],
    "python -m aslexp.measure.engine_agreement": ["--letters", "A", "--signs", "", "--seconds", "0.3"],
    "python bench/engine.py": ["--seconds", "0.2", "--sizes", "4", "--bodies", "hand 30 Hz",
                               "--ppo-steps-per-rollout", "256"],
}


# The GPU scripts' imitate runs on the CPU: a first update of 1,024 steps (ppo=hand_thesis collects 10,240,
# seconds at this size) ends past MIN, and no figures (the run folder, metrics and archive are the check).
SHORT_UPDATE = "ppo.steps_per_rollout=1024 plots=false"


def commands() -> list[str]:
    return bash_lines(DOC)


def tiny(command: str, tmp: Path) -> list[str]:
    prefix = next(p for p in TINY if command.startswith(p))
    words = shlex.split(command)
    if words[0] == "aslexp":
        words[0] = str(VENV_BIN / "aslexp")
    elif words[0] == "python":
        words[0] = sys.executable
    words = [w.replace("outputs/", f"{tmp}/") for w in words]
    given = {w.split("=")[0] for w in words if "=" in w}
    return words + [w.format(tmp=tmp) for w in TINY[prefix] if w.split("=")[0] not in given]


@pytest.mark.parametrize("command", commands())
def test_every_engines_doc_command_runs(command, tmp_path):
    proc = job_process.run(tiny(command, tmp_path), cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=900)
    assert proc.returncode == 0, f"{command}\n{proc.stderr[-3000:]}"


def test_the_gpu_device_script_runs_on_the_cpu(tmp_path, data_root):
    """bench/gpu_letters_thesis.sh (the lent GPU machine's check in docs/engines.md) on the CPU path:
    one letter, one seed, seconds of training; its run folder and archive come back as on the GPU."""
    import json
    import os
    import tarfile

    out, runs = tmp_path / "out", tmp_path / "runs" / "letters_thesis_mujoco"
    out.mkdir()
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "OUT": str(out), "RUNS": str(runs), "DEV": "cpu", "MIN": "0.02", "LETTERS": "A",
           "SEEDS": "0", "BENCH": "0", "NOPIP": "1", "PY": sys.executable,
           "EXTRA": f"ppo.hidden_sizes=[32,32] ppo.eval_steps=30 {SHORT_UPDATE}"}
    proc = subprocess.run(["bash", "bench/gpu_letters_thesis.sh"], cwd=PROJECT_ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, (out / "log.txt").read_text()[-3000:]
    metrics = json.loads((runs / "A_s0" / "metrics.json").read_text())
    assert metrics["motion"] == "A" and metrics["steps"] > 0 and metrics["stopped"] == "max_minutes"
    with tarfile.open(out / "letters_thesis_mujoco.tgz") as archive:
        names = archive.getnames()
    assert "letters_thesis_mujoco/A_s0/metrics.json" in names and not any("checkpoints" in n for n in names)


def test_the_gpu_check_script_runs_on_the_cpu(tmp_path, data_root):
    """bench/gpu_check.sh (the lent GPU machine's test run and imitate on CUDA) on the CPU path, as its
    header's command: one test file, seconds of training, no baselines."""
    import json
    import os

    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "OUT": str(tmp_path), "NOPIP": "1", "DEV": "cpu",
           "MIN": "0.02", "PY": sys.executable, "TESTS": "tests/imitation/test_assembly.py",
           "EXTRA": f"report.baselines=[] ppo.hidden_sizes=[32,32] ppo.eval_steps=30 {SHORT_UPDATE}"}
    proc = subprocess.run(["bash", "bench/gpu_check.sh"], cwd=PROJECT_ROOT, env=env, capture_output=True, text=True,
                          timeout=600)
    log = (tmp_path / "log.txt").read_text()
    assert proc.returncode == 0 and "3 passed" in log, log[-3000:]
    metrics = json.loads((tmp_path / "imitate_B" / "metrics.json").read_text())
    assert metrics["motion"] == "B" and metrics["steps"] > 0 and metrics["device"] == "cpu"


def test_the_stacked_letters_gpu_script_runs_on_the_cpu(tmp_path, data_root):
    """bench/gpu_stacked_letters.sh (figure 5.9's runs as one program) on the CPU path, as its header's
    command: one letter, two seeds, seconds of training; the summary and the archive come back."""
    import json
    import os
    import tarfile

    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "OUT": str(tmp_path), "DEV": "cpu", "MIN": "0.05",
           "LETTERS": "A", "SEEDS": "0,1", "NOPIP": "1", "PY": sys.executable,
           "EXTRA": "ppo.hidden_sizes=[32,32] ppo.eval_steps=30 ppo.steps_per_rollout=1024"}
    proc = subprocess.run(["bash", "bench/gpu_stacked_letters.sh"], cwd=PROJECT_ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, (tmp_path / "log.txt").read_text()[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["runs"] == 2 and summary["steps_per_run"] > 0
    assert summary["letters"]["A"]["last_eval"]["seeds"] == [0, 1] and "lookahead" in summary["letters"]["A"]["baselines"]
    with tarfile.open(tmp_path / "letters_stacked.tgz") as archive:
        names = archive.getnames()
    assert "letters_stacked/A_s1/progress.csv" in names and not any("checkpoints" in n for n in names)
    assert "letters_stacked/A_s1/.hydra/config.yaml" in names  # policy=RUN rebuilds the run from it


def test_the_stacked_signs_gpu_script_runs_on_the_cpu(tmp_path, data_root):
    """bench/gpu_stacked_signs.sh (Table 6.7's Run 1 as one program) on the CPU path, as its header's
    command: one sign, two seeds, one small update; the summary and the archive come back."""
    import json
    import os
    import tarfile

    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "OUT": str(tmp_path), "DEV": "cpu", "MIN": "0.05",
           "SIGNS": "00433", "SEEDS": "0,1", "NOPIP": "1", "PY": sys.executable, "ENVS": "2",
           "EXTRA": "ppo.hidden_sizes=[32,32] ppo.eval_steps=30 ppo.steps_per_rollout=512"}
    proc = subprocess.run(["bash", "bench/gpu_stacked_signs.sh"], cwd=PROJECT_ROOT, env=env, capture_output=True,
                          text=True, timeout=600)
    assert proc.returncode == 0, (tmp_path / "log.txt").read_text()[-3000:]
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["experiment"] == "signs_thesis_run1" and summary["runs"] == 2
    assert set(summary["letters"]) == {"00433"} and "lookahead" in summary["letters"]["00433"]["baselines"]
    with tarfile.open(tmp_path / "signs_run1.tgz") as archive:
        assert "signs_run1/00433_s0/progress.csv" in archive.getnames()
