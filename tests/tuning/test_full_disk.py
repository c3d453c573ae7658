"""A full disk never costs a study: journal appends are all-or-nothing; and never
costs its budget: a trial whose own files find the disk full does not count, the
sweep waits for room (or stops in one line naming the file), and the trial's point runs again.

The disk is a real small tmpfs filled by a real file (root can mount one here and in CI); where
mounting is not permitted, the in-process test uses a file-size limit (``RLIMIT_FSIZE``), under
which the kernel cuts a write short exactly where a full disk would.
"""

from __future__ import annotations

import errno
import json
import os
import re
import resource
import subprocess
import threading
import time
from pathlib import Path

import pytest
import job_process
from optuna.trial import TrialState
from sweep_helpers import load_study, run_cli, sweep_command, wait_for

from aslexp.tuning.storage import AtomicJournalFileBackend, FlockJournalLock, JournalWriteError
from aslexp.tuning.worker import ATTR_ERROR, ATTR_RERUN_OF, ATTR_STATE, INTERRUPTED


class SmallDisk:
    """A tmpfs of ``size`` bytes at ``path``; ``fill()`` takes every free byte, ``free()`` gives
    them back."""

    def __init__(self, path: Path, size: str = "4m") -> None:
        self.path = path
        path.mkdir(parents=True, exist_ok=True)
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                              capture_output=True, text=True)
        if done.returncode != 0:
            raise PermissionError(done.stderr.strip())
        self.filler = path / "filler"

    def fill(self) -> None:
        fd = os.open(self.filler, os.O_WRONLY | os.O_CREAT | os.O_APPEND)
        try:
            for size in (1 << 16, 4096, 1):  # big blocks, then the crumbs a page leaves
                block = b"\0" * size
                try:
                    while True:
                        os.write(fd, block)
                except OSError as err:
                    assert err.errno == errno.ENOSPC
        finally:
            os.close(fd)

    def free(self) -> None:
        self.filler.unlink(missing_ok=True)

    def unmount(self) -> None:
        subprocess.run(["umount", "-l", str(self.path)], capture_output=True)


@pytest.fixture
def small_disk(tmp_path):
    try:
        disk = SmallDisk(tmp_path / "disk")
    except (PermissionError, FileNotFoundError) as err:
        pytest.skip(f"cannot mount a tmpfs here ({err})")
    yield disk
    disk.unmount()


def _record(i: int, pad: int = 0) -> dict:
    # ``pad``: a record larger than the slack of the file's last page (tmpfs allocates pages).
    return {"op_code": 0, "worker_id": "test", "study_name": f"s{i}", "directions": [1], "pad": "x" * pad}


def _lines(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_bytes().splitlines()]


def test_an_append_on_a_full_disk_waits_for_space_and_never_tears_the_file(small_disk):
    journal = small_disk.path / "optuna.journal"
    backend = AtomicJournalFileBackend(str(journal), FlockJournalLock(journal), full_disk_wait=30)
    backend.append_logs([_record(0)])
    small_disk.fill()
    freed = threading.Timer(1.5, small_disk.free)
    freed.start()
    start = time.monotonic()
    backend.append_logs([_record(1, 5000), _record(2)])  # waits until the disk has room again
    assert time.monotonic() - start >= 1.0
    freed.join()
    assert [r["study_name"] for r in _lines(journal)] == ["s0", "s1", "s2"]


def test_an_append_that_cannot_wait_longer_fails_naming_the_file_and_leaves_it_whole(small_disk):
    journal = small_disk.path / "optuna.journal"
    backend = AtomicJournalFileBackend(str(journal), FlockJournalLock(journal), full_disk_wait=0.5)
    backend.append_logs([_record(0)])
    intact = journal.read_bytes()
    small_disk.fill()
    big = [_record(1, 5000)]
    with pytest.raises(JournalWriteError) as err:
        backend.append_logs(big)
    assert str(err.value).startswith(f"journal file {journal}: the disk is full; the record was not written")
    assert journal.read_bytes() == intact  # nothing glued, nothing torn
    small_disk.free()
    backend.append_logs([_record(2)])
    assert [r["study_name"] for r in _lines(journal)] == ["s0", "s2"]


def test_a_short_write_under_a_file_size_limit_is_cut_back_and_retried(tmp_path):
    """The kernel's own short write (RLIMIT_FSIZE), for machines where no tmpfs can be mounted."""
    journal = tmp_path / "optuna.journal"
    backend = AtomicJournalFileBackend(str(journal), FlockJournalLock(journal), full_disk_wait=30)
    backend.append_logs([_record(0)])
    intact = journal.stat().st_size
    soft, hard = resource.getrlimit(resource.RLIMIT_FSIZE)
    resource.setrlimit(resource.RLIMIT_FSIZE, (intact + 40, hard))  # room for part of a record
    try:
        lifted = threading.Timer(1.0, resource.setrlimit, (resource.RLIMIT_FSIZE, (soft, hard)))
        lifted.start()
        backend.append_logs([_record(1)])
        lifted.join()
    finally:
        resource.setrlimit(resource.RLIMIT_FSIZE, (soft, hard))
    assert [r["study_name"] for r in _lines(journal)] == ["s0", "s1"]


def test_a_full_disk_during_a_sweep_costs_nothing_and_a_resume_completes_the_budget(small_disk):
    """The disk fills while a trial runs (heartbeats and reports hit it), stays full past the
    journal's wait, and is freed: the journal reads back whole and a resume completes the budget."""
    sweep = small_disk.path / "sweep"
    env = {**os.environ, "HYDRA_FULL_ERROR": "0", "ASLEXP_JOURNAL_FULL_DISK_WAIT": "2"}
    command = sweep_command(sweep, "hydra.sweeper.n_trials=4", "hydra.sweeper.heartbeat_interval=0.2",
                            "steps=4", "sleep=0.25")
    proc = subprocess.Popen(command, cwd=small_disk.path, env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: (sweep / "1").is_dir(), 60, "the second trial to start")
        small_disk.fill()
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
        small_disk.free()
    # The sweep stopped on the full disk, in one line that names the journal or the trial's file
    # (whichever the disk refused first); either way the journal is whole.
    journal = sweep / "optuna.journal"
    assert all(line.endswith(b"\n") for line in journal.read_bytes().splitlines(keepends=True))
    assert "Traceback" not in err
    if proc.returncode != 0:
        assert proc.returncode == 1
        last = err.strip().splitlines()[-1]
        named = (rf"aslexp quadratic: (journal file {re.escape(str(journal))}: the disk is full|"
                 rf"disk full: cannot write (in )?{re.escape(str(sweep))}/)")
        assert re.match(named, last), err[-2000:]
    resumed = job_process.run(command, cwd=small_disk.path, env=env, capture_output=True, text=True,
                             timeout=180)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    study = load_study(sweep)
    counted = [t for t in study.trials if t.state in (TrialState.COMPLETE, TrialState.PRUNED)
               or (t.state == TrialState.FAIL and t.user_attrs.get("aslexp_state") != "interrupted")]
    assert len(counted) == 4  # the budget, exactly
    assert [t for t in counted if t.state == TrialState.FAIL] == []  # no disk-full "result"
    assert len({t.number for t in study.trials}) == len(study.trials)
    status = run_cli("sweep", "status", str(sweep), "--json")
    assert json.loads(status.stdout)["trials"] == len(study.trials)
    assert _run_statuses(sweep).count("running") == 0


def _run_statuses(sweep: Path) -> list[str]:
    return [json.loads(p.read_text())["status"] for p in sorted(sweep.glob("*/run.json"))]


def _trial_files_fill_the_disk(small_disk, tmp_path, wait: float) -> tuple[list, dict, Path, Path]:
    """A 2-trial sweep whose trial folders are on the small disk and whose journal is not (the
    disk refuses the trial's own files only); the command, its environment, sweep and journal."""
    sweep, journal = small_disk.path / "sweep", tmp_path / "optuna.journal"
    env = {**os.environ, "HYDRA_FULL_ERROR": "0", "ASLEXP_JOURNAL_FULL_DISK_WAIT": str(wait)}
    command = sweep_command(sweep, "hydra.sweeper.n_trials=2", f"hydra.sweeper.storage={journal}",
                            "sleep=1")  # the disk fills while trial 0 sleeps
    return command, env, sweep, journal


def _assert_the_point_ran_again(study, sweep: Path) -> None:
    """Trial 0 (the disk refused its files) is interrupted, uncounted, its run.json says so with
    the same reason; trial 1 ran its point again; trial 2 is new: the budget of 2, exactly."""
    trials = study.trials
    assert [t.state for t in trials] == [TrialState.FAIL, TrialState.COMPLETE, TrialState.COMPLETE]
    lost = trials[0]
    assert lost.user_attrs[ATTR_STATE] == INTERRUPTED
    assert lost.user_attrs[ATTR_ERROR].startswith(f"disk full: cannot write {sweep}/0/")
    assert trials[1].params == lost.params and trials[1].user_attrs[ATTR_RERUN_OF] == 0
    assert trials[2].params != lost.params
    run = json.loads((sweep / "0" / "run.json").read_text())
    assert run["status"] == INTERRUPTED and run["error"] == lost.user_attrs[ATTR_ERROR]
    assert _run_statuses(sweep) == [INTERRUPTED, "completed", "completed"]


def _sweep_while_trial_0_fills_the_disk(small_disk, command, env, sweep, cwd, while_full=None):
    """Run the sweep, fill the disk once trial 0 has started; ``while_full`` (then space is freed),
    else the disk stays full until the sweep ends. Returns exit code, stdout and stderr."""
    proc = subprocess.Popen(command, cwd=cwd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        wait_for(lambda: (sweep / "0" / "run.json").is_file(), 60, "trial 0 to start")
        small_disk.fill()
        if while_full is not None:
            while_full()
            small_disk.free()
        out, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
        small_disk.free()
    return proc.returncode, out, err


def test_a_trial_whose_own_files_find_the_disk_full_does_not_count_and_the_sweep_waits(
        small_disk, tmp_path):
    """The disk fills while trial 0 runs (its run.json cannot be finished) and is freed a moment
    later: the sweep pauses instead of burning trials, then completes its budget exactly."""
    command, env, sweep, journal = _trial_files_fill_the_disk(small_disk, tmp_path, wait=60)

    def while_full() -> None:
        wait_for(lambda: load_study(sweep, storage=str(journal)).trials[0].state == TrialState.FAIL,
                 60, "trial 0 to be recorded")
        time.sleep(0.5)  # the sweep waits; no trial starts meanwhile
        assert len(load_study(sweep, storage=str(journal)).trials) == 1

    code, out, err = _sweep_while_trial_0_fills_the_disk(small_disk, command, env, sweep, tmp_path, while_full)
    assert code == 0, err[-3000:]
    assert "its parameters run again; waiting up to 60 s for room in" in out + err
    assert "has room again" in out + err
    _assert_the_point_ran_again(load_study(sweep, storage=str(journal)), sweep)


def test_a_disk_that_stays_full_stops_the_sweep_in_one_line_and_the_resume_reruns_the_point(
        small_disk, tmp_path):
    command, env, sweep, journal = _trial_files_fill_the_disk(small_disk, tmp_path, wait=1)
    code, out, err = _sweep_while_trial_0_fills_the_disk(small_disk, command, env, sweep, tmp_path)
    assert code == 1, err[-3000:]
    lines = [ln for ln in err.splitlines() if ln.startswith("aslexp quadratic: ")]
    assert len(lines) == 1 and "Traceback" not in err, err[-3000:]
    assert lines[0].startswith(f"aslexp quadratic: disk full: cannot write {sweep}/0/")
    assert ("within 1 s (ASLEXP_JOURNAL_FULL_DISK_WAIT); trial 0 is recorded interrupted and does "
            "not count toward the budget: free space, then run the same command") in lines[0]
    study = load_study(sweep, storage=str(journal))
    assert [t.state for t in study.trials] == [TrialState.FAIL]  # nothing burned while full
    assert _run_statuses(sweep) == ["running"]  # no room to say more, until the resume

    resumed = job_process.run(command, cwd=tmp_path, env=env, capture_output=True, text=True,
                             timeout=120)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    _assert_the_point_ran_again(load_study(sweep, storage=str(journal)), sweep)
