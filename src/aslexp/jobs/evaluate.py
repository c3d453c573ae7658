"""``aslexp evaluate``: measure a policy or the controller alone on a motion; nothing is trained.

    aslexp evaluate motion=A                                   # the no-learning baselines only, and figures
    aslexp evaluate <the run's overrides> resume=RUN ppo.eval_episodes=16   # re-evaluate a trained run
    aslexp evaluate motion.file=FILE policy=RUN_DIR            # a trained policy performs a motion
    aslexp evaluate motion.file=FILE policy=RUN_DIR engine=NAME       # ... on another engine than its own

The groups and keys are the imitate job's (conf/evaluate.yaml includes conf/imitate.yaml), so a run's
own overrides re-evaluate it; runs go to outputs/evaluate/. ``aslexp imitate`` keeps its forms of the
same (``ppo.total_steps=0``, ``resume=`` with no steps left, ``policy=``): they call these functions.
The run folder gets metrics.json (the baselines, the evaluation, the best no-learning baseline),
tracking.png, tracking_baseline.png and imitation.gif/.mp4; the last log line compares the
evaluated policy with the best no-learning baseline.
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
from aslexp.jobs._imitation import (Bench, evaluated, finish, imitation_main, open_trainer, resume_path,
                                    told_on_command_line, trained_steps, trainer_metrics, training_pool)

log = logging.getLogger("aslexp.imitate")


def _in_process(ppo):
    """Nothing trains: one environment in this process, no workers."""
    return dataclasses.replace(ppo, num_envs=1, vector_env="sync", batched_workers=0, total_steps=0)


def baselines_only(cfg: dict[str, Any], out_dir: Path, reporter=None, metric_logger=None) -> dict[str, Any]:
    """The no-learning baselines under the run's protocol, the untrained policy's level (kept as such,
    never as the run's result) and figures of the controller on the reference one step ahead."""
    from aslexp.rl.ppo import PPOConfig

    bench = Bench.open(cfg, out_dir, _in_process(PPOConfig.parse(cfg["ppo"])), learned=False)
    try:
        trainer, _ = open_trainer(bench, reporter, metric_logger)
        started = time.perf_counter()
        try:
            untrained = evaluated(trainer, "no_training")
            counters = trainer.counters()
        finally:
            trainer.close()
        # The untrained policy is a level, not the run's result: its blow-up (a fresh policy's targets
        # far from the reference) is recorded and said, and the baselines stay the run's result.
        diverged = untrained.pop("last_eval_diverged")
        own = {**untrained, "untrained_eval": None if diverged else untrained["last_eval"],
               "untrained_eval_diverged": diverged, "last_eval": None, "best_eval": None,
               **trainer_metrics(trainer, started, counters)}
        return finish(bench, None, own, history=trainer.history,
                      shown="nothing trained, the controller on the reference one step ahead")
    finally:
        bench.close()


def re_evaluate(cfg: dict[str, Any], out_dir: Path, reporter=None, metric_logger=None) -> dict[str, Any]:
    """``resume=RUN``: a trained checkpoint evaluated under this config's protocol (e.g. a finished run
    under more start phases; ``stopped: evaluated``). Its training steps and history come with it;
    nothing is trained, whatever ``ppo.total_steps`` says."""
    from aslexp.rl.ppo import PPOConfig
    from aslexp.runs.read import resume_origin

    checkpoint = resume_path(cfg.get("resume"), cfg)  # a wrong run folder stops here, before any work
    if checkpoint is None:
        raise ConfigError("resume: expected a run folder or a checkpoint to re-evaluate, got null")
    pool = training_pool(cfg)  # recorded: what the policy trained on
    bench = Bench.open(cfg, out_dir, _in_process(PPOConfig.parse(cfg["ppo"])), learned=True, pool=pool,
                       train_on_pool=False)
    try:
        trainer, _ = open_trainer(bench, reporter, metric_logger)  # the run's rows were logged by the run
        try:
            trainer.restore(checkpoint)  # a corrupt or mismatched checkpoint stops here
            selected = checkpoint.parent / "selected.pt"
            if selected.is_file():  # a validated run ends on the policy its validation chose
                trainer.load_policy(selected)
            started = time.perf_counter()
            own = evaluated(trainer, "evaluated" if trainer.steps > 0 else "no_training")
            counters = trainer.counters()
        finally:
            trainer.close()
        own.update(resumed_from=resume_origin(checkpoint, trainer.steps), **trainer_metrics(trainer, started, counters))
        together = _trained_together(checkpoint, out_dir)
        if together is not None:  # a run of a stacked program (aslexp.jobs.stacked), finished in its own folder
            own.pop("resumed_from")
            own.update(stopped=together["stopped"], num_envs=together["num_envs"], trained_together=together)
            start = next((h["eval_reward"] for h in trainer.history if h["step"] == 0 and "eval_reward" in h), None)
            if start is not None:  # ppo.eval_at_start: where it began, as a run trained alone records it
                own["untrained_eval"] = start
            return finish(bench, trainer.evaluation_agent().act, own, history=trainer.history, shown="last policy")
        return finish(bench, trainer.evaluation_agent().act, own, history=trainer.history, shown="the resumed policy")
    finally:
        bench.close()


def _trained_together(checkpoint: Path, out_dir: Path) -> dict[str, Any] | None:
    """The program a checkpoint of this very folder was trained in, when it was one of many runs
    trained together (its ``stacked`` entry: runs, seconds, why it stopped, environments per run)."""
    from aslexp.rl.checkpoint import load_checkpoint

    if checkpoint.parent.parent.resolve() != Path(out_dir).resolve():
        return None
    payload = load_checkpoint(checkpoint)
    together = payload.get("stacked")
    return None if together is None else {**together, "num_envs": int(payload.get("num_envs", 1))}


def perform(cfg: dict[str, Any], out_dir: Path, reporter=None, metric_logger=None,
            keep_engine: bool = False) -> dict[str, Any]:
    """``policy=RUN_DIR``: a trained policy performs this run's motion under its own run's setting
    (aslexp.jobs.performing), on its own engine unless ``keep_engine`` (this command named one).
    Nothing is trained; there is no reward curve (the policy's run has it)."""
    from aslexp.jobs.performing import performing_config
    from aslexp.rl.ppo import PPOConfig

    cfg, performer = performing_config(cfg, keep=("engine",) if keep_engine else ())
    log.info("motion %s: performed by the policy of %s on %s (%s)", cfg["motion"]["name"], performer["run"],
             performer["engine"], performer["engine_chosen_by"])
    bench = Bench.open(cfg, out_dir, _in_process(PPOConfig.parse(cfg["ppo"])), learned=False)
    try:
        trainer, _ = open_trainer(bench, reporter, metric_logger)
        try:
            trainer.load_policy(performer["checkpoint"])  # the weights alone: no steps, no history
            started = time.perf_counter()
            own = evaluated(trainer, "performed")
            counters = trainer.counters()
        finally:
            trainer.close()
        own.update(policy=performer, **trainer_metrics(trainer, started, counters))
        return finish(bench, trainer.evaluation_agent().act, own, history=trainer.history, curve=False,
                      shown="the policy")
    finally:
        bench.close()


def evaluate(cfg: dict[str, Any], out_dir: Path, reporter=None, metric_logger=None) -> dict[str, Any]:
    """The job without Hydra: ``policy=`` performs, ``resume=`` re-evaluates, neither measures the
    baselines only."""
    if cfg.get("planner"):
        raise ConfigError("planner: aslexp evaluate measures a policy or the controller; a planner runs "
                          "with aslexp plan (or aslexp imitate planner=...)")
    if cfg.get("policy") and cfg.get("resume"):
        raise ConfigError("policy and resume: give one (policy=RUN performs another motion, resume=RUN "
                          "re-evaluates the run's own)")
    if cfg.get("policy"):
        return perform(cfg, out_dir, reporter, metric_logger, keep_engine=told_on_command_line("engine"))
    if cfg.get("resume"):
        return re_evaluate(cfg, out_dir, reporter, metric_logger)
    return baselines_only(cfg, out_dir, reporter, metric_logger)


def resumes_nothing_left(cfg: dict[str, Any]) -> bool:
    """``resume=`` a checkpoint already trained for ``ppo.total_steps`` or more: a re-evaluation."""
    checkpoint = resume_path(cfg.get("resume"), cfg)
    return checkpoint is not None and trained_steps(checkpoint) >= int(cfg["ppo"]["total_steps"])


@job_main("evaluate")
def main(cfg: DictConfig) -> float | None:
    """Hydra entry point; returns the evaluated policy's reward (None: the baselines only)."""
    return imitation_main("evaluate", cfg, evaluate)


if __name__ == "__main__":
    main()
