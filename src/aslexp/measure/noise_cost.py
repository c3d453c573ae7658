"""What exploration noise alone costs a run's controller: no learning, the residual policy's zero
action plus noise of each colour (:mod:`aslexp.rl.noise`) and size, in the run's TRAINING episodes
(its env config as trained: reference state initialisation, a fall ends the episode).

PPO learns from these episodes and is scored on deterministic ones; the further apart the two are,
the less an update that helps the first need help the second. Per noise: the mean reward per step,
the episode length and how many episodes fell.

    python -m aslexp.measure.noise_cost outputs/imitate-multirun/<sweep>/<run> --betas 0,1,2 --log-std -1.75 --episodes 24
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.rl.noise import ActionNoise


def noise_cost(env, beta: float | None, log_std: float, episodes: int, seed: int = 0, steps: int | None = None,
               horizon: int = 300) -> dict[str, Any]:
    """``episodes`` episodes of ``env`` under its box centre plus ``exp(log_std)`` x noise of colour
    ``beta`` (in half-widths of the action box, as the policy's; ``beta`` None: no noise). Episode
    ``k`` resets with seed ``seed + k`` and draws its noise from the same seed."""
    low, high = env.action_space.low.astype(np.float64), env.action_space.high.astype(np.float64)
    centre, half = (low + high) / 2, (high - low) / 2
    limit = steps or int(env.spec_env.episode_steps)
    rewards, lengths, falls = [], [], 0
    for k in range(episodes):
        env.reset(seed=seed + k)
        noise = ActionNoise(len(centre), seed + k, beta, horizon) if beta is not None else None
        total, length = 0.0, 0
        for _ in range(limit):
            eps = noise.sample().numpy() if noise is not None else 0.0
            _, reward, terminated, truncated, _ = env.step((centre + half * np.exp(log_std) * eps).astype(np.float32))
            total, length = total + float(reward), length + 1
            if terminated or truncated:
                falls += int(terminated)
                break
        rewards.append(total / length)
        lengths.append(length)
    return {"beta": beta, "log_std": log_std, "episodes": episodes, "reward_per_step": float(np.mean(rewards)),
            "reward_std": float(np.std(rewards)), "episode_length": float(np.mean(lengths)), "falls": falls}


def main(argv: list[str] | None = None) -> str:
    parser = argparse.ArgumentParser(prog="python -m aslexp.measure.noise_cost", description=__doc__.split("\n\n")[0])
    parser.add_argument("run_dir", type=Path, help="a run folder (its .hydra/config.yaml builds the env)")
    parser.add_argument("--betas", default="0,0.5,1,2", help="noise colours: 0 white, 1 pink, 2 red")
    parser.add_argument("--log-std", default="-1.75", help="noise sizes, log of box half-widths (comma-separated)")
    parser.add_argument("--episodes", type=int, default=24)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--steps", type=int, default=None, help="steps per episode at most (default: the env's)")
    parser.add_argument("--horizon", type=int, default=300, help="steps of one coloured sequence")
    args = parser.parse_args(argv)

    from aslexp.measure.residual import run_env
    from aslexp.reports.report import run_config

    cfg = run_config(args.run_dir)
    env = run_env(cfg)  # as trained: its training episodes
    names = {0.0: "white", 0.5: "beta 0.5", 1.0: "pink", 2.0: "red"}
    settings = [(None, 0.0)] + [(float(b), float(s)) for s in args.log_std.split(",") for b in args.betas.split(",")]
    lines = [f"motion {cfg['motion']['name']}, {args.episodes} training episodes per row (RSI; a fall ends one)",
             "| noise | std (box half-widths) | reward per step | episode length | falls |", "|---|---|---|---|---|"]
    started = time.perf_counter()
    try:
        for done, (beta, log_std) in enumerate(settings, 1):
            row = noise_cost(env, beta, log_std, args.episodes, args.seed, args.steps, args.horizon)
            name = "none (the controller)" if beta is None else names.get(beta, f"beta {beta:g}")
            std = "0" if beta is None else f"{np.exp(log_std):.3f} (log-std {log_std:g})"
            lines.append(f"| {name} | {std} | {row['reward_per_step']:.3f} ± {row['reward_std']:.3f} | "
                         f"{row['episode_length']:.0f} | {row['falls']}/{row['episodes']} |")
            each = (time.perf_counter() - started) / done
            print(f"{done}/{len(settings)} noises ({each:.0f} s each, ETA {each * (len(settings) - done):.0f} s)",
                  file=sys.stderr, flush=True)
    finally:
        env.close()
    table = "\n".join(lines)
    print(table)
    return table


if __name__ == "__main__":
    main()
