"""Upper-body imitation environment speed: where the time goes, naive loop vs the environment.

    nice -n 19 python bench/upper_body_env.py [--steps 300] [--motion motions/upper_body/00433.txt]

Prints control steps/s (8 physics substeps each) for
  * raw physics: the thesis model PD-driven through the motion (targets precomputed, array motor
    calls), with the components switched off one at a time (self collision, motors, solver
    iterations) to show what each costs;
  * a naive loop: the environment's work done the way the DeepMimic/thesis code does it (one
    PyBullet call per joint for motors, resets and joint states, one per link for link states,
    all links of both characters read every step);
  * the environment (array calls, only the links it observes and rewards, cached motion samples);
and checks that the naive loop and the environment produce the same rewards (same physics).
One process, torch threads 1; the machine's load is printed (other jobs share the 2 cores).
"""

from __future__ import annotations

import argparse
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import pybullet  # noqa: E402

from aslexp.envs.upper_body import UpperBodyImitationEnv  # noqa: E402
from aslexp.sim.pd import PDController  # noqa: E402
from aslexp.sim.world import Character, PhysicsConfig, World  # noqa: E402


def raw_physics(env: UpperBodyImitationEnv, steps: int, self_collision: bool = True, motors: bool = True,
                solver_iterations: int | None = None) -> float:
    """Control steps/s of the physics alone (PD targets precomputed, array motor calls)."""
    spec = env.spec_env
    iterations = solver_iterations or spec.solver_iterations
    world = World(PhysicsConfig(spec.physics_hz, spec.gravity, iterations))
    body = type(env.body_spec)(**{**env.body_spec.__dict__, "self_collision": self_collision})
    char = Character(world, env.urdf, body, env.layout, *env.reference.root(0.0)[:2])
    char.set_state(env.reference.joints(0.0))
    controller = PDController(env.controller_spec, env.layout)
    targets = [env.reference.joints((k + 1) * env.control_dt) for k in range(steps)]
    start = time.perf_counter()
    for target in targets:
        if motors:
            controller.apply(char, target)
        world.step(spec.substeps)
    rate = steps / (time.perf_counter() - start)
    world.close()
    return rate


class NaiveLoop:
    """The environment's step written with one PyBullet call per joint and per link (the thesis'
    DeepMimic-style code): same worlds, same physics, same reward function."""

    def __init__(self, env: UpperBodyImitationEnv) -> None:
        self.env = env

    def _set_state(self, char: Character, q: np.ndarray, qd: np.ndarray) -> None:
        pb, offset, voffset = char.world.client, 0, 0
        for joint in char.layout.joints:
            if joint.dof == 1:
                pb.resetJointState(char.id, joint.index, float(q[offset]), float(qd[voffset]))
                offset, voffset = offset + 1, voffset + 1
            else:
                w, x, y, z = q[offset:offset + 4]
                pb.resetJointStateMultiDof(char.id, joint.index, [x, y, z, w], list(qd[voffset:voffset + 3]))
                offset, voffset = offset + 4, voffset + 3

    def _joint_state(self, char: Character) -> tuple[np.ndarray, np.ndarray]:
        pb, q, qd = char.world.client, [], []
        for joint in char.layout.joints:
            pos, vel, *_ = pb.getJointStateMultiDof(char.id, joint.index)
            if joint.dof == 1:
                q.append(pos[0])
                qd.append(vel[0])
            else:
                q.extend([pos[3], pos[0], pos[1], pos[2]])
                qd.extend(vel)
        return np.asarray(q), np.asarray(qd)

    def _links(self, char: Character) -> np.ndarray:
        pb, out = char.world.client, np.zeros((char.num_links, 13))
        for i in range(char.num_links):
            s = pb.getLinkState(char.id, i, computeLinkVelocity=1, computeForwardKinematics=1)
            out[i, 0:3] = s[4]
            out[i, 3:7] = (s[5][3], s[5][0], s[5][1], s[5][2])
            out[i, 7:10], out[i, 10:13] = s[6], s[7]
        return out

    def _apply(self, char: Character, targets: np.ndarray) -> None:
        pb, ctl, offset = char.world.client, self.env.controller, 0
        for k, joint in enumerate(char.layout.joints):
            if joint.dof == 1:
                pb.setJointMotorControlMultiDof(char.id, joint.index, pb.POSITION_CONTROL,
                                                targetPosition=[float(targets[offset])], targetVelocity=[0.0],
                                                positionGain=ctl.kp[k], velocityGain=ctl.kd[k],
                                                force=[ctl.max_force[k]])
                offset += 1
            else:
                w, x, y, z = targets[offset:offset + 4] / np.linalg.norm(targets[offset:offset + 4])
                pb.setJointMotorControlMultiDof(char.id, joint.index, pb.POSITION_CONTROL,
                                                targetPosition=[x, y, z, w], targetVelocity=[0.0] * 3,
                                                positionGain=ctl.kp[k], velocityGain=ctl.kd[k],
                                                force=[ctl.max_force[k]] * 3)
                offset += 4

    def run(self, steps: int) -> tuple[float, list[float]]:
        from aslexp.envs.reward import PoseSnapshot

        env = self.env
        env.reset(options={"time": 0.0})
        rewards = []
        start = time.perf_counter()
        for _ in range(steps):
            targets = env.reference.motion._sample(env.time + env.control_dt)[env.reference._q_columns]
            self._apply(env.sim, np.clip(targets, env.joint_lower, env.joint_upper))
            env.sim_world.step(env.spec_env.substeps)
            env.time += env.control_dt
            links = self._links(env.sim)
            q, qd = self._joint_state(env.sim)
            base = env.sim.base_state()
            sim = PoseSnapshot(q, qd, env.sim.end_effector_positions(links), *base)
            frame_q = env.reference.motion._sample(env.time)[env.reference._q_columns]
            frame_qd = env.reference.joint_velocities(env.time)
            self._set_state(env.ref, frame_q, frame_qd)
            ref_links = self._links(env.ref)
            ref = PoseSnapshot(frame_q, frame_qd, env.ref.end_effector_positions(ref_links), *env.reference.root(env.time))
            reward, _, _ = env.reward_fn(sim, ref)
            env._observation(links)
            rewards.append(reward)
        return steps / (time.perf_counter() - start), rewards


def env_loop(env: UpperBodyImitationEnv, steps: int) -> tuple[float, list[float]]:
    env.reset(options={"time": 0.0})
    rewards = []
    start = time.perf_counter()
    for _ in range(steps):
        _, reward, _, _, _ = env.step(env.reference_action(1))
        rewards.append(reward)
    return steps / (time.perf_counter() - start), rewards


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--motion", default="motions/upper_body/00433.txt")
    parser.add_argument("--body", default="upper_body_thesis")
    parser.add_argument("--solver-iterations", type=int, default=None, help="override conf/env/upper_body")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    overrides = {"episode_steps": args.steps + 1, "reference_state_init": False}
    if args.solver_iterations:
        overrides["solver_iterations"] = args.solver_iterations
    env = UpperBodyImitationEnv(args.motion, body=args.body, env=overrides)
    n, sub = args.steps, env.spec_env.substeps
    print(f"body {args.body}: {env.sim.num_links} links, {env.layout.num_joints} actuated joints, "
          f"{env.spec_env.physics_hz:g} Hz physics, {sub} substeps, {env.spec_env.solver_iterations} solver "
          f"iterations; control steps/s (physics steps/s = x {sub})")
    rows = [("raw physics (thesis flags)", raw_physics(env, n)),
            ("raw physics, no self collision", raw_physics(env, n, self_collision=False)),
            ("raw physics, no motors", raw_physics(env, n, motors=False)),
            ("raw physics, 10 solver iterations", raw_physics(env, n, solver_iterations=10))]
    naive_rate, naive_rewards = NaiveLoop(env).run(n)
    env_rate, env_rewards = env_loop(env, n)
    rows += [("naive loop (per-joint/per-link calls)", naive_rate), ("environment", env_rate)]
    for label, rate in rows:
        print(f"  {label:42s} {rate:8.1f} control steps/s  ({rate * sub:8.0f} physics steps/s)")
    diff = np.max(np.abs(np.asarray(naive_rewards) - np.asarray(env_rewards)))
    print(f"environment / naive: {env_rate / naive_rate:.2f}x; max |reward difference| over {n} steps: {diff:.2e} "
          f"(mean reward {np.mean(env_rewards):.4f})")
    print(f"(one process, torch threads 1, cpu count {os.cpu_count()}, load {os.getloadavg()[0]:.1f}, "
          f"pybullet API {pybullet.getAPIVersion()})")
    env.close()


if __name__ == "__main__":
    main()
