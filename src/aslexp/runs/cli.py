"""``aslexp runs ...`` and ``aslexp sweep ...``: find, compare and repeat runs and sweeps.

    aslexp runs list [PATH ...] [--job J] [--status S] [--since DATE] [--where KEY=VALUE]
                     [--sort time|metric] [--limit N] [--format table|json]   (PATH: ./outputs)
    aslexp runs diff RUN_A RUN_B [--json]
    aslexp sweep status SWEEP_DIR [--json]
    aslexp sweep best SWEEP_DIR [--json]
    aslexp sweep report SWEEP_DIR [--out DIR]
    aslexp sweep dashboard SWEEP_DIR [--host 127.0.0.1] [--port 8080]

A damaged run file (a run.json of the wrong shape, an empty metrics.json, a bad
.hydra/overrides.yaml; :mod:`aslexp.runs.read`) is named in one warning line on stderr and the
tool goes on with the rest: ``runs list`` skips a run without a usable run.json, ``sweep status``
names the damaged files of trial folders, ``sweep best`` falls back to the overrides the study
recorded; ``runs diff`` of a damaged run prints that line and exits 2.

``--storage URL`` (or the environment variable ASLEXP_OPTUNA_STORAGE) reads a sweep whose study
lives in a database whose password sweep.json does not keep. Also runnable as
``python -m aslexp.runs.cli runs|sweep ...``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

log = logging.getLogger("aslexp")


DEFAULT_ROOT = Path("outputs")  # where the jobs write (hydra.run.dir / hydra.sweep.dir)


def runs_main(argv: list[str]) -> int:
    """Entry point of ``aslexp runs``; returns the process exit code."""
    parser = argparse.ArgumentParser(prog="aslexp runs", description="Find and compare runs.")
    sub = parser.add_subparsers(dest="command", required=True)

    p_list = sub.add_parser("list", help="table of runs under PATH (default: ./outputs)")
    p_list.add_argument("paths", nargs="*", type=Path)
    p_list.add_argument("--job", help="only runs of this job (recognize, imitate, tune_pd, ...)")
    p_list.add_argument("--status", help="only runs with this status (completed, failed, pruned, ...)")
    p_list.add_argument("--since", help="only runs started at or after this ISO date/time")
    p_list.add_argument("--where", action="append", default=[], metavar="KEY=VALUE",
                        help="only runs whose resolved config has KEY=VALUE (dotted keys; repeatable)")
    p_list.add_argument("--sort", choices=("time", "metric"), default="time",
                        help="time: newest first; metric: best main metric first")
    p_list.add_argument("--limit", type=int)
    p_list.add_argument("--format", choices=("table", "json"), default="table")

    p_diff = sub.add_parser("diff", help="config and metric difference of two run directories")
    p_diff.add_argument("run_a", type=Path)
    p_diff.add_argument("run_b", type=Path)
    p_diff.add_argument("--json", action="store_true")

    args = parser.parse_args(argv)
    _logging()
    if args.command == "list":
        from aslexp.runs.listing import format_json, format_table, list_runs

        roots = args.paths
        if not roots:
            # Never the whole current folder: it may hold anything (other projects' runs too).
            if not DEFAULT_ROOT.is_dir():
                print(f"aslexp runs list: no ./{DEFAULT_ROOT} here (where the jobs write); pass "
                      "the folders to search: aslexp runs list DIR ...", file=sys.stderr)
                return 2
            print(f"runs under ./{DEFAULT_ROOT} (pass folders to search elsewhere)", file=sys.stderr)
            roots = [DEFAULT_ROOT]
        for root in roots:
            if not root.exists():
                print(f"aslexp runs list: {root}: no such directory", file=sys.stderr)
                return 2
        for condition in args.where:
            if "=" not in condition:
                print(f"aslexp runs list: --where expects KEY=VALUE, got {condition!r}", file=sys.stderr)
                return 2
        runs = list_runs(roots, job=args.job, status=args.status, since=args.since,
                         where=args.where, sort=args.sort, limit=args.limit)
        if args.format == "json":
            print(format_json(runs))
        else:
            print(format_table(runs, base=Path.cwd()) if runs else "no runs found")
        return 0

    from aslexp.runs.diff import NotARunError, diff_runs, format_diff
    from aslexp.runs.read import RunFileError

    try:
        result = diff_runs(args.run_a, args.run_b)
    except (NotARunError, RunFileError) as err:  # one line: the folder or the damaged file, and why
        print(f"aslexp runs diff: {err}", file=sys.stderr)
        return 2
    print(json.dumps(result.as_dict(), indent=2, default=str) if args.json else format_diff(result))
    return 0


def sweep_main(argv: list[str]) -> int:
    """Entry point of ``aslexp sweep``; returns the process exit code."""
    parser = argparse.ArgumentParser(prog="aslexp sweep", description="Inspect Optuna sweeps.")
    sub = parser.add_subparsers(dest="command", required=True)
    commands = {
        "status": "trial counts by state and the budget",
        "best": "the best trial and the command that re-runs exactly it",
        "report": "plots (PNG) and trials.csv in SWEEP_DIR/report",
        "dashboard": "open the study in optuna-dashboard",
    }
    parsers = {}
    for name, text in commands.items():
        p = sub.add_parser(name, help=text)
        p.add_argument("sweep_dir", type=Path)
        p.add_argument("--storage", help="storage URL or journal path (default: from sweep.json)")
        p.add_argument("--study", help="study name (default: from sweep.json)")
        parsers[name] = p
    for name in ("status", "best"):
        parsers[name].add_argument("--json", action="store_true")
    parsers["report"].add_argument("--out", type=Path, help="folder for the plots")
    parsers["dashboard"].add_argument("--host", default="127.0.0.1")
    parsers["dashboard"].add_argument("--port", type=int, default=8080)

    args = parser.parse_args(argv)
    _logging()
    import optuna

    from aslexp.runs import sweep_report
    from aslexp.tuning.storage import StorageError
    from aslexp.tuning.study import StudyError, open_sweep

    optuna.logging.set_verbosity(optuna.logging.WARNING)
    if not args.sweep_dir.is_dir():
        print(f"aslexp sweep {args.command}: {args.sweep_dir}: no such directory", file=sys.stderr)
        return 2
    try:
        study, info = open_sweep(args.sweep_dir, storage=args.storage, study_name=args.study)
        if args.command == "status":
            sweep_report.check_trial_files(study)  # damaged run files: one warning line each
            summary = sweep_report.status_summary(study, info, args.sweep_dir)
            print(json.dumps(summary, indent=2, default=str) if args.json
                  else sweep_report.format_status(summary, args.sweep_dir))
        elif args.command == "best":
            best = sweep_report.best_summary(study, info)
            print(json.dumps(best, indent=2, default=str) if args.json
                  else sweep_report.format_best(best))
        elif args.command == "report":
            for path in sweep_report.write_report(study, args.sweep_dir, args.out):
                print(path)
        else:
            try:
                sweep_report.serve_dashboard(study, host=args.host, port=args.port)
            except KeyboardInterrupt:
                pass
    except (StudyError, StorageError) as err:
        print(f"aslexp sweep {args.command}: {err}", file=sys.stderr)
        return 2
    return 0


def _logging() -> None:
    logging.basicConfig(level=logging.INFO, format="%(message)s")


def main(argv: list[str] | None = None) -> int:
    """``python -m aslexp.runs.cli runs|sweep ...`` (the same as ``aslexp runs|sweep ...``)."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] not in ("runs", "sweep"):
        print("usage: python -m aslexp.runs.cli runs|sweep ...", file=sys.stderr)
        return 2
    return (runs_main if argv[0] == "runs" else sweep_main)(argv[1:])


if __name__ == "__main__":
    sys.exit(main())
