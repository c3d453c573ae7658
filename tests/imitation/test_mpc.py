"""Sampling-based MPC: it plans from the simulator's own state, improves on its
nominal (the controller alone), and what it plans scores the same in the environment."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest
import job_process

from aslexp.control.mpc import PlannerSpec, SamplingPlanner, evaluate_planner, plan_episode
from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.batched import BatchedImitationEnv
from aslexp.envs.imitation import ImitationEnv

TRACKING = {"control_hz": 30, "action_mode": "residual", "residual_range": 0.2, "reference_state_init": False,
            "early_termination": {"min_reward": None}}


@pytest.fixture
def setup(data_root):
    # letter A, 30 Hz, the tracking PD (aslexp's best no-learning controller) under the thesis reward
    return ImitationSetup.from_groups(data_root / "motions/hand/A.txt", "hand15", "reference_velocity_tuned",
                                      "hand_thesis", TRACKING, "mujoco", data_root=data_root)


def test_mpc_improves_on_its_own_nominal_on_a_letter(setup):
    steps = 30
    nominal = evaluate_planner(PlannerSpec(samples=3, noise=1e-12), setup, (0.0,), steps)
    planned = evaluate_planner(PlannerSpec(horizon=4, samples=32, noise=0.025), setup, (0.0,), steps)
    env = ImitationEnv.from_setup(setup)  # the controller alone, in the single environment
    env.reset(options={"time": 0.0})
    alone = np.mean([env.step(np.zeros(env.action_space.shape))[1] for _ in range(steps)])
    env.close()
    assert nominal["reward"] == pytest.approx(alone, abs=1e-9)  # a zero-noise plan is the controller
    assert planned["reward"] > nominal["reward"] and planned["diverged"] == 0
    assert planned["rollout_steps_per_step"] == 32 * 4 and planned["seconds_per_step"] > 0


def test_what_the_planner_plans_scores_the_same_in_the_environment(setup):
    planner = SamplingPlanner(PlannerSpec(horizon=3, samples=8, noise=0.05, method="mppi"), setup)
    body = BatchedImitationEnv.from_setup(1, setup)
    episode = plan_episode(planner, body, 0.4, 12)
    planner.close(), body.close()
    env = ImitationEnv.from_setup(setup)
    env.reset(options={"time": 0.4})
    replayed = [env.step(a.astype(np.float32))[1] for a in episode.actions]
    env.close()
    # float32 actions in the env, float64 in the planner's batch: equal to rounding
    np.testing.assert_allclose(replayed, episode.rewards, atol=1e-6)
    assert any(np.abs(a).max() > 0 for a in episode.actions)  # it did correct the controller


def test_the_planner_refuses_what_it_cannot_plan(setup):
    with pytest.raises(ValueError, match="needs env.action_mode residual"):
        SamplingPlanner(PlannerSpec(), setup.merged(env={"action_mode": "absolute"}))
    with pytest.raises(ValueError, match=r"planner.beam=3: unknown key"):
        PlannerSpec.parse({"beam": 3})
    with pytest.raises(ValueError, match="planner.method=ilqr: expected one of"):
        PlannerSpec.parse({"method": "ilqr"})
    with pytest.raises(ValueError, match="elites"):
        PlannerSpec.parse({"method": "cem", "samples": 4, "elites": 4})


def test_cem_runs_its_iterations(setup):
    result = evaluate_planner(PlannerSpec(method="cem", horizon=2, samples=6, elites=2, iterations=2), setup,
                              (0.0,), 4)
    assert result["rollout_steps_per_step"] == 6 * 2 * 2 and np.isfinite(result["reward"])


def test_the_imitate_job_scores_a_planner_beside_the_baselines(tmp_path):
    run = tmp_path / "run"
    done = job_process.run([sys.executable, "-m", "aslexp.cli", "imitate", "planner=mpc", "engine=mujoco",
                           "controller=reference_velocity_tuned", "env=residual", "reward=hand_thesis",
                           "ppo.eval_steps=6", "ppo.eval_episodes=2", "planner.samples=4", "planner.horizon=2",
                           "render.gif=false", "plots=false", f"hydra.run.dir={run}"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["stopped"] == "planned" and metrics["steps"] == 0
    planner = metrics["planner"]
    assert planner["method"] == "predictive_sampling" and planner["phases"] == [0.0, 0.5]
    assert metrics["last_eval"] == pytest.approx(planner["reward"], abs=1e-5)
    assert {"reference", "lookahead"} <= set(metrics["baselines"]) and 0 < planner["controller_alone"] <= 1
    # the thesis report reads the planner's run folder: the ceiling beside its controller, no learned cells
    from aslexp.reports.thesis_report import summarize_thesis

    row = summarize_thesis(tmp_path)["rows"][0]
    assert row["its controller alone"] == pytest.approx(planner["controller_alone"], abs=1e-4)
    assert "learned, last evaluation" not in row and row["s per control step"] > 0
    assert any(k.startswith("ceiling: mpc (predictive_sampling, horizon 2, 4 samples)") for k in row)
    assert (tmp_path / "ceiling_levels.png").is_file() and not (tmp_path / "thesis_curves.png").exists()


def test_the_results_page_shows_a_planner_s_runs_as_a_ceiling(tmp_path):
    """A planner's run folder on the results page: the ceiling column beside the baselines, the learned
    cell saying nothing was trained, and its rows as a ceiling of another entry (options.ceiling_folders)."""
    from aslexp.results.render import render_entry
    from aslexp.results.snapshots import build_snapshot

    run = tmp_path / "planned" / "0"
    done = job_process.run([sys.executable, "-m", "aslexp.cli", "imitate", "planner=mpc", "engine=mujoco", "motion=B",
                           "controller=reference_velocity_tuned", "env=residual", "reward=hand_thesis",
                           "ppo.eval_steps=4", "ppo.eval_episodes=1", "planner.samples=3", "planner.horizon=1",
                           "planner.knots=1", "render.gif=false", "plots=false", f"hydra.run.dir={run}"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    entry = {"id": "x", "report": "thesis", "title": "t", "beside": "aslexp headline", "thesis": {},
             "overlay": "letters_mpc", "command": "aslexp imitate -m experiment=letters_mpc", "engine": "mujoco",
             "reward": "hand_thesis", "options": {"row_name": "letter"}, "runs": [{"folders": ["planned"]}],
             "earlier": {"link": "docs/imitation.md", "section": "s"}}
    snapshot = build_snapshot(entry, tmp_path)
    ceiling = snapshot["rows"][0]["ceiling"]
    assert ceiling["n"] == 1 and ceiling["label"].startswith("MPC (predictive sampling, horizon 1, 3 samples) on ")
    page = "\n".join(render_entry(entry, snapshot))
    assert "| ceiling: MPC (predictive sampling" in page and "nothing trained: a planner's ceiling" in page
    assert "policy: none: model-predictive control" not in page  # no thesis setting named: no differences
    # another entry's rows (here a run that measured its baselines only) take the ceiling of the
    # planner's folder, motion by motion
    plain = tmp_path / "plain" / "0"
    done = job_process.run([sys.executable, "-m", "aslexp.cli", "imitate", "engine=mujoco", "motion=B",
                           "reward=hand_thesis", "ppo.total_steps=0", "ppo.eval_steps=4", "render.gif=false",
                           "plots=false", f"hydra.run.dir={plain}"], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    other = {**entry, "runs": [{"folders": ["plain"]}], "options": {"ceiling_folders": ["planned"]}}
    row = build_snapshot(other, tmp_path)["rows"][0]
    assert row["ceiling"] == ceiling and row["learned"]["mean"] is None
    alone = build_snapshot({**other, "options": {}}, tmp_path)
    assert "ceiling" not in alone["rows"][0]


@pytest.mark.parametrize("overlay, body, controller", [("signs_mpc", "base: pinned", "upper_body_reference_velocity"),
                                                      ("signs_mpc_standing", "base: free", "upper_body_thesis")])
def test_the_signs_ceiling_plans_on_the_upper_body_pinned_and_standing(tmp_path, overlay, body, controller):
    """experiment=signs_mpc (pinned) and signs_mpc_standing (a fall ends an episode), tiny: the planner
    drives the upper body (MuJoCo) on its controller and is scored beside that controller alone under
    the same protocol; no episode blows up, and falls are counted."""
    run = tmp_path / "run"
    done = job_process.run([sys.executable, "-m", "aslexp.cli", "imitate", f"experiment={overlay}", "motion='69546'",
                           "ppo.eval_steps=6", "ppo.eval_phases=[0.0]", "planner.samples=4", "planner.horizon=2",
                           "report.baselines=[]", "plots=false", f"hydra.run.dir={run}"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    planner = metrics["planner"]
    assert planner["name"] == "mpc" and planner["seconds_per_step"] > 0 and metrics["last_eval_diverged"] == 0
    assert 0 < metrics["last_eval"] <= 1 and 0 < planner["controller_alone"] <= 1
    composed = (run / ".hydra" / "config.yaml").read_text()
    assert body in composed and f"name: {controller}\n" in composed
    assert planner["fell"] == 0 and ("fall: true" in composed) == (overlay == "signs_mpc_standing")
