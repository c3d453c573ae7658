"""Run and time the recognition table (experiment=recognition_table) on the real clip set.

Two ways, the same table (settings from conf/: the classifier configs, the trainer each brings,
and the experiment overlay's groups and values, conf/experiment/recognition_table.yaml by default):

    python bench/recognition_table.py                                   # through the CLI (Hydra multirun)
    python bench/recognition_table.py --models logreg,svm,rf,hgb        # the CPU part
    python bench/recognition_table.py --direct --device cuda --jobs 4 --out $OUT/table \\
        --models mlp,lstm,gru,stgcn,slgcn,cnn3d --time-limit 540        # the deep part, no Hydra
    python bench/recognition_table.py --direct --experiment thesis_ch4 --device cuda --out $OUT/ch4

``--direct`` runs the cells in a process pool instead of a Hydra multirun (no launcher, no
plots; a GPU node needs only hydra-core and omegaconf besides the libraries): each cell (model x
property x split, K repeated splits each) is composed by Hydra's compose API from conf/ exactly as
``aslexp recognize experiment=<--experiment> classifier=M property=P split=S`` composes it, and
runs through the job's own ``recognize`` into a run folder that ``aslexp report`` reads. It prints
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


def compose_cell(experiment: str, overrides: list[str], hydra: bool = False):
    """The job's config for one cell: Hydra's compose API over conf/, as the command line does."""
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(ROOT / "conf"), version_base="1.3"):
        return compose("recognize", [f"experiment={experiment}", *overrides], return_hydra_config=hydra)


def experiment_lists(experiment: str) -> dict[str, list[str]]:
    """The overlay's multirun lists (hydra.sweeper.params): classifier, property, split."""
    cfg = compose_cell(experiment, [], hydra=True)
    params = cfg.hydra.sweeper.get("params") or {}
    return {key: [v.strip() for v in str(params.get(key, cfg[key].name)).split(",")]
            for key in ("classifier", "property", "split")}


def run_direct(args: argparse.Namespace, out: Path) -> int:
    lists = experiment_lists(args.experiment)
    models = args.models.split(",") if args.models else lists["classifier"]
    properties = args.properties.split(",") if args.properties else lists["property"]
    splits = args.splits.split(",") if args.splits else lists["split"]
    cells = [(model, prop, split) for split in splits for prop in properties for model in models]
    finished_dirs = ([out] if args.resume else []) + list(args.skip_done)
    if finished_dirs:
        done = [c for c in cells if any(_finished(d / _cell_name(*c)) for d in finished_dirs)]
        cells = [c for c in cells if c not in done]
        print(f"{len(done)} cell(s) already finished in {', '.join(map(str, finished_dirs))}: skipped")
    threads = args.threads or max(1, (os.cpu_count() or 1) // max(1, args.jobs))
    overrides = [f"trainer.device={args.device}", f"trainer.precision={args.precision}",
                 f"trainer.num_threads={threads}", "logger=none"]
    overrides += [f"split.repeats={args.repeats}"] if args.repeats else []
    overrides += [f"n_seeds={args.seeds}"] if args.seeds else []
    overrides += [f"data={args.lexicon}"] if args.lexicon else []
    overrides += [f"pose.subset={args.subset}"] if args.subset else []
    overrides += [f"data.root={args.data_root.resolve()}"] if args.data_root else []
    overrides += [f"trainer.{item}" for item in args.trainer_set] + list(args.overrides)
    import torch

    if args.device != "cpu" and torch.cuda.is_available():  # deterministic kernels cost time on a GPU
        overrides.append("trainer.deterministic=false")
    common = {"out": str(out), "experiment": args.experiment, "overrides": overrides, "threads": threads,
              "keep_models": args.keep_models}  # fmt: skip
    print(f"experiment={args.experiment}: {len(cells)} cell(s) -> {out}; {args.jobs} job(s) x {threads} thread(s); "
          f"overrides {overrides}", flush=True)
    started = time.perf_counter()
    from aslexp.data.wlasl_lex import build_or_load
    from aslexp.jobs.recognize import dataset_params

    for model, prop, split in {(c[1], c[2]): c for c in cells}.values():  # each dataset built once, before the workers
        cfg = compose_cell(args.experiment, [f"classifier={model}", f"property={prop}", f"split={split}", *overrides])
        build_or_load(Path(cfg.cache_dir), dataset_params(cfg), root=cfg.data.root)
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


def run_cell(cell: tuple[str, str, str], common: dict, deadline: float | None) -> tuple[str, float]:
    """One table cell in a worker process: the composed job config, run by the job's own function."""
    import logging

    import torch

    from aslexp.jobs.recognize import recognize
    from aslexp.runs.record import start_run

    if deadline is not None and time.time() > deadline:
        return "not started", 0.0
    started = time.perf_counter()
    logging.basicConfig(level=logging.WARNING)
    torch.set_num_threads(common["threads"])
    model, prop, split = cell
    cfg = compose_cell(common["experiment"], [f"classifier={model}", f"property={prop}", f"split={split}",
                                              *common["overrides"]])
    run_dir = Path(common["out"]) / _cell_name(*cell)
    extra = {"bench": "recognition_table --direct", "overrides": [f"experiment={common['experiment']}",
             f"classifier={model}", f"property={prop}", f"split={split}", *common["overrides"]]}  # fmt: skip
    with start_run(run_dir, "recognize", seed=int(cfg.seed), overwrite=True, extra=extra) as run:
        recognize(cfg, run)
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
