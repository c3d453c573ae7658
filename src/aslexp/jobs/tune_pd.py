"""``aslexp tune_pd``: how well do PD gains track a reference? (thesis section 5.3.1)

    aslexp tune_pd                                   # the controller config's gains
    aslexp tune_pd tuning.kp=0.5 tuning.kd=1.0       # other gains
    aslexp tune_pd tuning.objective=thesis           # Eq. 5.14: sums of squared errors
    aslexp tune_pd -m +sweeps=pd_gains_1             # Optuna (TPE) over kp, kd in [0, 1]

    aslexp tune_pd -m +sweeps=pd_gains_reference_velocity   # kp, kd, velocity_scale of the
                                                            # reference-velocity controller

The objective (minimised) while the PD targets follow the reference is ``tuning.objective``:
``mean_abs`` (aslexp's): mean |position error| + mean |velocity error|; ``thesis`` (Eq. 5.14):
pose error + velocity error, each the sum over joints of squared errors (Eq. 5.10), averaged over
the steps. The targets are one control step ahead for the thesis controller; for a controller with
target options (``target_velocity: reference``, ``target_rate: physics``) the environment runs
with ``action_mode: residual`` and no correction, so the controller's own targets are what is
measured. The reference is a random smooth motion (``tuning.motion: random``) or a motion file.
Each run writes ``controller.yaml``: the gains as a `controller` config, ready to copy into
conf/controller/ when it is the sweep's best.
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


def tune_pd(cfg: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """The job without Hydra: build the controller from the gains, measure tracking."""
    from aslexp.compose import deep_merge
    from aslexp.envs.imitation import ImitationEnv
    from aslexp.envs.tracking import pd_tracking_error
    from aslexp.sim.body import BodySpec, load_layout
    from aslexp.sim.motion import random_motion
    from aslexp.sim.pd import ControllerSpec

    tuning = cfg["tuning"]
    data_root = resolve_data_root(cfg.get("data_root"))
    controller = cfg["controller"]
    default = dict(controller["groups"].get("default", {}))
    overrides = {k: tuning[k] for k in ("kp", "kd", "max_force") if tuning.get(k) is not None}
    controller = deep_merge(controller, {"name": "tuned", "groups": {"default": default | overrides}})
    if overrides:  # the swept gains apply to every group
        controller["groups"] = {g: v | overrides for g, v in controller["groups"].items()}
    if tuning.get("velocity_scale") is not None:
        controller["velocity_scale"] = float(tuning["velocity_scale"])
    spec = ControllerSpec.parse(controller)
    plain = spec.is_thesis_pd
    if tuning["motion"] == "random":
        _, layout = load_layout(BodySpec.parse(cfg["body"]), data_root)
        rnd = tuning.get("random") or {}
        motion = random_motion([j.lower for j in layout.joints], [j.upper for j in layout.joints],
                               seconds=float(rnd.get("seconds", 4.0)),
                               keyframe_seconds=float(rnd.get("keyframe_seconds", 0.3)),
                               seed=int(rnd.get("seed", 0)))
    else:
        motion = tuning["motion"]
    # The thesis controller gets absolute targets `lookahead` steps ahead; a controller with target
    # options builds its targets from the reference itself, under a zero residual correction.
    env_cfg = deep_merge(cfg["env"], {"early_termination": {"min_reward": None},
                                      "action_mode": "absolute" if plain else "residual",
                                      "residual_velocity_range": 0.0, "reference_state_init": False})
    env = ImitationEnv(motion, body=cfg["body"], controller=controller, reward=cfg["reward"], env=env_cfg,
                       data_root=data_root, complete_configs=True, engine=cfg.get("engine"))  # Hydra composed every group
    lookahead = int(tuning.get("lookahead", 1)) if plain else env.spec_env.reference_lookahead
    result = pd_tracking_error(env, tuning.get("steps"), lookahead, tuning.get("objective", "mean_abs"))
    env.close()
    with open(out_dir / "controller.yaml", "w", encoding="utf-8") as fh:
        fh.write(f"# from aslexp tune_pd: objective {result['objective']:.5f}\n")
        yaml.safe_dump(controller, fh, sort_keys=False)
    return {**result, "gains": controller["groups"], "velocity_scale": spec.velocity_scale,
            "controller_options": not plain}


def _tune_pd_run(cfg: DictConfig, run: Run) -> float:
    check_config("tune_pd", cfg)  # swept values (the rest: ConfigCheck); a bad one fails this run
    seed_everything(int(cfg.seed))
    metric_logger, metrics = make_logger(to_dict(cfg.logger), run.dir, to_dict(cfg)), {}
    try:
        metrics = tune_pd(to_dict(cfg), run.dir)
        metric_logger.log(metrics, step=0)  # one evaluation: the tracking errors and reward
    finally:
        metric_logger.close(metrics)
    run.save_metrics(metrics)
    run.set_main_metric("tracking_error", metrics["objective"], "minimize")
    # No trial_reporter here: the objective is one value at the end, so a pruner could only
    # discard a finished trial (a median pruner marked 26 of 40 as pruned before this).
    log.info("kp/kd %s: objective %.5f (pose %.5f rad, velocity %.5f rad/s, reward %.4f)",
             metrics["gains"].get("default"), metrics["objective"], metrics["pose_error"],
             metrics["velocity_error"], metrics["reward"])
    return float(metrics["objective"])


@job_main("tune_pd")
def main(cfg: DictConfig) -> float:
    """Hydra entry point; returns the tracking objective (minimise)."""
    return run_guarded("tune_pd", cfg, lambda run: _tune_pd_run(cfg, run))


if __name__ == "__main__":
    main()
