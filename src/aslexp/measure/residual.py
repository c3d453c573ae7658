"""The residual setting's comparison rows, measured by the run (``report.residual`` of
``experiment=signs_free_residual``; the table: :mod:`aslexp.reports.residual_report`).

Per motion, under the run's reward and the policy's evaluation protocol (``ppo.eval_steps`` control
steps from each of ``ppo.phases``; deterministic): the controller with no correction on the
reference one step ahead, where the root drifts under it from phase 0, the smoothed reference for
each alpha of ``report.residual.smoothing``, constant random corrections
(``report.residual.random_corrections``) and the controller on a pinned base
(``report.residual.compare``). Cached by key: a sweep's seeds share one measurement.
"""

from __future__ import annotations

import json
import logging
import time
from pathlib import Path
from typing import Any

import numpy as np

from aslexp import compose
from aslexp.files import atomic_write_text

log = logging.getLogger("aslexp.residual")


def run_env(cfg: dict[str, Any], env_overrides: dict[str, Any] | None = None,
            body_overrides: dict[str, Any] | None = None):
    """The imitation environment a run's composed config describes, with ``env_overrides`` and
    ``body_overrides`` merged over its env and body configs."""
    from aslexp.data.root import resolve_data_root
    from aslexp.envs.assembly import ImitationSetup
    from aslexp.envs.imitation import ImitationEnv

    setup = ImitationSetup.from_config(cfg, resolve_data_root(cfg.get("data_root")))
    return ImitationEnv.from_setup(setup.merged(env=env_overrides or {}, body=body_overrides or {}))


def root_drift(env, policy, steps: int) -> dict[str, float]:
    """Where the root went under ``policy`` from phase 0: its largest tilt from vertical and its
    largest yaw against the reference's root (degrees), over ``steps`` control steps."""
    from aslexp import quaternion
    from aslexp.envs.spec import UP_AXIS

    obs, _ = env.reset(options={"phase": 0.0})
    tilt = yaw = 0.0
    for _ in range(steps):
        obs, _, terminated, _, _ = env.step(policy(obs, env))
        _, rotation, _, _ = env.sim.base_state()
        _, reference, _, _ = env.reference.root(env.time)
        up = quaternion.to_matrix(rotation)[:, UP_AXIS]
        tilt = max(tilt, float(np.degrees(np.arccos(np.clip(up[UP_AXIS], -1.0, 1.0)))))
        yaw = max(yaw, abs(float(np.degrees(quaternion.twist_angle(reference, rotation, UP_AXIS)))))
        if terminated:
            break
    return {"max_tilt_deg": tilt, "max_yaw_deg": yaw}


def residual_baselines(cfg: dict[str, Any], cache: Path | None = None) -> dict[str, Any]:
    """The comparison rows for one motion (deterministic: computed once, cached in ``cache``)."""
    from aslexp.envs.imitation import ImitationEnv
    from aslexp.envs.spec import RESIDUAL_BASE_KEYS, TRAINING_ONLY_KEYS
    from aslexp.rl.evaluate import (constant_correction_policy, evaluate_phases, reference_policy,
                                    smoothed_reference_policy)
    from aslexp.rl.ppo import PPOConfig

    settings = (cfg.get("report") or {}).get("residual") or {}
    ppo = PPOConfig.parse(cfg["ppo"])
    # Shaping scores nothing, and every row is measured on the reference's own base (the controller
    # is the reference one step ahead): a variant that filters its base is compared with the same bar.
    scored_env = {k: v for k, v in cfg["env"].items() if k not in TRAINING_ONLY_KEYS + RESIDUAL_BASE_KEYS}
    key = {"settings": settings, "body": cfg["body"], "controller": cfg["controller"], "reward": cfg["reward"],
           "env": scored_env, "motion": cfg["motion"], "protocol": ppo.eval_protocol}
    # the default engine's caches stay valid; what a report says of an engine (`report:`) simulates nothing
    engine = {k: v for k, v in (cfg.get("engine") or {}).items() if k != "report"}
    if engine and engine != {k: v for k, v in compose.group("engine").items() if k != "report"}:
        key["engine"] = engine
    key = json.loads(json.dumps(key))
    if cache is not None and cache.is_file():
        stored = json.loads(cache.read_text())
        if stored.get("key") == key:
            return stored["rows"]
    def make(body_overrides: dict[str, Any]) -> ImitationEnv:  # evaluations score whole episodes
        return run_env({**cfg, "env": scored_env}, {"early_termination": {"min_reward": None}}, body_overrides)

    chance = settings.get("random_corrections") or {}
    if set(chance) - {"count", "rms", "seed"} or (chance and "rms" not in chance):
        raise ValueError(f"report.residual.random_corrections: keys {sorted(chance)}; expected rms and "
                         f"optionally count (default 1) and seed (default 0)")
    planned = (2 + len(settings.get("smoothing", [])) + (int(chance.get("count", 1)) if chance else 0)
               + bool(settings.get("compare")))  # controller, its drift, smoothing, chance, compare
    started, done = time.perf_counter(), [0]

    def score(env: ImitationEnv, policy) -> float:
        value = evaluate_phases(env, policy, ppo.eval_steps, ppo.phases).mean_reward
        tick()
        return value

    def tick() -> None:  # minutes of evaluations per sign: say how far along they are
        done[0] += 1
        each = (time.perf_counter() - started) / done[0]
        log.info("residual baselines %s: %d/%d evaluations (%.1f s each, ETA %.0f s)", cfg["motion"]["name"],
                 done[0], planned, each, each * (planned - done[0]))

    lookahead = int(cfg["env"].get("reference_lookahead", 1))
    rows: dict[str, Any] = {}
    env = make({})
    try:
        rows["controller"] = score(env, reference_policy(lookahead))
        rows["controller_drift"] = root_drift(env, reference_policy(lookahead), ppo.eval_steps)
        tick()
        groups = settings.get("smoothing_groups")
        rows["smoothed"] = {str(a): score(env, smoothed_reference_policy(float(a), tuple(groups) if groups else None))
                            for a in settings.get("smoothing", [])}
        if chance:
            first, rms = int(chance.get("seed", 0)), float(chance["rms"])
            seeds = [first + k for k in range(int(chance.get("count", 1)))]
            rows["random_corrections"] = {"rms": rms, "seeds": seeds,
                                          "scores": [score(env, constant_correction_policy(rms, seed)) for seed in seeds]}
    finally:
        env.close()
    compare = settings.get("compare") or {}
    if compare:
        env = make(compare.get("body") or {})
        try:
            rows["compare"] = score(env, reference_policy(lookahead))
        finally:
            env.close()
    if cache is not None:  # atomic: the seeds of a sweep may write it at once (the same rows)
        cache.parent.mkdir(parents=True, exist_ok=True)
        atomic_write_text(cache, json.dumps({"key": key, "rows": rows}, indent=1))
    return rows
