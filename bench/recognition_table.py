"""Time the full recognition table on the real 291-clip keypoint set, through the real CLI.

    python bench/recognition_table.py                      # 7 models x 6 properties x 2 splits, 3 seeds
    python bench/recognition_table.py --models logreg,mlp --properties sign_type --seeds 1

Runs `aslexp recognize experiment=recognition_table` (a Hydra multirun, one process, jobs in
sequence), then prints the wall-clock time of the whole table, the median time per run of each
model, and the table itself (`aslexp report`). Figures go to BENCHMARKS.md by hand.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from collections import defaultdict
from datetime import datetime
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ALL_MODELS = "logreg,svm,mlp,lstm,gru,stgcn,cnn3d"
ALL_PROPERTIES = "sign_type,major_location,minor_location,selected_fingers,flexion,movement"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default=ALL_MODELS)
    parser.add_argument("--properties", default=ALL_PROPERTIES)
    parser.add_argument("--splits", default="phoneme,gloss")
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--jobs", type=int, default=1,
                        help="concurrent multiruns, one per split (each with 2/jobs torch threads)")
    parser.add_argument("--summarize", type=Path, default=None, metavar="DIR",
                        help="only print the figures of a finished table folder (no training)")
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides, e.g. trainer.max_epochs=20")
    args = parser.parse_args()
    if args.summarize:
        summarize(args.summarize)
        return 0
    out = args.out or ROOT / "outputs" / "bench" / f"table_{datetime.now():%Y%m%d_%H%M%S}"
    splits = args.splits.split(",")
    groups = [splits] if args.jobs <= 1 else [[s] for s in splits]
    threads = max(1, 2 // max(1, len(groups)))
    commands = []
    for group in groups:
        sweep_dir = out if len(groups) == 1 else out / "_".join(group)
        commands.append([
            sys.executable, "-m", "aslexp.cli", "recognize", "experiment=recognition_table",
            f"n_seeds={args.seeds}", f"hydra.sweep.dir={sweep_dir}",
            f"classifier={args.models}", f"property={args.properties}",
            f"split={','.join(group)}", f"trainer.num_threads={threads}",
            *args.overrides,
        ])
    started = time.perf_counter()
    procs = []
    for command in commands:
        print("$", " ".join(command[2:]), flush=True)
        procs.append(subprocess.Popen(command, cwd=ROOT, env=dict(os.environ, MPLBACKEND="Agg")))
    codes = [p.wait() for p in procs]
    total = time.perf_counter() - started
    if any(codes):
        print(f"multirun exit codes: {codes}", file=sys.stderr)
        return 1

    print(f"\n{len(groups)} concurrent multirun(s) x {threads} torch thread(s): "
          f"{total / 60:.1f} min wall-clock on {os.cpu_count()} cores")
    summarize(out)
    return 0


def summarize(out: Path) -> None:
    """Figures from the run folders alone: wall-clock span, per-model run times, the table."""
    per_model: dict[str, list[float]] = defaultdict(list)
    statuses: dict[str, int] = defaultdict(int)
    starts, ends, seeds = [], [], set()
    for run_file in out.rglob("run.json"):
        info = json.loads(run_file.read_text())
        statuses[info["status"]] += 1
        starts.append(datetime.fromisoformat(info["started"]))
        if info.get("finished"):
            ends.append(datetime.fromisoformat(info["finished"]))
        metrics_file = run_file.parent / "metrics.json"
        if metrics_file.exists():
            metrics = json.loads(metrics_file.read_text())
            per_model[metrics["context"]["classifier"]].append(float(metrics["time_s"]))
            seeds.add(len(metrics["context"]["seeds"]))
    runs = sum(statuses.values())
    span = (max(ends) - min(starts)).total_seconds() / 60 if ends else float("nan")
    print(f"table {out}: {runs} runs ({dict(statuses)}), seeds per run {sorted(seeds)}; "
          f"first start to last end {span:.1f} min wall-clock; "
          f"{sum(sum(t) for t in per_model.values()) / 60:.1f} min of run time in all")
    print("| model | runs | median s/run (all seeds) | total min |")
    print("|---|---|---|---|")
    for model, times in sorted(per_model.items()):
        print(f"| {model} | {len(times)} | {statistics.median(times):.1f} | {sum(times) / 60:.1f} |")
    subprocess.run([sys.executable, "-m", "aslexp.cli", "report", str(out)], cwd=ROOT, check=True)


if __name__ == "__main__":
    sys.exit(main())
