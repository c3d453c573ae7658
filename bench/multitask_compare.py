"""Multi-task vs per-property models: over K seeded phoneme and K seeded gloss
splits, the multi-task network (:mod:`aslexp.recognition.models.multitask`, one head per property), the
same encoder trained once per property (one head), and rf per property; test MCC per property, the
paired difference with its 95% t interval, and each multi-task head's ECE before/after temperature
scaling on the test clips.

    python bench/multitask_compare.py --repeats 10 --out outputs/multitask_compare

The clips are those :func:`aslexp.jobs.retrieve.retrieval_clips` aligns by video id across the
properties' WLASL-Lex builds (ASL-LEX 2.0, MediaPipe Pose); one split per seed serves every
property and model (split by clip for ``phoneme``, by gloss for ``gloss``; 70/15/15, not stratified:
a split stratified by one property would be arbitrary for the others). Every model trains on train,
chooses on val (epoch, temperature) and is tested on test: no retrain on train+val.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from pathlib import Path

import numpy as np

PROPERTIES = ("sign_type", "major_location", "minor_location", "movement", "selected_fingers", "flexion")
MODELS = ("multitask", "single", "rf")
log = logging.getLogger("multitask_compare")


def load_clips(properties=PROPERTIES, overrides=()):
    """(RetrievalClips, codes (N, P) with -1 for an unknown value) of the retrieve job's data config."""
    from aslexp.compose import compose
    from aslexp.data.lexicon import load_lexicon
    from aslexp.jobs.retrieve import retrieval_clips
    from aslexp.recognition.retrieval import lexicon_table

    cfg = compose("retrieve", list(overrides))
    lexicon = load_lexicon(cfg["data"]["lexicon"], cfg["data"]["root"],
                           movement_none_as_missing=bool(cfg["data"].get("movement_none_as_missing", False)))
    table = lexicon_table(lexicon.entries, list(properties), {p: lexicon.vocabulary(p) for p in properties})
    clips = retrieval_clips(cfg, list(properties), table, Path(cfg["cache_dir"]))
    return clips, table.codes[clips.entry_rows]


def split_indices(glosses, kind: str, seed: int):
    """train, val, test clip indices of one 70/15/15 split (by clip or by gloss) for every property."""
    from aslexp.data.splits import SplitOptions, resplit

    result = resplit(["all"] * len(glosses), list(glosses), SplitOptions(name=kind), seed)
    return tuple(np.sort(result.keep[np.asarray(result.splits[n], dtype=np.int64)]) for n in ("train", "val", "test"))


def rf_mcc(clips, codes, j, train, test, seed, n_estimators=300):
    from aslexp.recognition.metrics import mcc
    from aslexp.recognition.models import build_classifier

    known = train[codes[train, j] >= 0]
    classes = np.unique(codes[known, j])
    _, c, t, v, _ = clips.X.shape
    model = build_classifier("rf", {"n_estimators": n_estimators, "n_jobs": 2}, c, t, v, len(classes), clips.layout)
    model.fit(clips.X[known], clips.mask[known], np.searchsorted(classes, codes[known, j]), seed=seed)
    target = test[codes[test, j] >= 0]
    return mcc(codes[target, j], classes[model.predict(clips.X[target], clips.mask[target])])


def run(repeats: int, kinds, out: Path, params: dict, properties=PROPERTIES, seed0: int = 0) -> dict:
    from aslexp.recognition.models.multitask import fit_multitask

    clips, codes = load_clips(properties)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for kind in kinds:
        for k in range(repeats):
            seed = seed0 + k
            start = time.perf_counter()
            train, val, test = split_indices(clips.glosses, kind, seed)
            row = {"kind": kind, "seed": seed, "clips": [len(train), len(val), len(test)], "mcc": {}, "ece": {}}
            mt = fit_multitask(clips.X, clips.mask, codes, properties, train, val, params, seed=seed)
            log.info("multitask fit: %.1f s, best epoch %d of %d", time.perf_counter() - start, mt.best_epoch,
                     len(mt.history))
            evaluation = mt.evaluate(clips.X[test], clips.mask[test], codes[test])
            row["mcc"]["multitask"] = {p: evaluation[p]["mcc"] for p in properties}
            row["ece"] = {p: {key: evaluation[p][key] for key in ("ece_before", "ece_after", "nll_before", "nll_after",
                                                                  "temperature")} for p in properties}
            row["mcc"]["single"], row["mcc"]["rf"] = {}, {}
            for j, prop in enumerate(properties):
                single = fit_multitask(clips.X, clips.mask, codes[:, [j]], [prop], train, val, params, seed=seed,
                                       calibrate=False)
                row["mcc"]["single"][prop] = single.evaluate(clips.X[test], clips.mask[test], codes[test][:, [j]])[prop]["mcc"]
                row["mcc"]["rf"][prop] = rf_mcc(clips, codes, j, train, test, seed)
                log.info("%s: single (best epoch %d) and rf done at %.1f s", prop, single.best_epoch,
                         time.perf_counter() - start)
            row["time_s"] = time.perf_counter() - start
            rows.append(row)
            log.info("%s split seed %d: %.0f s; MCC multitask %s | single %s | rf %s", kind, seed, row["time_s"],
                     *[" ".join(f"{row['mcc'][m][p]:.2f}" for p in properties) for m in MODELS])
            (out / "splits.json").write_text(json.dumps(rows, indent=1))
    summary = summarize(rows, properties)
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    (out / "table.md").write_text("\n".join(table_lines(summary, properties)) + "\n")
    return summary


def summarize(rows, properties=PROPERTIES) -> dict:
    from aslexp.recognition.metrics import mean_interval, paired_comparison

    summary = {}
    for kind in sorted({r["kind"] for r in rows}):
        mine = [r for r in rows if r["kind"] == kind]
        entry = {"splits": len(mine), "mcc": {}, "paired": {}, "ece": {}}
        for prop in properties:
            values = {m: [r["mcc"][m][prop] for r in mine] for m in MODELS}
            entry["mcc"][prop] = {m: mean_interval(values[m]) for m in MODELS}
            entry["paired"][prop] = {ref: paired_comparison(values["multitask"], values[ref]) for ref in ("single", "rf")}
            entry["ece"][prop] = {key: mean_interval([r["ece"][prop][key] for r in mine])
                                  for key in ("ece_before", "ece_after", "nll_before", "nll_after", "temperature")}
        summary[kind] = entry
    return summary


def _cell(interval, digits=2):
    if not math.isfinite(interval["mean"]):
        return "-"
    if not math.isfinite(interval["low"]):
        return f"{interval['mean']:.{digits}f}"
    return f"{interval['mean']:.{digits}f} [{interval['low']:.{digits}f}, {interval['high']:.{digits}f}]"


def table_lines(summary, properties=PROPERTIES) -> list[str]:
    lines = []
    for kind, entry in summary.items():
        lines += [f"{kind} splits ({entry['splits']}): test MCC, mean [95% t interval]; multi-task minus the other, "
                  "paired over the same splits (wins/ties/losses); multi-task ECE on test before -> after temperature "
                  "scaling", "",
                  "| property | multi-task | per-property (same encoder) | rf | MT - per-property | MT - rf | ECE before | ECE after |",
                  "|---|---|---|---|---|---|---|---|"]
        for prop in properties:
            m, pair, ece = entry["mcc"][prop], entry["paired"][prop], entry["ece"][prop]
            diffs = [f"{_cell(pair[ref]['diff'])} ({pair[ref]['wins']}/{pair[ref]['ties']}/{pair[ref]['losses']})"
                     for ref in ("single", "rf")]
            lines.append(f"| {prop} | {_cell(m['multitask'])} | {_cell(m['single'])} | {_cell(m['rf'])} | "
                         f"{diffs[0]} | {diffs[1]} | {_cell(ece['ece_before'], 3)} | {_cell(ece['ece_after'], 3)} |")
        lines.append("")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=10)
    parser.add_argument("--kinds", default="phoneme,gloss")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("outputs/multitask_compare"))
    parser.add_argument("--params", default="{}", help="JSON: multitask params (encoder and fit keys)")
    args = parser.parse_args()
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    import torch

    torch.set_num_threads(1)  # the 2 cores are shared: 2 threads spin against other jobs
    summary = run(args.repeats, args.kinds.split(","), args.out, json.loads(args.params), seed0=args.seed)
    print("\n".join(table_lines(summary)))


if __name__ == "__main__":
    main()
