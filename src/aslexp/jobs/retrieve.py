"""`aslexp retrieve`: rank the whole ASL-LEX lexicon for clips of glosses never seen in training.

Data flow: lexicon (properties, SignFrequency(Z)) + WLASL-Lex builds of each property (the same
clips and keypoints) -> one gloss split over the clips, K times -> a classifier per property on the
training glosses -> per test clip, every lexicon entry scored by its predicted phonology, the
frequency prior, both, and the oracle -> recall@k, MRR, median rank over splits (with how often the
splits reuse test glosses, and recall by the frequency band of the true sign) -> run directory
(metrics.json, retrieval.md, ranks.csv, recall_at_k.png; with ``retrieval.save_model`` the lookup
model of ``aslexp lookup`` in model/). Definitions: docs/recognition.md,
"Lexicon retrieval for unseen glosses". Returns the validation recall@50 of phonology + prior
(mean over splits; the number a sweep maximises: test numbers never choose).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

import numpy as np
from omegaconf import DictConfig

from aslexp.errors import ConfigError
from aslexp.jobs._common import job_main, run_guarded, seed_everything, to_dict

log = logging.getLogger("aslexp.retrieve")


def check_retrieval(cfg: dict[str, Any]) -> dict[str, Any]:
    """The ``retrieval`` section checked (one line naming the key on a bad value); returns it."""
    from aslexp.data.lexicon import PROPERTIES
    from aslexp.recognition.retrieval import LIKELIHOODS, SELECT_BY

    section = dict(cfg.get("retrieval") or {})
    known = {"properties", "likelihood", "smoothing", "prior_weights", "select_by", "recall_at", "save_model"}
    unknown = sorted(set(section) - known)
    if unknown:
        raise ConfigError(f"retrieval: unknown key(s) {unknown}; accepted: {sorted(known)}")
    properties = section.get("properties")
    if not isinstance(properties, list) or not properties:
        raise ConfigError(f"retrieval.properties={properties!r}: expected a non-empty list of {list(PROPERTIES)}")
    bad = [p for p in properties if p not in PROPERTIES]
    if bad:
        raise ConfigError(f"retrieval.properties: unknown property {bad[0]!r}; expected some of {list(PROPERTIES)}")
    if len(set(properties)) != len(properties):
        raise ConfigError(f"retrieval.properties={properties}: a property is given twice")
    for key, low, high in (("smoothing", 0.0, 1.0), ("prior_weights", 0.0, None)):
        values = section.get(key)
        ok = isinstance(values, list) and values and all(
            isinstance(v, (int, float)) and not isinstance(v, bool) and v >= low and (high is None or v <= high)
            and not (key == "smoothing" and v == 0) for v in values)
        if not ok:
            span = "in (0, 1]" if key == "smoothing" else ">= 0"
            raise ConfigError(f"retrieval.{key}={values!r}: expected a non-empty list of numbers {span}")
    if section.get("likelihood") not in LIKELIHOODS:
        raise ConfigError(f"retrieval.likelihood={section.get('likelihood')!r}: expected one of {list(LIKELIHOODS)}")
    if section.get("select_by") not in SELECT_BY:
        raise ConfigError(f"retrieval.select_by={section.get('select_by')!r}: expected one of {sorted(SELECT_BY)}")
    recall_at = section.get("recall_at")
    if not isinstance(recall_at, list) or not recall_at or not all(isinstance(k, int) and k >= 1 for k in recall_at):
        raise ConfigError(f"retrieval.recall_at={recall_at!r}: expected a non-empty list of integers >= 1")
    if 50 not in recall_at:
        raise ConfigError(f"retrieval.recall_at={recall_at}: must include 50 (the job's objective is recall@50)")
    save = section.get("save_model", False)
    if save is True:
        section["save_model"] = "all"
    elif save not in (False, None, "all", "first_split"):
        raise ConfigError(f"retrieval.save_model={save!r}: expected false, all (true) or first_split")
    if cfg["split"]["name"] != "gloss":
        raise ConfigError(f"split={cfg['split']['name']}: retrieval is of glosses never seen in training; use split=gloss")
    return section


def retrieval_clips(cfg: dict[str, Any], properties: list[str], table, cache_dir: Path):
    """The clips of every property's WLASL-Lex build (the same keypoints; a clip whose value is
    missing for one property is still in another's build), each with its lexicon entry's row."""
    from aslexp.data.wlasl_lex import build_or_load, params_from_config
    from aslexp.recognition.retrieval_run import RetrievalClips

    clips: dict[str, tuple] = {}
    layout = None
    for prop in properties:
        # the build's own split is not used (retrieval splits the glosses itself); train_only keeps every clip
        build_cfg = {**cfg, "property": {"name": prop},
                     "split": {**cfg["split"], "name": "gloss", "seed": 0, "rare_classes": "train_only"}}
        dataset, folder = build_or_load(cache_dir, params_from_config(build_cfg), root=cfg["data"]["root"])
        entries = [c["entry_id"] for c in json.loads((folder / "clips.json").read_text(encoding="utf-8"))]
        if len(entries) != len(dataset.video_ids):
            raise ValueError(f"{folder}: clips.json has {len(entries)} clips, the build {len(dataset.video_ids)}")
        layout = layout or dataset.layout
        for i, video_id in enumerate(dataset.video_ids):
            if video_id not in clips:
                clips[video_id] = (dataset.X[i], dataset.mask[i], dataset.glosses[i], entries[i])
    order = sorted(clips)
    return RetrievalClips(
        X=np.stack([clips[v][0] for v in order]), mask=np.stack([clips[v][1] for v in order]),
        video_ids=order, glosses=[clips[v][2] for v in order],
        entry_rows=np.array([table.index(clips[v][3]) for v in order], dtype=np.int64), layout=layout,
    )


def retrieve(cfg: DictConfig, run) -> float:
    from aslexp.data.lexicon import load_lexicon
    from aslexp.recognition.retrieval import lexicon_table
    from aslexp.recognition.retrieval_run import interval_text, run_retrieval, table_lines, write_outputs

    plain = to_dict(cfg)
    section = check_retrieval(plain)
    seed_everything(int(cfg.seed))
    lexicon = load_lexicon(plain["data"]["lexicon"], plain["data"]["root"],
                           movement_none_as_missing=bool(plain["data"].get("movement_none_as_missing", False)))
    properties = list(section["properties"])
    table = lexicon_table(lexicon.entries, properties, {p: lexicon.vocabulary(p) for p in properties})
    clips = retrieval_clips(plain, properties, table, Path(plain["cache_dir"]))
    result = run_retrieval(
        clips, table, plain["classifier"], plain["trainer"], plain["split"], seed=int(cfg.seed),
        smoothing=section["smoothing"], prior_weights=section["prior_weights"], select_by=section["select_by"],
        recall_at=section["recall_at"], likelihood=section["likelihood"],
    )
    files = write_outputs(result, run.dir)
    if section.get("save_model"):
        files["model"] = save_model(plain, section["save_model"], clips, table, result, lexicon, run.dir)
    result["files"] = files
    result["context"] = {"lexicon": plain["data"]["lexicon"], "pose": plain["pose"]["name"],
                         "classifier": plain["classifier"]["name"], "properties": properties,
                         "split": plain["split"]["name"], "cache_dir": plain["cache_dir"]}
    # the objective is a validation number (a sweep must never choose by test): recall@50 of phonology
    # + prior on the validation glosses at the chosen smoothing and weight, mean over splits
    value = float(np.mean([s["validation"]["phonology+prior"]["metrics"]["recall@50"] for s in result["per_split"]]))
    result["objective"] = {"name": "val_recall@50_phonology+prior", "value": value}
    run.save_metrics(result)
    run.set_main_metric("val_recall@50_phonology+prior", value, "maximize")
    for line in table_lines(result):
        log.info("%s", line)
    log.info("%s", interval_text(len(result["per_split"]), result["split_overlap"]))
    return value


def save_model(plain: dict[str, Any], fit_on: str, clips, table, result, lexicon, run_dir: Path) -> str:
    """``retrieval.save_model``: the lookup model in ``<run>/model/`` (:mod:`aslexp.recognition.lookup`),
    with the keypoint route of the WLASL-Lex builds (the same for every property)."""
    from aslexp.data.root import resolve_data_root
    from aslexp.data.wlasl_lex import params_from_config
    from aslexp.recognition.lookup import MODEL_DIR, preprocessing_of, save_lookup_model

    build = params_from_config({**plain, "property": {"name": result["properties"][0]}}).to_dict()
    root = resolve_data_root(plain["data"]["root"])
    save_lookup_model(run_dir / MODEL_DIR, clips, table, result, plain["classifier"], plain["trainer"],
                      plain["split"], seed=int(plain["seed"]), fit_on=fit_on,
                      preprocessing=preprocessing_of(build, root), lexicon_path=lexicon.path, data_root=root)
    return MODEL_DIR


@job_main("retrieve")
def main(cfg: DictConfig) -> float:
    return run_guarded("retrieve", cfg, lambda run: retrieve(cfg, run))


if __name__ == "__main__":
    main()
