"""Lexicon retrieval for unseen glosses: a lexicon entry whose properties are given
ranks first; the oracle's figures are the counts of the lexicon CSV (and the issue's); ties give the
expected rank; intervals over splits stay in the metric's range and are not given below 3 splits;
the default splits' test glosses recur (counted from the real split generator); `aslexp retrieve`
runs end to end on a tiny budget (the documented commands of docs/recognition.md, cut) and writes a
complete run folder with recall by frequency band, which the results entry renders; an unknown
property is one line."""

from __future__ import annotations

import csv
import json
import math
import os
import shlex
import subprocess
import sys
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
import job_process
from doc_commands import bash_lines

from aslexp.data.lexicon import load_lexicon
from aslexp.data.splits import SplitOptions
from aslexp.recognition import retrieval as R
from aslexp.recognition import retrieval_run as RR

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(os.environ.get("ASLEXP_DATA_ROOT", ROOT.parent / "shared" / "data"))
CSV = DATA / "asl-lex" / "2.0" / "signdata-11-5-20.csv"
FOUR = ("sign_type", "major_location", "minor_location", "movement")
COLUMNS = {"sign_type": "SignType.2.0", "major_location": "MajorLocation.2.0", "minor_location": "MinorLocation.2.0",
           "selected_fingers": "SelectedFingers.2.0", "flexion": "Flexion.2.0", "movement": "Movement.2.0"}

pytestmark = pytest.mark.skipif(not CSV.is_file(), reason=f"shared data not found under {DATA}")


@pytest.fixture(scope="module")
def lexicon():
    return load_lexicon("asllex2", DATA)


def _table(lexicon, properties=FOUR):
    return R.lexicon_table(lexicon.entries, properties, {p: lexicon.vocabulary(p) for p in properties})


def _rows():
    with CSV.open(newline="", encoding="utf-8-sig") as handle:
        return list(csv.DictReader(handle))


# --------------------------------------------------------------------------- scores and ranks


@pytest.mark.parametrize("likelihood", R.LIKELIHOODS)
def test_an_entry_whose_properties_are_given_ranks_first(lexicon, likelihood):
    table = _table(lexicon)
    groups = Counter(map(tuple, table.codes.tolist()))
    unique = next(i for i, row in enumerate(table.codes.tolist()) if groups[tuple(row)] == 1)
    shared = next(i for i, row in enumerate(table.codes.tolist()) if groups[tuple(row)] == 7)
    priors = [R.value_prior(table.codes[:, j], len(v)) for j, v in enumerate(table.vocab)] \
        if likelihood == "ratio" else None
    for entry, expected in ((unique, 1.0), (shared, 4.0)):  # 7 entries tie: expected rank (7 + 1) / 2
        scores = R.phonology_scores(table, R.one_hot(table, entry), eps=0.01, priors=priors)[0]
        rank = R.rank_of_true(scores, entry)
        assert rank.expected == expected and rank.tied == groups[tuple(table.codes[entry])]
        assert np.argmax(scores) in np.flatnonzero((table.codes == table.codes[entry]).all(axis=1))
    # a value no classifier gave any probability still scores finitely (the floor eps / |V|)
    blank = [np.zeros((1, len(v))) for v in table.vocab]
    for p in blank:
        p[0, 0] = 1.0
    assert np.isfinite(R.phonology_scores(table, blank, eps=0.001, priors=priors)).all()


def test_ties_give_the_expected_rank():
    rank = R.rank_of_true(np.array([3.0, 5.0, 5.0, 5.0, 1.0]), 1)
    assert (rank.above, rank.tied, rank.expected) == (0, 3, 2.0)
    assert [rank.recall_at(k) for k in (1, 2, 3, 4)] == pytest.approx([1 / 3, 2 / 3, 1.0, 1.0])
    assert rank.reciprocal == pytest.approx((1 + 1 / 2 + 1 / 3) / 3)
    behind = R.rank_of_true(np.array([9.0, 9.0, 4.0, 4.0, 1.0]), 3)  # two above, two tied
    assert (behind.expected, behind.recall_at(2), behind.recall_at(3)) == (3.5, 0.0, 0.5)
    assert behind.reciprocal == pytest.approx((1 / 3 + 1 / 4) / 2)
    chance = R.rank_metrics([R.chance_rank(2723)])
    assert chance["recall@10"] == pytest.approx(10 / 2723) and chance["recall@50"] == pytest.approx(50 / 2723)
    assert chance["median_rank"] == 1362.0


def test_the_prior_ranks_by_sign_frequency(lexicon):
    table = _table(lexicon)
    z = np.array([float(r["SignFrequency(Z)"]) for r in _rows()])
    assert np.allclose(table.frequency_z, z) and np.exp(table.log_prior).sum() == pytest.approx(1.0)
    entry = int(np.argsort(z)[len(z) // 2])
    rank = R.rank_of_true(table.log_prior, entry)
    assert (rank.above, rank.tied) == (int(np.sum(z > z[entry])), int(np.sum(z == z[entry])))


# --------------------------------------------------------------------------- the oracle


@pytest.mark.parametrize(("properties", "issue"), [(FOUR, {10: 0.486, 50: 0.795}),
                                                   (tuple(COLUMNS), {10: 0.895})])
def test_the_oracle_figures_are_the_lexicons_counts(lexicon, properties, issue):
    oracle = R.oracle_lexicon(_table(lexicon, properties), recall_at=(1, 10, 50))
    rows = _rows()  # straight from the CSV: a blank or NA is a value of its own here
    groups = Counter(tuple(r[COLUMNS[p]] for p in properties) for r in rows)
    sizes = [groups[tuple(r[COLUMNS[p]] for p in properties)] for r in rows]
    for k in (1, 10, 50):
        assert oracle[f"recall@{k}"] == pytest.approx(sum(min(1.0, k / s) for s in sizes) / len(rows))
        assert oracle[f"chance_recall@{k}"] == pytest.approx(k / 2723)
    assert oracle["groups"] == len(groups) and oracle["entries"] == len(rows) == 2723
    for k, value in issue.items():  # the issue's figures, rounded as it gives them
        assert round(oracle[f"recall@{k}"], 3) == value
    assert (round(100 * oracle["chance_recall@50"], 1), round(100 * oracle["chance_recall@10"], 2)) == (1.8, 0.37)


def test_the_oracle_of_a_clip_puts_its_group_first_and_the_prior_orders_it(lexicon):
    table = _table(lexicon)
    entry = table.index("book")
    same = (table.codes == table.codes[entry]).all(axis=1)
    ranks = R.method_ranks(table, R.one_hot(table, entry), [entry], eps=0.01, eps_combined=0.01, weight=1.0)
    assert ranks["oracle"][0].expected == (same.sum() + 1) / 2
    assert ranks["oracle+prior"][0].above == int(np.sum(same & (table.frequency_z > table.frequency_z[entry])))
    assert ranks["phonology"][0].expected == ranks["oracle"][0].expected  # certain and right = the oracle


# --------------------------------------------------------------------------- intervals over splits


def test_an_interval_stays_in_the_metrics_range_and_needs_three_splits():
    # a rate: recall@50 of the prior on three splits, one of which has no frequent test gloss
    recall = RR.split_interval([0.0, 0.05, 0.9], RR.metric_range("recall@50", 2723))
    assert recall["low"] == 0.0 and 0.0 < recall["mean"] < recall["high"] <= 1.0
    assert recall["half_width"] > recall["mean"]  # the t half-width itself is kept, unclipped
    rank = RR.split_interval([1.0, 2.0, 2700.0], RR.metric_range("median_rank", 2723))
    assert (rank["low"], rank["high"]) == (1.0, 2723.0)
    # two splits: t(1) = 12.7 standard errors, the report's "42.4 [-220.7, 305.6]": no interval at all
    two = RR.split_interval([0.2, 0.65], RR.metric_range("recall@50", 2723))
    assert two["mean"] == pytest.approx(0.425) and two["n"] == 2
    assert (two["low"], two["high"], two["half_width"], two["interval"]) == (None, None, None, RR.NO_INTERVAL)
    assert RR._metric_cell("recall@50", two) == "42.5" and RR._metric_cell("median_rank", {**two, "mean": 90}) == "90"


def test_the_default_splits_reuse_test_glosses(clip_cache):
    """The 10 default gloss splits, drawn by the job's own split generator over the real clips'
    glosses: 70 test-gloss slots hold only 37 glosses, and 56 slots hold a gloss tested in another split."""
    from hydra import compose, initialize_config_dir

    from aslexp.jobs._common import to_dict
    from aslexp.jobs.retrieve import retrieval_clips

    with initialize_config_dir(str(ROOT / "conf"), version_base=None):
        plain = to_dict(compose("retrieve", overrides=[f"data.root={DATA}"]))
    properties = ["sign_type", "major_location"]  # the CLI test's builds: the same 285 clips of 47 glosses
    table = _table(load_lexicon("asllex2", DATA), properties)
    clips = retrieval_clips(plain, properties, table, clip_cache)
    assert (len(clips.glosses), len(set(clips.glosses))) == (285, 47)
    options = SplitOptions.parse(plain["split"])
    assert options.repeats == 10
    tests = []
    for k in range(options.repeats):
        test = RR.gloss_split(clips.glosses, options, options.seed + k)[2]
        tests.append(sorted({clips.glosses[i] for i in test}))
    assert RR.split_overlap(tests) == {"test_slots": 70, "distinct_test_glosses": 37, "recurring": 56,
                                       "recurring_glosses": 23, "most_tested": 4}
    # the glosses are common words: the median is about the 92nd most frequent of the 2,723 signs
    ranks = R.frequency_rank(table, sorted(set(clips.entry_rows.tolist())))
    assert np.median(ranks) == pytest.approx(91.5)
    assert R.lexicon_terciles(table, sorted(set(clips.entry_rows.tolist()))) == {"low": 2, "mid": 2, "high": 43}


# --------------------------------------------------------------------------- the job


# A documented command cut to a test's size: 2 splits, 2 properties, one grid point each (these keys
# replace the command's own), and a small forest when the classifier is rf.
CUT = ["split.repeats=2", "retrieval.properties=[sign_type,major_location]", "retrieval.smoothing=[0.01]",
       "retrieval.prior_weights=[0,4]"]
RF_CUT = ["classifier.params.n_estimators=10", "classifier.params.n_jobs=1"]


def _cut(words: list[str]) -> list[str]:
    keys = {c.split("=")[0] for c in CUT}
    kept = [w for w in words if w.split("=")[0] not in keys]
    classifier = next((w.split("=", 1)[1] for w in kept if w.startswith("classifier=")), "rf")
    return kept + CUT + (RF_CUT if classifier == "rf" else [])


def _documented() -> list[str]:
    return [line for line in bash_lines(ROOT / "docs" / "recognition.md") if line.startswith("aslexp retrieve")]


@pytest.fixture(scope="module")
def clip_cache(tmp_path_factory) -> Path:
    """One dataset cache for this module's runs (the WLASL-Lex builds are made once)."""
    return tmp_path_factory.mktemp("retrieve-cache")


def _cli(args: list[str], cache: Path) -> subprocess.CompletedProcess:
    env = dict(os.environ, ASLEXP_CACHE_DIR=str(cache), MPLBACKEND="Agg")
    return job_process.run([sys.executable, "-m", "aslexp.cli", *args], cwd=ROOT, env=env, capture_output=True,
                          text=True, timeout=300)


def test_the_documented_commands_run_and_write_a_complete_run_folder(tmp_path, clip_cache):
    commands = _documented()
    assert commands, "docs/recognition.md documents `aslexp retrieve`"
    for number, command in enumerate(commands):
        words = shlex.split(command)[2:]
        where = [w for w in words if w.startswith(("hydra.run.dir=", "hydra.sweep.dir="))]
        words = [w for w in words if w not in where]
        multirun = "-m" in words
        folder = tmp_path / f"run{number}"
        words = _cut(words) + [f"hydra.{'sweep' if multirun else 'run'}.dir={folder}"]
        proc = _cli(["retrieve", *words], clip_cache)
        assert proc.returncode == 0, f"{command}: exit {proc.returncode}\n{proc.stderr[-3000:]}"
        run_dir = next(folder.rglob("run.json")).parent
        assert json.loads((run_dir / "run.json").read_text())["status"] == "completed"
        for name in ("metrics.json", "retrieval.md", "ranks.csv", "recall_at_k.png", "retrieve.log"):
            assert (run_dir / name).is_file() and (run_dir / name).stat().st_size > 0, name
        metrics = json.loads((run_dir / "metrics.json").read_text())
        assert metrics["properties"] == ["sign_type", "major_location"] and len(metrics["per_split"]) == 2
        for method in R.METHODS:
            for key in ("recall@1", "recall@10", "recall@50", "mrr", "median_rank"):
                cell = metrics["table"][method][key]
                # two splits: no t interval, null in metrics.json with the reason
                assert cell["n"] == 2 and math.isfinite(cell["mean"]) and cell["interval"] == RR.NO_INTERVAL
                assert cell["low"] is None and cell["high"] is None and cell["half_width"] is None
        assert all(p["diff"]["low"] is None and p["resolved"] == 0 for p in metrics["paired"])
        assert metrics["table"]["chance"]["recall@50"]["mean"] == pytest.approx(50 / 2723)
        assert metrics["objective"]["name"].startswith("val_")  # a sweep never chooses by test
        with (run_dir / "ranks.csv").open() as handle:
            rows = list(csv.DictReader(handle))
        assert len(rows) == sum(s["clips"]["test"] for s in metrics["per_split"])
        assert {r["split"] for r in rows} == {"0", "1"} and all(float(r["rank_oracle"]) >= 1 for r in rows)
        for split in metrics["per_split"]:  # the test glosses were never trained on, for every property
            assert split["glosses"]["train"] + split["glosses"]["val"] + len(split["glosses"]["test"]) == 47
        tests = [s["glosses"]["test"] for s in metrics["per_split"]]
        assert metrics["split_overlap"] == RR.split_overlap(tests)
        assert metrics["split_overlap"]["test_slots"] == sum(len(t) for t in tests) == 14
        _check_frequency(metrics, rows)
        table = (run_dir / "retrieval.md").read_text()
        assert "properties used: sign_type, major_location" in table and "| phonology + prior |" in table
        assert "95% t interval: n/a (fewer than 3 splits)" in table and " [" not in table.split("| method |")[1]
        assert "| rank > 500 |" in table and "median rank by SignFrequency(Z) of the test glosses" in table
        if number == 0:
            _check_results_entry(folder)
        assert "split 2/2" in proc.stderr + (run_dir / "retrieve.log").read_text()  # progress with ETA


def _check_frequency(metrics: dict, rows: list[dict]) -> None:
    """Recall by the true sign's frequency band: every test clip of every split in one band; the
    prior alone never finds a sign ranked beyond 500 by frequency in its top 50."""
    frequency = metrics["frequency"]
    bands = {b["band"]: b for b in frequency["bands"]}
    assert list(bands) == ["rank 1-100", "rank 101-500", "rank > 500"]
    assert sum(b["clips"] for b in bands.values()) == len(rows)
    for band in bands.values():
        assert set(band["methods"]) == {"prior", "phonology", "phonology+prior"}
        assert band["clips"] == 0 or all(0.0 <= band["methods"][m]["recall@50"] <= 1.0 for m in band["methods"])
    rare = bands["rank > 500"]
    assert rare["clips"] == 0 or rare["methods"]["prior"]["recall@50"] == 0.0
    prior_rank = {r["entry_id"]: float(r["rank_prior"]) for r in rows}  # the prior's rank = the frequency rank
    assert frequency["median_prior_rank"]["test_glosses"] == pytest.approx(np.median(list(prior_rank.values())), abs=1e-3)
    assert frequency["median_prior_rank"]["all_glosses"] == pytest.approx(91.5)
    assert frequency["glosses_by_lexicon_tercile"] == {"low": 2, "mid": 2, "high": 43}


def _check_results_entry(folder: Path) -> None:
    """The results page's entry of this run: no interval from 2 splits, the overlap and the bands."""
    from aslexp.results import retrieval as results_retrieval

    snapshot = results_retrieval.results_summary({}, [folder])
    assert snapshot["facts"]["splits"] == 2 and snapshot["facts"]["split_overlap"]["test_slots"] == 14
    table = "\n".join(results_retrieval.table(snapshot))
    assert "[" not in table  # no interval from 2 splits
    legend = "\n".join(results_retrieval.legend(snapshot))
    assert "95% t interval: n/a (fewer than 3 splits)" in legend and "test-gloss slots" in legend
    assert "frequency prior is strong because WLASL's glosses are common words" in legend
    assert "| rank 1-100 |" in legend and "phonology + prior @50 (%)" in legend


def test_an_unknown_property_is_one_clear_line(tmp_path):
    proc = _cli(["retrieve", "retrieval.properties=[sign_type,handshape]", f"hydra.run.dir={tmp_path / 'bad'}"],
                tmp_path / "cache")
    assert proc.returncode == 2
    lines = [line for line in proc.stderr.splitlines() if line.strip()]
    assert lines[-1].startswith("aslexp retrieve: retrieval.properties: unknown property 'handshape'"), proc.stderr
    assert "Traceback" not in proc.stderr
