"""Benchmark: MediaPipe extraction speed (frames/s) and real-time factor on real WLASL clips.

    python bench/extraction.py                       # 1 core, Holistic + Hands, two 25 fps clips
    python bench/extraction.py --cpus 2 --no-hands-model --clips 70266

Prints one row per (clip, setting): frames, seconds of the worker on that video (decode +
Holistic [+ Hands]; model loading excluded), frames/s, and the real-time factor = frames/s
divided by the clip's frame rate (> 1: faster than real time). Per setting it also prints the
worker's start-up time and its CPU time per frame: wall-clock figures depend on what else runs on
the machine, frames per CPU-second (the speed on one otherwise idle core) much less.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

from aslexp.data.root import resolve_data_root
from aslexp.pose.extract import ExtractOptions, VideoJob, extract_videos, read_status


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", nargs="+", default=["70266", "63185"], help="WLASL video ids")
    p.add_argument("--cpus", type=int, nargs="+", default=[1], help="core counts to try (0 = all)")
    p.add_argument("--no-hands-model", action="store_true", help="also time Holistic alone")
    p.add_argument("--data-root")
    args = p.parse_args()
    videos = resolve_data_root(args.data_root) / "videos" / "wlasl"
    settings = [(c, True) for c in args.cpus] + ([(c, False) for c in args.cpus] if args.no_hands_model else [])
    print(f"{'clip':>6} {'size':>9} {'cores':>5} {'model':>16} {'frames':>6} {'seconds':>7} "
          f"{'frames/s':>8} {'x real time':>11}")  # fmt: skip
    for cpus, hands in settings:
        jobs = [VideoJob(c, str(videos / f"{c}.mp4")) for c in args.clips]
        with tempfile.TemporaryDirectory() as out:
            start = time.perf_counter()
            cpu_before = resource.getrusage(resource.RUSAGE_CHILDREN)
            summary = extract_videos(jobs, out, ExtractOptions(cpus=cpus or None, hands_model=hands), progress=False)
            wall = time.perf_counter() - start
            cpu_after = resource.getrusage(resource.RUSAGE_CHILDREN)
            cpu = (cpu_after.ru_utime - cpu_before.ru_utime) + (cpu_after.ru_stime - cpu_before.ru_stime)
            per_video = 0.0
            for job in jobs:
                s = read_status(out, job.video_id)
                if s is None or s.get("status") != "ok":
                    print(f"{job.video_id:>6} failed: {summary.failed.get(job.video_id)}")
                    continue
                fps = s["frames"] / s["seconds"]
                per_video += s["seconds"]
                model = "holistic+hands" if hands else "holistic"
                print(f"{job.video_id:>6} {s['width']:>4}x{s['height']:<4} {cpus or 'all':>5} {model:>16} "
                      f"{s['frames']:>6} {s['seconds']:>7.2f} {fps:>8.1f} {fps / s['fps']:>11.2f}")  # fmt: skip
            print(f"{'':>6} total {summary.frames} frames in {wall:.1f} s wall "
                  f"({summary.frames / wall:.1f} frames/s incl. start-up {wall - per_video:.1f} s); "
                  f"CPU {cpu:.1f} s = {summary.frames / cpu:.1f} frames per CPU-second "
                  f"(load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")  # fmt: skip


if __name__ == "__main__":
    main()
