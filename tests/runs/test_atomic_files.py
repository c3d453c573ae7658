"""Atomic writes: concurrent writers of one file never collide, a failed write keeps the old file."""

from __future__ import annotations

import json
import multiprocessing as mp

import pytest

from aslexp.files import atomic_path, read_json, write_json


def _hammer(path: str, worker: int, rounds: int) -> None:
    for i in range(rounds):
        write_json(path, {"worker": worker, "round": i, "pad": "x" * 4096})


def test_two_processes_writing_one_file_never_collide(tmp_path):
    # The CI failure this guards against: two sweep workers wrote sweep.json through one shared
    # temporary name, and one rename found its temporary already moved away.
    target = tmp_path / "sweep.json"
    ctx = mp.get_context("spawn")
    procs = [ctx.Process(target=_hammer, args=(str(target), w, 200)) for w in range(2)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=60)
    assert [p.exitcode for p in procs] == [0, 0]
    last = read_json(target)
    assert last["worker"] in (0, 1) and last["round"] == 199
    assert sorted(x.name for x in tmp_path.iterdir()) == ["sweep.json"]  # no temporaries left


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "result.json"
    write_json(target, {"kept": True})
    with pytest.raises(RuntimeError, match="crash mid-write"):
        with atomic_path(target) as tmp:
            tmp.write_text('{"half":', encoding="utf-8")
            raise RuntimeError("crash mid-write")
    assert json.loads(target.read_text()) == {"kept": True}
    assert sorted(x.name for x in tmp_path.iterdir()) == ["result.json"]
