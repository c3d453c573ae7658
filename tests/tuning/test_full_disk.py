"""A full disk never costs a study (issue 26.1): journal appends are all-or-nothing.

The disk is a real small tmpfs filled by a real file (root can mount one here and in CI); where
mounting is not permitted, the in-process test uses a file-size limit (``RLIMIT_FSIZE``), under
which the kernel cuts a write short exactly where a full disk would.
"""

from __future__ import annotations

import errno
import json
import os
import resource
import subprocess
import threading
import time
from pathlib import Path

import pytest
from optuna.trial import TrialState
from sweep_helpers import load_study, run_cli, sweep_command, wait_for

from aslexp.tuning.storage import AtomicJournalFileBackend, FlockJournalLock, JournalWriteError


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
                            "steps=4", "sleep=0.5")
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
    # The sweep stopped on the full disk, in one line that names the journal (or finished with
    # failed trials whose own files could not be written); either way the journal is whole.
    journal = sweep / "optuna.journal"
    assert all(line.endswith(b"\n") for line in journal.read_bytes().splitlines(keepends=True))
    assert "Traceback" not in err
    if proc.returncode != 0:
        assert f"journal file {journal}: the disk is full" in err, err[-2000:]
    resumed = subprocess.run(command, cwd=small_disk.path, env=env, capture_output=True, text=True,
                             timeout=180)
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    study = load_study(sweep)
    counted = [t for t in study.trials if t.state in (TrialState.COMPLETE, TrialState.PRUNED)
               or (t.state == TrialState.FAIL and t.user_attrs.get("aslexp_state") != "interrupted")]
    assert len(counted) == 4  # the budget, exactly
    assert len({t.number for t in study.trials}) == len(study.trials)
    status = run_cli("sweep", "status", str(sweep), "--json")
    assert json.loads(status.stdout)["trials"] == len(study.trials)
