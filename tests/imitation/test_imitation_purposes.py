"""The imitation jobs by purpose, small: the default training starts at the best no-learning controller
and its last line says where it ended beside it; `aslexp evaluate` (perform on the policy's engine,
re-evaluate) and `aslexp plan` are jobs of their own on the imitate job's config, each run ending
with the same verdict line."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import job_process
import pytest

from aslexp import cli
from aslexp.jobs._imitation import LEVEL_TOLERANCE, last_line

ROOT = Path(__file__).resolve().parents[2]
# The default training (no env=, no ppo=: ppo=quick's network) on a tiny budget, its start evaluated.
TINY = ["ppo.total_steps=256", "ppo.steps_per_rollout=256", "ppo.minibatch_size=128", "ppo.epochs=1",
        "ppo.eval_interval=256", "ppo.eval_steps=40", "ppo.eval_at_start=true"]
NO_FIGURES = ["plots=false", "render.gif=false", "render.mp4=false"]


def aslexp(cwd: Path, data_root: Path, job: str, *overrides: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg"}
    proc = job_process.run([sys.executable, "-m", "aslexp.cli", job, *overrides], cwd=cwd, env=env,
                           capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return proc


def metrics_of(run: Path) -> dict:
    return json.loads((run / "metrics.json").read_text())


def last_logged(run: Path, job: str) -> str:
    """The job log's last line, without its time stamp and logger name."""
    return (run / f"{job}.log").read_text().strip().splitlines()[-1].split(" - ", 1)[1]


@pytest.fixture(scope="module")
def trained(tmp_path_factory, data_root) -> Path:
    run = tmp_path_factory.mktemp("default_training") / "run"
    aslexp(ROOT, data_root, "imitate", "motion=B", *TINY, *NO_FIGURES, f"hydra.run.dir={run}")
    return run


def test_the_default_training_starts_at_the_best_no_learning_controller_and_says_where_it_ended(trained):
    metrics = metrics_of(trained)
    config = (trained / ".hydra" / "config.yaml").read_text()
    assert "action_mode: residual" in config  # a correction on the body's controller
    best = metrics["best_baseline"]
    assert best["reward"] == pytest.approx(max(metrics["baselines"].values()), abs=1e-5)
    assert best["reward"] == pytest.approx(metrics["baselines"]["lookahead"], abs=1e-5)
    # The untrained policy (step 0) is the controller alone, within a small tolerance.
    assert metrics["untrained_eval"] == pytest.approx(best["reward"], abs=0.005)
    line = last_logged(trained, "imitate")
    assert line == last_line(metrics) and "best no-learning baseline" in line and best["name"] in line
    below = metrics["last_eval"] < best["reward"] - LEVEL_TOLERANCE
    assert ("BELOW the best no-learning baseline" in line) == below
    assert f"untrained {metrics['untrained_eval']:.4f}" in line


def test_a_policy_performs_on_its_own_engine_unless_told_and_the_line_says_which(trained, data_root, tmp_path):
    aslexp(tmp_path, data_root, "evaluate", "motion=C", f"policy={trained}", "ppo.eval_steps=20", *NO_FIGURES)
    [run] = (tmp_path / "outputs" / "evaluate").iterdir()  # the evaluate job's own folders
    performed = metrics_of(run)
    assert performed["stopped"] == "performed" and performed["steps"] == 0
    assert performed["policy"]["engine"] == "pybullet" and performed["policy"]["engine_chosen_by"] == "the policy's run"
    line = last_logged(run, "evaluate")
    assert line == last_line(performed) and "on pybullet, the policy's run" in line
    assert performed["best_baseline"]["name"] in line

    told = tmp_path / "told"
    aslexp(ROOT, data_root, "evaluate", "motion=C", f"policy={trained}", "engine=mujoco", "ppo.eval_steps=20",
           *NO_FIGURES, f"hydra.run.dir={told}")
    on_mujoco = metrics_of(told)
    assert on_mujoco["policy"]["engine"] == "mujoco" and on_mujoco["policy"]["trained_on_engine"] == "pybullet"
    assert "on mujoco, this command" in last_logged(told, "evaluate")


def test_evaluate_re_evaluates_a_run_as_imitate_does(trained, data_root, tmp_path):
    again = tmp_path / "again"
    aslexp(ROOT, data_root, "evaluate", "motion=B", f"resume={trained}", "ppo.eval_steps=40", *NO_FIGURES,
           f"hydra.run.dir={again}")
    evaluated, original = metrics_of(again), metrics_of(trained)
    assert evaluated["stopped"] == "evaluated" and evaluated["steps"] == original["steps"]
    assert evaluated["last_eval"] == original["last_eval"]  # the same policy under the same protocol
    assert evaluated["baselines"] == original["baselines"]
    assert "re-evaluated policy" in last_logged(again, "evaluate")


def test_the_best_baseline_is_the_controller_the_run_rides_on_when_it_is_stronger(data_root, tmp_path):
    """With a controller that has target options, the run's own controller alone is measured beside the
    thesis PD's baselines; it is the stronger one here, and it is what the verdict names."""
    run = tmp_path / "run"
    aslexp(ROOT, data_root, "evaluate", "motion=B", "controller=reference_velocity_tuned", "env=residual_velocity",
           "ppo.eval_steps=40", *NO_FIGURES, f"hydra.run.dir={run}")
    metrics = metrics_of(run)
    base = metrics["baselines"]
    assert base["reference_velocity_pd"] > base["lookahead"]
    assert metrics["best_baseline"]["reward"] == pytest.approx(base["reference_velocity_pd"], abs=1e-5)
    assert metrics["untrained_eval"] == pytest.approx(base["reference_velocity_pd"], abs=0.005)
    line = last_logged(run, "evaluate")
    assert "nothing trained" in line and "the run's controller alone" in line


def test_plan_is_a_job_of_its_own_with_the_planner_chosen(data_root, tmp_path):
    aslexp(tmp_path, data_root, "plan", "engine=mujoco", "motion=B", "controller=reference_velocity_tuned",
           "env=residual", "reward=hand_thesis", "ppo.eval_steps=4", "ppo.eval_episodes=1", "planner.samples=3",
           "planner.horizon=1", "planner.knots=1", *NO_FIGURES)
    [run] = (tmp_path / "outputs" / "plan").iterdir()
    metrics = metrics_of(run)
    assert metrics["stopped"] == "planned" and metrics["planner"]["name"] == "mpc"
    line = last_logged(run, "plan")
    assert line == last_line(metrics) and line.startswith("motion B: planner mpc")


def test_the_new_jobs_are_listed_with_the_imitate_job_s_groups():
    assert {"evaluate", "plan"} <= set(cli._jobs())
    assert cli._job_keys("evaluate") == cli._job_keys("imitate") == cli._job_keys("plan")
    plan_help = cli.job_help("plan")
    assert "\n  planner        mpc" in plan_help and "letters_mpc" in plan_help
    assert "\n  planner        (none) | mpc" in cli.job_help("evaluate")


def test_a_baselines_run_whose_untrained_policy_blows_up_is_its_baselines_not_an_error(data_root, tmp_path):
    """The upper body's default env (absolute targets) on MuJoCo: a fresh policy's targets, the joint
    ranges' centres, blow up the fingers' stand-in motors in the first control step, where the
    controller's baselines run; nothing was trained, so the run is its baselines (exit 0), and the
    untrained policy's blow-up is recorded and said, never a score. The residual env starts there."""
    run = tmp_path / "run"
    aslexp(ROOT, data_root, "evaluate", "motion='00433'", "body=upper_body", "engine=mujoco", "ppo.eval_steps=20",
           *NO_FIGURES, f"hydra.run.dir={run}")
    metrics = metrics_of(run)
    assert metrics["untrained_eval"] is None and metrics["untrained_eval_diverged"] == len(metrics["eval_protocol"]["phases"])
    assert "last_eval_diverged" not in metrics and metrics["best_baseline"]["reward"] > 0.5
    line = last_logged(run, "evaluate")
    assert "nothing trained" in line and "the untrained policy's simulation blew up in" in line
    residual = tmp_path / "residual"
    aslexp(ROOT, data_root, "evaluate", "motion='00433'", "body=upper_body", "engine=mujoco", "env=upper_body_residual",
           "ppo.eval_steps=20", *NO_FIGURES, f"hydra.run.dir={residual}")
    assert metrics_of(residual)["untrained_eval_diverged"] == 0 and metrics_of(residual)["untrained_eval"] > 0.5
