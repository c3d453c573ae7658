"""How an imitation result's runs differ from the setting it stands beside, computed, not typed.

A results-page row is only comparable with the thesis' number under the same definitions. This
module reads the facts a reader compares (engine and PD stand-in, rates, environments and steps per
update, KL estimator, action mapping, budget, seeds, evaluation protocol of the learned and the
baseline columns) from composed configs: the runs' own (``.hydra/config.yaml``) against the overlay
composed alone, which is the thesis' setting for a thesis overlay (``experiment=letters_thesis``
composes Table D.1, the thesis' hand, PD, reward and 240 Hz). Snapshots store the sentences, so the
page renders them without reading configs.

A run from before an option existed has no key for it; its value is then the behaviour it had
(no joint-speed clamp, aslexp's box action mapping, torchrl's KL reading), and the sentence says so.

What a row says about the engine is the engine's own data: ``report:`` of ``conf/engine/<name>.yaml``
(a sentence and its parts, :class:`aslexp.sim.engine.EngineReport`), filled here from the run's engine
section; this module names no engine. A run from before ``report:`` existed gets today's
``conf/engine/<name>.yaml``'s, and an engine with none (one registered by the tests) is said by its name.
"""

from __future__ import annotations

import math
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from aslexp.compose import compose, group
from aslexp.errors import ConfigError
from aslexp.paths import CONF_DIR

# What a key meant before it existed (the behaviour of the code that ran without it).
_BEFORE = {"joint_speed_limit": None, "action_mapping": "box", "kl_stop": "torchrl"}


def compose_overlay(job: str, overrides: list[str], conf_dir: Path = CONF_DIR) -> dict[str, Any]:
    """``job``'s config composed from ``conf_dir`` with ``overrides`` (a plain dict, interpolations
    kept), by the one composer (:mod:`aslexp.compose`)."""
    return compose(job, overrides, conf_dir=conf_dir, resolve=False)


def _engine_today(name: str | None) -> dict[str, Any]:
    """``conf/engine/<name>.yaml`` as the imitate job composes it today (None: the job's default
    engine; {} for an engine that has no file there, one registered by the tests)."""
    try:
        return group("engine", name)
    except ConfigError:
        return {}


def engine_section(cfg: dict[str, Any]) -> dict[str, Any]:
    """A run's engine section, completed as it ran: no section at all (a run from before the engine
    group) is the default engine; a key the run lacks is what it meant then (:data:`_BEFORE`), else
    today's file's (``report:`` included)."""
    engine = dict(cfg.get("engine") or {})
    today = _engine_today(engine.get("name"))
    before = {k: v for k, v in _BEFORE.items() if k in today}
    return {**today, **before, **engine}


def _chosen(by: str, engine: dict[str, Any], cfg: dict[str, Any]) -> Any:
    """The value a report part is chosen by: an engine key, or ``section.key`` of the config."""
    if "." not in by:
        return engine.get(by)
    section, _, name = by.partition(".")
    return (cfg.get(section) or {}).get(name)


def engine_text(cfg: dict[str, Any]) -> str:
    """What a row says about a run's engine: its ``report:`` filled from its own values (the name
    where it has none)."""
    engine = engine_section(cfg)
    report = engine.get("report")
    if not report:
        return str(engine.get("name", "?"))
    values = {k: v for k, v in engine.items() if k != "report"}
    try:
        for name, part in (report.get("parts") or {}).items():
            value = _chosen(part["by"], engine, cfg)
            text = part.get("null" if value is None else str(value), part.get("otherwise", ""))
            values[name] = text.format(**values)
        return report["text"].format(**values)
    except (KeyError, ValueError) as error:
        raise ConfigError(f"engine.report of engine {engine.get('name')}: {error!r} cannot be filled "
                          f"from {sorted(values)}") from None


def facts(cfg: dict[str, Any]) -> dict[str, str]:
    """The comparable facts of one composed imitation config, each as the page prints it."""
    ppo, env, controller = cfg.get("ppo") or {}, cfg.get("env") or {}, cfg.get("controller") or {}
    out: dict[str, str] = {"engine": engine_text(cfg)}
    gains = (controller.get("groups") or {}).get("default") or {}
    out["controller"] = (f"{controller.get('name', '?')} ({controller.get('mode', '?')}, kp {gains.get('kp', '?')}, "
                         f"kd {gains.get('kd', '?')})")
    out["rate"] = f"physics {env.get('physics_hz', '?'):g} Hz, control {env.get('control_hz', '?'):g} Hz"
    reward = cfg.get("reward") or {}
    terms = ", ".join(f"{name} {term.get('weight', 0):.3g}/{term.get('scale', 0):.3g}"
                      for name, term in (reward.get("terms") or {}).items() if term.get("weight", 0))
    out["reward"] = f"{reward.get('combine', 'sum')} of {terms} (weight/scale)"
    planner = cfg.get("planner")
    if planner:  # a planner acts (aslexp.control.mpc): nothing is trained, no learner's fact applies
        out["policy"] = (f"none: model-predictive control ({planner.get('method')}, horizon {planner.get('horizon')}, "
                         f"{planner.get('samples')} samples) on the controller")
        return out
    out["policy"] = "learned (PPO)"
    pool = cfg.get("train_motions")  # one policy of many motions (aslexp.envs.motion_pool)
    if not pool:
        out["trained on"] = "the evaluated motion"
    elif pool.get("folder"):  # real signs in folds by gloss (aslexp.envs.sign_folds)
        out["trained on"] = (f"a pool ({pool.get('name')}): the motions of {pool['folder']} outside the evaluated "
                             f"sign's gloss fold ({pool.get('folds')} folds by gloss, seed {pool.get('seed')})")
    else:
        out["trained on"] = (f"a pool ({pool.get('name')}): {', '.join(map(str, pool.get('motions') or [])) or 'no listed motion'}"
                             f"{' but the evaluated one' if pool.get('hold_out_evaluated', True) else ''} and "
                             f"{(pool.get('generated') or {}).get('count', 0)} generated motions")
    num_envs, batch = int(ppo.get("num_envs", 1)), int(ppo.get("steps_per_rollout", 0))
    out["update"] = f"{num_envs} environment{'s' if num_envs != 1 else ''} x {math.ceil(batch / max(num_envs, 1)):,} steps = {batch:,} per update"
    out["learner"] = (f"{' x '.join(str(h) for h in ppo.get('hidden_sizes') or [])} MLP, lr {ppo.get('learning_rate')}, "
                      f"minibatch {ppo.get('minibatch_size')}, {ppo.get('epochs')} epochs, gamma {ppo.get('gamma')}")
    kl_stop = ppo.get("kl_stop", _BEFORE["kl_stop"])
    kl_text = {"sb3": "SB3 1.6's (before the step)", "torchrl": "torchrl's (after the step)"}.get(kl_stop, kl_stop)
    out["KL stop"] = ("none" if ppo.get("target_kl") is None else f"target {ppo.get('target_kl')}, {kl_text}"
                      + ("" if "kl_stop" in ppo else ", the only one before ppo.kl_stop existed"))
    mapping = ppo.get("action_mapping", _BEFORE["action_mapping"])
    out["action mapping"] = ({"sb3": "SB3's (the sample in joint units, clipped)",
                              "box": "aslexp's (a unit Gaussian onto the action box)"}.get(mapping, mapping)
                             + ("" if "action_mapping" in ppo else ", the only one before ppo.action_mapping existed"))
    return out


def run_facts(metrics: list[dict[str, Any]]) -> dict[str, Any]:
    """What the runs' metrics.json say about budget, seeds and evaluation protocols."""
    trained = [m for m in metrics if m.get("steps", 0) > 0]
    per_motion: dict[str, int] = {}
    for m in trained:
        per_motion[str(m.get("motion"))] = per_motion.get(str(m.get("motion")), 0) + 1
    protocols = set()
    for m in metrics:
        protocol = m.get("eval_protocol") or {}
        learned = (len(protocol.get("phases") or [0.0]), protocol.get("steps"))
        measured = m.get("report_baselines")
        if measured:
            baselines = (len(measured[0].get("phases") or [0.0]), measured[0].get("seconds"))
        elif protocol and not _names_report_baselines(m):
            # no report.baselines: the columns are the run's own `baselines`, measured by the job under
            # its evaluation protocol (every run that records eval_protocol)
            baselines = (learned[0], None)
        else:  # report.baselines measured by the report from phase 0 (runs older than metrics.json's report_baselines)
            baselines = None
        protocols.add((learned, baselines))
    return {"steps": [m["steps"] for m in trained], "seeds_per_motion": sorted(set(per_motion.values())),
            "protocols": sorted(protocols, key=str)}


def _names_report_baselines(metrics: dict[str, Any]) -> bool:
    """Whether the run's overlay named ``report.baselines`` (its composed config, beside metrics.json)."""
    from aslexp.reports.report import run_config

    try:
        return bool(((run_config(Path(metrics["run_dir"])) or {}).get("report") or {}).get("baselines"))
    except (KeyError, FileNotFoundError):
        return True  # unknown: as runs older than report_baselines were read


def _phases(count: int) -> str:
    return f"{count} start phase{'s' if count != 1 else ''}"


def imitation_differences(run_configs: list[dict[str, Any]], reference: dict[str, Any], runs: dict[str, Any],
                          thesis_seeds: int | None = None, reference_name: str = "thesis") -> list[str]:
    """Sentences: every fact where the runs differ from ``reference`` (the thesis' setting: its
    overlay composed alone), the budget as a fraction of the reference's, the seeds per motion
    against ``thesis_seeds``, and the evaluation protocols of the learned and the baseline columns
    (``runs``: :func:`run_facts`)."""
    out = []
    ours: dict[str, list[str]] = {}
    for cfg in run_configs:
        for key, value in facts(cfg).items():
            ours.setdefault(key, [])
            if value not in ours[key]:
                ours[key].append(value)
    theirs = facts(reference)
    for key, values in ours.items():
        if key in theirs and values != [theirs.get(key)]:
            out.append(f"{key}: {' / '.join(values)} ({reference_name}: {theirs.get(key, '-')})")
    total = (reference.get("ppo") or {}).get("total_steps")
    steps = runs.get("steps") or []
    if steps and isinstance(total, (int, float)) and total > 0:
        low, high = min(steps), max(steps)
        span = f"{low:,}" if low == high else f"{low:,}-{high:,}"
        share = f"{100 * low / total:.2g}%" if low == high else f"{100 * low / total:.2g}-{100 * high / total:.2g}%"
        out.append(f"budget: {span} steps per run, {share} of {reference_name}' {int(total):,}")
    if runs.get("seeds_per_motion") and thesis_seeds:
        out.append(f"seeds: {'/'.join(str(c) for c in runs['seeds_per_motion'])} per motion (thesis: {thesis_seeds})")
    scored = "the planner" if any(cfg.get("planner") for cfg in run_configs) else "learned"
    for (count, eval_steps), baselines in runs.get("protocols") or []:
        episodes = f"{_phases(count)} x {eval_steps} control steps"
        if baselines is None:
            out.append(f"evaluation: {scored} from {episodes}; the no-learning baselines from phase 0 only, 10 s "
                       f"(measured at report time: runs older than report_baselines)")
        elif baselines[0] != count:
            out.append(f"evaluation: {scored} from {episodes}, the baselines from {_phases(baselines[0])} x {baselines[1]:g} s")
        else:
            out.append(f"evaluation: {scored} and baselines alike, {episodes}")
    return out


def conf_at_commit(commit: str, root: Path, into: Path) -> Path:
    """``conf/`` as it was at ``commit`` (git archive), under ``into``; the folder."""
    into.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(root), "archive", commit, "conf"], check=True, capture_output=True).stdout
    subprocess.run(["tar", "-x", "-C", str(into)], input=archive, check=True)
    return into / "conf"


def configs_at_commits(job: str, overrides: dict[str, Any], commits: list[str], root: Path) -> list[dict[str, Any]]:
    """For a snapshot whose run folders are gone: the runs' configs recomposed from ``conf/`` at each
    of their git commits with their recorded overrides (a ``+``, a dirty tree, cannot be recovered:
    its commit stands in; the first value of each varied override stands for all)."""
    common = list(overrides.get("common") or [])
    varied = overrides.get("varied") or {}
    first_values = [f"{k}={v[0]}" for k, v in varied.items() if v]
    configs = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, commit in enumerate(sorted({c.rstrip("+") for c in commits})):
            conf = conf_at_commit(commit, root, Path(tmp) / str(k))
            configs.append(compose_overlay(job, common + first_values, conf))
    return configs
