"""``aslexp imitate``: learn to imitate one reference motion with PPO.

    aslexp imitate motion=A                                   # ppo=quick: minutes on a laptop
    aslexp imitate motion=A ppo=hand_thesis ppo.num_envs=8    # Table D.1 PPO (long), 8 workers
    aslexp imitate motion=A env=residual ppo=fast seed=1      # fast settings for this hardware
    aslexp imitate motion=A ppo.total_steps=0                 # baselines and plots only
    aslexp imitate hydra.run.dir=outputs/imitate/X resume=outputs/imitate/X   # continue a run
    aslexp imitate <the run's overrides> resume=RUN ppo.eval_episodes=16 hydra.run.dir=NEW   # re-evaluate it
    aslexp imitate -m experiment=letters_tracking            # letters x seeds (figure 5.9's task), aslexp's
    aslexp imitate -m experiment=letters_thesis              # as the thesis ran it, beside figure 5.9
    aslexp imitate -m experiment=letters_unseen              # one policy, many motions; scored on unseen letters
    aslexp imitate motion=FILE policy=RUN_DIR                # a trained policy performs a motion (no training)
    aslexp imitate --help                                    # the catalogue of experiments

The run folder gets: metrics.json (baselines, last evaluation (the headline) and best, the
evaluation protocol, steps, seconds, steps per
second, counts of NaN actions / divergences / early ends, steps and seconds to pass the
lookahead baseline), progress.csv, checkpoints/{last,best}.pt, reward_curve.png,
tracking.png (reference vs simulation per joint), imitation.gif (reference | simulation; small) and
imitation.mp4 (H.264, where an encoder is installed).
"""

from __future__ import annotations

import dataclasses
import logging
import time
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.experimental.callback import Callback
from omegaconf import DictConfig

from aslexp.data.root import resolve_data_root
from aslexp.errors import ConfigError
from aslexp.jobs._common import job_main, run_guarded, seed_everything, to_dict
from aslexp.jobs.validation import check_config
from aslexp.runs.loggers import make_logger
from aslexp.runs.read import resume_origin
from aslexp.runs.record import Run
from aslexp.tuning.context import trial_reporter

log = logging.getLogger("aslexp.imitate")


def score_rewards(cfg: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """``report.score_rewards`` (reward config names) -> their configs: the other reward scales every
    evaluation and baseline of the run is also scored under (e.g. the authors' code weights)."""
    from aslexp.compose import resolve_group

    names = (cfg.get("report") or {}).get("score_rewards") or []
    return {str(name): resolve_group("reward", str(name)) for name in names}


def build_envs(cfg: dict[str, Any], data_root: Path, vector_env: str = "auto", pool=None):
    """A factory of training envs (picklable: PPO may build them in worker processes) and the
    evaluation env (no early termination: evaluations score whole episodes; also scored under
    ``report.score_rewards``). With
    ``vector_env: batched`` (an engine that batches) the factory takes the number of environments and
    builds one :class:`~aslexp.envs.batched.BatchedImitationEnv` of them; with ``train_motions`` (``pool``:
    :func:`training_pool`'s, when the caller has it) its rows imitate the pool's motions, the evaluation
    env the run's motion."""
    import functools

    from aslexp.envs.assembly import ImitationSetup
    from aslexp.envs.imitation import ImitationEnv

    setup = ImitationSetup.from_config(cfg, data_root, score_rewards=score_rewards(cfg))  # Hydra composed every group
    if pool is None and vector_env == "batched":
        pool = training_pool(cfg, setup)
    if pool is not None and vector_env != "batched":
        from aslexp.sim.engine import batching_engines

        raise ConfigError(f"train_motions: a pool of motions trains on a batch (ppo.vector_env batched, or auto "
                          f"on an engine that batches: engine={'/'.join(batching_engines())}); got {vector_env!r}")
    if vector_env == "batched":
        from aslexp.envs.batched import BatchedImitationEnv

        make_train_env = functools.partial(BatchedImitationEnv.from_setup, setup=setup, shape_reward=True,
                                           motions=None if pool is None else pool.motions)
    else:  # env.heading_shaping / offset_shaping apply to the training envs only
        make_train_env = functools.partial(ImitationEnv.from_setup, setup, shape_reward=True)
    render = cfg.get("render") or {}
    eval_env = ImitationEnv.from_setup(setup.merged(env={"early_termination": {"min_reward": None}}),
                                       render_mode="rgb_array", render_size=tuple(render.get("size", (240, 240))))
    return make_train_env, eval_env


def training_pool(cfg: dict[str, Any], setup):
    """``train_motions`` (aslexp.envs.motion_pool): the motions a policy trains on, the run's own held
    out; None: it trains on the run's motion."""
    if not cfg.get("train_motions"):
        return None
    from aslexp.envs.motion_pool import TrainMotionsSpec, training_motions

    return training_motions(TrainMotionsSpec.parse(dict(cfg["train_motions"])), setup, cfg["motion"]["file"])


def _engine(cfg: dict[str, Any]):
    from aslexp.compose import choices
    from aslexp.sim.engine import get_engine

    engine = cfg.get("engine") or {}
    return get_engine(engine.get("name") or choices()["engine"], engine.get("module"))


def engine_vector_env(cfg: dict[str, Any], vector_env: str) -> str:
    """``auto`` on an engine that batches is ``batched``: every environment in one
    batch; any other choice stays."""
    return "batched" if vector_env == "auto" and _engine(cfg).batched else vector_env


def _resume_path(resume: str | None, cfg: dict[str, Any]) -> Path | None:
    """The checkpoint to resume from; a run folder's must have imitated this run's motion and seed
    (a re-evaluation sweep addresses runs by number: a misnumbered one would score another policy)."""
    if not resume:
        return None
    path = Path(resume)
    checkpoint = path / "checkpoints" / "last.pt" if path.is_dir() else path
    run_dir = checkpoint.parent.parent
    if (run_dir / ".hydra" / "config.yaml").is_file():
        from aslexp.reports.report import run_config

        run = run_config(run_dir)
        for key, theirs, ours in (("motion", (run.get("motion") or {}).get("name"), cfg["motion"]["name"]),
                                  ("seed", run.get("seed"), cfg.get("seed"))):
            if str(theirs) != str(ours):
                raise ConfigError(f"resume: {run_dir / '.hydra' / 'config.yaml'}: {key} is {theirs!r}, "
                                 f"expected this run's {ours!r}")
    return checkpoint


def imitate(cfg: dict[str, Any], out_dir: Path, reporter=None, metric_logger=None) -> dict[str, Any]:
    """The job without Hydra: train, evaluate, draw; returns the metrics. ``metric_logger`` (the
    `logger` group) gets every rollout's and evaluation's row of the trainer's history."""
    from aslexp.runs.loggers import HistoryLogger, MetricLogger, ppo_tag

    import numpy as np

    from aslexp.rl.evaluate import baselines, evaluate
    from aslexp.rl.ppo import PPOConfig, PPOTrainer
    from aslexp.reports import report

    data_root = resolve_data_root(cfg.get("data_root"))
    performer = None
    if cfg.get("policy"):  # a trained policy performs this run's motion under its own run's setting
        from aslexp.jobs.performing import performing_config

        cfg, performer = performing_config(cfg)
    ppo = PPOConfig.parse(cfg["ppo"])
    if cfg.get("planner"):  # a planner acts, nothing learns
        return plan(cfg, out_dir, data_root, ppo)
    ppo = dataclasses.replace(ppo, vector_env=engine_vector_env(cfg, ppo.vector_env))
    resume = _resume_path(cfg.get("resume"), cfg)  # a wrong run folder stops here, before any work
    untrained = ppo.total_steps == 0 and resume is None and performer is None
    if untrained or performer is not None:  # nothing trains: one environment in this process, no workers
        ppo = dataclasses.replace(ppo, num_envs=1, vector_env="sync", batched_workers=0, total_steps=0)
    pool = None
    if cfg.get("train_motions") and not untrained:  # one policy, many motions: the run's own motion is
        # evaluated, never trained on (with nothing to train, the baselines of the run's motion alone)
        from aslexp.envs.assembly import ImitationSetup
        from aslexp.envs.motion_pool import describe

        pool = training_pool(cfg, ImitationSetup.from_config(cfg, data_root))
        log.info("motion %s: %s", cfg["motion"]["name"], describe(pool))
    make_train_env, eval_env = build_envs(cfg, data_root, ppo.vector_env, pool=pool)
    base = baselines(eval_env, ppo.eval_steps, ppo.phases)  # the policy's evaluation protocol
    log.info("motion %s: baselines %s", cfg["motion"]["name"], {k: round(v, 4) for k, v in base.items()})
    report_baselines = measure_report_baselines(cfg, eval_env, ppo)
    residual_baselines = measure_residual_baselines(cfg, out_dir, learns=not untrained)

    history_logger: HistoryLogger | None = None

    def on_eval(step: int, value: float, row: dict[str, Any]) -> None:
        history_logger.flush()  # the rollouts since the last evaluation, and this evaluation
        if reporter is not None:  # the last evaluation is final: never pruned
            reporter.report(value, step, final=step >= ppo.total_steps)

    trainer = PPOTrainer(make_train_env, eval_env, ppo, out_dir, seed=int(cfg.get("seed") or 0), on_eval=on_eval)
    history_logger = HistoryLogger(metric_logger or MetricLogger(), trainer.history, rename=ppo_tag)
    try:  # worker processes end with the job, also when a sweep prunes it
        if resume is not None:
            trainer.restore(resume)  # a corrupt or mismatched checkpoint stops here, before any training
            resumed_from = resume_origin(resume, trainer.steps)  # the machine that trained those steps
        if performer is not None:
            trainer.load_policy(performer["checkpoint"])  # the weights alone: no steps, no history
        started = time.perf_counter()
        history_logger.logged = len(trainer.history)  # a resumed run's earlier rows were logged then
        result = trainer.train() if ppo.total_steps > trainer.steps else None
        history_logger.flush()  # rollouts after the last evaluation
        counters = trainer.counters()
    finally:
        trainer.close()
    if result is None:  # nothing to train: evaluate the policy as it is, under this config's protocol
        summary = trainer.evaluate()
        result_eval, action_rms = round(summary.mean_reward, 5), summary.action_rms  # rounded as the trainer's are
        last_scores, last_diverged = {k: round(v, 5) for k, v in summary.scores.items()}, summary.diverged
        # A resumed checkpoint with no steps left is re-evaluated ("evaluated": e.g. a finished run
        # under more start phases); with total_steps=0 only the baselines were measured, and the
        # untrained policy's level is kept as such, never as the run's result.
        stopped = "performed" if performer is not None else "evaluated" if trainer.steps > 0 else "no_training"
        best_eval, last_eval = (None, None) if untrained else (result_eval, result_eval)
    else:
        best_eval, last_eval, stopped = result.best_eval, result.last_eval, result.stopped
        action_rms = next((h["eval_action_rms"] for h in reversed(trainer.history) if "eval_action_rms" in h),
                          float("nan"))
        last_row = next((h for h in reversed(trainer.history) if "eval_reward" in h), {})
        last_scores = {k[len("eval_score_"):]: v for k, v in last_row.items() if k.startswith("eval_score_")}
        last_diverged = last_row.get("eval_diverged", 0)

    # When did the evaluation first pass each baseline?
    passed: dict[str, Any] = {}
    for name in ("lookahead", "reference"):
        first = next((h for h in trainer.history if h.get("eval_reward", -1) > base[name]), None)
        passed[f"steps_to_{name}"] = None if first is None else int(first["step"])
        passed[f"seconds_to_{name}"] = None if first is None else float(first["seconds"])

    # Figures with the last policy (the headline's; checkpoints/best.pt keeps the best one):
    # tracking plots and a side-by-side GIF.
    render = cfg.get("render") or {}
    frames_every = int(render.get("frames_every", 2)) if render.get("gif", True) else 0
    policy = trainer.evaluation_agent()
    look = evaluate(eval_env, lambda obs, env: env.reference_action(1), ppo.eval_steps, record=True,
                    frames_every=frames_every if untrained else 0)
    # nothing learned: the figures show the controller on the reference one step ahead (the same episode)
    final = look if untrained else evaluate(eval_env, lambda obs, env: policy.act(obs), ppo.eval_steps,
                                            record=True, frames_every=frames_every)
    joint_names = [j.name for j in eval_env.layout.joints]
    if not eval_env.layout.all_revolute:  # spherical joints: rotation angle and angular speed
        for run in ([final] if final is look else [final, look]):  # one episode when nothing was trained
            run.trajectory = report.per_joint_trajectory(run.trajectory, eval_env.layout)
    if cfg.get("plots", True):
        shown = "nothing trained, the controller on the reference one step ahead" if untrained else "last policy"
        report.plot_tracking(final.trajectory, joint_names, out_dir / "tracking.png",
                             f"{cfg['motion']['name']}: {shown} from phase 0 (reward {final.mean_reward:.3f})")
        # This run's controller driven by the reference one step ahead (the thesis-controller
        # baselines in metrics.json are the bar; with controller options they differ).
        controller = HydraConfig.get().runtime.choices.get("controller", "?") if HydraConfig.initialized() else "?"
        report.plot_tracking(look.trajectory, joint_names, out_dir / "tracking_baseline.png",
                             f"{cfg['motion']['name']}: reference one step ahead, controller {controller} "
                             f"(reward {look.mean_reward:.3f})")
        if performer is None:  # a performance has no curve of its own (its policy's run has)
            report.plot_reward_curve(trainer.history, base, out_dir / "reward_curve.png",
                                     f"{cfg['motion']['name']} (seed {cfg.get('seed')})")
    if frames_every and "frames" in final.trajectory:
        from aslexp.viz.video import save_gif, save_mp4

        fps = eval_env.spec_env.control_hz / frames_every
        save_gif(final.trajectory["frames"], out_dir / "imitation.gif", fps=fps)
        if render.get("mp4", True) and save_mp4(final.trajectory["frames"], out_dir / "imitation.mp4", fps) is None:
            log.info("no H.264 encoder (pip install imageio-ffmpeg): imitation.gif only")
    rows = [h for h in trainer.history if "steps_per_s" in h]
    metrics = {
        "motion": cfg["motion"]["name"], "seed": cfg.get("seed"), "baselines": base,
        "last_eval": last_eval, "best_eval": best_eval, "eval_protocol": ppo.eval_protocol,
        **({"train_motions": pool.summary()} if pool is not None else {}),
        **({"policy": performer} if performer is not None else {}),
        **({"resumed_from": resumed_from} if resume is not None else {}),
        **({"untrained_eval": result_eval} if untrained else {}),
        # The last evaluation's episodes that blew up (a number they touched is not a score), and the
        # last evaluation under report.score_rewards (the same episodes under another reward scale).
        "last_eval_diverged": int(last_diverged), "last_eval_scores": last_scores,
        "last_eval_divergences": list(trainer.last_evaluation.divergences) if trainer.last_evaluation else [],
        **({"report_baselines": report_baselines} if report_baselines is not None else {}),
        **({"residual_baselines": residual_baselines} if residual_baselines is not None else {}),
        ("lookahead_terms" if untrained else "final_eval_terms"): final.terms, "num_envs": ppo.num_envs, "device": str(trainer.device),
        "steps": trainer.steps, "seconds": trainer.elapsed, "stopped": stopped,
        "steps_per_s": float(np.mean([h["steps_per_s"] for h in rows])) if rows else None,
        "env_steps_per_s": float(np.mean([h["env_steps_per_s"] for h in rows])) if rows else None,
        "wall_seconds_this_process": time.perf_counter() - started,
        "counters": counters, **passed,
        # How far the evaluated policy's actions are from the box centre (a residual's: from the
        # controller) and the exploration noise it was trained with, in the same units (half-widths).
        "last_eval_action_rms": round(action_rms, 5) if np.isfinite(action_rms) else None,
        "exploration_std": round(float(np.exp(trainer.agent.head.log_std.detach().mean().item())), 5),
    }
    eval_env.close()
    return metrics


def plan(cfg: dict[str, Any], out_dir: Path, data_root: Path, ppo) -> dict[str, Any]:
    """``planner=...``: the planner drives the body (aslexp.control.mpc), scored under the run's
    evaluation protocol (``ppo.eval_phases``/``eval_episodes``, ``ppo.eval_steps``) beside the same
    baselines a trained run measures; its cost per control step. Nothing is trained."""
    from aslexp.control.mpc import PlannerSpec, evaluate_planner
    from aslexp.envs.assembly import ImitationSetup
    from aslexp.envs.imitation import ImitationEnv
    from aslexp.rl.evaluate import baselines, evaluate_phases, reference_policy

    spec = PlannerSpec.parse(dict(cfg["planner"]))
    setup = ImitationSetup.from_config(cfg, data_root, score_rewards=score_rewards(cfg))
    eval_env = ImitationEnv.from_setup(setup.merged(env={"early_termination": {"min_reward": None}}))
    try:
        base = baselines(eval_env, ppo.eval_steps, ppo.phases)
        log.info("motion %s: baselines %s", cfg["motion"]["name"], {k: round(v, 4) for k, v in base.items()})
        report_baselines = measure_report_baselines(cfg, eval_env, ppo)
        # the run's own controller with a zero correction (the planner's zero sequence): what it adds to;
        # rl.evaluate.baselines measures it already when the controller has target options
        controller = base.get("reference_velocity_pd")
        if controller is None:
            controller = evaluate_phases(eval_env, reference_policy(eval_env.spec_env.reference_lookahead),
                                         ppo.eval_steps, ppo.phases).mean_reward
    finally:
        eval_env.close()
    started = time.perf_counter()
    planned = evaluate_planner(spec, setup, ppo.phases, ppo.eval_steps, label=f"{spec.name} on {cfg['motion']['name']}")
    log.info("motion %s: planner %s %.4f (the controller alone %.4f), %.3f s per control step",
             cfg["motion"]["name"], spec.name, planned["reward"], controller, planned["seconds_per_step"])
    return {
        "motion": cfg["motion"]["name"], "seed": cfg.get("seed"), "baselines": base,
        "last_eval": round(planned["reward"], 5), "best_eval": round(planned["reward"], 5),
        "eval_protocol": ppo.eval_protocol, "last_eval_diverged": int(planned["diverged"]), "last_eval_scores": {},
        "last_eval_divergences": [], **({"report_baselines": report_baselines} if report_baselines is not None else {}),
        "planner": {**dataclasses.asdict(spec), **planned, "controller_alone": controller},
        "steps": 0, "seconds": round(time.perf_counter() - started, 2), "stopped": "planned",
    }


def measure_report_baselines(cfg: dict[str, Any], eval_env, ppo) -> list[dict[str, Any]] | None:
    """The overlay's ``report.baselines`` (aslexp.envs.baselines), measured now under the run's own
    evaluation protocol (its start phases, ``ppo.eval_steps`` at the run's control rate), reward and
    ``report.score_rewards``: a report reads them from metrics.json and simulates nothing. None when
    the overlay names none."""
    rows = (cfg.get("report") or {}).get("baselines")
    if not rows:
        return None
    from aslexp.envs.baselines import Baseline, no_learning_baselines

    seconds = ppo.eval_steps / eval_env.spec_env.control_hz
    measured = no_learning_baselines(eval_env.setup, [Baseline.parse(dict(b)) for b in rows], seconds,
                                     phases=ppo.phases)
    return [{**row, "seconds": seconds} for row in measured]


def measure_residual_baselines(cfg: dict[str, Any], out_dir: Path, learns: bool) -> dict[str, Any] | None:
    """The overlay's ``report.residual`` comparison rows (aslexp.measure.residual), measured now under
    the run's protocol; the seeds of a multirun share one measurement (cached in the sweep folder).
    The constant random corrections size a learned correction: a run that learns nothing skips them."""
    settings = (cfg.get("report") or {}).get("residual")
    if not settings:
        return None
    from aslexp.jobs._common import in_multirun
    from aslexp.measure.residual import residual_baselines

    if not learns:
        settings = {k: v for k, v in settings.items() if k != "random_corrections"}
        cfg = {**cfg, "report": {**cfg["report"], "residual": settings}}
    cache = out_dir.parent / "baselines" / f"{cfg['motion']['name']}.json" if in_multirun() else None
    return residual_baselines(cfg, cache)


def refuse_blown_up(metrics: dict[str, Any], cfg: DictConfig) -> None:
    """A last evaluation whose simulation blew up is an error, never a score: one line saying where
    and when, and what to change (metrics.json keeps the numbers, marked ``last_eval_diverged``)."""
    count = int(metrics.get("last_eval_diverged") or 0)
    if not count:
        return
    from aslexp.errors import SimulationDiverged

    episodes = len(metrics["eval_protocol"]["phases"])
    first = (metrics.get("last_eval_divergences") or [{}])[0]
    where = ""
    if first.get("joint"):
        where = (f" (first: joint {first['joint']} at {first['speed']:.3g} rad/s, {first['seconds']:g} s into the "
                 f"episode from phase {first.get('phase', 0):g})")
    hints = _engine(cfg).divergence_hint
    raise SimulationDiverged(
        f"motion {metrics['motion']}: the simulation blew up in {count} of {episodes} evaluation episodes{where}; "
        f"the last evaluation is not a score (kept in metrics.json as last_eval_diverged). Try {hints}")


def _imitate_run(cfg: DictConfig, run: Run) -> float | None:
    check_config("imitate", cfg)  # swept values (the rest: ConfigCheck); a bad one fails this run
    import torch

    torch.set_num_threads(int(cfg.ppo.get("torch_threads", 1)))
    seed_everything(int(cfg.seed))
    metric_logger, metrics = make_logger(to_dict(cfg.logger), run.dir, to_dict(cfg)), {}
    try:
        metrics = imitate(to_dict(cfg), run.dir, trial_reporter(cfg), metric_logger)
    finally:
        metric_logger.close(metrics)
    run.save_metrics(metrics)
    refuse_blown_up(metrics, cfg)  # after the metrics are written: nothing computed is lost
    if metrics["last_eval"] is None:  # ppo.total_steps=0: nothing learned, so no learned score (no main metric)
        log.info("nothing trained (ppo.total_steps=0): baselines %s; the untrained policy scores %.4f "
                 "(not a result); metrics.json holds them", metrics["baselines"], metrics["untrained_eval"])
        return None  # no objective: a sweep has nothing to rank
    run.set_main_metric("eval_reward", metrics["last_eval"], "maximize")
    log.info("last eval %.4f (best %.4f; lookahead baseline %.4f) after %d steps, %.0f s",
             metrics["last_eval"], metrics["best_eval"], metrics["baselines"]["lookahead"], metrics["steps"],
             metrics["seconds"])
    return float(metrics["last_eval"])


@job_main("imitate")
def main(cfg: DictConfig) -> float | None:
    """Hydra entry point; returns the last evaluation reward (the sweep objective; never the best of
    many; None when nothing was trained)."""
    from aslexp.jobs.validation import name_motion_after_its_file

    name_motion_after_its_file(cfg, list(HydraConfig.get().overrides.task))  # multirun jobs too
    return run_guarded("imitate", cfg, lambda run: _imitate_run(cfg, run))


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
