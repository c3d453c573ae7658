"""A full disk during a job is one line naming the file and saying "disk full"; exit 1,
the run recorded as failed. A real small tmpfs (root can mount one here and in CI; the test is
skipped where mounting is not permitted) and, everywhere, the kernel's own ENOSPC from /dev/full."""

from __future__ import annotations

import errno
import json
import os
import re
import sys
from pathlib import Path

import numpy as np
import pytest
import job_process
from platform_helpers import error_lines

from aslexp.files import describe_os_error, save_npy, write_text
from aslexp.jobs._common import one_line

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def test_a_dataset_build_on_a_full_disk_names_the_file_and_fails_the_run(small_disk, tmp_path):
    run_dir, cache = tmp_path / "run", small_disk / "cache"
    proc = job_process.run(
        [sys.executable, "-m", "aslexp.cli", "recognize", "experiment=debug", "classifier=logreg",
         f"cache_dir={cache}", f"hydra.run.dir={run_dir}"],
        cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=300,
        env={**os.environ, "MPLBACKEND": "Agg"})
    assert proc.returncode == 1, proc.stderr[-3000:]
    lines = error_lines(proc.stderr)
    assert len(lines) == 1, lines
    pattern = (rf"aslexp recognize: disk full: cannot write {re.escape(str(cache))}/\.wlasl_lex-[^/]+/\S+ "
               rf"\(\[Errno 28\] No space left on device\) \(run folder {re.escape(str(run_dir))}\)")
    assert re.fullmatch(pattern, lines[0]), lines[0]
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "failed" and info["error"].startswith(f"disk full: cannot write {cache}/")
    assert list(cache.iterdir()) == []  # the half build is gone: its space is given back


def test_the_kernel_s_enospc_is_reported_as_disk_full_with_the_file():
    if not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    expected = "disk full: cannot write /dev/full ([Errno 28] No space left on device)"
    for write in (lambda: save_npy("/dev/full", np.zeros(100_000)), lambda: write_text("/dev/full", "x" * 100_000)):
        with pytest.raises(OSError) as err:
            write()
        assert err.value.errno == errno.ENOSPC and err.value.filename == "/dev/full"
        assert describe_os_error(err.value) == expected and one_line(err.value) == expected
    missing = FileNotFoundError(errno.ENOENT, "No such file or directory", "/nowhere/x")
    assert one_line(missing) == "FileNotFoundError: [Errno 2] No such file or directory: '/nowhere/x'"
