"""Phonology as help for seen signs: the split keeps every tested gloss in training;
top-k counts what it should; the multi-task fit lets only the named heads choose the epoch; `aslexp
glosses` runs end to end on a tiny budget (the documented commands of docs/recognition.md, cut),
writes a complete run folder, and the results page's entry is made from that folder; a bad key is
one line."""

from __future__ import annotations

import csv
import json
import math
import os
import shlex
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import job_process
from doc_commands import bash_lines

from aslexp.data.splits import SplitOptions
from aslexp.recognition.seen_glosses import seen_gloss_split, top_k_accuracy

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("ASLEXP_DATA_ROOT", ROOT.parent / "shared" / "data"))
needs_data = pytest.mark.skipif(not (DATA / "asl-lex" / "2.0").is_dir(), reason=f"shared data not found under {DATA}")

# A documented command cut to a test's size (these keys replace the command's own): short clips and a
# narrow encoder (the networks' fits were most of the test's time at 150 frames and 128 channels).
CUT = ["split.repeats=2", "glosses.auxiliary=[sign_type,major_location]", "glosses.fit.max_epochs=3",
       "+glosses.simple_baseline_params.n_estimators=10", "+glosses.simple_baseline_params.n_jobs=1",
       "data.num_frames=32", "classifier.params.hidden_size=32"]


def test_top_k_counts_the_true_class_among_the_k_highest_scores():
    scores = np.array([[0.1, 0.7, 0.2], [0.5, 0.3, 0.2], [0.2, 0.3, 0.5]])
    truth = np.array([1, 1, -1])  # -1: a class the scorer never saw, always wrong
    assert top_k_accuracy(scores, truth, 1) == pytest.approx(1 / 3)
    assert top_k_accuracy(scores, truth, 2) == pytest.approx(2 / 3)
    assert top_k_accuracy(scores, truth, 3) == pytest.approx(2 / 3)
    assert math.isnan(top_k_accuracy(scores[:0], truth[:0], 1))


def test_the_split_tests_only_glosses_seen_in_training_and_keeps_rare_ones_there():
    glosses = ["a"] * 10 + ["b"] * 6 + ["c"] * 3 + ["d"] * 2 + ["e"]
    options = SplitOptions(name="phoneme", rare_classes="train_only")
    train, val, test = seen_gloss_split(glosses, options, seed=3)
    assert sorted(np.concatenate([train, val, test]).tolist()) == list(range(len(glosses)))  # every clip, once
    named = lambda idx: {glosses[i] for i in idx}  # noqa: E731
    assert named(test) == {"a", "b", "c"} and named(test) <= named(train) and named(val) <= named(train)
    assert {"d", "e"} <= named(train) and not ({"d", "e"} & (named(val) | named(test)))
    again = seen_gloss_split(glosses, options, seed=3)
    assert all(np.array_equal(x, y) for x, y in zip((train, val, test), again))  # deterministic


def _documented() -> list[str]:
    return [line for line in bash_lines(ROOT / "docs" / "recognition.md") if line.startswith("aslexp glosses")]


def _cli(args: list[str], cache: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, ASLEXP_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    return job_process.run([sys.executable, "-m", "aslexp.cli", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)


@needs_data
def test_the_documented_commands_run_and_the_results_entry_is_made_from_the_folder(tmp_path):
    from aslexp.results import seen_glosses as results_seen_glosses
    from aslexp.results.catalogue import load_catalogue
    from aslexp.results.snapshots import build_snapshot

    commands = _documented()
    assert commands, "docs/recognition.md documents `aslexp glosses`"
    keys = {c.lstrip("+").split("=")[0] for c in CUT}
    for number, command in enumerate(commands):
        words = [w for w in shlex.split(command)[2:] if not w.startswith(("hydra.run.dir=", "hydra.sweep.dir="))]
        # the first command checked in full on 2 splits; the others (the same job with other keys) on 1
        words = [w for w in words if w.lstrip("+").split("=")[0] not in keys] + CUT + ([] if number == 0 else
                                                                                   ["split.repeats=1"])
        multirun = "-m" in words
        folder = tmp_path / f"run{number}"
        proc = _cli(["glosses", *words, f"hydra.{'sweep' if multirun else 'run'}.dir={folder}"], tmp_path / "cache")
        assert proc.returncode == 0, f"{command}: exit {proc.returncode}\n{proc.stderr[-3000:]}"
        run_dirs = sorted(p.parent for p in folder.rglob("run.json"))
        assert all(json.loads((d / "run.json").read_text())["status"] == "completed" for d in run_dirs)
        if number:
            continue
        run_dir = run_dirs[0]
        for name in ("metrics.json", "glosses.md", "predictions.csv", "top_k_by_split.png", "glosses.log"):
            assert (run_dir / name).is_file() and (run_dir / name).stat().st_size > 0, name
        metrics = json.loads((run_dir / "metrics.json").read_text())
        assert metrics["auxiliary"] == ["sign_type", "major_location"] and len(metrics["per_split"]) == 2
        assert list(metrics["methods"]) == ["chance", "majority", "simple", "gloss", "gloss+phonology"]
        for method in metrics["methods"]:
            for k in ("top1", "top5"):
                cell = metrics["table"][method][k]
                assert cell["n"] == 2 and 0.0 <= cell["mean"] <= 1.0
        for split in metrics["per_split"]:
            assert split["metrics"]["chance"]["top1"] == pytest.approx(1 / split["glosses"]["train"])
            assert split["metrics"]["gloss"]["top1"] <= split["metrics"]["gloss"]["top5"]
            # the same clips and the same epoch rule for both networks: only the auxiliary heads differ
            assert all(1 <= split["epochs"][m]["best"] <= split["epochs"][m]["ran"] <= 3 for m in ("gloss", "gloss+phonology"))
        pairs = {(p["method"], p["reference"], p["metric"]) for p in metrics["paired"]}
        assert ("gloss+phonology", "gloss", "top1") in pairs and ("gloss+phonology", "simple", "top5") in pairs
        assert metrics["objective"]["name"].startswith("val_")  # a sweep never chooses by test
        with (run_dir / "predictions.csv").open() as handle:
            rows = list(csv.DictReader(handle))
        assert len(rows) == 3 * sum(s["clips"]["test"] for s in metrics["per_split"])  # 3 scored models per clip
        assert "split 2/2" in proc.stderr + (run_dir / "glosses.log").read_text()  # progress with ETA
        # the results page's entry, from this folder alone
        entry = next(e for e in load_catalogue() if e["report"] == results_seen_glosses.REPORT)
        entry = {**entry, "runs": [{"folders": [folder.name], "machine": "this test's"}]}
        snapshot = build_snapshot(entry, tmp_path)
        assert [r["key"] for r in snapshot["rows"]] == list(metrics["methods"])
        lines = results_seen_glosses.render(entry, snapshot)
        assert any(line.startswith("| gloss head + 2 property heads (auxiliary) | ") for line in lines)
        assert any(line.startswith("Kezar et al.'s question") for line in lines)


def test_a_bad_key_is_one_clear_line(tmp_path):
    proc = _cli(["glosses", "glosses.auxiliary=[sign_type,handshape]", f"hydra.run.dir={tmp_path / 'bad'}"],
                tmp_path / "cache")
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines[-1].startswith("aslexp glosses: glosses.auxiliary: unknown property 'handshape'"), proc.stderr
    assert "Traceback" not in proc.stderr
