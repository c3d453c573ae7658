"""The MuJoCo engine beside PyBullet: both bodies load, the reward is shared, the batched environment
is N single environments, PPO trains and resumes on it, and every imitation overlay takes engine=."""

from __future__ import annotations

import functools
import json
import subprocess
import sys

import numpy as np
import pytest
from hydra import compose, initialize_config_dir

from aslexp.envs.batched import BatchedImitationEnv
from aslexp.paths import CONF_DIR
from aslexp.envs.imitation import ImitationEnv
from aslexp.envs.upper_body import UpperBodyImitationEnv
from aslexp.sim.engine import EngineSpec

HAND = dict(env="default", reward="hand_thesis")
UPPER = dict(controller="upper_body_thesis", reward="upper_body_thesis", env="upper_body_thesis")


def pair(cls, motion, **kwargs):
    return cls(motion, engine="pybullet", **kwargs), cls(motion, engine="mujoco", **kwargs)


@pytest.mark.parametrize("cls, motion, kwargs", [
    (ImitationEnv, "motions/hand/A.txt", HAND),
    (UpperBodyImitationEnv, "motions/upper_body/00433.txt", dict(UPPER, body={"base": "pinned"})),
    (UpperBodyImitationEnv, "motions/upper_body/00433.txt", dict(UPPER, body={"base": "free"})),
    (UpperBodyImitationEnv, "motions/upper_body/00433.txt", {}),  # built model, position control, fixed base
], ids=["hand", "upper-pinned", "upper-free", "upper-built-fixed"])
def test_both_engines_load_both_bodies_and_see_the_same_pose_the_same_way(data_root, cls, motion, kwargs):
    pb, mj = pair(cls, data_root / motion, **kwargs)
    try:
        assert mj.sim.link_names == pb.sim.link_names
        assert mj.observation_space.shape == pb.observation_space.shape
        assert mj.action_space.shape == pb.action_space.shape
        # The same state teleported into both: joints, root, links and end effectors agree, and so
        # do the observation and the reward (the one ImitationReward, fed by either engine).
        for env in (pb, mj):
            env.reset(options={"time": 0.4})
        q_pb, _ = pb.sim.joint_state()
        q_mj, _ = mj.sim.joint_state()
        np.testing.assert_allclose(q_mj, q_pb, atol=1e-9)
        for a, b in zip(mj.sim.base_state()[:2], pb.sim.base_state()[:2]):
            np.testing.assert_allclose(a, b, atol=1e-6)
        links_pb, links_mj = pb.sim.link_states(), mj.sim.link_states()
        np.testing.assert_allclose(links_mj[:, 0:3], links_pb[:, 0:3], atol=1e-5)
        dots = np.abs(np.sum(links_mj[:, 3:7] * links_pb[:, 3:7], axis=1))
        np.testing.assert_allclose(dots, 1.0, atol=1e-6)
        np.testing.assert_allclose(mj.sim.end_effector_positions(), pb.sim.end_effector_positions(links_pb), atol=1e-5)
        sim_pb, sim_mj = pb._sim_snapshot(links_pb), mj._sim_snapshot(links_mj)
        ref = pb._reference_snapshot(pb.time)
        np.testing.assert_allclose(mj._reference_snapshot(mj.time).end_effectors, ref.end_effectors, atol=1e-5)
        r_pb, _, e_pb = pb.reward_fn(sim_pb, ref)
        r_mj, _, e_mj = mj.reward_fn(sim_mj, ref)
        assert r_mj == pytest.approx(r_pb, abs=1e-5)
        assert e_mj["pose"] == pytest.approx(e_pb["pose"], abs=1e-8)
        # and both engines step it
        for env in (pb, mj):
            _, reward, *_ = env.step(env.reference_action(1))
            assert 0.0 < reward <= 1.0
    finally:
        pb.close()
        mj.close()


def test_the_reward_of_a_batch_is_the_reward_of_each_state(data_root):
    env = ImitationEnv(data_root / "motions/hand/A.txt", engine="mujoco", **HAND)
    rng = np.random.default_rng(0)
    sims, refs = [], []
    for t in rng.uniform(0, env.reference.duration, 5):
        env.reset(options={"time": float(t)})
        env.step(rng.uniform(env.action_space.low, env.action_space.high).astype(np.float32))
        sims.append(env.last_sim_state)
        refs.append(env.last_reference_state)
    from aslexp.envs.reward import PoseSnapshot

    def stack(snapshots):
        return PoseSnapshot(*(np.stack([getattr(s, f) for s in snapshots]) for f in PoseSnapshot.__dataclass_fields__))

    total, terms, _ = env.reward_fn.many(stack(sims), stack(refs))
    for i, (s, r) in enumerate(zip(sims, refs)):
        one, one_terms, _ = env.reward_fn(s, r)
        assert total[i] == pytest.approx(one, abs=1e-12)
        assert {k: v[i] for k, v in terms.items()} == pytest.approx(one_terms, abs=1e-12)
    env.close()


@pytest.mark.parametrize("cls, motion, kwargs", [
    (ImitationEnv, "motions/hand/A.txt", HAND),
    (UpperBodyImitationEnv, "motions/upper_body/00433.txt", dict(UPPER, body={"base": "free"})),
], ids=["hand", "upper-free"])
def test_the_probes_read_what_a_probe_step_senses_bit_for_bit(data_root, cls, motion, kwargs):
    """body.read's forward stages in one mujoco.batch call give exactly the sensors a probe mj_step
    evaluates (before it integrates) from the same states, for a whole batch and for fewer rows."""
    import mujoco

    env = BatchedImitationEnv(6, data_root / motion, engine="mujoco", env_class=cls, **kwargs)
    env.reset(seed=0)
    rng = np.random.default_rng(1)
    for _ in range(3):
        env.step(rng.uniform(-1, 1, (6, env.single_action_space.shape[0])).astype(np.float32))
    body, states = env.body, env.states.copy()
    for model, tips_only in ((body.probe, False), (body.tip_probe, True)):
        for rows in (slice(None), slice(0, 2), slice(3, 4), slice(None)):
            expected = []
            for state in states[rows]:
                data = mujoco.MjData(model)
                mujoco.mj_setState(model, data, state[:body.physics_size], mujoco.mjtState.mjSTATE_FULLPHYSICS)
                data.mocap_pos[:] = state[body.slices["mocap_pos"]].reshape(-1, 3)
                data.mocap_quat[:] = state[body.slices["mocap_quat"]].reshape(-1, 4)
                mujoco.mj_step(model, data)  # sensors are evaluated before it integrates
                expected.append(data.sensordata.copy())
            np.testing.assert_array_equal(body.read(states[rows], tips_only=tips_only), np.stack(expected))
    env.close()


@pytest.mark.parametrize("env_name, kwargs", [
    ("hand_thesis", {"env": {"episode_steps": 100}}),  # random targets at 240 Hz: the speed clamp acts
    ("residual", {"env": {"normalize_actions": True, "early_termination": {"min_reward": 0.9, "patience": 2}}}),
    # the tracking PD: reference targets re-sampled every physics substep, reference velocities fed
    ("residual", {"env": {"early_termination": {"min_reward": 0.9, "patience": 2}},
                  "controller": "reference_velocity_tuned"}),
    ("residual_velocity", {"controller": "reference_velocity_tuned"}),  # and velocity-target corrections
], ids=["absolute-240Hz", "residual-normalized-early-end", "physics-rate-targets", "velocity-corrections"])
def test_a_batch_is_n_single_environments_step_for_step(data_root, env_name, kwargs):
    n, motion = 3, data_root / "motions/hand/C.txt"
    env_cfg = kwargs.get("env", env_name)
    if isinstance(env_cfg, dict):
        from aslexp.compose import deep_merge, resolve_group

        env_cfg = deep_merge(resolve_group("env", env_name), env_cfg)
    controller = kwargs.get("controller")
    singles = [ImitationEnv(motion, engine="mujoco", reward="hand_thesis", env=env_cfg, controller=controller)
               for _ in range(n)]
    batch = BatchedImitationEnv(n, motion, engine="mujoco", reward="hand_thesis", env=env_cfg, controller=controller)
    seeds = [7, 8, 9]
    obs = np.stack([e.reset(seed=s)[0] for e, s in zip(singles, seeds)])
    batch_obs, _ = batch.reset(seed=seeds)
    np.testing.assert_array_equal(batch_obs, obs)
    rng = np.random.default_rng(1)
    space = batch.single_action_space
    ends = 0
    for t in range(360 if env_name == "hand_thesis" else 120):
        actions = rng.uniform(space.low, space.high, size=(n, space.shape[0])).astype(np.float32)
        if t == 5:
            actions[1, 0] = np.nan  # a NaN action ends that episode, unstepped, in both
        results = [e.step(a) for e, a in zip(singles, actions)]
        b_obs, b_reward, b_term, b_trunc, info = batch.step(actions)
        for i, (o, r, term, trunc, _) in enumerate(results):
            assert (b_term[i], b_trunc[i]) == (term, trunc), (t, i)
            assert b_reward[i] == pytest.approx(r, abs=1e-12)
            if term or trunc:  # same-step autoreset: the last observation in info, a new episode returned
                ends += 1
                np.testing.assert_array_equal(info["final_obs"][i], o)
                o, _ = singles[i].reset()
            np.testing.assert_array_equal(b_obs[i], o)
    assert ends >= 2
    if env_name == "hand_thesis":  # PyBullet's joint-speed clamp, in the batch as in each single env
        assert batch.body.clamped_steps > 0
        assert batch.body.clamped_steps == sum(e.sim.body.clamped_steps for e in singles)
        assert batch.call("counter_values")[0]["diverged"] == 0
    assert batch.call("counter_values")[0]["nan_actions"] == 1
    assert batch.call("counter_values")[0]["episodes"] == sum(e.counters["episodes"] for e in singles)
    batch.close()
    for e in singles:
        e.close()


def test_a_standing_batch_falls_where_each_single_environment_falls(data_root):
    """A free-base upper body with early_termination.fall: random targets at 30 Hz tip it over; the
    batch ends and counts the same rows' episodes as falls, step for step, and says which fell."""
    from aslexp.compose import deep_merge, resolve_group

    env_cfg = deep_merge(resolve_group("env", "upper_body_thesis"),
                         {"early_termination": {"fall": True, "min_reward": None}, "control_hz": 30})
    kwargs = dict(controller="upper_body_thesis", reward="upper_body_thesis", env=env_cfg, body={"base": "free"},
                  engine="mujoco")
    motion, n, seeds = data_root / "motions/upper_body/00433.txt", 3, [7, 8, 9]
    singles = [UpperBodyImitationEnv(motion, **kwargs) for _ in range(n)]
    batch = BatchedImitationEnv(n, motion, env_class=UpperBodyImitationEnv, **kwargs)
    obs = np.stack([e.reset(seed=s)[0] for e, s in zip(singles, seeds)])
    np.testing.assert_array_equal(batch.reset(seed=seeds)[0], obs)
    rng, space, falls = np.random.default_rng(1), batch.single_action_space, 0
    for t in range(150):
        actions = rng.uniform(space.low, space.high, size=(n, space.shape[0])).astype(np.float32)
        results = [e.step(a) for e, a in zip(singles, actions)]
        _, reward, terminated, truncated, info = batch.step(actions)
        for i, (_, r, term, trunc, one) in enumerate(results):
            assert (terminated[i], truncated[i], bool(info["fall"][i])) == (term, trunc, bool(one.get("fall"))), (t, i)
            assert reward[i] == pytest.approx(r, abs=1e-9)
            if term or trunc:
                falls += bool(one.get("fall"))
                singles[i].reset()
    assert falls >= 3 and batch.call("counter_values")[0]["falls"] == falls
    batch.close()
    for e in singles:
        e.close()


def test_the_batch_needs_an_engine_that_batches_and_engine_keys_are_checked(data_root):
    with pytest.raises(ValueError, match="the engine is 'pybullet'"):
        BatchedImitationEnv(2, data_root / "motions/hand/A.txt", engine="pybullet")
    with pytest.raises(ValueError, match="engine.integrator=verlet: expected one of Euler, implicitfast"):
        EngineSpec.parse({"name": "mujoco", "integrator": "verlet"})
    with pytest.raises(ValueError, match="engine.substeps=4: unknown key"):
        EngineSpec.parse({"name": "mujoco", "substeps": 4})


def test_ppo_trains_and_resumes_on_the_batched_engine(data_root, tmp_path):
    from aslexp.rl.ppo import PPOConfig, PPOTrainer

    motion = data_root / "motions/hand/B.txt"
    make = functools.partial(BatchedImitationEnv, motion=motion, engine="mujoco", reward="hand_thesis", env="residual")
    config = PPOConfig.parse(dict(hidden_sizes=[32, 32], steps_per_rollout=512, minibatch_size=128, epochs=1,
                                      total_steps=1024, eval_interval=512, eval_steps=30, eval_episodes=1,
                                      num_envs=8, vector_env="batched", device="cpu", log_std_init=-2.0))
    eval_env = ImitationEnv(motion, engine="mujoco", reward="hand_thesis", env="residual")
    trainer = PPOTrainer(make, eval_env, config, tmp_path / "run", seed=0)
    result = trainer.train()
    assert trainer.steps == 1024 and np.isfinite(result.last_eval)
    assert trainer.counters()["episodes"] >= 8
    rollouts = [h for h in trainer.history if "train_reward" in h]
    assert rollouts and all(0 < h["train_reward"] <= 1 for h in rollouts)
    checkpoint = trainer.save()
    trainer.close()
    longer = PPOConfig.parse({**config.__dict__, "total_steps": 2048, "hidden_sizes": [32, 32]})
    resumed = PPOTrainer(make, eval_env, longer, tmp_path / "run", seed=0)
    resumed.restore(checkpoint)
    assert resumed.steps == 1024
    resumed.train()
    assert resumed.steps == 2048
    resumed.close()
    eval_env.close()


def test_rollout_workers_step_mujoco_environments(data_root, tmp_path):
    from aslexp.rl.ppo import PPOConfig, PPOTrainer

    motion = data_root / "motions/hand/B.txt"
    make = functools.partial(ImitationEnv, motion, engine="mujoco", reward="hand_thesis", env="residual")
    config = PPOConfig.parse(dict(hidden_sizes=[16], steps_per_rollout=128, minibatch_size=64, epochs=1,
                                      total_steps=256, eval_interval=256, eval_steps=10, eval_episodes=1,
                                      num_envs=2, vector_env="workers", device="cpu"))
    trainer = PPOTrainer(make, make(), config, tmp_path / "run", seed=0)
    try:
        trainer.train()
        assert trainer.steps == 256 and trainer.counters()["episodes"] >= 2
    finally:
        trainer.close()


def test_the_engine_switch_composes_in_every_imitation_overlay():
    from aslexp import cli

    composed = {}
    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        assert compose(config_name="imitate").engine.name == "pybullet"  # the thesis' engine by default
        # the imitate job's catalogue and archived probes (the help's lists: each overlay belongs to one job)
        for name in cli.experiments_of("imitate") + cli.experiments_of("imitate", archived=True):
            composed[name] = compose(config_name="imitate", overrides=[f"experiment={name}", "engine=mujoco"])
    assert {"letters_thesis", "letters_scratch", "signs_thesis_run2", "signs_free_residual",
            "archive/signs_free_residual_anneal_quiet"} <= set(composed)
    for overlay, cfg in composed.items():
        assert cfg.engine.name == "mujoco" and "motion" in cfg, overlay
        EngineSpec.parse(dict(cfg.engine))


# The MuJoCo engine's path imports no PyBullet: it runs where PyBullet has no wheel (Python 3.12 GPU images).
WITHOUT_PYBULLET = ("import sys, runpy; [sys.modules.__setitem__(m, None) for m in ('pybullet', 'pybullet_data', "
                    "'pybullet_utils')]; sys.argv[0] = 'imitate'; runpy.run_module('aslexp.jobs.imitate', run_name='__main__')")


def test_imitate_runs_on_mujoco_from_the_command_line_without_pybullet(data_root, tmp_path):
    run = tmp_path / "run"
    proc = subprocess.run([sys.executable, "-c", WITHOUT_PYBULLET, "engine=mujoco", "motion=B", "env=residual",
                           "ppo=quick", "ppo.total_steps=1024", "ppo.steps_per_rollout=512", "ppo.num_envs=8",
                           "ppo.eval_interval=1024", "ppo.eval_steps=30", "ppo.hidden_sizes=[32,32]",
                           "render.gif=false", "plots=false", f"hydra.run.dir={run}"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    metrics = json.loads((run / "metrics.json").read_text())
    assert metrics["steps"] == 1024 and metrics["num_envs"] == 8
    assert 0.5 < metrics["baselines"]["lookahead"] <= 1.0  # measured on the MuJoCo body


def test_batched_workers_collect_the_batch_in_processes(data_root, tmp_path):
    from aslexp.rl.ppo import PPOConfig, PPOTrainer

    motion = data_root / "motions/hand/B.txt"
    make = functools.partial(BatchedImitationEnv, motion=motion, engine="mujoco", reward="hand_thesis", env="residual")
    config = PPOConfig.parse(dict(hidden_sizes=[16], steps_per_rollout=256, minibatch_size=64, epochs=1,
                                      total_steps=512, eval_interval=512, eval_steps=10, eval_episodes=1,
                                      num_envs=8, vector_env="batched", batched_workers=2, device="cpu"))
    trainer = PPOTrainer(make, ImitationEnv(motion, engine="mujoco", reward="hand_thesis", env="residual"),
                         config, tmp_path / "run", seed=0)
    try:
        trainer.train()
        assert trainer.steps == 512
        assert trainer.counters()["episodes"] >= 8  # both workers' batches, summed
        assert len(trainer.envs.call("counter_values")) == 2
    finally:
        trainer.close()
    with pytest.raises(ValueError, match="batched_workers must be 0 or a divisor of num_envs"):
        PPOConfig.parse(dict(num_envs=8, vector_env="batched", batched_workers=3))


def test_a_diverging_mujoco_simulation_is_counted_and_ended_not_silently_reset(data_root, tmp_path):
    # The explicit integrator with the hand's motor gains is unstable without the joint-speed clamp
    # (which holds it): MuJoCo would reset such a state to the zero pose and go on; here the
    # environment sees it diverge, ends and counts it.
    batch = BatchedImitationEnv(4, data_root / "motions/hand/A.txt", env="default", reward="hand_thesis",
                                engine={"name": "mujoco", "integrator": "Euler", "joint_speed_limit": None})
    batch.reset(seed=0)
    ended = 0
    for _ in range(10):
        obs, reward, terminated, truncated, _ = batch.step(np.stack([batch.template.reference_action(1)] * 4))
        assert np.all(np.isfinite(obs))
        ended += int(terminated.sum())
        assert np.all(reward[terminated] == 0.0)
    assert batch.counters["diverged"] == ended > 0
    assert not (tmp_path / "MUJOCO_LOG.TXT").exists()


@pytest.mark.skipif(not __import__("torch").cuda.is_available(), reason="needs a CUDA GPU (torch finds none)")
def test_the_learner_and_the_batch_policy_on_a_gpu(data_root, tmp_path):
    from aslexp.rl.ppo import PPOConfig, PPOTrainer

    motion = data_root / "motions/hand/B.txt"
    make = functools.partial(BatchedImitationEnv, motion=motion, engine="mujoco", reward="hand_thesis", env="residual")
    config = PPOConfig.parse(dict(hidden_sizes=[64, 64], steps_per_rollout=1024, minibatch_size=256, epochs=2,
                                      total_steps=2048, eval_interval=2048, eval_steps=30, eval_episodes=1,
                                      num_envs=64, vector_env="batched", device="cuda", rollout_device="learner"))
    trainer = PPOTrainer(make, ImitationEnv(motion, engine="mujoco", reward="hand_thesis", env="residual"),
                         config, tmp_path / "run", seed=0)
    try:
        result = trainer.train()
        assert trainer.steps == 2048 and np.isfinite(result.last_eval)
        assert trainer.device.type == "cuda" and trainer.rollout_agent is trainer.agent
        # The evaluations ask a CPU copy with the learner's weights (eval_device: cpu, the default).
        policy = trainer.evaluation_agent()
        assert policy.device.type == "cpu" and policy is not trainer.agent
        obs = np.zeros((1, trainer.eval_env.observation_space.shape[0]), np.float32)
        np.testing.assert_allclose(policy.act(obs), trainer.agent.act(obs), atol=1e-5)
    finally:
        trainer.close()


def test_evaluations_ask_the_learner_on_the_cpu_and_the_device_is_checked(data_root, tmp_path):
    from aslexp.rl.ppo import PPOConfig, PPOTrainer

    motion = data_root / "motions/hand/B.txt"
    config = PPOConfig(hidden_sizes=(16,), steps_per_rollout=64, total_steps=64, eval_steps=10, device="cpu")
    env = ImitationEnv(motion, engine="mujoco")
    trainer = PPOTrainer(env, env, config, tmp_path / "run", seed=0)
    try:
        assert trainer.evaluation_agent() is trainer.agent  # a CPU learner is its own evaluator
    finally:
        trainer.close()
        env.close()
    with pytest.raises(ValueError, match="eval_device"):
        PPOConfig(eval_device="gpu")


def test_a_mujoco_env_renders_what_pybullet_renders_for_the_same_pose(data_root):
    pb, mj = pair(ImitationEnv, data_root / "motions/hand/A.txt", render_mode="rgb_array", render_size=(96, 96), **HAND)
    try:
        for env in (pb, mj):
            env.reset(options={"time": 0.5})
        images = [env.render() for env in (pb, mj)]
        assert images[0].shape == images[1].shape == (96, 192, 3)
        differs = np.any(images[0].astype(int) != images[1].astype(int), axis=2)
        assert differs.mean() < 0.01  # reference | simulation, drawn by PyBullet from MuJoCo's state
        assert (images[1] < 200).any(axis=2).mean() > 0.02  # and there is a hand in the picture
    finally:
        pb.close()
        mj.close()
