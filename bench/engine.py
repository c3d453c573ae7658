"""Engine throughput: control steps/s of the PyBullet env, the MuJoCo env (one, and N per process
batched), and raw MuJoCo physics, for the hand and the upper body, in one run.

    python bench/engine.py [--seconds 3] [--sizes 1,16,64,256] [--threads 0] [--json PATH]

Every row drives the reference one step ahead as the PD target (the no-learning baseline: the
work of a training step without the policy): PD targets, physics, observation and reward.
Rows:
* ``pybullet env``: ``ImitationEnv`` (engine pybullet), one environment.
* ``mujoco env``: ``ImitationEnv`` with ``engine=mujoco``, one environment.
* ``mujoco batched N``: ``BatchedImitationEnv`` of N environments in this process.
* ``raw mujoco``: the physics alone: ``mujoco.rollout`` of 256 states with held controls (the
  ceiling the batched env approaches), and ``mj_step`` in a Python loop.
With ``--ppo N``: two rollouts and updates of ``ppo=hand_thesis`` (Table D.1: 2 x 1024 MLP,
10,240 steps per update, 10 epochs of minibatches of 128) on N batched MuJoCo hands, with the split
of time between collection (physics, observation, reward and the policy's inference) and learning,
and what that gives for 50 M steps.
Bodies: the hand (``env=hand_thesis``: 240 Hz, one physics step per action; and the 30 Hz
``env=default``), the upper body (``upper_body_thesis`` URDF, the authors' code's stable PD
(``controller=upper_body_thesis_code``), pinned base) at 240 Hz
(``env=upper_body_thesis``) and 30 Hz (the same at ``control_hz`` 30). Medians of 7 timed windows.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import time
from typing import Any

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402

from aslexp.envs.batched import BatchedImitationEnv  # noqa: E402
from aslexp.envs.imitation import ImitationEnv  # noqa: E402
from aslexp.envs.upper_body import UpperBodyImitationEnv  # noqa: E402

BODIES = {
    "hand 240 Hz": dict(cls=ImitationEnv, motion="motions/hand/A.txt",
                        kwargs=dict(env="hand_thesis", reward="hand_thesis")),
    "hand 30 Hz": dict(cls=ImitationEnv, motion="motions/hand/A.txt",
                       kwargs=dict(env="default", reward="hand_thesis")),
    "upper body 240 Hz": dict(cls=UpperBodyImitationEnv, motion="motions/upper_body/00433.txt",
                              kwargs=dict(body={"base": "pinned"}, controller="upper_body_thesis_code",
                                          reward="upper_body_thesis", env="upper_body_thesis")),
    "upper body 30 Hz": dict(cls=UpperBodyImitationEnv, motion="motions/upper_body/00433.txt",
                             kwargs=dict(body={"base": "pinned"}, controller="upper_body_thesis_code",
                                         reward="upper_body_thesis", env={"control_hz": 30, "physics_hz": 240})),
}


def _median_rate(run, repeats: int = 7) -> float:
    return statistics.median(run() for _ in range(repeats))


def single_rate(cls, motion: str, kwargs: dict, engine: str, seconds: float) -> float:
    env = cls(motion, engine=engine, **kwargs)
    env.reset(seed=0)

    def run() -> float:
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 7:
            _, _, terminated, truncated, _ = env.step(env.reference_action(1))
            steps += 1
            if terminated or truncated:
                env.reset()
        return steps / (time.perf_counter() - start)

    rate = _median_rate(run)
    env.close()
    return rate


def batched_rate(cls, motion: str, kwargs: dict, n: int, seconds: float, threads: int) -> float:
    env = BatchedImitationEnv(n, motion, engine={"name": "mujoco", "threads": threads}, env_class=cls, **kwargs)
    env.reset(seed=0)
    template = env.template

    def run() -> float:
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 7:
            # the reference one step ahead for every environment (its own time)
            targets = template.reference.joints_many(env.time + template.control_dt)
            env.step(template.normalize_action(targets).astype(np.float32))
            steps += n
        return steps / (time.perf_counter() - start)

    rate = _median_rate(run)
    env.close()
    return rate


def raw_rates(cls, motion: str, kwargs: dict, seconds: float, threads: int) -> tuple[float, float]:
    """Physics steps/s: rollout of 256 states (held controls), and mj_step in a Python loop."""
    import mujoco

    env = BatchedImitationEnv(256, motion, engine={"name": "mujoco", "threads": threads}, env_class=cls, **kwargs)
    env.reset(seed=0)
    body = env.body
    ctrl = body.controls(env.template.reference.joints_many(env.time))

    def run_rollout() -> float:
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 7:
            body.step(env.states, ctrl, 8)
            steps += 256 * 8
        return steps / (time.perf_counter() - start)

    data = mujoco.MjData(body.model)
    mujoco.mj_setState(body.model, data, env.states[0, :body.physics_size], mujoco.mjtState.mjSTATE_FULLPHYSICS)
    data.ctrl[:] = ctrl[0]

    def run_loop() -> float:
        steps, start = 0, time.perf_counter()
        while time.perf_counter() - start < seconds / 7:
            for _ in range(100):
                mujoco.mj_step(body.model, data)
            steps += 100
        return steps / (time.perf_counter() - start)

    rates = _median_rate(run_rollout), _median_rate(run_loop)
    env.close()
    return rates


def ppo_split(num_envs: int, device: str, threads: int, steps_per_rollout: int | None = None,
              rollout_device: str = "cpu", updates: int = 2, ppo: str = "hand_thesis",
              ppo_set: dict[str, Any] | None = None, env: str = "hand_thesis") -> dict[str, float]:
    """Collection and learning time of ``ppo`` updates (a conf/ppo file, ``ppo_set`` over it) on
    ``num_envs`` batched MuJoCo hands (letter A, ``env``; with more than two updates the first, which
    pays the device's warm-up, is left out)."""
    import functools
    import tempfile

    from aslexp.compose import resolve_group
    from aslexp.rl.ppo import PPOConfig, PPOTrainer

    values = {**resolve_group("ppo", ppo), **(ppo_set or {})}
    values.pop("defaults", None)
    if steps_per_rollout:  # a smaller update (the test's); the figures are for Table D.1's 10,240
        values["steps_per_rollout"] = steps_per_rollout
    config = PPOConfig.parse({**values, "num_envs": num_envs, "vector_env": "batched", "device": device,
                                  "rollout_device": rollout_device,
                                  "total_steps": updates * int(values["steps_per_rollout"]), "eval_interval": 10**9,
                                  "progress_interval": 1e9, "torch_threads": threads})
    make = functools.partial(BatchedImitationEnv, motion="motions/hand/A.txt", engine="mujoco",
                             env=env, reward="hand_thesis")
    with tempfile.TemporaryDirectory() as out:
        trainer = PPOTrainer(make, None, config, out, seed=0)
        result = trainer.train()
        trainer.close()
    rows = [h for h in result.history if "steps_per_s" in h]
    rows = rows[1:] if len(rows) > 2 else rows
    batch = config.batch_size
    collect = sum(batch / h["env_steps_per_s"] for h in rows)
    total = sum(batch / h["steps_per_s"] for h in rows)
    steps = batch * len(rows)
    return {"collect_steps_per_s": steps / collect, "learn_s_per_update": (total - collect) / len(rows),
            "steps_per_s": steps / total, "hours_for_50M": 50e6 / (steps / total) / 3600,
            "collection_hours_for_50M": 50e6 / (steps / collect) / 3600,
            "learn_ms_per_minibatch": 1000 * (total - collect) / len(rows) / (config.epochs * math.ceil(
                batch / config.minibatch_size))}


def _split_top(text: str) -> list[str]:
    """``a=1,b=[2,3]`` -> ["a=1", "b=[2,3]"] (commas inside brackets kept)."""
    items, depth, current = [], 0, ""
    for char in text:
        depth += 1 if char in "[{" else -1 if char in "]}" else 0
        if char == "," and depth == 0:
            items.append(current)
            current = ""
        else:
            current += char
    return [item for item in items + [current] if item.strip()]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--seconds", type=float, default=3.0, help="timed seconds per row (7 windows, the median reported)")
    parser.add_argument("--sizes", default="1,16,64,256", help="batch sizes N")
    parser.add_argument("--threads", type=int, default=0, help="MuJoCo threads (0: every core)")
    parser.add_argument("--bodies", default=",".join(BODIES), help="rows of " + ", ".join(BODIES) + " (none: only --ppo)")
    parser.add_argument("--json", default=None, help="also write the figures here")
    parser.add_argument("--ppo", type=int, default=0, help="also time hand_thesis PPO on this many batched hands")
    parser.add_argument("--device", default="cpu", help="the learner's device for --ppo (cpu | cuda)")
    parser.add_argument("--ppo-updates", type=int, default=2, help="--ppo: updates timed (> 2: the first left out)")
    parser.add_argument("--rollout-device", default="cpu", help="--ppo: policy inference while collecting: cpu | learner")
    parser.add_argument("--ppo-config", default="hand_thesis", help="--ppo: the conf/ppo file timed")
    parser.add_argument("--ppo-set", default="", help="--ppo: key=value,... over it (e.g. hidden_sizes=[64,64])")
    parser.add_argument("--ppo-env", default="hand_thesis", help="--ppo: the conf/env file (e.g. residual)")
    parser.add_argument("--ppo-steps-per-rollout", type=int, default=None,
                        help="--ppo with smaller updates than Table D.1's 10,240 steps (a quick check)")
    args = parser.parse_args()
    sizes = [int(n) for n in args.sizes.split(",")]
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    print(f"cores {cores}, load average {os.getloadavg()[0]:.2f}, MuJoCo threads {args.threads or cores}")
    results: dict[str, dict[str, float]] = {}
    try:
        import pybullet  # noqa: F401
        has_pybullet = True
    except ImportError:  # a machine without its wheel (Python 3.12 GPU images): MuJoCo rows only
        has_pybullet = False
        print("pybullet is not installed here: no PyBullet row")
    for name in [b.strip() for b in args.bodies.split(",") if b.strip() and b.strip() != "none"]:
        body = BODIES[name]
        row: dict[str, float] = {}
        if has_pybullet:
            row["pybullet env"] = single_rate(body["cls"], body["motion"], body["kwargs"], "pybullet", args.seconds)
        row["mujoco env"] = single_rate(body["cls"], body["motion"], body["kwargs"], "mujoco", args.seconds)
        for n in sizes:
            row[f"mujoco batched {n}"] = batched_rate(body["cls"], body["motion"], body["kwargs"], n, args.seconds,
                                                      args.threads)
        row["raw mujoco rollout 256 (physics steps/s)"], row["raw mujoco mj_step loop (physics steps/s)"] = raw_rates(
            body["cls"], body["motion"], body["kwargs"], args.seconds, args.threads)
        results[name] = row
        print(f"\n{name}")
        for key, value in row.items():
            print(f"  {key:44s} {value:12,.0f}")
        best = max(v for k, v in row.items() if k.startswith("mujoco batched"))
        substeps = 1 if "240" in name else 8
        if has_pybullet:
            print(f"  best batched / pybullet env                  {best / row['pybullet env']:12.1f}x")
        print(f"  best batched / raw rollout ceiling           "
              f"{best / (row['raw mujoco rollout 256 (physics steps/s)'] / substeps):12.2f}")
    if args.ppo:
        import yaml

        settings = {k: yaml.safe_load(v) for k, v in (item.split("=", 1) for item in _split_top(args.ppo_set))}
        split = ppo_split(args.ppo, args.device, cores, args.ppo_steps_per_rollout, args.rollout_device,
                          args.ppo_updates, args.ppo_config, settings, args.ppo_env)
        label = args.ppo_config + "".join(f" {k}={v}" for k, v in settings.items())
        results[f"ppo {label}"] = split
        print(f"\nppo={label}, env={args.ppo_env}, on {args.ppo} batched MuJoCo hands, learner on {args.device}, "
              f"rollout inference on {args.rollout_device}")
        for key, value in split.items():
            print(f"  {key:44s} {value:12,.2f}")
    print(f"\nload average at the end {os.getloadavg()[0]:.2f}")
    if args.json:
        os.makedirs(os.path.dirname(os.path.abspath(args.json)), exist_ok=True)
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(results, fh, indent=2)


if __name__ == "__main__":
    main()
