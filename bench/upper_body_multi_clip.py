"""One multi-clip policy for all signs vs one policy per sign, at equal environment steps.

    nice -n 19 python bench/upper_body_multi_clip.py [--steps-per-sign 20000] [--out outputs/multi_clip]
    nice -n 19 python bench/upper_body_multi_clip.py --controller upper_body_reference_velocity \
        --env upper_body_residual_velocity --critic-warmup-steps 8192 --steps-per-sign 16384

Per-sign: a PPO run of ``steps_per_sign`` steps on each sign. Multi-clip: one PPO run of
``steps_per_sign x signs`` steps on :class:`~aslexp.envs.multi_clip.MultiClipImitationEnv` (a clip
drawn per episode, one-hot clip code in the observation). Both use the same env and controller
configs (default env=upper_body_residual, controller=upper_body) and ppo=upper_body_fast (batch
sizes scaled down with --small); the table gives the deterministic evaluation reward per sign (from
phase 0) of the final policies, beside the no-learning baseline of the same controller (a zero
residual: the one-step lookahead for controller=upper_body).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

SIGNS = ("00433", "52861", "69318", "69546")


def main() -> None:
    import torch

    from aslexp.compose import deep_merge, resolve_group
    from aslexp.envs.multi_clip import MultiClipImitationEnv
    from aslexp.envs.upper_body import UpperBodyImitationEnv
    from aslexp.rl.evaluate import evaluate, evaluate_clips, reference_policy
    from aslexp.rl.ppo import PPOConfig, PPOTrainer

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps-per-sign", type=int, default=20000)
    parser.add_argument("--signs", nargs="+", default=list(SIGNS))
    parser.add_argument("--eval-steps", type=int, default=90)
    parser.add_argument("--small", action="store_true", help="small rollouts/network (a smoke run)")
    parser.add_argument("--out", default="outputs/multi_clip")
    parser.add_argument("--env", default="upper_body_residual", help="conf/env group file")
    parser.add_argument("--controller", default="upper_body", help="conf/controller group file")
    parser.add_argument("--critic-warmup-steps", type=int, default=0)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    env_cfg = resolve_group("env", args.env)
    controller = resolve_group("controller", args.controller)
    ppo = resolve_group("ppo", "upper_body_fast")
    ppo = deep_merge(ppo, {"eval_steps": args.eval_steps, "max_minutes": None, "name": "multi_clip_bench",
                           "critic_warmup_steps": args.critic_warmup_steps})
    if args.small:
        ppo = deep_merge(ppo, {"hidden_sizes": [64, 64], "steps_per_rollout": 512, "minibatch_size": 128,
                               "eval_interval": 1024})
    motions = [f"motions/upper_body/{s}.txt" for s in args.signs]
    eval_cfg = deep_merge(env_cfg, {"early_termination": {"min_reward": None}})
    rows: dict[str, dict[str, float]] = {}

    for sign, motion in zip(args.signs, motions):
        config = PPOConfig.parse({**ppo, "total_steps": args.steps_per_sign})
        env = UpperBodyImitationEnv(motion, env=env_cfg, controller=controller)
        eval_env = UpperBodyImitationEnv(motion, env=eval_cfg, controller=controller)
        start = time.perf_counter()
        trainer = PPOTrainer(env, eval_env, config, out / f"single_{sign}", seed=args.seed)
        trainer.train()
        result = evaluate(eval_env, lambda o, e: trainer.agent.act(o), args.eval_steps).mean_reward
        base = evaluate(eval_env, reference_policy(1), args.eval_steps).mean_reward
        rows[sign] = {"baseline": base, "per_sign": result, "per_sign_minutes": (time.perf_counter() - start) / 60}
        print(sign, rows[sign], flush=True)
        env.close()
        eval_env.close()

    config = PPOConfig.parse({**ppo, "total_steps": args.steps_per_sign * len(motions)})
    env = MultiClipImitationEnv(motions, env=env_cfg, controller=controller)
    eval_env = MultiClipImitationEnv(motions, env=eval_cfg, cycle=True, controller=controller)
    start = time.perf_counter()
    trainer = PPOTrainer(env, eval_env, config, out / "multi_clip", seed=args.seed)
    trainer.train()
    per_clip = evaluate_clips(eval_env, lambda o, e: trainer.agent.act(o), args.eval_steps)
    minutes = (time.perf_counter() - start) / 60
    for sign in args.signs:
        rows[sign]["multi_clip"] = per_clip[sign]
    print(f"\n{args.controller} / {args.env}, seed {args.seed}")
    print(f"| sign | no-learning baseline | per-sign policy ({args.steps_per_sign} steps) | "
          f"multi-clip policy ({args.steps_per_sign * len(motions)} steps, all signs) |\n|---|---|---|---|")
    for sign, row in rows.items():
        print(f"| {sign} | {row['baseline']:.3f} | {row['per_sign']:.3f} | {row['multi_clip']:.3f} |")
    print(f"multi-clip training: {minutes:.1f} min; per-sign: "
          f"{sum(r['per_sign_minutes'] for r in rows.values()):.1f} min (load {os.getloadavg()[0]:.1f})")
    (out / "multi_clip_vs_per_sign.json").write_text(json.dumps(rows, indent=2))
    env.close()
    eval_env.close()


if __name__ == "__main__":
    main()
