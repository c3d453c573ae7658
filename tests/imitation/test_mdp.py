"""The imitation MDP written once for N rows (aslexp.envs.mdp): each kernel on small arrays of a real
motion, then the single environment and batches of one giving the same trajectory, the training
options of the free-base residual (a smoothed base, drift shaping) included."""

from __future__ import annotations

from collections import defaultdict

import numpy as np
import pytest

from aslexp import quaternion
from aslexp.compose import deep_merge, resolve_group
from aslexp.envs import mdp
from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.batched import BatchedImitationEnv
from aslexp.envs.imitation import ImitationEnv
from aslexp.envs.spec import UP_AXIS
from aslexp.envs.upper_body import UpperBodyImitationEnv


@pytest.fixture(scope="module")
def hand(data_root):
    """The hand's motion A: its reference and joint limits (no engine)."""
    setup = ImitationSetup.from_groups("A", "hand15", "reference_velocity_tuned", env="residual", data_root=data_root)
    lower = np.array([j.lower for j in setup.layout.joints])
    upper = np.array([j.upper for j in setup.layout.joints])
    return setup, lower, upper


def _rule(setup, lower, upper, **changes) -> mdp.TargetRule:
    rule = mdp.TargetRule.of(setup.env, setup.controller, lower, upper, setup.layout.action_size)
    return mdp.TargetRule(**{**rule.__dict__, **changes})


def test_the_targets_are_the_action_or_the_base_plus_it_clipped_to_the_joint_limits(hand):
    setup, lower, upper = hand
    reference, size = setup.reference, setup.layout.action_size
    times = np.array([0.0, 0.3, 0.71])
    correction = np.full((3, size), 0.05)
    correction[1, 0] = 50.0  # far past the joint's upper limit: clipped there
    rule = _rule(setup, lower, upper, physics_rate=False, velocity_scale=None)
    base = reference.joints_many(rule.base_times(times))
    [(targets, velocities, steps)] = mdp.pd_targets(rule, correction, times, reference, base)
    assert steps == setup.env.substeps and velocities is None
    np.testing.assert_array_equal(targets, np.clip(base + correction, lower, upper))
    assert targets[1, 0] == upper[0]
    absolute = _rule(setup, lower, upper, residual=False, physics_rate=False, velocity_scale=None)
    [(targets, _, _)] = mdp.pd_targets(absolute, correction, times, reference)
    np.testing.assert_array_equal(targets, np.clip(correction, lower, upper))
    with pytest.raises(ValueError, match="needs the residual base"):
        mdp.pd_targets(rule, correction, times, reference)


def test_physics_rate_targets_follow_the_reference_every_physics_step_with_its_velocities(hand):
    setup, lower, upper = hand
    reference, size = setup.reference, setup.layout.action_size
    rule = _rule(setup, lower, upper)
    assert rule.physics_rate and rule.velocity_scale is not None  # the tuned tracking controller's options
    times = np.array([0.1, 0.5])
    velocity_size = reference.joint_velocities_many(times).shape[1]
    physical = np.concatenate([np.zeros((2, size)), np.full((2, velocity_size), 0.25)], axis=1)
    holds = mdp.pd_targets(rule, physical, times, reference)
    assert len(holds) == rule.substeps and all(steps == 1 for _, _, steps in holds)
    for i, (targets, velocities, _) in enumerate(holds):
        t = times + (i + 1) * (rule.control_dt / rule.substeps)
        np.testing.assert_array_equal(targets, np.clip(reference.joints_many(t), lower, upper))
        np.testing.assert_array_equal(velocities, rule.velocity_scale * reference.joint_velocities_many(t) + 0.25)
    assert mdp.velocity_targets(None, None, np.zeros((2, 0))) is None


def test_the_smoothed_base_filters_the_chosen_values_and_restarts_per_row():
    reference = np.array([[1.0, 2.0, 3.0], [1.0, 2.0, 3.0]])
    previous = np.zeros((2, 3))
    smoothing = mdp.BaseSmoothing(0.5, np.array([0, 2]), np.full(3, -0.4), np.full(3, 0.4))
    state, base = mdp.residual_base(reference, previous, np.array([False, True]), smoothing)
    np.testing.assert_array_equal(state, [[0.5, 2.0, 1.5], [1.0, 2.0, 3.0]])  # row 1 starts over
    np.testing.assert_array_equal(base, [[0.6, 2.0, 2.6], [1.0, 2.0, 3.0]])  # within 0.4 of the reference
    state, base = mdp.residual_base(reference, None, np.array([False, False]), smoothing)  # no state yet
    np.testing.assert_array_equal(base, reference)
    assert mdp.residual_base(reference, previous, np.array([False, False]), None) == (None, reference)


def test_divergence_is_a_non_finite_state_or_a_joint_too_fast_before_the_clamp():
    state = np.zeros((4, 2, 13))
    state[1, 0, 5] = np.inf
    qd = np.array([[1.0, -2.0], [0.0, 0.0], [0.0, np.nan], [0.0, 30.0]])
    speed = mdp.joint_speeds(qd, np.array([0.0, 0.0, 0.0, 2000.0]))
    np.testing.assert_array_equal(speed[[0, 1, 3]], [2.0, 0.0, 2000.0])
    assert np.isnan(speed[2])
    np.testing.assert_array_equal(mdp.diverged(state, qd, speed, 1000.0), [False, True, True, True])
    np.testing.assert_array_equal(mdp.finite_actions(np.array([[0.0, 1.0], [np.nan, 1.0]])), [True, False])


def test_episode_ends_count_patience_falls_truncation_nan_actions_and_divergence():
    rule = mdp.Termination(min_reward=0.5, patience=2, fall=True, episode_steps=10)
    finite = np.array([True, True, True, True, False, True])
    diverged = np.array([False, False, False, False, False, True])
    reward = np.array([0.4, 0.4, 0.9, 0.9, 0.0, 0.0])
    below = np.array([0, 1, 3, 0, 0, 0])
    fell = np.array([False, False, False, True, False, False])
    steps = np.array([3, 3, 10, 4, 4, 4])
    ends = mdp.episode_ends(rule, finite, diverged, reward, below, fell, steps)
    np.testing.assert_array_equal(ends.below, [1, 2, 0, 0, 0, 0])
    np.testing.assert_array_equal(ends.early, [False, True, False, True, False, False])
    np.testing.assert_array_equal(ends.terminated, [False, True, False, True, True, True])
    np.testing.assert_array_equal(ends.truncated, [False, False, True, False, False, False])
    np.testing.assert_array_equal(ends.scored, [True, True, True, True, False, False])
    counters: dict[str, int] = defaultdict(int)
    mdp.count_ends(counters, ends)
    assert dict(counters) == {"nan_actions": 1, "diverged": 1, "early_terminations": 2, "falls": 1}
    # without early_termination.fall a contact ends nothing; without min_reward no reward does
    rule = mdp.Termination(min_reward=None, patience=1, fall=False, episode_steps=10)
    ends = mdp.episode_ends(rule, finite, diverged, reward, below, fell, steps)
    assert not ends.early.any() and not ends.below.any()
    sums: dict[str, float] = defaultdict(float)
    mdp.add_term_sums(sums, ends.scored, reward, {"pose": reward / 2}, np.full(6, 0.5))
    assert dict(sums) == pytest.approx({"pose": 1.3, "reward": 2.6, "steps": 4, "drift": 2.0})


def test_drift_charges_the_turn_about_the_up_axis_and_the_horizontal_offset():
    rng = np.random.default_rng(0)
    ref_rot = rng.normal(size=(5, 4))
    sim_rot = rng.normal(size=(5, 4))
    ref_rot /= np.linalg.norm(ref_rot, axis=1, keepdims=True)
    sim_rot /= np.linalg.norm(sim_rot, axis=1, keepdims=True)
    ref_pos, sim_pos = rng.normal(size=(5, 3)), rng.normal(size=(5, 3))
    factors = mdp.drift(sim_pos, sim_rot, ref_pos, ref_rot, 10.0, 100.0)
    for i in range(5):
        yaw = quaternion.twist_angle(ref_rot[i], sim_rot[i], UP_AXIS)
        offset = np.delete(sim_pos[i] - ref_pos[i], UP_AXIS)
        assert factors[i] == pytest.approx(np.exp(-10.0 * yaw ** 2 - 100.0 * offset @ offset), rel=1e-12)
    # a root standing on its reference, turned about the up axis alone by 0.1 rad
    turn = np.array([[np.cos(0.05), 0.0, np.sin(0.05), 0.0]])
    assert mdp.drift(ref_pos[:1], turn, ref_pos[:1], np.array([[1.0, 0, 0, 0]]), 10.0, 100.0)[0] == \
        pytest.approx(np.exp(-10.0 * 0.01), rel=1e-12)


# -- the single environment and batches of one, step for step -------------------------------------------
FREE_RESIDUAL = dict(controller="upper_body_thesis_code", reward="upper_body_table6_4_run3", body={"base": "free"},
                     env=deep_merge(resolve_group("env", "upper_body_free_residual"), {
                         "residual_base_smoothing": 0.6,
                         "residual_base_smoothing_groups": ["chest", "neck", "shoulder", "elbow"],
                         "heading_shaping": 10.0, "offset_shaping": 100.0}))
ARMS = {"policy_groups": ["chest", "neck", "shoulder", "elbow"], "observe_joints": True, "observe_future": [1, 2],
        "observe_links": ["root", "chest", "neck", "*_hip", "*_knee", "*_ankle", "*_shoulder", "*_elbow"]}
# (env class, motion, groups, shape_reward, noise: None random actions over the box, else the
# reference action plus that fraction of the box drawn at random: the upper body keeps its feet and its
# simulation stays sane)
CASES = {
    "hand-absolute": (ImitationEnv, "A", dict(reward="hand_thesis", env="default"), False, None),
    "hand-residual": (ImitationEnv, "A", dict(reward="hand_thesis", env="residual"), False, None),
    "hand-residual-smoothed-base": (ImitationEnv, "A", dict(reward="hand_thesis", env=deep_merge(
        resolve_group("env", "residual"), {"residual_base_smoothing": 0.5})), False, None),
    "upper-absolute": (UpperBodyImitationEnv, "00433", {}, False, 0.05),  # built model, position control, fixed base
    # the standing residual's training env: a smoothed base, the drift charged, falls ending episodes
    "upper-free-residual-shaped": (UpperBodyImitationEnv, "00433", FREE_RESIDUAL, True, 0.3),
    # experiment=signs_unseen_tracking_error's observation: the frame ahead as a tracking error, no phase
    "upper-free-residual-tracking-error": (UpperBodyImitationEnv, "00433", {**FREE_RESIDUAL, "env": deep_merge(
        FREE_RESIDUAL["env"], {"observe_future_as": "error", "observe_phase": False, "observe_joints": True})},
        True, 0.3),
    # experiment=signs_unseen_arms's policy: it corrects and sees the arms, chest and neck alone
    "upper-free-residual-arms": (UpperBodyImitationEnv, "00433", {**FREE_RESIDUAL, "env": deep_merge(
        FREE_RESIDUAL["env"], ARMS)}, True, 0.3),
}


@pytest.mark.parametrize("case", list(CASES))
def test_a_batch_of_one_is_the_single_environment_step_for_step(data_root, case):
    cls, motion, kwargs, shape, noise = CASES[case]
    single = cls(motion, engine="mujoco", data_root=data_root, shape_reward=shape, **kwargs)
    batches = [BatchedImitationEnv(1, motion, engine="mujoco", data_root=data_root, shape_reward=shape,
                                   env_class=cls, **kwargs),
               BatchedImitationEnv.from_setup(1, single.setup, shape_reward=shape, env_class=cls)]
    obs, _ = single.reset(seed=3)
    for batch in batches:
        np.testing.assert_array_equal(batch.reset(seed=3)[0][0], obs)
    rng = np.random.default_rng(4)
    space, rewards, ends = single.action_space, [], 0
    for t in range(30):
        action = rng.uniform(space.low, space.high).astype(np.float32)
        if noise is not None:
            action = np.clip(single.reference_action(1) + noise * action, space.low, space.high)
        o, r, term, trunc, info = single.step(action)
        rewards.append(r)
        for batch in batches:
            b_obs, b_reward, b_term, b_trunc, b_info = batch.step(action[None])
            assert (b_term[0], b_trunc[0]) == (term, trunc), (case, t)
            assert b_reward[0] == pytest.approx(r, abs=1e-12), (case, t)
            np.testing.assert_array_equal(b_info["final_obs"][0] if term or trunc else b_obs[0], o)
        if term or trunc:
            ends += 1
            o, _ = single.reset()
            for batch in batches:  # the batch's autoreset drew from its own stream: start both alike
                np.testing.assert_array_equal(batch.reset(options={"time": single.time})[0][0], o)
        if shape and not (term or trunc):
            assert 0 < info["r_drift"] <= 1  # the training reward: the step reward times the drift's factor
    means = single.pop_term_means()
    for batch in batches:
        assert batch.pop_term_means() == pytest.approx(means, abs=1e-12)
        # (episodes aside: a batch's restart after its autoreset counts one more)
        assert {k: v for k, v in batch.counters.items() if v and k != "episodes"} == \
            {k: v for k, v in single.counters.items() if v and k != "episodes"}
        batch.close()
    assert len(set(rewards)) > 1 and (not shape or 0 < means["drift"] < 1)
    single.close()


def test_a_policy_of_some_joint_groups_acts_on_and_sees_those_alone(data_root):
    """env.policy_groups: the action is the chosen groups' corrections (the other joints follow the
    base: a zero action is the whole body's zero correction, step for step), the observation holds those
    joints' reference frames and state alone, and a policy on the others is refused in absolute mode."""
    from aslexp.errors import ConfigError

    kwargs = {**FREE_RESIDUAL, "env": deep_merge(FREE_RESIDUAL["env"], ARMS)}
    whole_env = deep_merge(FREE_RESIDUAL["env"], {k: v for k, v in ARMS.items() if k != "policy_groups"})
    arms = UpperBodyImitationEnv("00433", engine="mujoco", data_root=data_root, **kwargs)
    whole = UpperBodyImitationEnv("00433", engine="mujoco", data_root=data_root, **{**FREE_RESIDUAL, "env": whole_env})
    groups = [j.group for j in arms.layout.joints]
    values, speeds = arms.policy_seen
    chosen = [j for j in arms.layout.joints if j.group in ARMS["policy_groups"]]
    assert len(values) == sum(j.dof for j in chosen) == arms.action_space.shape[0] < whole.action_space.shape[0]
    assert len(speeds) == sum(1 if j.dof == 1 else 3 for j in chosen)
    assert "fingers" in groups and "wrist" in groups  # left to the controller
    # 2 frames ahead + positions + velocities: the hands' values gone from each
    hidden = (whole.layout.action_size - len(values)) * 3 + (whole.velocity_size - len(speeds))
    assert whole.observation_space.shape[0] - arms.observation_space.shape[0] == hidden
    a_obs, _ = arms.reset(seed=5)
    w_obs, _ = whole.reset(seed=5)
    for _ in range(12):
        a_obs, a_reward, *_ = arms.step(np.zeros(arms.action_space.shape, np.float32))
        w_obs, w_reward, *_ = whole.step(np.zeros(whole.action_space.shape, np.float32))
        assert a_reward == w_reward
    rng = np.random.default_rng(0)
    action = rng.uniform(-1, 1, arms.action_space.shape)
    full = arms.physical_action(action)
    others = np.setdiff1d(np.arange(arms.layout.action_size), values)
    assert np.all(full[others] == 0) and np.allclose(full[values], 0.2 * action)
    np.testing.assert_allclose(arms.normalize_action(arms.policy_part(full)), action)
    batch = BatchedImitationEnv(2, "00433", engine="mujoco", data_root=data_root, env_class=UpperBodyImitationEnv,
                                **kwargs)
    assert batch.single_action_space.shape == arms.action_space.shape
    assert batch.reset(seed=1)[0].shape == (2, arms.observation_space.shape[0])
    # the no-learning baselines drive every joint themselves: the same bar with or without policy_groups
    from aslexp.envs.baselines import Baseline, no_learning_baselines

    row = [Baseline.parse({"label": "thesis PD", "controller": "upper_body_thesis_code", "lookahead": [0, 1]})]
    assert ([b["reward"] for b in no_learning_baselines(arms.setup, row, seconds=1.0)]
            == [b["reward"] for b in no_learning_baselines(whole.setup, row, seconds=1.0)])
    from aslexp.rl.evaluate import baselines

    assert baselines(arms, 30) == baselines(whole, 30)
    for env in (arms, whole, batch):
        env.close()
    with pytest.raises(ConfigError, match="policy_groups.*needs action_mode residual"):
        UpperBodyImitationEnv("00433", engine="mujoco", data_root=data_root,
                              env={"policy_groups": ["shoulder"], "action_mode": "absolute"})
