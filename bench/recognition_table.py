"""Run and time the recognition table (experiment=recognition_table) on the real clip set.

Two ways, the same table (settings from conf/: the classifier configs, the trainer each brings,
and the experiment overlay's groups and values, conf/experiment/recognition_table.yaml by default):

    python bench/recognition_table.py                                   # through the CLI (Hydra multirun)
    python bench/recognition_table.py --models logreg,svm,rf,hgb        # the CPU part
    python bench/recognition_table.py --direct --device cuda --jobs 4 --out $OUT/table \\
        --models mlp,lstm,gru,stgcn,slgcn,cnn3d --time-limit 540        # the deep part, no Hydra
    python bench/recognition_table.py --direct --experiment thesis_ch4 --device cuda --out $OUT/ch4

``--direct`` needs neither Hydra nor PyYAML nor matplotlib (a bare GPU node): it composes the
overlay (``--experiment``: its data/split/trainer choices and values, its multirun lists) the way
Hydra does for these files, builds the datasets through the data layer, runs every cell (model x
property x split, K repeated splits each) with ``run_recognition`` and writes run folders that
``aslexp report`` reads. It prints
progress with rate and ETA, stops starting cells after ``--time-limit`` seconds (finished cells
are complete folders) and ``--resume`` / ``--skip-done DIR`` skip cells already finished in
``--out`` / DIR, so a table can be filled by several calls (a GPU call whose $OUT starts empty
carries the earlier calls' results in and names them with --skip-done). Model checkpoints are left out unless ``--keep-models``.
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

from recognition_conf import CONF, _scalar, experiment_plan, read_yaml, resolve_classifier, trainer_for

ROOT = Path(__file__).resolve().parents[1]
ALL_MODELS = "logreg,svm,rf,hgb,mlp,lstm,gru,stgcn,slgcn,cnn3d"
ALL_PROPERTIES = "sign_type,major_location,minor_location,selected_fingers,flexion,movement"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--experiment", default="recognition_table",
                        help="--direct: the conf/experiment overlay to run (recognition_table, thesis_ch4, thesis_ch3, ...)")
    parser.add_argument("--models", default=None, help="default: the experiment's (CLI mode: all)")
    parser.add_argument("--properties", default=None, help="default: the experiment's (CLI mode: all six)")
    parser.add_argument("--splits", default=None, help="default: the experiment's (CLI mode: phoneme,gloss)")
    parser.add_argument("--repeats", type=int, default=None, help="K repeated splits (default: the experiment's)")
    parser.add_argument("--seeds", type=int, default=None, help="model seeds per split (default: the experiment's)")
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
    parser.add_argument("--skip-done", type=Path, action="append", default=[], metavar="DIR",
                        help="--direct: also skip cells finished in DIR (e.g. an earlier call's results)")
    parser.add_argument("--keep-models", action="store_true", help="--direct: keep model checkpoints")
    parser.add_argument("--trainer-set", action="append", default=[], metavar="KEY=VALUE",
                        help="--direct: a trainer value over everything else, e.g. max_epochs=2 (smoke runs)")
    parser.add_argument("--lexicon", default=None, help="default: the experiment's (asllex2 for the table)")
    parser.add_argument("--subset", default=None, help="keypoint subset (default: the experiment's)")
    parser.add_argument("--data-root", type=Path, default=None, help="--direct: the data root")
    parser.add_argument("overrides", nargs="*", help="CLI mode: extra Hydra overrides, e.g. trainer.max_epochs=20")
    args = parser.parse_args()
    if args.summarize:
        summarize(args.summarize)
        return 0
    out = args.out or ROOT / "outputs" / "bench" / f"table_{datetime.now():%Y%m%d_%H%M%S}"
    return run_direct(args, out) if args.direct else run_cli(args, out)


def run_cli(args: argparse.Namespace, out: Path) -> int:
    args.models, args.properties = args.models or ALL_MODELS, args.properties or ALL_PROPERTIES
    args.seeds, args.lexicon, args.subset = args.seeds or 1, args.lexicon or "asllex2", args.subset or "upper_body"
    splits = (args.splits or "phoneme,gloss").split(",")
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


def run_direct(args: argparse.Namespace, out: Path) -> int:
    plan = experiment_plan(args.experiment)
    if args.repeats:
        plan["split_values"]["repeats"] = args.repeats
    if args.seeds:
        plan["n_seeds"] = args.seeds
    if args.lexicon:
        plan["data"]["lexicon"] = args.lexicon
    if args.subset:
        plan["pose"]["subset"] = args.subset
    plan["trainer_overrides"] = {key: _scalar(value) for key, value in (item.split("=", 1) for item in args.trainer_set)}
    models = args.models.split(",") if args.models else plan["classifiers"]
    properties = args.properties.split(",") if args.properties else plan["properties"]
    splits = args.splits.split(",") if args.splits else plan["splits"]
    cells = [(model, prop, split) for split in splits for prop in properties for model in models]
    finished_dirs = ([out] if args.resume else []) + list(args.skip_done)
    if finished_dirs:
        done = [c for c in cells if any(_finished(d / _cell_name(*c)) for d in finished_dirs)]
        cells = [c for c in cells if c not in done]
        print(f"{len(done)} cell(s) already finished in {', '.join(map(str, finished_dirs))}: skipped")
    threads = args.threads or max(1, (os.cpu_count() or 1) // max(1, args.jobs))
    common = {"out": str(out), "plan": plan, "device": args.device, "precision": args.precision, "threads": threads,
              "keep_models": args.keep_models, "data_root": str(args.data_root) if args.data_root else None}  # fmt: skip
    print(f"experiment={args.experiment}: {len(cells)} cell(s) -> {out}; {args.jobs} job(s) x {threads} thread(s); "
          f"device {args.device} {args.precision}; {plan['data']['lexicon']}, {plan['pose']['subset']}, "
          f"T={plan['data']['num_frames']} {plan['data']['padding']}; split {plan['split_values']}; "
          f"{plan['n_seeds']} seed(s); trainer {plan['trainer_preset'] or 'per classifier'} + {plan['trainer_values']}",
          flush=True)  # fmt: skip
    started = time.perf_counter()
    from aslexp.data.wlasl_lex import build_or_load

    for prop, split in dict.fromkeys((prop, split) for _, prop, split in cells):  # built once, before the workers
        build_or_load(ROOT / "outputs" / "cache", dataset_params(plan, prop, split)[0], root=common["data_root"])
    finished, skipped_late, failed = 0, 0, 0
    deadline = time.time() + args.time_limit if args.time_limit else None
    with ProcessPoolExecutor(max_workers=max(1, args.jobs), mp_context=get_context("spawn")) as pool:
        futures = {pool.submit(run_cell, cell, common, deadline): cell for cell in cells}
        for future in as_completed(futures):
            cell = futures[future]
            try:
                status, seconds = future.result()
            except Exception as error:  # one failing cell does not stop the table
                status, seconds = f"failed ({type(error).__name__}: {error})", 0.0
                failed += 1
            finished += status == "completed"
            skipped_late += status == "not started"
            elapsed = time.perf_counter() - started
            rate = finished / elapsed if elapsed else 0.0
            remaining = len(cells) - finished - skipped_late - failed
            eta = remaining / rate if rate else float("nan")
            print(f"[{finished + skipped_late + failed}/{len(cells)}] {'/'.join(cell)}: {status} in {seconds:.0f}s; "
                  f"{rate * 60:.1f} cells/min, ETA {eta / 60:.1f} min", flush=True)  # fmt: skip
    print(f"{finished} cell(s) completed, {failed} failed, {skipped_late} not started (time limit), "
          f"{(time.perf_counter() - started) / 60:.1f} min wall-clock", flush=True)
    return 1 if failed else 0


def _cell_name(model: str, prop: str, split: str) -> str:
    return f"{model}_{prop}_{split}"


def _finished(run_dir: Path) -> bool:
    try:
        return json.loads((run_dir / "run.json").read_text())["status"] == "completed"
    except (OSError, ValueError, KeyError):
        return False


def dataset_params(plan: dict, prop: str, split: str):
    """The WLASL-Lex build parameters of one (property, split) under the experiment's plan."""
    from aslexp.data.wlasl_lex import WlaslLexParams

    split_options = {**read_yaml(CONF / "split" / f"{split}.yaml"), **plan["split_values"]}
    data, pose = plan["data"], plan["pose"]
    params = WlaslLexParams(
        lexicon=data["lexicon"], property=prop, source=pose["source"], source_path=pose.get("path"),
        source_options=pose.get("options") or {}, subset=pose["subset"], channels=pose.get("channels"), split=split,
        length=int(data["num_frames"]), padding=data["padding"], seed=int(split_options["seed"]),
        rare_classes=split_options["rare_classes"],
        movement_none_as_missing=bool(data.get("movement_none_as_missing", False)),
    )
    return params, split_options


def run_cell(cell: tuple[str, str, str], common: dict, deadline: float | None) -> tuple[str, float]:
    """One table cell in a worker process: the dataset, the experiment's splits, the run folder."""
    import logging

    import torch

    from aslexp.data.wlasl_lex import build_or_load
    from aslexp.recognition.device import resolve_device
    from aslexp.recognition.experiment import run_recognition
    from aslexp.runs.record import start_run

    if deadline is not None and time.time() > deadline:
        return "not started", 0.0
    started = time.perf_counter()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(common["threads"])
    plan = common["plan"]
    name, prop, split = cell
    model, params, preset, batch_size = resolve_classifier(name, prop)
    on_cpu = resolve_device(common["device"]).type == "cpu"  # deterministic kernels cost time on a GPU
    trainer = {**trainer_for(plan, preset, batch_size), "device": common["device"], "precision": common["precision"],
               "num_threads": common["threads"], "deterministic": on_cpu, **plan["trainer_overrides"]}  # fmt: skip
    data, pose = plan["data"], plan["pose"]
    data_params, split_options = dataset_params(plan, prop, split)
    dataset, dataset_dir = build_or_load(ROOT / "outputs" / "cache", data_params, root=common["data_root"])
    run_dir = Path(common["out"]) / _cell_name(*cell)
    seeds = list(range(plan["n_seeds"]))
    with start_run(run_dir, "recognize", seed=0, overwrite=True, extra={"bench": "recognition_table --direct"}) as run:
        result = run_recognition(dataset, {"name": model, "params": params}, trainer, seeds, run_dir, split=split_options)
        result["context"] = {"property": prop, "split": split, "pose": pose["name"], "lexicon": data["lexicon"],
                             "classifier": model, "seeds": seeds, "num_clips": int(len(dataset.y)),
                             "num_classes": int(dataset.num_classes), "skipped": dataset.skipped,
                             "dataset_dir": str(dataset_dir), "config": name}  # fmt: skip
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
