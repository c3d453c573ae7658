"""ASLEXP_TEST_TIMELINE and scripts/suite_timeline.py: a real pytest run of one of the suite's own
files writes one line per test phase, and the script sums them per worker and per file."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TESTS = ["tests/platform/test_quaternion.py"]


def test_a_run_writes_its_timeline_and_the_script_reads_it(tmp_path):
    timeline = tmp_path / "timeline.jsonl"
    env = {**os.environ, "ASLEXP_TEST_TIMELINE": str(timeline)}
    ran = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-n", "0", *TESTS],
                         cwd=ROOT, env=env, capture_output=True, text=True, timeout=300)
    assert ran.returncode == 0, ran.stdout[-2000:]
    lines = [json.loads(line) for line in timeline.read_text().splitlines()]
    tests = {r["test"] for r in lines}
    assert tests and all(t.startswith(TESTS[0] + "::") for t in tests)
    assert {r["phase"] for r in lines} == {"setup", "call", "teardown"} and len(lines) == 3 * len(tests)
    assert {r["worker"] for r in lines} == {"main"} and all(r["stop"] >= r["start"] for r in lines)

    report = subprocess.run([sys.executable, "scripts/suite_timeline.py", str(timeline), "--files", "3"],
                            cwd=ROOT, capture_output=True, text=True, timeout=60)
    assert report.returncode == 0, report.stderr
    busy = sum(r["stop"] - r["start"] for r in lines)
    assert f"{len(tests)} tests, {busy:.0f} worker-seconds in tests on 1 workers" in report.stdout
    assert f"  main: busy {busy:.0f} s" in report.stdout and f"s  {TESTS[0]}" in report.stdout

    # Under --dist loadgroup a grouped test's id ends in "@group" (a parameter's "@" is not a group).
    line = lambda test, worker, start, stop: json.dumps(  # noqa: E731
        {"worker": worker, "test": test, "phase": "call", "start": start, "stop": stop})
    timeline.write_text("\n".join([line("tests/a.py::test_1@waiting", "gw1", 100.0, 130.0),
                                   line("tests/b.py::test_2@waiting", "gw1", 140.0, 150.0),
                                   line("tests/c.py::test_3[x@y]", "gw0", 100.0, 160.0)]) + "\n")
    grouped = subprocess.run([sys.executable, "scripts/suite_timeline.py", str(timeline)], cwd=ROOT,
                             capture_output=True, text=True, timeout=60)
    assert grouped.returncode == 0, grouped.stderr
    assert "     40.0 s  waiting: from 0 s to 50 s on gw1\n" in grouped.stdout
    assert "y]" not in grouped.stdout.split("files by time")[0]

    timeline.write_text("not json\n")
    bad = subprocess.run([sys.executable, "scripts/suite_timeline.py", str(timeline)], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and str(timeline) in bad.stderr and len(bad.stderr.splitlines()) == 1
