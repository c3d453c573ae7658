"""tests/job_process.py gives a job what a fresh interpreter gives it: the same folder, environment,
arguments, stdin, stdout, stderr, exit code and exit handlers, compared here with subprocess.run on
the same script and module."""

from __future__ import annotations

import os
import subprocess
import sys

import job_process
import pytest

SCRIPT = r'''
import atexit, json, os, sys
atexit.register(lambda: open("atexit.txt", "w").write("ran"))
print(json.dumps({"cwd": os.getcwd(), "argv": sys.argv[1:], "var": os.environ.get("JOB_PROCESS_VAR"),
                  "stdin": sys.stdin.read(), "path0": sys.path[0], "main": __name__}))
print("to stderr", file=sys.stderr)
kind = sys.argv[1]
if kind == "code":
    sys.exit(3)
if kind == "message":
    sys.exit("stopped: a message")
if kind == "raise":
    raise ValueError("a failure")
'''


@pytest.fixture()
def script(tmp_path):
    path = tmp_path / "scripts" / "job.py"
    path.parent.mkdir()
    path.write_text(SCRIPT)
    return path


@pytest.mark.parametrize("kind", ["ok", "code", "message", "raise"])
def test_a_forked_job_and_a_fresh_one_give_the_same_result(script, tmp_path, kind):
    results = []
    for runner in (subprocess.run, job_process.run):
        cwd = tmp_path / runner.__module__
        cwd.mkdir()
        proc = runner([sys.executable, str(script), kind, "x y"], cwd=cwd, input="in", capture_output=True, text=True,
                      env={**os.environ, "JOB_PROCESS_VAR": "v"}, timeout=60)
        assert (cwd / "atexit.txt").read_text() == "ran"
        # The traceback names the same lines; only the folder in it differs.
        assert runner is subprocess.run or job_process.last_forked
        results.append((proc.returncode, proc.stdout.replace(str(cwd), "CWD"), proc.stderr.replace(str(cwd), "CWD")))
    assert results[0] == results[1]
    assert results[0][0] == {"ok": 0, "code": 3, "message": 1, "raise": 1}[kind]


def test_a_module_runs_as_its_main_and_output_not_captured_reaches_this_process(tmp_path, capfd):
    forked = job_process.run([sys.executable, "-m", "json.tool"], input='{"a": 1}', capture_output=True, text=True)
    assert forked.returncode == 0 and forked.stdout == subprocess.run(
        [sys.executable, "-m", "json.tool"], input='{"a": 1}', capture_output=True, text=True).stdout
    job_process.run([sys.executable, "-m", "json.tool"], input='{"b": 2}', text=True)
    assert '"b": 2' in capfd.readouterr().out
    with pytest.raises(subprocess.CalledProcessError):
        job_process.run([sys.executable, "-m", "json.tool"], input=b"not json", capture_output=True, check=True)
    assert job_process.last_forked


def test_a_job_past_its_timeout_is_killed_with_what_it_started(script, tmp_path):
    sleeper = tmp_path / "sleeper.py"
    marker = tmp_path / "child.pid"
    sleeper.write_text("import subprocess, sys, time\n"
                       f"child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'])\n"
                       f"open({str(marker)!r}, 'w').write(str(child.pid))\n"
                       "time.sleep(60)\n")
    with pytest.raises(subprocess.TimeoutExpired):
        job_process.run([sys.executable, str(sleeper)], capture_output=True, timeout=5)
    assert job_process.last_forked  # (subprocess.run would leave the grandchild running)
    pid = int(marker.read_text())
    try:  # killed: gone, or a zombie until init collects it
        with open(f"/proc/{pid}/stat") as stat:
            assert stat.read().rsplit(")", 1)[1].split()[0] in "ZX"
    except FileNotFoundError:
        pass


def test_an_environment_read_at_import_gets_a_fresh_interpreter(tmp_path):
    code = [sys.executable, "-m", "aslexp.cli", "--help"]
    assert job_process.run(code, capture_output=True, text=True).returncode == 0
    # A different PYTHONPATH is read when the interpreter starts: run fresh, so the job sees it.
    (tmp_path / "sitecustomize.py").write_text("print('fresh interpreter')\n")
    proc = job_process.run(code, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert not job_process.last_forked and proc.returncode == 0 and proc.stdout.startswith("fresh interpreter")
