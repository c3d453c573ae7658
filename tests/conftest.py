"""Suite-wide: which tests share one xdist worker (scripts/test.sh runs ``pytest -n auto --dist loadgroup``).

* Slurm: the single-node loopback cluster has room for one test's jobs at a time (the tests count
  jobs in flight and wait on squeue), so every Slurm test joins one group and they run in turn.
* Extraction: the MediaPipe extraction of the six videos (session fixtures ``extracted`` and
  ``wlasl6``, ~25 s each) is made once, on the worker that runs every test reading it.
A file whose tests depend on each other's files marks itself (``pytestmark = xdist_group``).
"""

from __future__ import annotations

import pytest

_SLURM_FILES = ("tests/tuning/test_slurm.py", "tests/tuning/test_docs_commands.py")
_EXTRACTION_FIXTURES = {"extracted", "wlasl6"}


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("xdist_group"):
            continue
        if item.nodeid.startswith(_SLURM_FILES):
            item.add_marker(pytest.mark.xdist_group("slurm"))
        elif _EXTRACTION_FIXTURES & set(getattr(item, "fixturenames", ())):
            item.add_marker(pytest.mark.xdist_group("extraction"))
