"""`aslexp glosses`: seen-gloss classification with and without auxiliary phonology heads.

Data flow: the clips of every property's WLASL-Lex build aligned by video id (as ``aslexp retrieve``
aligns them) with each clip's gloss and ASL-LEX property values -> K splits stratified by gloss ->
per split the multi-task encoder with a gloss head alone and with the property heads as auxiliary
tasks (same seed, same clips, the epoch chosen by the gloss head), beside chance, the majority
baseline and a simple feature baseline -> top-k over splits, paired -> run directory (metrics.json,
glosses.md, predictions.csv, top_k_by_split.png). Definitions: docs/recognition.md, "Phonology as
help for seen signs". Returns the mean validation MCC of the gloss head with the auxiliary heads
(the number a sweep of ``glosses.aux_weight`` maximises; test numbers never choose).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from omegaconf import DictConfig

from aslexp.errors import ConfigError
from aslexp.jobs._common import job_main, run_guarded, seed_everything, to_dict

log = logging.getLogger("aslexp.glosses")


def glosses(cfg: DictConfig, run) -> float:
    from aslexp.compose import deep_merge, group
    from aslexp.data.lexicon import load_lexicon
    from aslexp.data.splits import SplitOptions
    from aslexp.jobs.retrieve import retrieval_clips
    from aslexp.recognition.retrieval import lexicon_table
    from aslexp.recognition.seen_glosses import WITH, SeenGlossOptions, run_seen_glosses, table_lines, write_outputs

    plain = to_dict(cfg)
    options = SeenGlossOptions.parse(plain.get("glosses"))
    if plain["classifier"]["name"] != "multitask":
        raise ConfigError(f"classifier={plain['classifier']['name']}: the gloss networks are the multi-task encoder's "
                          "(heads for the gloss and the properties); use classifier=multitask")
    split = SplitOptions.parse(plain["split"])
    if split.name != "phoneme":
        raise ConfigError(f"split={split.name}: seen glosses are split by clip, stratified by gloss; use split=phoneme")
    simple = None
    if options.simple_baseline:
        chosen = group("classifier", options.simple_baseline, job="glosses")
        simple = {"name": chosen["name"], "params": deep_merge(chosen.get("params") or {}, options.simple_baseline_params)}
        if chosen.get("module"):
            simple["module"] = chosen["module"]
    seed_everything(int(cfg.seed))
    lexicon = load_lexicon(plain["data"]["lexicon"], plain["data"]["root"],
                           movement_none_as_missing=bool(plain["data"].get("movement_none_as_missing", False)))
    # the clips of the auxiliary properties' builds (each clip with its value for every one of them)
    properties = list(options.auxiliary)
    table = lexicon_table(lexicon.entries, properties, {p: lexicon.vocabulary(p) for p in properties})
    clips = retrieval_clips(plain, properties, table, Path(plain["cache_dir"]))
    result = run_seen_glosses(clips, table.codes[clips.entry_rows], options, plain["classifier"].get("params") or {},
                              split, simple=simple, seed=int(cfg.seed), property_names=properties)
    result["files"] = write_outputs(result, run.dir)
    result["context"] = {"lexicon": plain["data"]["lexicon"], "pose": plain["pose"]["name"],
                         "classifier": plain["classifier"]["name"], "cache_dir": plain["cache_dir"]}
    value = float(np.mean([s["epochs"][WITH]["val_mcc"] for s in result["per_split"]]))
    result["objective"] = {"name": "val_mcc_gloss_with_auxiliary", "value": value}
    predictions = result.pop("predictions")  # in predictions.csv
    result["num_predictions"] = len(predictions)
    run.save_metrics(result)
    run.set_main_metric("val_mcc_gloss_with_auxiliary", value, "maximize")
    for line in table_lines(result):
        log.info("%s", line)
    return value


@job_main("glosses")
def main(cfg: DictConfig) -> float:
    return run_guarded("glosses", cfg, lambda run: glosses(cfg, run))


if __name__ == "__main__":
    main()
