"""One damaged run file never stops the tools: `runs list`, `runs diff`, `report`,
`sweep status` and `sweep best` on a real sweep folder where trials' run.json, metrics.json and
.hydra/overrides.yaml were damaged after the fact. Each tool names every damaged file it reads in
one warning line, goes on with the rest and exits as documented; no traceback. `report` on a
clean Optuna sweep folder reports its runs."""

from __future__ import annotations

import csv
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import job_process
from runs_helpers import run_cli

N_TRIALS = 8
# What is written over a trial's file, and the problem its warning line must state.
DAMAGE = {
    "run_list": ("run.json", "[1, 2]\n", "a JSON list, expected an object"),
    "status_number": ("run.json", None, '"status" is 5 (a number), expected a string'),
    "metric_text": ("run.json", None, '"main_metric" is "x" (a string), expected an object'),
    "metrics_empty": ("metrics.json", "", "empty file"),
    "overrides_yaml": (".hydra/overrides.yaml", "- x=1\n- [unclosed\n", "not valid YAML"),
    "overrides_mapping": (".hydra/overrides.yaml", "x: 1\ny: 2\n", "a mapping, expected a list of overrides"),
}


def report(*args: str, cwd: Path) -> subprocess.CompletedProcess:
    """``aslexp report ...`` as the CLI dispatches it."""
    return job_process.run([sys.executable, "-m", "aslexp.cli", "report", *args], cwd=cwd, capture_output=True,
                          text=True, timeout=120, env={**os.environ, "MPLBACKEND": "Agg"})


pytestmark = pytest.mark.xdist_group("damaged_sweep")  # one worker runs the module's sweep once

@pytest.fixture(scope="module")
def folders(tmp_path_factory) -> dict:
    """A real Optuna sweep of the quadratic job (8 completed trials), a clean copy of it, and the
    damage done to the original: the best trial's overrides.yaml is invalid YAML (so `sweep best`
    meets it), the other kinds go to trials 1-5; trials 6-7 (and 0 unless best) stay intact."""
    root = tmp_path_factory.mktemp("damaged")
    sweep = root / "sweep"
    job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", "-m", "+sweeps=quadratic",
                    f"hydra.sweep.dir={sweep}", f"hydra.sweeper.n_trials={N_TRIALS}",
                    "hydra/sweeper/sampler=random", "hydra.sweeper.sampler.seed=5", "steps=2", "seed=11"],
                   cwd=root, check=True, capture_output=True, timeout=120)
    clean = root / "clean"
    shutil.copytree(sweep, clean)
    values = {n: json.loads((sweep / str(n) / "run.json").read_text())["main_metric"]["value"]
              for n in range(N_TRIALS)}
    best = max(values, key=values.get)
    others = [n for n in range(1, N_TRIALS) if n != best]
    trials = {"overrides_yaml": best, **dict(zip([k for k in DAMAGE if k != "overrides_yaml"], others))}
    damaged = {}
    for kind, number in trials.items():
        name, text, problem = DAMAGE[kind]
        path = sweep / str(number) / name
        if text is None:  # a field of the wrong type
            info = json.loads(path.read_text())
            info.update({"status": 5} if kind == "status_number" else {"main_metric": "x"})
            text = json.dumps(info)
        path.write_text(text)
        damaged[kind] = (number, path, problem)
    intact = [n for n in range(N_TRIALS) if n not in trials.values()]
    return {"root": root, "sweep": sweep, "clean": clean, "damaged": damaged, "intact": intact, "best": best}


def named(stderr: str, kinds: list[str], damaged: dict) -> None:
    """Each damaged file of ``kinds`` is named in exactly one line, which says what is wrong."""
    assert "Traceback" not in stderr
    for kind in kinds:
        _, path, problem = damaged[kind]
        lines = [line for line in stderr.splitlines() if f"{path}:" in line]
        assert len(lines) == 1, (kind, stderr)
        assert problem in lines[0], (kind, lines[0])


def test_runs_list_skips_the_damaged_runs_and_names_each_file(folders):
    sweep, damaged = folders["sweep"], folders["damaged"]
    proc = run_cli("runs", "list", str(sweep), "--format", "json", check=False)
    assert proc.returncode == 0, proc.stderr
    listed = {Path(row["path"]).name for row in json.loads(proc.stdout)}
    bad_run_json = {str(damaged[k][0]) for k in ("run_list", "status_number", "metric_text")}
    assert listed == {str(n) for n in range(N_TRIALS)} - bad_run_json
    named(proc.stderr, ["run_list", "status_number", "metric_text", "overrides_yaml", "overrides_mapping"], damaged)
    table = run_cli("runs", "list", str(sweep), "--sort", "metric", check=False)
    assert table.returncode == 0 and "Traceback" not in table.stderr
    assert len([line for line in table.stdout.splitlines() if "quadratic" in line]) == len(listed)


def test_runs_diff_of_a_damaged_run_is_one_line_and_exit_2(folders):
    sweep, damaged, good = folders["sweep"], folders["damaged"], folders["intact"][0]
    for kind in ("run_list", "status_number", "metric_text", "overrides_yaml", "overrides_mapping"):
        number, path, problem = damaged[kind]
        proc = run_cli("runs", "diff", str(sweep / str(good)), str(sweep / str(number)), check=False)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr + proc.stdout, (kind, proc.stderr)
        lines = proc.stderr.splitlines()
        assert len(lines) == 1 and lines[0].startswith(f"aslexp runs diff: {path}: ") and problem in lines[0]
        assert proc.stdout == ""
    # runs diff reads no metrics.json (the main metric is run.json's): that run compares as usual
    number = damaged["metrics_empty"][0]
    proc = run_cli("runs", "diff", str(sweep / str(good)), str(sweep / str(number)), check=False)
    assert proc.returncode == 0 and "config: 2 changed" in proc.stdout and proc.stderr == ""


def test_report_reports_the_good_runs_and_names_each_damaged_file(folders, tmp_path):
    sweep, damaged = folders["sweep"], folders["damaged"]
    proc = report(str(sweep), "--out", str(tmp_path / "out"), cwd=folders["root"])
    assert proc.returncode == 0, proc.stderr
    named(proc.stderr, ["run_list", "status_number", "metric_text", "overrides_yaml", "overrides_mapping"], damaged)
    with open(tmp_path / "out" / "runs.csv", encoding="utf-8") as fh:
        runs = {Path(row["run"]).name for row in csv.DictReader(fh)}
    bad = {str(damaged[k][0]) for k in ("run_list", "status_number", "metric_text")}
    assert runs == {str(n) for n in range(N_TRIALS)} - bad
    assert f"{len(runs)} runs of other jobs" in proc.stdout


def test_sweep_status_names_each_damaged_trial_file(folders):
    sweep, damaged = folders["sweep"], folders["damaged"]
    proc = run_cli("sweep", "status", str(sweep), check=False)
    assert proc.returncode == 0 and f"complete {N_TRIALS}" in proc.stdout, proc.stderr
    named(proc.stderr, list(DAMAGE), damaged)
    assert json.loads(run_cli("sweep", "status", str(sweep), "--json").stdout)["counts"] == {"complete": N_TRIALS}


def test_sweep_best_falls_back_to_the_study_record_and_names_the_file(folders):
    sweep, clean, damaged = folders["sweep"], folders["clean"], folders["damaged"]
    proc = run_cli("sweep", "best", str(sweep), "--json", check=False)
    assert proc.returncode == 0, proc.stderr
    named(proc.stderr, ["overrides_yaml"], damaged)
    best = json.loads(proc.stdout)
    assert best["number"] == folders["best"]
    # the command is the study's record of the trial's overrides: what the clean folder's file says
    assert best["command"] == json.loads(run_cli("sweep", "best", str(clean), "--json").stdout)["command"]
    assert best["command"].startswith("aslexp quadratic +sweeps=quadratic ")


def test_report_on_a_clean_optuna_sweep_reports_its_runs(folders, tmp_path):
    clean = folders["clean"]
    proc = report(str(clean), "--out", str(tmp_path / "out"), cwd=folders["root"])
    assert proc.returncode == 0 and proc.stderr.count("warning") == 0, proc.stderr
    lines = [line for line in proc.stdout.splitlines() if line.startswith("| quadratic |")]
    assert len(lines) == N_TRIALS
    values = [float(line.split("|")[5]) for line in lines]
    assert values == sorted(values, reverse=True)  # best first (maximize)
    assert f"aslexp sweep report {clean}" in proc.stdout


def test_a_damaged_sweep_json_or_missing_folder_is_one_line_and_exit_2(folders, tmp_path):
    broken = tmp_path / "broken"
    shutil.copytree(folders["clean"], broken)
    (broken / "sweep.json").write_text("[]")
    for command in ("status", "best"):
        proc = run_cli("sweep", command, str(broken), check=False)
        assert proc.returncode == 2 and "Traceback" not in proc.stderr, proc.stderr
        assert proc.stderr.splitlines() == [f"aslexp sweep {command}: {broken / 'sweep.json'}: a JSON list, "
                                            "expected an object; pass --storage and --study to read the study "
                                            "without it"]
    proc = report(str(tmp_path / "nope"), cwd=tmp_path)
    assert proc.returncode == 2 and proc.stderr.splitlines() == [f"aslexp report: {tmp_path / 'nope'}: no such "
                                                                  "file or directory"]
