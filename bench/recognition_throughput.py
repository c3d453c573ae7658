"""Training throughput of the recognition models on the real clip set, on the CPU and on a device.

Builds the sign-type set of the shared MediaPipe Pose clips through the data layer (ASL-LEX 2.0,
upper body 23 nodes or --subset, x/y/visibility, T = 150), then trains every model with its own
configuration (conf/classifier/<model>.yaml and the trainer it brings: SL-GCN trains with the
authors' batch 96 and 100-frame crops) and prints training clips/s: on the CPU (a subset of
--cpu-clips clips, --cpu-epochs epochs) and, with --device cuda, on the GPU (all clips, --epochs
epochs), the first epoch left out as warm-up on both, and their ratio, in the same process. Figures
only: nothing is asserted. Each model's settings come from Hydra's compose API over conf/ (as
`aslexp recognize classifier=<model>` composes them); a GPU node needs hydra-core and omegaconf.

    python bench/recognition_throughput.py                                  # CPU only
    python bench/recognition_throughput.py --device cuda --json $OUT/throughput.json
    python bench/recognition_throughput.py --device cuda --precision bf16 --models slgcn,stgcn
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import statistics
import time
from pathlib import Path

import numpy as np
import torch

from aslexp.data.wlasl_lex import WlaslLexParams, build_wlasl_lex
from aslexp.recognition.device import device_info, resolve_device
from aslexp.recognition.models import build_classifier
from aslexp.recognition.train import ArraySplit, fit_final

DEFAULT_MODELS = "mlp,lstm,gru,stgcn,slgcn,cnn3d"


def model_config(name: str) -> tuple[str, dict, dict]:
    """(model, params, trainer) of `aslexp recognize classifier=<name>`, composed by Hydra from conf/."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    conf = Path(__file__).resolve().parents[1] / "conf"
    with initialize_config_dir(config_dir=str(conf), version_base="1.3"):
        cfg = OmegaConf.to_container(compose("recognize", [f"classifier={name}"]), resolve=True)
    return cfg["classifier"]["name"], cfg["classifier"]["params"], cfg["trainer"]


def measure(name: str, data, clips: np.ndarray, device: str, precision: str, epochs: int, threads: int,
            skip_first: bool) -> dict:  # fmt: skip
    model_name, params, trainer = model_config(name)
    trainer = {**trainer, "device": device, "precision": precision, "num_threads": threads,
               "max_epochs": epochs, "deterministic": False}  # fmt: skip
    train = ArraySplit(data.X[clips], data.mask[clips], data.y[clips])
    probe = ArraySplit(data.X[:8], data.mask[:8], data.y[:8])
    torch.manual_seed(0)
    model = build_classifier(model_name, params, data.X.shape[1], data.X.shape[2], data.X.shape[3], data.num_classes,
                             data.layout)  # fmt: skip
    if model.kind != "torch":
        return {}
    if device.startswith("cuda"):
        torch.cuda.synchronize()
    start = time.perf_counter()
    result = fit_final(model, train, probe, trainer, epochs=epochs)
    if device.startswith("cuda"):
        torch.cuda.synchronize()
    history = result.fit.history[1:] if skip_first and len(result.fit.history) > 1 else result.fit.history
    return {"clips_per_s": statistics.median(row["clips_per_s"] for row in history),
            "seconds_per_epoch": statistics.median(row["epoch_time"] for row in history), "clips": len(clips),
            "epochs": epochs, "batch_size": trainer["batch_size"], "crop_window": trainer["crop_window"],
            "parameters": model.num_parameters(), "wall_s": time.perf_counter() - start}  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default=DEFAULT_MODELS, help="conf/classifier names, comma-separated")
    parser.add_argument("--device", default="cpu", help="cpu (CPU only) or cuda / cuda:<i> (CPU and device)")
    parser.add_argument("--precision", default="32", help="32 | bf16 | fp16 on the device (CPU runs float32)")
    parser.add_argument("--epochs", type=int, default=4, help="device epochs (the first is warm-up)")
    parser.add_argument("--cpu-epochs", type=int, default=2, help="CPU epochs (the first is warm-up when > 1)")
    parser.add_argument("--cpu-clips", type=int, default=64, help="clips of the CPU measurement (slgcn is slow)")
    parser.add_argument("--threads", type=int, default=min(16, os.cpu_count() or 1), help="torch CPU threads")
    parser.add_argument("--subset", default="upper_body", help="keypoint subset: upper_body (23) | slgcn27 (13 on Pose)")
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--json", type=Path, default=None, help="also write the figures here")
    parser.add_argument("--data-root", type=Path,
                        default=Path(os.environ.get("ASLEXP_DATA_ROOT", Path(__file__).resolve().parents[2] / "shared" / "data")))  # fmt: skip
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)

    params = WlaslLexParams(lexicon="asllex2", property="sign_type", subset=args.subset,
                            channels=("x", "y", "visibility"), length=args.frames)  # fmt: skip
    data = build_wlasl_lex(None, params, root=args.data_root)
    gpu = args.device != "cpu"
    device = resolve_device(args.device)
    info = device_info(device, args.precision) if gpu else device_info(device)
    print(f"data: {len(data.y)} clips, X {tuple(data.X.shape)}, layout {data.layout.name}; torch {torch.__version__}, "
          f"{args.threads} CPU thread(s), load average {' '.join(f'{v:.1f}' for v in os.getloadavg())} on "
          f"{os.cpu_count()} CPUs; device {info['name']}{' ' + args.precision if gpu else ''}", flush=True)  # fmt: skip
    rng = np.random.default_rng(0)
    cpu_clips = np.sort(rng.choice(len(data.y), size=min(args.cpu_clips, len(data.y)), replace=False))
    every_clip = np.arange(len(data.y))
    rows = []
    print(f"{'model':<8} {'params':>10} {'batch':>5} {'crop':>4} {'CPU clips/s':>11} {'device clips/s':>14} {'ratio':>7}")
    for name in [m for m in args.models.split(",") if m]:
        cpu = measure(name, data, cpu_clips, "cpu", "32", args.cpu_epochs, args.threads, skip_first=True)
        if not cpu:
            print(f"{name:<8} (not a torch model: skipped)")
            continue
        on_device = measure(name, data, every_clip, args.device, args.precision, args.epochs, args.threads,
                            skip_first=True) if gpu else {}  # fmt: skip
        ratio = on_device["clips_per_s"] / cpu["clips_per_s"] if on_device else float("nan")
        print(f"{name:<8} {cpu['parameters']:>10,d} {cpu['batch_size']:>5} {cpu['crop_window']:>4} "
              f"{cpu['clips_per_s']:>11.1f} {on_device.get('clips_per_s', float('nan')):>14.1f} {ratio:>7.1f}", flush=True)  # fmt: skip
        rows.append({"model": name, "cpu": cpu, "device": on_device, "ratio": ratio})
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"device": info, "threads": args.threads, "subset": args.subset,
                                         "frames": args.frames, "rows": rows}, indent=1))  # fmt: skip
        print(f"figures written to {args.json}")


if __name__ == "__main__":
    main()
