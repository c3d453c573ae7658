"""Runs never share a folder: claimed atomically, locked while they run.

Real jobs started at the same instant as separate processes."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from platform_helpers import error_lines
from platform_helpers import folder_hashes as _all_hashes

from aslexp.runs.record import LOCK_FILE
import job_process

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def folder_hashes(folder: Path) -> dict[str, str]:
    """The run's files (the lock file names its last holder: bookkeeping, not the run)."""
    return {k: v for k, v in _all_hashes(folder).items() if k != LOCK_FILE}


def _start(module: str, *overrides: str, cwd: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", module, *overrides], cwd=cwd,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "MPLBACKEND": "Agg"})


def _together(commands: list[tuple[str, ...]], cwd: Path) -> list[subprocess.CompletedProcess]:
    procs = [_start(*command, cwd=cwd) for command in commands]
    results = []
    for command, proc in zip(commands, procs):
        out, err = proc.communicate(timeout=300)
        results.append(subprocess.CompletedProcess(command, proc.returncode, out, err))
    return results


def test_three_runs_started_at_the_same_instant_get_three_folders(tmp_path):
    # The same time-stamped default name for all three (a year stamp: no second boundary between
    # them), as a Slurm array's tasks get from a name without their index.
    name = "hydra.run.dir=runs/q_${now:%Y}"
    done = _together([("aslexp.jobs.quadratic", f"x={x}", name, "sleep=1") for x in (0.1, 0.2, 0.3)],
                     tmp_path)
    assert [d.returncode for d in done] == [0, 0, 0], [d.stderr[-1500:] for d in done]
    folders = sorted(p for p in (tmp_path / "runs").iterdir())
    year = folders[0].name.split("_")[1]
    assert [p.name for p in folders] == [f"q_{year}", f"q_{year}_2", f"q_{year}_3"]
    xs = sorted(json.loads((p / "metrics.json").read_text())["x"] for p in folders)
    assert xs == [0.1, 0.2, 0.3]  # each folder holds exactly one run's metrics
    for p in folders:  # and that run's own config and log
        assert json.loads((p / "metrics.json").read_text())["x"] == float(
            next(o for o in json.loads((p / "run.json").read_text())["overrides"] if o.startswith("x="))[2:])


def test_the_default_folder_names_hold_seed_motion_body_and_engine():
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(str(PROJECT_ROOT / "conf"), version_base="1.3"):
        # The hand and the upper body on one clip: two folder names, each naming its body.
        for job in ("imitate", "evaluate", "plan"):
            for body in ("hand15", "upper_body"):
                cfg = compose(job, overrides=["motion=00433", f"body={body}", "engine=mujoco", "seed=3"],
                              return_hydra_config=True)
                folder = Path(cfg.hydra.run.dir)
                assert folder.parent == Path("outputs") / job and folder.name.endswith(f"_00433_{body}_mujoco_s3"), \
                    (job, folder)
        for job, overrides, parts in (("imitate", ["motion=C", "seed=3"], ["_C_hand15_mujoco_s3"]),
                                      ("recognize", ["seed=2"], ["_s2"]),
                                      ("tune_pd", ["seed=5"], ["hand15_mujoco_s5"])):
            cfg = compose(job, overrides=overrides, return_hydra_config=True)
            raw = cfg.hydra.run._get_node("dir")._value()
            assert "${now:" in raw, raw
            for part in parts:
                assert part in raw.replace("${motion.name}", "C").replace("${seed}", overrides[-1][5:]) \
                    .replace("${body.name}", "hand15").replace("${engine.name}", "mujoco"), (job, raw)


def test_two_jobs_into_one_explicit_folder_one_runs_the_other_is_refused(tmp_path):
    run_dir = tmp_path / "shared"
    done = _together([("aslexp.jobs.quadratic", f"x={x}", f"hydra.run.dir={run_dir}", "sleep=3")
                      for x in (0.1, 0.2)], tmp_path)
    codes = sorted(d.returncode for d in done)
    assert codes == [0, 2], [d.stderr[-1500:] for d in done]
    refused = next(d for d in done if d.returncode == 2)
    assert error_lines(refused.stderr) == [next(ln for ln in refused.stderr.splitlines()
                                                if "is in use by another aslexp job" in ln)]
    winner = next(d for d in done if d.returncode == 0)
    x = float(winner.args[1][2:])
    assert json.loads((run_dir / "metrics.json").read_text())["x"] == x
    assert f"x={x}" in json.loads((run_dir / "run.json").read_text())["overrides"]
    assert (run_dir / ".hydra" / "overrides.yaml").read_text().count(f"x={x}") == 1


SMALL = ["env=residual", "ppo=fast", "ppo.hidden_sizes=[16,16]", "ppo.steps_per_rollout=128",
         "ppo.minibatch_size=64", "ppo.epochs=1", "ppo.eval_interval=128", "ppo.eval_steps=20",
         "plots=false", "render.gif=false", "render.mp4=false"]


def _interrupted_imitate_run(tmp_path: Path) -> Path:
    """A run stopped before its budget (ppo.max_minutes=0: one rollout, then a checkpoint)."""
    run_dir = tmp_path / "run"
    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.imitate", "motion=B", *SMALL,
                           "ppo.total_steps=128", f"hydra.run.dir={run_dir}"], cwd=PROJECT_ROOT,
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    # Make it an unfinished run, as a kill would leave it: run.json interrupted, last.pt kept.
    info = json.loads((run_dir / "run.json").read_text())
    info.update(status="interrupted", error="interrupted (SIGTERM)")
    (run_dir / "run.json").write_text(json.dumps(info))
    (run_dir / "metrics.json").unlink()
    return run_dir


def test_an_unfinished_imitate_run_is_never_restarted_over_and_resumes_once(tmp_path):
    run_dir = _interrupted_imitate_run(tmp_path)
    before = folder_hashes(run_dir)
    base = ["aslexp.jobs.imitate", "motion=B", *SMALL, f"hydra.run.dir={run_dir}"]

    # Without resume: refused, the checkpoint and config untouched.
    fresh = job_process.run([sys.executable, "-m", *base, "ppo.total_steps=256"], cwd=PROJECT_ROOT,
                           capture_output=True, text=True, timeout=300)
    assert fresh.returncode == 2, fresh.stderr[-2000:]
    assert error_lines(fresh.stderr) == [
        f"aslexp imitate: {run_dir} holds an unfinished run's checkpoint {run_dir}/checkpoints/last.pt; "
        f"nothing was changed: add resume={run_dir} to continue it, or overwrite=true to start over"]
    assert folder_hashes(run_dir) == before

    # Resumed in place with another motion: refused before Hydra rewrites the folder's config.
    other = job_process.run([sys.executable, "-m", "aslexp.jobs.imitate", "motion=C", *SMALL,
                            f"hydra.run.dir={run_dir}", f"resume={run_dir}", "ppo.total_steps=256"],
                           cwd=PROJECT_ROOT, capture_output=True, text=True, timeout=300)
    assert other.returncode == 2 and "motion.name is 'B', this command asks for 'C'" in other.stderr
    assert len(error_lines(other.stderr)) == 1
    assert folder_hashes(run_dir) == before

    # Two resumes at once: one continues the run, the other is refused; rows written once.
    done = _together([(*base, f"resume={run_dir}", "ppo.total_steps=384")] * 2, PROJECT_ROOT)
    assert sorted(d.returncode for d in done) == [0, 2], [d.stderr[-1500:] for d in done]
    refused = next(d for d in done if d.returncode == 2)
    assert "is in use by another aslexp job" in refused.stderr
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["steps"] == 384
    steps = [json.loads(line)["steps"] for line in (run_dir / "progress.jsonl").read_text().splitlines()] \
        if (run_dir / "progress.jsonl").exists() else None
    rows = (run_dir / "progress.csv").read_text().splitlines()[1:]
    assert len(rows) == len(set(rows)), "a progress row was written twice"
    assert steps is None or len(steps) == len(set(steps))
