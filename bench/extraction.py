"""Benchmark: MediaPipe extraction with 1, 2, ... workers, and what WLASL x ASL-LEX would cost.

    python bench/extraction.py                                   # 1 and 2 workers, five real clips
    python bench/extraction.py --workers 1 2 4 --nodes 1 10 50 --cores-per-node 32
    python bench/extraction.py --clips 63185 68011 --max-frames 15   # a smoke run (seconds)

Per worker count, in one run on the same clips (each worker one MediaPipe process pinned to its
own core, the videos on one shared queue): videos, frames, wall seconds (model loading
included), frames/s, CPU seconds per frame (all worker processes, start-up included; the figure
that depends least on how busy the machine is), the same without the start-up (a one-frame run
first measures a worker's start-up CPU: interpreter, models, first frame), speed-up and parallel
efficiency (speed-up / workers) against one worker.

Then the cost of the 15,911 WLASL x ASL-LEX 2.0 clips (``--clips-total``) at ``--frames-per-clip``
frames each (about 70 on average: ~1.1 M frames): core-hours at the measured CPU seconds per
frame, and wall-clock hours on N nodes of C cores with one worker per core (``--shard i/n`` per
node, ``--workers C`` within it) at the measured efficiency of the largest worker count.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

from aslexp.data.root import resolve_data_root
from aslexp.pose.extract import ExtractOptions, VideoJob, extract_videos

DEFAULT_CLIPS = ["63048", "63185", "68011", "68012", "70266"]  # 70212 is mostly a title card


def children_cpu() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", nargs="+", default=DEFAULT_CLIPS, help="WLASL video ids under <data>/videos/wlasl")
    p.add_argument("--max-frames", type=int, default=None, help="only the first N frames of each clip")
    p.add_argument("--workers", type=int, nargs="+", default=[1, 2], help="worker counts to compare")
    p.add_argument("--no-hands-model", action="store_true", help="Holistic only (no MediaPipe Hands)")
    p.add_argument("--clips-total", type=int, default=15911, help="clips to project the cost for")
    p.add_argument("--frames-per-clip", type=float, default=70.0, help="their mean length in frames")
    p.add_argument("--nodes", type=int, nargs="+", default=[1, 10, 50], help="cluster sizes to project")
    p.add_argument("--cores-per-node", type=int, default=32)
    p.add_argument("--data-root")
    args = p.parse_args()
    videos = resolve_data_root(args.data_root) / "videos" / "wlasl"
    end = args.max_frames if args.max_frames else None
    jobs = [VideoJob(c, str(videos / f"{c}.mp4"), 1 if end else None, end) for c in args.clips]
    options = ExtractOptions(cpus=1, hands_model=not args.no_hands_model)
    model = "Holistic + Hands" if options.hands_model else "Holistic"
    print(f"{model}, clips {' '.join(args.clips)}" + (f", first {end} frames each" if end else "")
          + f"; {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} before")  # fmt: skip
    with tempfile.TemporaryDirectory() as out:  # a worker's start-up: one frame of the first clip
        cpu_before = children_cpu()
        extract_videos([VideoJob(jobs[0].video_id, jobs[0].path, 1, 1)], out, options, progress=False)
        startup_cpu = children_cpu() - cpu_before
    print(f"start-up of one worker (one frame): {startup_cpu:.2f} CPU-s")
    print(f"{'workers':>7} {'videos':>6} {'frames':>6} {'wall s':>7} {'frames/s':>8} {'CPU-s/frame':>11} "
          f"{'w/o start-up':>12} {'speed-up':>8} {'efficiency':>10}")  # fmt: skip
    rows = []
    for workers in args.workers:
        with tempfile.TemporaryDirectory() as out:
            cpu_before, start = children_cpu(), time.perf_counter()
            summary = extract_videos(jobs, out, options, progress=False, workers=workers)
            wall, cpu = time.perf_counter() - start, children_cpu() - cpu_before
        if summary.failed:
            print(f"{workers:>7} failed: {summary.failed}")
            continue
        frames = max(summary.frames, 1)
        fps, cpu_per_frame = summary.frames / wall, cpu / frames
        steady = max(cpu - workers * startup_cpu, 0.0) / frames
        base = rows[0]["fps"] if rows else fps
        rows.append({"workers": workers, "fps": fps, "cpu_per_frame": cpu_per_frame, "steady": steady})
        print(f"{workers:>7} {len(summary.extracted):>6} {summary.frames:>6} {wall:>7.1f} {fps:>8.2f} "
              f"{cpu_per_frame:>11.3f} {steady:>12.3f} {fps / base:>8.2f} "
              f"{fps / base / workers * rows[0]['workers']:>10.2f}")  # fmt: skip
    if not rows:
        return
    cpu_per_frame = rows[0]["steady"] or rows[0]["cpu_per_frame"]  # at scale the start-up is negligible
    widest = rows[-1]
    efficiency = widest["fps"] / rows[0]["fps"] / widest["workers"] * rows[0]["workers"]
    frames = args.clips_total * args.frames_per_clip
    core_hours = frames * cpu_per_frame / 3600
    print(f"\n{args.clips_total} clips x {args.frames_per_clip:.0f} frames = {frames / 1e6:.2f} M frames at "
          f"{cpu_per_frame:.3f} CPU-s/frame: {core_hours:.0f} core-hours "
          f"({core_hours / 24:.1f} days on one core)")  # fmt: skip
    print(f"on N nodes x {args.cores_per_node} cores, one worker per core, parallel efficiency "
          f"{efficiency:.2f} (measured with {widest['workers']} workers here):")  # fmt: skip
    for nodes in args.nodes:
        hours = core_hours / (nodes * args.cores_per_node * efficiency)
        print(f"  {nodes:>4} node(s): {hours:7.2f} h wall")


if __name__ == "__main__":
    main()
