"""Many runs as one program (aslexp.rl.stacked) against the same runs one at a time.

    python bench/stacked_runs.py                       # the letters' thesis PPO, R = 1, 2, 5, 10 runs
    python bench/stacked_runs.py --runs 1,5 --steps 2048 --repeats 3 --device cuda   # on a GPU
    python bench/stacked_runs.py --ppo fast --steps 4096    # a 256 x 256 learner (ppo=fast)

Per R: one StackedPPO of R runs (letters A-E in turn, a seed each) with ``ppo=hand_thesis``'s learner
(10 environments per run, minibatch 128, 10 epochs; ``--steps`` shrinks the update, all else the
thesis' setting) on the hand of ``env=hand_thesis`` on MuJoCo; one untimed update warms it up, then
``--repeats`` updates are timed, collection and learning apart. Beside it, one PPOTrainer run of the
same setting alone (the R = 1 cost the program is compared with). Printed: medians of steps/s for
all runs together, per run, and the speed-up over R runs one after another
(steps/s(R together) / steps/s(one run alone)).
"""

from __future__ import annotations

import argparse
import functools
import json
import os
import statistics
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

from aslexp.compose import group  # noqa: E402
from aslexp.data.root import resolve_data_root  # noqa: E402
from aslexp.envs.batched import BatchedImitationEnv  # noqa: E402
from aslexp.rl.ppo import PPOConfig, PPOTrainer  # noqa: E402
from aslexp.rl.stacked import StackedPPO, StackedRun  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--runs", default="1,2,5,10")
    parser.add_argument("--steps", type=int, default=10240, help="steps per update per run (thesis: 10240)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--ppo", default="hand_thesis", help="the conf/ppo file (its num_envs per run)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args()
    root = resolve_data_root(None)
    letters = [root / "motions" / "hand" / f"{x}.txt" for x in "ABCDE"]
    ppo = {k: v for k, v in group("ppo", args.ppo).items() if k != "defaults"}
    config = PPOConfig.parse({**ppo, "steps_per_rollout": args.steps, "vector_env": "batched", "device": args.device,
                              "batched_workers": 0})

    def factory(motions):
        return functools.partial(BatchedImitationEnv, motion=motions[0], motions=list(motions), engine="mujoco",
                                 env="hand_thesis", reward="hand_thesis")

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        alone = PPOTrainer(factory(letters[:1]), None, config, Path(tmp) / "alone", seed=0)
        times = []
        for k in range(args.repeats + 1):
            t0 = time.perf_counter()
            alone.learn(alone.collect())
            if k:
                times.append(time.perf_counter() - t0)
        alone.close()
        alone_rate = config.batch_size / statistics.median(times)
        print(f"one run alone (PPOTrainer): {alone_rate:,.0f} steps/s")
        for count in (int(x) for x in args.runs.split(",")):
            runs = [StackedRun(seed=r, out_dir=Path(tmp) / f"r{r}", clip=r % len(letters)) for r in range(count)]
            program = StackedPPO(factory(letters[:min(count, len(letters))]), runs, config)
            collect, learn = [], []
            for k in range(args.repeats + 1):
                program.learning_rate = config.scheduled(program.steps)[0]
                t0 = time.perf_counter()
                batch = program.collect()
                t1 = time.perf_counter()
                program.learn(batch)
                if k:
                    collect.append(t1 - t0)
                    learn.append(time.perf_counter() - t1)
            program.close()
            total = count * config.batch_size / (statistics.median(collect) + statistics.median(learn))
            row = {"runs": count, "steps_per_s": round(total), "per_run": round(total / count),
                   "collect_s": round(statistics.median(collect), 3), "learn_s": round(statistics.median(learn), 3),
                   "speedup_over_one_at_a_time": round(total / alone_rate, 2)}
            rows.append(row)
            print(f"R={count:3d}: {total:9,.0f} steps/s in all, {total / count:8,.0f} per run; collect "
                  f"{row['collect_s']:.2f} s, learn {row['learn_s']:.2f} s per update; "
                  f"x{row['speedup_over_one_at_a_time']:.2f} over one run at a time")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"alone_steps_per_s": round(alone_rate), "rows": rows,
                                         "load": os.getloadavg(), "device": args.device}, indent=1))


if __name__ == "__main__":
    main()
