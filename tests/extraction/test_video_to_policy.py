"""A video becomes a signing humanoid in two commands, with no training: `aslexp extract VIDEO
--motions`, then `aslexp imitate motion.file=... policy=RUN_DIR` (docs/signing.md). On the repository
video 63185 ("whistle"; the session's MediaPipe extraction, read from its cache) and a policy trained
for a few hundred steps on the standing body (experiment=signs_standing_residual_quiet): the run
performs the video's sign with that policy, scores it beside the controller it rides on, against the
person, and says which is better."""

from __future__ import annotations

import contextlib
import io
import json
import os
import shutil
import sys

import job_process

from aslexp.pose.extract_cli import extract_main

from .conftest import CLIP

TINY = ["ppo.total_steps=256", "ppo.num_envs=8", "ppo.steps_per_rollout=128", "ppo.minibatch_size=64",
        "ppo.eval_interval=256", "ppo.eval_steps=30", "ppo.eval_episodes=1", "ppo.hidden_sizes=[16,16]",
        "plots=false", "render.gif=false", "render.mp4=false"]


def _aslexp(*args: str, data_root) -> job_process.subprocess.CompletedProcess:
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg"}
    return job_process.run([sys.executable, "-m", "aslexp.cli", *args], capture_output=True, text=True,
                           timeout=600, env=env)


def test_a_video_becomes_a_signing_humanoid_in_two_commands(extracted, videos, data_root, tmp_path):
    trained = tmp_path / "policy"
    proc = _aslexp("imitate", "experiment=signs_standing_residual_quiet", "motion='00433'", *TINY,
                   f"hydra.run.dir={trained}", data_root=data_root)
    assert proc.returncode == 0, proc.stderr[-3000:]

    # 1. the video's motions (MediaPipe's landmarks from the session's cache: no MediaPipe run here)
    out = tmp_path / "keypoints"
    shutil.copytree(extracted[0], out)
    with contextlib.redirect_stdout(io.StringIO()):
        assert extract_main([str(videos / f"{CLIP}.mp4"), "--out", str(out), "--motions", "--quiet"]) == 0
    motion = out / "motions" / "upper_body" / f"{CLIP}.txt"
    assert motion.is_file()
    # 2. the trained policy performs it: nothing is trained
    run = tmp_path / "performed"
    proc = _aslexp("imitate", f"motion.file={motion}", "body=upper_body", f"policy={trained}", "ppo.eval_steps=30",
                   "ppo.eval_episodes=1", "plots=false", "render.gif=false", "render.mp4=false",
                   f"hydra.run.dir={run}", data_root=data_root)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["stopped"] == "performed" and metrics["steps"] == 0 and metrics["motion"] == CLIP
    assert metrics["policy"]["run"] == str(trained) and metrics["policy"]["engine"] == "mujoco"
    # beside the controller it rides on, and against the person
    assert "reference_velocity_pd" in metrics["baselines"] or metrics["best_baseline"] is not None
    assert set(metrics["signing"]["stages"]) == {"reference", "controller", "policy"}
    last = [line for line in proc.stdout.splitlines() + proc.stderr.splitlines() if f"motion {CLIP}:" in line][-1]
    assert f"the policy of {trained}" in last and "best no-learning baseline" in last
    assert any(word in last for word in ("above the best", "BELOW the best", "AT the best"))
