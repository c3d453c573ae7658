"""``aslexp plan``: a planner drives the body on a motion (model-predictive control); nothing is trained.

    aslexp plan motion=A                                       # planner=mpc on the hand's controller
    aslexp plan -m experiment=letters_mpc                      # the letters' ceiling (an overlay of imitate's)
    aslexp plan experiment=signs_mpc "motion='00433'"          # a sign on the upper body

The groups and keys are the imitate job's (conf/plan.yaml includes conf/imitate.yaml and chooses
``planner: mpc``); runs go to outputs/plan/. ``aslexp imitate planner=...`` calls the same function.
The planner is scored under the run's evaluation protocol (``ppo.eval_phases``/``eval_episodes``,
``ppo.eval_steps``) beside the same baselines a trained run measures, with its cost per control step
(metrics.json ``planner``); tracking_baseline.png shows the controller it plans on. The last log line
compares the planner with the best no-learning baseline.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from aslexp.errors import ConfigError
from aslexp.jobs._common import job_main
from aslexp.jobs._imitation import Bench, finish, imitation_main

log = logging.getLogger("aslexp.imitate")


def plan(cfg: dict[str, Any], out_dir: Path, reporter=None, metric_logger=None) -> dict[str, Any]:
    """``planner=...``: the planner drives the body (aslexp.control.mpc), scored under the run's
    evaluation protocol beside the baselines; the run's own controller with a zero correction (the
    planner's zero sequence) is what it adds to."""
    from aslexp.control.mpc import PlannerSpec, evaluate_planner
    from aslexp.rl.evaluate import evaluate_phases, reference_policy
    from aslexp.rl.ppo import PPOConfig

    if not cfg.get("planner"):
        raise ConfigError("planner: null; expected a planner config (planner=mpc)")
    spec = PlannerSpec.parse(dict(cfg["planner"]))
    ppo = dataclasses.replace(PPOConfig.parse(cfg["ppo"]), num_envs=1, vector_env="sync", total_steps=0)
    bench = Bench.open(cfg, out_dir, ppo, learned=False)
    try:
        # rl.evaluate.baselines measures the controller already when it has target options
        controller = bench.base.get("reference_velocity_pd")
        if controller is None:
            controller = evaluate_phases(bench.eval_env, reference_policy(bench.eval_env.spec_env.reference_lookahead),
                                         ppo.eval_steps, ppo.phases).mean_reward
        started = time.perf_counter()
        planned = evaluate_planner(spec, bench.eval_env.setup, ppo.phases, ppo.eval_steps,
                                   label=f"{spec.name} on {cfg['motion']['name']}")
        log.info("motion %s: planner %s %.4f (the controller alone %.4f), %.3f s per control step",
                 cfg["motion"]["name"], spec.name, planned["reward"], controller, planned["seconds_per_step"])
        own = {"last_eval": round(planned["reward"], 5), "best_eval": round(planned["reward"], 5),
               "last_eval_diverged": int(planned["diverged"]), "last_eval_scores": {}, "last_eval_divergences": [],
               "planner": {**dataclasses.asdict(spec), **planned, "controller_alone": controller},
               "steps": 0, "seconds": round(time.perf_counter() - started, 2), "stopped": "planned"}
        # the planner's episodes are not recorded: the figures show the controller it plans on
        return finish(bench, None, own, shown="the controller the planner plans on", video=False)
    finally:
        bench.close()


@job_main("plan")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns the planner's reward."""
    return imitation_main("plan", cfg, plan)


if __name__ == "__main__":
    main()
