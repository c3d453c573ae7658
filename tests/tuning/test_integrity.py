"""Sweep integrity: nothing finished is overwritten, duplicated or silently lost.

Real Hydra multiruns of the quadratic job on real journal files and PostgreSQL."""

from __future__ import annotations

import fcntl
import json
import os
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import optuna
import pytest
from optuna.trial import TrialState
from sweep_helpers import load_study, run_cli, run_sweep, sweep_command, wait_for

from aslexp.process import process_identity, process_is_gone
from aslexp.tuning.storage import StorageError, _lock_key, open_storage
from aslexp.tuning.worker import ATTR_ERROR, ATTR_RERUN_OF, ATTR_RUN_DIR, ATTR_STATE, INTERRUPTED


def _hashes(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file() and ".lock" not in p.name and "optuna.journal" not in p.name}



# --------------------------------------------------------------------------- 11.2


def test_two_studies_in_one_sweep_folder_both_complete_and_never_share_a_folder(tmp_path):
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=3")
    first = {k: v for k, v in _hashes(sweep).items() if not k.startswith("sweep.json")}
    run_sweep(sweep, "hydra.sweeper.n_trials=2", "hydra.sweeper.study_name=other", "x=interval(0, 0.5)")
    # The first study's trial folders, configs and logs are untouched; the second has its home.
    assert {k: v for k, v in _hashes(sweep).items() if k in first} == first
    assert json.loads((sweep / "sweep.json").read_text())["study_name"] == "quadratic"
    home = sweep / "studies" / "other"
    assert json.loads((home / "sweep.json").read_text())["study_name"] == "other"
    for name, n, folder in (("quadratic", 3, sweep), ("other", 2, home)):
        study = load_study(sweep, name=name)
        assert [t.state for t in study.trials] == [TrialState.COMPLETE] * n
        for t in study.trials:
            assert t.user_attrs[ATTR_RUN_DIR] == str(t.number)  # relative to the study's home
            metrics = json.loads((folder / str(t.number) / "metrics.json").read_text())
            assert metrics["objective"] == t.value and metrics["x"] == t.params["x"]
    assert "other studies in this folder" in run_cli("sweep", "status", str(sweep)).stdout
    status = json.loads(run_cli("sweep", "status", str(home), "--json").stdout)
    assert status["study_name"] == "other" and status["counts"] == {"complete": 2}


def test_a_sweep_with_another_search_space_into_a_study_s_folder_is_refused_untouched(tmp_path):
    """Another space and fixed override (``x=interval(2,3) noise=0.5`` beside x in
    [-1, 1]) is another sweep, not a resume: refused in one line (exit 2) that names the folder,
    what differs and the ways on, with every file of the first study byte-identical (its journal
    too). The same space written otherwise is the same sweep: it resumes."""
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=2")
    def everything() -> dict[str, bytes]:  # the journal too
        return _hashes(sweep) | {"journal": (sweep / "optuna.journal").read_bytes()}

    before = everything()
    refused = run_sweep(sweep, "hydra.sweeper.n_trials=3", "x=interval(2,3)", "noise=0.5",
                        check=False)
    assert refused.returncode == 2, refused.stderr[-3000:]
    lines = [ln for ln in refused.stderr.splitlines() if ln.startswith("aslexp quadratic: ")]
    assert len(lines) == 1 and "Traceback" not in refused.stderr, refused.stderr[-3000:]
    assert lines[0].startswith(f"aslexp quadratic: {sweep} holds study 'quadratic' of another "
                               "sweep (its sweep.json differs: x=interval(2,3) here, interval(-1, "
                               "1) there; fixed noise=0.5 is new here); nothing was changed: ")
    assert "hydra.sweeper.study_name=NEW" in lines[0] and "hydra.sweeper.continue_study=true" in lines[0]
    assert everything() == before
    assert sorted(p.name for p in sweep.iterdir() if p.is_dir()) == ["0", "1"]

    run_sweep(sweep, "hydra.sweeper.n_trials=3", "x=interval(-1,1)")  # the same space: a resume
    assert [t.state for t in load_study(sweep).trials] == [TrialState.COMPLETE] * 3


def test_a_trial_folder_that_holds_anything_is_never_reused(tmp_path):
    """A journal deleted by hand restarts trial numbers at 0: the new trials go beside."""
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=1")
    before = _hashes(sweep / "0")
    (sweep / "optuna.journal").unlink()
    run_sweep(sweep, "hydra.sweeper.n_trials=1")
    assert _hashes(sweep / "0") == before
    assert load_study(sweep).trials[0].user_attrs[ATTR_RUN_DIR] == "0-2"


# --------------------------------------------------------------------------- 11.3


def _holding(pid: int, path: Path) -> bool:
    """Whether process ``pid`` has ``path`` open (it then waits on its flock)."""
    try:
        return any(os.readlink(f"/proc/{pid}/fd/{fd}") == str(path) for fd in os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return False


def _start_together(sweep: Path, n: int, overrides: list[str], hold, released) -> list[subprocess.Popen]:
    """Start ``n`` identical workers and let them ask for their first trial at the same instant:
    the test holds the study's budget lock until every worker waits on it."""
    with hold():
        procs = [subprocess.Popen(sweep_command(sweep, *overrides), cwd=sweep.parent,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                 for _ in range(n)]
        wait_for(lambda: all(released(p.pid) for p in procs) or any(p.poll() is not None for p in procs),
                  120, f"{n} workers waiting on the budget lock")
    for proc in procs:
        _, err = proc.communicate(timeout=120)
        assert proc.returncode == 0, err[-3000:]
    return procs


def _assert_no_duplicates(study: optuna.Study, n_trials: int, procs) -> None:
    trials = study.trials
    assert len(trials) == n_trials and all(t.state == TrialState.COMPLETE for t in trials)
    points = [json.dumps(t.params, sort_keys=True) for t in trials]
    assert len(set(points)) == len(points), f"duplicate parameter sets: {sorted(points)}"
    assert {t.user_attrs["aslexp_worker"]["pid"] for t in trials} == {p.pid for p in procs}


def test_workers_started_at_the_same_instant_never_duplicate_a_point_journal(tmp_path):
    sweep = tmp_path / "sweep"
    sweep.mkdir()
    lock_path = sweep / "optuna.journal.budget-lock"

    class hold:
        def __enter__(self):
            self.fh = open(lock_path, "a")
            fcntl.flock(self.fh.fileno(), fcntl.LOCK_EX)

        def __exit__(self, *exc):
            fcntl.flock(self.fh.fileno(), fcntl.LOCK_UN)
            self.fh.close()

    procs = _start_together(sweep, 3, ["hydra/sweeper/sampler=random", "hydra.sweeper.n_trials=9",
                                       "hydra.sweeper.sampler.seed=0", "sleep=0.3"],
                            hold, lambda pid: _holding(pid, lock_path))
    _assert_no_duplicates(load_study(sweep), 9, procs)


def test_workers_started_at_the_same_instant_never_duplicate_a_point_postgresql(tmp_path, pg_url):
    import sqlalchemy

    sweep = tmp_path / "sweep"
    sweep.mkdir()
    name = f"test_{uuid.uuid4().hex[:10]}"
    key = _lock_key(f"aslexp-budget:{name}")
    engine = sqlalchemy.create_engine(pg_url, poolclass=sqlalchemy.pool.NullPool)
    conn = engine.connect()

    class hold:
        def __enter__(self):
            conn.execute(sqlalchemy.text("SELECT pg_advisory_lock(:k)"), {"k": key})

        def __exit__(self, *exc):
            conn.execute(sqlalchemy.text("SELECT pg_advisory_unlock(:k)"), {"k": key})

    def waiting(_pid) -> bool:  # every worker's session waits on the advisory lock
        with engine.connect() as c:
            n = c.execute(sqlalchemy.text(
                "SELECT count(*) FROM pg_locks WHERE locktype = 'advisory' AND NOT granted")).scalar()
        return n >= 3

    try:
        procs = _start_together(sweep, 3, [f"hydra.sweeper.storage='{pg_url}'",
                                           f"hydra.sweeper.study_name={name}",
                                           "hydra/sweeper/sampler=random", "hydra.sweeper.n_trials=9",
                                           "hydra.sweeper.sampler.seed=0", "sleep=0.3"], hold, waiting)
    finally:
        conn.close()
    _assert_no_duplicates(load_study(sweep, storage=pg_url, name=name), 9, procs)


# --------------------------------------------------------------------------- 11.5


def test_a_torn_journal_tail_is_cut_off_with_a_backup_and_the_sweep_resumes(tmp_path):
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=2")
    journal = sweep / "optuna.journal"
    intact = journal.read_bytes()
    torn = b'{"op_code": 4, "worker_id": "dead-writer", "study_id": 0, "dat'
    journal.write_bytes(intact + torn)
    status = run_cli("sweep", "status", str(sweep))  # a reader skips it and writes nothing
    assert "complete 2" in status.stdout
    assert f"{journal}: the last record is torn" in status.stderr
    assert journal.read_bytes() == intact + torn
    resumed = run_sweep(sweep, "hydra.sweeper.n_trials=3")  # the next writer cuts it off
    assert (f"{journal}: the last record was torn ({len(torn)} bytes from byte {len(intact)}, "
            "no newline" in resumed.stdout + resumed.stderr)
    backups = list(sweep.glob("optuna.journal.torn-*"))
    assert len(backups) == 1 and backups[0].read_bytes().endswith(b'"study_id": 0, "dat')
    assert [t.state for t in load_study(sweep).trials] == [TrialState.COMPLETE] * 3


def test_damage_inside_a_journal_is_refused_naming_file_line_and_byte(tmp_path):
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra.sweeper.n_trials=1")
    journal = sweep / "optuna.journal"
    lines = journal.read_bytes().splitlines(keepends=True)
    lines[1] = lines[1][:20] + b"\n"  # a record cut short inside the file (not a torn tail)
    journal.write_bytes(b"".join(lines))
    with pytest.raises(StorageError) as err:
        open_storage(str(journal))
    assert f"journal file {journal} is damaged at line 2 (byte {len(lines[0])})" in str(err.value)
    status = run_cli("sweep", "status", str(sweep), check=False)
    assert status.returncode == 2 and "is damaged at line 2" in status.stderr
    assert "Traceback" not in status.stderr


# --------------------------------------------------------------------------- 11.6


def test_a_zombie_worker_counts_as_gone():
    child = subprocess.Popen([sys.executable, "-c", "pass"])
    identity = process_identity(child.pid)
    wait_for(lambda: open(f"/proc/{child.pid}/stat").read().rsplit(")", 1)[1].split()[0] == "Z",
              30, "the child to exit (a zombie: not reaped yet)")
    assert process_is_gone(identity)  # os.kill(pid, 0) still succeeds on a zombie
    child.wait()
    assert process_is_gone(identity)
    assert not process_is_gone(process_identity())


def test_ctrl_c_with_two_workers_leaves_no_trial_running(tmp_path):
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen(sweep_command(sweep, "hydra.sweeper.n_trials=20",
                                          "hydra.sweeper.n_workers=2", "sleep=30"),
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, start_new_session=True,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))

    def both_running() -> bool:
        if not (sweep / "optuna.journal").exists():
            return False
        running = [t for t in load_study(sweep).trials if t.state == TrialState.RUNNING]
        return len(running) == 2 and all(
            (sweep / t.user_attrs.get(ATTR_RUN_DIR, "/nonexistent") / "run.json").exists() for t in running)

    wait_for(both_running, 90, "two trials running, one per worker")
    time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGINT)  # what Ctrl-C in a terminal does: every process gets it
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130
    lines = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("[20")]
    assert len(lines) == 2 and all(ln.startswith("aslexp quadratic: interrupted (Ctrl-C): trial ")
                                   for ln in lines), stderr[-3000:]
    study = load_study(sweep)
    assert [t.state for t in study.trials] == [TrialState.FAIL] * 2
    for t in study.trials:
        assert t.user_attrs[ATTR_STATE] == INTERRUPTED and "Ctrl-C" in t.user_attrs[ATTR_ERROR]
        run = json.loads((sweep / t.user_attrs[ATTR_RUN_DIR] / "run.json").read_text())
        assert run["status"] == "interrupted"


def test_after_sigkill_the_resume_records_the_lost_trial_in_its_run_folder_too(tmp_path):
    sweep = tmp_path / "sweep"
    proc = subprocess.Popen(sweep_command(sweep, "hydra.sweeper.n_trials=3", "sleep=30"),
                            cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    wait_for(lambda: (sweep / "0" / "run.json").exists(), 60, "the first trial's run.json")
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert json.loads((sweep / "0" / "run.json").read_text())["status"] == "running"
    status = run_cli("sweep", "status", str(sweep)).stdout
    assert "running 1" in status and "1 of the running trials' workers are gone" in status
    # Resumed without the sleep: another fixed override, so continuing the study is asked for.
    run_sweep(sweep, "hydra.sweeper.n_trials=1", "sleep=0", "hydra.sweeper.continue_study=true")
    lost, rerun = load_study(sweep).trials
    assert lost.state == TrialState.FAIL and lost.user_attrs[ATTR_STATE] == INTERRUPTED
    run = json.loads((sweep / "0" / "run.json").read_text())
    assert run["status"] == "interrupted" and run["error"] == lost.user_attrs[ATTR_ERROR]
    assert rerun.state == TrialState.COMPLETE and rerun.params == lost.params  # its point, again
    assert rerun.user_attrs[ATTR_RERUN_OF] == 0


# --------------------------------------------------------------------------- 11.7


def test_a_pruner_never_discards_a_trial_that_reports_once(tmp_path):
    """One report per trial (a classical model's single fit): the median pruner, with every
    chance to prune (1 start-up trial, no warm-up), leaves every trial complete."""
    sweep = tmp_path / "sweep"
    run_sweep(sweep, "hydra/sweeper/sampler=random", "hydra.sweeper.n_trials=8", "steps=1",
              "hydra.sweeper.pruner.n_startup_trials=1", overlay="quadratic_pruning")
    trials = load_study(sweep).trials
    assert [t.state for t in trials] == [TrialState.COMPLETE] * 8
    assert all(sorted(t.intermediate_values) == [0] for t in trials)
