"""``aslexp imitate``: learn to imitate one reference motion with PPO.

    aslexp imitate motion=A                                   # ppo=quick: minutes on a laptop
    aslexp imitate motion.file=FILE                           # your motion: a correction on the body's controller
    aslexp imitate motion=A ppo=hand_thesis ppo.num_envs=8    # Table D.1 PPO (long), 8 workers
    aslexp imitate motion=A env=residual ppo=fast seed=1      # fast settings for this hardware
    aslexp imitate hydra.run.dir=outputs/imitate/X resume=outputs/imitate/X   # continue a run
    aslexp imitate -m experiment=letters_tracking            # letters x seeds (figure 5.9's task), aslexp's
    aslexp imitate -m experiment=letters_thesis              # as the thesis ran it, beside figure 5.9
    aslexp imitate -m experiment=letters_unseen              # one policy, many motions; scored on unseen letters
    aslexp imitate --help                                    # the catalogue of experiments

Evaluating and planning have jobs of their own, ``aslexp evaluate`` (aslexp.jobs.evaluate: the
baselines only, re-evaluate a run, a policy performs a motion) and ``aslexp plan`` (aslexp.jobs.plan);
this job's forms of them call the same functions: ``ppo.total_steps=0`` (baselines and plots only),
``resume=RUN`` with no steps left (re-evaluate), ``policy=RUN_DIR`` (perform), ``planner=mpc`` (plan).

The run folder gets: metrics.json (baselines and the best of them, last evaluation (the headline) and
best, the evaluation protocol, steps, seconds, steps per second, counts of NaN actions / divergences /
early ends, steps and seconds to pass the lookahead baseline), progress.csv, checkpoints/{last,best}.pt,
reward_curve.png, tracking.png (reference vs simulation per joint), imitation.gif (reference |
simulation; small) and imitation.mp4 (H.264, where an encoder is installed). The last log line compares
the learned policy with the best no-learning baseline and says so when it is below.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from aslexp.jobs import evaluate as evaluating
from aslexp.jobs._common import job_main
from aslexp.jobs._imitation import (  # noqa: F401  (build_envs, training_pool: the imitation tests build with them)
    Bench, build_envs, engine_vector_env, finish, imitation_main, open_trainer, resume_path,
    told_on_command_line, trainer_metrics, training_pool)
from aslexp.jobs.plan import plan

log = logging.getLogger("aslexp.imitate")


def train(cfg: dict[str, Any], out_dir: Path, reporter=None, metric_logger=None) -> dict[str, Any]:
    """PPO on the run's motion (or ``train_motions``' pool), from scratch or from ``resume=`` (a
    checkpoint with steps left); the last policy's evaluation is the headline."""
    from aslexp.envs.motion_pool import describe
    from aslexp.rl.ppo import PPOConfig
    from aslexp.runs.read import resume_origin

    ppo = PPOConfig.parse(cfg["ppo"])
    ppo = dataclasses.replace(ppo, vector_env=engine_vector_env(cfg, ppo.vector_env))
    resume = resume_path(cfg.get("resume"), cfg)  # a wrong run folder stops here, before any work
    pool = training_pool(cfg)  # one policy, many motions: the run's own motion is evaluated, never trained on
    if pool is not None:
        log.info("motion %s: %s", cfg["motion"]["name"], describe(pool))
    bench = Bench.open(cfg, out_dir, ppo, learned=True, pool=pool)
    try:
        trainer, history_logger = open_trainer(bench, reporter, metric_logger)
        try:  # worker processes end with the job, also when a sweep prunes it
            if resume is not None:
                trainer.restore(resume)  # a corrupt or mismatched checkpoint stops here, before any training
                resumed_from = resume_origin(resume, trainer.steps)  # the machine that trained those steps
            started = time.perf_counter()
            history_logger.logged = len(trainer.history)  # a resumed run's earlier rows were logged then
            result = trainer.train()
            history_logger.flush()  # rollouts after the last evaluation
            counters = trainer.counters()
        finally:
            trainer.close()
        history = trainer.history
        last_row = next((h for h in reversed(history) if "eval_reward" in h), {})
        start = next((h["eval_reward"] for h in history if h["step"] == 0 and "eval_reward" in h), None)
        own = {
            "last_eval": result.last_eval, "best_eval": result.best_eval, "stopped": result.stopped,
            **({"resumed_from": resumed_from} if resume is not None else {}),
            **({"untrained_eval": start} if start is not None else {}),  # ppo.eval_at_start: where it began
            # The last evaluation's episodes that blew up (a number they touched is not a score), and the
            # last evaluation under report.score_rewards (the same episodes under another reward scale).
            "last_eval_diverged": int(last_row.get("eval_diverged", 0)),
            "last_eval_scores": {k[len("eval_score_"):]: v for k, v in last_row.items() if k.startswith("eval_score_")},
            "action_rms": last_row.get("eval_action_rms", float("nan")),
            **trainer_metrics(trainer, started, counters),
        }
        if trainer.ended_on_selected:  # validated: the run ends on the policy its validation motions chose
            trained = next(h for h in reversed(history[:-1]) if "eval_reward" in h)
            own["selected"] = {"step": trainer.selected_step, "validation_reward": trainer.best_validation,
                               "validation_motions": bench.validation.names,
                               "last_trained_eval": trained["eval_reward"], "last_trained_step": trained["step"]}
        return finish(bench, trainer.evaluation_agent().act, own, history=history, shown="last policy")
    finally:
        bench.close()


def imitate(cfg: dict[str, Any], out_dir: Path, reporter=None, metric_logger=None) -> dict[str, Any]:
    """The job without Hydra: train, or (as this job's forms of them) perform, plan, re-evaluate or
    measure the baselines only; returns the metrics. ``metric_logger`` (the `logger` group) gets every
    rollout's and evaluation's row of the trainer's history."""
    if cfg.get("policy"):  # a trained policy performs this run's motion under its own run's setting
        return evaluating.perform(cfg, out_dir, reporter, metric_logger, keep_engine=told_on_command_line("engine"))
    if cfg.get("planner"):  # a planner acts, nothing learns
        return plan(cfg, out_dir, reporter, metric_logger)
    if cfg.get("resume"):
        if evaluating.resumes_nothing_left(cfg):
            return evaluating.re_evaluate(cfg, out_dir, reporter, metric_logger)
    elif int(cfg["ppo"]["total_steps"]) == 0:
        return evaluating.baselines_only(cfg, out_dir, reporter, metric_logger)
    return train(cfg, out_dir, reporter, metric_logger)


@job_main("imitate")
def main(cfg: DictConfig) -> float | None:
    """Hydra entry point; returns the last evaluation reward (the sweep objective; never the best of
    many; None when nothing was trained)."""
    return imitation_main("imitate", cfg, imitate)


class _MultirunSummary(Callback):
    """After a multirun: the experiment's summary table and curves in the sweep folder."""

    kind = ""

    def summarize(self, sweep_dir: Path) -> dict:
        raise NotImplementedError

    def on_multirun_end(self, config: DictConfig, **kwargs: Any) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        try:
            summary = self.summarize(sweep_dir)
            log.info("%s summary in %s\n%s", self.kind, sweep_dir, summary["table"])
        except FileNotFoundError as exc:
            log.warning("no %s summary: %s", self.kind, exc)


class LettersSummary(_MultirunSummary):
    """The letters experiment: mean/std curves per letter and the results table."""

    kind = "letters"

    def summarize(self, sweep_dir: Path) -> dict:
        from aslexp.reports.report import summarize_letters

        return summarize_letters(sweep_dir)


class ScratchSummary(_MultirunSummary):
    """From-scratch letters (experiment=letters_scratch): curves and table against each letter's
    reference-as-target baseline (the bar, dashed), in scratch_curves.png and scratch_table.{md,csv}."""

    kind = "scratch"

    def summarize(self, sweep_dir: Path) -> dict:
        from aslexp.reports.report import summarize_letters

        return summarize_letters(sweep_dir, targets="reference", stem="scratch", lines=("reference",))


class ThesisSummary(_MultirunSummary):
    """The thesis overlays: per letter or sign, the thesis' number, every no-learning baseline and the
    learned policies' last evaluation, all under the runs' reward (aslexp.reports.thesis_report)."""

    kind = "thesis"

    def summarize(self, sweep_dir: Path) -> dict:
        from aslexp.reports.thesis_report import summarize_thesis

        return summarize_thesis(sweep_dir)


class ResidualSummary(_MultirunSummary):
    """A residual policy on a controller that loses reward for a physical reason
    (experiment=signs_free_residual): per sign the controller, the same on a pinned base, the
    smoothed-reference baselines and the learned last evaluation over seeds, with the verdict
    (aslexp.reports.residual_report)."""

    kind = "residual"

    def summarize(self, sweep_dir: Path) -> dict:
        from aslexp.reports.residual_report import summarize_residual

        return summarize_residual(sweep_dir)


class SignsSummary(_MultirunSummary):
    """The signs experiment: curves and the table beside thesis table 6.7."""

    kind = "signs"

    def summarize(self, sweep_dir: Path) -> dict:
        from aslexp.reports.upper_body_report import summarize_signs

        return summarize_signs(sweep_dir)


if __name__ == "__main__":
    main()
