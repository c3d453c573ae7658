"""One policy, many motions: generated training motions like the letters, and a batch whose
rows each imitate a motion of a pool, step for step as single environments of those motions."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import numpy as np
import pytest
import job_process

from aslexp.compose import deep_merge, resolve_group
from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.batched import BatchedImitationEnv
from aslexp.envs.imitation import ImitationEnv
from aslexp.sim.motion import generated_motions, mean_joint_speed

LETTERS = ["A", "B", "C", "D", "E"]
# the letters' tracking setting, whole episodes (an early end would start a row on a drawn motion)
TRACKING = dict(engine="mujoco", reward="hand_thesis", controller="reference_velocity_tuned",
                env=deep_merge(resolve_group("env", "residual_velocity"), {"early_termination": {"min_reward": None}}))


def test_generated_motions_stay_inside_the_joint_limits_with_the_letters_durations_and_speeds(data_root):
    setup = ImitationSetup.from_groups("A", engine="mujoco", data_root=data_root)
    letters = [setup.load_motion(m) for m in LETTERS]
    lower = np.array([j.lower for j in setup.layout.joints])
    upper = np.array([j.upper for j in setup.layout.joints])
    motions = generated_motions(letters, lower, upper, count=40, seed=3)
    assert len(motions) == 40
    durations = {round(m.duration, 6) for m in letters}
    for motion in motions:
        joints = motion.frames[:, 7:]
        assert np.all(joints >= lower - 1e-12) and np.all(joints <= upper + 1e-12)
        assert round(motion.duration, 6) in durations and motion.loop == "wrap"
        np.testing.assert_allclose(motion.frames[:, :7], letters[0].frames[:1, :7].repeat(motion.num_frames, 0))
    speeds = [mean_joint_speed(m) for m in motions]
    letter_speeds = [mean_joint_speed(m) for m in letters]
    # the example's mean speed, less where the limits clip the scaled trajectory
    assert min(letter_speeds) * 0.6 <= np.median(speeds) <= max(letter_speeds) * 1.01
    assert len({m.frames[:, 7:].tobytes() for m in motions}) == 40  # all different
    again = generated_motions(letters, lower, upper, count=40, seed=3)
    assert all(np.array_equal(a.frames, b.frames) for a, b in zip(motions, again))  # the seed decides
    # a bad example width: one line naming it
    with pytest.raises(ValueError, match="values per frame"):
        generated_motions([letters[0]], lower[:3], upper[:3], count=1)


def test_a_batch_of_a_pool_is_single_environments_of_each_rows_motion(data_root):
    motions = ["C", "A", "E"]
    batch = BatchedImitationEnv(3, "A", motions=motions, data_root=data_root, **TRACKING)
    singles = [ImitationEnv(m, data_root=data_root, **TRACKING) for m in ["E", "C", "A"]]
    seeds = [5, 6, 7]
    obs = np.stack([e.reset(seed=s)[0] for e, s in zip(singles, seeds)])
    # rows 0, 1, 2 imitate pool motions 2 (E), 0 (C), 1 (A); each row's times drawn as its single env's
    batch_obs, _ = batch.reset(seed=seeds, options={"clip": [2, 0, 1]})
    np.testing.assert_array_equal(batch_obs, obs)  # the frames ahead in the observation: the row's motion
    rng = np.random.default_rng(2)
    space = batch.single_action_space
    for _ in range(60):
        actions = rng.uniform(space.low, space.high, size=(3, space.shape[0])).astype(np.float32)
        b_obs, b_reward, b_term, b_trunc, _ = batch.step(actions)
        for i, (e, a) in enumerate(zip(singles, actions)):
            o, r, term, trunc, _ = e.step(a)
            assert b_reward[i] == pytest.approx(r, abs=1e-12)
            assert (b_term[i], b_trunc[i]) == (term, trunc)
            np.testing.assert_array_equal(b_obs[i], o)
    # new episodes draw their motion from the pool, row by row, and count them per motion
    batch.reset(seed=11)
    for _ in range(20):
        batch._start(np.arange(3), {})
    assert np.all(batch.clip_episodes > 0) and batch.clip_episodes.sum() == 3 * 22  # 2 resets, 20 more starts
    ref = batch.pool.references[int(batch.clip[0])]
    future = batch._observe(np.arange(1), batch._read(np.arange(1))[0])[0]
    ahead = ref.joints_many(np.array([batch.time[0] + 1 / 30]))[0]
    assert any(np.allclose(future[k:k + len(ahead)], ahead) for k in range(len(future) - len(ahead) + 1))
    with pytest.raises(ValueError, match="clip 3 for a pool of 3 motions"):
        batch.reset(options={"clip": 3})
    batch.close()
    for e in singles:
        e.close()


def _imitate(*overrides: str, data_root) -> subprocess.CompletedProcess:
    env = {**os.environ, "ASLEXP_DATA_ROOT": str(data_root), "MPLBACKEND": "Agg"}
    return job_process.run([sys.executable, "-m", "aslexp.cli", "imitate", *overrides], capture_output=True,
                          text=True, timeout=600, env=env)


def test_a_pool_policy_trains_without_its_motion_and_performs_any_motion_from_its_run_folder(data_root, tmp_path):
    """experiment=letters_unseen on C (tiny): C never in the pool; `policy=RUN` performs C again (the
    same score: the same policy, motion and protocol) and another motion, nothing trained, each a
    complete run folder; a folder without a checkpoint is one line and no folder."""
    policy = tmp_path / "policy"
    tiny = ["ppo.total_steps=512", "ppo.num_envs=8", "ppo.steps_per_rollout=256", "ppo.eval_interval=512",
            "ppo.critic_warmup_steps=0", "ppo.eval_steps=30", "ppo.eval_episodes=2", "ppo.hidden_sizes=[32,32]",
            "train_motions.generated.count=3", "render.gif=false", "plots=false"]
    proc = _imitate("experiment=letters_unseen", "motion=C", *tiny, f"hydra.run.dir={policy}", data_root=data_root)
    assert proc.returncode == 0, proc.stderr[-3000:]
    trained = json.loads((policy / "metrics.json").read_text())
    assert trained["train_motions"] == {"listed": ["A", "B", "D", "E"], "generated": 3, "held_out": "C", "count": 7}
    assert trained["steps"] == 512 and trained["eval_protocol"]["episodes"] == 2

    again = tmp_path / "again"
    proc = _imitate("motion=C", f"policy={policy}", "plots=false", "render.gif=false", f"hydra.run.dir={again}",
                    data_root=data_root)
    assert proc.returncode == 0, proc.stderr[-3000:]
    performed = json.loads((again / "metrics.json").read_text())
    assert performed["stopped"] == "performed" and performed["steps"] == 0
    assert performed["last_eval"] == trained["last_eval"]
    assert performed["baselines"] == pytest.approx(trained["baselines"])
    assert performed["policy"]["trained_on"]["held_out"] == "C"

    tuning = tmp_path / "tuning"
    proc = _imitate("motion=tuning", f"policy={policy}", f"hydra.run.dir={tuning}", data_root=data_root)
    assert proc.returncode == 0, proc.stderr[-3000:]
    made = json.loads((tuning / "metrics.json").read_text())
    assert made["motion"] == "tuning" and 0.0 < made["last_eval"] <= 1.0 and made["last_eval_diverged"] == 0
    assert {"run.json", "metrics.json", "imitation.gif", "tracking.png"} <= {p.name for p in tuning.iterdir()}
    assert json.loads((tuning / "run.json").read_text())["status"] == "completed"

    proc = _imitate("motion=C", f"policy={tmp_path / 'none'}", f"hydra.run.dir={tmp_path / 'refused'}",
                    data_root=data_root)
    assert proc.returncode == 2 and "no checkpoint" in proc.stderr and len(proc.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "refused").exists()
