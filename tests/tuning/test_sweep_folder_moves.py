"""A sweep folder is self-contained: moved, copied or read-only, it reads back.

sweep.json records the journal relative to the folder and the study records trial folders
relative to the study's home; the tools open the journal read-only and take no lock."""

from __future__ import annotations

import json
import shutil
import subprocess

import pytest
from optuna.trial import TrialState
from sweep_helpers import load_study, run_cli, run_sweep


def test_a_moved_and_a_copied_sweep_folder_each_read_and_resume_their_own_study(tmp_path):
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=3")
    assert json.loads((sweep / "sweep.json").read_text())["storage"] == "optuna.journal"

    moved = tmp_path / "moved"
    sweep.rename(moved)
    status = json.loads(run_cli("sweep", "status", str(moved), "--json").stdout)
    assert status["counts"] == {"complete": 3}
    best = json.loads(run_cli("sweep", "best", str(moved), "--json").stdout)
    assert best["run_dir"].startswith(str(moved)) and any(o.startswith("x=") for o in best["overrides"])

    copy = tmp_path / "copy"
    shutil.copytree(moved, copy)
    before = (moved / "optuna.journal").read_bytes()
    run_sweep(copy, "hydra.sweeper.n_trials=4")  # resumes in the copy, from the copy's journal
    assert (moved / "optuna.journal").read_bytes() == before
    assert [t.state for t in load_study(copy).trials] == [TrialState.COMPLETE] * 4
    assert len(load_study(moved).trials) == 3
    assert (copy / "3" / "metrics.json").is_file() and not (moved / "3").exists()
    copied = json.loads(run_cli("sweep", "status", str(copy), "--json").stdout)
    assert copied["counts"] == {"complete": 4}


def test_a_sweep_on_a_read_only_file_system_reads_back(tmp_path):
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=2")
    readonly = tmp_path / "readonly"
    readonly.mkdir()
    bind = subprocess.run(["mount", "--bind", str(sweep), str(readonly)], capture_output=True, text=True)
    if bind.returncode != 0:
        pytest.skip(f"cannot bind-mount here ({bind.stderr.strip()})")
    try:
        remount = subprocess.run(["mount", "-o", "remount,bind,ro", str(readonly)],
                                 capture_output=True, text=True)
        if remount.returncode != 0:
            pytest.skip(f"cannot remount read-only here ({remount.stderr.strip()})")
        with pytest.raises(OSError):
            (readonly / "probe").write_text("x")  # it is read-only, even for root
        status = run_cli("sweep", "status", str(readonly), "--json")
        assert json.loads(status.stdout)["counts"] == {"complete": 2}
        best = json.loads(run_cli("sweep", "best", str(readonly), "--json").stdout)
        assert best["run_dir"].startswith(str(readonly))
        listed = run_cli("runs", "list", str(readonly))
        assert listed.stdout.count("completed") >= 2 and "Traceback" not in listed.stderr
    finally:
        subprocess.run(["umount", str(readonly)], capture_output=True)
