"""`aslexp extract` fails well on real faults: a `.pose` cut short, without frames or with a frame
rate of 0 (one line naming the file and what is expected, exit 2; the good files of a batch still
written); Ctrl-C and a full disk (one line, what is finished kept, no temporary left); a worker's
write killed midway (its temporary removed); many inputs warned of one thing (one counted line).
Real files throughout: the shared data's MediaPipe Pose arrays, as arrays and as `.pose` files."""

from __future__ import annotations

import os
import shutil
import signal
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from pose_format import Pose
from pose_format.pose_header import PoseHeader
from pose_format.utils.reader import BufferReader

from aslexp.keypoints import holistic as H
from aslexp.keypoints.posefile import write_holistic_pose
from aslexp.pose.extract_cli import extract_main

PROJECT_ROOT = Path(__file__).resolve().parents[2]
POSE_DIR = Path("keypoints") / "wlasl-mediapipe-pose"
CLIP = "05307"  # 145 frames


def _run(args, capsys) -> tuple[int, str, str]:
    rc = extract_main([str(a) for a in args])
    captured = capsys.readouterr()
    return rc, captured.out, captured.err


def _cli(*args, **kwargs) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "aslexp.cli", "extract", *map(str, args)], cwd=PROJECT_ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, **kwargs)  # fmt: skip


def _temporaries(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.name.endswith(".tmp")]


@pytest.fixture()
def pose_files(data_root, tmp_path) -> dict[str, Path]:
    """The clip as a `.pose` (body only, no world: as pose-format's video_to_pose writes a body),
    and the same file damaged: cut short (format 0.2, and 0.1, whose reader reads what the bytes
    hold), with frame rate 0, and with 0 frames."""
    array = np.load(data_root / POSE_DIR / f"{CLIP}.npy")
    body = np.full((len(array), H.NUM_NODES, 4), np.nan, np.float32)
    body[:, : H.NUM_POSE] = array.reshape(len(array), H.NUM_POSE, 4)
    folder = tmp_path / "pose"
    whole = write_holistic_pose(folder / "whole.pose", body, 25.0, 640, 480)
    data = whole.read_bytes()
    reader = BufferReader(data)
    PoseHeader.read(reader)
    start = reader.read_offset  # the body: fps (float32), frames (uint32), people (uint16), then the frames
    fps, frames, people = struct.unpack_from("<fIH", data, start)
    v01 = struct.pack("<f", 0.1) + data[4:start] + struct.pack("<HHH", int(fps), frames, people) + data[start + 10 :]
    files = {"whole": whole, "cut": folder / "cut.pose", "cut_v01": folder / "cut_v01.pose",
             "fps0": folder / "fps0.pose"}  # fmt: skip
    files["cut"].write_bytes(data[: len(data) * 58 // 100])
    files["cut_v01"].write_bytes(v01[: len(v01) * 58 // 100])
    files["fps0"].write_bytes(data[:start] + struct.pack("<f", 0.0) + data[start + 4 :])
    files["empty"] = write_holistic_pose(folder / "empty.pose", body[:0], 25.0, 640, 480)
    return files


@pytest.mark.parametrize("name, expected", [
    ("cut", "cut short (truncated): its header says 145 frames of 1 person(s) x 75 points, 174000 bytes; the file "
            "holds 100109 (83 whole frames): copy or write it again"),
    ("cut_v01", "cut short (truncated): its header says 145 frames of 1 person(s) x 75 points, 174000 bytes; the "
                "file holds 100111 (83 whole frames): copy or write it again"),
    ("fps0", "frame rate 0 in the file: expected a positive fps (frames per second); write it again with its "
             "video's frame rate"),
    ("empty", "0 frames: the file has a header and no keypoints; a motion needs at least one frame"),
])  # fmt: skip
def test_a_bad_pose_file_is_one_line_and_exit_2(pose_files, tmp_path, capsys, name, expected):
    rc, _, err = _run([pose_files[name], "--motions", "--out", tmp_path / "out"], capsys)
    assert rc == 2 and err.splitlines() == [f"aslexp extract: {pose_files[name]}: {expected}"]
    assert not (tmp_path / "out" / "motions" / "upper_body").exists()


def test_a_format_0_1_file_cut_short_reads_silently_as_a_shorter_clip_in_pose_format(pose_files):
    """Why the check: pose-format's own reader takes the cut 0.1 file as 83 frames (its confidences
    read from coordinates), where the file says 145."""
    assert Pose.read(pose_files["cut_v01"].read_bytes()).body.data.shape[0] == 83


def test_in_a_batch_the_good_files_are_written_and_the_bad_ones_listed(pose_files, tmp_path, capsys):
    rc, printed, _ = _run([pose_files["whole"], pose_files["cut"], pose_files["empty"], "--motions", "--out",
                           tmp_path / "out"], capsys)  # fmt: skip
    assert rc == 0 and (tmp_path / "out" / "motions" / "upper_body" / "whole.txt").is_file()
    assert f"motion FAILED {pose_files['cut']}: cut short" in printed
    assert f"motion FAILED {pose_files['empty']}: 0 frames" in printed


def test_many_inputs_warned_of_one_thing_give_one_counted_line(data_root, tmp_path, capsys):
    folder = tmp_path / "pose"
    folder.mkdir()
    out_of_view = ("70292", "70298", "70350", "70356")  # neither arm seen in half the frames
    for vid in (*out_of_view, "01457"):
        shutil.copy(data_root / POSE_DIR / f"{vid}.npy", folder)
    rc, printed, _ = _run([folder, "--motions", "--out", tmp_path / "out"], capsys)
    assert rc == 0
    lines = [line for line in printed.splitlines() if "out of view" in line]
    assert len(lines) == 1, lines
    assert lines[0].startswith("  motion WARNING x4 (70292 upper_body, 70298 upper_body, 70350 upper_body, ... "
                               "(1 more)), e.g. 70292 upper_body: out of view: the better seen arm is seen in ")
    kinds = [line for line in printed.splitlines() if "motion WARNING" in line]
    assert f"warning(s) of {len(kinds)} kind(s) above" in printed


def test_a_full_disk_is_one_line_and_leaves_no_temporary(data_root, small_disk):
    proc = _cli(data_root / POSE_DIR / "10585.npy", data_root / POSE_DIR / "01457.npy", "--motions", "--out",
                small_disk / "out")  # fmt: skip
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 1, err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"aslexp extract: disk full: cannot write {small_disk}/out/")
    assert "[Errno 28] No space left on device" in lines[0] and "run the same command again" in lines[0]
    assert _temporaries(small_disk) == []


def test_ctrl_c_is_one_line_keeps_the_finished_motions_and_leaves_no_temporary(data_root, tmp_path):
    out = tmp_path / "out"
    proc = _cli(data_root / POSE_DIR, "--motions", "--out", out,
                preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))  # fmt: skip
    reports = out / "motions" / "reports"
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(list(reports.glob("*.json"))) < 3:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert err.strip().splitlines() == ["aslexp extract: interrupted (Ctrl-C): the files finished so far are kept; "
                                        "the same command resumes"]  # fmt: skip
    assert _temporaries(out) == []
    from aslexp.pose.retarget import UPPER_FILE_VALUES
    from aslexp.sim.motion import load_motion

    for motion in (out / "motions" / "upper_body").glob("*.txt"):  # every one written is whole
        assert load_motion(motion, expected_columns=UPPER_FILE_VALUES).num_frames > 0


def test_a_worker_write_on_a_full_disk_leaves_no_temporary(small_disk):
    from aslexp.pose.mediapipe_worker import _atomic_save_npy

    with pytest.raises(OSError, match="requested and .* written"):  # numpy's words for a full disk
        _atomic_save_npy(small_disk / "world" / "clip.npy", np.zeros((200, 75, 3), np.float32))  # 180 kB > 64 kB
    assert _temporaries(small_disk) == [] and not (small_disk / "world" / "clip.npy").exists()


def test_a_worker_killed_midway_leaves_a_temporary_the_next_extraction_removes(tmp_path):
    """SIGKILL (nothing runs on the way out): the temporary stays until the video is extracted again,
    when `extract_videos` removes what a killed worker left of it (remove_temporaries)."""
    from aslexp.pose.extract import remove_temporaries

    out = tmp_path / "out"
    target = out / "world" / "clip.npy"
    # A worker writing a large array, killed while the temporary is being written.
    script = ("import sys, numpy as np; from pathlib import Path; from aslexp.pose.mediapipe_worker import "
              "_atomic_save_npy; _atomic_save_npy(Path(sys.argv[1]), np.ones((3000, 75, 3, 200), np.float32))")
    proc = subprocess.Popen([sys.executable, "-c", script, str(target)], cwd=PROJECT_ROOT)
    tmp = target.with_name(f".{target.name}.tmp")
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and not (tmp.is_file() and tmp.stat().st_size > 0):
        time.sleep(0.01)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    assert tmp.is_file() and not target.exists()  # the fault is real: a half file under the temporary name
    assert remove_temporaries(out, ["other"]) == [] and tmp.is_file()  # another video's: not touched
    assert remove_temporaries(out, ["clip"]) == [tmp] and _temporaries(out) == []
