"""PPO throughput against the number of environments: collection alone and whole PPO iterations.

    python bench/ppo_scaling.py                       # hand + upper body, 30 + 240 Hz, N = 1, 2, 4, ... cores
    python bench/ppo_scaling.py --bodies hand --rates 30 --steps 1024 --repeats 2   # a short check
    python bench/ppo_scaling.py --backends            # gymnasium AsyncVectorEnv vs torchrl ParallelEnv
    python bench/ppo_scaling.py --device cuda [--rollout-device learner]   # learner on a GPU

For each body and control rate, and each N (``ppo.num_envs``), one trainer is built with the
thesis' PPO settings (``--ppo-hand``, ``--ppo-upper-body``); one untimed iteration warms it up
(worker start, first episodes), then ``--repeats`` rounds time one iteration of every trainer in
turn (so that a change of load falls on all N alike): collection (the policy
on every environment's observation, the environments stepping, episode bookkeeping) and the
update (GAE and the PPO epochs). Printed per N: medians of steps/s of collection and of whole
iterations, the efficiency steps/s(N) / (N x steps/s(1)) against one environment in this
process (the default; the median of each round's own ratio), and the wall-clock of a 50 M-step run at that rate, without and with the
evaluations the config asks for (they run in the learner, at one environment's speed). Each N > 1
is measured in both worker modes (``--modes``): lockstep workers (``vector_env: async``, one round
trip per step, the policy batched in the learner) and rollout workers (``vector_env: workers``, the
policy in each worker, one round trip per rollout). N = 1 is also measured in one worker process
of each mode, to show what the inter-process round trips cost. All rows
of one body and rate come from the same run, so their ratios hold even on a loaded machine;
the absolute figures do not (the load average is printed).
"""

from __future__ import annotations

import argparse
import csv
import functools
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from aslexp.data.root import resolve_data_root  # noqa: E402
from aslexp.compose import group as load_group_file  # noqa: E402
from aslexp.paths import CONF_DIR  # noqa: E402
from aslexp.envs.imitation import ImitationEnv  # noqa: E402
from aslexp.envs.upper_body import UpperBodyImitationEnv  # noqa: E402
from aslexp.rl.ppo import PPOConfig, PPOTrainer  # noqa: E402
from aslexp.rl.vector import cpu_cores  # noqa: E402

BODIES = {"hand": (ImitationEnv, "motions/hand/A.txt"), "upper_body": (UpperBodyImitationEnv, "motions/upper_body/00433.txt")}
RUN_STEPS = 50_000_000


def default_envs() -> list[int]:
    """1, 2, 4, ... up to the cores present, and the core count itself."""
    n, out = 1, []
    while n <= cpu_cores():
        out.append(n)
        n *= 2
    return sorted(set(out) | {cpu_cores()})


def make_factory(body: str, rate: float, data_root: Path):
    cls, motion = BODIES[body]
    return functools.partial(cls, motion, env={"control_hz": rate}, data_root=data_root)


def ppo_config(name: str, **overrides) -> PPOConfig:
    base = load_group_file("ppo", "base")
    return PPOConfig.parse({**base, **load_group_file("ppo", name), **overrides})


def time_iteration(trainer: PPOTrainer) -> tuple[float, float]:
    """steps/s of one collection and of the whole iteration (collection + update)."""
    t0 = time.perf_counter()
    batch = trainer.collect()
    t1 = time.perf_counter()
    trainer.learn(batch)
    t2 = time.perf_counter()
    return trainer.config.batch_size / (t1 - t0), trainer.config.batch_size / (t2 - t0)


def measure(factory, configs: list[PPOConfig], repeats: int) -> list[list[tuple[float, float]]]:
    """steps/s of collection and of the whole iteration, per round and config.

    Every trainer is built and warmed up first (one untimed iteration: workers, first episodes,
    allocator); then each round times one iteration of every config in turn, so that a change
    of load on a shared machine falls on all of them alike and their ratios stay fair.
    """
    with tempfile.TemporaryDirectory() as out:
        trainers = []
        try:
            for k, config in enumerate(configs):
                trainers.append(PPOTrainer(factory, None, config, Path(out) / str(k), seed=0))
                trainers[-1].learn(trainers[-1].collect())
            return [[time_iteration(t) for t in trainers] for _ in range(repeats)]
        finally:
            for trainer in trainers:
                trainer.close()


def hours(rate: float, steps: int = RUN_STEPS) -> float:
    return steps / rate / 3600


def scaling(args, data_root: Path) -> list[dict]:
    rows = []
    for body in args.bodies:
        ppo_name = args.ppo_hand if body == "hand" else args.ppo_upper_body
        for rate in args.rates:
            factory = make_factory(body, rate, data_root)
            runs = ([(1, "sync")] + [(1, mode) for mode in args.modes] * args.async_one
                    + [(n, mode) for n in args.envs if n > 1 for mode in args.modes])
            print(f"\n### {body}, {rate:g} Hz control, ppo={ppo_name}", flush=True)
            print("| N | environments | collection steps/s | efficiency | iteration steps/s | efficiency "
                  "| 50 M steps, training only | with evaluations |")
            print("|---|---|---|---|---|---|---|---|")
            configs = []
            for n, mode in runs:
                overrides = dict(num_envs=n, vector_env=mode, device=args.device, rollout_device=args.rollout_device,
                                 torch_threads=args.torch_threads)
                if args.steps:
                    overrides["steps_per_rollout"] = args.steps
                configs.append(ppo_config(ppo_name, **overrides))
            rounds = measure(factory, configs, args.repeats)
            # Medians over rounds; the efficiencies are medians of each round's own ratio to the
            # first config (one environment in this process).
            reference = {"collect": statistics.median(r[0][0] for r in rounds)}
            for k, ((n, mode), config) in enumerate(zip(runs, configs)):
                rates = {"collect": statistics.median(r[k][0] for r in rounds),
                         "iteration": statistics.median(r[k][1] for r in rounds)}
                eff_c = statistics.median(r[k][0] / (n * r[0][0]) for r in rounds)
                eff_i = statistics.median(r[k][1] / (n * r[0][1]) for r in rounds)
                # Evaluations run in the learner at about one environment's collection speed.
                eval_steps = RUN_STEPS / config.eval_interval * len(config.phases) * config.eval_steps
                with_eval = hours(rates["iteration"]) + eval_steps / reference["collect"] / 3600
                kind = {"async": "lockstep", "workers": "rollout"}.get(mode, mode)
                where = "in process" if mode == "sync" else f"{n} {kind} worker{'s' if n > 1 else ''}"
                row = {"body": body, "rate_hz": rate, "ppo": ppo_name, "num_envs": n, "mode": mode,
                       "batch": config.batch_size, "collect_steps_per_s": round(rates["collect"], 1),
                       "collect_efficiency": round(eff_c, 3), "iteration_steps_per_s": round(rates["iteration"], 1),
                       "iteration_efficiency": round(eff_i, 3), "hours_50M": round(hours(rates["iteration"]), 2),
                       "hours_50M_with_eval": round(with_eval, 2)}
                rows.append(row)
                print(f"| {n} | {where} | {rates['collect']:,.0f} | {eff_c:.2f} | {rates['iteration']:,.0f} | "
                      f"{eff_i:.2f} | {row['hours_50M']:.1f} h | {row['hours_50M_with_eval']:.1f} h |", flush=True)
    return rows


# -- backends: gymnasium's AsyncVectorEnv against torchrl's ParallelEnv, no policy ---------------
def _stepping_rate(step, reset, num_envs: int, steps: int) -> float:
    reset()
    for _ in range(20):
        step()
    start = time.perf_counter()
    for _ in range(steps // num_envs):
        step()
    return (steps // num_envs) * num_envs / (time.perf_counter() - start)


def backend_rates(rate: float, data_root: Path, steps: int) -> dict[str, float]:
    from gymnasium.vector import AsyncVectorEnv, AutoresetMode, SyncVectorEnv

    from aslexp.rl.vector import START_METHOD, _DropInfoFactory

    factory = make_factory("hand", rate, data_root)
    out = {}
    env = factory()
    action = env.reference_action(1)

    def single_step():
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()

    out["one env, in process"] = _stepping_rate(single_step, lambda: env.reset(seed=0), 1, steps)
    env.close()
    for name, n in (("SyncVectorEnv, N = 1", 1), ("AsyncVectorEnv, N = 1", 1), ("AsyncVectorEnv, N = 2", 2)):
        fns = [_DropInfoFactory(factory)] * n
        vec = (SyncVectorEnv(fns, autoreset_mode=AutoresetMode.SAME_STEP) if name.startswith("Sync") else
               AsyncVectorEnv(fns, context=START_METHOD, autoreset_mode=AutoresetMode.SAME_STEP))
        actions = np.stack([action] * n)
        out[name] = _stepping_rate(lambda: vec.step(actions), lambda: vec.reset(seed=0), n, steps)
        vec.close()
    from torchrl.envs import ParallelEnv

    for n in (1, 2):
        penv = ParallelEnv(n, functools.partial(_torchrl_env, factory), mp_start_method=START_METHOD)
        td = penv.reset()
        actions = torch.as_tensor(np.stack([action] * n))

        def step():
            nonlocal td
            td["action"] = actions
            _, td = penv.step_and_maybe_reset(td)

        out[f"ParallelEnv, N = {n}"] = _stepping_rate(step, lambda: None, n, steps)
        penv.close()
    return out


def _torchrl_env(factory):
    from torchrl.envs import GymWrapper

    from aslexp.rl.vector import DropInfo

    return GymWrapper(DropInfo(factory()))


def backends(args, data_root: Path) -> None:
    results = {rate: [] for rate in args.rates}
    for _ in range(args.repeats):
        for rate in args.rates:
            results[rate].append(backend_rates(rate, data_root, args.backend_steps))
    names = list(results[args.rates[0]][0])
    print("| control steps/s | " + " | ".join(f"{r:g} Hz" for r in args.rates) + " |")
    print("|---|" + "---|" * len(args.rates))
    for name in names:
        cells = [f"{statistics.median(r[name] for r in results[rate]):,.0f}" for rate in args.rates]
        print(f"| {name} | " + " | ".join(cells) + " |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--bodies", nargs="+", default=list(BODIES), choices=list(BODIES))
    parser.add_argument("--rates", nargs="+", type=float, default=[30.0, 240.0], help="control rates (Hz)")
    parser.add_argument("--envs", nargs="+", type=int, default=default_envs(), help="values of N")
    parser.add_argument("--steps", type=int, default=None, help="steps per update (default: the PPO config's)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--ppo-hand", default="hand_thesis", help="conf/ppo file for the hand")
    parser.add_argument("--ppo-upper-body", default="upper_body_run1", help="conf/ppo file for the upper body")
    parser.add_argument("--device", default="cpu", help="the learner's device (auto, cpu, cuda)")
    parser.add_argument("--rollout-device", default="cpu", choices=["cpu", "learner"],
                        help="policy inference while collecting: on the CPU or on the learner's device")
    parser.add_argument("--torch-threads", type=int, default=1)
    parser.add_argument("--async-one", type=int, default=1, choices=[0, 1], help="also N = 1 in a worker process")
    parser.add_argument("--modes", nargs="+", default=["async", "workers"], choices=["async", "workers"],
                        help="vector_env modes for the worker rows: async (lockstep, the policy batched in the "
                             "learner) and workers (the policy in each worker, one message per rollout)")
    parser.add_argument("--csv", type=Path, default=None, help="also write the rows here")
    parser.add_argument("--backends", action="store_true", help="compare vector-env backends (hand, no policy)")
    parser.add_argument("--backend-steps", type=int, default=1500)
    args = parser.parse_args()
    torch.set_num_threads(args.torch_threads)
    data_root = resolve_data_root(None)
    print(f"# ppo_scaling: {cpu_cores()} cores, load {os.getloadavg()[0]:.1f}, torch {torch.__version__}, "
          f"learner {args.device}, rollout {args.rollout_device}, python {sys.version.split()[0]}, conf {CONF_DIR}", flush=True)
    start = time.perf_counter()
    if args.backends:
        backends(args, data_root)
    else:
        rows = scaling(args, data_root)
        if args.csv:
            args.csv.parent.mkdir(parents=True, exist_ok=True)
            with open(args.csv, "w", newline="", encoding="utf-8") as fh:
                writer = csv.DictWriter(fh, fieldnames=list(rows[0]))
                writer.writeheader()
                writer.writerows(rows)
    print(f"\n(load {os.getloadavg()[0]:.1f} at the end; {time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
