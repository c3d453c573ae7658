"""The lexicon-retrieval entry of the results page (``report: retrieval``): an ``aslexp retrieve`` run's
table, one row per method (chance, the frequency prior, phonology, phonology + prior, the oracle,
oracle + prior): recall@k, MRR and the median rank, each the mean over gloss splits with its 95% t
interval (none below 3 splits). The legend says how often the splits reuse test glosses, why the
frequency prior is strong, recall by the frequency band of the true sign, and where the lookup's
targets land."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from aslexp.results.kinds import ReportKind, register_report
from aslexp.results.render import render_entry, with_table
from aslexp.results.snapshots import number, split_table_rows
from aslexp.runs.completed import find_job_runs, latest

REPORT = "retrieval"
JOB = "retrieve"
METRICS = ("recall@1", "recall@10", "recall@50", "mrr", "median_rank")
HEADERS = {"recall@1": "recall@1 (%)", "recall@10": "recall@10 (%)", "recall@50": "recall@50 (%)", "mrr": "MRR",
           "median_rank": "median rank"}
# The lookup's targets: phonology alone recall@50 >= 10%; with the prior >= 50% and a median
# rank below the prior's.
TARGET_ALONE, TARGET_COMBINED = 0.10, 0.50


def results_summary(entry: dict[str, Any], folders: list[Path]) -> dict[str, Any]:
    """The rows of the latest completed retrieve run under ``folders`` (one per method) and its facts;
    the earlier runs there are counted as left out."""
    runs, skipped = find_job_runs(folders, JOB)
    if not runs:
        return {"rows": [], "run_dirs": [], "skipped": skipped}
    run_dir, metrics = latest(runs, skipped)
    rows = split_table_rows(metrics, METRICS, "recall@50", "test recall@50 over gloss splits")
    splits = metrics["per_split"]
    tests = [s["clips"]["test"] for s in splits]
    facts = {
        "properties": list(metrics["properties"]), "classifier": metrics["classifier"],
        "likelihood": metrics.get("likelihood", "posterior"), "lexicon_entries": metrics["lexicon_entries"],
        "clips": metrics["num_clips"], "glosses": metrics["num_glosses"], "splits": len(splits),
        "test_clips": [min(tests), max(tests)], "test_glosses": sorted({len(s["glosses"]["test"]) for s in splits}),
        "select_by": metrics["selection"]["select_by"],
        "prior_weights_chosen": [s["chosen"]["phonology+prior"]["weight"] for s in splits],
        "oracle_lexicon": {k: metrics["oracle_lexicon"][k] for k in ("recall@10", "recall@50", "chance_recall@10",
                                                                      "chance_recall@50")},
        "paired": [{"method": p["method"], "reference": p["reference"], "metric": p["metric"],
                    "diff": {k: number(p["diff"][k]) for k in ("mean", "low", "high")},
                    "wins": p["wins"], "ties": p["ties"], "losses": p["losses"], "wilcoxon_p": number(p["wilcoxon_p"])}
                   for p in metrics.get("paired", [])],
        "recall_at": list(metrics.get("recall_at", [])),
    }
    if "split_overlap" in metrics:  # runs made before these were recorded have neither
        facts["split_overlap"] = dict(metrics["split_overlap"])
    if "frequency" in metrics:
        facts["frequency"] = _frequency_facts(metrics["frequency"])
    return {"rows": rows, "run_dirs": [run_dir], "skipped": skipped, "quantity": "test retrieval over gloss splits",
            "row_name": "method", "facts": facts}


def _frequency_facts(frequency: dict[str, Any]) -> dict[str, Any]:
    """metrics.json's ``frequency`` with its numbers as a snapshot keeps them (None for NaN)."""
    bands = [{"band": b["band"], "clips": b["clips"], "glosses": b["glosses"],
              "methods": {m: {k: number(v) for k, v in values.items()} for m, values in b["methods"].items()}}
             for b in frequency["bands"]]
    median = {k: number(v) for k, v in frequency["median_prior_rank"].items()}
    return {**frequency, "median_prior_rank": median, "bands": bands}


def _cell(metric: str, cell: dict[str, Any]) -> str:
    mean, low, high = cell.get("mean"), cell.get("low"), cell.get("high")
    if mean is None:
        return "-"
    if metric.startswith("recall@"):
        fmt = lambda v: f"{100 * v:.1f}"  # noqa: E731
    elif metric == "median_rank":
        fmt = lambda v: f"{v:.0f}"  # noqa: E731
    else:
        fmt = lambda v: f"{v:.3f}"  # noqa: E731
    return fmt(mean) + (f" [{fmt(low)}, {fmt(high)}]" if low is not None and high is not None else "")


def targets(snapshot: dict[str, Any]) -> str:
    """Where the lookup's targets land, from the snapshot's numbers."""
    rows = {r["key"]: r["learned"]["metrics"] for r in snapshot["rows"]}
    alone, both, prior = rows.get("phonology"), rows.get("phonology+prior"), rows.get("prior")
    if not (alone and both and prior) or None in (alone["recall@50"]["mean"], both["recall@50"]["mean"]):
        return ""

    def mark(ok: bool) -> str:
        return "reached" if ok else "not reached"

    a, b = alone["recall@50"]["mean"], both["recall@50"]["mean"]
    rb, rp = both["median_rank"]["mean"], prior["median_rank"]["mean"]
    return (f"Targets: phonology alone recall@50 >= {100 * TARGET_ALONE:.0f}%: {mark(a >= TARGET_ALONE)} "
            f"({100 * a:.1f}%); phonology + prior recall@50 >= {100 * TARGET_COMBINED:.0f}%: "
            f"{mark(b >= TARGET_COMBINED)} ({100 * b:.1f}%); its median rank below the prior's: "
            f"{mark(rb < rp)} ({rb:.0f} against {rp:.0f}).")


def table(snapshot: dict[str, Any]) -> list[str]:
    header = [snapshot.get("row_name") or "method", *[HEADERS[m] for m in METRICS]]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for row in snapshot["rows"]:
        cells = row["learned"]["metrics"]
        lines.append("| " + " | ".join([row["label"], *[_cell(m, cells[m]) for m in METRICS]]) + " |")
    return lines


def legend(snapshot: dict[str, Any]) -> list[str]:
    facts = snapshot.get("facts") or {}
    if not facts:
        return []
    from aslexp.recognition.retrieval_run import frequency_lines, interval_text

    oracle = facts["oracle_lexicon"]
    scored = "the likelihood ratio" if facts.get("likelihood") == "ratio" else "the posterior"
    glosses = "-".join(str(g) for g in (facts["test_glosses"][0], facts["test_glosses"][-1])) \
        if len(facts["test_glosses"]) > 1 else str(facts["test_glosses"][0])
    text = (f"Numbers: each test clip's gloss never seen in training, ranked among all {facts['lexicon_entries']:,} "
            f"ASL-LEX entries; properties used: {', '.join(facts['properties'])}; classifier {facts['classifier']} "
            f"(phonology scored as {scored}); {facts['splits']} gloss splits of {facts['glosses']} glosses / "
            f"{facts['clips']} clips ({glosses} test glosses, {facts['test_clips'][0]}-{facts['test_clips'][1]} test "
            f"clips per split); {interval_text(facts['splits'], facts.get('split_overlap'))} Smoothing and prior weight chosen on the validation "
            f"glosses by {facts['select_by']} (prior weight per split: "
            f"{', '.join(f'{w:g}' for w in facts['prior_weights_chosen'])}). Over every lexicon entry the oracle with "
            f"these properties gives recall@10 {100 * oracle['recall@10']:.1f}% and recall@50 "
            f"{100 * oracle['recall@50']:.1f}% (chance {100 * oracle['chance_recall@10']:.2f}% and "
            f"{100 * oracle['chance_recall@50']:.2f}%); the oracle rows above are over the test clips' glosses.")
    line = targets(snapshot)
    labels = {r["key"]: r["label"] for r in snapshot["rows"]}
    paired = []
    for item in facts.get("paired") or []:
        diff, percent = item["diff"], item["metric"].startswith("recall@")
        scale = 100.0 if percent else 1.0
        interval = f" [{scale * diff['low']:+.1f}, {scale * diff['high']:+.1f}]" if diff["low"] is not None else ""
        paired.append(f"{labels.get(item['method'], item['method'])} minus {labels.get(item['reference'], item['reference'])}, "
                      f"{item['metric']}{' (points)' if percent else ''}: {scale * diff['mean']:+.1f}{interval}, splits "
                      f"higher/equal/lower {item['wins']}/{item['ties']}/{item['losses']}, Wilcoxon p = "
                      f"{'-' if item['wilcoxon_p'] is None else format(item['wilcoxon_p'], '.3g')}")
    paired_line = [f"Paired over the same splits: {'; '.join(paired)}.", ""] if paired else []
    frequency = []
    if facts.get("frequency"):
        frequency = frequency_lines(facts["frequency"], facts.get("recall_at") or [10, 50],
                                    facts["lexicon_entries"], facts["glosses"]) + [""]
    return [text, ""] + ([line, ""] if line else []) + paired_line + frequency


def render(entry: dict[str, Any], snapshot: dict[str, Any] | None) -> list[str]:
    """``render_entry``'s lines for a retrieval entry with its table (and the line of numbers) in place
    of the generic one."""
    if snapshot is None:
        return render_entry(entry, snapshot)
    return with_table(entry, snapshot, table(snapshot), legend(snapshot))


register_report(ReportKind(REPORT, results_summary, render, job_defaults=True))
