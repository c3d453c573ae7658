"""bench/recognition_table.py --direct (the GPU-node route to the tables) composes each cell with Hydra
as the command line does and writes run folders that `aslexp report` reads."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
import job_process

ROOT = Path(__file__).resolve().parents[2]


def test_direct_table_runs_cells_and_reports(tmp_path):
    out = tmp_path / "table"
    env = {**os.environ, "MPLBACKEND": "Agg", "ASLEXP_CACHE_DIR": str(tmp_path / "cache")}
    proc = job_process.run(
        [sys.executable, "bench/recognition_table.py", "--direct", "--experiment", "thesis_ch4", "--models", "mlp,logreg",
         "--properties", "sign_type", "--splits", "phoneme", "--repeats", "2", "--trainer-set", "max_epochs=2",
         "--device", "cpu", "--out", str(out),
         "simple_baseline=logreg"],  # one simple baseline: the 500-tree rf would be most of the cells' time
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    assert "2 cell(s) completed, 0 failed" in proc.stdout
    for model in ("mlp", "logreg"):
        metrics = json.loads((out / f"{model}_sign_type_phoneme" / "metrics.json").read_text())
        # the overlay's settings, as `aslexp recognize experiment=thesis_ch4` composes them
        assert metrics["context"]["lexicon"] == "asllex1" and metrics["context"]["classifier"] == model
        assert len(metrics["splits"]) == 2
    report = job_process.run([sys.executable, "-m", "aslexp.cli", "report", str(out)], cwd=ROOT, env=env,
                            capture_output=True, text=True, timeout=300)  # fmt: skip
    assert report.returncode == 0, report.stderr[-2000:]
    assert "mlp" in (out / "table.md").read_text()


def test_throughput_bench_runs_on_tiny_settings(tmp_path):
    proc = job_process.run(
        [sys.executable, "bench/recognition_throughput.py", "--models", "mlp,logreg", "--cpu-clips", "16",
         "--cpu-epochs", "2", "--threads", "1", "--frames", "32", "--json", str(tmp_path / "t.json")],
        cwd=ROOT, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = json.loads((tmp_path / "t.json").read_text())["rows"]
    assert [r["model"] for r in rows] == ["mlp"] and rows[0]["cpu"]["clips_per_s"] > 0  # logreg: not torch
