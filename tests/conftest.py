"""Suite-wide: which tests share one xdist worker (scripts/test.sh runs ``pytest -n <cores + 1> --dist loadgroup``).

* Waiting: the single-node loopback Slurm cluster has room for one test's jobs at a time (the tests
  count jobs in flight and wait on squeue), so every Slurm test joins one group and they run in turn.
  The sweep tests that mostly wait on processes they started (trials that sleep, signals, orphaned
  jobs adopted, a disk that fills: a third to two thirds of a core each, measured) join that lane: one worker
  waits through all of them while the others compute (scripts/test.sh starts one worker more than
  cores for it), instead of two workers waiting at once with a core idle.
* Extraction: the MediaPipe extraction of the six videos (session fixtures ``extracted`` and
  ``wlasl6``, ~25 s each) is made once, on the worker that runs every test reading it.
* A module's own module-scoped fixture (a trained model, a finished run) is made once per worker that
  runs a test asking for it: the tests asking for one run on one worker (their group is the module),
  so it is made once (three workers made test_read_back.py's models three times, 10 s each).
A file whose tests depend on each other's files marks itself (``pytestmark = xdist_group``).
"""

from __future__ import annotations

import json
import os
import subprocess

import pytest

_WAITING_FILES = ("tests/tuning/test_slurm.py", "tests/tuning/test_docs_commands.py", "tests/tuning/test_sweeper.py",
                  "tests/tuning/test_adoption.py", "tests/tuning/test_full_disk.py")
_EXTRACTION_FIXTURES = {"extracted", "wlasl6"}


@pytest.hookimpl(tryfirst=True)  # before xdist's own hook, which reads the groups into the test ids
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("xdist_group"):
            continue
        if item.nodeid.startswith(_WAITING_FILES):
            item.add_marker(pytest.mark.xdist_group("waiting"))
        elif _EXTRACTION_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.xdist_group("extraction"))
        elif _uses_a_module_fixture_of_its_own(item):
            item.add_marker(pytest.mark.xdist_group(item.nodeid.split("::")[0].removeprefix("tests/")))


def _uses_a_module_fixture_of_its_own(item: pytest.Item) -> bool:
    """Whether the test asks (itself or through its fixtures) for a module-scoped fixture its module defines."""
    module = item.nodeid.split("::")[0]
    definitions = getattr(getattr(item, "_fixtureinfo", None), "name2fixturedefs", {})
    return any(defs and defs[-1].scope == "module" and defs[-1].baseid == module for defs in definitions.values())


@pytest.hookimpl(trylast=True)
def pytest_collection_finish(session: pytest.Session) -> None:
    """Fail loudly where xdist_group would be ignored: pytest-xdist 3.8 groups a test by appending
    "@group" to its id, which pytest 9.2 no longer reads (its ids come from elsewhere), so every group
    above was silently spread over the workers (pyproject.toml pins pytest < 9)."""
    # a worker of this run (not a pytest a test starts, which inherits PYTEST_XDIST_WORKER)
    if not (hasattr(session.config, "workerinput") and getattr(session.config.option, "loadgroup", False)):
        return
    ignored = [item.nodeid for item in session.items
               if item.get_closest_marker("xdist_group") and "@" not in item.nodeid]
    if ignored:
        raise pytest.UsageError(f"xdist_group is ignored by this pytest ({pytest.__version__}) and pytest-xdist: "
                                f"{ignored[0]} has no @group in its id; install pytest<9 (pyproject.toml's dev extra)")


_timeline: dict[str, str] = {}


def pytest_configure(config: pytest.Config) -> None:
    if config.getoption("numprocesses", None) and not hasattr(config, "workerinput"):
        return  # the xdist controller: its workers, started next, read the variable
    # Taken out of the environment, so that a pytest a test starts does not write into the same file.
    path = os.environ.pop("ASLEXP_TEST_TIMELINE", None)
    if path:
        _timeline.update(path=path, worker=getattr(config, "workerinput", {}).get("workerid", "main"))


def pytest_runtest_logreport(report: pytest.TestReport) -> None:
    """ASLEXP_TEST_TIMELINE=FILE: each worker appends a JSON line per test phase (worker, test,
    phase, start, stop), read by scripts/suite_timeline.py: where the suite's time goes, per file
    and per worker, and how long the workers waited for each other at the end."""
    if not _timeline or hasattr(report, "node"):  # the xdist controller sees every report again
        return
    line = {"worker": _timeline["worker"], "test": report.nodeid, "phase": report.when, "start": report.start,
            "stop": report.stop}
    with open(_timeline["path"], "a", encoding="utf-8") as fh:
        fh.write(json.dumps(line) + "\n")


# A full disk for real: a 64 KB tmpfs (a test that needs one skips where mount is refused). The sweep
# tests' journal disk (tests/tuning/test_full_disk.py) is its own.
@pytest.fixture()
def small_disk(tmp_path):
    mount = tmp_path / "small"
    mount.mkdir()
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=64k", "tmpfs", str(mount)],
                          capture_output=True, text=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.strip()}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], capture_output=True)
