"""What PyBullet's joint-speed clamp costs MuJoCo's batched hands (engine.joint_speed_limit).

    python bench/joint_speed_clamp.py [--size 256] [--seconds 1.5] [--repeats 5] [--threads 1]

N batched hands of letter A at 240 Hz (the thesis' hand, PD and rate) driven two ways: by the
reference one step ahead (joints stay under 100 rad/s: the clamp only checks) and by random targets
drawn anew at every step inside the joint box (an untrained policy's worst case: joints pass 100
rad/s and the clamp re-steps those hands), each stepped alternately with the clamp (100 rad/s, the
default) and without it, in one process: control steps per second, medians over the repeats, their
ratio, and how often the clamp acted.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=256, help="hands in the batch")
    parser.add_argument("--seconds", type=float, default=1.5, help="per measurement")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1, help="engine.threads")
    parser.add_argument("--data-root", default=None)
    args = parser.parse_args(argv)

    from aslexp.data.root import resolve_data_root
    from aslexp.envs.batched import BatchedImitationEnv

    motion = Path(resolve_data_root(args.data_root)) / "motions" / "hand" / "A.txt"
    envs = {name: BatchedImitationEnv(args.size, motion, env="hand_thesis", reward="hand_thesis",
                                      engine={"name": "mujoco", "joint_speed_limit": limit, "threads": args.threads})
            for name, limit in (("clamped", 100.0), ("unclamped", None))}
    space = envs["clamped"].single_action_space
    reference = np.stack([envs["clamped"].template.reference_action(1)] * args.size)
    rng = np.random.default_rng(0)
    drives = {"reference": lambda: reference,
              "random targets": lambda: rng.uniform(space.low, space.high, size=(args.size, space.shape[0]))}
    for drive, actions in drives.items():
        rates: dict[str, list[float]] = {name: [] for name in envs}
        acted = {}
        for name, env in envs.items():
            env.reset(seed=0)
            acted[name] = env.body.clamped_steps
        for _ in range(args.repeats):
            for name, env in envs.items():  # alternated: a change of load hits both alike
                start, steps = time.perf_counter(), 0
                while time.perf_counter() - start < args.seconds:
                    env.step(actions())
                    steps += args.size
                rates[name].append(steps / (time.perf_counter() - start))
        clamped = envs["clamped"].body.clamped_steps - acted["clamped"]
        total = sum(rates["clamped"]) * args.seconds  # about: the control steps measured, clamped
        print(f"{drive}: " + ", ".join(f"{name} {np.median(v):,.0f}" for name, v in rates.items())
              + f" control steps/s (medians of {args.repeats}); clamped / unclamped "
              f"{np.median(rates['clamped']) / np.median(rates['unclamped']):.3f}; the clamp acted on "
              f"{clamped:,} environment steps (about {100 * clamped / max(total, 1):.1f}%)")
    for env in envs.values():
        env.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
