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
    parser.add_argument("overrides", nargs="*", help="extra Hydra overrides, e.g. trainer.max_epochs=20")
    args = parser.parse_args()
    out = args.out or ROOT / "outputs" / "bench" / f"table_{datetime.now():%Y%m%d_%H%M%S}"
    command = [
        sys.executable, "-m", "aslexp.cli", "recognize", "experiment=recognition_table",
        f"n_seeds={args.seeds}", f"hydra.sweep.dir={out}",
        f"hydra.sweeper.params.classifier={args.models}",
        f"hydra.sweeper.params.property={args.properties}",
        f"hydra.sweeper.params.split={args.splits}", *args.overrides,
    ]
    print("$", " ".join(command[2:]), flush=True)
    started = time.perf_counter()
    subprocess.run(command, cwd=ROOT, check=True, env=dict(os.environ, MPLBACKEND="Agg"))
    total = time.perf_counter() - started

    per_model: dict[str, list[float]] = defaultdict(list)
    statuses: dict[str, int] = defaultdict(int)
    for run_file in out.rglob("run.json"):
        info = json.loads(run_file.read_text())
        statuses[info["status"]] += 1
        metrics_file = run_file.parent / "metrics.json"
        if metrics_file.exists():
            metrics = json.loads(metrics_file.read_text())
            per_model[metrics["context"]["classifier"]].append(float(metrics["time_s"]))
    runs = sum(statuses.values())
    print(f"\nfull table: {runs} runs ({dict(statuses)}), {args.seeds} seed(s) each, "
          f"{total / 60:.1f} min wall-clock on {os.cpu_count()} cores")
    print("| model | runs | median s/run (all seeds) | total min |")
    print("|---|---|---|---|")
    for model, times in sorted(per_model.items()):
        print(f"| {model} | {len(times)} | {statistics.median(times):.1f} | {sum(times) / 60:.1f} |")
    subprocess.run([sys.executable, "-m", "aslexp.cli", "report", str(out)], cwd=ROOT, check=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
