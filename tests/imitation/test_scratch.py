"""From-scratch learning's environment options on real PyBullet: normalised
actions, the motion's action box, early termination with patience, observations without link
states, their validation, and the letters_scratch overlay as Hydra composes it."""

from __future__ import annotations

import numpy as np
import pytest

from aslexp.paths import CONF_DIR
from aslexp.envs.imitation import EnvSpec, ImitationEnv

FIXED = {"reference_state_init": False, "early_termination": {"min_reward": None}}


def hand(motion, **env) -> ImitationEnv:
    """The hand on env=default's absolute targets (the body's own env is a residual), with ``env`` over it."""
    from aslexp.compose import resolve_group

    return ImitationEnv(motion, reward="hand_thesis", env={**resolve_group("env", "default"), **FIXED, **env})


def test_normalized_actions_map_the_unit_box_exactly_onto_the_joint_range(motion_a):
    env = hand(motion_a, normalize_actions=True)
    assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    box = env.physical_action_space
    assert np.allclose(box.low, env.joint_lower) and np.allclose(box.high, env.joint_upper)
    assert np.allclose(env.physical_action(-np.ones(15)), env.joint_lower, atol=1e-12)
    assert np.allclose(env.physical_action(np.ones(15)), env.joint_upper, atol=1e-12)
    a = np.random.default_rng(0).uniform(-1, 1, 15)
    assert np.allclose(env.normalize_action(env.physical_action(a)), a, atol=1e-12)
    env.close()


def test_normalized_actions_drive_the_same_physics_as_physical_ones(motion_a):
    plain, unit = hand(motion_a), hand(motion_a, normalize_actions=True)
    for env in (plain, unit):
        env.reset(options={"time": 0.2})
    for _ in range(10):
        a_plain, a_unit = plain.reference_action(1), unit.reference_action(1)
        assert np.all(np.abs(a_unit) <= 1) and not np.allclose(a_plain, a_unit)
        _, r_plain, *_ = plain.step(a_plain)
        _, r_unit, *_ = unit.step(a_unit)
        assert r_unit == pytest.approx(r_plain, abs=1e-5)  # float32 actions: the same targets to ~1e-7 rad
    plain.close()
    unit.close()


def test_motion_action_box_lies_within_the_joint_range_and_covers_the_reference(motion_a):
    margin = 0.25
    env = hand(motion_a, action_range="motion", action_range_margin=margin, normalize_actions=True)
    low, high = env.physical_action_space.low, env.physical_action_space.high
    assert np.all(low >= env.joint_lower - 1e-6) and np.all(high <= env.joint_upper + 1e-6)
    assert np.all(high - low < env.joint_upper - env.joint_lower)  # narrower than the joint range on letter A
    q = np.stack([env.reference.joints(t) for t in np.linspace(0, env.reference.duration, 97)])
    assert np.all(q >= low - 1e-6) and np.all(q <= high + 1e-6)
    # The margin where the joint range leaves room for it, the joint limit where it does not.
    expected_low = np.maximum(env.joint_lower, q.min(0) - margin)
    assert np.allclose(low, expected_low, atol=0.02)  # 97 samples vs the box's denser ones
    # Every reference action (one step ahead) is inside the unit box.
    env.reset(options={"time": 0.0})
    for _ in range(40):
        action = env.reference_action(1)
        assert np.all(np.abs(action) <= 1.0 + 1e-6)
        env.step(action)
    env.close()


def test_patience_counts_consecutive_steps_below_the_threshold(motion_a):
    # Letter A from phase 0 at 30 Hz: the flat hand (zero targets) scores about .2-.6, the reference
    # one step ahead above .89 (measured here), against a threshold of .7.
    env = hand(motion_a, early_termination={"min_reward": 0.7, "patience": 3})
    env.reset(options={"time": 0.0})
    bad = np.zeros(15, np.float32)

    def run(plan: str) -> list[tuple[float, bool]]:
        out = []
        for step in plan:
            _, reward, terminated, truncated, info = env.step(bad if step == "x" else env.reference_action(1))
            assert not truncated and info["early_termination"] == terminated
            out.append((reward, terminated))
        return out

    low = run("xx")  # patience - 1 low steps: the episode goes on
    assert all(r < 0.7 and not t for r, t in low)
    good = run("ooo")  # a good step resets the count
    assert all(r > 0.7 and not t for r, t in good)
    again = run("xxx")  # patience low steps in a row: the end
    assert all(r < 0.7 for r, _ in again) and [t for _, t in again] == [False, False, True]
    assert env.counters["early_terminations"] == 1
    # The count starts again with each episode.
    env.reset(options={"time": 0.0})
    assert [t for _, t in run("xx")] == [False, False]
    env.close()


def test_default_patience_ends_at_the_first_low_step(motion_a):
    env = hand(motion_a, early_termination={"min_reward": 0.7})
    env.reset(options={"time": 0.0})
    *_, terminated, _, info = env.step(np.zeros(15, np.float32))
    assert terminated and info["early_termination"]
    env.close()


@pytest.mark.parametrize("observation, links, future, joints, size", [
    ("aslexp", [], [], False, 1),               # the phase alone
    ("aslexp", [], [1, 2], True, 1 + 2 * 15 + 2 * 15),  # env=scratch's: 61
    ("deepmimic", [], [1], False, 2 + 15),       # phase, root height, one future pose
    ("aslexp", None, [], False, 1 + 16 * 13),   # every link (null)
    ("aslexp", ["*dist"], [], False, 1 + 5 * 13),  # the five finger tips
])
def test_observation_size_follows_observe_links(motion_a, observation, links, future, joints, size):
    env = hand(motion_a, observation=observation, observe_links=links, observe_future=future, observe_joints=joints)
    obs, _ = env.reset(options={"time": 0.1})
    assert obs.shape == env.observation_space.shape == (size,)
    obs, *_ = env.step(env.reference_action(1))
    assert obs.shape == (size,) and np.all(np.isfinite(obs))
    if future:  # the future reference poses sit right after the phase (and root height)
        start = 2 if observation == "deepmimic" else 1
        assert np.allclose(obs[start:start + 15], env.reference_targets(future[0]), atol=1e-6)
    env.close()


@pytest.mark.parametrize("values, message", [
    ({"early_termination": {"min_reward": 0.5, "patience": 0}}, "env.early_termination.patience=0: expected an integer >= 1"),
    ({"early_termination": {"min_reward": 0.5, "patience": 2.5}}, "env.early_termination.patience=2.5: expected an integer >= 1"),
    ({"early_termination": {"min_reward": 0.5, "wait": 3}}, "env.early_termination: unknown keys ['wait']"),
    ({"action_range": "box"}, "env.action_range=box: expected one of joint, motion"),
    ({"action_range": "motion", "action_mode": "residual"}, "env.action_range=motion: needs action_mode absolute"),
    ({"action_range": "motion", "action_range_margin": -0.1}, "action_range_margin >= 0"),
    ({"normalise_actions": True}, "env.normalise_actions=true: unknown key; did you mean env.normalize_actions?"),
])
def test_bad_env_options_fail_with_one_clear_line(values, message):
    with pytest.raises(ValueError) as info:
        EnvSpec.parse(values)
    text = str(info.value)
    assert message in text and text.startswith("env.") and "\n" not in text


def test_observe_links_matching_nothing_is_a_clear_error(motion_a):
    with pytest.raises(ValueError, match=r"observe_links \['wrist2\*'\] match no link of body hand15"):
        hand(motion_a, observe_links=["wrist2*"])


def compose_scratch(*overrides: str) -> dict:
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = compose(config_name="imitate", overrides=["experiment=letters_scratch", *overrides],
                      return_hydra_config=True)
    return OmegaConf.to_container(cfg, resolve=False)


def test_letters_scratch_overlay_composes_with_the_values_its_comments_claim():
    cfg = compose_scratch()
    env, ppo = cfg["env"], cfg["ppo"]
    # The thesis' task: hand, PD, reward (Table 5.2), absolute targets, 30 Hz (8 physics steps per action).
    assert cfg["body"]["name"] == "hand15" and cfg["controller"]["name"] == "thesis"
    assert cfg["controller"]["groups"]["default"] == {"kp": 0.22, "kd": 0.87, "max_force": 100.0}
    assert cfg["reward"]["terms"]["pose"] == {"weight": 0.65, "scale": 2.0, "root": True}
    assert env["action_mode"] == "absolute" and (env["physics_hz"], env["control_hz"]) == (240, 30)
    # env=scratch: normalised actions on the motion's box, RSI, early termination, no link states.
    assert env["normalize_actions"] is True and env["action_range"] == "motion"
    assert env["action_range_margin"] == 0.25 and env["reference_state_init"] is True
    assert env["early_termination"]["min_reward"] == 0.5 and env["early_termination"]["patience"] == 10
    assert env["observe_links"] == [] and env["observe_future"] == [1, 2] and env["observe_joints"] is True
    assert env["episode_steps"] == 300
    # ppo=scratch: a linear policy beside an MLP critic, and the evaluation protocol of the bar.
    assert ppo["name"] == "scratch" and ppo["actor_hidden_sizes"] == [] and ppo["hidden_sizes"] == [256, 256]
    assert ppo["num_envs"] == 2 and ppo["eval_steps"] == 300 and ppo["eval_episodes"] == 4
    # The sweep: letters A-E, one seed by default, and the summary callback.
    params = cfg["hydra"]["sweeper"]["params"]
    assert params["motion"] == "A,B,C,D,E" and str(params["seed"]) == "0"
    assert cfg["hydra"]["callbacks"]["scratch_summary"]["_target_"] == "aslexp.jobs.imitate.ScratchSummary"


def test_letters_scratch_builds_the_61_value_environment_of_its_comments(data_root):
    from aslexp.jobs._common import to_dict
    from aslexp.jobs.imitate import build_envs
    from hydra import compose, initialize_config_dir

    with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
        cfg = to_dict(compose(config_name="imitate", overrides=["experiment=letters_scratch", "motion=C"]))
    make_train_env, eval_env = build_envs(cfg, data_root)
    train = make_train_env()
    assert train.observation_space.shape == (61,) and train.action_space.shape == (15,)
    assert np.all(train.action_space.high == 1.0)
    assert train.spec_env.early_termination["min_reward"] == 0.5
    assert eval_env.spec_env.early_termination["min_reward"] is None  # evaluations never end early
    train.close()
    eval_env.close()


def test_a_linear_actor_beside_an_mlp_critic(motion_a):
    import torch

    from aslexp.rl.ppo import PPOConfig, make_agent

    config = PPOConfig.parse({"hidden_sizes": [32, 32], "actor_hidden_sizes": [], "log_std_init": -2.0})
    assert config.actor_hidden_sizes == () and PPOConfig.parse({}).actor_hidden_sizes is None
    env = hand(motion_a, normalize_actions=True, observe_links=[], observe_future=[1])
    agent = make_agent(env, config)
    actor = [m for m in agent.head.net if isinstance(m, torch.nn.Linear)]
    critic = [m for m in agent.critic.module if isinstance(m, torch.nn.Linear)]
    assert [tuple(m.weight.shape) for m in actor] == [(15, 16)]  # phase + one future pose -> 15 targets
    assert [tuple(m.weight.shape) for m in critic] == [(32, 16), (32, 32), (1, 32)]
    obs, _ = env.reset(options={"time": 0.0})
    action = agent.act(obs)
    assert action.shape == (15,) and np.all(np.abs(action) < 0.1)  # near the box centre at first
    env.close()


def test_letters_scratch_runs_end_to_end_with_its_summary(tmp_path):
    """The documented command on a tiny budget: the run, and the sweep's table and curves against
    each letter's reference-as-target bar measured in the same run."""
    import csv
    import json

    from .test_jobs import run_job

    sweep = tmp_path / "scratch"
    run_job("imitate", "-m", "experiment=letters_scratch", "motion=B", "ppo.hidden_sizes=[32,32]",
            "ppo.steps_per_rollout=128", "ppo.minibatch_size=128", "ppo.epochs=1", "ppo.total_steps=256",
            "ppo.eval_interval=128", "ppo.eval_steps=24", "render.frames_every=8", "render.size=[48,48]",
            "ppo.num_envs=1", "plots=false", "render.gif=false", f"hydra.sweep.dir={sweep}")
    metrics = json.loads((sweep / "0" / "metrics.json").read_text())
    assert metrics["motion"] == "B" and metrics["steps"] == 256
    bar = metrics["baselines"]["reference"]
    assert 0.5 < bar < metrics["baselines"]["lookahead"] <= 1.0  # the reference one step ahead tracks better
    [row] = list(csv.DictReader((sweep / "scratch_table.csv").open(encoding="utf-8")))
    assert row["motion"] == "B" and float(row["target"]) == pytest.approx(bar, abs=1e-4)
    assert row["reached_target"] == "0/1"  # 256 steps of PPO do not imitate a letter
    assert (sweep / "scratch_curves.png").stat().st_size > 0
