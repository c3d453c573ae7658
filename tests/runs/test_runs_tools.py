"""`runs list`, `runs diff` and `sweep status|best|report|dashboard` on a real sweep's folders."""

from __future__ import annotations

import json
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

from runs_helpers import run_cli

from aslexp.runs.diff import diff_mappings, diff_runs, flatten
import job_process
from aslexp.runs.listing import list_runs


def test_flatten_and_diff_nested_configs() -> None:
    a = {"model": {"layers": [{"units": 64}, {"units": 32}], "act": "relu"}, "lr": 0.1, "old": 1}
    b = {"model": {"layers": [{"units": 64}, {"units": 16}], "act": "relu", "drop": 0.2}, "lr": 0.1}
    assert flatten(a)["model.layers[1].units"] == 32
    changed, added, removed = diff_mappings(a, b)
    assert changed == {"model.layers[1].units": (32, 16)}
    assert added == {"model.drop": 0.2} and removed == {"old": 1}
    assert diff_mappings({"a": 1, "b": True}, {"a": 1.0, "b": 1}) == ({"b": (True, 1)}, {}, {})


def test_runs_diff_of_two_trials(small_sweep: Path) -> None:
    d = diff_runs(small_sweep / "0", small_sweep / "1")
    assert set(d.changed) == {"x", "y"} and not d.added and not d.removed
    info = [json.loads((small_sweep / n / "run.json").read_text()) for n in ("0", "1")]
    assert d.metric["a"] == info[0]["main_metric"]["value"]
    if d.metric["delta"] is not None:
        assert abs(d.metric["delta"] - (d.metric["b"] - d.metric["a"])) < 1e-12
    text = run_cli("runs", "diff", str(small_sweep / "0"), str(small_sweep / "1")).stdout
    assert "config: 2 changed, 0 added, 0 removed" in text and "~ x:" in text
    assert "main metric objective (maximize)" in text
    same = run_cli("runs", "diff", str(small_sweep / "0"), str(small_sweep / "0")).stdout
    assert "config: identical" in same and "(same)" in same
    bad = run_cli("runs", "diff", str(small_sweep), str(small_sweep / "nope"), check=False)
    assert bad.returncode == 2 and "not a run directory" in bad.stderr


def test_runs_diff_reports_added_and_removed_keys(small_sweep: Path, tmp_path: Path) -> None:
    other = tmp_path / "other"
    job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", "+note=extra", "~overwrite",
                    f"hydra.run.dir={other}"], check=True, capture_output=True, cwd=tmp_path)
    d = diff_runs(small_sweep / "0", other)
    assert d.added == {"note": "extra"} and d.removed == {"overwrite": False}
    assert "+note=extra" in d.overrides_b_only


def test_runs_list_shows_every_override_whole(tmp_path: Path) -> None:
    """The override that tells runs apart is often the last; the table never cuts it."""
    run = tmp_path / "run"
    tail = "+note=the_override_that_tells_this_run_apart_from_the_one_beside_it"
    job_process.run([sys.executable, "-m", "aslexp.jobs.quadratic", "x=0.25", "y=-0.75", "+label=a_long_label_first",
                    tail, f"hydra.run.dir={run}"], check=True, capture_output=True, cwd=tmp_path)
    text = run_cli("runs", "list", str(tmp_path)).stdout
    header, _, row = text.splitlines()
    assert header.split()[-1] == "overrides" and row.endswith(tail) and "…" not in text


def test_runs_list_filters_and_sorts(small_sweep: Path) -> None:
    runs = list_runs([small_sweep])
    assert len(runs) == 5
    failed = list_runs([small_sweep], status="failed")
    assert failed and all(json.loads((r.path / "run.json").read_text())["status"] == "failed"
                          for r in failed)
    best = list_runs([small_sweep], sort="metric", status="completed")
    values = [r.metric_value for r in best]
    assert values == sorted(values, reverse=True)
    x = best[0].overrides[[o.split("=")[0] for o in best[0].overrides].index("x")].split("=")[1]
    assert [r.path for r in list_runs([small_sweep], where=[f"x={x}"])] == [best[0].path]
    assert list_runs([small_sweep], job="recognize") == []
    table = run_cli("runs", "list", str(small_sweep), "--sort", "metric").stdout
    assert table.splitlines()[0].split() == ["started", "job", "run", "status", "main", "metric",
                                             "overrides"]
    assert "objective=" in table and "failed" in table
    rows = json.loads(run_cli("runs", "list", str(small_sweep), "--format", "json",
                              "--where", "seed=11").stdout)
    assert len(rows) == 5 and rows[0]["git"] is not None


def test_sweep_status_and_best(small_sweep: Path) -> None:
    status = json.loads(run_cli("sweep", "status", str(small_sweep), "--json").stdout)
    assert status["trials"] == 5 and status["n_trials_budget"] == 5
    assert sum(status["counts"].values()) == 5 and status["counts"].get("fail", 0) >= 1
    text = run_cli("sweep", "status", str(small_sweep)).stdout
    assert "budget 5, 5 counted, 0 to go" in text
    best = json.loads(run_cli("sweep", "best", str(small_sweep), "--json").stdout)
    runs = list_runs([small_sweep], sort="metric", status="completed")
    assert best["value"] == runs[0].metric_value and Path(best["run_dir"]) == runs[0].path
    assert best["command"].startswith("aslexp quadratic +sweeps=quadratic ")
    missing = run_cli("sweep", "status", str(small_sweep / "0"), check=False)
    assert missing.returncode == 2 and "not a sweep directory" in missing.stderr


def test_sweep_report_writes_pngs(small_sweep: Path, tmp_path: Path) -> None:
    out = tmp_path / "report"
    written = run_cli("sweep", "report", str(small_sweep), "--out", str(out)).stdout.split()
    names = {Path(p).name for p in written}
    assert {"optimization_history.png", "param_importances.png", "parallel_coordinate.png",
            "slice.png", "intermediate_values.png", "trials.csv"} <= names
    for name in names - {"trials.csv"}:
        data = (out / name).read_bytes()
        assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 5000


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_sweep_dashboard_serves_the_study_on_loopback(small_sweep: Path) -> None:
    port = _free_port()
    proc = subprocess.Popen([sys.executable, "-m", "aslexp.runs.cli", "sweep", "dashboard",
                             str(small_sweep), "--port", str(port)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30
        while True:
            try:
                with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/studies", timeout=2) as r:
                    studies = json.loads(r.read())
                break
            except OSError:
                if time.monotonic() > deadline or proc.poll() is not None:
                    raise AssertionError(f"dashboard did not come up: {proc.stderr.read() if proc.poll() is not None else ''}")
                time.sleep(0.3)
        names = [s["study_name"] for s in studies["study_summaries"]]
        assert names == ["quadratic"]
        study_id = studies["study_summaries"][0]["study_id"]
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/api/studies/{study_id}?after=0",
                                    timeout=5) as r:
            detail = json.loads(r.read())
        assert len(detail["trials"]) == 5
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/dashboard/", timeout=5) as r:
            assert r.status == 200 and b"<html" in r.read().lower()
    finally:
        proc.terminate()
        proc.wait(timeout=10)


def test_runs_diff_does_not_rank_runs_measured_on_different_splits(tmp_path: Path) -> None:
    """Two real recognize runs, phoneme and gloss split: their MCCs are not one scale."""
    import os

    root = Path(__file__).resolve().parents[2]
    env = {**os.environ, "ASLEXP_CACHE_DIR": str(tmp_path / "cache")}
    runs = {}
    for split in ("phoneme", "gloss"):
        runs[split] = tmp_path / split
        job_process.run([sys.executable, "-m", "aslexp.jobs.recognize", "experiment=debug", "classifier=logreg",
                        f"split={split}", f"hydra.run.dir={runs[split]}"], cwd=root, env=env, check=True,
                       capture_output=True, timeout=300)
    d = diff_runs(runs["phoneme"], runs["gloss"])
    assert d.metric["better"] is None and "split.name" in d.metric["not_comparable"]
    text = run_cli("runs", "diff", str(runs["phoneme"]), str(runs["gloss"])).stdout
    assert "(not comparable: they differ in split.name" in text and "is better" not in text


def test_bars_of_one_run_claim_no_interval() -> None:
    from aslexp.viz.recognition import interval_label

    assert interval_label([1, 1]) == "one unit: no interval"
    assert interval_label([10, 10]) == "95% CI"
    assert interval_label([1, 10]) == "95% CI where 2+ units"
