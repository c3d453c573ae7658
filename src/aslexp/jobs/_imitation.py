"""What the imitation jobs share (``aslexp imitate``, ``aslexp evaluate``, ``aslexp plan``).

* :class:`Bench`: one run's environments, evaluation protocol and no-learning baselines, which every
  purpose (training, evaluation, planning) measures against.
* :func:`open_trainer`: the PPO trainer around a policy, its rows forwarded to the run's logger.
* :func:`finish`: the shared tail. It records the episode the figures show (the policy's, or the
  controller's when nothing acts but the controller), draws tracking plots, the reward curve and the
  GIF/MP4, and builds metrics.json's common part.
* :func:`run_imitation`: a purpose function inside a run record: metrics.json written, a blown-up
  evaluation refused, the main metric set, and :func:`last_line`, the run's verdict: its result beside
  the best no-learning baseline, said plainly when below.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from aslexp.errors import ConfigError

log = logging.getLogger("aslexp.imitate")

# A learned result within this of the best baseline is "at" it (rewards are rounded to 5 digits).
LEVEL_TOLERANCE = 5e-4


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


def training_pool(cfg: dict[str, Any], setup=None):
    """``train_motions`` (aslexp.envs.motion_pool): the motions a policy trains on, the run's own held
    out; None: it trains on the run's motion."""
    if not cfg.get("train_motions"):
        return None
    from aslexp.envs.motion_pool import TrainMotionsSpec, training_motions

    if setup is None:
        from aslexp.data.root import resolve_data_root
        from aslexp.envs.assembly import ImitationSetup

        setup = ImitationSetup.from_config(cfg, resolve_data_root(cfg.get("data_root")))
    return training_motions(TrainMotionsSpec.parse(dict(cfg["train_motions"])), setup, cfg["motion"]["file"])


def engine_of(cfg: dict[str, Any]):
    from aslexp.compose import choices
    from aslexp.sim.engine import get_engine

    engine = cfg.get("engine") or {}
    return get_engine(engine.get("name") or choices()["engine"], engine.get("module"))


def engine_vector_env(cfg: dict[str, Any], vector_env: str) -> str:
    """``auto`` on an engine that batches is ``batched``: every environment in one
    batch; any other choice stays."""
    return "batched" if vector_env == "auto" and engine_of(cfg).batched else vector_env


def resume_path(resume: str | None, cfg: dict[str, Any]) -> Path | None:
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


def trained_steps(checkpoint: Path) -> int:
    """The environment steps a checkpoint was trained for (a corrupt file stops here, in one line)."""
    from aslexp.rl.checkpoint import load_checkpoint

    return int(load_checkpoint(checkpoint).get("steps", 0))


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


# --------------------------------------------------------------------------- the bench


@dataclass
class Bench:
    """One run's environments, evaluation protocol and no-learning baselines."""

    cfg: dict[str, Any]
    out_dir: Path
    ppo: Any  # aslexp.rl.ppo.PPOConfig
    make_train_env: Callable[..., Any]
    eval_env: Any
    base: dict[str, float]
    report_baselines: list[dict[str, Any]] | None
    residual_baselines: dict[str, Any] | None
    pool: Any = None  # train_motions' pool (None: the run's motion alone)
    validation: Any = None  # the pool's validation motions, one row per motion and start phase (Validation)

    @classmethod
    def open(cls, cfg: dict[str, Any], out_dir: Path, ppo, learned: bool, pool=None, train_on_pool: bool = True):
        """Build the envs and measure the baselines under the run's protocol; ``learned``: the run's
        policy learned (or learns) a correction, which the random-correction controls size. ``pool``: the motions a
        policy trains (or trained) on; ``train_on_pool`` false when nothing trains here (the training
        envs are then the run's motion alone, and the pool is only recorded)."""
        from aslexp.data.root import resolve_data_root
        from aslexp.rl.evaluate import baselines

        make_train_env, eval_env = build_envs(cfg, resolve_data_root(cfg.get("data_root")), ppo.vector_env,
                                              pool=pool if train_on_pool else None)
        try:
            base = baselines(eval_env, ppo.eval_steps, ppo.phases)  # the policy's evaluation protocol
            log.info("motion %s: baselines %s", cfg["motion"]["name"], {k: round(v, 4) for k, v in base.items()})
            report_baselines = measure_report_baselines(cfg, eval_env, ppo)
            residual = measure_residual_baselines(cfg, out_dir, learns=learned)
        except BaseException:
            eval_env.close()
            raise
        bench = cls(cfg, out_dir, ppo, make_train_env, eval_env, base, report_baselines, residual, pool)
        if train_on_pool and pool is not None and pool.validation:
            bench.validation = Validation.open(eval_env.setup, pool.validation, ppo)
        return bench

    def close(self) -> None:
        self.eval_env.close()
        if self.validation is not None:
            self.validation.close()


@dataclass
class Validation:
    """A pool's validation motions (``train_motions.validation_motions``), scored under the run's
    protocol (its start phases and ``ppo.eval_steps``) in one batch: every motion and phase a row."""

    names: list[str]
    env: Any  # aslexp.envs.batched.BatchedImitationEnv
    clips: Any
    phases: Any
    steps: int

    @classmethod
    def open(cls, setup, motions: dict[str, Any], ppo) -> "Validation":
        import numpy as np

        from aslexp.envs.batched import BatchedImitationEnv

        phases = np.asarray(ppo.phases, dtype=np.float64)
        clips = np.repeat(np.arange(len(motions)), len(phases))
        # an episode as long as the evaluation's: the batch's truncation (and autoreset) comes at its end
        env = BatchedImitationEnv.from_setup(len(clips), setup.merged(env={"episode_steps": ppo.eval_steps}),
                                             motions=list(motions.values()))
        return cls(list(motions), env, clips, np.tile(phases, len(motions)), ppo.eval_steps)

    def __call__(self, agent) -> float:
        """The policy's mean reward over every validation episode; NaN when one blew up (never a
        score, never chosen)."""
        import numpy as np

        from aslexp.rl.evaluate import evaluate_rows

        rewards, blew_up = evaluate_rows(self.env, lambda obs: agent.act(obs, deterministic=True), self.steps,
                                         self.clips, self.phases)
        if blew_up.any():
            log.warning("validation: %d episode(s) of %s blew up; this policy is not chosen", int(blew_up.sum()),
                        sorted({self.names[c] for c in self.clips[blew_up]}))
            return float("nan")
        return float(np.mean(rewards))

    def close(self) -> None:
        self.env.close()


def open_trainer(bench: Bench, reporter=None, metric_logger=None):
    """The PPO trainer of ``bench`` and the logger of its history rows (every rollout's and
    evaluation's row goes to ``metric_logger``, the `logger` group; ``reporter``: a sweep's trial,
    told each evaluation, the last one final)."""
    from aslexp.rl.ppo import PPOTrainer
    from aslexp.runs.loggers import HistoryLogger, MetricLogger, ppo_tag

    ppo = bench.ppo
    history_logger: HistoryLogger | None = None

    def on_eval(step: int, value: float, row: dict[str, Any]) -> None:
        history_logger.flush()  # the rollouts since the last evaluation, and this evaluation
        if reporter is not None:  # the last evaluation is final: never pruned
            reporter.report(value, step, final=step >= ppo.total_steps)

    trainer = PPOTrainer(bench.make_train_env, bench.eval_env, ppo, bench.out_dir,
                         seed=int(bench.cfg.get("seed") or 0), on_eval=on_eval,
                         validate=bench.validation)
    history_logger = HistoryLogger(metric_logger or MetricLogger(), trainer.history, rename=ppo_tag)
    return trainer, history_logger


def evaluated(trainer, stopped: str) -> dict[str, Any]:
    """Metrics of a policy evaluated as it is (nothing trained here), under this config's protocol."""
    summary = trainer.evaluate()
    value = round(summary.mean_reward, 5)  # rounded as the trainer's are
    return {"last_eval": value, "best_eval": value, "stopped": stopped,
            "last_eval_diverged": int(summary.diverged),
            "last_eval_scores": {k: round(v, 5) for k, v in summary.scores.items()},
            "action_rms": summary.action_rms}


def trainer_metrics(trainer, started: float, counters: dict[str, int]) -> dict[str, Any]:
    """What a run that holds a trainer records of it (speeds, steps, noise, the last evaluation's blow-ups)."""
    import numpy as np

    rows = [h for h in trainer.history if "steps_per_s" in h]
    return {
        "last_eval_divergences": list(trainer.last_evaluation.divergences) if trainer.last_evaluation else [],
        "num_envs": trainer.config.num_envs, "device": str(trainer.device),
        "steps": trainer.steps, "seconds": trainer.elapsed,
        "steps_per_s": float(np.mean([h["steps_per_s"] for h in rows])) if rows else None,
        "env_steps_per_s": float(np.mean([h["env_steps_per_s"] for h in rows])) if rows else None,
        "wall_seconds_this_process": time.perf_counter() - started,
        "counters": counters,
        # the policy's exploration noise, in half-widths of the action box (as last_eval_action_rms)
        "exploration_std": round(float(np.exp(trainer.agent.head.log_std.detach().mean().item())), 5),
    }


# --------------------------------------------------------------------------- the shared tail


def finish(bench: Bench, policy: Callable[[Any], Any] | None, own: dict[str, Any],
           history: list[dict[str, Any]] | None = None, shown: str = "", curve: bool = True,
           video: bool = True) -> dict[str, Any]:
    """The tail every purpose ends with: the episode from phase 0 the figures show, recorded with the
    trajectory at hand (``policy(obs)``; None: the controller on the reference one step ahead, which is
    always recorded too, as tracking_baseline.png), tracking plots, the reward curve (``curve``, from
    ``history``, a trainer's rows: also when each baseline was first passed; None: no trainer), imitation.gif/.mp4 (``video``) and metrics.json: its common part, then
    ``own`` (the purpose's keys; ``action_rms`` becomes ``last_eval_action_rms``)."""
    import math

    from aslexp.reports.report import per_joint_trajectory
    from aslexp.rl.evaluate import evaluate

    cfg, ppo, env, out_dir = bench.cfg, bench.ppo, bench.eval_env, bench.out_dir
    render = cfg.get("render") or {}
    frames_every = int(render.get("frames_every", 2)) if render.get("gif", True) and video else 0
    look = evaluate(env, lambda obs, env: env.reference_action(1), ppo.eval_steps, record=True,
                    frames_every=frames_every if policy is None else 0)
    final = look if policy is None else evaluate(env, lambda obs, env: policy(obs), ppo.eval_steps,
                                                 record=True, frames_every=frames_every)
    # before the per-joint view replaces q_sim; signing.mp4/.gif where the run draws its GIF
    signing = signing_scores(env, look, final, out_dir, cfg, video=bool(frames_every))
    joint_names = [j.name for j in env.layout.joints]
    if not env.layout.all_revolute:  # spherical joints: rotation angle and angular speed
        for run in ([final] if final is look else [final, look]):
            run.trajectory = per_joint_trajectory(run.trajectory, env.layout)
    name = cfg["motion"]["name"]
    if cfg.get("plots", True):
        from aslexp.viz.imitation import plot_reward_curve, plot_tracking

        plot_tracking(final.trajectory, joint_names, out_dir / "tracking.png",
                      f"{name}: {shown or 'the policy'} from phase 0 (reward {final.mean_reward:.3f})")
        # This run's controller driven by the reference one step ahead (the thesis-controller
        # baselines in metrics.json are the bar; with controller options they differ).
        plot_tracking(look.trajectory, joint_names, out_dir / "tracking_baseline.png",
                      f"{name}: reference one step ahead, controller {_controller_name(cfg)} "
                      f"(reward {look.mean_reward:.3f})")
        if history is not None and curve:
            plot_reward_curve(history, bench.base, out_dir / "reward_curve.png", f"{name} (seed {cfg.get('seed')})")
    if frames_every and "frames" in final.trajectory:
        from aslexp.viz.video import save_gif, save_mp4

        fps = env.spec_env.control_hz / frames_every
        save_gif(final.trajectory["frames"], out_dir / "imitation.gif", fps=fps)
        if render.get("mp4", True) and save_mp4(final.trajectory["frames"], out_dir / "imitation.mp4", fps) is None:
            log.info("no H.264 encoder (pip install imageio-ffmpeg): imitation.gif only")
    own = dict(own)
    action_rms = own.pop("action_rms", None)
    metrics = {
        "motion": name, "seed": cfg.get("seed"), "baselines": bench.base, "eval_protocol": ppo.eval_protocol,
        **({"train_motions": bench.pool.summary()} if bench.pool is not None else {}),
        **({"report_baselines": bench.report_baselines} if bench.report_baselines is not None else {}),
        **({"residual_baselines": bench.residual_baselines} if bench.residual_baselines is not None else {}),
        ("lookahead_terms" if policy is None else "final_eval_terms"): final.terms,
        **({} if history is None else passed_baselines(history, bench.base)),
        **own,
    }
    if action_rms is not None:  # how far the evaluated actions are from the box centre (a residual's: the controller)
        metrics["last_eval_action_rms"] = round(action_rms, 5) if math.isfinite(action_rms) else None
    metrics["best_baseline"] = best_baseline(metrics)
    if signing is not None:
        metrics["signing"] = signing
    return metrics


def signing_scores(env, look, final, out_dir: Path, cfg: dict[str, Any] | None = None,
                   video: bool = False) -> dict[str, Any] | None:  # fmt: skip
    """The performance against the person it imitates (aslexp.signing): the retargeted reference,
    the controller alone and (when one acted) the policy, and signing.pose; None, said in one line,
    for a motion with no source keypoint file. With ``signing.read_back.enabled`` each stage and the
    person's clip are also read back by the recognition wing (aslexp.signing.reading). ``video``
    (the run's render.gif): also signing.gif and (render.mp4) signing.mp4, the person beside the agent."""
    from aslexp.signing.performance import signing_metrics

    keypoints: dict = {}
    drawn = {"video": video, "mp4": bool(((cfg or {}).get("render") or {}).get("mp4", True))}
    if final is look:
        signing = signing_metrics(env, look.trajectory, out_dir, stage="controller", keypoints=keypoints, **drawn)
    else:
        signing = signing_metrics(env, final.trajectory, out_dir, stage="policy", others={"controller": look.trajectory},
                                  keypoints=keypoints, **drawn)
    settings = ((cfg or {}).get("signing") or {}).get("read_back") or {}
    if signing is not None and settings.get("enabled"):
        signing["read_back"] = _read_back(signing, keypoints, tuple(settings.get("overrides") or ()),
                                          cfg.get("data_root"))
    return signing


def _read_back(signing: dict[str, Any], keypoints: dict, overrides: tuple[str, ...], data_root) -> dict[str, Any]:
    import json

    from aslexp.data.root import resolve_data_root
    from aslexp.errors import DataError
    from aslexp.signing.reading import gloss_of_source, models_for, read_back_stages

    report = json.loads(Path(signing["motion_report"]).read_text())
    gloss = gloss_of_source(report, signing["source"], resolve_data_root(data_root))
    if gloss is None:
        return {"note": f"{signing['source']}: no gloss known for the clip (its report and WLASL name none)"}
    try:
        return read_back_stages(models_for(overrides), keypoints, signing["source"], gloss)
    except DataError as error:  # a gloss without a lexicon entry: the keypoint scores stand
        return {"note": str(error)}


def _controller_name(cfg: dict[str, Any]) -> str:
    from hydra.core.hydra_config import HydraConfig

    if HydraConfig.initialized():
        return HydraConfig.get().runtime.choices.get("controller", "?")
    return str((cfg.get("controller") or {}).get("name", "?"))


def passed_baselines(history: list[dict[str, Any]], base: dict[str, float]) -> dict[str, Any]:
    """When did the evaluation first pass each baseline (steps and seconds; None: never)?"""
    passed: dict[str, Any] = {}
    for name in ("lookahead", "reference"):
        first = next((h for h in history if h.get("eval_reward", -1) > base[name]), None)
        passed[f"steps_to_{name}"] = None if first is None else int(first["step"])
        passed[f"seconds_to_{name}"] = None if first is None else float(first["seconds"])
    return passed


BASELINE_NAMES = {
    "reference": "the reference as the PD target (thesis PD)",
    "lookahead": "the reference one step ahead (thesis PD)",
    "reference_velocity_pd": "the run's controller alone (no correction)",
}


def best_baseline(metrics: dict[str, Any]) -> dict[str, Any] | None:
    """The highest no-learning baseline of a run, measured under its own protocol: the bar a learned
    result is read against. From ``baselines``, the overlay's ``report.baselines`` rows (those whose
    episodes did not blow up) and ``residual_baselines``' smoothed references; None when none."""
    rows = [(BASELINE_NAMES.get(key, key), float(value)) for key, value in (metrics.get("baselines") or {}).items()]
    for row in metrics.get("report_baselines") or []:
        if not row.get("diverged"):
            rows.append((f"{row['label']} (lookahead {row.get('lookahead', 1)})", float(row["reward"])))
    for alpha, value in ((metrics.get("residual_baselines") or {}).get("smoothed") or {}).items():
        rows.append((f"the reference one step ahead, smoothed (alpha {alpha})", float(value)))
    if not rows:
        return None
    label, value = max(rows, key=lambda r: r[1])
    return {"name": label, "reward": round(value, 5)}


def last_line(metrics: dict[str, Any]) -> str:
    """The run's verdict: what it scored beside the best no-learning baseline (named), and plainly
    whether it is below, at or above it."""
    name, best = metrics["motion"], metrics.get("best_baseline")
    bar = "" if best is None else f"best no-learning baseline {best['reward']:.4f}: {best['name']}"
    if metrics.get("last_eval") is None:  # nothing trained: the baselines are the result
        blown = int(metrics.get("untrained_eval_diverged") or 0)
        untrained = (f"the untrained policy's simulation blew up in {blown} of {len(metrics['eval_protocol']['phases'])} "
                     "episodes" if blown else f"the untrained policy scores {metrics['untrained_eval']:.4f}")
        return (f"motion {name}: nothing trained (ppo.total_steps=0); {bar}; {untrained} (not a result); "
                "metrics.json holds every baseline")
    value, stopped = float(metrics["last_eval"]), metrics.get("stopped")
    if stopped == "planned":
        what = f"planner {metrics['planner']['name']} {value:.4f}"
    elif stopped == "performed":
        policy = metrics["policy"]
        what = (f"the policy of {policy['run']} (on {policy['engine']}, {policy['engine_chosen_by']}) "
                f"scores {value:.4f}")
    elif stopped == "evaluated":
        what = f"re-evaluated policy ({metrics['steps']} steps) {value:.4f}"
    else:
        start = metrics.get("untrained_eval")
        what = (f"last eval {value:.4f} (best {metrics['best_eval']:.4f}"
                f"{'' if start is None else f'; untrained {start:.4f}'}) after {metrics['steps']} steps, "
                f"{metrics['seconds']:.0f} s")
    if best is None:
        return f"motion {name}: {what}"
    gap = value - best["reward"]
    verdict = ("AT the best no-learning baseline" if abs(gap) <= LEVEL_TOLERANCE else
               f"BELOW the best no-learning baseline by {-gap:.4f}" if gap < 0 else
               f"above the best no-learning baseline by {gap:.4f}")
    return f"motion {name}: {what}; {bar}; {verdict}"


# --------------------------------------------------------------------------- inside the run record


def refuse_blown_up(metrics: dict[str, Any], cfg: dict[str, Any]) -> None:
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
    hints = engine_of(cfg).divergence_hint
    raise SimulationDiverged(
        f"motion {metrics['motion']}: the simulation blew up in {count} of {episodes} evaluation episodes{where}; "
        f"the last evaluation is not a score (kept in metrics.json as last_eval_diverged). Try {hints}")


def run_imitation(cfg, run, purpose: Callable[..., dict[str, Any]], verdict: list[str]) -> float | None:
    """``purpose(cfg, out_dir, reporter, metric_logger) -> metrics`` inside the run record ``run``
    (``cfg``: the Hydra config): the imitate schema checked (a swept value fails this run only),
    metrics.json written before a blown-up evaluation is refused, the main metric set; the verdict
    (:func:`last_line`) appended to ``verdict`` for the job to say last. Returns the objective
    (None: nothing was trained, nothing to rank)."""
    import torch

    from aslexp.jobs._common import seed_everything, to_dict
    from aslexp.jobs.validation import check_config
    from aslexp.runs.loggers import make_logger
    from aslexp.tuning.context import trial_reporter

    check_config("imitate", cfg)
    torch.set_num_threads(int(cfg.ppo.get("torch_threads", 1)))
    seed_everything(int(cfg.seed))
    metric_logger, metrics = make_logger(to_dict(cfg.logger), run.dir, to_dict(cfg)), {}
    try:
        metrics = purpose(to_dict(cfg), run.dir, trial_reporter(cfg), metric_logger)
    finally:
        metric_logger.close(metrics)
    run.save_metrics(metrics)
    refuse_blown_up(metrics, to_dict(cfg))  # after the metrics are written: nothing computed is lost
    verdict.append(last_line(metrics))
    if metrics["last_eval"] is None:  # ppo.total_steps=0: nothing learned, so no learned score (no main metric)
        return None
    run.set_main_metric("eval_reward", metrics["last_eval"], "maximize")
    return float(metrics["last_eval"])


def imitation_main(job: str, cfg, purpose: Callable[..., dict[str, Any]]) -> float | None:
    """A job's body: the motion named after its file, the run guarded, the verdict said last (after
    the run folder's line)."""
    from hydra.core.hydra_config import HydraConfig

    from aslexp.jobs._common import run_guarded
    from aslexp.jobs.validation import name_motion_after_its_file

    name_motion_after_its_file(cfg, list(HydraConfig.get().overrides.task))  # multirun jobs too
    verdict: list[str] = []
    value = run_guarded(job, cfg, lambda run: run_imitation(cfg, run, purpose, verdict))
    for line in verdict:
        log.info("%s", line)
    return value


def told_on_command_line(group: str) -> bool:
    """Whether this job's command line (or a sweep's job) sets ``group`` or one of its keys."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return False
    keys = {o.split("=", 1)[0].lstrip("+~") for o in HydraConfig.get().overrides.task}
    return any(key == group or key.startswith(f"{group}.") for key in keys)
