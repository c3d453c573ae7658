"""Upper-body imitation environment speed: where the time goes, naive loop vs the environment.

    nice -n 19 python bench/upper_body_env.py [--steps 300] [--motion motions/upper_body/00433.txt]
    nice -n 19 python bench/upper_body_env.py --convergence [--steps 300]

Speed (default) prints control steps/s (8 physics substeps each) for
  * raw physics: the thesis model PD-driven through the motion (targets precomputed, array motor
    calls), with the components switched off one at a time (self collision, motors, solver
    iterations, collision detection) to show what each costs;
  * a naive loop: the environment's work done the way the DeepMimic/thesis code does it (one
    PyBullet call per joint for motors, resets and joint states, one per link for link states,
    all links of both characters read every step), once with the configured solver and once with
    200 plain iterations (what a plain solver needs to converge, giving the same rewards);
  * the environment (array calls, only the links it observes and rewards, cached motion samples);
and checks that the naive loops and the environment produce the same rewards.
``--convergence`` prints the no-learning baselines (thesis controller one step ahead; the
reference-velocity controller with no correction) on the four signs for several solver settings
(iterations x non-contact inner iterations): the rewards a converged solve gives, and which
settings reach them.
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
from aslexp.sim.world import Character, PhysicsConfig, World, pack_joint_states, pack_link_states  # noqa: E402


def raw_physics(env: UpperBodyImitationEnv, steps: int, self_collision: bool = True, motors: bool = True,
                solver: tuple[int, int] | None = None, collision_detection: bool = True) -> float:
    """Control steps/s of the physics alone (PD targets precomputed, array motor calls);
    ``solver``: (iterations, non-contact inner iterations), default the env's;
    ``collision_detection=False`` takes every link out of collision detection (filter mask 0)."""
    spec = env.spec_env
    iterations, inner = solver or (spec.solver_iterations, spec.non_contact_inner_iterations)
    world = World(PhysicsConfig(spec.physics_hz, spec.gravity, iterations, inner))
    body = type(env.body_spec)(**{**env.body_spec.__dict__, "self_collision": self_collision})
    char = Character(world, env.urdf, body, env.layout, *env.reference.root(0.0)[:2])
    char.set_state(env.reference.joints(0.0))
    if not collision_detection:
        for link in range(-1, char.num_links):
            world.client.setCollisionFilterGroupMask(char.id, link, 0, 0)
    controller = PDController(env.controller_spec, env.layout)
    targets = [env.reference.joints((k + 1) * env.control_dt) for k in range(steps)]
    start = time.perf_counter()
    for target in targets:
        if motors:
            char.apply_pd(controller, target)
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
        pb = char.world.client
        return pack_joint_states(char.layout.joints,
                                 [pb.getJointStateMultiDof(char.id, joint.index) for joint in char.layout.joints])

    def _links(self, char: Character) -> np.ndarray:
        pb, indices = char.world.client, range(char.num_links)
        states = [pb.getLinkState(char.id, i, computeLinkVelocity=1, computeForwardKinematics=1) for i in indices]
        return pack_link_states(states, indices, char.num_links)

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


SIGNS = ("00433", "52861", "69318", "69546")
SOLVERS = ((10, 1), (50, 1), (200, 1), (5, 10), (10, 10))


def convergence(args: argparse.Namespace) -> None:
    """No-learning baselines per solver setting: which settings give the converged rewards."""
    from aslexp.rl.evaluate import evaluate, reference_policy

    print(f"mean reward over {args.steps} control steps from phase 0 (the thesis reward, upper_body_thesis), "
          f"thesis controller one step ahead | reference-velocity controller, no correction")
    print("| solver (iterations x inner) | controller | " + " | ".join(SIGNS) + " | control steps/s (median) |")
    print("|---|---|" + "---|" * len(SIGNS) + "---|")
    for iterations, inner in SOLVERS:
        for controller in ("upper_body", "upper_body_reference_velocity"):
            rewards, rates = [], []
            for sign in SIGNS:
                env = UpperBodyImitationEnv(
                    f"motions/upper_body/{sign}.txt", body=args.body, controller=controller,
                    env={"action_mode": "residual", "residual_range": 0.2, "reference_lookahead": 1,
                         "early_termination": {"min_reward": None}, "solver_iterations": iterations,
                         "non_contact_inner_iterations": inner})
                start = time.perf_counter()
                rewards.append(evaluate(env, reference_policy(1), args.steps).mean_reward)
                rates.append(args.steps / (time.perf_counter() - start))
                env.close()
            print(f"| {iterations} x {inner} | {controller} | " + " | ".join(f"{r:.3f}" for r in rewards)
                  + f" | {np.median(rates):.0f} |", flush=True)
    print(f"(load {os.getloadavg()[0]:.1f})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--motion", default="motions/upper_body/00433.txt")
    parser.add_argument("--body", default="upper_body_thesis")
    parser.add_argument("--convergence", action="store_true", help="rewards per solver setting (see above)")
    args = parser.parse_args()
    import torch

    torch.set_num_threads(1)
    if args.convergence:
        convergence(args)
        return
    overrides = {"episode_steps": args.steps + 1, "reference_state_init": False}
    env = UpperBodyImitationEnv(args.motion, body=args.body, env=overrides)
    plain = UpperBodyImitationEnv(args.motion, body=args.body,
                                  env={**overrides, "solver_iterations": 200, "non_contact_inner_iterations": 1})
    n, sub, spec = args.steps, env.spec_env.substeps, env.spec_env
    solver = (spec.solver_iterations, spec.non_contact_inner_iterations)
    print(f"body {args.body}: {env.sim.num_links} links, {env.layout.num_joints} actuated joints, "
          f"{spec.physics_hz:g} Hz physics, {sub} substeps, solver {solver[0]} iterations x {solver[1]} "
          f"non-contact inner iterations; control steps/s (physics steps/s = x {sub})")
    rows = [(f"raw physics, solver {solver[0]} x {solver[1]} (thesis flags)", raw_physics(env, n)),
            ("raw physics, no self collision", raw_physics(env, n, self_collision=False)),
            ("raw physics, no motors", raw_physics(env, n, motors=False)),
            ("raw physics, solver 1 x 1", raw_physics(env, n, solver=(1, 1))),
            ("raw physics, no motors, solver 1 x 1", raw_physics(env, n, motors=False, solver=(1, 1))),
            ("raw physics, no motors, 1 x 1, no collision detection",
             raw_physics(env, n, motors=False, solver=(1, 1), collision_detection=False)),
            ("raw physics, solver 200 x 1", raw_physics(env, n, solver=(200, 1)))]
    naive_rate, naive_rewards = NaiveLoop(env).run(n)
    plain_rate, plain_rewards = NaiveLoop(plain).run(n)
    env_rate, env_rewards = env_loop(env, n)
    rows += [(f"naive loop, solver {solver[0]} x {solver[1]}", naive_rate),
             ("naive loop, solver 200 x 1 (converged)", plain_rate),
             (f"environment, solver {solver[0]} x {solver[1]}", env_rate)]
    for label, rate in rows:
        print(f"  {label:54s} {rate:8.1f} control steps/s  ({rate * sub:8.0f} physics steps/s)")
    same = np.max(np.abs(np.asarray(naive_rewards) - np.asarray(env_rewards)))
    converged = np.abs(np.mean(plain_rewards) - np.mean(env_rewards))
    print(f"environment / naive loop, same solver: {env_rate / naive_rate:.2f}x; max |reward difference| per step "
          f"{same:.2e}")
    print(f"environment / naive loop with the 200-iteration solve: {env_rate / plain_rate:.2f}x; mean reward "
          f"{np.mean(env_rewards):.4f} vs {np.mean(plain_rewards):.4f} (|difference| {converged:.4f})")
    print(f"(one process, torch threads 1, cpu count {os.cpu_count()}, load {os.getloadavg()[0]:.1f}, "
          f"pybullet API {pybullet.getAPIVersion()})")
    env.close()
    plain.close()


if __name__ == "__main__":
    main()
