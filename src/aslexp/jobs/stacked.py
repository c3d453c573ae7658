"""Runs trained together: the jobs of an imitate multirun (letters x seeds, signs x seeds) as one
program on one device (:class:`aslexp.rl.stacked.StackedPPO`), then each job finished as its own run.

    aslexp imitate -m experiment=letters_thesis hydra/launcher=stacked                 # figure 5.9's 50 runs
    aslexp imitate -m experiment=letters_thesis hydra/launcher=stacked ppo.device=cuda
    aslexp imitate -m motion=A,B seed=0,1 engine=mujoco ppo=fast hydra/launcher=stacked

The launcher (``hydra_plugins.aslexp_stacked_launcher``, ``conf/hydra/launcher/stacked.yaml``) composes
every job of the sweep and gives them to :func:`train_together`: their environments one batch of the engine
(each run's rows on its own motion), their agents one stacked network, each run with its own seed,
evaluations, progress.csv and checkpoints/last.pt (a PPOTrainer checkpoint: ``resume=`` continues one
run alone). Then each job runs as ``aslexp imitate`` with ``resume=`` its own folder: nothing is left
to train, so its policy is evaluated under its protocol and its folder gets what every imitate run's
gets (metrics.json, the reward curve, the tracking figures, run.json); the multirun's summary follows.

Jobs trained together may differ in their motion and seed only (one batch has one body, controller,
reward, environment and learner); anything else is refused in one line that names the key.
"""

from __future__ import annotations

import functools
import logging
import time
from pathlib import Path
from typing import Any

from aslexp.errors import ConfigError

log = logging.getLogger("aslexp.stacked")

# What the runs of one program may set apart: the rest makes one batch and one learner.
OWN_KEYS = ("motion", "seed")


def _flat(tree: Any, prefix: str = "") -> dict[str, Any]:
    if isinstance(tree, dict):
        out: dict[str, Any] = {}
        for key, value in tree.items():
            out.update(_flat(value, f"{prefix}{key}."))
        return out
    return {prefix[:-1]: tree}


def check_together(cfgs: list[dict[str, Any]]) -> None:
    """Refuse jobs that cannot share one program: a key other than motion and seed that differs, a job
    that does not train (policy=, planner=, resume=, ppo.total_steps=0), a pool of motions."""
    if not cfgs:
        raise ConfigError("hydra/launcher=stacked: the sweep has no job")
    for cfg in cfgs:
        for key, what in (("policy", "performs a policy"), ("planner", "plans"), ("resume", "resumes a run"),
                          ("train_motions", "trains on a pool of motions")):
            if cfg.get(key):
                raise ConfigError(f"hydra/launcher=stacked: {key}={cfg[key]!r}: a job that {what} is not trained "
                                  f"together (the stacked launcher trains runs of one motion each)")
        if int(cfg["ppo"]["total_steps"]) <= 0:
            raise ConfigError("hydra/launcher=stacked: ppo.total_steps must be > 0 (the runs are trained)")
    first = {k: v for k, v in _flat(cfgs[0]).items() if k.split(".")[0] not in OWN_KEYS}
    for cfg in cfgs[1:]:
        other = {k: v for k, v in _flat(cfg).items() if k.split(".")[0] not in OWN_KEYS}
        for key in sorted(set(first) | set(other)):
            if first.get(key) != other.get(key):
                raise ConfigError(f"hydra/launcher=stacked: {key} is {first.get(key)!r} in one job and "
                                  f"{other.get(key)!r} in another; runs trained together differ in motion and "
                                  f"seed only")


def task_config(cfg, overrides: list[str]) -> dict[str, Any]:
    """A job's composed config (Hydra's, its ``hydra`` node removed) as the imitate job reads it: the
    motion named after its file, the imitate schema checked, plain containers."""
    from aslexp.jobs._common import to_dict
    from aslexp.jobs.validation import check_config, name_motion_after_its_file

    name_motion_after_its_file(cfg, overrides)
    check_config("imitate", cfg)
    return to_dict(cfg)


def train_together(cfgs: list[dict[str, Any]], out_dirs: list[Path]) -> dict[str, Any]:
    """Train the jobs ``cfgs`` (plain imitate configs) as one program, job ``k`` into ``out_dirs[k]``;
    returns the program's summary (runs, steps per run, seconds, steps/s over all runs)."""
    import dataclasses

    from aslexp.data.root import resolve_data_root
    from aslexp.envs.assembly import ImitationSetup
    from aslexp.envs.batched import BatchedImitationEnv
    from aslexp.jobs._imitation import build_envs, engine_vector_env
    from aslexp.rl.ppo import PPOConfig
    from aslexp.rl.stacked import StackedPPO, StackedRun

    check_together(cfgs)
    config = PPOConfig.parse(cfgs[0]["ppo"])
    config = dataclasses.replace(config, vector_env=engine_vector_env(cfgs[0], config.vector_env))
    root = resolve_data_root(cfgs[0].get("data_root"))
    motions: dict[str, int] = {}  # motion file -> its clip in the batch; runs of one motion share its evaluation
    setups, evals = [], {}
    for cfg in cfgs:
        file = str(cfg["motion"]["file"])
        if file not in motions:
            motions[file] = len(motions)
            setups.append(ImitationSetup.from_config(cfg, root))
            evals[file] = build_envs(cfg, root, "batched")[1]
    make_env = functools.partial(BatchedImitationEnv.from_setup, setup=setups[0], shape_reward=True,
                                 motions=[setup.motion for setup in setups])
    runs = [StackedRun(seed=int(cfg["seed"]), out_dir=Path(out), clip=motions[str(cfg["motion"]["file"])],
                       eval_env=evals[str(cfg["motion"]["file"])]) for cfg, out in zip(cfgs, out_dirs)]
    log.info("%d runs as one program: %s", len(runs), ", ".join(f"{cfg['motion']['name']} seed {cfg['seed']}"
                                                              for cfg in cfgs))
    if cfgs[0].get("overwrite"):  # start over: the folders' earlier curves and checkpoints go
        for out in out_dirs:
            for name in ("progress.csv", "checkpoints/last.pt", "checkpoints/last.pt.prev"):
                (Path(out) / name).unlink(missing_ok=True)
    started = time.perf_counter()
    program = StackedPPO(make_env, runs, config)
    try:
        program.restore()  # a program stopped before its end (a kill, a time limit) continues
        program.train()
    finally:
        program.close()
        for env in evals.values():
            env.close()
    seconds = time.perf_counter() - started
    return {"runs": len(runs), "steps_per_run": program.steps, "seconds": round(seconds, 1),
            "steps_per_s_all_runs": round(len(runs) * program.steps / max(seconds, 1e-9))}
