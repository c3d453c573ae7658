"""Run and time the recognition table (experiment=recognition_table) on the real clip set.

Two ways, the same table (settings from conf/: the classifier configs, the trainer each brings,
and conf/experiment/recognition_table.yaml's split and trainer values):

    python bench/recognition_table.py                                   # through the CLI (Hydra multirun)
    python bench/recognition_table.py --models logreg,svm,rf,hgb        # the CPU part
    python bench/recognition_table.py --direct --device cuda --jobs 4 --out $OUT/table \\
        --models mlp,lstm,gru,stgcn,slgcn,cnn3d --time-limit 540        # the deep part, no Hydra

``--direct`` needs neither Hydra nor PyYAML nor matplotlib (a bare GPU node): it builds the
datasets through the data layer, runs every cell (model x property x split, K repeated splits
each) with ``run_recognition`` and writes run folders that ``aslexp report`` reads. It prints
progress with rate and ETA, stops starting cells after ``--time-limit`` seconds (finished cells
are complete folders) and ``--resume`` skips cells already finished in ``--out``, so a table can
be filled by several calls. Model checkpoints are left out unless ``--keep-models``.
Built datasets are cached under outputs/cache (not in --out, which stays small).
``--summarize DIR`` prints the figures of a finished table folder (wall-clock, time per model)
and its report. Figures go to BENCHMARKS.md by hand.
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
from concurrent.futures import ProcessPoolExecutor, as_completed
from datetime import datetime
from multiprocessing import get_context
from pathlib import Path

from recognition_conf import CONF, classifier_config, read_yaml, trainer_config

ROOT = Path(__file__).resolve().parents[1]
ALL_MODELS = "logreg,svm,rf,hgb,mlp,lstm,gru,stgcn,slgcn,cnn3d"
ALL_PROPERTIES = "sign_type,major_location,minor_location,selected_fingers,flexion,movement"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default=ALL_MODELS)
    parser.add_argument("--properties", default=ALL_PROPERTIES)
    parser.add_argument("--splits", default="phoneme,gloss")
    parser.add_argument("--repeats", type=int, default=None, help="K repeated splits (default: the experiment's)")
    parser.add_argument("--seeds", type=int, default=1, help="model seeds per split")
    parser.add_argument("--out", type=Path, default=None)
    parser.add_argument("--jobs", type=int, default=1,
                        help="CLI: concurrent multiruns, one per split; --direct: concurrent cells (processes)")
    parser.add_argument("--summarize", type=Path, default=None, metavar="DIR",
                        help="only print the figures of a finished table folder (no training)")
    parser.add_argument("--direct", action="store_true", help="run without Hydra (see above)")
    parser.add_argument("--device", default="auto", help="--direct: trainer.device")
    parser.add_argument("--precision", default="32", help="--direct: trainer.precision")
    parser.add_argument("--threads", type=int, default=None, help="--direct: torch threads per job")
    parser.add_argument("--time-limit", type=float, default=None, help="--direct: start no cell after this many s")
    parser.add_argument("--resume", action="store_true", help="--direct: skip cells finished in --out")
    parser.add_argument("--keep-models", action="store_true", help="--direct: keep model checkpoints")
    parser.add_argument("--lexicon", default="asllex2")
    parser.add_argument("--subset", default="upper_body")
    parser.add_argument("--data-root", type=Path, default=None, help="--direct: the data root")
    parser.add_argument("overrides", nargs="*", help="CLI mode: extra Hydra overrides, e.g. trainer.max_epochs=20")
    args = parser.parse_args()
    if args.summarize:
        summarize(args.summarize)
        return 0
    out = args.out or ROOT / "outputs" / "bench" / f"table_{datetime.now():%Y%m%d_%H%M%S}"
    return run_direct(args, out) if args.direct else run_cli(args, out)


def run_cli(args: argparse.Namespace, out: Path) -> int:
    splits = args.splits.split(",")
    groups = [splits] if args.jobs <= 1 else [[s] for s in splits]
    threads = max(1, 2 // max(1, len(groups)))
    extra = [f"split.repeats={args.repeats}"] if args.repeats else []
    commands = []
    for group in groups:
        sweep_dir = out if len(groups) == 1 else out / "_".join(group)
        commands.append([
            sys.executable, "-m", "aslexp.cli", "recognize", "experiment=recognition_table",
            f"n_seeds={args.seeds}", f"hydra.sweep.dir={sweep_dir}", f"classifier={args.models}",
            f"property={args.properties}", f"split={','.join(group)}", f"trainer.num_threads={threads}",
            f"pose.subset={args.subset}", f"data={args.lexicon}", *extra, *args.overrides,
        ])  # fmt: skip
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


def table_settings() -> tuple[dict, dict]:
    """(split values, trainer values) that conf/experiment/recognition_table.yaml sets."""
    experiment = read_yaml(CONF / "experiment" / "recognition_table.yaml")
    return dict(experiment.get("split") or {}), dict(experiment.get("trainer") or {})


def run_direct(args: argparse.Namespace, out: Path) -> int:
    split_values, trainer_values = table_settings()
    if args.repeats:
        split_values["repeats"] = args.repeats
    cells = [(model, prop, split) for split in args.splits.split(",") for prop in args.properties.split(",")
             for model in args.models.split(",")]  # fmt: skip
    if args.resume:
        done = [c for c in cells if _finished(out / _cell_name(*c))]
        cells = [c for c in cells if c not in done]
        print(f"resume: {len(done)} cell(s) already finished in {out}")
    threads = args.threads or max(1, (os.cpu_count() or 1) // max(1, args.jobs))
    common = {"out": str(out), "split_values": split_values, "trainer_values": trainer_values,
              "device": args.device, "precision": args.precision, "threads": threads, "seeds": args.seeds,
              "lexicon": args.lexicon, "subset": args.subset, "keep_models": args.keep_models,
              "data_root": str(args.data_root) if args.data_root else None}  # fmt: skip
    print(f"{len(cells)} cell(s) -> {out}; {args.jobs} job(s) x {threads} thread(s); device {args.device} "
          f"{args.precision}; split {split_values}; trainer {trainer_values}", flush=True)
    started = time.perf_counter()
    finished, skipped_late = 0, 0
    deadline = started + args.time_limit if args.time_limit else None
    with ProcessPoolExecutor(max_workers=max(1, args.jobs), mp_context=get_context("spawn")) as pool:
        futures = {pool.submit(run_cell, cell, common, deadline): cell for cell in cells}
        for future in as_completed(futures):
            cell = futures[future]
            status, seconds = future.result()
            finished += status == "completed"
            skipped_late += status == "not started"
            elapsed = time.perf_counter() - started
            rate = finished / elapsed if elapsed else 0.0
            remaining = len(cells) - finished - skipped_late
            eta = remaining / rate if rate else float("nan")
            print(f"[{finished + skipped_late}/{len(cells)}] {'/'.join(cell)}: {status} in {seconds:.0f}s; "
                  f"{rate * 60:.1f} cells/min, ETA {eta / 60:.1f} min", flush=True)  # fmt: skip
    print(f"{finished} cell(s) completed, {skipped_late} not started (time limit), "
          f"{(time.perf_counter() - started) / 60:.1f} min wall-clock", flush=True)
    return 0


def _cell_name(model: str, prop: str, split: str) -> str:
    return f"{model}_{prop}_{split}"


def _finished(run_dir: Path) -> bool:
    try:
        return json.loads((run_dir / "run.json").read_text())["status"] == "completed"
    except (OSError, ValueError, KeyError):
        return False


def run_cell(cell: tuple[str, str, str], common: dict, deadline: float | None) -> tuple[str, float]:
    """One table cell in a worker process: the dataset, K splits, the run folder."""
    import logging

    import torch

    from aslexp.data.wlasl_lex import WlaslLexParams, build_or_load
    from aslexp.recognition.experiment import run_recognition
    from aslexp.runs.record import start_run

    if deadline is not None and time.perf_counter() > deadline:
        return "not started", 0.0
    started = time.perf_counter()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(common["threads"])
    name, prop, split = cell
    model, params, preset = classifier_config(name)
    from aslexp.recognition.device import resolve_device

    on_cpu = resolve_device(common["device"]).type == "cpu"  # deterministic kernels cost time on a GPU
    trainer = {**trainer_config(preset), **common["trainer_values"], "device": common["device"],
               "precision": common["precision"], "num_threads": common["threads"], "deterministic": on_cpu}  # fmt: skip
    split_options = {**read_yaml(CONF / "split" / f"{split}.yaml"), **common["split_values"]}
    data_params = WlaslLexParams(lexicon=common["lexicon"], property=prop, subset=common["subset"],
                                 channels=("x", "y", "visibility"), split=split, length=150, padding="loop",
                                 seed=int(split_options["seed"]), rare_classes=split_options["rare_classes"])  # fmt: skip
    dataset, dataset_dir = build_or_load(ROOT / "outputs" / "cache", data_params, root=common["data_root"])
    run_dir = Path(common["out"]) / _cell_name(*cell)
    seeds = list(range(common["seeds"]))
    with start_run(run_dir, "recognize", seed=0, overwrite=True, extra={"bench": "recognition_table --direct"}) as run:
        result = run_recognition(dataset, {"name": model, "params": params}, trainer, seeds, run_dir, split=split_options)
        result["context"] = {"property": prop, "split": split, "pose": "mediapipe_pose", "lexicon": common["lexicon"],
                             "classifier": model, "seeds": seeds, "num_clips": int(len(dataset.y)),
                             "num_classes": int(dataset.num_classes), "skipped": dataset.skipped,
                             "dataset_dir": str(dataset_dir), "config": name, "trainer_preset": preset}  # fmt: skip
        run.info["device"] = result["device"]
        run.save_metrics(result)
        run.set_main_metric(result["objective"]["name"], float(result["objective"]["value"]))
    if not common["keep_models"]:
        for checkpoint in run_dir.glob("model.*"):
            checkpoint.unlink()
    return "completed", time.perf_counter() - started


def summarize(out: Path) -> None:
    """Figures from the run folders alone: wall-clock span, per-model run times, the table."""
    per_model: dict[str, list[float]] = defaultdict(list)
    statuses: dict[str, int] = defaultdict(int)
    starts, ends, units, devices = [], [], set(), set()
    for run_file in out.rglob("run.json"):
        info = json.loads(run_file.read_text())
        statuses[info["status"]] += 1
        starts.append(datetime.fromisoformat(info["started"]))
        if info.get("finished"):
            ends.append(datetime.fromisoformat(info["finished"]))
        devices.add((info.get("device") or {}).get("name", "?"))
        metrics_file = run_file.parent / "metrics.json"
        if metrics_file.exists():
            metrics = json.loads(metrics_file.read_text())
            per_model[metrics["context"]["classifier"]].append(float(metrics["time_s"]))
            units.add(f"{len(metrics.get('splits', [0]))} split(s) x {len(metrics['context']['seeds'])} seed(s)")
    runs = sum(statuses.values())
    span = (max(ends) - min(starts)).total_seconds() / 60 if ends else float("nan")
    print(f"table {out}: {runs} runs ({dict(statuses)}), {sorted(units)} per run, device(s) {sorted(devices)}; "
          f"first start to last end {span:.1f} min wall-clock; "
          f"{sum(sum(t) for t in per_model.values()) / 60:.1f} min of run time in all")  # fmt: skip
    print("| model | runs | median s/run | total min |")
    print("|---|---|---|---|")
    for model, times in sorted(per_model.items()):
        print(f"| {model} | {len(times)} | {statistics.median(times):.1f} | {sum(times) / 60:.1f} |")
    subprocess.run([sys.executable, "-m", "aslexp.cli", "report", str(out)], cwd=ROOT, check=True)


if __name__ == "__main__":
    sys.exit(main())
