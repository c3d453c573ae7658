"""engine=mjx beside engine=mujoco: the same model read the same way, the same short trajectories
within a stated tolerance (MJX computes in single precision), PyBullet's joint-speed clamp, both
bodies, the batched environment unchanged on it; and on a GPU, the device-resident path to torch.

The tolerances: link frames and tips read from one state agree to 1e-5 (float32 against float64);
the rewards of 1 s of letter A under the thesis PD, and of 0.25 s of sign 00433 under the authors'
stable PD (pinned, 240 Hz), agree per step to 2e-3 and in their mean to 1e-3 (docs/engines.md, "MJX", has what was
measured). XLA compiles each batch size and substep count once per process (tens of seconds on
the CPU), so every test here uses one environment (the hand at 30 Hz); compilations persist in
``~/.cache/aslexp/jax`` (JAX_COMPILATION_CACHE_DIR overrides it) across runs.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

jax = pytest.importorskip("jax", reason="engine=mjx needs jax and mujoco-mjx (pip install -e '.[mjx]')")
pytest.importorskip("mujoco.mjx", reason="engine=mjx needs mujoco-mjx (pip install -e '.[mjx]')")
jax.config.update("jax_compilation_cache_dir",
                  os.environ.get("JAX_COMPILATION_CACHE_DIR", str(Path.home() / ".cache" / "aslexp" / "jax")))

from aslexp.envs.assembly import ImitationSetup  # noqa: E402
from aslexp.envs.batched import BatchedImitationEnv  # noqa: E402
from aslexp.envs.imitation import ImitationEnv  # noqa: E402
from aslexp.envs.tracking import reference_rollout  # noqa: E402
from aslexp.envs.upper_body import UpperBodyImitationEnv  # noqa: E402
from aslexp.errors import ConfigError  # noqa: E402
from aslexp.sim.engine import EngineSpec  # noqa: E402

pytestmark = [pytest.mark.slow, pytest.mark.xdist_group("mjx")]  # one worker compiles the bodies once

HAND = dict(env="default", reward="hand_thesis")  # the thesis PD (position, kp 0.22, kd 0.87), 30 Hz
UPPER = dict(controller="upper_body_thesis_code", reward="upper_body_thesis", env="upper_body_thesis")


def _gpu() -> bool:
    try:
        return bool(jax.devices("gpu"))
    except RuntimeError:
        return False


def test_mjx_reads_a_state_as_the_mujoco_engine_reads_it(data_root):
    setup = ImitationSetup.from_groups(data_root / "motions/hand/A.txt", None, None, "hand_thesis", "default", "mjx")
    mjx_sim, cpu_sim = setup.simulation(), setup.merged(engine="mujoco").simulation()
    try:
        mjx_body, cpu_body = mjx_sim.batch, cpu_sim.batch
        assert type(mjx_body).__name__ == "MjxBody" and type(cpu_body).__name__ == "MujocoBody"
        rng = np.random.default_rng(0)
        states = cpu_body.new_states(1)
        rotation = rng.normal(size=4)
        cpu_body.write(states, slice(None), rng.uniform(-0.5, 0.5, (1, cpu_body.model.nq)),
                       rng.uniform(-2, 2, (1, cpu_body.model.nv)), np.array([[0.1, 0.2, 0.3]]),
                       (rotation / np.linalg.norm(rotation))[None])
        cpu, mjx = cpu_body.read(states), mjx_body.read(states)
        np.testing.assert_allclose(mjx_body.frames(mjx), cpu_body.frames(cpu), atol=1e-5)  # every link moved by the root
        np.testing.assert_allclose(mjx_body.tips(mjx), cpu_body.tips(cpu), atol=1e-5)
        np.testing.assert_allclose(mjx_body.read(states, tips_only=True), cpu_body.read(states, tips_only=True), atol=1e-5)
    finally:
        mjx_sim.close()
        cpu_sim.close()


@pytest.mark.parametrize("cls, motion, kwargs, seconds", [
    (ImitationEnv, "motions/hand/A.txt", HAND, 1.0),
    (UpperBodyImitationEnv, "motions/upper_body/00433.txt", dict(UPPER, body={"base": "pinned"}), 0.25),
], ids=["hand-thesis-pd", "upper-body-stable-pd"])
def test_a_short_trajectory_on_mjx_is_the_mujoco_engines_within_tolerance(data_root, cls, motion, kwargs, seconds):
    rewards = {}
    for engine in ("mujoco", "mjx"):
        env = cls(data_root / motion, engine=engine, **kwargs)
        try:
            steps = int(round(seconds * env.spec_env.control_hz))
            run = reference_rollout(env, steps, lookahead=1)
            assert not run.ended_early and len(run.rewards) == steps
            rewards[engine] = np.asarray(run.rewards)
        finally:
            env.close()
    assert np.all((rewards["mjx"] > 0.0) & (rewards["mjx"] <= 1.0))
    np.testing.assert_allclose(rewards["mjx"], rewards["mujoco"], atol=2e-3)
    assert abs(rewards["mjx"].mean() - rewards["mujoco"].mean()) < 1e-3


def test_mjx_clamps_joint_speed_as_the_mujoco_engine_does(data_root):
    envs = [ImitationEnv(data_root / "motions/hand/A.txt", engine=engine, **HAND) for engine in ("mujoco", "mjx")]
    try:
        for env in envs:
            env.reset(options={"time": 0.3})
            q, qd = env.sim.joint_state()
            qd[[2, 6]] = [400.0, -250.0]  # two fingers far past PyBullet's 100 rad/s
            env.sim.set_state(q, qd)
            env.step(env.reference_action(1))
        (cpu, mjx) = envs
        q_cpu, qd_cpu = cpu.sim.joint_state()
        q_mjx, qd_mjx = mjx.sim.joint_state()
        assert np.max(np.abs(qd_mjx)) <= 100.0 + 1e-3
        assert mjx.sim.peak_speed > 100.0 and mjx.sim.body.clamped_steps > 0
        assert mjx.sim.peak_joint == cpu.sim.peak_joint
        assert mjx.sim.body.clamped_steps == cpu.sim.body.clamped_steps
        assert mjx.sim.peak_speed == pytest.approx(cpu.sim.peak_speed, rel=1e-3)
        np.testing.assert_allclose(q_mjx, q_cpu, atol=1e-3)
        np.testing.assert_allclose(qd_mjx, qd_cpu, atol=0.05)
    finally:
        for env in envs:
            env.close()


def test_the_batched_environment_runs_unchanged_on_mjx(data_root):
    motion = data_root / "motions/hand/C.txt"
    batches = [BatchedImitationEnv(1, motion, engine=engine, **HAND) for engine in ("mujoco", "mjx")]
    try:
        assert [b.reset(seed=[3])[0].shape for b in batches] == [(1, batches[0].single_observation_space.shape[0])] * 2
        np.testing.assert_allclose(batches[1].reset(seed=[3])[0], batches[0].reset(seed=[3])[0], atol=1e-4)
        rng = np.random.default_rng(2)
        space = batches[0].single_action_space
        for _ in range(8):
            actions = rng.uniform(space.low, space.high, size=(1, space.shape[0])).astype(np.float32) * 0.3
            (_, r_cpu, *_), (_, r_mjx, *_) = (b.step(actions) for b in batches)
            assert r_mjx[0] == pytest.approx(r_cpu[0], abs=2e-3)
        assert batches[1].call("counter_values")[0]["diverged"] == 0
    finally:
        for b in batches:
            b.close()


def test_the_mjx_engine_refuses_what_mjx_cannot_run():
    with pytest.raises(ConfigError, match=r"engine\.solver=PGS: expected one of Newton, CG"):
        EngineSpec.parse({"name": "mjx", "module": "aslexp.sim.mjx_engine", "solver": "PGS"})
    with pytest.raises(ConfigError, match=r"engine\.integrator=implicit"):
        EngineSpec.parse({"name": "mjx", "module": "aslexp.sim.mjx_engine", "integrator": "implicit"})
    spec = EngineSpec.parse({"name": "mjx", "module": "aslexp.sim.mjx_engine", "max_geom_pairs": 6})
    assert spec.options.max_geom_pairs == 6 and spec.options.joint_speed_limit == 100.0


@pytest.mark.skipif(not _gpu(), reason="needs a GPU that jax sees (jax finds none)")
def test_on_a_gpu_the_physics_stays_on_the_device_and_torch_reads_it_without_a_copy(data_root):
    import torch

    from aslexp.sim.mjx_engine import from_torch, to_torch

    setup = ImitationSetup.from_groups(data_root / "motions/hand/A.txt", None, None, "hand_thesis", "default", "mjx")
    sim = setup.simulation()
    try:
        body = sim.batch
        assert body.device.platform == "gpu"
        n = 256
        states = body.device_states(body.new_states(n))
        ctrl = from_torch(torch.zeros((n, body.model.nu), device="cuda"))
        states, peak, _, _ = body.device_step(states, ctrl, 8)
        sensors = body.device_read(states)
        assert states.devices() == {body.device} and sensors.devices() == {body.device}
        tensor = to_torch(sensors)
        assert tensor.is_cuda and tensor.shape == (n, sensors.shape[1])
        assert tensor.data_ptr() == sensors.unsafe_buffer_pointer()  # DLPack: the same memory
        assert torch.isfinite(tensor).all() and np.all(np.asarray(peak) < 100.0)
        # and it agrees with the CPU engine from the same state
        cpu = setup.merged(engine="mujoco").simulation()
        try:
            host = cpu.batch.new_states(1)
            cpu.batch.set_gains(None)
            body.set_gains(None)
            mine = body.new_states(1)
            body.step(mine, np.zeros((1, body.model.nu)), 8)
            cpu.batch.step(host, np.zeros((1, body.model.nu)), 8)
            np.testing.assert_allclose(mine[:, body.slices["qpos"]], host[:, body.slices["qpos"]], atol=1e-4)
        finally:
            cpu.close()
    finally:
        sim.close()
