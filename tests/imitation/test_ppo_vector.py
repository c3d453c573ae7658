"""PPO with many environments: worker processes give the same transitions as single environments,
GAE bootstraps truncated episodes per environment, runs resume with workers, the learner's device
is a switch, evaluations are several phases and the headline is the last one, progress is logged."""

from __future__ import annotations

import functools
import logging
import os

import numpy as np
import pytest
import job_process
import torch
import yaml

from aslexp.paths import CONF_DIR
from aslexp.envs.imitation import ImitationEnv
from aslexp.rl.checkpoint import load_checkpoint, save_checkpoint
from aslexp.rl.evaluate import baselines, evaluate, evaluate_phases, reference_policy
from aslexp.rl.noise import ActionNoise
from aslexp.rl.policy import RunningNormalizer
from aslexp.rl.ppo import PPOConfig, PPOTrainer, make_agent, resolve_device
from aslexp.rl.vector import START_METHOD, DropInfo, make_vector_env, worker_seeds
from aslexp.rl.workers import noise_seeds, rollout_segment

TINY = dict(hidden_sizes=(32, 32), learning_rate=1e-3, steps_per_rollout=128, minibatch_size=64, epochs=2,
            log_std_init=-1.0, weight_decay=0.0, eval_interval=128, eval_steps=20, eval_episodes=2,
            target_kl=None, total_steps=256)
# Short episodes that end both ways inside one rollout of 64 steps per environment: early
# termination below reward 0.15 and truncation at 15 steps (seeds 0 and 3: 3-4 of 6-7 ends per
# environment are terminations, measured).
ENV = {"episode_steps": 15, "early_termination": {"min_reward": 0.15}}


def absolute(**env) -> dict:
    """env=default's absolute targets (whose random actions end episodes both ways; the body's own env
    is a residual on the controller) with ENV and ``env`` over it."""
    from aslexp.compose import resolve_group

    return {**resolve_group("env", "default"), **ENV, **env}


def factory(motion, engine: str | None = None, **env):
    return functools.partial(ImitationEnv, motion, engine=engine, env=absolute(**env))


def test_two_workers_collect_the_transitions_of_two_single_environments(tmp_path, motion_a):
    config = PPOConfig(**TINY, num_envs=2, vector_env="async", device="cpu")  # CPU tensors compared below
    trainer = PPOTrainer(factory(motion_a), None, config, tmp_path, seed=3)
    try:
        batch = trainer.collect()
    finally:
        trainer.close()
    assert batch.batch_size == (2, 64) and trainer.steps == 128
    done, terminated = batch["next", "done"].squeeze(-1), batch["next", "terminated"].squeeze(-1)
    assert (terminated & ~done).sum() == 0 and terminated.sum() > 0 and (done & ~terminated).sum() > 0

    # Replay the sampled actions in two plain environments, seeded as the workers were.
    normalise = RunningNormalizer(batch["observation"].shape[-1])  # the statistics the rollout used
    agent = trainer.agent
    for i, seed in enumerate(worker_seeds(3, 2)):
        env = factory(motion_a)()
        obs, _ = env.reset(seed=seed)
        for t in range(64):
            assert torch.equal(normalise(torch.from_numpy(obs)), batch["observation"][i, t]), (i, t)
            action = agent.to_env_action(batch["action"][i, t]).numpy()
            obs, reward, term, trunc, _ = env.step(action)
            assert np.float32(reward) == batch["next", "reward"][i, t, 0].item(), (i, t)
            assert (term, term or trunc) == (bool(terminated[i, t]), bool(done[i, t])), (i, t)
            assert torch.equal(normalise(torch.from_numpy(obs)), batch["next", "observation"][i, t]), (i, t)
            if term or trunc:
                obs, _ = env.reset()
        env.close()


@pytest.mark.parametrize("beta", [0.0, 1.0])
def test_rollout_workers_collect_what_the_same_loop_collects_in_this_process(tmp_path, motion_a, beta):
    # vector_env=workers: each worker steps its environment with a copy of the policy for the whole
    # rollout. Its transitions equal rollout_segment run here with the same seeds, episode ends and
    # the normaliser's statistics included; a second rollout continues the same episodes. With
    # white noise (beta 0) and with pink noise (beta 1, restarted at every episode's end).
    config = PPOConfig(**TINY, num_envs=2, vector_env="workers", noise_beta=beta, noise_horizon=16)
    trainer = PPOTrainer(factory(motion_a), None, config, tmp_path, seed=3)
    try:
        first = trainer.collect()
        second = trainer.collect()
        counters = trainer.counters()
    finally:
        trainer.close()
    assert first.batch_size == (2, 64) and trainer.steps == 256 and counters["episodes"] > 2
    done, terminated = first["next", "done"].squeeze(-1), first["next", "terminated"].squeeze(-1)
    assert terminated.sum() > 0 and (done & ~terminated).sum() > 0

    for i, (reset_seed, noise_seed) in enumerate(zip(worker_seeds(3, 2), noise_seeds(3, 2))):
        env = DropInfo(factory(motion_a)())
        obs, _ = env.reset(seed=reset_seed)
        noise = ActionNoise(env.action_space.shape[0], noise_seed, beta, horizon=16)
        torch.manual_seed(3)  # as the trainer did: the initial weights the workers received
        policy = make_agent(env, config)
        segment, obs = rollout_segment(env, policy, noise, np.asarray(obs, np.float32), 64)
        normalise = RunningNormalizer(segment["obs"].shape[-1])  # the statistics the first rollout used
        assert torch.equal(normalise(torch.from_numpy(segment["obs"])), first["observation"][i])
        assert torch.equal(torch.from_numpy(segment["action"]), first["action"][i])
        assert torch.equal(torch.from_numpy(segment["reward"]), first["next", "reward"][i, :, 0])
        assert torch.equal(torch.from_numpy(segment["terminated"]), terminated[i])
        assert torch.equal(torch.from_numpy(segment["terminated"] | segment["truncated"]), done[i])
        assert torch.equal(normalise(torch.from_numpy(segment["next_obs"])), first["next", "observation"][i])
        env.close()
    assert not torch.equal(first["observation"], second["observation"])


def test_a_run_with_rollout_workers_trains_and_resumes(tmp_path, motion_a):
    eval_env = ImitationEnv(motion_a, env=absolute(early_termination={"min_reward": None}))
    config = PPOConfig(**{**TINY, "total_steps": 128}, num_envs=2, vector_env="workers")
    first = PPOTrainer(factory(motion_a), eval_env, config, tmp_path, seed=1)
    try:
        first.train()
    finally:
        first.close()
    second = PPOTrainer(factory(motion_a), eval_env, PPOConfig(**TINY, num_envs=2, vector_env="workers"), tmp_path,
                        seed=1)
    try:
        second.restore(tmp_path / "checkpoints" / "last.pt")
        result = second.train()
    finally:
        second.close()
    assert [h["step"] for h in result.history] == [128, 256] and np.isfinite(result.last_eval)
    assert result.history[-1]["count_episodes"] > 0
    eval_env.close()


def test_gae_bootstraps_truncation_not_termination_in_each_environment(tmp_path, motion_a):
    config = PPOConfig(**TINY, num_envs=2, gamma=0.9, gae_lambda=0.8, device="cpu")  # CPU tensors compared below
    trainer = PPOTrainer(factory(motion_a), None, config, tmp_path, seed=0)
    batch = trainer.collect()
    with torch.no_grad():
        trainer.gae(batch)
        value = trainer.agent.critic.module(batch["observation"]).squeeze(-1).numpy()
        next_value = trainer.agent.critic.module(batch["next", "observation"]).squeeze(-1).numpy()
    reward = batch["next", "reward"].squeeze(-1).numpy()
    done = batch["next", "done"].squeeze(-1).numpy()
    terminated = batch["next", "terminated"].squeeze(-1).numpy()
    for i in range(2):  # by hand, per environment, backwards in time
        expected, running = np.zeros(64), 0.0
        for t in reversed(range(64)):
            delta = reward[i, t] + 0.9 * next_value[i, t] * (1 - terminated[i, t]) - value[i, t]
            running = delta + 0.9 * 0.8 * (1 - done[i, t]) * running
            expected[t] = running
        np.testing.assert_allclose(batch["advantage"][i].squeeze(-1).numpy(), expected, rtol=1e-4, atol=1e-5)
    trainer.close()


def test_a_run_with_two_workers_resumes(tmp_path, motion_a):
    eval_env = ImitationEnv(motion_a, env=absolute(early_termination={"min_reward": None}))
    config = PPOConfig(**{**TINY, "total_steps": 128}, num_envs=2)
    first = PPOTrainer(factory(motion_a), eval_env, config, tmp_path, seed=1)
    try:
        first.train()
        counters = first.counters()
    finally:
        first.close()
    assert counters["episodes"] >= 2 * 3  # both workers, first episodes and same-step resets
    saved = load_checkpoint(tmp_path / "checkpoints" / "last.pt")
    assert saved["steps"] == 128 and saved["num_envs"] == 2

    second = PPOTrainer(factory(motion_a), eval_env, PPOConfig(**TINY, num_envs=2), tmp_path, seed=1)
    try:
        second.restore(tmp_path / "checkpoints" / "last.pt")
        assert second.steps == 128 and second.history == first.history
        for a, b in zip(first.agent.state_dict().values(), second.agent.state_dict().values()):
            assert torch.equal(a, b)
        result = second.train()
    finally:
        second.close()
    assert result.steps == 256 and len(result.history) == 2
    assert [h["step"] for h in result.history] == [128, 256] and "eval_reward" in result.history[-1]
    eval_env.close()


def test_a_checkpoint_without_the_new_fields_still_resumes(tmp_path, motion_a):
    # Checkpoints written before many environments (no num_envs / device entries) resume unchanged.
    env = factory(motion_a)()
    trainer = PPOTrainer(env, None, PPOConfig(**TINY), tmp_path, seed=0)
    old = {k: v for k, v in trainer.state().items() if k not in ("num_envs", "device")}
    save_checkpoint(tmp_path / "old.pt", old)
    fresh = PPOTrainer(env, None, PPOConfig(**TINY), tmp_path, seed=5)
    fresh.restore(tmp_path / "old.pt")
    assert all(torch.equal(a, b) for a, b in zip(trainer.agent.state_dict().values(),
                                                 fresh.agent.state_dict().values()))
    env.close()


def test_device_switch(tmp_path, motion_a):
    assert resolve_device("cpu") == torch.device("cpu")
    assert resolve_device("auto").type == ("cuda" if torch.cuda.is_available() else "cpu")
    with pytest.raises(ValueError, match="device must be"):
        resolve_device("gpu0")
    if not torch.cuda.is_available():  # refused with the config, before any environment starts
        with pytest.raises(ValueError, match="no CUDA device"):
            PPOConfig.parse({**TINY, "device": "cuda"})
    trainer = PPOTrainer(factory(motion_a), None, PPOConfig(**TINY, device="cpu"), tmp_path)
    assert trainer.rollout_agent is trainer.agent and trainer.agent.device.type == "cpu"
    trainer.close()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA GPU (torch finds none)")
@pytest.mark.parametrize("rollout_device", ["cpu", "learner"])
def test_learner_on_cuda_and_back(tmp_path, motion_a, rollout_device):
    # MuJoCo: GPU machines run Python 3.12, where PyBullet has no wheel.
    eval_env = ImitationEnv(motion_a, engine="mujoco", env=absolute(early_termination={"min_reward": None}))
    config = PPOConfig(**TINY, device="cuda", num_envs=2, rollout_device=rollout_device)
    trainer = PPOTrainer(factory(motion_a, engine="mujoco"), eval_env, config, tmp_path)
    try:
        before = trainer.rollout_agent.head.net[0].weight.clone()
        result = trainer.train()
    finally:
        trainer.close()
    assert next(trainer.agent.parameters()).is_cuda
    assert trainer.rollout_agent.device.type == ("cpu" if rollout_device == "cpu" else "cuda")
    assert result.steps == 256 and np.isfinite(result.last_eval)
    # The policy that collects follows the learner after every update.
    assert not torch.equal(before, trainer.rollout_agent.head.net[0].weight)
    assert torch.equal(trainer.rollout_agent.head.net[0].weight.cpu(), trainer.agent.head.net[0].weight.cpu())
    cpu = PPOTrainer(factory(motion_a, engine="mujoco"), None, PPOConfig(**TINY, device="cpu"), tmp_path / "cpu")
    cpu.restore(tmp_path / "checkpoints" / "last.pt")
    assert cpu.steps == 256
    cpu.close()
    eval_env.close()


def test_evaluation_is_several_phases_and_the_headline_is_the_last(tmp_path, motion_a, caplog):
    eval_env = ImitationEnv(motion_a, env=absolute(early_termination={"min_reward": None}))
    lookahead = reference_policy(1)
    summary = evaluate_phases(eval_env, lookahead, 20, (0.0, 0.5))
    singles = [evaluate(eval_env, lookahead, 20, phase=p).mean_reward for p in (0.0, 0.5)]
    assert summary.rewards == singles and singles[0] != singles[1]
    assert summary.mean_reward == pytest.approx(np.mean(singles)) and summary.std > 0
    assert baselines(eval_env, 20, (0.0, 0.5))["lookahead"] == pytest.approx(summary.mean_reward)
    # The actions' size, in half-widths of the action box: a quarter of the way from the centre to
    # the upper edge on every value is 0.25; the box centre is 0.
    low, high = eval_env.action_space.low, eval_env.action_space.high
    quarter = evaluate_phases(eval_env, lambda obs, env: (low + high) / 2 + (high - low) / 8, 20, (0.0, 0.5))
    centre = evaluate(eval_env, lambda obs, env: (low + high) / 2, 20)
    assert quarter.action_rms == pytest.approx(0.25) and centre.action_rms == pytest.approx(0.0, abs=1e-12)

    rows = []
    config = PPOConfig(**{**TINY, "total_steps": 384, "eval_phases": (0.0, 0.25, 0.5)}, progress_interval=0.0)
    trainer = PPOTrainer(factory(motion_a), eval_env, config, tmp_path, seed=0, on_progress=rows.append)
    with caplog.at_level(logging.INFO, logger="aslexp.ppo"):
        result = trainer.train()
    trainer.close()
    evals = [h["eval_reward"] for h in result.history]
    assert len(rows) == 3 and rows == result.history  # on_progress: every update's row
    assert result.last_eval == evals[-1] and result.best_eval == max(evals)
    assert rows[-1]["last_eval"] == evals[-1] and rows[-1]["best_eval"] == max(evals)
    assert {"eval_reward_std", "eval_reward_min", "eval_action_rms", "steps_per_s", "train_reward",
            "loss_critic"} <= set(rows[-1])
    assert config.eval_protocol["phases"] == [0.0, 0.25, 0.5]
    lines = [r.getMessage() for r in caplog.records if "steps/s" in r.getMessage()]
    assert lines and all("ETA" in line for line in lines) and "step 384/384" in lines[-1]
    # K = 2: the headline is the mean of the last two evaluations.
    k2 = PPOTrainer(factory(motion_a), eval_env, PPOConfig(**TINY, eval_last_k=2), tmp_path / "k2")
    k2.history = result.history
    assert k2.last_eval() == pytest.approx(np.mean(evals[-2:]))
    k2.close()
    eval_env.close()


def test_every_ppo_file_is_a_valid_config_and_base_holds_the_defaults():
    base = yaml.safe_load((CONF_DIR / "ppo" / "base.yaml").read_text())
    defaults = PPOConfig()
    assert set(base) == set(PPOConfig.__dataclass_fields__)
    for key, value in base.items():
        expected = getattr(defaults, key)
        assert (tuple(value) if isinstance(value, list) else value) == expected or key == "name", key
    from aslexp.compose import group as load_group_file

    for path in sorted((CONF_DIR / "ppo").glob("*.yaml")):
        config = PPOConfig.parse({**base, **load_group_file("ppo", path.stem)})
        assert config.batch_size >= config.minibatch_size, path.name
    quick = PPOConfig.parse({**base, **load_group_file("ppo", "quick")})
    assert quick.total_steps <= 200_000 and quick.max_minutes <= 15 and quick.num_envs == 1


def test_bad_vector_settings_are_refused_with_the_key(motion_a):
    with pytest.raises(ValueError, match="num_envs must be at least 1"):
        PPOConfig(num_envs=0)
    with pytest.raises(ValueError, match="vector_env must be one of"):
        PPOConfig(vector_env="threads")
    env = factory(motion_a)()
    with pytest.raises(ValueError, match="needs an environment factory"):
        make_vector_env(env, num_envs=2)
    env.close()
    assert PPOConfig(num_envs=3, steps_per_rollout=1000).batch_size == 1002  # 334 steps per environment


def test_imitate_composes_quick_by_default_and_builds_a_factory_workers_can_unpickle(data_root):
    import pickle

    from hydra import compose, initialize_config_dir

    from aslexp.jobs._common import to_dict
    from aslexp.jobs.imitate import build_envs

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        default = compose(config_name="imitate")
        cfg = to_dict(compose(config_name="imitate", overrides=["ppo=authors_script", "ppo.num_envs=2", "ppo.device=cpu"]))
    assert default.ppo.name == "quick" and default.ppo.num_envs == 1
    config = PPOConfig.parse(cfg["ppo"])  # base.yaml's keys under the chosen file
    assert config.num_envs == 2 and config.learning_rate == 3e-6 and config.eval_episodes == 4
    make_train_env, eval_env = build_envs(cfg, data_root)
    env = pickle.loads(pickle.dumps(make_train_env))()  # as a worker process receives it
    assert env.observation_space == eval_env.observation_space and env.spec_env.episode_steps == cfg["env"]["episode_steps"]
    env.close()
    eval_env.close()


def test_the_scaling_benchmark_runs_on_tiny_settings(tmp_path, data_root):
    import csv
    import os
    import sys

    root = CONF_DIR.parent
    out = tmp_path / "scaling.csv"
    proc = job_process.run(
        [sys.executable, str(root / "bench" / "ppo_scaling.py"), "--bodies", "hand", "--rates", "240", "--envs", "1",
         "2", "--steps", "64", "--repeats", "1", "--ppo-hand", "quick", "--csv", str(out)],
        cwd=root, env={**os.environ, "ASLEXP_DATA_ROOT": str(data_root)}, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = list(csv.DictReader(out.open()))
    assert [(r["num_envs"], r["mode"]) for r in rows] == [("1", "sync"), ("1", "async"), ("1", "workers"),
                                                          ("2", "async"), ("2", "workers")]
    assert float(rows[0]["collect_efficiency"]) == 1.0 and all(float(r["hours_50M"]) > 0 for r in rows)
    assert "| 2 | 2 lockstep workers |" in proc.stdout and "| 2 | 2 rollout workers |" in proc.stdout


PRELOAD_PROBE = """
import functools, os, sys
from pathlib import Path
from aslexp.envs.imitation import ImitationEnv
from aslexp.rl.ppo import agent_for_spaces
from aslexp.rl.policy import ModelSpec
from aslexp.rl.workers import PolicyWorkers

def children(pid):
    with open(f"/proc/{pid}/task/{pid}/children") as fh:
        return [int(c) for c in fh.read().split()]

if __name__ == "__main__":
    workers = PolicyWorkers(functools.partial(ImitationEnv, Path(sys.argv[1])), 2,
                            functools.partial(agent_for_spaces, ModelSpec()))
    [server] = [c for c in children(os.getpid()) if b"forkserver" in open(f"/proc/{c}/cmdline", "rb").read()]
    maps = open(f"/proc/{server}/maps").read()
    print("server holds torch:", "libtorch" in maps)
    print("workers forked from it:", sorted(p.pid for p in workers._processes) == sorted(children(server)))
    workers.close()
"""


@pytest.mark.skipif(not os.path.isdir("/proc/self/task") or START_METHOD != "forkserver",
                    reason="reads the process tree from Linux's /proc; needs the forkserver start method")
def test_rollout_workers_fork_from_a_server_that_has_their_modules_loaded(motion_a, tmp_path):
    """The forkserver imports the workers' modules once (torch, torchrl's modules, the environment's
    module): each worker forks from it instead of importing them again (~3 s each)."""
    import sys

    probe = tmp_path / "probe.py"
    probe.write_text(PRELOAD_PROBE)
    out = job_process.run([sys.executable, str(probe), str(motion_a)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.splitlines() == ["server holds torch: True", "workers forked from it: True"]
