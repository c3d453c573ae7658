"""Imitation environment throughput, on one core, against raw PyBullet stepping of the same hand.

    python bench/imitation_env.py [--steps 3000] [--motion motions/hand/A.txt]

Prints: raw physics steps/s (the hand alone, 240 Hz, same solver settings, same process),
the control-step ceiling that implies (physics / substeps), the environment's control steps/s
(PD targets from the reference, reward, observation: everything a training step costs except
the policy) and their ratio; then the same with a small policy in the loop (PPO rollout speed).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from aslexp.envs.imitation import ImitationEnv  # noqa: E402
from aslexp.sim.world import Character, PhysicsConfig, World  # noqa: E402


def raw_physics_rate(env: ImitationEnv, control_steps: int) -> float:
    """Physics steps/s of the hand alone, PD-driven through the same motion (targets precomputed)."""
    spec = env.spec_env
    world = World(PhysicsConfig(spec.physics_hz, spec.gravity, spec.solver_iterations))
    char = Character(world, env.urdf, env.body_spec, env.layout, *env.reference.root(0.0)[:2])
    char.set_state(env.reference.joints(0.0))
    targets = [env.reference.joints((k + 1) * env.control_dt) for k in range(control_steps)]
    pb, ids = world.client, char.joint_indices
    kp, kd, force = env.controller.kp, env.controller.kd, env.controller.max_force
    start = time.perf_counter()
    for target in targets:
        pb.setJointMotorControlArray(char.id, ids, pb.POSITION_CONTROL, targetPositions=list(target),
                                     forces=force, positionGains=kp, velocityGains=kd)
        world.step(spec.substeps)
    rate = control_steps * spec.substeps / (time.perf_counter() - start)
    world.close()
    return rate


def env_rate(env: ImitationEnv, steps: int, policy=None) -> float:
    obs, _ = env.reset(seed=0)
    start = time.perf_counter()
    for _ in range(steps):
        action = env.reference_action(1) if policy is None else policy(obs)
        obs, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            obs, _ = env.reset()
    return steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--motion", default="motions/hand/A.txt")
    args = parser.parse_args()
    torch.set_num_threads(1)
    for name, env_cfg in (("default (absolute actions)", "default"), ("residual", "residual")):
        env = ImitationEnv(args.motion, env=env_cfg)
        substeps = env.spec_env.substeps
        physics = raw_physics_rate(env, args.steps)
        control = env_rate(env, args.steps)
        print(f"[{name}] raw PyBullet: {physics:,.0f} physics steps/s -> ceiling {physics / substeps:,.0f} "
              f"control steps/s ({substeps} substeps)")
        print(f"[{name}] environment: {control:,.0f} control steps/s = {control * substeps / physics:.2f} "
              f"of the raw-physics ceiling (overhead {1e3 / control - 1e3 * substeps / physics:.3f} ms/step)")
        from aslexp.rl.ppo import PPOConfig, make_agent

        for hidden in ((256, 256), (1024, 1024)):
            agent = make_agent(env, PPOConfig(hidden_sizes=hidden))
            rate = env_rate(env, args.steps // 2, lambda o: agent.act(o, deterministic=False))
            print(f"[{name}] with a {hidden} policy in the loop: {rate:,.0f} steps/s")
        env.close()
    print(f"(one process, torch threads 1, cpu count {os.cpu_count()}, load {os.getloadavg()[0]:.1f})")


if __name__ == "__main__":
    main()
