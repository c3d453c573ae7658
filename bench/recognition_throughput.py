"""Training throughput of the recognition models on the real 291-clip set shape.

Loads every clip of ../shared/data/keypoints/wlasl-mediapipe-pose (33 MediaPipe pose landmarks,
x/y/z), loops or truncates it to T frames (default 150), labels it with its WLASL gloss, and
trains each model for a few epochs with the default hyperparameters. Prints clips/s (median
over the epochs) and seconds per epoch. Figures only: nothing is asserted.

    python bench/recognition_throughput.py [--models stgcn,gru,mlp] [--epochs 3] [--threads 2]
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

from aslexp.data.dataset import KeypointLayout
from aslexp.recognition.models import DEFAULT_PARAMS, build_classifier
from aslexp.recognition.train import ArraySplit, fit_final

# MediaPipe Pose connections; centre = left shoulder (the face is not linked to the body).
POSE_EDGES = (
    (0, 1), (1, 2), (2, 3), (3, 7), (0, 4), (4, 5), (5, 6), (6, 8), (9, 10), (11, 12), (11, 13),
    (13, 15), (15, 17), (15, 19), (15, 21), (17, 19), (12, 14), (14, 16), (16, 18), (16, 20),
    (16, 22), (18, 20), (11, 23), (12, 24), (23, 24), (23, 25), (24, 26), (25, 27), (26, 28),
    (27, 29), (28, 30), (29, 31), (30, 32), (27, 31), (28, 32),
)
LAYOUT = KeypointLayout("mediapipe-pose", tuple(f"pose_{i}" for i in range(33)), POSE_EDGES, center=11)


def load_clips(data_root: Path, num_frames: int) -> ArraySplit:
    glosses = {}
    for entry in json.loads((data_root / "wlasl" / "WLASL_v0.3.json").read_text()):
        for instance in entry["instances"]:
            glosses[instance["video_id"]] = entry["gloss"]
    X, masks, labels = [], [], []
    for path in sorted((data_root / "keypoints" / "wlasl-mediapipe-pose").glob("*.npy")):
        frames = np.load(path)
        frames = np.resize(frames, (num_frames, frames.shape[1])) if len(frames) < num_frames else frames[:num_frames]
        raw = frames.reshape(num_frames, 33, 4)
        observed = np.any(raw != 0, axis=2)
        xyz = np.clip(np.stack([2 * raw[..., 0] - 1, 2 * raw[..., 1] - 1, raw[..., 2]]), -1, 1)
        X.append((xyz * observed).astype(np.float32)[..., None])
        masks.append(observed)
        labels.append(glosses[path.stem])
    names = sorted(set(labels))
    y = np.array([names.index(label) for label in labels], dtype=np.int64)
    return ArraySplit(np.stack(X), np.stack(masks), y)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", default="stgcn,gru,mlp", help="comma-separated classifier names")
    parser.add_argument("--epochs", type=int, default=3)
    parser.add_argument("--frames", type=int, default=150)
    parser.add_argument("--threads", type=int, default=2)
    parser.add_argument("--batch-size", type=int, default=32)
    parser.add_argument("--wide-stgcn", action="store_true", help="also time ST-GCN with [64, 64, 128, 128, 256]")
    parser.add_argument("--frame-stride", type=int, default=None, help="override frame_stride of stgcn/gru/lstm/cnn3d")
    parser.add_argument("--data-root", type=Path, default=Path(os.environ.get("ASLEXP_DATA_ROOT", Path(__file__).resolve().parents[2] / "shared" / "data")))
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING)

    start = time.perf_counter()
    clips = load_clips(args.data_root, args.frames)
    num_classes = int(clips.y.max()) + 1
    print(f"data: {len(clips)} clips, X {tuple(clips.X.shape)}, {num_classes} glosses, loaded in {time.perf_counter() - start:.1f}s")
    print(f"torch {torch.__version__}, {args.threads} thread(s), batch {args.batch_size}, {args.epochs} epochs per model")
    print(f"load average before: {' '.join(f'{v:.1f}' for v in os.getloadavg())} ({os.cpu_count()} CPUs; shared machines skew figures)", flush=True)

    runs = [(name, {}) for name in args.models.split(",") if name]
    if args.wide_stgcn:
        runs.append(("stgcn", {"channels": [64, 64, 128, 128, 256]}))
    if args.frame_stride is not None:
        runs = [(name, {**params, "frame_stride": args.frame_stride} if "frame_stride" in DEFAULT_PARAMS[name] else params) for name, params in runs]
    trainer = {"batch_size": args.batch_size, "num_threads": args.threads}
    print(f"{'model':<32} {'params':>9} {'clips/s':>9} {'s/epoch':>8}")
    for name, params in runs:
        torch.manual_seed(0)
        model = build_classifier(name, params, 3, args.frames, 33, num_classes, LAYOUT)
        if model.kind != "torch":
            print(f"{name:<32} (not a torch model: skipped)")
            continue
        result = fit_final(model, clips, ArraySplit(clips.X[:1], clips.mask[:1], clips.y[:1]), trainer, epochs=args.epochs)
        rate = statistics.median(row["clips_per_s"] for row in result.fit.history)
        seconds = statistics.median(row["epoch_time"] for row in result.fit.history)
        label = " ".join([name] + [f"{key}={value}" for key, value in params.items()])
        print(f"{label:<32} {model.num_parameters():>9,d} {rate:>9.1f} {seconds:>8.2f}", flush=True)
    channels = DEFAULT_PARAMS["stgcn"]["channels"]
    print(f"(default stgcn channels: {channels})")


if __name__ == "__main__":
    main()
