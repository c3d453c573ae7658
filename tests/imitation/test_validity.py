"""Numbers that mean what they say: both engines share PyBullet's joint-speed clamp, so a
stable episode never ends as "diverged"; a simulation that really blows up does, and is counted in
the evaluation, the counters and the run's metrics; a looping reference's seam gives no velocity
spike; the thesis' PPO settings map actions as SB3 does; baselines run under the learned policy's
evaluation protocol and every score also under the authors' code weights."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from aslexp.envs.baselines import Baseline, no_learning_baselines
from aslexp.compose import resolve_group
from aslexp.envs.imitation import ImitationEnv
from aslexp.rl.evaluate import evaluate_phases, reference_policy
from aslexp.rl.ppo import PPOConfig, agent_for_spaces
from aslexp.envs.assembly import ImitationSetup
from aslexp.sim.engine import EngineSpec

from .test_jobs import run_job

TRACKING_240 = dict(controller="reference_velocity_tuned", reward="hand_thesis",
                    env={"physics_hz": 240, "control_hz": 240, "action_mode": "residual",
                         "reference_state_init": False, "early_termination": {"min_reward": None}})


def test_mujoco_clamps_joint_speed_as_pybullet_and_a_stable_episode_never_ends_as_diverged(motion_a):
    # aslexp's reference-velocity PD at 240 Hz drives A's joints past 100 rad/s at the reference's
    # loop seam (1.2 s): PyBullet clamps it; MuJoCo now does the same, and the episode runs on.
    steps = 360  # 1.5 s: across the seam at step 288
    rewards = {}
    for engine in ("pybullet", "mujoco"):
        env = ImitationEnv(motion_a, engine=engine, **TRACKING_240)
        summary = evaluate_phases(env, reference_policy(1), steps, (0.0,))
        assert summary.diverged == 0 and summary.ended_early == 0, engine
        assert env.counters.get("diverged", 0) == 0
        _, qd = env.sim.joint_state()
        assert np.max(np.abs(qd)) <= 100.0 + 1e-9
        rewards[engine] = summary.mean_reward
        if engine == "mujoco":
            assert env.sim.body.clamped_steps > 0  # the seam's transient, clamped
        env.close()
    assert rewards["mujoco"] == pytest.approx(rewards["pybullet"], abs=0.03)
    assert rewards["mujoco"] > 0.9


def test_without_the_clamp_mujoco_runs_faster_than_pybullet_can(motion_a):
    env = ImitationEnv(motion_a, engine={"name": "mujoco", "joint_speed_limit": None}, **TRACKING_240)
    env.reset(options={"phase": 0.0})
    fastest = 0.0
    for _ in range(300):
        env.step(env.reference_action(1))
        fastest = max(fastest, float(np.max(np.abs(env.sim.joint_state()[1]))))
    assert fastest > 100.0  # the transient PyBullet's clamp absorbs; below the 1,000 rad/s divergence bound
    assert env.counters.get("diverged", 0) == 0
    env.close()


@pytest.mark.parametrize("limit", [100.0, None], ids=["clamped", "unclamped"])
def test_a_real_divergence_ends_the_episode_and_is_counted(motion_a, limit):
    # Explicit Euler, no damping, a stiffness of 1e6: the simulation blows up. With the clamp the
    # state stays finite (every speed clipped to 100 rad/s), so the guard reads the speed before the
    # clamp: a blow-up is never hidden by it.
    env = ImitationEnv(motion_a, engine={"name": "mujoco", "integrator": "Euler", "joint_speed_limit": limit},
                       reward="hand_thesis", env="hand_thesis",
                       controller={"physical_groups": {"default": {"kp": 1e6, "kd": 0.0}}})
    summary = evaluate_phases(env, reference_policy(1), 240, (0.0, 0.5))
    assert summary.diverged == 2 and summary.ended_early == 2
    assert env.counters["diverged"] == 2
    assert summary.mean_reward < 0.1  # the steps after the blow-up score nothing
    env.close()


def test_the_engine_config_refuses_a_bad_speed_limit():
    assert EngineSpec.parse({"name": "mujoco"}).options.joint_speed_limit == 100.0
    assert EngineSpec.parse({"name": "mujoco", "joint_speed_limit": None}).options.joint_speed_limit is None
    with pytest.raises(ValueError, match="engine.joint_speed_limit=0: expected null or a positive number"):
        EngineSpec.parse({"name": "mujoco", "joint_speed_limit": 0})


def test_the_loop_seam_of_a_wrapping_reference_gives_no_velocity_spike(data_root):
    # The letters do not close their loop (A's last frame is up to 1.66 rad from its first): the
    # positions jump at the seam, but the reference velocity is each frame interval's own slope
    # (DeepMimic's cycle handling), never a difference taken across the jump.
    env = ImitationEnv(data_root / "motions/hand/A.txt", env="hand_thesis")
    reference, motion = env.reference, env.reference.motion
    interior = np.max(np.abs(np.diff(motion.frames, axis=0) / motion.dt[:-1, None]))
    seam = motion.duration
    times = seam + np.linspace(-0.05, 0.05, 241)
    velocities = reference.joint_velocities_many(times)
    assert np.max(np.abs(velocities)) <= interior + 1e-9
    before, after = reference.joint_velocities(seam - 1e-6), reference.joint_velocities(seam + 1e-6)
    np.testing.assert_allclose(before, reference._joint_velocity[motion.num_frames - 2])
    np.testing.assert_allclose(after, reference._joint_velocity[0])
    assert np.max(np.abs(reference.joints(seam - 1e-6) - reference.joints(seam + 1e-6))) > 1.0  # the jump is real
    env.close()


def test_thesis_ppo_settings_map_actions_as_sb3_and_aslexp_settings_keep_the_box(motion_a):
    env = ImitationEnv(motion_a, env="hand_thesis", reward="hand_thesis")
    low, high = env.action_space.low, env.action_space.high
    assert np.all(low <= 0.0) and np.any(high > 1.0)  # the hand's joints: 0 is open, the box centre is not
    for name, mapping in (("hand_thesis", "sb3"), ("authors_script", "sb3"), ("upper_body_run1", "sb3"),
                          ("upper_body_run2", "sb3"), ("fast", "box"), ("scratch", "box"), ("quick", "box")):
        values = {**resolve_group("ppo", "base"), **resolve_group("ppo", name)}
        values.pop("defaults", None)
        assert PPOConfig.parse(values).action_mapping == mapping, name
    config = PPOConfig.parse({**{k: v for k, v in resolve_group("ppo", "hand_thesis").items() if k != "defaults"},
                                  "device": "cpu"})
    torch.manual_seed(0)
    agent = agent_for_spaces(config.model, env.observation_space, env.action_space)
    obs, _ = env.reset(options={"phase": 0.0})
    sb3 = agent.act(obs)
    assert np.all(sb3 >= low - 1e-6) and np.all(sb3 <= high + 1e-6)
    assert np.mean(np.abs(sb3)) < 0.35  # around 0 rad, clipped: an open hand
    sample = torch.tensor([[-5.0] * len(low), [5.0] * len(low)])
    np.testing.assert_allclose(agent.to_env_action(sample).numpy(), np.stack([low, high]), atol=1e-6)
    boxed = agent_for_spaces(PPOConfig(device="cpu", hidden_sizes=(8,)).model, env.observation_space, env.action_space)
    np.testing.assert_allclose(boxed.to_env_action(torch.zeros(1, len(low))).numpy()[0], (low + high) / 2, atol=1e-6)
    env.close()


def test_baselines_run_from_the_evaluation_phases_and_score_under_every_reward(motion_a):
    setup = ImitationSetup.from_groups(motion_a, "hand15", "thesis", "hand_thesis", "default",
                                       score_rewards={"hand_code": "hand_code"})
    rows = no_learning_baselines(setup, [Baseline(label="thesis PD", controller="thesis")], seconds=1.0,
                                 phases=(0.0, 0.5))
    assert [r["lookahead"] for r in rows] == [0, 1]
    for row in rows:
        assert row["phases"] == [0.0, 0.5] and len(row["per_phase"]) == 2
        assert row["reward"] == pytest.approx(np.mean(row["per_phase"]))
        assert row["diverged"] == 0 and row["steps"] == row["planned_steps"] == 30
        # the same trajectory under the authors' code weights (THESIS.md 10.1) scores higher on the hand
        assert row["scores"]["hand_code"] > row["reward"]
    single = no_learning_baselines(ImitationSetup.from_groups(motion_a, "hand15", "thesis", "hand_thesis", "default"),
                                   [Baseline(label="x", controller="thesis")], seconds=1.0, phases=(0.5,))
    assert single[0]["reward"] == pytest.approx(rows[0]["per_phase"][1])


def test_an_open_hand_scores_as_the_issue_measured_under_both_reward_scales(motion_a):
    # THESIS.md G9: an open hand (all targets 0) scores 0.278 under Table 5.2 and 0.379 under the code.
    env = ImitationEnv(motion_a, env="hand_thesis", reward="hand_thesis", score_rewards={"hand_code": "hand_code"})
    summary = evaluate_phases(env, lambda obs, e: np.zeros(e.action_space.shape, np.float32), 2400, (0.0,))
    assert summary.mean_reward == pytest.approx(0.278, abs=0.01)  # PyBullet here; the issue's reading: MuJoCo
    assert summary.scores["hand_code"] == pytest.approx(0.379, abs=0.01)
    assert summary.scores["hand_code"] - summary.mean_reward > 0.09
    env.close()


def test_the_thesis_overlay_writes_its_baselines_untrained_level_and_code_scale_into_the_run(tmp_path, data_root):
    run_dir = tmp_path / "run"
    run_job("imitate", "experiment=letters_thesis", "engine=mujoco", "motion=B", "ppo.total_steps=2048",
            "ppo.steps_per_rollout=2048", "ppo.num_envs=8", "ppo.eval_steps=48", "ppo.eval_interval=2048",
            "ppo.hidden_sizes=[32,32]", "plots=false", "render.gif=false", "render.mp4=false",
            f"data_root={data_root}", f"hydra.run.dir={run_dir}")
    metrics = json.loads((run_dir / "metrics.json").read_text())
    assert metrics["last_eval_diverged"] == 0 and metrics["counters"].get("diverged", 0) == 0
    assert set(metrics["last_eval_scores"]) == {"hand_code"}
    labels = {(r["label"], r["lookahead"]) for r in metrics["report_baselines"]}
    assert len(labels) == 6  # Table 5.1's PD at 240 and 30 Hz (2 lookaheads each), aslexp's at 30 and 240 Hz
    for row in metrics["report_baselines"]:
        assert row["phases"] == metrics["eval_protocol"]["phases"]
        assert row["seconds"] == pytest.approx(48 / 240)
        assert "hand_code" in row["scores"] and row["diverged"] == 0
    progress = (run_dir / "progress.csv").read_text().splitlines()
    header = progress[0].split(",")
    first = dict(zip(header, progress[1].split(",")))
    assert first["step"] == "0" and first["eval_reward"]  # the untrained level, the curve's first point
    assert metrics["last_eval"] == pytest.approx(float(dict(zip(header, progress[-1].split(",")))["eval_reward"]))


def test_a_run_whose_last_evaluation_blew_up_exits_1_with_where_and_when_and_keeps_its_metrics(tmp_path):
    # the upper body on MuJoCo under the position-motor stand-in with a barely trained policy's
    # absolute targets. It used to end "last eval 0.0000", exit 0. (A run that trains nothing is
    # its baselines instead: tests/imitation/test_imitation_purposes.py.)
    run_dir = tmp_path / "run"
    proc = run_job("imitate", "motion='00433'", "body=upper_body", "engine=mujoco", "ppo.total_steps=64",
                   "ppo.steps_per_rollout=64", "ppo.minibatch_size=32", "ppo.epochs=1", "ppo.eval_interval=64",
                   "ppo.eval_steps=30", "ppo.eval_episodes=2", "plots=false", "render.gif=false", "render.mp4=false",
                   f"hydra.run.dir={run_dir}", check=False)
    assert proc.returncode == 1, proc.stderr[-2000:]
    [line] = [x for x in proc.stderr.splitlines() if x.startswith("aslexp imitate:")]
    assert "the simulation blew up in 2 of 2 evaluation episodes (first: joint " in line
    assert "is not a score" in line and "Try " in line
    metrics = json.loads((run_dir / "metrics.json").read_text())  # nothing computed is lost
    assert metrics["last_eval_diverged"] == 2 and metrics["last_eval_divergences"][0]["speed"] > 1000
    assert json.loads((run_dir / "run.json").read_text())["status"] == "failed"
