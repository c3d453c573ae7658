"""`aslexp extract VIDEO_OR_DIR... --out DIR`: videos -> keypoints (+ overlays, motion files).

Examples::

    aslexp extract ../shared/data/videos/wlasl --out outputs/keypoints/wlasl6 --overlay --motions
    aslexp extract --wlasl ../shared/data/wlasl/WLASL_v0.3.json --videos ../shared/data/videos/wlasl \\
        --out outputs/keypoints/wlasl6            # cut each video to frame_start..frame_end
    aslexp extract clip.mp4 --frames 11:60 --out DIR --format pose   # frames 11..60 -> DIR/clip.pose
    aslexp extract VIDEOS/ --out DIR --workers 8                     # 8 MediaPipe processes
    aslexp extract VIDEOS/ --out DIR --shard $SLURM_ARRAY_TASK_ID/$SLURM_ARRAY_TASK_COUNT
    aslexp extract clip.pose --motions --out DIR                     # keypoints already: retarget
    aslexp extract hands/ --motions --frame-size 640x480 --out DIR   # MediaPipe Hands arrays (T, 126)
    aslexp extract ../shared/data/keypoints/wlasl-mediapipe-pose --motions --out DIR  # Pose arrays (T, 132)

Exit code (as every aslexp command): 0 when the batch ran, also when some videos, overlays or
motions failed (a video without hands, an unreadable file: each listed with its reason, and a
last line counting them); 1 when nothing succeeded (every video failed, or no MediaPipe
environment); 2 for bad input (bad arguments, no videos in the inputs, keypoints without
--motions, hand arrays without --frame-size), also when every input is bad (a .pose cut short,
without frames or frame rate: its one line); 130 on Ctrl-C and 1 on a full disk, one line each
(what is finished is kept; the same command resumes). Motions that are written but implausible (a
joint held at its limit, arms deeper than a body reaches, tracking jumps, arms out of view) are
WARNING lines, one per kind, not failures; the report marks them (``plausibility``).
"""

from __future__ import annotations

import argparse
import errno
import json
import math
import sys
from collections import Counter
from pathlib import Path

from aslexp.keypoints.hands import HANDEDNESS_SUFFIX
from aslexp.pose.extract import (
    ExtractionError,
    ExtractOptions,
    apply_frame_ranges,
    collect_jobs,
    extract_videos,
    parse_frames,
    parse_shard,
    render_overlays,
    select_shard,
    video_files,
    write_pose_files,
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="aslexp extract",
        description="Extract MediaPipe Holistic keypoints from sign videos (cached per video), "
        "optionally with skeleton overlays and DeepMimic reference motions.",
    )
    p.add_argument("inputs", nargs="*", help="video files, folders of videos, or a WLASL json; or, with "
                   "--motions, keypoints retargeted as they are: .pose files (pose-format; MediaPipe points by "
                   "name), .npy keypoint arrays (MediaPipe Hands (T, 126), ...), or folders of them")
    p.add_argument("--out", required=True, help="output folder (a 'directory' keypoint source)")
    p.add_argument("--wlasl", help="WLASL json: cut each video to its instance's frame range "
                   "(the videos come from --videos DIR or a folder among the inputs); with keypoint "
                   "arrays: each one's frame rate and gloss, by video id")
    p.add_argument("--videos", help="folder of <video_id>.mp4 for a WLASL json")
    p.add_argument("--ids", nargs="*", help="only these video ids")
    p.add_argument("--frames", action="append", default=[], metavar="[ID=]START:END",
                   help="frames START..END (1-based, inclusive; END -1 = to the end) of every video "
                   "taken whole, or with ID= of that video only (repeatable)")
    p.add_argument("--format", choices=("npy", "pose"), default="npy",
                   help="pose: also write <out>/<id>.pose (pose-format, MediaPipe Holistic) beside "
                   "the arrays, which stay the cache")
    p.add_argument("--workers", type=int, default=1,
                   help="MediaPipe processes sharing the videos (default 1); each gets --cpus cores")
    p.add_argument("--shard", metavar="I/N",
                   help="cluster array task I of N (0-based): only the videos whose position in "
                   "video-id order is I mod N; every task shares --out, its cache and resume")
    p.add_argument("--face", action="store_true", help="also store the 468 face landmarks")
    p.add_argument("--no-hands-model", action="store_true",
                   help="Holistic only (no metric 3D hands from MediaPipe Hands; faster)")
    p.add_argument("--cpus", type=int, default=1,
                   help="cores per MediaPipe worker (default 1; 0 = no pinning)")
    p.add_argument("--force", action="store_true", help="redo videos that are already extracted")
    p.add_argument("--overlay", action="store_true", help="draw the skeleton on each video")
    p.add_argument("--overlay-format", choices=("mp4", "gif"), default="mp4")
    p.add_argument("--motions", action="store_true",
                   help="write hand (23-column) and upper-body (76-column) motion files")
    # defaults: conf/retargeting/default.yaml (aslexp retarget reads the same)
    p.add_argument("--hand", choices=("dominant", "right", "left"), default=None,
                   help="which signer hand drives the 15-DoF hand motion (default: dominant)")
    p.add_argument("--torso", choices=("vertical", "hips"), default=None,
                   help="chest pitch: upright (default; waist-framed videos) or from the hips")
    p.add_argument("--sigma", type=float, default=None, help="temporal smoothing of angles (frames)")
    p.add_argument("--pose-hand-points", action="store_true", default=None,
                   help="where a hand's landmarks are missing (a MediaPipe Pose array), turn the upper body's "
                        "wrist from Pose's wrist, index and pinky points (retargeting.pose_hand_points)")
    p.add_argument("--filter", choices=("none", "savgol", "gaussian"), default=None,
                   help="landmarks smoothed in time before inverse kinematics: Savitzky-Golay or Gaussian")
    p.add_argument("--filter-window", type=float, default=None, metavar="SECONDS",
                   help="the filter's window (Savitzky-Golay) or twice its sigma (Gaussian), in seconds")
    p.add_argument("--filter-order", type=int, default=None, help="the Savitzky-Golay polynomial's order")
    p.add_argument("--frame-size", metavar="WIDTHxHEIGHT",
                   help="keypoint arrays: the video's frame size in pixels (normalised hand landmarks need it "
                   "for the hand's proportions; MediaPipe Pose arrays fit it per clip without), e.g. 640x480")
    p.add_argument("--fps", type=float, default=None,
                   help="keypoint arrays: their frame rate (default 25, WLASL's; arrays hold none)")
    p.add_argument("--hand-order", choices=("left_right", "detection"), default="left_right",
                   help="two-hand arrays: the signer's left hand first (default), or MediaPipe's detection "
                   "order (sides per frame, from <id>.handedness.npy when present; see pose.options.hand_order)")
    p.add_argument("--mirrored", action="store_true",
                   help="two-hand arrays in detection order from a mirrored (selfie) video")
    p.add_argument("--data-root", help="data root with models/ (default: ../shared/data)")
    p.add_argument("--quiet", action="store_true", help="no progress line")
    p.add_argument("--debug", action="store_true", help="tracebacks on Ctrl-C and a full disk (else one line)")
    return p


def extract_main(argv: list[str]) -> int:
    """Entry point for `aslexp extract`; returns the exit code. Ctrl-C (130) and a full disk (1)
    are one line each, not a traceback: what is finished stays (each file is written whole or not
    at all), and the same command resumes (``--debug`` keeps the traceback)."""
    debug = "--debug" in argv  # known before parsing: a Ctrl-C may come at any time
    try:
        return _extract(argv)
    except KeyboardInterrupt:
        if debug:
            raise
        print("aslexp extract: interrupted (Ctrl-C): the files finished so far are kept; the same command "
              "resumes", file=sys.stderr)  # fmt: skip
        return 130
    except OSError as err:
        from aslexp.files import describe_os_error

        if debug or err.errno not in NO_SPACE:
            raise
        print(f"aslexp extract: {describe_os_error(err)}; the files finished so far are kept: free some space "
              "and run the same command again", file=sys.stderr)  # fmt: skip
        return 1


NO_SPACE = (errno.ENOSPC, errno.EDQUOT)  # a full disk stops the batch: every next file would fail too


def _extract(argv: list[str]) -> int:
    """`aslexp extract` (the exit code)."""
    args = build_parser().parse_args(argv)
    if args.motions:  # a bad retargeting option stops here, before any work
        from aslexp.errors import ConfigError

        try:
            args.retargeting = retargeting_options(args)
        except ConfigError as err:
            print(f"aslexp extract: {err}", file=sys.stderr)
            return 2
    keypoints, keypoint_skips = keypoint_inputs(args.inputs, read_handedness=args.hand_order == "detection")
    if keypoints:  # already keypoints: retarget them (no MediaPipe)
        return _retarget_keypoints(args, keypoints, keypoint_skips)
    skipped: Counter = Counter()
    try:
        jobs, summary_name = _video_jobs(args, skipped)
    except ExtractionError as err:
        print(f"aslexp extract: {err}", file=sys.stderr)
        return 2  # bad input
    if not jobs and not args.shard:
        print("aslexp extract: no videos found in the inputs "
              f"({', '.join(args.inputs or [args.wlasl])}); skipped: {dict(skipped) or 'nothing'}",
              file=sys.stderr)  # fmt: skip
        return 2
    options = ExtractOptions(face=args.face, hands_model=not args.no_hands_model,
                             cpus=args.cpus or None)  # fmt: skip
    try:
        summary = extract_videos(jobs, args.out, options, force=args.force, progress=not args.quiet,
                                 workers=args.workers, summary_name=summary_name)  # fmt: skip
    except ExtractionError as err:
        print(f"aslexp extract: {err}", file=sys.stderr)
        return 1
    summary.skipped_inputs = dict(skipped)
    print(summary.report())
    problems = [f"  FAILED {vid}: {f.get('reason')}" for vid, f in sorted(summary.failed.items())]
    done = sorted(summary.ok)
    if args.format == "pose" and done:
        written = write_pose_files(args.out, done, force=args.force)
        print(f".pose files: {len(written)} in {args.out}")
    if args.overlay and done:
        results = render_overlays(done, args.out, fmt=args.overlay_format, cpus=args.cpus or None)
        bad = {v: r for v, r in results.items() if r.get("status") != "ok"}
        print(f"overlays: {len(results) - len(bad)} written to {Path(args.out) / 'overlay'}")
        for vid, r in sorted(bad.items()):
            print(f"  overlay FAILED {vid}: {r.get('error')}")
        problems += [f"  overlay FAILED {vid}: {r.get('error')}" for vid, r in sorted(bad.items())]
    if args.motions and done:
        problems += _write_motions(done, args)[0]
    summary_path = Path(args.out) / summary_name
    data = json.loads(summary_path.read_text())
    data["skipped_inputs"] = dict(skipped)
    summary_path.write_text(json.dumps(data, indent=1))
    return _batch_end(len(jobs), len(done), problems)


def _retarget_keypoints(args, keypoints: list[Path], keypoint_skips: Counter) -> int:
    """Inputs that are keypoints already: retargeted to motions (no MediaPipe); the exit code."""
    others = [i for i in args.inputs if not _is_keypoints(Path(i))]
    if others or not args.motions:
        kinds = Counter(path.suffix for path in keypoints)
        print(f"aslexp extract: {', '.join(f'{n} {suffix}' for suffix, n in sorted(kinds.items()))} "
              "input(s) are keypoints already: give only keypoint files and folders, with --motions, to "
              "retarget them" + (f" (not keypoints: {', '.join(others)})" if others else ""),
              file=sys.stderr)  # fmt: skip
        return 2
    if keypoint_skips:
        print(f"skipped inputs: {dict(keypoint_skips)}")
    from aslexp.pose.landmarks import NeedsOption

    try:
        problems, written = _write_motions([str(path) for path in keypoints], args, from_files=True)
    except NeedsOption as err:  # the same for every array of the batch: one line, not one per file
        print(f"aslexp extract: {err}", file=sys.stderr)
        return 2
    return _batch_end(len(keypoints), written, problems)


def _video_jobs(args, skipped: Counter) -> tuple[list, str]:
    """The videos to extract (``--wlasl``/``--videos``, ``--frames``, ``--shard``) and the summary's
    file name; an ExtractionError names what is wrong with the inputs."""
    if not args.inputs and not args.wlasl:
        raise ExtractionError("nothing to extract: give video files or folders, or --wlasl FILE "
                              "--videos DIR")  # fmt: skip
    if args.wlasl and not args.videos and not any(Path(i).is_dir() for i in args.inputs):
        raise ExtractionError(f"--wlasl {args.wlasl} needs the videos: add --videos DIR (a folder "
                              "of <video_id>.mp4), e.g. --videos ../shared/data/videos/wlasl")  # fmt: skip
    if args.workers < 1:
        raise ExtractionError(f"--workers {args.workers}: expected 1 or more")
    jobs = collect_jobs(args.inputs, wlasl_json=args.wlasl, video_dir=args.videos,
                        ids=args.ids, skipped=skipped)  # fmt: skip
    jobs = apply_frame_ranges(jobs, [parse_frames(text) for text in args.frames])
    if not args.shard:
        return jobs, "summary.json"
    index, count = parse_shard(args.shard)
    total = len(jobs)
    jobs = select_shard(jobs, index, count)
    print(f"shard {index}/{count}: {len(jobs)} of {total} videos")
    return jobs, f"summary.shard-{index}-of-{count}.json"


def _batch_end(total: int, succeeded: int, problems: list[str]) -> int:
    """The batch's last line and exit code: 0 when anything succeeded (the failures are listed
    above, each with its reason), 1 when nothing did, 2 when nothing did because every input is
    bad (:class:`BadInput`)."""
    if problems and succeeded:
        print(f"done with {len(problems)} problem(s) in {total} input(s), listed above "
              "(FAILED lines); the rest is written")
    if total and not succeeded:
        bad_input = bool(problems) and all(isinstance(line, BadInput) for line in problems)
        if bad_input and len(problems) == 1:  # one bad file: its own line is the report
            print(f"aslexp extract: {problems[0].strip().removeprefix('motion FAILED ')}", file=sys.stderr)
        else:
            print(f"aslexp extract: none of the {total} input(s) succeeded"
                  + (" (FAILED lines above)" if problems else ""), file=sys.stderr)  # fmt: skip
        return 2 if bad_input else 1
    return 0


class BadInput(str):
    """A FAILED line whose input is bad (unreadable, cut short, without frames or frame rate): when
    every input of a batch is one, the exit code is 2, as for bad arguments."""


KEYPOINT_SUFFIXES = (".pose", ".npy")


def _is_keypoints(path: Path) -> bool:
    """A keypoint file, or a folder of keypoint files without videos."""
    if path.suffix in KEYPOINT_SUFFIXES and not path.is_dir():
        return True
    return path.is_dir() and not video_files(path) and any(_keypoint_files(path))


def _keypoint_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.iterdir() if p.is_file() and p.suffix in KEYPOINT_SUFFIXES
                  and not p.name.endswith(HANDEDNESS_SUFFIX))  # fmt: skip


def keypoint_inputs(inputs: list[str], read_handedness: bool = False) -> tuple[list[Path], Counter]:
    """The keypoint files among the inputs (files, and folders holding keypoints and no videos)
    and what those folders hold besides, counted by why it is not taken: other files (handedness
    files too, unless ``read_handedness``: --hand-order detection reads them), and an ``<id>.npy``
    beside an ``<id>.pose`` (the .pose is taken: it is the documented container, and aslexp
    writes both from one extraction)."""
    files: list[Path] = []
    skipped: Counter = Counter()
    for item in inputs:
        path = Path(item)
        if not _is_keypoints(path):
            continue
        if not path.is_dir():
            files.append(path)
            continue
        found = _keypoint_files(path)
        poses = {p.stem for p in found if p.suffix == ".pose"}
        for p in found:
            if p.suffix == ".npy" and p.stem in poses:
                skipped[".npy beside a .pose of the same id (the .pose is taken)"] += 1
            else:
                files.append(p)
        for p in path.iterdir():
            if not p.is_file() or p in found:
                continue
            if p.name.endswith(HANDEDNESS_SUFFIX):
                if not read_handedness:
                    skipped["handedness file (read with --hand-order detection)"] += 1
            else:
                skipped[f"{p.suffix or 'no suffix'} file (not keypoints)"] += 1
    return files, skipped


def retargeting_options(args) -> dict:
    """The retargeting's options: conf/retargeting/default.yaml, with the flags given over it."""
    from aslexp.compose import group
    from aslexp.errors import ConfigError
    from aslexp.pose.landmark_filter import retargeting_options as parse  # the one reader of the section

    section = group("retargeting", job="retarget")
    for key in ("hand", "torso", "sigma", "pose_hand_points"):
        if getattr(args, key) is not None:
            section[key] = getattr(args, key)
    for key, flag in (("kind", "filter"), ("window", "filter_window"), ("order", "filter_order")):
        if getattr(args, flag) is not None:
            section["filter"][key] = getattr(args, flag)
    try:
        return parse(section)
    except ValueError as error:  # said as the flags are spelled
        text = str(error).replace("retargeting.filter.kind", "--filter").replace("retargeting.filter.", "--filter-")
        raise ConfigError(text.replace("retargeting.", "--")) from None


def _write_motions(video_ids: list[str], args, from_files: bool = False) -> tuple[list[str], int]:
    """Motions for extracted videos (ids in --out), or for keypoint files (.pose, .npy paths) into
    --out/motions; prints the counts, each failure, each warning (implausible joints or
    proportions, an input's own) and, once per reason, the parts an input kind never holds;
    returns the FAILED lines and how many inputs gave at least one motion."""
    from aslexp.errors import DataError
    from aslexp.pose.body_arrays import landmarks_from_keypoint_array
    from aslexp.pose.landmarks import NeedsOption, parse_frame_size
    from aslexp.pose.retarget import retarget_landmarks, retarget_video
    from aslexp.pose.source_frame import record_source

    counts: Counter = Counter()
    problems: list[str] = []
    warnings: list[str] = []
    not_made: Counter = Counter()  # (part, reason) -> inputs
    written = 0
    out = Path(args.out) / "motions"
    options = dict(args.retargeting, data_root=args.data_root)
    clips = _wlasl_clips(args) if from_files else {}
    for vid in video_ids:
        name = Path(vid).stem if from_files else vid
        try:
            if from_files and vid.endswith(".npy"):
                try:
                    size = parse_frame_size(args.frame_size) if args.frame_size else None
                except ValueError as err:
                    raise NeedsOption(f"--frame-size: {err}") from None
                fps, fps_from, gloss = _array_fps(name, args, clips)
                landmarks = landmarks_from_keypoint_array(vid, size, fps, fps_from, gloss, args.data_root,
                                                          hand=options["hand"], hand_order=args.hand_order,
                                                          mirrored=args.mirrored)  # fmt: skip
                result = retarget_landmarks(landmarks, out, **options)
                if "pose_array" in result:  # a MediaPipe Pose array: its image keypoints are the source
                    record_source(result, vid, out, args.data_root, size)
            else:
                result = retarget_video(vid if from_files else args.out, None if from_files else vid, out, **options)
                # the source keypoint file, the camera and the retargeting error: what scores a performance
                record_source(result, vid if from_files else Path(args.out) / f"{vid}.npy", out, args.data_root)
        except NeedsOption:
            raise
        except (DataError, OSError, ValueError) as err:
            if isinstance(err, OSError) and err.errno in NO_SPACE:
                raise
            text = str(err)  # a keypoint file's message names it already
            line = f"  motion FAILED {text if text.startswith(str(vid)) else f'{vid}: {text}'}"
            problems.append(BadInput(line) if isinstance(err, (DataError, FileNotFoundError)) else line)
            continue
        warnings += [f"  motion WARNING {name}: {line}" for line in result.get("warnings", [])]
        for part in ("hand", "upper_body"):
            r = result[part]
            counts[f"{part} {r['status']}"] += 1
            if not r.get("plausibility", {}).get("plausible", True):
                counts[f"{part} implausible"] += 1
            if r["status"] == "failed":
                problems.append(f"  motion FAILED {name} {part}: {r['error']}")
            elif r["status"] == "skipped":
                not_made[(part, r["detail"])] += 1
            warnings += [f"  motion WARNING {name} {part}: {line}" for line in r.get("warnings", [])]
        written += any(result[part]["status"] == "ok" for part in ("hand", "upper_body"))
    print(f"motions in {out}: " + (", ".join(f"{k}: {v}" for k, v in sorted(counts.items())) or "none"))
    for (part, reason), n in sorted(not_made.items()):
        print(f"  {part} not made for {n} input(s): {reason}")
    for line in problems:
        print(line)
    counted = counted_warnings(warnings)
    for line in counted:
        print(line)
    if warnings:
        print(f"{len(warnings)} warning(s) of {len(counted)} kind(s) above (WARNING lines; each motion's own in "
              f"{out / 'reports'}/<id>.json): those motions are written, but check them")  # fmt: skip
    implausible = counts.get("upper_body implausible", 0)
    if implausible:
        print(f"{implausible} upper-body motion(s) marked implausible in their reports (plausibility): a training "
              "pool leaves them out")  # fmt: skip
    return problems, written


DEFAULT_FPS = 25.0  # keypoint arrays hold no frame rate
DEFAULT_FPS_FROM = "the default: WLASL's frame rate (WLASL_v0.3.json gives fps 25 for each of its 21083 clips)"


def _wlasl_clips(args) -> dict[str, dict]:
    """video id -> {'gloss', 'fps'} from --wlasl, for keypoint arrays ({} without it)."""
    if not args.wlasl:
        return {}
    from aslexp.errors import DataError
    from aslexp.pose.body_arrays import wlasl_instances
    from aslexp.pose.landmarks import NeedsOption

    try:
        return wlasl_instances(args.wlasl)
    except DataError as err:  # the same for the whole batch: one line, exit 2
        raise NeedsOption(f"--wlasl {err}") from None


def _array_fps(name: str, args, clips: dict[str, dict]) -> tuple[float, str, str | None]:
    """A keypoint array's frame rate, where it comes from, and its gloss: from --wlasl's entry for
    its video id when there is one, else --fps (said whether given or the default)."""
    clip = clips.get(name)
    if clip and clip.get("fps"):
        return float(clip["fps"]), f"{args.wlasl}: the fps of video {name}", clip.get("gloss")
    fps = DEFAULT_FPS if args.fps is None else args.fps
    if not (math.isfinite(fps) and fps > 0):
        from aslexp.pose.landmarks import NeedsOption

        raise NeedsOption(f"--fps {fps:g}: expected a positive frame rate (frames per second), e.g. --fps 25")
    source = f"--fps {fps:g}" if args.fps is not None else f"{DEFAULT_FPS:g} fps, {DEFAULT_FPS_FROM}"
    if clips:
        source += f" (video {name} is not in {args.wlasl})"
    return fps, source, clip.get("gloss") if clip else None


def counted_warnings(lines: list[str], examples: int = 3) -> list[str]:
    """WARNING lines, one per kind (the same words once numbers and frame lists are set aside): a
    kind met once is its own line; a kind met more often is one line counting the inputs, naming a
    few, with its first line as the example."""
    import re

    kinds: dict[str, list[str]] = {}
    for line in lines:
        message = line.split(": ", 1)[1] if ": " in line else line
        named = re.match(r"[a-z ]+: ", message)  # "jumps: ...", "out of view: ...": the kind says itself
        key = named.group(0) if named else re.sub(r"\(frames [^()]*(\([^)]*\))?\)|\d+(\.\d+)?", "#", message)  # "(frames 0-3, ... (6 ranges))"
        head = line.split(": ", 1)[0].split()
        part = head[-1] if head and head[-1] in ("hand", "upper_body") else ""
        kinds.setdefault(f"{part}|{key}", []).append(line)
    out = []
    for same in kinds.values():
        if len(same) == 1:
            out.append(same[0])
            continue
        names = [line.split(": ", 1)[0].split("WARNING ", 1)[-1] for line in same]
        shown = ", ".join(names[:examples]) + (f", ... ({len(names) - examples} more)" if len(names) > examples else "")
        out.append(f"  motion WARNING x{len(same)} ({shown}), e.g. {same[0].split('WARNING ', 1)[-1]}")
    return out


if __name__ == "__main__":
    sys.exit(extract_main(sys.argv[1:]))
