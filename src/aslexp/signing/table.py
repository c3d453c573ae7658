"""The signer against the person over many clips (``aslexp signing``; docs/signing.md, "The table"):
per stage (the retargeted reference, the controller alone, a policy) the keypoint error to the
person and the recognition wing's reading beside the person's own clip, with intervals over glosses.

A record is one clip's (:func:`aslexp.jobs.signing.score_clip`): ``gloss``, ``stages`` (each
stage's ``signing`` scores) and ``read_back`` (:func:`aslexp.signing.reading.read_back_stages`).
The targets are the ones a readable signer should meet: each body property's agreement with
ASL-LEX within 5 points of the source clip's own, the lookup's median rank within 10% of the
source's, and the controller's keypoint error at most 1.2x the retargeted reference's.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from aslexp.signing.reading import SOURCE_STAGE

AGREEMENT_POINTS = 0.05  # a stage keeps a property when its agreement is within 5 points of the source's
RANK_RATIO = 1.10  # ... and the lexicon rank when its median is within 10% of the source's
PHYSICS_RATIO = 1.2  # the controller's keypoint error at most this times the reference's


def gloss_bootstrap(values: np.ndarray, glosses: Sequence[str], how: str, resamples: int, confidence: float,
               seed: int) -> dict[str, float]:  # fmt: skip
    """A statistic of per-clip ``values`` (NaN: no value) with a percentile bootstrap over glosses."""
    values = np.asarray(values, dtype=np.float64)
    known = np.isfinite(values)
    stat = np.median if how == "median" else np.mean
    if not known.any():
        return {"value": math.nan, "low": math.nan, "high": math.nan, "n": 0}
    names = np.asarray(glosses, dtype=object)
    groups = [np.flatnonzero((names == g) & known) for g in sorted(set(names[known]))]
    rng = np.random.default_rng(seed)
    draws = [float(stat(values[np.concatenate([groups[i] for i in rng.integers(len(groups), size=len(groups))])]))
             for _ in range(resamples)]
    tail = (1 - confidence) / 2
    low, high = np.quantile(draws, [tail, 1 - tail])
    q25, q75 = np.quantile(values[known], [0.25, 0.75])
    return {"value": float(stat(values[known])), "low": float(low), "high": float(high), "n": int(known.sum()),
            "q25": float(q25), "q75": float(q75)}


def stage_names(records: Sequence[Mapping[str, Any]]) -> list[str]:
    """The stages the records hold, in their order (reference, controller, policy)."""
    names: list[str] = []
    for record in records:
        names += [n for n in record.get("stages") or {} if n not in names]
    return names


def keypoint_errors(records: Sequence[Mapping[str, Any]], stage: str, part: str = "body") -> np.ndarray:
    """Per clip the stage's DTW mean joint error of ``part`` (NaN where none)."""
    out = []
    for record in records:
        cell = ((record.get("stages") or {}).get(stage) or {}).get(part) or {}
        value = cell.get("dtw_mje", cell.get("dtwp", cell.get("handshape")))
        out.append(math.nan if value is None else float(value))
    return np.asarray(out)


def hand_values(records: Sequence[Mapping[str, Any]], stage: str, metric: str) -> np.ndarray:
    """Per clip the hand body's ``metric`` (handshape, dtw_mje, dtwp) at ``stage`` (NaN where none)."""
    values = [(((r.get("hand") or {}).get("stages") or {}).get(stage) or {}).get(metric) for r in records]
    return np.asarray([math.nan if v is None else float(v) for v in values])


def rewards(records: Sequence[Mapping[str, Any]], stage: str) -> np.ndarray:
    """Per clip the stage's mean reward over its pass (NaN where the stage did not run)."""
    values = [(r.get("rewards") or {}).get(stage) for r in records]
    return np.asarray([math.nan if v is None else float(v) for v in values])


def lexicon_ranks(records: Sequence[Mapping[str, Any]], reading: str) -> list[float]:
    """Per clip read back the lexicon rank of the true gloss by ``reading`` (a stage or the source)."""
    return [float(r["read_back"]["stages"][reading]["lexicon_rank"]) for r in records
            if r.get("read_back") and reading in r["read_back"]["stages"]]


def build_table(records: Sequence[Mapping[str, Any]], properties: Sequence[str], recall_at: Sequence[int] = (10, 50),
                resamples: int = 2000, confidence: float = 0.95, seed: int = 0) -> dict[str, Any]:  # fmt: skip
    """Every stage's keypoint error and reward, and every reading's agreement and lexicon rank (the
    source's beside), each with its bootstrap interval over glosses; then the targets."""
    from aslexp.recognition.read_back import IntervalSettings, table_of

    scored = [r for r in records if r.get("stages")]
    glosses = [str(r["gloss"]) for r in scored]
    stages = stage_names(scored)
    interval = IntervalSettings(resamples=resamples, confidence=confidence, seed=seed)
    table: dict[str, Any] = {"clips": len(scored), "glosses": len(set(glosses)), "stages": stages,
                             "keypoint_error": {}, "reward": {}, "read_back": {}}
    for stage in stages:
        table["keypoint_error"][stage] = {
            part: gloss_bootstrap(keypoint_errors(scored, stage, part), glosses, "median", resamples, confidence, seed)
            for part in ("body", "left_hand", "right_hand", "hands", "handshape")}
        if stage != "reference":
            table["reward"][stage] = gloss_bootstrap(rewards(scored, stage), glosses, "mean", resamples, confidence, seed)
    hands = [r for r in scored if (r.get("hand") or {}).get("stages")]
    if hands:  # the hand body's fingers on the reference arm (aslexp.jobs.signing.score_hand_clip)
        names = [str(r["gloss"]) for r in hands]
        table["hand_body"] = {stage: {metric: gloss_bootstrap(hand_values(hands, stage, metric), names, "median",
                                                         resamples, confidence, seed)
                                      for metric in ("handshape", "dtw_mje")}
                              for stage in HAND_STAGES}
    read = [r for r in scored if r.get("read_back")]
    for stage in [SOURCE_STAGE, *stages]:
        results = [{**r["read_back"]["stages"][stage], "gloss": r["gloss"]} for r in read
                   if stage in r["read_back"]["stages"]]
        if results:
            table["read_back"][stage] = table_of(results, properties, recall_at, interval)
    table["targets"] = targets(table, properties)
    return table


def targets(table: Mapping[str, Any], properties: Sequence[str]) -> dict[str, Any]:
    """Each stage against the bars a readable signer meets (module doc): met, or by how much it misses."""
    out: dict[str, Any] = {}
    read = table.get("read_back") or {}
    source = read.get(SOURCE_STAGE)
    for stage in table["stages"]:
        row: dict[str, Any] = {}
        if source is not None and stage in read:
            for prop in properties:
                ours = read[stage]["properties"][prop]["agreement"]["value"]
                theirs = source["properties"][prop]["agreement"]["value"]
                row[f"{prop} agreement"] = {"value": ours, "source": theirs,
                                            "met": bool(ours >= theirs - AGREEMENT_POINTS)}
            ours = read[stage]["lookup"]["phonology+prior"]["median_rank"]["value"]
            theirs = source["lookup"]["phonology+prior"]["median_rank"]["value"]
            row["lookup median rank"] = {"value": ours, "source": theirs, "met": bool(ours <= RANK_RATIO * theirs)}
        if stage != "reference" and "reference" in table["keypoint_error"]:
            ours = table["keypoint_error"][stage]["body"]["value"]
            theirs = table["keypoint_error"]["reference"]["body"]["value"]
            row["body keypoint error"] = {"value": ours, "reference": theirs, "ratio": ours / theirs if theirs else math.nan,
                                          "met": bool(ours <= PHYSICS_RATIO * theirs)}
        out[stage] = row
    return out


def _cell(c: Mapping[str, float], digits: int = 3, scale: float = 1.0) -> str:
    if not math.isfinite(c["value"]):
        return "-"
    return f"{scale * c['value']:.{digits}f} [{scale * c['low']:.{digits}f}, {scale * c['high']:.{digits}f}]"


def table_lines(table: Mapping[str, Any], properties: Sequence[str], recall_at: Sequence[int] = (10, 50)) -> list[str]:
    """The table as Markdown: keypoint error and reward per stage, then each reading per stage."""
    stages = table["stages"]
    lines = ["| stage | body keypoint error, median [95% CI] (IQR) | reward (mean) |", "|---|---|---|"]
    for stage in stages:
        body = table["keypoint_error"][stage]["body"]
        iqr = f" ({body['q25']:.3f}-{body['q75']:.3f})" if body["n"] else ""
        reward = table["reward"].get(stage)
        lines.append(f"| {stage} | {_cell(body)}{iqr} | {'-' if reward is None else _cell(reward)} |")
    shape = {stage: table["keypoint_error"][stage].get("handshape") for stage in stages}
    if any(c and c["n"] for c in shape.values()):
        lines += ["", "| stage | handshape error, median [95% CI] (hand sizes) |" +
                  (" hand body's handshape error (its fingers worn on the reference arm) |" if "hand_body" in table
                   else ""), "|---|---|" + ("---|" if "hand_body" in table else "")]
        for stage in [*stages, *(s for s in table.get("hand_body") or {} if s not in stages)]:
            hand = (table.get("hand_body") or {}).get(stage)
            mine = shape.get(stage)
            lines.append(f"| {stage} | {_cell(mine) if mine else '-'} |"
                         + (f" {_cell(hand['handshape']) if hand else '-'} |" if "hand_body" in table else ""))
    read = table.get("read_back") or {}
    if read:
        names = [n for n in (SOURCE_STAGE, *stages) if n in read]
        lines += ["", "| reading (% or rank) | " + " | ".join(names) + " |", "|---|" + "---|" * len(names)]
        for prop in properties:
            lines.append(f"| {prop} agreement with ASL-LEX | "
                         + " | ".join(_cell(read[n]["properties"][prop]["agreement"], 1, 100) for n in names) + " |")
        lines.append(f"| {properties[0]} majority value's | "
                     + " | ".join(_cell(read[n]["properties"][properties[0]]["majority"], 1, 100) for n in names) + " |")
        lines.append("| lookup median rank | "
                     + " | ".join(_cell(read[n]["lookup"]["phonology+prior"]["median_rank"], 1) for n in names) + " |")
        for k in recall_at:
            lines.append(f"| lookup recall@{k} | "
                         + " | ".join(_cell(read[n]["lookup"]["phonology+prior"][f"recall@{k}"], 1, 100) for n in names)
                         + " |")
        lines.append("| frequency prior alone, median rank | "
                     + " | ".join(_cell(read[n]["lookup"]["prior"]["median_rank"], 1) for n in names) + " |")
    return lines


HAND_STAGES = ("reference", "controller", "open hand")  # the hand body's (aslexp.jobs.signing.score_hand_clip)
CLIP_ROWS = 12  # a table of at most this many clips also gets a row per clip


def clip_lines(records: Sequence[Mapping[str, Any]]) -> list[str]:
    """A row per clip: the body's and the hands' errors per stage, the hand body's, the lexicon ranks."""
    scored = [r for r in records if r.get("stages")]
    stages = stage_names(scored)
    value = (lambda v, d=3: "-" if v is None or not math.isfinite(float(v)) else f"{float(v):.{d}f}")
    per = (lambda cells: " / ".join(cells))
    header = " / ".join(stages)
    lines = [f"| clip (gloss) | plausible | body error: {header} | handshape (the hand motion's side): {header} | "
             "hand body's handshape: " + " / ".join(HAND_STAGES) + " (reward) | lookup rank: source / " + header + " |",
             "|---|---|---|---|---|---|"]
    for r in scored:
        cells = r["stages"]
        hand = r.get("hand") or {}
        side = hand.get("side")
        hand_cell = (per(value((hand["stages"].get(s) or {}).get("handshape")) for s in HAND_STAGES)
                     + f" ({value((hand.get('rewards') or {}).get('controller'))})" if hand.get("stages")
                     else "-" if not hand else "not scored")
        ranks = ((r.get("read_back") or {}).get("stages") or {})
        lines.append(f"| {r['motion']} ({r.get('gloss')}) | {'yes' if r.get('plausible', True) else 'no'} | "
                     f"{per(value(cells[s]['body'].get('dtw_mje')) for s in stages)} | "
                     f"{per(value((cells[s].get('handshape') or {}).get(side or 'handshape')) for s in stages)} | {hand_cell} | "
                     f"{per(value((ranks.get(n) or {}).get('lexicon_rank'), 0) for n in (SOURCE_STAGE, *stages))} |")
    return lines


def clip_handshapes(records: Sequence[Mapping[str, Any]]) -> dict[str, dict[str, float]]:
    """Per clip with a hand body's run: the handshape error of the hand motion's side, retargeted
    (the reference), performed by each body's controller, and held open (the floor)."""
    out = {}
    for r in records:
        hand = r.get("hand") or {}
        if not hand.get("stages"):
            continue
        side = hand["side"]
        upper = {s: ((r["stages"].get(s) or {}).get("handshape") or {}).get(side) for s in ("reference", "controller")}
        values = {"retargeted (reference)": upper["reference"], "upper body's controller": upper["controller"],
                  "hand body's controller": hand["stages"]["controller"].get("handshape"),
                  "open hand": hand["stages"]["open hand"].get("handshape")}
        out[f"{r['motion']}\n{r.get('gloss')}"] = {k: float(v) for k, v in values.items() if v is not None}
    return out


def verdict_lines(table: Mapping[str, Any]) -> list[str]:
    """Each target per stage, plainly: met or missed, with both numbers."""
    lines = []
    for stage, row in table["targets"].items():
        for name, cell in row.items():
            theirs = cell.get("source", cell.get("reference"))
            bar = "the source's" if "source" in cell else "the reference's"
            shown = ((lambda v: f"{100 * v:.1f}%") if "agreement" in name else
                     (lambda v: f"{v:g}") if "rank" in name else (lambda v: f"{v:.3f}"))
            lines.append(f"- {stage}: {name} {shown(cell['value'])} against {bar} {shown(theirs)}: "
                         f"{'met' if cell['met'] else 'MISSED'}")
    return lines
