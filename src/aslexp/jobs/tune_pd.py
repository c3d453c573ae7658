"""``aslexp tune_pd``: how well do PD gains track a reference? (thesis section 5.3.1)

    aslexp tune_pd                                   # the controller config's gains
    aslexp tune_pd tuning.kp=0.5 tuning.kd=1.0       # other gains
    aslexp tune_pd tuning.motion=motions/hand/A.txt  # on a motion file (default: a random one)
    aslexp tune_pd tuning.objective=thesis           # Eq. 5.14: sums of squared errors
    aslexp tune_pd -m +sweeps=pd_gains_1             # Optuna (TPE) over kp, kd in [0, 1]

    aslexp tune_pd -m +sweeps=pd_gains_reference_velocity   # kp, kd, velocity_scale of the
                                                            # reference-velocity controller

The objective (minimised) while the PD targets follow the reference is ``tuning.objective``:
``reward`` (the default): 1 - the mean imitation reward over the motion, with the body's reward
config (the one imitate uses: its terms, weights and scales), so the best gains are the
best-scoring ones; ``mean_abs`` (aslexp's earlier one): mean |position error| + mean |velocity
error|, radians and rad/s added unweighted (so it can prefer gains that score a lower reward);
``thesis`` (Eq. 5.14): pose error + velocity error, each the sum over joints of squared
errors (Eq. 5.10), averaged over the steps. The targets are one control step ahead for the thesis
controller; for a controller with target options (``target_velocity: reference``, ``target_rate:
physics``) the environment runs with ``action_mode: residual`` and no correction, so the
controller's own targets are what is measured. The reference is a random smooth motion
(``tuning.motion: random``) or a motion file. Every run also measures the controller config's own
gains the same way: metrics.json holds ``reward`` beside ``default_reward`` (and
``reward_vs_default``), and the last log line says whether the tuned reward is below, at or above
the default's. The sweeps try the controller's own gains first (``hydra.sweeper.enqueue``), so a
sweep's best never scores below them. Each run writes ``controller.yaml``: the gains as a
`controller` config, ready to copy into conf/controller/ when it is the sweep's best.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import yaml
from omegaconf import DictConfig

from aslexp.data.root import resolve_data_root
from aslexp.jobs._common import job_main, run_guarded, seed_everything, to_dict
from aslexp.jobs.validation import check_config
from aslexp.runs.loggers import make_logger
from aslexp.runs.record import Run

log = logging.getLogger("aslexp.tune_pd")


# Rewards closer than this are the same (the imitate job's verdicts use the same tolerance).
LEVEL_TOLERANCE = 5e-4


def _tuned_controller(controller: dict[str, Any], tuning: dict[str, Any]) -> dict[str, Any]:
    """The controller config with the swept gains (every group) and velocity scale."""
    from aslexp.compose import deep_merge

    default = dict(controller["groups"].get("default", {}))
    overrides = {k: tuning[k] for k in ("kp", "kd", "max_force") if tuning.get(k) is not None}
    tuned = deep_merge(controller, {"name": "tuned", "groups": {"default": default | overrides}})
    if overrides:  # the swept gains apply to every group
        tuned["groups"] = {g: v | overrides for g, v in tuned["groups"].items()}
    if tuning.get("velocity_scale") is not None:
        tuned["velocity_scale"] = float(tuning["velocity_scale"])
    return tuned


def _reference(cfg: dict[str, Any], data_root: Path) -> Any:
    """The motion to track: a random smooth one over the body's joint ranges, or a motion file."""
    from aslexp.sim.body import BodySpec, load_layout
    from aslexp.sim.motion import random_motion

    tuning = cfg["tuning"]
    if tuning["motion"] != "random":
        return tuning["motion"]
    _, layout = load_layout(BodySpec.parse(cfg["body"]), data_root)
    rnd = tuning.get("random") or {}
    return random_motion([j.lower for j in layout.joints], [j.upper for j in layout.joints],
                         seconds=float(rnd.get("seconds", 4.0)),
                         keyframe_seconds=float(rnd.get("keyframe_seconds", 0.3)),
                         seed=int(rnd.get("seed", 0)))


def _track(cfg: dict[str, Any], controller: dict[str, Any], motion: Any, data_root: Path) -> dict[str, Any]:
    """``controller`` driven by the reference over the motion in the imitation env (its reward
    config): the tracking errors, the objective and the mean reward (:func:`pd_tracking_error`)."""
    from aslexp.compose import deep_merge
    from aslexp.envs.imitation import ImitationEnv
    from aslexp.envs.tracking import pd_tracking_error
    from aslexp.sim.pd import ControllerSpec

    tuning = cfg["tuning"]
    plain = ControllerSpec.parse(controller).is_thesis_pd
    # The thesis controller gets absolute targets `lookahead` steps ahead; a controller with target
    # options builds its targets from the reference itself, under a zero residual correction.
    env_cfg = deep_merge(cfg["env"], {"early_termination": {"min_reward": None},
                                      "action_mode": "absolute" if plain else "residual",
                                      "residual_velocity_range": 0.0, "reference_state_init": False})
    env = ImitationEnv(motion, body=cfg["body"], controller=controller, reward=cfg["reward"], env=env_cfg,
                       data_root=data_root, complete_configs=True, engine=cfg.get("engine"))  # Hydra composed every group
    try:
        lookahead = int(tuning.get("lookahead", 1)) if plain else env.spec_env.reference_lookahead
        return pd_tracking_error(env, tuning.get("steps"), lookahead, tuning.get("objective", "reward"))
    finally:
        env.close()


def tune_pd(cfg: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """The job without Hydra: build the controller from the gains, measure tracking, and measure
    the controller config's own gains the same way (the bar tuned gains must reach)."""
    from aslexp.sim.pd import ControllerSpec

    data_root = resolve_data_root(cfg.get("data_root"))
    controller = _tuned_controller(cfg["controller"], cfg["tuning"])
    spec = ControllerSpec.parse(controller)
    motion = _reference(cfg, data_root)
    result = _track(cfg, controller, motion, data_root)
    default = _track(cfg, cfg["controller"], motion, data_root)
    with open(out_dir / "controller.yaml", "w", encoding="utf-8") as fh:
        fh.write(f"# from aslexp tune_pd: objective {result['objective']:.5f} ({result['objective_kind']}), "
                 f"reward {result['reward']:.4f} (the {cfg['controller'].get('name')} controller's own gains: "
                 f"reward {default['reward']:.4f})\n")
        yaml.safe_dump(controller, fh, sort_keys=False)
    return {**result, "gains": controller["groups"], "velocity_scale": spec.velocity_scale,
            "controller_options": not spec.is_thesis_pd,
            # the controller config's own gains on the same motion, measured the same way
            "default_controller": cfg["controller"].get("name"), "default_gains": cfg["controller"]["groups"],
            "default_velocity_scale": ControllerSpec.parse(cfg["controller"]).velocity_scale,
            "default_reward": default["reward"], "default_objective": default["objective"],
            "reward_vs_default": result["reward"] - default["reward"]}


def verdict(metrics: dict[str, Any]) -> str:
    """The run's last line: the tuned gains' reward beside the controller config's own, and plainly
    whether it is below, at or above it."""
    gap = metrics["reward_vs_default"]
    level = ("AT the default controller's" if abs(gap) <= LEVEL_TOLERANCE else
             f"BELOW the default controller's by {-gap:.4f}" if gap < 0 else
             f"above the default controller's by {gap:.4f}")
    return (f"tuned gains {metrics['gains'].get('default')}: reward {metrics['reward']:.4f}; default controller "
            f"{metrics['default_controller']} {metrics['default_gains'].get('default')}: reward "
            f"{metrics['default_reward']:.4f}; {level}")


def _tune_pd_run(cfg: DictConfig, run: Run, said_last: list[str]) -> float:
    check_config("tune_pd", cfg)  # swept values (the rest: ConfigCheck); a bad one fails this run
    seed_everything(int(cfg.seed))
    metric_logger, metrics = make_logger(to_dict(cfg.logger), run.dir, to_dict(cfg)), {}
    try:
        metrics = tune_pd(to_dict(cfg), run.dir)
        metric_logger.log(metrics, step=0)  # one evaluation: the tracking errors and reward
    finally:
        metric_logger.close(metrics)
    run.save_metrics(metrics)
    # reward: 1 - reward (the imitation reward); mean_abs, thesis: errors in rad and rad/s
    name = "reward_shortfall" if metrics["objective_kind"] == "reward" else "tracking_error"
    run.set_main_metric(name, metrics["objective"], "minimize")
    # No trial_reporter here: the objective is one value at the end, so a pruner could only
    # discard a finished trial (a median pruner marked 26 of 40 as pruned before this).
    log.info("kp/kd %s: objective %.5f (%s; pose %.5f rad, velocity %.5f rad/s, reward %.4f)",
             metrics["gains"].get("default"), metrics["objective"], metrics["objective_kind"],
             metrics["pose_error"], metrics["velocity_error"], metrics["reward"])
    said_last.append(verdict(metrics))
    return float(metrics["objective"])


@job_main("tune_pd")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns the tracking objective (minimise); says the verdict last."""
    said_last: list[str] = []
    value = run_guarded("tune_pd", cfg, lambda run: _tune_pd_run(cfg, run, said_last))
    for line in said_last:
        log.info("%s", line)
    return value


if __name__ == "__main__":
    main()
