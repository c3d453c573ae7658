"""`aslexp recognize`: recognise one phonological property from skeleton keypoints.

Data flow: lexicon + WLASL -> WLASL-Lex table -> keypoints (pose source) -> fixed-length,
normalised arrays -> split -> classifier -> metrics -> run directory. Returns the validation MCC
(mean over seeds), the number an Optuna sweep maximises. Ends by printing the test metrics beside
the strongest simple baseline (``simple_baseline``, run on the same splits) and the chance baseline.
"""

from __future__ import annotations

import copy
import logging
from pathlib import Path

from omegaconf import DictConfig, OmegaConf, open_dict

from aslexp.data.wlasl_lex import WlaslLexParams, build_or_load, params_from_config
from aslexp.jobs._common import job_main, run_guarded, seed_everything, to_dict
from aslexp.jobs.validation import check_config
from aslexp.recognition.experiment import run_recognition, simple_baseline_params
from aslexp.recognition.report import comparison_text
from aslexp.runs.loggers import epoch_tag, make_logger
from aslexp.tuning.context import trial_reporter

log = logging.getLogger("aslexp.recognize")


def dataset_params(cfg: DictConfig) -> WlaslLexParams:
    """The WLASL-Lex build parameters of a composed config (:func:`aslexp.data.wlasl_lex.params_from_config`)."""
    return params_from_config(to_dict(cfg))


def recognize(cfg: DictConfig, run) -> float:
    check_config("recognize", cfg)  # swept values (the rest: ConfigCheck); a bad one fails this run
    simple_baseline_params(simple_baseline(cfg), simple_overrides(cfg))  # a bad name stops here, before the build
    seed_everything(int(cfg.seed))
    dataset, dataset_dir = build_or_load(Path(cfg.cache_dir), dataset_params(cfg), root=cfg.data.root)
    log.info(
        "dataset %s/%s/%s: %d clips, %d classes, shape %s, splits %s",
        cfg.property.name, cfg.pose.name, cfg.split.name, len(dataset.y), dataset.num_classes,
        tuple(dataset.X.shape),
        {k: len(v) for k, v in dataset.splits.items() if k != "folds"},
    )
    metric_logger = make_logger(to_dict(cfg.logger), run.dir, to_dict(cfg))
    reporter = trial_reporter(cfg)
    max_epochs = int(cfg.trainer.get("max_epochs") or 0)

    def on_epoch_record(epoch: int, record: dict) -> None:
        metric_logger.log({epoch_tag(k): v for k, v in record.items() if k != "epoch"}, step=epoch)

    def on_epoch_end(epoch: int, val_score: float) -> None:
        # The last epoch's report is final: a pruner never discards a finished fit.
        reporter.report(val_score, epoch, final=epoch >= max_epochs)

    seeds = [int(cfg.seed) + i for i in range(int(cfg.n_seeds))]
    summary: dict = {}  # the logger's run summary (and TensorBoard hparams metrics)
    try:
        result = run_recognition(
            dataset,
            classifier=to_dict(cfg.classifier),
            trainer=to_dict(cfg.trainer),
            seeds=seeds,
            out_dir=run.dir,
            on_epoch_end=on_epoch_end,
            on_epoch_record=on_epoch_record,
            split=to_dict(cfg.split),
            simple_baseline=simple_baseline(cfg),
            simple_baseline_overrides=simple_overrides(cfg),
            simple_baseline_cache=cfg.get("simple_baseline_cache") or None,
        )
        summary = {"val_mcc": result["val_mcc"], **{f"test_{k}": v for k, v in result.get("test", {}).items()}}
    finally:
        metric_logger.close(summary)
    result["context"] = {
        "property": cfg.property.name,
        "split": cfg.split.name,
        "pose": cfg.pose.name,
        "lexicon": cfg.data.lexicon,
        "classifier": cfg.classifier.name,
        "seeds": seeds,
        "num_clips": int(len(dataset.y)),
        "num_classes": int(dataset.num_classes),
        "skipped": dataset.skipped,
        "dataset_dir": str(dataset_dir),
    }
    run.save_metrics(result)
    run.info["device"] = result["device"]  # where it trained (GPU name), beside the versions
    objective = result["objective"]
    run.set_main_metric(objective["name"], float(objective["value"]), "maximize")
    test = result.get("test", {})
    log.info(
        "%s on %s (%s split): %s %.3f | test MCC %s, balanced acc %s",
        cfg.classifier.name, cfg.property.name, cfg.split.name, objective["name"], objective["value"],
        test.get("mcc"), test.get("balanced_accuracy"),
    )
    caution = seed_cannot_change(cfg, bool(result.get("seed_changes_result", True)))
    if caution:
        log.warning("%s", caution)
    comparison = result.get("comparison")
    if comparison:
        log.info("%s vs the baselines on the same split(s):\n%s", cfg.classifier.name,
                 comparison_text(comparison, cfg.property.name, cfg.split.name))  # fmt: skip
    return float(objective["value"])


def seed_cannot_change(cfg: DictConfig, seed_changes_result: bool) -> str | None:
    """The warning for a run whose ``seed`` was chosen (on the command line or by a sweep, as in
    ``-m seed=0,1``) although it cannot change the result: the model draws no random number
    (``seed_changes_result`` false) and the data and split do not follow ``seed`` (the split has
    its own ``split.seed``; a config that sets ``split.seed: ${seed}`` is not such a case)."""
    if seed_changes_result or not _seed_chosen():
        return None
    probe = copy.deepcopy(cfg)
    with open_dict(probe):
        probe.seed = int(cfg.seed) + 1
    groups = ("data", "pose", "property", "split")
    if any(to_dict(probe[group]) != to_dict(cfg[group]) for group in groups if group in cfg):
        return None  # another seed is another split
    name = cfg.classifier.name
    return (f"seed={cfg.seed} cannot change {name}'s result: {name} draws no random number with these settings "
            f"and split.seed={cfg.split.seed} fixes the split, so seed=0,1,... give identical runs of {name}; vary "
            "split.seed or split.repeats instead (a seeded model, such as rf or stgcn, does use seed)")


def _seed_chosen() -> bool:
    """``seed`` is among this job's overrides (the command line's, or the sweep's for this trial)."""
    from hydra.core.hydra_config import HydraConfig

    if not HydraConfig.initialized():
        return False
    return any(str(o).split("=", 1)[0].lstrip("+~") == "seed" for o in HydraConfig.get().overrides.task)


def simple_baseline(cfg: DictConfig) -> str | list[str] | None:
    """``simple_baseline``: a classifier name, a list of names (the best by validation is the
    reference) or null (none); a config without the key (an older run's) has none."""
    value = OmegaConf.select(cfg, "simple_baseline", default=None)
    if value is None or isinstance(value, str):
        return value
    return [str(name) for name in value]


def simple_overrides(cfg: DictConfig) -> dict[str, dict]:
    """``simple_baseline_params``: per simple baseline, params over its conf/classifier defaults."""
    value = OmegaConf.select(cfg, "simple_baseline_params", default=None)
    return to_dict(value) if value else {}


@job_main("recognize")
def main(cfg: DictConfig) -> float:
    return run_guarded("recognize", cfg, lambda run: recognize(cfg, run))


if __name__ == "__main__":
    main()
