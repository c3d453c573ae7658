"""A finished run is never rewritten; errors and signals end a job with one line and the right
exit code; the run folder tells what happened."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import job_process
from platform_helpers import error_lines, folder_hashes, quadratic


def test_refused_imitate_rerun_leaves_the_finished_run_byte_identical(aslexp, tmp_path):
    run_dir = tmp_path / "imitate"
    aslexp("imitate", "ppo.total_steps=0", "plots=false", "render.gif=false",
           f"hydra.run.dir={run_dir}")
    before = folder_hashes(run_dir)
    again = aslexp("imitate", "motion=B", "seed=4", "ppo.total_steps=0", f"hydra.run.dir={run_dir}",
                   check=False)
    assert again.returncode == 2
    assert folder_hashes(run_dir) == before
    assert error_lines(again.stderr) == [next(ln for ln in again.stderr.splitlines()
                                              if "holds a finished run" in ln)]
    assert "add overwrite=true" in again.stderr


def test_a_multirun_into_a_folder_of_finished_runs_is_refused_untouched(tmp_path):
    sweep = tmp_path / "grid"
    quadratic("-m", "x=0.1,0.2", f"hydra.sweep.dir={sweep}", cwd=tmp_path)
    before = folder_hashes(sweep)
    assert {"0/run.json", "1/run.json", "multirun.yaml"} <= set(before)
    again = quadratic("-m", "x=0.5,0.6", f"hydra.sweep.dir={sweep}", cwd=tmp_path, check=False)
    assert again.returncode == 2 and folder_hashes(sweep) == before
    assert error_lines(again.stderr) == [
        f"aslexp quadratic: {sweep} holds 2 finished run(s) of an earlier multirun (e.g. {sweep}/0); "
        "nothing was changed: choose another hydra.sweep.dir (the default has the date and time), "
        "or add overwrite=true to run into it again"]
    # overwrite=true is the override that works (not +overwrite=true): the runs are replaced.
    quadratic("-m", "x=0.5,0.6", f"hydra.sweep.dir={sweep}", "overwrite=true", cwd=tmp_path)
    assert json.loads((sweep / "1" / "metrics.json").read_text())["x"] == 0.6


def test_a_single_run_prints_its_folder_and_rounds_logged_floats(tmp_path):
    run_dir = tmp_path / "run"
    done = quadratic("x=0.123456789", f"hydra.run.dir={run_dir}", cwd=tmp_path)
    logged = done.stdout.splitlines()
    assert logged[0].endswith(f"quadratic: run folder {run_dir}")
    assert logged[-1].endswith(f"quadratic completed: run folder {run_dir}")
    assert "objective(x=0.1235, y=0) = -1.031" in done.stdout  # 4 significant digits in the log
    assert "0.123456789" not in (run_dir / "quadratic.log").read_text()
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["x"] == 0.123456789 and metrics["objective"] == -(0.123456789 - 0.3) ** 2 - 1


@pytest.mark.parametrize("override, code, message", [
    ("xx=1", 2, "aslexp quadratic: Could not override 'xx'. To append to your config use +xx=1; "
                "--debug shows the traceback"),
    ("fail_if=always", 1, "aslexp quadratic: RuntimeError: quadratic: fail_if 'always' holds at "
                          "x=0.0, y=0.0 (run folder {run})"),
    ("nan_if=always", 1, "aslexp quadratic: ValueError: the objective is nan, not a finite number "
                         "(run folder {run})"),
])
def test_errors_are_one_line_and_tracebacks_come_on_request(tmp_path, override, code, message):
    run_dir = tmp_path / "run"
    proc = quadratic(override, f"hydra.run.dir={run_dir}", cwd=tmp_path, check=False)
    assert proc.returncode == code
    assert error_lines(proc.stderr) == [message.format(run=run_dir)]
    if run_dir.exists():  # the run folder keeps the story: failed, the error, its traceback
        info = json.loads((run_dir / "run.json").read_text())
        assert info["status"] == "failed" and info["error"] in message
    if override == "nan_if=always":
        return  # a NaN objective has no traceback to show
    for flag, env in (("--debug", {}), (f"hydra.run.dir={tmp_path / 'debug'}", {"HYDRA_FULL_ERROR": "1"})):
        loud = quadratic(override, flag, cwd=tmp_path, check=False, env=env)
        assert loud.returncode == code and "Traceback (most recent call last)" in loud.stderr


def test_a_bad_data_root_is_one_line(aslexp, tmp_path):
    proc = aslexp("recognize", "experiment=debug", "classifier=logreg",
                  f"data.root={tmp_path / 'nowhere'}", f"hydra.run.dir={tmp_path / 'r'}", check=False)
    assert proc.returncode == 2  # bad input
    lines = error_lines(proc.stderr)
    assert len(lines) == 1 and "nowhere" in lines[0] and "data root" in lines[0]
    assert json.loads((tmp_path / "r" / "run.json").read_text())["status"] == "failed"


@pytest.mark.parametrize("signum, code, what", [(signal.SIGINT, 130, "Ctrl-C"),
                                                 (signal.SIGTERM, 143, "SIGTERM")])
def test_a_signal_ends_a_run_with_one_line_and_records_it_interrupted(tmp_path, signum, code, what):
    run_dir = tmp_path / "run"
    proc = subprocess.Popen([sys.executable, "-m", "aslexp.jobs.quadratic", "sleep=30",
                             f"hydra.run.dir={run_dir}"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))
    deadline = time.monotonic() + 60
    while not (run_dir / "run.json").exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(0.3)
    proc.send_signal(signum)
    _, stderr = proc.communicate(timeout=30)
    assert proc.returncode == code
    assert error_lines(stderr) == [f"aslexp quadratic: interrupted ({what}): run folder {run_dir} "
                                   "recorded as interrupted"]
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "interrupted" and what in info["error"]


def test_runs_list_looks_in_outputs_only_and_says_so(tmp_path):
    elsewhere = tmp_path / "project" / "somewhere_else"
    quadratic(f"hydra.run.dir={elsewhere}", cwd=tmp_path)  # a run outside ./outputs
    cli = [sys.executable, "-m", "aslexp.cli", "runs", "list"]
    none = job_process.run(cli, cwd=tmp_path / "project", capture_output=True, text=True)
    assert none.returncode == 2 and "no ./outputs here" in none.stderr  # the cwd is not walked
    quadratic("hydra.run.dir=outputs/r1", cwd=tmp_path / "project")
    found = job_process.run(cli, cwd=tmp_path / "project", capture_output=True, text=True, check=True)
    assert "runs under ./outputs" in found.stderr
    assert "outputs/r1" in found.stdout and "somewhere_else" not in found.stdout


def test_a_killed_run_is_listed_lost_not_running(tmp_path):
    run_dir = tmp_path / "outputs" / "killed"
    proc = subprocess.Popen([sys.executable, "-m", "aslexp.jobs.quadratic", "sleep=30",
                             f"hydra.run.dir={run_dir}"], cwd=tmp_path, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while not (run_dir / "run.json").exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    assert json.loads((run_dir / "run.json").read_text())["status"] == "running"
    rows = json.loads(job_process.run([sys.executable, "-m", "aslexp.cli", "runs", "list", "--format",
                                      "json"], cwd=tmp_path, capture_output=True, text=True,
                                     check=True).stdout)
    assert [r["status"] for r in rows] == ["lost"]
