"""Letters x seeds of an imitation experiment trained as one program (aslexp.rl.stacked): figure 5.9's
runs (experiment=letters_thesis: the thesis' hand, PD, reward, 240 Hz and PPO) in one process.

    python bench/stacked_letters.py --letters A --seeds 0,1 --steps 4096 --out /tmp/stacked   # the CPU miniature
    python bench/stacked_letters.py --seeds 0-9 --minutes 8 --device cuda --out $OUT/letters  # on a GPU node

Every run is composed as ``aslexp imitate experiment=EXPERIMENT engine=mujoco motion=LETTER seed=SEED``
would compose it (``--set`` adds overrides, e.g. ``ppo.num_envs=64``), and all of them train together
(aslexp.jobs.stacked.train_together, what ``aslexp imitate -m ... hydra/launcher=stacked`` runs, without
the per-job figures and re-evaluation that cost seconds a run): their environments one MuJoCo batch,
their policies one stacked network. Each run's folder
(``OUT/<letter>_s<seed>``) holds its progress.csv (evaluations every ``ppo.eval_interval`` steps on
its own letter, from step 0), checkpoints/last.pt and .hydra/config.yaml (so ``aslexp imitate
policy=RUN`` performs its policy). ``OUT/summary.json`` and the printed table give,
per letter: the untrained policy's evaluation, the no-learning baselines under the same protocol,
and the last evaluation, mean ± std over seeds, with the steps reached and the program's steps/s.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402


def _seeds(text: str) -> list[int]:
    if "-" in text:
        low, high = text.split("-")
        return list(range(int(low), int(high) + 1))
    return [int(s) for s in text.split(",")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--experiment", default="letters_thesis")
    parser.add_argument("--letters", "--motions", dest="letters", default="A,B,C,D,E",
                        help="the motions (letters, or signs such as 00433,52861)")
    parser.add_argument("--seeds", default="0,1,2", help="0,1,2 or 0-9")
    parser.add_argument("--steps", type=int, help="ppo.total_steps per run (default: the experiment's)")
    parser.add_argument("--minutes", type=float, help="ppo.max_minutes: the program stops after this long")
    parser.add_argument("--device", default="cpu", help="the learner's device (ppo.device)")
    parser.add_argument("--engine", default="mujoco", help="an engine that batches (mujoco, mjx)")
    parser.add_argument("--set", nargs="*", default=[], help="more overrides, as on the imitate command line")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()

    from aslexp.compose import compose
    from aslexp.data.root import resolve_data_root
    from aslexp.jobs._imitation import build_envs
    from aslexp.jobs.stacked import train_together
    from aslexp.rl.checkpoint import load_checkpoint
    from aslexp.rl.evaluate import baselines
    from aslexp.rl.ppo import PPOConfig

    letters, seeds = args.letters.split(","), _seeds(args.seeds)
    overrides = [f"experiment={args.experiment}", f"engine={args.engine}", "ppo.vector_env=batched", f"ppo.device={args.device}",
                 "ppo.eval_at_start=true", *([f"ppo.total_steps={args.steps}"] if args.steps else []),
                 *([f"ppo.max_minutes={args.minutes}"] if args.minutes else []), *args.set]
    root = resolve_data_root(None)
    jobs = [(x, s, compose("imitate", [*overrides, f"motion='{x}'", f"seed={s}"])) for x in letters for s in seeds]
    import yaml

    for x, s, cfg in jobs:  # the run's config, as a job writes it: policy=RUN and re-evaluation rebuild from it
        hydra_dir = args.out / f"{x}_s{s}" / ".hydra"
        hydra_dir.mkdir(parents=True, exist_ok=True)
        (hydra_dir / "config.yaml").write_text(yaml.safe_dump(cfg, sort_keys=False))
    config = PPOConfig.parse(jobs[0][2]["ppo"])
    print(f"{len(jobs)} runs ({args.experiment}: letters {letters} x seeds {seeds}) as one program, "
          f"{config.num_envs} environments each, learner on {args.device}")
    start = time.perf_counter()
    program = train_together([cfg for _, _, cfg in jobs], [args.out / f"{x}_s{s}" for x, s, _ in jobs])
    base = {}
    for x in letters:  # the no-learning baselines under the runs' protocol, once per letter
        eval_env = build_envs(next(cfg for y, _, cfg in jobs if y == x), root, "batched")[1]
        base[x] = baselines(eval_env, config.eval_steps, config.phases)
        eval_env.close()
    histories = [load_checkpoint(args.out / f"{x}_s{s}" / "checkpoints" / "last.pt")["history"] for x, s, _ in jobs]
    seconds = time.perf_counter() - start
    table = {}
    for x in letters:
        mine = [h for (y, _, _), h in zip(jobs, histories) if y == x]
        last = [[r["eval_reward"] for r in h if "eval_reward" in r][-1] for h in mine]
        table[x] = {"untrained": float(np.mean([h[0]["eval_reward"] for h in mine])),
                    "baselines": {name: round(v, 5) for name, v in base[x].items()},
                    "last_eval": {"mean": float(np.mean(last)), "std": float(np.std(last, ddof=1)) if len(last) > 1 else 0.0,
                                  "values": last, "seeds": seeds}}
        print(f"{x}: untrained {table[x]['untrained']:.3f}  baselines "
              + "  ".join(f"{n} {v:.3f}" for n, v in base[x].items())
              + f"  learned {table[x]['last_eval']['mean']:.3f} ± {table[x]['last_eval']['std']:.3f} (n={len(last)})")
    summary = {"experiment": args.experiment, "overrides": overrides, "runs": len(jobs),
               "steps_per_run": program["steps_per_run"], "seconds": round(seconds, 1),
               "training_seconds": program["seconds"], "steps_per_s_all_runs": program["steps_per_s_all_runs"],
               "device": args.device, "letters": table}
    (args.out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(f"{program['steps_per_run']:,} steps per run in {seconds:.0f} s: {summary['steps_per_s_all_runs']:,} steps/s over "
          f"all runs; {args.out / 'summary.json'}")


if __name__ == "__main__":
    main()
