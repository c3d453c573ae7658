"""The Hydra jobs end to end, small: imitate (train, resume, bad checkpoint) and a tune_pd sweep."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import optuna
import pytest
import job_process

from aslexp.tuning.storage import open_storage

ROOT = Path(__file__).resolve().parents[2]
SMALL = ["env=residual", "ppo=fast", "ppo.hidden_sizes=[32,32]", "ppo.steps_per_rollout=256",
         "ppo.minibatch_size=128", "ppo.epochs=2", "ppo.eval_interval=256", "ppo.eval_steps=40",
         "render.frames_every=4", "render.size=[64,64]"]
# For runs whose figures no test reads: the tracking plots and the GIF's rendered frames cost a small
# run more than its training (the metrics are the same without them).
NO_FIGURES = ["plots=false", "render.gif=false", "render.mp4=false"]


def run_job(job: str, *overrides: str, check: bool = True) -> subprocess.CompletedProcess:
    env = dict(os.environ)
    proc = job_process.run([sys.executable, "-m", f"aslexp.jobs.{job}", *overrides], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=300)
    if check and proc.returncode != 0:
        raise AssertionError(proc.stderr[-3000:])
    return proc


def test_imitate_trains_writes_figures_and_resumes(tmp_path):
    out = tmp_path / "run"
    run_job("imitate", "motion=B", *SMALL, "ppo.total_steps=256", f"hydra.run.dir={out}")
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["motion"] == "B" and metrics["steps"] == 256
    assert 0.9 < metrics["baselines"]["lookahead"] and metrics["baselines"]["reference"] < metrics["baselines"]["lookahead"]
    for name in ("tracking.png", "tracking_baseline.png", "reward_curve.png", "imitation.gif", "progress.csv",
                 "checkpoints/last.pt", "checkpoints/best.pt", "run.json"):
        assert (out / name).is_file(), name
    assert json.loads((out / "run.json").read_text())["main_metric"]["name"] == "eval_reward"

    # Continue the same run to 512 steps in a new folder.
    out2 = tmp_path / "run2"
    run_job("imitate", "motion=B", *SMALL, *NO_FIGURES, "ppo.total_steps=512", f"+resume={out}",
            f"hydra.run.dir={out2}")
    resumed = json.loads((out2 / "metrics.json").read_text())
    assert resumed["steps"] == 512
    # Where its first 256 steps were trained: the run, its machine and device (results pages list them).
    origin, info = resumed["resumed_from"], json.loads((out / "run.json").read_text())
    assert origin["steps"] == 256 and origin["run"] == str(out) and origin["device"] == metrics["device"]
    assert origin["host"] == info["host"] and origin["torch"] == info["versions"]["torch"]
    assert "resumed_from" not in metrics
    # The new folder holds the whole curve: the first run's rows, then its own.
    first, whole = (list(csv.DictReader((d / "progress.csv").open())) for d in (out, out2))
    assert [(r["step"], r["eval_reward"]) for r in whole[:len(first)]] == [(r["step"], r["eval_reward"]) for r in first]
    assert len(whole) > len(first) and whole[-1]["step"] == "512"

    # A corrupt checkpoint: a clear error, the trained run untouched.
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"\x00garbage")
    proc = run_job("imitate", "motion=B", *SMALL, f"+resume={bad}", f"hydra.run.dir={tmp_path / 'run3'}",
                   check=False)
    assert proc.returncode == 2 and "corrupt" in proc.stderr  # bad input
    assert (out / "checkpoints" / "last.pt").stat().st_size > 1000


def test_a_sweep_re_evaluated_by_job_number_reports_what_training_under_that_protocol_would(tmp_path):
    """docs/imitation_upper_body.md's re-evaluation command, small: resume=SWEEP/${hydra:job.num}."""
    from aslexp.reports.report import learned

    def metrics(folder: Path) -> dict:
        return json.loads((folder / "metrics.json").read_text())

    sweep = tmp_path / "sweep"
    run_job("imitate", "-m", "motion=B", *SMALL, *NO_FIGURES, "ppo.total_steps=256", "seed=0,1",
            f"hydra.sweep.dir={sweep}")
    finished = {p: p.read_bytes() for p in sweep.rglob("*") if p.is_file()}

    # Resumed with no steps left, by job number: nothing trains; each run's policy under 3 phases.
    again = tmp_path / "eval3"
    run_job("imitate", "-m", "motion=B", *SMALL, *NO_FIGURES, "ppo.total_steps=256", "seed=0,1", "ppo.eval_episodes=3",
            f"resume={sweep}/${{hydra:job.num}}", f"hydra.sweep.dir={again}")
    for num in (0, 1):
        m = metrics(again / str(num))
        assert m["seed"] == num and m["stopped"] == "evaluated" and m["steps"] == 256 and learned(m)
        assert m["eval_protocol"]["phases"] == [0.0, 1 / 3, 2 / 3]
        assert m["last_eval"] != metrics(sweep / str(num))["last_eval"]  # 4 phases there

    # Exactly what a run trained with 3 phases reports: evaluation draws nothing from training's streams.
    direct = tmp_path / "direct"
    run_job("imitate", "motion=B", *SMALL, *NO_FIGURES, "ppo.total_steps=256", "seed=1", "ppo.eval_episodes=3",
            f"hydra.run.dir={direct}")
    assert metrics(again / "1")["last_eval"] == metrics(direct)["last_eval"]
    assert metrics(again / "1")["baselines"] == metrics(direct)["baselines"]

    # A misnumbered run folder is refused before any work, in one line; the sweep is never rewritten.
    proc = run_job("imitate", "motion=B", *SMALL, *NO_FIGURES, "ppo.total_steps=256", "seed=1", f"resume={sweep}/0",
                   f"hydra.run.dir={tmp_path / 'wrong'}", check=False)
    assert proc.returncode == 2 and "seed is 0, expected this run's 1" in proc.stderr, proc.stderr[-2000:]
    assert len(proc.stderr.strip().splitlines()) == 1 and not (tmp_path / "wrong" / "metrics.json").exists()
    assert {p: p.read_bytes() for p in sweep.rglob("*") if p.is_file()} == finished


def _last_log_line(run_dir: Path) -> str:
    return (run_dir / "tune_pd.log").read_text().strip().splitlines()[-1]


def test_tune_pd_sweep_on_a_letter_never_ends_below_the_default_controller(tmp_path):
    """A few trials on letter A: the controller's own gains are the first trial and the objective is
    1 - the imitation reward, so the sweep's best scores at least the default controller's reward
    (each trial's metrics hold both, measured the same way)."""
    sweep = tmp_path / "sweep"
    run_job("tune_pd", "-m", "+sweeps=pd_gains_1", "hydra.sweeper.n_trials=4", "tuning.motion=motions/hand/A.txt",
            f"hydra.sweep.dir={sweep}")
    trials = sorted((p for p in sweep.iterdir() if p.is_dir() and (p / "metrics.json").is_file()),
                    key=lambda p: int(p.name))
    assert [p.name for p in trials] == ["0", "1", "2", "3"]
    # One objective value at the end of each trial, no intermediate report: a pruner never
    # discards a finished trial (past the median pruner's 5 startup trials it would).
    study = optuna.load_study(study_name="pd_gains_1", storage=open_storage(str(sweep / "optuna.journal")))
    assert [t.state for t in study.trials] == [optuna.trial.TrialState.COMPLETE] * 4
    assert all(t.intermediate_values == {} for t in study.trials)
    assert study.trials[0].params == {"tuning.kp": 0.22, "tuning.kd": 0.87}  # conf/controller/thesis.yaml
    rows = [json.loads((trial / "metrics.json").read_text()) for trial in trials]
    for trial, metrics in zip(trials, rows):
        gains = metrics["gains"]["default"]
        assert 0 <= gains["kp"] <= 1 and 0 <= gains["kd"] <= 1 and not metrics["diverged"]
        assert metrics["objective_kind"] == "reward" and metrics["objective"] == pytest.approx(1 - metrics["reward"])
        assert metrics["default_controller"] == "thesis" and metrics["default_reward"] == rows[0]["default_reward"]
        assert metrics["reward_vs_default"] == pytest.approx(metrics["reward"] - metrics["default_reward"])
        assert f"reward {metrics['reward']:.4f}; default controller thesis" in _last_log_line(trial)
        assert (trial / "controller.yaml").is_file()
    assert rows[0]["reward"] == rows[0]["default_reward"] > 0.9  # the first trial is the default controller
    best = rows[study.best_trial.number]
    assert best["reward"] == max(m["reward"] for m in rows) >= best["default_reward"] - 5e-4


def test_tune_pd_with_thesis_gains_tracks_well(tmp_path):
    run_job("tune_pd", "tuning.motion=motions/hand/tuning_motion.txt", f"hydra.run.dir={tmp_path / 'thesis'}")
    metrics = json.loads((tmp_path / "thesis" / "metrics.json").read_text())
    assert metrics["pose_error"] < 0.05 and not metrics["diverged"]
    assert metrics["reward"] == metrics["default_reward"] and metrics["reward_vs_default"] == 0
    assert _last_log_line(tmp_path / "thesis").endswith("AT the default controller's")


def test_tune_pd_says_when_tuned_gains_score_below_the_default_controller(tmp_path):
    """On letter A the unweighted objective (radians plus rad/s) prefers kp 0.13, kd 0.855 to the
    thesis gains while the reward ranks them lower; the run says so, whatever its objective."""
    run_job("tune_pd", "tuning.motion=motions/hand/A.txt", "tuning.objective=mean_abs", "tuning.kp=0.13",
            "tuning.kd=0.855", f"hydra.run.dir={tmp_path}")
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["objective"] < metrics["default_objective"]  # mean_abs: better ...
    assert metrics["reward"] < metrics["default_reward"] - 0.005  # ... the reward: worse
    assert metrics["objective_kind"] == "mean_abs"
    assert _last_log_line(tmp_path).endswith(f"BELOW the default controller's by {-metrics['reward_vs_default']:.4f}")
    assert f"reward {metrics['default_reward']:.4f}" in (tmp_path / "controller.yaml").read_text().splitlines()[0]


def test_tune_pd_measures_a_controller_with_target_options(tmp_path):
    # The reference-velocity controller builds its own targets from the reference (it needs a
    # residual action): tune_pd runs it with no correction and sweeps its velocity scale.
    run_job("tune_pd", "controller=reference_velocity", "tuning.kp=0.4", "tuning.kd=1.0",
            "tuning.velocity_scale=0.8", "tuning.random.seconds=1.0", f"hydra.run.dir={tmp_path / 'rv'}")
    run_job("tune_pd", "tuning.random.seconds=1.0", f"hydra.run.dir={tmp_path / 'thesis'}")
    rv = json.loads((tmp_path / "rv" / "metrics.json").read_text())
    thesis = json.loads((tmp_path / "thesis" / "metrics.json").read_text())
    assert rv["controller_options"] and not thesis["controller_options"]
    assert rv["velocity_scale"] == 0.8 and rv["gains"]["default"]["kp"] == 0.4
    # Same random reference: feeding the reference velocity tracks it far better than held targets.
    assert rv["objective"] < 0.5 * thesis["objective"] and not rv["diverged"]
    saved = (tmp_path / "rv" / "controller.yaml").read_text()
    assert "velocity_scale: 0.8" in saved and "target_rate: physics" in saved


def test_tune_pd_thesis_objective_is_eq_5_14(tmp_path, motion_a, data_root):
    """Eq. 5.14 on the hand: per step, the sum over joints of squared pose errors plus that of squared
    velocity errors, averaged over the steps; recomputed here from the joint states."""
    import numpy as np

    from aslexp.envs.imitation import ImitationEnv
    from aslexp.envs.tracking import pd_tracking_error

    env = ImitationEnv(motion_a, env={"reference_state_init": False}, data_root=data_root)
    result = pd_tracking_error(env, 60, 1, objective="thesis")
    env.reset(options={"time": 0.0})
    pose, vel = [], []
    for _ in range(60):
        env.step(env.reference_action(1))
        q, qd = env.sim.joint_state()
        pose.append(np.sum((q - env.reference.joints(env.time)) ** 2))
        vel.append(np.sum((qd - env.reference.joint_velocities(env.time)) ** 2))
    assert result["pose_error"] == pytest.approx(np.mean(pose), rel=1e-9)
    assert result["velocity_error"] == pytest.approx(np.mean(vel), rel=1e-9)
    assert result["objective"] == pytest.approx(np.mean(pose) + np.mean(vel), rel=1e-9)
    run_job("tune_pd", "tuning.objective=thesis", "tuning.random.seconds=1.0", f"hydra.run.dir={tmp_path}")
    metrics = json.loads((tmp_path / "metrics.json").read_text())
    assert metrics["objective_kind"] == "thesis"
    assert metrics["objective"] == pytest.approx(metrics["pose_error"] + metrics["velocity_error"])


def test_a_run_that_trains_nothing_measures_baselines_only_in_a_folder_named_by_engine(tmp_path):
    """Ppo.total_steps=0 starts no worker processes, keeps the untrained policy's
    level as such (never the run's result or main metric), and the folder name says the body and engine."""
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(ROOT.parent / "shared" / "data")}
    proc = job_process.run([sys.executable, "-m", "aslexp.jobs.imitate", "motion=B", "ppo.total_steps=0",
                           "ppo.num_envs=4", "ppo.vector_env=workers", "ppo.eval_steps=20", "plots=false",
                           "render.gif=false", "render.mp4=false"], cwd=tmp_path, env=env, capture_output=True,
                          text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    [run] = (tmp_path / "outputs" / "imitate").iterdir()
    assert run.name.endswith("_B_hand15_pybullet_s0")
    log = (run / "imitate.log").read_text()
    assert "worker process" not in log and "nothing trained (ppo.total_steps=0)" in log
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["last_eval"] is None and metrics["best_eval"] is None and metrics["stopped"] == "no_training"
    assert 0 <= metrics["untrained_eval"] <= 1 and set(metrics["baselines"]) >= {"reference", "lookahead"}
    info = json.loads((run / "run.json").read_text())
    assert info["status"] == "completed" and info["main_metric"] is None
