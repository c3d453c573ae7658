"""engine=mjx throughput: physics steps/s of an MJX batch on its device (the device-resident path,
no host copy), and control steps/s of BatchedImitationEnv on it (numpy in and out, as PPO collects),
beside engine=mujoco's batched environment, for the hand and the upper body.

    python bench/mjx_engine.py [--sizes 1,64,256] [--env-sizes 1,64,256] [--bodies hand,upper]
                               [--seconds 2] [--json PATH]

Rows, each the median of 5 timed windows after a compiling warm-up (its seconds reported as
``compile_s``):
* ``mjx physics N``: ``MjxBody.device_step`` of N states under held controls (the reference's
  targets), one control step of substeps per call, then ``device_read`` (every link frame and tip,
  what the observation and reward need) and its hand-off to torch through DLPack: physics steps/s
  (N x substeps per call) and control steps/s (N per call).
* ``mjx env N`` / ``mujoco env N``: ``BatchedImitationEnv`` of N environments, the reference one
  step ahead as the action (the work of a training step without the policy): control steps/s.
Bodies: ``hand`` (the thesis hand and PD, ``env=default``: 30 Hz, 8 physics steps of 240 Hz per
action), ``upper`` (the upper body, the authors' code's stable PD, pinned base, ``env=upper_body_thesis``
at 30 Hz control). On a GPU the sizes go to 65,536 (bench/gpu_mjx.sh).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path

import numpy as np

from aslexp.envs.assembly import ImitationSetup
from aslexp.envs.batched import BatchedImitationEnv
from aslexp.envs.imitation import ImitationEnv
from aslexp.envs.upper_body import UpperBodyImitationEnv

BODIES = {
    "hand": dict(cls=ImitationEnv, motion="motions/hand/A.txt", groups=dict(reward="hand_thesis", env="default")),
    "upper": dict(cls=UpperBodyImitationEnv, motion="motions/upper_body/00433.txt",
                  groups=dict(body="upper_body_thesis", controller="upper_body_thesis_code", reward="upper_body_thesis",
                              env={"control_hz": 30, "physics_hz": 240})),
}


def _timed(run, seconds: float, windows: int = 5) -> float:
    """The median rate of ``run`` (one call: returns the steps it did) over timed windows."""
    rates = []
    for _ in range(windows):
        steps, start = 0, time.perf_counter()
        while True:
            steps += run()
            spent = time.perf_counter() - start
            if spent >= seconds / windows:
                break
        rates.append(steps / spent)
    return statistics.median(rates)


def _setup(name: str, engine) -> ImitationSetup:
    body = BODIES[name]
    groups = dict(body["groups"])
    if body["cls"] is UpperBodyImitationEnv:
        defaults = UpperBodyImitationEnv.GROUP_DEFAULTS
        return ImitationSetup.from_groups(body["motion"], groups.pop("body"), groups.pop("controller"),
                                          groups["reward"], groups["env"], engine, defaults=defaults)
    return ImitationSetup.from_groups(body["motion"], None, None, groups["reward"], groups["env"], engine)


def physics_rows(name: str, sizes: list[int], seconds: float, engine: dict) -> list[dict]:
    """``mjx physics N`` rows: the device-resident step, read and hand-off to torch."""
    import jax

    from aslexp.sim.mjx_engine import to_torch

    env = BODIES[name]["cls"].from_setup(_setup(name, engine))
    body, substeps = env.simulation.batch, env.spec_env.substeps
    body.set_gains(env.controller)
    rows = []
    for n in sizes:
        host = body.new_states(n)
        times = np.linspace(0.0, env.reference.duration, n, endpoint=False)
        body.write(host, slice(None), env.reference.joints_many(times), env.reference.joint_velocities_many(times),
                   *env.reference.root_many(times))
        targets = env.reference.joints_many(times + env.control_dt)
        ctrl = jax.device_put(np.asarray(body.controls(targets), dtype=np.float32), body.device)
        states = [body.device_states(host)]

        def run() -> int:
            states[0], peak, _, _ = body.device_step(states[0], ctrl, substeps)
            tensor = to_torch(body.device_read(states[0]))
            tensor.sum().item()  # the learner's first use waits for the physics
            return n

        start = time.perf_counter()
        run()
        compile_s = time.perf_counter() - start
        rate = _timed(run, seconds)
        finite = bool(np.isfinite(np.asarray(states[0])).all())
        rows.append({"row": f"mjx physics {n}", "body": name, "n": n, "device": str(body.device),
                     "control_steps_per_s": rate, "physics_steps_per_s": rate * substeps, "compile_s": compile_s,
                     "finite": finite})
        print(f"{name:6s} mjx physics {n:6d}: {rate * substeps:12,.0f} physics steps/s, {rate:11,.0f} control "
              f"steps/s ({body.device}, compile {compile_s:.1f} s, finite {finite})", flush=True)
    env.close()
    return rows


def env_rows(name: str, sizes: list[int], seconds: float, engine) -> list[dict]:
    """``<engine> env N`` rows: BatchedImitationEnv, the reference one step ahead."""
    label = engine if isinstance(engine, str) else engine["name"]
    rows = []
    for n in sizes:
        env = BatchedImitationEnv.from_setup(n, _setup(name, engine), env_class=BODIES[name]["cls"])
        env.reset(seed=0)
        template = env.template

        def run() -> int:
            targets = template.reference.joints_many(env.time + template.control_dt)
            env.step(template.normalize_action(targets).astype(np.float32))
            return n

        start = time.perf_counter()
        run()
        compile_s = time.perf_counter() - start
        rate = _timed(run, seconds)
        diverged = env.call("counter_values")[0].get("diverged", 0)
        env.close()
        rows.append({"row": f"{label} env {n}", "body": name, "n": n, "control_steps_per_s": rate,
                     "compile_s": compile_s, "diverged": diverged})
        print(f"{name:6s} {label:6s} env {n:6d}: {rate:11,.0f} control steps/s (first step {compile_s:.1f} s, "
              f"diverged {diverged})", flush=True)
    return rows


def _sizes(text: str) -> list[int]:
    return [int(n) for n in text.split(",") if n.strip()]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", default="1,64,256", help="N of the mjx physics rows ('' for none)")
    parser.add_argument("--env-sizes", default="1,64,256", help="N of the env rows ('' for none)")
    parser.add_argument("--engines", default="mjx,mujoco", help="engines of the env rows")
    parser.add_argument("--bodies", default="hand,upper")
    parser.add_argument("--seconds", type=float, default=2.0, help="timed seconds per row")
    parser.add_argument("--engine-set", default="", help="JSON over conf/engine/mjx.yaml, e.g. '{\"max_geom_pairs\": 8}'")
    parser.add_argument("--json", default=None)
    args = parser.parse_args(argv)
    mjx = {"name": "mjx", "module": "aslexp.sim.mjx_engine", **(json.loads(args.engine_set) if args.engine_set else {})}
    rows = []
    for name in [b for b in args.bodies.split(",") if b]:
        if _sizes(args.sizes):
            rows += physics_rows(name, _sizes(args.sizes), args.seconds, mjx)
        for engine in [e for e in args.engines.split(",") if e]:
            if _sizes(args.env_sizes):
                rows += env_rows(name, _sizes(args.env_sizes), args.seconds, mjx if engine == "mjx" else engine)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    result = {"cores": cores, "engine": mjx, "command": " ".join(sys.argv), "rows": rows}
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
