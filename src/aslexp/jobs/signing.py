"""``aslexp signing``: the simulated signer scored against the person over a folder of extracted motions.

    aslexp signing                                              # the 291 WLASL clips, the standing body's controller
    aslexp signing motions=DIR limit=20                         # another folder, its first 20 motions
    aslexp signing policy=RUN_DIR                               # ... and a trained policy performing each one
    aslexp signing resume=RUN_DIR                               # an interrupted table: its clips are not redone

Every motion of ``motions`` (a folder ``aslexp extract --motions`` wrote: ``motions/upper_body/*.txt``
and ``reports/``) is performed once from its start: the retargeted reference played kinematically,
the controller alone on the reference one step ahead and, with ``policy=``, the policy (under its
run's setting, :mod:`aslexp.jobs.performing`). Each stage's keypoints in the source's image frame are
scored against the person's (DTW, :mod:`aslexp.signing.performance`) and read back by the recognition
wing's fold models beside the person's own clip (:mod:`aslexp.signing.reading`). The run folder holds
``clips.jsonl`` (a line per clip, written as it goes), ``signing.json`` and ``signing.md`` (the table
with intervals over glosses and the targets, :mod:`aslexp.signing.table`) and ``signing.png``.
"""

from __future__ import annotations

import json
import logging
import math
import time
from pathlib import Path
from typing import Any

from omegaconf import DictConfig

from aslexp.errors import ConfigError, DataError
from aslexp.jobs._common import job_main, run_guarded, seed_everything, to_dict

log = logging.getLogger("aslexp.signing")

CLIPS_FILE = "clips.jsonl"
OPEN_HAND = "open hand"  # the hand body's baseline stage: every finger joint at 0
TABLE_JSON = "signing.json"
TABLE_MD = "signing.md"
FIGURE = "signing.png"


def motion_files(folder: str | Path, limit: int | None, implausible: str, glosses: set[str] | None = None,
                 data_root: str | Path | None = None) -> tuple[list[Path], list[dict]]:  # fmt: skip
    """The upper-body motions of an extraction folder (:func:`aslexp.envs.sign_folds.read_sign_folder`,
    sorted by name; those of ``glosses`` only, when given; the first ``limit``) and those left out
    (marked implausible by their report, unless ``implausible: keep``). A video's clip, whose report
    names no gloss, has WLASL's gloss for its video id (under ``data_root``)."""
    from aslexp.envs.sign_folds import read_sign_folder
    from aslexp.signing.reading import gloss_of_source

    kept, left_out = [], []
    for clip in read_sign_folder(Path(folder), lambda name: gloss_of_source(None, name, data_root)):
        if glosses is not None and clip.gloss not in glosses:
            continue
        if not clip.plausible and implausible == "skip":
            left_out.append({"motion": clip.name, "why": "implausible: " + "; ".join(clip.reasons)})
            continue
        kept.append(clip.file)
    return (kept if limit is None else kept[:limit]), left_out


def held_out_glosses(performer: dict[str, Any] | None) -> set[str] | None:
    """A pool-trained policy's test glosses (its run's ``train_motions``): the signs it never saw."""
    pool = (performer or {}).get("trained_on")
    signs = pool.get("signs") if isinstance(pool, dict) else None
    if isinstance(signs, dict) and signs.get("test_glosses"):
        return set(signs["test_glosses"])
    return None


def policy_of(cfg: dict[str, Any]):
    """``policy=RUN_DIR``: the config its run performs under and its agent (weights and observation
    statistics); None when no policy is given."""
    if not cfg.get("policy"):
        return cfg, None, None
    from aslexp.jobs.performing import performing_config

    performing, record = performing_config(cfg)
    return performing, record, record["checkpoint"]


def _agent(cfg: dict[str, Any], env, checkpoint: str):
    from aslexp.rl.checkpoint import load_checkpoint
    from aslexp.rl.ppo import PPOConfig, agent_for_spaces

    agent = agent_for_spaces(PPOConfig.parse(cfg["ppo"]).model, env.observation_space, env.action_space)
    try:
        agent.load_state_dict(load_checkpoint(checkpoint)["agent"])
    except (KeyError, RuntimeError, ValueError) as error:
        raise ConfigError(f"policy: checkpoint {checkpoint} does not fit this body and setting: {error}") from None
    return agent


def performing_env(cfg: dict[str, Any], motion: Path, data_root: Path):
    """The env that performs ``motion`` once from its start under ``cfg``'s setting (no early end on
    a low reward: the whole pass is scored), and the control steps of one pass."""
    from aslexp.envs.assembly import ImitationSetup
    from aslexp.envs.imitation import ImitationEnv

    setup = ImitationSetup.from_config({**cfg, "motion": {"name": motion.stem, "file": str(motion)}}, data_root)
    env = ImitationEnv.from_setup(setup.merged(env={"early_termination": {"min_reward": None}}))
    return env, int(math.ceil(float(env.reference.duration) * float(env.spec_env.control_hz))) + 1


def hand_file(motion: Path) -> Path:
    """The hand motion extraction wrote beside an upper-body one (``motions/hand/<id>.txt``)."""
    return motion.parent.parent / "hand" / motion.name


def score_hand_clip(hand_cfg: dict[str, Any], file: Path, body_env, data_root: Path) -> dict[str, Any]:
    """The hand body's controller on a clip's hand motion, its fingers worn by the clip's upper body
    on the reference arm (:func:`aslexp.signing.performance.score_hand_trajectory`) and scored against
    the person's hand of the side the hand motion was retargeted from: the reference and the controller."""
    import numpy as np

    from aslexp.rl.evaluate import evaluate
    from aslexp.signing.keypoints import SigningSource
    from aslexp.signing.performance import score_hand_trajectory

    source, why = SigningSource.for_motion(body_env.motion.source)
    if source is None:
        return {"file": str(file), "stages": None, "why": why}
    side = (json.loads(source.report.read_text()).get("hand") or {}).get("side")
    if side not in ("right", "left"):
        return {"file": str(file), "stages": None, "why": f"{source.report}: hand.side: expected right or left"}
    env, steps = performing_env(hand_cfg, file, data_root)
    try:
        look = evaluate(env, lambda obs, env: env.reference_action(1), steps, record=True)
        # The no-learning floor of a handshape: the hand held open (every finger joint at 0) all along.
        trajectory = {**look.trajectory, "q_open": np.zeros_like(look.trajectory["q_ref"])}
        stages = {stage: score_hand_trajectory(body_env, env, trajectory, source, side, joints)
                  for stage, joints in (("reference", "q_ref"), ("controller", "q_sim"), (OPEN_HAND, "q_open"))}
    finally:
        env.close()
    return {"file": str(file), "side": side, "body": hand_cfg["body"]["name"], "engine": hand_cfg["engine"]["name"],
            "rewards": {"controller": round(look.mean_reward, 5)}, "diverged": {"controller": bool(look.diverged)},
            "stages": stages}


def score_clip(cfg: dict[str, Any], motion: Path, data_root: Path, models, agent_state: dict,
               hand_cfg: dict[str, Any] | None = None) -> dict[str, Any]:
    """One clip: its stages performed once from the start, scored against the person and read back;
    with ``hand_cfg`` (``signing.hand``) its hand motion too, on the hand body (:func:`score_hand_clip`)."""
    from aslexp.rl.evaluate import evaluate
    from aslexp.signing.performance import signing_metrics
    from aslexp.signing.reading import gloss_of_source, read_back_stages

    started = time.perf_counter()
    env, steps = performing_env(cfg, motion, data_root)
    try:
        look = evaluate(env, lambda obs, env: env.reference_action(1), steps, record=True)
        runs, rewards = {"controller": look}, {"controller": round(look.mean_reward, 5)}
        if agent_state.get("checkpoint"):
            if "agent" not in agent_state:
                agent_state["agent"] = _agent(cfg, env, agent_state["checkpoint"])
            runs["policy"] = evaluate(env, lambda obs, env: agent_state["agent"].act(obs), steps, record=True)
            rewards["policy"] = round(runs["policy"].mean_reward, 5)
        final = "policy" if "policy" in runs else "controller"
        keypoints: dict = {}
        signing = signing_metrics(env, runs[final].trajectory, None, stage=final, write_pose=False, keypoints=keypoints,
                                  others={n: r.trajectory for n, r in runs.items() if n != final})
        hand = None
        if hand_cfg is not None and signing is not None:
            hand = (score_hand_clip(hand_cfg, hand_file(motion), env, data_root) if hand_file(motion).is_file() else
                    {"file": str(hand_file(motion)), "stages": None,
                     "why": "extraction wrote no hand motion for this clip (its report's hand.status says why)"})
    finally:
        env.close()
    record: dict[str, Any] = {"motion": motion.stem, "file": str(motion), "rewards": rewards,
                              "diverged": {n: bool(r.diverged) for n, r in runs.items()}}
    if signing is None:
        return {**record, "stages": None, "why": "no source keypoints (the log says why)"}
    report = json.loads(Path(signing["motion_report"]).read_text())
    gloss = gloss_of_source(report, signing["source"], data_root)
    plausibility = (report.get("upper_body") or {}).get("plausibility") or {}
    record.update(gloss=gloss, source=signing["source"], stages=signing["stages"],
                  retargeting_error=signing["retargeting_error"], plausible=bool(plausibility.get("plausible", True)),
                  **({"hand": hand} if hand is not None else {}))
    if models is not None and gloss is not None:
        try:
            record["read_back"] = read_back_stages(models, keypoints, signing["source"], gloss)
        except DataError as error:  # a gloss without a lexicon entry: its keypoint scores stand
            record["read_back"] = None
            record["read_back_why"] = str(error)
    record["seconds"] = round(time.perf_counter() - started, 3)
    return record


def _reused(resume: str | None, wanted: set[str]) -> dict[str, dict]:
    """``resume=RUN_DIR``: an earlier signing run's clip records (those of this run's motions)."""
    if not resume:
        return {}
    path = Path(resume) / CLIPS_FILE
    if not path.is_file():
        raise ConfigError(f"resume={resume}: no {path}; expected a folder of `aslexp signing`")
    out = {}
    for number, line in enumerate(path.read_text().splitlines(), 1):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            log.warning("%s:%d: not a JSON line (an interrupted write?): that clip is scored again", path, number)
            continue
        if record.get("motion") in wanted:
            out[record["motion"]] = record
    return out


def signing_table(cfg: dict[str, Any], out_dir: Path) -> dict[str, Any]:
    """The job without Hydra: every motion scored (reusing ``resume``'s), the table and its figure."""
    from aslexp.data.root import resolve_data_root
    from aslexp.files import write_json, write_text
    from aslexp.signing import table as T

    settings = cfg["signing"]
    performing, performer, checkpoint = policy_of(cfg)
    glosses = held_out_glosses(performer) if settings.get("held_out_only", True) else None
    data_root = resolve_data_root(cfg.get("data_root"))
    files, left_out = motion_files(settings["motions"], settings.get("limit"), settings.get("implausible", "skip"),
                                   glosses, data_root)
    if glosses is not None:
        log.info("signing: the policy's held-out glosses only (%d; signing.held_out_only=false: every clip)",
                 len(glosses))
    hand_cfg = None
    if (settings.get("hand") or {}).get("enabled"):
        from aslexp.compose import compose

        hand_cfg = compose("imitate", list(settings["hand"].get("overrides") or []))
    models = None
    if settings["read_back"]["enabled"]:
        from aslexp.signing.reading import models_for

        models = models_for(tuple(settings["read_back"]["overrides"]))
    done = _reused(cfg.get("resume"), {p.stem for p in files})
    agent_state = {"checkpoint": checkpoint}
    records, started, scored = [], time.perf_counter(), 0
    to_score = sum(p.stem not in done for p in files)
    with open(out_dir / CLIPS_FILE, "a", encoding="utf-8") as sink:
        for i, motion in enumerate(files):
            record = done.get(motion.stem)
            if record is None:
                record = score_clip(performing, motion, data_root, models, agent_state, hand_cfg)
                scored += 1
            else:
                record = {**record, "reused_from": str(cfg["resume"])}
            sink.write(json.dumps(record) + "\n")
            sink.flush()
            records.append(record)
            if scored and (scored % 10 == 0 or scored == to_score) and record.get("reused_from") is None:
                rate = scored / (time.perf_counter() - started)
                log.info("signing: %d/%d clips (%d scored here: %.2f clips/s, ETA %.0f s)", i + 1, len(files), scored,
                         rate, (to_score - scored) / rate)
    properties = list(models.properties) if models is not None else []
    recall_at = list(models.setup.settings.recall_at) if models is not None else [10, 50]
    table = T.build_table(records, properties, recall_at)
    unscored = [{"motion": r["motion"], "why": r.get("why")} for r in records if not r.get("stages")]
    kept = [r["motion"] for r in records if r.get("stages") and not r.get("plausible", True)]
    out = {"motions": str(settings["motions"]), "clips": len(records), "left_out": left_out,
           "implausible_kept": kept, "unscored": unscored,
           "policy": performer, "read_back": None if models is None else {
               "cache": models.cache, "fit_time_s": round(models.fit_time_s, 1), "folds": len(models.folds)},
           "seconds": round(time.perf_counter() - started, 1), "table": table}
    lines = T.table_lines(table, properties, recall_at) if table["clips"] else ["no clip was scored"]
    if 0 < table["clips"] <= T.CLIP_ROWS:
        lines += ["", *T.clip_lines(records)]
    out.update(table_lines=lines, verdict_lines=T.verdict_lines(table))
    write_json(out_dir / TABLE_JSON, out)
    write_text(out_dir / TABLE_MD, "\n".join([f"# The signer against the person: {table['clips']} clips of "
                                              f"{table['glosses']} glosses", "", *lines, "", *out["verdict_lines"]]) + "\n")
    if cfg.get("plots", True) and table["clips"]:
        from aslexp.viz.signing import plot_signing_table

        scored = [r for r in records if r.get("stages")]
        plot_signing_table({s: T.keypoint_errors(scored, s) for s in table["stages"]},
                           {n: T.lexicon_ranks(scored, n) for n in table["read_back"]}, table, properties,
                           out_dir / FIGURE, T.clip_handshapes(scored) if len(scored) <= T.CLIP_ROWS else None)
    for line in out["verdict_lines"]:
        log.info("signing: %s", line[2:])
    return out


@job_main("signing")
def main(cfg: DictConfig) -> None:
    """Hydra entry point: a measurement, nothing to rank (no objective)."""
    def body(run) -> None:
        seed_everything(int(cfg.seed))
        result = signing_table(to_dict(cfg), run.dir)
        run.save_metrics({"clips": result["clips"], "left_out": len(result["left_out"]),
                          "implausible_kept": len(result["implausible_kept"]),
                          "unscored": len(result["unscored"]), "table": result["table"],
                          "table_lines": result["table_lines"], "verdict_lines": result["verdict_lines"]})
        return None

    return run_guarded("signing", cfg, body)


if __name__ == "__main__":
    main()
