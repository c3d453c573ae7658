"""`aslexp report RUN_OR_SWEEP_DIR... [--out DIR]`: recognition runs -> tables, comparisons, agreement.
`aslexp report --results [--outputs DIR] [--render-only] [--add-test-clips]`: the results page, docs/results.md
(aslexp.results: one table per result of conf/results.yaml, from snapshots made of run folders;
recognition rows carry their test clips and intervals, aslexp.results.recognition).

Reads only run directories (run.json + metrics.json + predictions.csv) and writes, per keypoint
layout and lexicon (a suffix names the group when a folder holds more than one):

    table.md / table.csv              models x properties: test MCC, mean ± 95% t interval over the
                                      splits (model seeds for one split), balanced accuracy; ▼ marks a
                                      mean below the chance baseline; the baseline rows
    comparisons.md / .json            every model minus the chance baseline and minus the strongest
                                      simple baseline (rf/hgb/logreg/svm, best by validation), paired
                                      on the same splits: mean difference [95% CI], W/T/L, Wilcoxon p
    best_vs_baseline.md / .csv / .png per property and split: the model chosen by validation against
                                      the chance baseline
    table_thesis_ch3.md               Table 3.4's layout (micro/macro F1, mean ± std)
    table_thesis_ch4.md               Tables 4.2/4.3's layout (A ± 95% half-width, Ā) and C.2's (P_μ, P_M, R_M, MCC)
    comparisons.png                   the paired differences to the strongest simple baseline, per
                                      property and split (95% intervals)
    validation_curves.png             per property and split, the validation MCC per epoch of the
                                      models trained over epochs (mean over runs) against the
                                      feature baselines' validation MCC
    run_plots/<split>_<property>_<model>/  confusion_matrix.png, learning_curves.png drawn from
                                      metrics.json for runs whose folder has none (a GPU node
                                      without matplotlib); the run folders are not touched
    agreement.json                    the thesis' section 4.4: Fleiss' kappa over the clips that all
                                      models misclassify, per task, with mean ± std over the six tasks;
                                      the mutual misclassification (clips in 2 (3) test sets wrong for
                                      every model on all of them); the per-model error overlap
    runs.md / runs.csv                the runs of other jobs (tune_pd, imitate, ...), per job best
                                      main metric first: folder, status, main metric, overrides

A folder with several runs of one split, model and property (an Optuna sweep's trials) is
reported by the one with the best validation objective (run.json's main metric), named in a log
line; test numbers never choose. A damaged run.json or metrics.json is named in one warning line
and its run left out (:mod:`aslexp.runs.read`).
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

# This module parses the arguments and dispatches: aslexp.runs.folder_report writes a folder's files,
# aslexp.results the results page.


def results_main(args: argparse.Namespace) -> int:
    """``aslexp report --results``: the snapshots from the run folders, then docs/results.md."""
    from aslexp.results.recognition import add_test_clips_to_snapshots
    from aslexp.results.render import write_results

    if not args.catalogue.is_file():
        print(f"aslexp report: {args.catalogue}: no such file", file=sys.stderr)
        return 2
    if args.add_test_clips:
        for entry_id, what in add_test_clips_to_snapshots(args.catalogue, args.snapshots).items():
            print(f"{entry_id}: {what}")
    result = write_results(args.catalogue, args.outputs, args.snapshots, args.page, render_only=args.render_only)
    for entry_id, what in result["entries"].items():
        print(f"{entry_id}: {what}")
    print(f"-> {result['page']}")
    return 0


def report_main(argv: list[str]) -> int:
    from aslexp.results.catalogue import CATALOGUE
    from aslexp.results.render import PAGE
    from aslexp.results.snapshots import SNAPSHOTS
    from aslexp.runs.folder_report import write_report

    parser = argparse.ArgumentParser(prog="aslexp report", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="*", type=Path, help="run or sweep directories")
    parser.add_argument("--out", type=Path, default=None, help="output folder (default: first path)")
    page = parser.add_argument_group("the results page (docs/results.md, from conf/results.yaml)")
    page.add_argument("--results", action="store_true",
                      help="summarise every result of the catalogue whose run folders are under --outputs into "
                           "its snapshot (docs/results/<id>.json; others keep theirs) and render the page")
    page.add_argument("--render-only", action="store_true", help="with --results: render the page from the snapshots")
    page.add_argument("--add-test-clips", action="store_true",
                      help="with --results: first add the test clips (the split recomputed from the data), intervals "
                           "and majority values to the recognition snapshots that lack them (run folders gone)")
    page.add_argument("--outputs", type=Path, default=Path("outputs"),
                      help="where the run folders are (default: outputs)")
    page.add_argument("--catalogue", type=Path, default=CATALOGUE, help="default: conf/results.yaml")
    page.add_argument("--snapshots", type=Path, default=SNAPSHOTS, help="default: docs/results")
    page.add_argument("--page", type=Path, default=PAGE, help="default: docs/results.md")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    if args.results:
        if args.paths:
            parser.error("--results reads the catalogue's folders: give no paths")
        return results_main(args)
    if args.render_only or args.add_test_clips:
        parser.error("--render-only and --add-test-clips go with --results")
    if not args.paths:
        parser.error("give run or sweep directories, or --results")
    missing = [path for path in args.paths if not path.exists()]
    if missing:
        print(f"aslexp report: {missing[0]}: no such file or directory", file=sys.stderr)
        return 2
    result = write_report(args.paths, args.out or args.paths[0])
    if result["runs"]:
        print(f"{result['runs']} recognition runs -> {result['out_dir']}\n")
        print(result["table"])
        print(result["best_vs_baseline"])
    if result["other_runs"]:
        print(f"{result['other_runs']} runs of other jobs -> {Path(result['out_dir']) / 'runs.md'}\n")
        print(result["runs_table"])
    for path in args.paths:
        if (path / "sweep.json").is_file():
            print(f"{path} is an Optuna sweep: `aslexp sweep report {path}` draws its study (history, importances)")
    return 0
