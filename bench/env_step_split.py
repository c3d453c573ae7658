"""Where a batched MuJoCo environment step goes, per environment: the physics, the two probe reads
(the bodies' frames for the observation, the references' tips for the reward) and the rest (numpy:
PD targets, observation, reward, ends), with the ratio of the whole step to the physics alone.

    python bench/env_step_split.py [--body hand|upper] [--n 1024] [--threads 1] [--seconds 2] [--stages]

One MuJoCo thread by default, so the split is of one core's time (more threads share out the
MuJoCo parts only; numpy stays on one). Every environment is driven by the reference one step
ahead (a training step without the policy; the actions' own cost is measured apart and left out), at
240 Hz (one physics step per action). ``--stages`` adds what each of MuJoCo's forward functions costs
on one state of the frames probe's model (one ``MjData``, best of 5): what a probe pays for beyond the
kinematics it needs.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import timeit

os.environ.setdefault("OMP_NUM_THREADS", "1")


from aslexp.data.root import resolve_data_root  # noqa: E402
from aslexp.envs.batched import BatchedImitationEnv  # noqa: E402
from aslexp.envs.imitation import ImitationEnv  # noqa: E402
from aslexp.envs.upper_body import UpperBodyImitationEnv  # noqa: E402

BODIES = {
    "hand": dict(env_class=ImitationEnv, motion="motions/hand/A.txt", env="hand_thesis", reward="hand_thesis"),
    "upper": dict(env_class=UpperBodyImitationEnv, motion="motions/upper_body/00433.txt", body={"base": "pinned"},
                  controller="upper_body_thesis_code", reward="upper_body_thesis", env="upper_body_thesis"),
}


def _us_per_env(run, n: int, seconds: float) -> float:
    """Median over 7 windows of one call's microseconds, per environment."""
    times = []
    for _ in range(7):
        calls, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 7:
            run()
            calls += 1
        times.append((time.perf_counter() - start) / calls / n * 1e6)
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--body", default="hand", choices=sorted(BODIES))
    parser.add_argument("--n", type=int, default=1024)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seconds", type=float, default=2.0)
    parser.add_argument("--stages", action="store_true", help="also each forward function's cost on one state")
    args = parser.parse_args()
    kwargs = dict(BODIES[args.body])
    motion = resolve_data_root(None) / kwargs.pop("motion")
    env = BatchedImitationEnv(args.n, motion, engine={"name": "mujoco", "threads": args.threads}, **kwargs)
    env.reset(seed=0)
    template, body, n = env.template, env.body, args.n

    def step() -> None:
        env.step(template.normalize_action(template.reference.joints_many(env.time + template.control_dt)))

    for _ in range(5):
        step()
    states = env.states.copy()
    ctrl = body.controls(template.reference.joints_many(env.time))
    driver = _us_per_env(lambda: template.normalize_action(template.reference.joints_many(env.time + template.control_dt)),
                         n, args.seconds)  # the actions' cost, the policy's part: not the environment's
    parts = {
        "whole environment step": _us_per_env(step, n, args.seconds) - driver,
        "physics (one mj_step, rollout)": _us_per_env(lambda: body.step(states.copy(), ctrl, 1), n, args.seconds),
        "frames probe (observation)": _us_per_env(lambda: body.read(states), n, args.seconds),
        "tips probe (the references' end effectors)": _us_per_env(lambda: body.read(states, tips_only=True), n,
                                                                   args.seconds),
    }
    rest = parts["whole environment step"] - sum(v for k, v in parts.items() if k != "whole environment step")
    print(f"{args.body}, N = {n}, {args.threads} MuJoCo thread(s), load average {os.getloadavg()[0]:.2f}")
    for name, value in [*parts.items(), ("the rest (numpy, copies)", rest)]:
        print(f"  {name:46s} {value:7.2f} us per environment")
    physics = parts["physics (one mj_step, rollout)"]
    print(f"  physics / whole step: {physics / parts['whole environment step']:.2f}; "
          f"with the rest free: {physics / (parts['whole environment step'] - rest):.2f}")
    if args.stages:
        _stages(body, states[0])
    env.close()


STAGES = ("mj_kinematics", "mj_comPos", "mj_crb", "mj_factorM", "mj_comVel", "mj_sensorPos", "mj_sensorVel",
          "mj_fwdPosition", "mj_fwdVelocity")


def _stages(body, state) -> None:
    """Microseconds per call of MuJoCo's forward functions on one state of the frames probe's model: a
    probe at the velocity stage runs mj_fwdPosition (kinematics, com, inertia and its factor, ...),
    mj_fwdVelocity and both sensor passes, where the frames need the kinematics and the velocities."""
    import mujoco

    model = body.probe
    data = mujoco.MjData(model)
    mujoco.mj_setState(model, data, state[:body.physics_size], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    print("  one state of the frames probe's model, us per call (best of 5 x 2,000):")
    for name in STAGES:
        call = getattr(mujoco, name)
        best = min(timeit.repeat(lambda: call(model, data), number=2000, repeat=5)) / 2000 * 1e6
        print(f"    {name:16s} {best:6.2f}")


if __name__ == "__main__":
    main()
