"""Read a performed sign back: the recognition wing's models on a clip's keypoints, from any source
in the keypoint source's layout (the real clips, or a simulated signer's keypoints), scored against
the ASL-LEX entry of the clip's gloss (docs/recognition.md, "Reading a performed sign back").

    python -m aslexp.recognition.read_back [OVERRIDES of conf/read_back.yaml] [--out DIR]

* **Gloss folds** (:func:`gloss_folds`): the glosses of the clips with a lexicon entry are shuffled
  (``fold_seed``) and dealt into K disjoint folds. Fold k's models are fitted on the clips of the
  other K - 1 folds only, so the models that read a clip of fold k never saw its gloss.
* **Two models per fold** (:func:`fit_fold_models`), each configured by its job's config
  (``conf/read_back.yaml``: ``phonology`` and ``lookup`` name the job and its overrides):

  - the property classifiers (``aslexp recognize``'s model: logistic regression on pooled summary
    features by default), one per property, predict each property's value;
  - the lookup model (``aslexp retrieve``'s: its classifier per property, its likelihood, smoothing
    and prior grids) ranks every lexicon entry as ``aslexp lookup`` does. Its smoothing and prior
    weight are chosen on an inner validation fold (the next fold, k + 1 mod K: fitted on the other
    K - 2), then every classifier is fitted again on all K - 1 training folds.
* **The cache** (``model_cache``): one checkpoint per fold, property and classifier, with a JSON
  beside it holding its key: the fold, the property, the classifier, trainer, seed and epoch budget,
  and the training data's identity (SHA-256 of the training clips' arrays, masks, lexicon values and
  ids). A model whose JSON names other training data is stale: refused, refitted and replaced.
* **A read-back** (:func:`read_back`, :func:`read_back_many`): keypoints (an array or a ``.npy``) go
  through the dataset builder's own route (the keypoint source's reader -> subset -> channels ->
  :func:`aslexp.data.preprocess.preprocess_clips`); the fold that held the gloss out reads them (a
  gloss of no fold: fold 0, which never saw it either; the result says which and why).
* **The table** (:func:`score_clips`, :func:`table_of`): per property the agreement rate with ASL-LEX,
  the lookup's median rank and recall@k, each with a percentile bootstrap interval over glosses.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import math
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.compose import compose
from aslexp.config_schema import Float, Int, List, Section, Text, key
from aslexp.errors import ConfigError, DataError
from aslexp.recognition import retrieval as R
from aslexp.recognition.retrieval_run import RetrievalClips

log = logging.getLogger(__name__)

MODEL_FORMAT = "aslexp-read-back-model"
MODEL_VERSION = 1
CONFIG = "read_back"
METHODS = ("phonology+prior", "phonology", "prior")  # the lookup model's score, its phonology alone, no reading
TABLE_FILE = "read_back.md"
RESULT_FILE = "read_back.json"


# --------------------------------------------------------------------------- settings


@dataclass(frozen=True)
class JobModel(Section):
    """A model configured by a job's config: the job (conf/<job>.yaml) and overrides of it."""

    SECTION = "read_back.phonology"

    job: str = field(default="recognize", metadata=key(Text()))
    overrides: tuple[str, ...] = ()


@dataclass(frozen=True)
class IntervalSettings(Section):
    """The table's percentile bootstrap over glosses."""

    SECTION = "read_back.interval"

    resamples: int = field(default=2000, metadata=key(Int(100)))
    confidence: float = field(default=0.95, metadata=key(Float(0.0, 1.0, low_open=True, high_open=True)))
    seed: int = field(default=0, metadata=key(Int(0)))


@dataclass(frozen=True)
class ReadBackSettings(Section):
    """``conf/read_back.yaml``."""

    SECTION = "read_back"

    folds: int = field(default=5, metadata=key(Int(3)))
    fold_seed: int = field(default=0, metadata=key(Int(0)))
    overrides: tuple[str, ...] = ()
    phonology: JobModel = JobModel("recognize")
    lookup: JobModel = JobModel("retrieve")
    glosses: tuple[str, ...] | None = None
    model_cache: str = field(default="outputs/read_back_models", metadata=key(Text()))
    interval: IntervalSettings = IntervalSettings()
    recall_at: tuple[int, ...] = field(default=(10, 50), metadata=key(List(Int(1), nonempty=True)))


@dataclass(frozen=True)
class ModelSpec:
    """One role's classifier as its job configures it: registered name, resolved params, trainer, seed."""

    name: str
    params: dict[str, Any]
    module: str | None
    trainer: dict[str, Any]
    seed: int

    def identity(self) -> dict[str, Any]:
        return {"name": self.name, "params": self.params, "module": self.module, "trainer": self.trainer,
                "seed": self.seed}

    def digest(self) -> str:
        return _digest_of(self.identity())[:10]


@dataclass(frozen=True)
class ReadBackSetup:
    """Everything the folds' models depend on, read from the composed configs."""

    settings: ReadBackSettings
    phonology: ModelSpec
    lookup: ModelSpec
    selection: dict[str, Any]  # the lookup's likelihood, smoothing and prior grids, select_by
    properties: tuple[str, ...]
    keypoints: dict[str, Any]  # data, pose and split groups, as the dataset builder reads them
    cache_dir: str  # built WLASL-Lex datasets (the jobs' cache_dir)


def _digest_of(payload: Any) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode("utf-8")).hexdigest()


def _model_spec(cfg: Mapping[str, Any], job: str) -> ModelSpec:
    from aslexp.recognition.models import resolve_params
    from aslexp.recognition.train import TrainerConfig

    classifier = cfg.get("classifier") or {}
    if "name" not in classifier:
        raise ConfigError(f"conf/{job}.yaml: classifier has no 'name'; expected a conf/classifier group")
    try:
        params = resolve_params(str(classifier["name"]), classifier.get("params"), classifier.get("module"))
    except (ValueError, KeyError) as error:
        raise ConfigError(f"conf/{job}.yaml: classifier: {error}") from None
    trainer = TrainerConfig.parse(cfg.get("trainer"), f"{job}.trainer").to_dict()
    return ModelSpec(str(classifier["name"]), params, classifier.get("module"), trainer, int(cfg.get("seed", 0)))


def setup_from_config(values: Mapping[str, Any]) -> ReadBackSetup:
    """The setup from a composed ``conf/read_back.yaml`` (plain values): both jobs' configs composed
    with their overrides; a ConfigError names the key when they read other keypoints."""
    settings = ReadBackSettings.parse(values)
    phonology = compose(settings.phonology.job, [*settings.overrides, *settings.phonology.overrides])
    lookup = compose(settings.lookup.job, [*settings.overrides, *settings.lookup.overrides])
    for group in ("data", "pose"):
        if phonology.get(group) != lookup.get(group):
            raise ConfigError(f"read_back: {group} of conf/{settings.phonology.job}.yaml ({phonology.get(group)}) differs "
                              f"from conf/{settings.lookup.job}.yaml's ({lookup.get(group)}); expected the same "
                              "keypoints for both models (set them with read_back's overrides)")
    retrieval = dict(lookup.get("retrieval") or {})
    missing = [k for k in ("properties", "likelihood", "smoothing", "prior_weights", "select_by") if k not in retrieval]
    if missing:
        raise ConfigError(f"read_back.lookup: conf/{settings.lookup.job}.yaml has no retrieval.{missing[0]}; expected "
                          "a job configured like conf/retrieve.yaml")
    from aslexp.data.lexicon import PROPERTIES

    properties = tuple(retrieval["properties"])
    bad = [p for p in properties if p not in PROPERTIES]
    if bad or not properties:
        raise ConfigError(f"retrieval.properties={list(properties)}: expected some of {list(PROPERTIES)}")
    if retrieval["likelihood"] not in R.LIKELIHOODS:
        raise ConfigError(f"retrieval.likelihood={retrieval['likelihood']!r}: expected one of {list(R.LIKELIHOODS)}")
    if retrieval["select_by"] not in R.SELECT_BY:
        raise ConfigError(f"retrieval.select_by={retrieval['select_by']!r}: expected one of {sorted(R.SELECT_BY)}")
    selection = {"likelihood": retrieval["likelihood"], "smoothing": [float(v) for v in retrieval["smoothing"]],
                 "prior_weights": [float(v) for v in retrieval["prior_weights"]], "select_by": retrieval["select_by"]}
    keypoints = {"data": lookup["data"], "pose": lookup["pose"], "split": lookup.get("split") or {"name": "gloss"}}
    return ReadBackSetup(settings=settings, phonology=_model_spec(phonology, settings.phonology.job),
                         lookup=_model_spec(lookup, settings.lookup.job), selection=selection, properties=properties,
                         keypoints=keypoints, cache_dir=str(lookup.get("cache_dir") or "outputs/cache"))


def load_setup(overrides: Sequence[str] = ()) -> ReadBackSetup:
    """``conf/read_back.yaml`` with Hydra ``overrides`` (``folds=3``, ``'lookup.overrides=["classifier=logreg"]'``)."""
    return setup_from_config(compose(CONFIG, list(overrides)))


# --------------------------------------------------------------------------- the clips and the folds


def _build_params(setup: ReadBackSetup, prop: str):
    from aslexp.data.wlasl_lex import params_from_config

    # the build's own split is not used (the folds split the glosses); train_only keeps every clip
    split = {**setup.keypoints["split"], "name": "gloss", "seed": 0, "rare_classes": "train_only"}
    return params_from_config({**setup.keypoints, "property": {"name": prop}, "split": split})


def training_clips(setup: ReadBackSetup):
    """The clips of every property's WLASL-Lex build (the same keypoints, built as ``aslexp retrieve``
    builds them; a clip without one property's value is still in another's build), restricted to
    ``glosses`` when the settings name some. Returns (RetrievalClips, LexiconTable, Lexicon)."""
    from aslexp.data.lexicon import load_lexicon
    from aslexp.data.wlasl_lex import build_or_load

    data = setup.keypoints["data"]
    lexicon = load_lexicon(data["lexicon"], data["root"],
                           movement_none_as_missing=bool(data.get("movement_none_as_missing", False)))
    table = R.lexicon_table(lexicon.entries, setup.properties, {p: lexicon.vocabulary(p) for p in setup.properties})
    clips: dict[str, tuple] = {}
    layout = None
    for prop in setup.properties:
        dataset, folder = build_or_load(setup.cache_dir, _build_params(setup, prop), root=data["root"])
        entries = [c["entry_id"] for c in json.loads((folder / "clips.json").read_text(encoding="utf-8"))]
        if len(entries) != len(dataset.video_ids):
            raise DataError(f"{folder}: clips.json has {len(entries)} clips, the build {len(dataset.video_ids)}")
        layout = layout or dataset.layout
        for i, video_id in enumerate(dataset.video_ids):
            clips.setdefault(video_id, (dataset.X[i], dataset.mask[i], dataset.glosses[i], entries[i]))
    wanted = setup.settings.glosses
    if wanted is not None:
        known = {v[2] for v in clips.values()}
        absent = [g for g in wanted if g not in known]
        if absent:
            raise ConfigError(f"read_back.glosses: {absent[0]!r} is no gloss of the clips; expected some of "
                              f"{sorted(known)}")
        clips = {v: c for v, c in clips.items() if c[2] in set(wanted)}
    order = sorted(clips)
    return RetrievalClips(
        X=np.stack([clips[v][0] for v in order]), mask=np.stack([clips[v][1] for v in order]), video_ids=order,
        glosses=[clips[v][2] for v in order],
        entry_rows=np.array([table.index(clips[v][3]) for v in order], dtype=np.int64), layout=layout,
    ), table, lexicon


def gloss_folds(glosses: Sequence[str], folds: int, seed: int) -> list[tuple[str, ...]]:
    """The distinct glosses shuffled with ``seed`` and dealt into ``folds`` disjoint folds (sizes
    differ by at most one gloss), each sorted."""
    unique = sorted(set(glosses))
    if folds < 2 or len(unique) < folds:
        raise ConfigError(f"read_back.folds={folds}: expected 2 .. {len(unique)} (the number of glosses)")
    order = np.random.default_rng(seed).permutation(len(unique))
    return [tuple(sorted(unique[i] for i in part)) for part in np.array_split(order, folds)]


def _identity(clips: RetrievalClips, table: R.LexiconTable, rows: np.ndarray) -> dict[str, Any]:
    """The training data's identity: its clips, arrays, masks and lexicon values."""
    hasher = hashlib.sha256()
    for array in (clips.X[rows], clips.mask[rows]):
        hasher.update(np.ascontiguousarray(array).tobytes())
    values = [[table.vocab[j][c] if c >= 0 else None for j, c in enumerate(table.codes[clips.entry_rows[r]])]
              for r in rows]
    hasher.update(json.dumps([[clips.video_ids[r] for r in rows], values, list(table.properties)]).encode())
    return {"clips": int(len(rows)), "glosses": len({clips.glosses[r] for r in rows}), "sha256": hasher.hexdigest()}


# --------------------------------------------------------------------------- one classifier


@dataclass
class Head:
    """One property's fitted classifier: the values it can predict and the model (or, with fewer
    than two values seen, constant probabilities over them)."""

    classes: tuple[str, ...]
    model: Any = None
    constant: np.ndarray | None = None

    def proba(self, X: np.ndarray, mask: np.ndarray, vocab: Sequence[str]) -> np.ndarray:
        """(n, |vocab|): the probabilities over the whole vocabulary (0 for values never seen)."""
        out = np.zeros((len(X), len(vocab)))
        if not self.classes:
            out[:] = 1.0 / len(vocab)
            return out
        columns = [list(vocab).index(c) for c in self.classes]
        out[:, columns] = self.constant[None, :] if self.model is None else self.model.predict_proba(X, mask)
        return out


def _fit(spec: ModelSpec, clips: RetrievalClips, codes: np.ndarray, vocab: Sequence[str], train: np.ndarray,
         val: np.ndarray | None, epochs: int | None) -> tuple[Head, int]:
    """Fit on the clips of ``train`` whose value is known: with ``epochs`` None early-stopped on the
    ``val`` clips of known classes (the training clips stand in when there are none), else for
    exactly ``epochs``. Returns the head and the validated epoch budget (1 for scikit-learn)."""
    from aslexp.recognition.models import build_classifier
    from aslexp.recognition.train import ArraySplit, TrainerConfig, fit, fit_final

    labelled = train[codes[train] >= 0]
    classes = np.unique(codes[labelled])
    names = tuple(vocab[c] for c in classes)
    if len(classes) < 2:  # nothing to learn: the one value seen (or none)
        return Head(names, None, np.ones(len(classes))), 1
    _, channels, frames, nodes, _ = clips.X.shape
    config = TrainerConfig.parse(spec.trainer)
    model = build_classifier(spec.name, dict(spec.params), channels, frames, nodes, len(classes), clips.layout,
                             module=spec.module)
    data = ArraySplit(clips.X[labelled], clips.mask[labelled], np.searchsorted(classes, codes[labelled]))
    if epochs is None:
        known = val[np.isin(codes[val], classes)] if val is not None else np.array([], dtype=np.int64)
        check = ArraySplit(clips.X[known], clips.mask[known], np.searchsorted(classes, codes[known])) if len(known) else data
        result = fit(model, data, check, config, seed=spec.seed)
        return Head(names, model), max(1, int(result.best_epoch))
    fit_final(model, data, ArraySplit(data.X[:1], data.mask[:1], data.y[:1]), config, epochs=max(1, int(epochs)),
              seed=spec.seed)
    return Head(names, model), int(epochs)


# --------------------------------------------------------------------------- the cache


class ModelCache:
    """Fitted heads and fold plans on disk: ``<folder>/<entry>.json`` holds the entry's key and names
    its checkpoint; an entry whose key differs (other training data) is stale, never read."""

    def __init__(self, folder: str | Path):
        self.folder = Path(folder)
        self.reused = 0
        self.fitted = 0
        self.refused: list[str] = []

    def _read(self, path: Path, key_fields: Mapping[str, Any]) -> dict[str, Any] | None:
        if not path.is_file():
            return None
        try:
            stored = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError) as error:
            self.refused.append(f"{path}: unreadable ({error})")
            log.warning("%s: unreadable model cache entry (%s); fitting again", path, error)
            return None
        if stored.get("format") != MODEL_FORMAT or stored.get("version") != MODEL_VERSION:
            why = f"format {stored.get('format')!r} version {stored.get('version')!r}"
        elif stored.get("key") != _digest_of(key_fields):
            old = stored.get("fields", {})
            changed = sorted(k for k in set(old) | set(key_fields) if old.get(k) != key_fields.get(k))
            why = f"stale: {', '.join(changed) or 'its key'} changed"
        else:
            return stored
        self.refused.append(f"{path}: {why}")
        log.warning("%s: %s; fitting again", path, why)
        return None

    def _write(self, path: Path, key_fields: Mapping[str, Any], content: Mapping[str, Any]) -> None:
        from aslexp.files import atomic_write_text

        payload = {"format": MODEL_FORMAT, "version": MODEL_VERSION, "key": _digest_of(key_fields),
                   "fields": dict(key_fields), **content}
        atomic_write_text(path, json.dumps(payload, indent=1, sort_keys=True, default=str) + "\n")

    def head(self, name: str, key_fields: Mapping[str, Any], fit_head) -> Head:
        """The head of entry ``name``: read from the cache when its key matches, else ``fit_head()``
        (a :class:`Head`), saved and returned."""
        from aslexp.files import atomic_path
        from aslexp.recognition.train import load_checkpoint, save_checkpoint

        path = self.folder / f"{name}.json"
        stored = self._read(path, key_fields)
        if stored is not None:
            try:
                if stored["checkpoint"] is None:
                    head = Head(tuple(stored["classes"]), None, np.asarray(stored["constant"], dtype=np.float64))
                else:
                    head = Head(tuple(stored["classes"]), load_checkpoint(path.parent / stored["checkpoint"])[0])
                self.reused += 1
                return head
            except (OSError, ValueError, KeyError, EOFError, RuntimeError) as error:
                self.refused.append(f"{path}: checkpoint unreadable ({type(error).__name__})")
                log.warning("%s: its checkpoint is unreadable (%s); fitting again", path, error)
        head = fit_head()
        self.fitted += 1
        checkpoint = None
        if head.model is not None:
            checkpoint = f"{Path(name).name}-{_digest_of(key_fields)[:12]}{head.model.checkpoint_suffix}"
            with atomic_path(path.parent / checkpoint) as tmp:
                save_checkpoint(head.model, tmp)
                if head.model.kind == "sklearn":  # compressed, as the lookup model's: a forest ~5x smaller
                    import joblib

                    joblib.dump(joblib.load(tmp), tmp, compress=3)
        old = stored_checkpoint(path)
        self._write(path, key_fields, {"classes": list(head.classes), "checkpoint": checkpoint,
                                       "constant": None if head.constant is None else head.constant.tolist()})
        if old and old != checkpoint:
            (path.parent / old).unlink(missing_ok=True)
        return head

    def plan(self, name: str, key_fields: Mapping[str, Any], make_plan) -> dict[str, Any]:
        """A fold's plan (epoch budgets, the lookup's chosen smoothing and weight): cached as a head is."""
        path = self.folder / f"{name}.json"
        stored = self._read(path, key_fields)
        if stored is not None:
            self.reused += 1
            return stored["plan"]
        plan = make_plan()
        self.fitted += 1
        self._write(path, key_fields, {"plan": plan})
        return plan


def stored_checkpoint(path: Path) -> str | None:
    """The checkpoint an entry's JSON names (None when there is no readable one)."""
    try:
        return json.loads(path.read_text(encoding="utf-8")).get("checkpoint")
    except (OSError, ValueError, AttributeError):
        return None


# --------------------------------------------------------------------------- the folds' models


@dataclass
class FoldModels:
    """Fold ``index``'s models: fitted on every gloss but ``test_glosses``."""

    index: int
    test_glosses: tuple[str, ...]
    training: dict[str, Any]  # the training data's identity
    phonology: dict[str, Head]
    lookup: dict[str, Head]
    smoothing_alone: float
    smoothing: float
    prior_weight: float
    value_priors: list[np.ndarray] | None
    majority: dict[str, str | None]  # the most frequent training value of each property
    plan: dict[str, Any]


@dataclass
class ReadBackModels:
    """Every fold's models and what reading a clip needs: the lexicon, its table, the keypoint route."""

    setup: ReadBackSetup
    table: R.LexiconTable
    lexicon: Any
    folds: list[FoldModels]
    entry_fold: dict[str, int]  # lexicon EntryID -> the fold that held out its gloss
    gloss_fold: dict[str, int]
    cache: dict[str, Any]
    fit_time_s: float  # wall-clock seconds of fitting or reading every fold's models
    fit_cpu_s: float  # CPU seconds of this process meanwhile (every thread: a loaded machine's fair figure)

    @property
    def properties(self) -> tuple[str, ...]:
        return self.setup.properties


def _lookup_plan(setup: ReadBackSetup, clips: RetrievalClips, table: R.LexiconTable, inner_train: np.ndarray,
                 inner_val: np.ndarray) -> dict[str, Any]:
    """Fit the lookup's classifiers on ``inner_train``, predict ``inner_val``, choose the smoothing
    and prior weight there (as ``aslexp retrieve`` chooses them on its validation glosses)."""
    codes_all = table.codes[clips.entry_rows]
    proba, epochs = [], {}
    for j, prop in enumerate(table.properties):
        head, budget = _fit(setup.lookup, clips, codes_all[:, j], table.vocab[j], inner_train, inner_val, None)
        proba.append(head.proba(clips.X[inner_val], clips.mask[inner_val], table.vocab[j]))
        epochs[prop] = budget
    priors = None
    if setup.selection["likelihood"] == "ratio":
        priors = [R.value_prior(codes_all[inner_train, j], len(v)) for j, v in enumerate(table.vocab)]
    chosen = R.choose(table, proba, clips.entry_rows[inner_val], setup.selection["smoothing"],
                      setup.selection["prior_weights"], setup.selection["select_by"], priors)
    return {"epochs": epochs, "smoothing_alone": float(chosen["phonology"]["smoothing"]),
            "smoothing": float(chosen["phonology+prior"]["smoothing"]),
            "prior_weight": float(chosen["phonology+prior"]["weight"]),
            "validation": {"clips": int(len(inner_val)), "phonology": chosen["phonology"]["metrics"],
                           "phonology+prior": chosen["phonology+prior"]["metrics"]}}


def _phonology_plan(setup: ReadBackSetup, clips: RetrievalClips, table: R.LexiconTable, inner_train: np.ndarray,
                    inner_val: np.ndarray) -> dict[str, Any]:
    """The property classifiers' epoch budgets, validated on the inner fold (a torch model's; 1 for scikit-learn)."""
    codes_all = table.codes[clips.entry_rows]
    return {"epochs": {prop: _fit(setup.phonology, clips, codes_all[:, j], table.vocab[j], inner_train, inner_val,
                                  None)[1] for j, prop in enumerate(table.properties)}}


def _fits_once(spec: ModelSpec, clips: RetrievalClips) -> bool:
    """Whether the classifier fits once, with no epochs to validate (scikit-learn's)."""
    from aslexp.recognition.models import build_classifier

    _, channels, frames, nodes, _ = clips.X.shape
    probe = build_classifier(spec.name, dict(spec.params), channels, frames, nodes, 2, clips.layout, module=spec.module)
    return probe.kind == "sklearn"


def fit_fold_models(setup: ReadBackSetup, data=None, cache_folder: str | Path | None = None) -> ReadBackModels:
    """Every fold's property classifiers and lookup model, read from the cache where their key
    matches and fitted otherwise; ``data`` is :func:`training_clips`' return (built when None)."""
    clips, table, lexicon = data if data is not None else training_clips(setup)
    start, cpu = time.perf_counter(), time.process_time()
    settings = setup.settings
    folds = gloss_folds(clips.glosses, settings.folds, settings.fold_seed)
    glosses = np.asarray(clips.glosses, dtype=object)
    codes_all = table.codes[clips.entry_rows]
    # one folder per fold plan and keypoint route (data, pose, glosses): other settings' models stay side
    # by side; within a folder a changed clip, label or lexicon makes an entry stale
    route = _digest_of({"keypoints": setup.keypoints, "glosses": settings.glosses})[:8]
    cache = ModelCache(Path(cache_folder or settings.model_cache) / f"k{settings.folds}-seed{settings.fold_seed}-{route}")
    selection = {**setup.selection, "properties": list(table.properties)}
    phonology_fits_once = _fits_once(setup.phonology, clips)
    out = []
    for k, test_glosses in enumerate(folds):
        test = np.isin(glosses, test_glosses)
        train = np.flatnonzero(~test)
        val_fold = (k + 1) % len(folds)
        inner_val = np.flatnonzero(np.isin(glosses, folds[val_fold]))
        inner_train = np.setdiff1d(train, inner_val)
        identity = _identity(clips, table, train)
        inner = {"validation_fold": val_fold, "validation_glosses": list(folds[val_fold])}
        where = f"fold{k}"
        lookup_plan = cache.plan(f"{where}/lookup-plan-{setup.lookup.name}-{setup.lookup.digest()}",
                                 {"fold": k, "training": identity, **inner, "classifier": setup.lookup.identity(),
                                  "selection": selection},
                                 lambda: _lookup_plan(setup, clips, table, inner_train, inner_val))
        if phonology_fits_once:
            phonology_plan = {"epochs": {p: 1 for p in table.properties}}
        else:
            phonology_plan = cache.plan(f"{where}/phonology-plan-{setup.phonology.name}-{setup.phonology.digest()}",
                                        {"fold": k, "training": identity, **inner,
                                         "classifier": setup.phonology.identity()},
                                        lambda: _phonology_plan(setup, clips, table, inner_train, inner_val))
        heads: dict[str, dict[str, Head]] = {"phonology": {}, "lookup": {}}
        for role, spec, plan in (("phonology", setup.phonology, phonology_plan), ("lookup", setup.lookup, lookup_plan)):
            for j, prop in enumerate(table.properties):
                epochs = int(plan["epochs"][prop])
                fields = {"fold": k, "property": prop, "training": identity, "classifier": spec.identity(),
                          "epochs": epochs}
                # one entry per fold, property and classifier: a phonology and a lookup classifier of the
                # same settings are one model, fitted once
                name = f"{where}/{prop}-{spec.name}-{_digest_of({'c': spec.identity(), 'e': epochs})[:10]}"
                heads[role][prop] = cache.head(name, fields, lambda j=j, spec=spec, epochs=epochs: _fit(
                    spec, clips, codes_all[:, j], table.vocab[j], train, None, epochs)[0])
        priors = None
        if setup.selection["likelihood"] == "ratio":
            priors = [R.value_prior(codes_all[train, j], len(v)) for j, v in enumerate(table.vocab)]
        majority = {}
        for j, prop in enumerate(table.properties):
            known = codes_all[train, j][codes_all[train, j] >= 0]
            majority[prop] = table.vocab[j][int(np.bincount(known).argmax())] if len(known) else None
        out.append(FoldModels(index=k, test_glosses=tuple(test_glosses), training=identity,
                              phonology=heads["phonology"], lookup=heads["lookup"],
                              smoothing_alone=float(lookup_plan["smoothing_alone"]),
                              smoothing=float(lookup_plan["smoothing"]), prior_weight=float(lookup_plan["prior_weight"]),
                              value_priors=priors, majority=majority, plan=lookup_plan))
    entry_fold, gloss_fold = {}, {}
    for k, test_glosses in enumerate(folds):
        for gloss in test_glosses:
            gloss_fold[gloss] = k
    for gloss, row in zip(clips.glosses, clips.entry_rows):
        entry_fold[table.entry_ids[int(row)]] = gloss_fold[gloss]
    elapsed, cpu = time.perf_counter() - start, time.process_time() - cpu
    log.info("read-back models: %d folds of %d glosses (%d clips): %d fitted, %d read from %s (%.1f s, %.1f s of CPU)",
             len(folds), len(set(clips.glosses)), len(clips.glosses), cache.fitted, cache.reused, cache.folder, elapsed,
             cpu)
    return ReadBackModels(setup=setup, table=table, lexicon=lexicon, folds=out, entry_fold=entry_fold,
                          gloss_fold=gloss_fold, cache={"folder": str(cache.folder), "fitted": cache.fitted,
                                                        "reused": cache.reused, "refused": list(cache.refused)},
                          fit_time_s=elapsed, fit_cpu_s=cpu)


# --------------------------------------------------------------------------- reading clips


@dataclass
class PreparedClips:
    """Keypoints prepared as the dataset builder prepares its clips."""

    X: np.ndarray  # (n, C, T, V, 1)
    mask: np.ndarray  # (n, T, V)
    frames: list[int]


def prepare_keypoints(keypoints: Sequence[np.ndarray | str | Path], setup: ReadBackSetup,
                      origins: Sequence[str] | None = None) -> PreparedClips:
    """Each item (an array in the keypoint source's file layout, e.g. MediaPipe Pose's (T, 132) or
    (T, 33, 4), or a ``.npy`` path) read by the source's own reader (all-zero frames missing ...),
    then the subset, the channels and :func:`~aslexp.data.preprocess.preprocess_clips`: the route
    the builder's training clips took."""
    from aslexp.data.keypoints import open_keypoint_source
    from aslexp.data.preprocess import preprocess_clips
    from aslexp.data.wlasl_lex import _channel_index
    from aslexp.keypoints.source import SubsetSource

    params = _build_params(setup, setup.properties[0])
    root = setup.keypoints["data"]["root"]
    options = {k: v for k, v in dict(params.source_options).items() if k != "names"}
    origins = list(origins) if origins is not None else [
        str(item) if isinstance(item, (str, Path)) else f"keypoints[{i}]" for i, item in enumerate(keypoints)]
    clips, frames = [], []
    with tempfile.TemporaryDirectory(prefix="read_back_") as scratch:
        sources: dict[str, Any] = {}

        def source_of(folder: str):
            if folder not in sources:
                sources[folder] = SubsetSource(open_keypoint_source(params.source, root, folder, **options), params.subset)
            return sources[folder]

        layout = source_of(scratch).layout
        channel_index = _channel_index(layout, params.channels)
        channels = [layout.channels[c] for c in channel_index]
        for i, (item, origin) in enumerate(zip(keypoints, origins)):
            if isinstance(item, (str, Path)):
                path = Path(item)
                if not path.is_file():
                    raise FileNotFoundError(f"{origin}: no such keypoint file; expected a .npy array")
                if path.suffix != ".npy":
                    raise DataError(f"{origin}: a {path.suffix or 'suffix-less'} file; expected a .npy keypoint array")
                folder, name = str(path.parent), path.stem
            else:
                array = np.asarray(item)
                if array.ndim not in (2, 3) or not np.issubdtype(array.dtype, np.number):
                    raise DataError(f"{origin}: keypoints of shape {array.shape} ({array.dtype}); expected a numeric "
                                    "(T, V*C) or (T, V, C) array in the keypoint source's layout")
                folder, name = scratch, f"clip{i}"
                np.save(Path(scratch) / f"{name}.npy", array)
            try:
                clip = source_of(folder).load(name)
            except DataError as error:
                text = str(error).replace(str(Path(scratch) / f"{name}.npy"), origin)
                raise DataError(text if origin in text else f"{origin}: {text}") from None
            clips.append(clip[..., channel_index])
            frames.append(len(clip))
    prepared = preprocess_clips(clips, channels, params.length, params.padding)
    if prepared.skipped_no_valid_frame:
        bad = prepared.skipped_no_valid_frame[0]
        raise DataError(f"{origins[bad]}: none of its {frames[bad]} frames has an observed keypoint; expected a "
                        "visible signer")
    return PreparedClips(X=prepared.X, mask=prepared.mask, frames=frames)


def _entry_of(models: ReadBackModels, gloss: str, origin: str):
    from aslexp.data.matching import match_names

    match = match_names([gloss], models.lexicon)[0].get(gloss)
    if match is None or match.entry.entry_id not in models.table.entry_ids:
        raise DataError(f"{origin}: gloss {gloss!r} has no {models.lexicon.name} entry; expected a gloss of the "
                        "lexicon (its EntryID or LemmaID, e.g. 'book')")
    return match.entry


def _rank_record(rank: R.Rank) -> dict[str, float]:
    return {"expected": rank.expected, "above": rank.above, "tied": rank.tied}


def read_back_many(items: Sequence[tuple[np.ndarray | str | Path, str]], models: ReadBackModels,
                   origins: Sequence[str] | None = None) -> list[dict[str, Any]]:
    """:func:`read_back` of every (keypoints, gloss), each by the fold that held its gloss out,
    every fold's clips predicted together."""
    if not items:
        return []
    origins = list(origins) if origins is not None else [
        str(k) if isinstance(k, (str, Path)) else f"keypoints[{i}] ({g})" for i, (k, g) in enumerate(items)]
    entries = [_entry_of(models, gloss, origin) for (_, gloss), origin in zip(items, origins)]
    prepared = prepare_keypoints([k for k, _ in items], models.setup, origins)
    table = models.table
    results: list[dict[str, Any] | None] = [None] * len(items)
    chosen = [models.entry_fold.get(e.entry_id) for e in entries]
    for k in sorted({0 if c is None else c for c in chosen}):
        rows = [i for i, c in enumerate(chosen) if (0 if c is None else c) == k]
        fold = models.folds[k]
        X, mask = prepared.X[rows], prepared.mask[rows]
        phonology = {p: fold.phonology[p].proba(X, mask, table.vocab[j]) for j, p in enumerate(table.properties)}
        lookup = [fold.lookup[p].proba(X, mask, table.vocab[j]) for j, p in enumerate(table.properties)]
        alone = R.phonology_scores(table, lookup, fold.smoothing_alone, fold.value_priors)
        both = R.phonology_scores(table, lookup, fold.smoothing, fold.value_priors) + fold.prior_weight * table.log_prior
        for n, i in enumerate(rows):
            entry = entries[i]
            row = table.index(entry.entry_id)
            properties = {}
            for j, prop in enumerate(table.properties):
                p = phonology[prop][n]
                predicted = table.vocab[j][int(p.argmax())]
                truth = entry.properties.get(prop)
                properties[prop] = {"predicted": predicted, "probability": float(p.max()), "asllex": truth,
                                    "agrees": None if truth is None else predicted == truth,
                                    "majority": fold.majority[prop]}
            ranks = {"phonology+prior": R.rank_of_true(both[n], row), "phonology": R.rank_of_true(alone[n], row),
                     "prior": R.rank_of_true(table.log_prior, row)}
            gloss = items[i][1]
            if chosen[i] is None:
                why = (f"{gloss!r} ({entry.entry_id}) is the gloss of no fold: no fold's models saw it; fold 0's "
                       "read it")
            else:
                why = (f"fold {k} held out {gloss!r} ({entry.entry_id}): its models were fitted on the other "
                       f"{len(models.folds) - 1} folds' {fold.training['glosses']} glosses")
            results[i] = {
                "origin": origins[i], "gloss": gloss, "entry_id": entry.entry_id,
                "fold": k, "gloss_in_folds": chosen[i] is not None, "fold_note": why,
                "frames": prepared.frames[i], "observed": float(prepared.mask[i].mean()),
                "properties": properties,
                "lexicon_rank": ranks["phonology+prior"].expected,
                "lexicon_size": len(table),
                "ranks": {m: _rank_record(r) for m, r in ranks.items()},
            }
    return [r for r in results if r is not None]


def folder_items(folder: str | Path, models: ReadBackModels,
                 glosses: Mapping[str, str] | None = None) -> list[tuple[Path, str]]:
    """Every ``<name>.npy`` of ``folder`` (sorted) with its gloss: ``glosses[name]`` when given, else
    WLASL's gloss when the name is a WLASL video id, else the name read as a gloss (``book_2`` ->
    book: one trailing ``_<digits>`` dropped, ``_`` a space, as ``pose.options.names=gloss`` reads it)."""
    from aslexp.data.matching import normalise_gloss
    from aslexp.data.wlasl import load_wlasl
    from aslexp.keypoints.arrays import npy_ids

    folder = Path(folder)
    if not folder.is_dir():
        raise FileNotFoundError(f"{folder}: no such folder; expected a folder of .npy keypoint arrays")
    names = sorted(npy_ids(folder))
    if not names:
        raise DataError(f"{folder}: no .npy keypoint arrays; expected <name>.npy files")
    given = dict(glosses or {})
    by_video = None
    items = []
    for name in names:
        if name in given:
            gloss = given[name]
        else:
            if by_video is None:
                by_video = load_wlasl(models.setup.keypoints["data"]["root"]).by_video_id()
            instance = by_video.get(name)
            gloss = instance.gloss if instance is not None else normalise_gloss(name)
        items.append((folder / f"{name}.npy", gloss))
    return items


def read_back(keypoints: np.ndarray | str | Path, gloss: str, models: ReadBackModels) -> dict[str, Any]:
    """One clip read back: ``{"properties": {name: {"predicted", "probability", "asllex", "agrees",
    "majority"}}, "lexicon_rank", "lexicon_size", "ranks", "fold", "gloss_in_folds", "fold_note", ...}``.
    ``lexicon_rank`` is the expected rank of the gloss's entry among all lexicon entries by the
    lookup's score (phonology + prior; ties broken at random, so it may end in .5); ``ranks`` also
    gives phonology alone and the prior alone (no reading at all)."""
    return read_back_many([(keypoints, gloss)], models)[0]


# --------------------------------------------------------------------------- the table


def wilson_interval(successes: int, n: int, confidence: float = 0.95) -> dict[str, float]:
    """The Wilson score interval of a rate (independent trials)."""
    from scipy.stats import norm

    if n == 0:
        return {"value": math.nan, "low": math.nan, "high": math.nan, "n": 0}
    z = float(norm.ppf(0.5 + confidence / 2))
    p = successes / n
    centre = (p + z * z / (2 * n)) / (1 + z * z / n)
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / (1 + z * z / n)
    return {"value": p, "low": max(0.0, centre - half), "high": min(1.0, centre + half), "n": n}


def _statistics(results: Sequence[Mapping[str, Any]], properties: Sequence[str], recall_at: Sequence[int]):
    """Per clip the numbers the table averages: (name -> (per-clip values, per-clip weight 0/1))."""
    columns: dict[str, tuple[np.ndarray, np.ndarray, str]] = {}
    for prop in properties:
        known = np.array([r["properties"][prop]["agrees"] is not None for r in results])
        agrees = np.array([bool(r["properties"][prop]["agrees"]) for r in results], dtype=np.float64)
        majority = np.array([r["properties"][prop]["majority"] == r["properties"][prop]["asllex"] for r in results],
                            dtype=np.float64)
        columns[f"{prop}/agreement"] = (agrees, known, "mean")
        columns[f"{prop}/majority"] = (majority, known, "mean")
    for method in METHODS:
        ranks = [R.Rank(int(r["ranks"][method]["above"]), int(r["ranks"][method]["tied"])) for r in results]
        every = np.ones(len(ranks), dtype=bool)
        columns[f"{method}/median_rank"] = (np.array([x.expected for x in ranks]), every, "median")
        for k in recall_at:
            columns[f"{method}/recall@{k}"] = (np.array([x.recall_at(k) for x in ranks]), every, "mean")
    return columns


def _value(values: np.ndarray, weight: np.ndarray, how: str) -> float:
    chosen = values[weight]
    if len(chosen) == 0:
        return math.nan
    return float(np.median(chosen) if how == "median" else chosen.mean())


def table_of(results: Sequence[Mapping[str, Any]], properties: Sequence[str], recall_at: Sequence[int] = (10, 50),
             interval: IntervalSettings = IntervalSettings()) -> dict[str, Any]:
    """The table of read-back results (the source's clips, or an agent's): per property the agreement
    rate with ASL-LEX (clips whose value is known) beside the majority value's; per lookup method the
    median expected rank and recall@k. Every number with a percentile bootstrap interval over glosses
    (all clips of each drawn gloss; with one clip per gloss, a bootstrap over clips); the rates also
    with Wilson intervals, which treat clips as independent."""
    columns = _statistics(results, properties, recall_at)
    glosses = [str(r["gloss"]) for r in results]
    groups = [np.flatnonzero(np.asarray(glosses, dtype=object) == g) for g in sorted(set(glosses))]
    rng = np.random.default_rng(interval.seed)
    draws: dict[str, list[float]] = {name: [] for name in columns}
    for _ in range(interval.resamples if results else 0):
        picked = rng.integers(len(groups), size=len(groups))
        idx = np.concatenate([groups[g] for g in picked])
        for name, (values, weight, how) in columns.items():
            draws[name].append(_value(values[idx], weight[idx], how))
    tail = (1 - interval.confidence) / 2

    def cell(name: str) -> dict[str, float]:
        values, weight, how = columns[name]
        drawn = np.asarray(draws[name], dtype=np.float64)
        drawn = drawn[np.isfinite(drawn)]
        low, high = (np.quantile(drawn, [tail, 1 - tail]) if len(drawn) else (math.nan, math.nan))
        return {"value": _value(values, weight, how), "low": float(low), "high": float(high), "n": int(weight.sum())}

    table: dict[str, Any] = {"properties": {}, "lookup": {}}
    for prop in properties:
        values, weight, _ = columns[f"{prop}/agreement"]
        table["properties"][prop] = {
            "agreement": cell(f"{prop}/agreement"), "majority": cell(f"{prop}/majority"),
            "wilson": wilson_interval(int(values[weight].sum()), int(weight.sum()), interval.confidence)}
    for method in METHODS:
        table["lookup"][method] = {"median_rank": cell(f"{method}/median_rank"),
                                   **{f"recall@{k}": cell(f"{method}/recall@{k}") for k in recall_at}}
    table.update(clips=len(results), glosses=len(groups), lexicon_size=int(results[0]["lexicon_size"]) if results else 0,
                 interval={"method": "percentile bootstrap over glosses", "resamples": interval.resamples,
                           "confidence": interval.confidence, "seed": interval.seed})
    return table


def score_clips(items: Sequence[tuple[np.ndarray | str | Path, str]], models: ReadBackModels,
                origins: Sequence[str] | None = None) -> dict[str, Any]:
    """Read every (keypoints, gloss) back and table them (:func:`table_of`): ``{"table", "clips"}``."""
    results = read_back_many(items, models, origins)
    settings = models.setup.settings
    return {"table": table_of(results, models.properties, settings.recall_at, settings.interval), "clips": results}


def _pct(cell: Mapping[str, float]) -> str:
    if not math.isfinite(cell["value"]):
        return "-"
    return f"{100 * cell['value']:.1f} [{100 * cell['low']:.1f}, {100 * cell['high']:.1f}]"


def table_lines(table: Mapping[str, Any], recall_at: Sequence[int] = (10, 50)) -> list[str]:
    """The table as Markdown: the properties' agreement, then the lookup's ranks."""
    lines = ["| property | clips | agreement with ASL-LEX (%) | majority value's (%) | Wilson, clips independent (%) |",
             "|---|---|---|---|---|"]
    for prop, row in table["properties"].items():
        lines.append(f"| {prop} | {row['agreement']['n']} | {_pct(row['agreement'])} | {_pct(row['majority'])} | "
                     f"{_pct(row['wilson'])} |")
    lines += ["", "| lexicon rank by | median rank | " + " | ".join(f"recall@{k} (%)" for k in recall_at) + " |",
              "|---|---|" + "---|" * len(recall_at)]
    labels = {"phonology+prior": "lookup: phonology + prior", "phonology": "phonology alone",
              "prior": "frequency prior alone (no reading)"}
    for method, row in table["lookup"].items():
        median = row["median_rank"]
        lines.append(f"| {labels[method]} | {median['value']:.1f} [{median['low']:.1f}, {median['high']:.1f}] | "
                     + " | ".join(_pct(row[f"recall@{k}"]) for k in recall_at) + " |")
    return lines


# --------------------------------------------------------------------------- the source's own table


def source_items(setup: ReadBackSetup, clips: RetrievalClips) -> tuple[list[tuple[Path, str]], list[str]]:
    """The real clips as read-back items: each clip's keypoint file (the source's folder) and gloss."""
    from aslexp.data.keypoints import open_keypoint_source

    params = _build_params(setup, setup.properties[0])
    options = {k: v for k, v in dict(params.source_options).items() if k != "names"}
    source = open_keypoint_source(params.source, setup.keypoints["data"]["root"], params.source_path, **options)
    folder = Path(getattr(source, "directory"))
    paths = [folder / f"{v}.npy" for v in clips.video_ids]
    return [(p, g) for p, g in zip(paths, clips.glosses)], [p.name for p in paths]


def measure_source(setup: ReadBackSetup) -> dict[str, Any]:
    """Fit (or read) every fold's models and read every real clip back: the source's own table."""
    data = training_clips(setup)
    models = fit_fold_models(setup, data)
    start = time.perf_counter()
    items, origins = source_items(setup, data[0])
    scored = score_clips(items, models, origins)
    return {"settings": {"folds": setup.settings.folds, "fold_seed": setup.settings.fold_seed,
                         "phonology": setup.phonology.identity(), "lookup": setup.lookup.identity(),
                         "selection": setup.selection, "properties": list(setup.properties)},
            "folds": [{"index": f.index, "test_glosses": list(f.test_glosses), "training": f.training,
                       "smoothing_alone": f.smoothing_alone, "smoothing": f.smoothing, "prior_weight": f.prior_weight}
                      for f in models.folds],
            "cache": models.cache, "fit_time_s": models.fit_time_s, "fit_cpu_s": models.fit_cpu_s,
            "read_time_s": time.perf_counter() - start,
            **scored}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m aslexp.recognition.read_back",
                                     description="The source's own read-back table: every real clip read by the "
                                                 "fold models that never saw its gloss.")
    parser.add_argument("overrides", nargs="*", help="overrides of conf/read_back.yaml (folds=3, ...)")
    parser.add_argument("--out", default=None, help="a new folder for read_back.json and read_back.md")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    out = Path(args.out) if args.out else None
    if out is not None and (out / RESULT_FILE).exists():
        print(f"--out {out}: holds a finished read-back ({RESULT_FILE}); expected a new folder", file=sys.stderr)
        return 2
    try:
        setup = load_setup(args.overrides)
        result = measure_source(setup)
    except (ConfigError, DataError, FileNotFoundError) as error:
        print(str(error).splitlines()[0], file=sys.stderr)
        return 2
    lines = table_lines(result["table"], setup.settings.recall_at)
    print("\n".join(lines))
    print(f"{result['table']['clips']} clips of {result['table']['glosses']} glosses; models: "
          f"{result['cache']['fitted']} fitted, {result['cache']['reused']} read from the cache in "
          f"{result['fit_time_s']:.1f} s ({result['fit_cpu_s']:.1f} s of CPU); read back in {result['read_time_s']:.1f} s")
    if out is not None:
        from aslexp.files import write_json, write_text

        out.mkdir(parents=True, exist_ok=True)
        write_json(out / RESULT_FILE, result)
        write_text(out / TABLE_FILE, "# Read back: the source's own clips\n\n" + "\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
