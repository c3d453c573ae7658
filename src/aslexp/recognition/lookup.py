"""Look one clip up in the lexicon: its predicted phonology and the ASL-LEX signs that fit it best
(``aslexp lookup``; no Hydra here).

Two halves:

* **The saved model** (:func:`save_lookup_model`, called by ``aslexp retrieve`` with
  ``retrieval.save_model=all|first_split``): per property a classifier fitted once more, on every
  clip of the data (``all``: a deployment model; its figures are the K splits' of the same run, not
  its own) or on the first split's train+val glosses (``first_split``: the first split's test
  glosses stay unseen, so a lookup of one of its clips is a fair example); the smoothing ``eps``
  and prior weight ``w`` (for ``all`` the lower median over the K splits of the values chosen on
  each split's validation glosses, for ``first_split`` the first split's), ``pi`` of the likelihood
  ratio (the values' shares among the clips fitted on), the keypoint source, subset, channels,
  length and padding of the WLASL-Lex build, the lexicon's name and SHA-256, and which clip was
  fitted on. All of it in ``<run>/model/``: ``model.json`` and one checkpoint per property
  (:func:`aslexp.recognition.train.save_checkpoint`: joblib for scikit-learn, ``.pt`` for torch).
* **A lookup** (:func:`read_clip`, :func:`lookup_clip`): a ``.npy`` keypoint array (read by the
  model's own keypoint source, as the dataset builder read its training clips, or, beside a
  ``layout.json``, as an ``aslexp extract`` folder), a ``.pose`` file (pose-format; MediaPipe points
  by name) or a video (MediaPipe via ``aslexp extract``'s worker, when its environment exists)
  goes through the builder's own functions (source -> subset -> channels ->
  :func:`aslexp.data.preprocess.preprocess_clips`), every property's classifier predicts it, and
  every lexicon entry is scored as ``aslexp retrieve`` scores it (phonology + ``w`` log prior,
  :mod:`aslexp.recognition.retrieval`).

Bad input is a :class:`~aslexp.errors.DataError` (or FileNotFoundError) whose one line names the
file, the field and what was expected.
"""

from __future__ import annotations

import hashlib
import json
import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from aslexp.errors import DataError
from aslexp.keypoints.layout import KeypointLayout
from aslexp.recognition import retrieval as R

log = logging.getLogger(__name__)

MODEL_DIR = "model"
MODEL_FILE = "model.json"
MODEL_FORMAT = "aslexp-lookup-model"
MODEL_VERSION = 1
FIT_ON = ("all", "first_split")
FIT_ON_TEXT = {
    "all": "every clip of the data (train, validation and test glosses of the splits): a deployment model; "
           "the retrieval figures of its run folder are the K splits', not this model's",
    "first_split": "the train+val glosses of the first split; its test glosses were never seen",
}
KEYPOINT_SUFFIXES = (".npy", ".pose")
CARD_FORMATS = ("md", "html")


def _lower_median(values: Sequence[float]) -> float:
    """The lower of the two middle values (the middle one for an odd count): always a value given."""
    ordered = sorted(float(v) for v in values)
    return ordered[(len(ordered) - 1) // 2]


def _sha256(path: Path) -> str:
    with open(path, "rb") as handle:
        return hashlib.file_digest(handle, "sha256").hexdigest()


# --------------------------------------------------------------------------- what the builder did


def preprocessing_of(params: Mapping[str, Any], root: str | Path | None = None) -> dict[str, Any]:
    """The keypoint route of a WLASL-Lex build (``WlaslLexParams.to_dict()``): its source's layout,
    the subset's layout and the channels kept, found with the builder's own functions."""
    from aslexp.data.keypoints import open_keypoint_source
    from aslexp.data.wlasl_lex import _channel_index
    from aslexp.keypoints import subset_layout

    options = {k: v for k, v in dict(params.get("source_options") or {}).items() if k != "names"}
    inner = open_keypoint_source(params["source"], root, params.get("source_path"), **options)
    layout, _ = subset_layout(inner.layout, params["subset"])
    channels = [layout.channels[i] for i in _channel_index(layout, params.get("channels"))]
    keys = ("lexicon", "source", "source_path", "source_options", "subset", "channels", "length", "padding",
            "movement_none_as_missing")
    return {"build": {k: params.get(k) for k in keys}, "source_layout": inner.layout.to_spec(),
            "layout": layout.to_spec(), "channels": channels}


# --------------------------------------------------------------------------- saving


def _what_to_fit(fit_on: str, splits: list[Mapping[str, Any]], clips, table: R.LexiconTable,
                 split: Mapping[str, Any]) -> tuple[np.ndarray, dict[str, float], dict[str, int], str]:  # fmt: skip
    """The clips the saved model is fitted on, its smoothing and prior weight, each head's epochs,
    and how they were chosen: from every split (``all``) or from the first split's train+val."""
    from aslexp.data.splits import SplitOptions, resplit

    n = len(clips.X)
    if fit_on == "all":
        chosen = {"smoothing_alone": _lower_median([s["chosen"]["phonology"]["smoothing"] for s in splits]),
                  "smoothing": _lower_median([s["chosen"]["phonology+prior"]["smoothing"] for s in splits]),
                  "prior_weight": _lower_median([s["chosen"]["phonology+prior"]["weight"] for s in splits])}
        epochs = {p: int(_lower_median([s["epochs"][p] for s in splits])) for p in table.properties}
        how = (f"the lower median over the {len(splits)} split(s) of the values chosen on each split's validation "
               "glosses")
        return np.arange(n), chosen, epochs, how
    first = splits[0]
    options = split if isinstance(split, SplitOptions) else SplitOptions.parse(split)
    parts = resplit(["all"] * n, clips.glosses, options, int(first["seed"]))
    fitted = np.sort(np.concatenate([parts.keep[np.asarray(parts.splits[name], dtype=np.int64)]
                                     for name in ("train", "val")]))
    chosen = {"smoothing_alone": float(first["chosen"]["phonology"]["smoothing"]),
              "smoothing": float(first["chosen"]["phonology+prior"]["smoothing"]),
              "prior_weight": float(first["chosen"]["phonology+prior"]["weight"])}
    epochs = {p: int(first["epochs"][p]) for p in table.properties}
    return fitted, chosen, epochs, f"chosen on the validation glosses of the first split (seed {first['seed']})"


def _fit_head(folder: Path, prop: str, vocab: Sequence[str], codes: np.ndarray, fitted: np.ndarray, clips,
              classifier: Mapping[str, Any], params, config, epochs: int, seed: int) -> dict[str, Any]:  # fmt: skip
    """One property's head, fitted on the ``fitted`` clips that have a value and saved in ``folder``
    (a constant where fewer than two values were seen): its ``model.json`` record."""
    from aslexp.recognition.models import build_classifier
    from aslexp.recognition.train import ArraySplit, fit_final, save_checkpoint

    labelled = fitted[codes[fitted] >= 0]
    classes = np.unique(codes[labelled])
    head: dict[str, Any] = {"classes": [vocab[c] for c in classes], "clips": int(len(labelled)), "file": None,
                            "constant": None, "epochs": epochs}
    if len(classes) < 2:  # nothing to learn: uniform (no value seen) or the one value seen
        constant = np.full(len(vocab), 1.0 / len(vocab)) if len(classes) == 0 else np.eye(len(vocab))[classes[0]]
        head["constant"] = [float(v) for v in constant]
        return head
    _, channels, frames, nodes, _ = clips.X.shape
    model = build_classifier(str(classifier["name"]), dict(params), channels, frames, nodes, len(classes),
                             clips.layout, module=classifier.get("module"))
    train = ArraySplit(clips.X[labelled], clips.mask[labelled], np.searchsorted(classes, codes[labelled]))
    fit_final(model, train, ArraySplit(train.X[:1], train.mask[:1], train.y[:1]), config,
              epochs=max(1, epochs), seed=seed)
    path = save_checkpoint(model, folder / f"{prop}{model.checkpoint_suffix}",
                           extra={"property": prop, "classes": head["classes"]})
    if path.suffix == ".joblib":  # the same payload compressed (a forest of 500 trees: ~5x smaller)
        import joblib

        joblib.dump(joblib.load(path), path, compress=3)
    head["file"] = path.name
    return head


def save_lookup_model(
    folder: str | Path,
    clips,
    table: R.LexiconTable,
    result: Mapping[str, Any],
    classifier: Mapping[str, Any],
    trainer: Mapping[str, Any] | None,
    split: Mapping[str, Any],
    *,
    seed: int,
    fit_on: str,
    preprocessing: Mapping[str, Any],
    lexicon_path: str | Path,
    data_root: str | Path,
) -> dict[str, Any]:
    """Fit and save the lookup model of a retrieval run (see the module docstring): ``clips`` and
    ``table`` as :func:`aslexp.recognition.retrieval_run.run_retrieval` took them, ``result`` its
    return (the per-split choices and epoch budgets). Returns the saved ``model.json`` content."""
    from aslexp.files import write_json
    from aslexp.recognition.models import resolve_params
    from aslexp.recognition.train import TrainerConfig

    if fit_on not in FIT_ON:
        raise ValueError(f"retrieval.save_model={fit_on!r}; expected one of {list(FIT_ON)}")
    start = time.perf_counter()
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    n = len(clips.X)
    fitted, chosen, epochs, how = _what_to_fit(fit_on, list(result["per_split"]), clips, table, split)
    params = resolve_params(str(classifier["name"]), classifier.get("params"), classifier.get("module"))
    config = TrainerConfig.parse(trainer)
    codes_all = table.codes[clips.entry_rows]
    heads: dict[str, Any] = {}
    priors: dict[str, list[float]] = {}
    for j, prop in enumerate(table.properties):
        heads[prop] = _fit_head(folder, prop, table.vocab[j], codes_all[:, j], fitted, clips, classifier, params,
                                config, epochs[prop], int(seed))
        priors[prop] = [float(v) for v in R.value_prior(codes_all[fitted, j], len(table.vocab[j]))]
    in_fit = np.zeros(n, dtype=bool)
    in_fit[fitted] = True
    meta = {
        "format": MODEL_FORMAT, "version": MODEL_VERSION,
        "fit_on": fit_on, "fitted_on": FIT_ON_TEXT[fit_on],
        "classifier": {"name": str(classifier["name"]), "params": params, "module": classifier.get("module")},
        "seed": int(seed),
        "properties": list(table.properties),
        "vocab": {p: list(v) for p, v in zip(table.properties, table.vocab)},
        "heads": heads,
        "likelihood": result["likelihood"],
        "value_priors": priors if result["likelihood"] == "ratio" else None,
        **chosen,
        "chosen_how": how,
        "preprocessing": dict(preprocessing),
        "lexicon": {"name": preprocessing["build"]["lexicon"], "file": str(lexicon_path),
                    "sha256": _sha256(Path(lexicon_path)), "entries": len(table)},
        "data_root": str(data_root),
        "num_clips": int(n), "num_glosses": len(set(clips.glosses)),
        "fitted_clips": int(len(fitted)), "fitted_glosses": len({clips.glosses[i] for i in fitted}),
        "clips": {v: {"gloss": g, "entry_id": table.entry_ids[int(e)], "fitted": bool(f)}
                  for v, g, e, f in zip(clips.video_ids, clips.glosses, clips.entry_rows, in_fit)},
        "time_s": round(time.perf_counter() - start, 2),
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    write_json(folder / MODEL_FILE, meta)
    log.info("lookup model saved in %s: %s on %d clips of %d glosses (%s), eps %g, w %g (%.1f s)", folder,
             classifier["name"], len(fitted), meta["fitted_glosses"], fit_on, chosen["smoothing"],
             chosen["prior_weight"], meta["time_s"])
    return meta


# --------------------------------------------------------------------------- loading


@dataclass
class LookupModel:
    """A saved lookup model (``<run>/model/``); the classifiers load on first use."""

    folder: Path
    meta: dict[str, Any]
    source_layout: KeypointLayout
    layout: KeypointLayout
    _classifiers: dict[str, Any] = field(default_factory=dict)

    @property
    def properties(self) -> list[str]:
        return list(self.meta["properties"])

    @property
    def build(self) -> dict[str, Any]:
        return self.meta["preprocessing"]["build"]

    @property
    def channels(self) -> list[str]:
        return list(self.meta["preprocessing"]["channels"])

    def classifier(self, prop: str):
        from aslexp.recognition.train import load_checkpoint

        if prop not in self._classifiers:
            path = self.folder / self.meta["heads"][prop]["file"]
            try:
                self._classifiers[prop] = load_checkpoint(path)[0]
            except (ValueError, EOFError, OSError, KeyError, RuntimeError) as error:
                if isinstance(error, FileNotFoundError):
                    raise
                raise DataError(f"{path}: not a readable checkpoint of property {prop!r} ({type(error).__name__}: "
                                f"{error}); save the model again with `aslexp retrieve retrieval.save_model=all`"
                                ) from None
        return self._classifiers[prop]


def _layout_of(spec: Mapping[str, Any], origin: str) -> KeypointLayout:
    from aslexp.keypoints import get_layout

    layout = KeypointLayout.from_spec(spec, origin)
    try:  # the registered one, with its subsets, when it is the same
        known = get_layout(layout.name)
        if known.names == layout.names and known.channels == layout.channels:
            return known
    except DataError:
        pass
    if layout.name.startswith("pose_header_"):  # a .pose header's own layout (OpenPose): offer its subsets
        from aslexp.keypoints.slgcn27 import register_header_map

        register_header_map(layout)  # slgcn27 by point name, as the training run's reader offered it
    return layout


def load_lookup_model(run_dir: str | Path) -> LookupModel:
    """The model a retrieval run saved (``RUN/model/model.json``, or that folder itself)."""
    given = Path(run_dir)
    if not given.exists():
        raise FileNotFoundError(f"model={given}: no such folder; expected the run folder of `aslexp retrieve "
                                "retrieval.save_model=all`")
    folder = given if (given / MODEL_FILE).is_file() else given / MODEL_DIR
    path = folder / MODEL_FILE
    if not path.is_file():
        raise DataError(f"model={given}: no {MODEL_DIR}/{MODEL_FILE}: this run folder saved no lookup model; "
                        "expected the run folder of `aslexp retrieve retrieval.save_model=all` (or first_split)")
    try:
        meta = json.loads(path.read_text(encoding="utf-8"))
    except (ValueError, UnicodeDecodeError) as error:
        raise DataError(f"{path}: not JSON ({error})") from None
    if not isinstance(meta, dict) or meta.get("format") != MODEL_FORMAT:
        raise DataError(f"{path}: field 'format' = {meta.get('format') if isinstance(meta, dict) else None!r}; "
                        f"expected {MODEL_FORMAT!r} (written by `aslexp retrieve retrieval.save_model=all`)")
    if meta.get("version") != MODEL_VERSION:
        raise DataError(f"{path}: field 'version' = {meta.get('version')!r}; this aslexp reads version "
                        f"{MODEL_VERSION}: save the model again with `aslexp retrieve retrieval.save_model=all`")
    try:
        pre = meta["preprocessing"]
        source_layout = _layout_of(pre["source_layout"], f"{path}: preprocessing.source_layout")
        layout = _layout_of(pre["layout"], f"{path}: preprocessing.layout")
        for prop in meta["properties"]:
            head = meta["heads"][prop]
            if head.get("file") is None and head.get("constant") is None:
                raise DataError(f"{path}: field 'heads.{prop}' has neither a checkpoint file nor constant "
                                "probabilities")
            if head.get("file") is not None and not (folder / head["file"]).is_file():
                raise DataError(f"{path}: field 'heads.{prop}.file' names {head['file']}, which is not in {folder}")
    except KeyError as error:
        raise DataError(f"{path}: field {error.args[0]!r} missing; save the model again with `aslexp retrieve "
                        "retrieval.save_model=all`") from None
    return LookupModel(folder=folder, meta=meta, source_layout=source_layout, layout=layout)


def load_table(model: LookupModel, root: str | Path | None = None):
    """The lexicon the model was trained against, from the data root; a lexicon file of other content
    (another version) is one line. Returns (LexiconTable, Lexicon)."""
    from aslexp.data.lexicon import load_lexicon

    info = model.meta["lexicon"]
    lexicon = load_lexicon(info["name"], root,
                           movement_none_as_missing=bool(model.build.get("movement_none_as_missing")))
    digest = _sha256(lexicon.path)
    if digest != info["sha256"]:
        raise DataError(f"{lexicon.path}: lexicon file differs from the one model={model.folder.parent} was trained "
                        f"against ({info['file']}, sha256 {info['sha256'][:12]}..., this one {digest[:12]}...): "
                        "expected the same ASL-LEX file; set data_root= to the data the model was trained on")
    properties = model.properties
    table = R.lexicon_table(lexicon.entries, properties, {p: lexicon.vocabulary(p) for p in properties})
    for prop, vocab in zip(properties, table.vocab):
        if list(vocab) != list(model.meta["vocab"][prop]):
            raise DataError(f"{lexicon.path}: the values of {prop} differ from the model's vocab "
                            f"({model.folder / MODEL_FILE}: vocab.{prop})")
    return table, lexicon


# --------------------------------------------------------------------------- one clip


@dataclass
class LookupClip:
    """One input clip, read and preprocessed as the model's training clips were."""

    path: Path
    kind: str
    keypoints: np.ndarray  # (T_i, V, C): the model's nodes and channels, NaN where missing, before preprocessing
    X: np.ndarray  # (1, C, T, V, 1) float32, the model's input
    mask: np.ndarray  # (1, T, V) bool
    frames: int
    notes: list[str] = field(default_factory=list)
    span: tuple[int, int] | None = None  # frames=START:END: the 1-based frames kept of the file's

    @property
    def video_id(self) -> str:
        return self.path.stem


def input_kind(path: str | Path) -> str:
    """'keypoints' (.npy), 'pose' (.pose) or 'video'; a DataError for anything else."""
    from aslexp.pose.extract import VIDEO_SUFFIXES

    suffix = Path(path).suffix.lower()
    if suffix == ".npy":
        return "keypoints"
    if suffix == ".pose":
        return "pose"
    if suffix in VIDEO_SUFFIXES:
        return "video"
    raise DataError(f"input={path}: unknown file type {suffix or '(no suffix)'!r}; expected a keypoint array "
                    f"(.npy), a .pose file or a video ({', '.join(VIDEO_SUFFIXES)})")


def check_input(path: str | Path) -> str:
    """The input exists and has a known type (a video also needs the MediaPipe environment):
    returns its kind; else the one line."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"input={path}: {'a folder, not a file' if path.is_dir() else 'no such file'}; "
                                "expected a keypoint array (.npy), a .pose file or a video")
    kind = input_kind(path)
    if kind == "video":
        from aslexp.pose.extract import ExtractionError, mediapipe_python

        try:
            mediapipe_python()
        except ExtractionError as error:
            raise DataError(f"input={path}: a video needs MediaPipe to become keypoints: {error}; "
                            "or look up its keypoints (.npy, .pose) made elsewhere") from None
    return kind


def onto_layout(clip: np.ndarray, have: KeypointLayout, want: KeypointLayout, origin: str) -> np.ndarray:
    """(T, V, C) keypoints of layout ``have`` laid out as ``want``, nodes and channels by name."""
    if have.names == want.names and have.channels == want.channels:
        return clip
    nodes = [n for n in want.names if n not in have.names]
    channels = [c for c in want.channels if c not in have.channels]
    if nodes or channels:
        lacks = (f"{len(nodes)} node(s) ({', '.join(nodes[:4])}{', ...' if len(nodes) > 4 else ''})" if nodes else "") \
            + (" and " if nodes and channels else "") + (f"channel(s) {channels}" if channels else "")
        raise DataError(f"{origin}: its keypoints (layout {have.name!r}, {have.num_nodes} nodes, channels "
                        f"{list(have.channels)}) lack {lacks} that the model's layout {want.name!r} needs: the "
                        "model was trained on other keypoints")
    node_index = [have.names.index(n) for n in want.names]
    channel_index = [have.channels.index(c) for c in want.channels]
    return clip[:, node_index][:, :, channel_index]


# Arrays without a layout.json: the layouts told apart by their shape, and the training run's reader of each.
_ARRAY_LAYOUTS = {"mediapipe_pose": "pose=mediapipe_pose", "mediapipe_hands": "pose=mediapipe_hands",
                  "mediapipe_holistic": "pose=array_folder pose.options.layout=mediapipe_holistic",
                  "mediapipe_holistic_reduced": "pose=array_folder pose.options.layout=mediapipe_holistic_reduced"}


def file_layout(path: Path) -> tuple[str | None, str, str] | None:
    """What a keypoint file holds, for a refusal: (its layout's name or None, the layout in words, the
    pose overrides with which `aslexp retrieve` reads a folder of such files), or None when the file
    reads as no layout at all."""
    from aslexp.keypoints import get_layout
    from aslexp.keypoints.arrays import LAYOUT_FILE, read_layout

    if path.suffix.lower() == ".pose":
        from aslexp.keypoints.posefile import auto_layout, header_layout, known_format, read_pose
        from aslexp.keypoints.slgcn27 import header_map

        try:
            header = read_pose(path).header
        except DataError:
            return None
        layout = auto_layout(header, str(path))
        if layout is not None:  # the hands-only layout has no visibility channel
            return (layout.name, f"{layout.name} ({layout.num_nodes} nodes)",
                    "pose=pose_format" + ("" if "visibility" in layout.channels else " pose.channels=null"))
        layout = header_layout(header, str(path))[0]
        return (layout.name, f"{layout.name} (the file's own header, {layout.num_nodes} nodes; {known_format(header)})",
                "pose=pose_format" + ("" if header_map(layout.names) else " pose.subset=all pose.channels=null"))
    if (path.parent / LAYOUT_FILE).is_file():
        layout = read_layout(path.parent / LAYOUT_FILE)
        return layout.name, f"{layout.name} ({layout.num_nodes} nodes, its {LAYOUT_FILE})", "pose=mediapipe"
    try:
        shape = tuple(np.load(path, mmap_mode="r", allow_pickle=False).shape)
    except (OSError, ValueError):
        return None
    for name, overrides in _ARRAY_LAYOUTS.items():
        layout = get_layout(name)
        if shape[1:] in ((layout.num_nodes * len(layout.channels),), (layout.num_nodes, len(layout.channels))):
            return name, f"{name} (a {shape} array)", overrides
    return None, f"none known (a {shape} array)", "pose=array_folder"


def layout_refusal(path: Path, model: LookupModel) -> str | None:
    """The one line for a file of another layout than the model's: the file, the layout found, the
    layout expected and the ways on; None when the file's layout is the model's (another fault)."""
    found = file_layout(path)
    want = model.source_layout
    if found is None or found[0] == want.name:
        return None
    from aslexp.keypoints import holistic as H

    ways = []
    if set(want.names) <= set(H.NAMES):  # what `aslexp extract` writes holds the model's nodes
        ways.append("extract the video with `aslexp extract VIDEO --out DIR` (MediaPipe, Pose's 33 points among "
                    "them) and look up DIR/VIDEO_ID.npy (or give the video as the input)")
    spelled = " (its layout written in conf/pose/array_folder.yaml)" if found[0] is None else ""
    ways.append(f"train a lookup model on this layout: `aslexp retrieve {found[2]} pose.path=FOLDER "
                f"retrieval.save_model=all`{spelled} (FOLDER: such clips named by WLASL video id), then model=THAT_RUN")
    return (f"input={path}: keypoints of layout {found[1]}; model={model.folder.parent} expects layout {want.name} "
            f"({want.num_nodes} nodes, channels {', '.join(want.channels)}): " + ", or ".join(ways))


def _source_clip(path: Path, model: LookupModel, root, work_dir: Path | None) -> tuple[np.ndarray, str]:
    """(T, V, C) in the model's source layout, NaN where missing, and how it was read."""
    from aslexp.keypoints.arrays import LAYOUT_FILE, DirectoryKeypointSource

    kind = input_kind(path)
    build = model.build
    want = model.source_layout
    if kind == "keypoints" and (path.parent / LAYOUT_FILE).is_file():
        source = DirectoryKeypointSource(path.parent)
        return (onto_layout(source.load(path.stem), source.layout, want, str(path)),
                f"keypoint array of a folder described by its {LAYOUT_FILE} (as `aslexp extract` writes)")
    if kind == "keypoints":
        from aslexp.data.keypoints import open_keypoint_source

        options = {k: v for k, v in dict(build.get("source_options") or {}).items() if k != "names"}
        # the model's own source on the file's folder: the reader its training clips went through
        source = open_keypoint_source(build["source"], root, str(path.parent), **options)
        return (onto_layout(source.load(path.stem), source.layout, want, str(path)),
                f"keypoint array read by the model's keypoint source {build['source']!r}")
    if kind == "pose":
        from aslexp.keypoints.posefile import LAYOUT_MODES, read_pose_file

        mode = (want.name if want.name in LAYOUT_MODES
                else "header" if want.name.startswith("pose_header_") else "auto")
        pose = read_pose_file(path, mode)
        return (onto_layout(pose.keypoints, pose.layout, want, str(path)),
                f".pose file ({pose.fps:g} fps, {pose.width}x{pose.height}; read as layout {pose.layout.name})")
    # a video: MediaPipe Holistic through `aslexp extract`'s worker, into work_dir
    from aslexp.pose.extract import ExtractOptions, VideoJob, extract_videos

    check_input(path)
    out = Path(work_dir) if work_dir is not None else path.parent / f".{path.stem}_keypoints"
    summary = extract_videos([VideoJob(path.stem, str(path))], out, ExtractOptions(cpus=1), progress=False)
    if path.stem in summary.failed:
        failure = summary.failed[path.stem]
        raise DataError(f"input={path}: MediaPipe extraction failed ({failure['reason']}): {failure['error']}")
    source = DirectoryKeypointSource(out)
    return (onto_layout(source.load(path.stem), source.layout, want, str(path)),
            f"video, MediaPipe Holistic keypoints extracted into {out}")


def read_clip(path: str | Path, model: LookupModel, *, root: str | Path | None = None,
              work_dir: str | Path | None = None, frames: tuple[int, int] | None = None) -> LookupClip:
    """Read ``path`` and preprocess it exactly as the model's WLASL-Lex build did (source -> subset
    -> channels -> :func:`~aslexp.data.preprocess.preprocess_clips`); ``frames`` = (start, end),
    1-based and inclusive (end -1: to the end), cuts the clip first."""
    from aslexp.data.preprocess import preprocess_clips
    from aslexp.data.wlasl_lex import _channel_index
    from aslexp.keypoints import subset_layout

    path = Path(path)
    kind_of = check_input(path)
    build = model.build
    try:
        clip, kind = _source_clip(path, model, root, None if work_dir is None else Path(work_dir))
    except DataError as error:
        refusal = None if kind_of == "video" else layout_refusal(path, model)
        if refusal is not None:
            raise DataError(refusal) from None
        text = str(error)
        if str(path) not in text and path.name not in text:
            text = f"input={path}: {text}"
        raise DataError(f"{text} (model={model.folder.parent} reads {build['source']} keypoints, layout "
                        f"{model.source_layout.name}, subset {build['subset']})") from None
    layout, keep = subset_layout(model.source_layout, build["subset"])
    if layout.names != model.layout.names:
        raise DataError(f"{model.folder / MODEL_FILE}: subset {build['subset']!r} of layout "
                        f"{model.source_layout.name!r} gives nodes other than the model's layout {model.layout.name!r}")
    clip = clip[:, list(keep)]
    clip = clip[..., _channel_index(layout, model.channels)]
    total = len(clip)
    if frames is not None:
        start, end = frames
        if start > total or end > total:
            raise DataError(f"frames={start}:{end}: input={path} has {total} frames; expected 1 <= START <= END <= "
                            f"{total} (END -1 or empty: to the end)")
        end = total if end == -1 else end
        clip = clip[start - 1:end]
    if len(clip) == 0:
        raise DataError(f"input={path}: no frames; expected keypoints of at least one frame")
    prepared = preprocess_clips([clip], model.channels, int(build["length"]), build["padding"])
    if len(prepared.kept) == 0:
        raise DataError(f"input={path}: none of its {len(clip)} frames has an observed keypoint of the model's "
                        f"{layout.num_nodes} nodes ({layout.name}); expected a visible signer")
    notes = []
    seen = float(np.isfinite(clip).all(axis=-1).mean())
    if seen < 0.5:
        notes.append(f"only {100 * seen:.0f}% of the keypoints the model uses are observed")
    if frames is not None:
        notes.insert(0, f"frames {start}..{end} of {total} (frames={frames[0]}:{frames[1]})")
    if len(clip) > int(build["length"]):
        notes.append(f"{len(clip)} frames: the model reads the first {build['length']} (as in training)")
    return LookupClip(path=path, kind=kind, keypoints=clip, X=prepared.X, mask=prepared.mask, frames=len(clip),
                      notes=notes, span=None if frames is None else (start, end))


def predict_properties(model: LookupModel, clip: LookupClip) -> list[np.ndarray]:
    """Per property, the probabilities (1, |vocabulary|) over the lexicon's whole vocabulary (0 for
    values the classifier never saw)."""
    out = []
    for prop in model.properties:
        vocab = model.meta["vocab"][prop]
        head = model.meta["heads"][prop]
        proba = np.zeros((1, len(vocab)))
        if head["constant"] is not None:
            proba[0] = np.asarray(head["constant"], dtype=np.float64)
        else:
            columns = [vocab.index(v) for v in head["classes"]]
            proba[0, columns] = model.classifier(prop).predict_proba(clip.X, clip.mask)[0]
        out.append(proba)
    return out


def _known_clip(model: LookupModel, video_id: str, lexicon, root) -> dict[str, Any] | None:
    """The clip's own gloss and lexicon entry where the file is named by a WLASL video id: from the
    model's clips (then also whether it was fitted on), else from WLASL's metadata."""
    known = model.meta.get("clips", {}).get(video_id)
    fitted_glosses = {c["gloss"] for c in model.meta.get("clips", {}).values() if c["fitted"]}
    if known is not None:
        return {"gloss": known["gloss"], "entry_id": known["entry_id"], "clip_fitted": bool(known["fitted"]),
                "gloss_fitted": known["gloss"] in fitted_glosses, "source": "the model's training data"}
    try:
        from aslexp.data.matching import match_names
        from aslexp.data.wlasl import load_wlasl

        instance = load_wlasl(root).by_video_id().get(video_id)
        if instance is None:
            return None
        match = match_names([instance.gloss], lexicon)[0].get(instance.gloss)
    except (OSError, ValueError, KeyError):
        return None
    if match is None:
        return None
    return {"gloss": instance.gloss, "entry_id": match.entry.entry_id, "clip_fitted": False,
            "gloss_fitted": instance.gloss in fitted_glosses, "source": "WLASL's metadata"}


def lookup_clip(model: LookupModel, clip: LookupClip, table: R.LexiconTable, lexicon, *, top_k: int = 10,
                root: str | Path | None = None) -> dict[str, Any]:
    """The lookup of one clip: per property the probabilities, the ``top_k`` lexicon entries by
    phonology + prior (the retrieval score), and, where the clip's own sign is known, its rank."""
    proba = predict_properties(model, clip)
    meta = model.meta
    priors = None
    if meta["likelihood"] == "ratio":
        priors = [np.asarray(meta["value_priors"][p], dtype=np.float64) for p in model.properties]
    phonology = R.phonology_scores(table, proba, meta["smoothing"], priors)[0]
    weight = float(meta["prior_weight"])
    score = phonology + weight * table.log_prior
    order = np.lexsort((np.arange(len(table)), -score))[:top_k]  # best first, ties in lexicon order
    entries = {e.entry_id: e for e in lexicon.entries}
    properties = {}
    for prop, p in zip(model.properties, proba):
        vocab = meta["vocab"][prop]
        ranked = sorted(((vocab[k], float(p[0, k])) for k in range(len(vocab)) if p[0, k] > 0),
                        key=lambda item: -item[1])
        properties[prop] = {"predicted": ranked[0][0], "probability": ranked[0][1],
                            "probabilities": dict(ranked), "classes_seen": len(meta["heads"][prop]["classes"])}
    top = []
    for position, row in enumerate(order, start=1):
        entry_id = table.entry_ids[row]
        values = {p: (table.vocab[j][table.codes[row, j]] if table.codes[row, j] >= 0 else None)
                  for j, p in enumerate(model.properties)}
        top.append({"rank": position, "entry_id": entry_id, "lemma_id": entries[entry_id].lemma_id,
                    "values": values, "frequency_z": float(table.frequency_z[row]), "score": float(score[row]),
                    "phonology": float(phonology[row]), "log_prior": float(table.log_prior[row]),
                    "matches": sum(values[p] == properties[p]["predicted"] for p in model.properties)})
    truth = _known_clip(model, clip.video_id, lexicon, root)
    if truth is not None and truth["entry_id"] in table.entry_ids:
        row = table.index(truth["entry_id"])
        alone = R.phonology_scores(table, proba, meta["smoothing_alone"], priors)[0]
        truth["values"] = {p: (table.vocab[j][table.codes[row, j]] if table.codes[row, j] >= 0 else None)
                           for j, p in enumerate(model.properties)}
        truth["rank"] = {"phonology+prior": R.rank_of_true(score, row).expected,
                         "phonology": R.rank_of_true(alone, row).expected,
                         "prior": R.rank_of_true(table.log_prior, row).expected}
    elif truth is not None:
        truth = None
    return {
        "input": {"file": str(clip.path), "kind": clip.kind, "frames": clip.frames,
                  "span": None if clip.span is None else list(clip.span),
                  "observed": float(clip.mask[0].mean()), "notes": clip.notes},
        "model": {"folder": str(model.folder), "classifier": meta["classifier"]["name"], "fit_on": meta["fit_on"],
                  "fitted_on": meta["fitted_on"], "fitted_clips": meta["fitted_clips"],
                  "fitted_glosses": meta["fitted_glosses"], "properties": model.properties,
                  "layout": model.layout.name, "channels": model.channels, "lexicon": meta["lexicon"]["name"],
                  "likelihood": meta["likelihood"], "smoothing": meta["smoothing"], "prior_weight": weight,
                  "chosen_how": meta["chosen_how"]},
        "lexicon_entries": len(table),
        "properties": properties,
        "top": top,
        "truth": truth,
    }


# --------------------------------------------------------------------------- the card


SHORT = {"sign_type": "sign type", "major_location": "major loc.", "minor_location": "minor loc.",
         "selected_fingers": "fingers", "flexion": "flexion", "movement": "movement"}


def _rank_text(rank: float) -> str:
    return f"{rank:.0f}" if float(rank).is_integer() else f"{rank:.1f}"


def _property_rows(result: Mapping[str, Any], shown: int = 3) -> list[list[str]]:
    rows = []
    for prop, info in result["properties"].items():
        others = list(info["probabilities"].items())[1:shown]
        rows.append([prop, info["predicted"], f"{info['probability']:.2f}",
                     ", ".join(f"{v} {p:.2f}" for v, p in others) or "-"])
    return rows


def _top_rows(result: Mapping[str, Any]) -> list[list[str]]:
    truth = (result.get("truth") or {}).get("entry_id")
    rows = []
    for item in result["top"]:
        mark = " *" if item["entry_id"] == truth else ""
        rows.append([str(item["rank"]), item["entry_id"] + mark,
                     *[item["values"][p] or "-" for p in result["model"]["properties"]],
                     f"{item['frequency_z']:+.2f}", f"{item['score']:.2f}"])
    return rows


def _truth_line(result: Mapping[str, Any]) -> str:
    truth = result.get("truth")
    if not truth:
        return ("The clip's own sign is not known (its file name is not a WLASL video id of the model's data or "
                "of WLASL).")
    rank = truth["rank"]
    seen = ("this very clip was among those the model was fitted on, so its rank is optimistic"
            if truth["clip_fitted"] else
            "its gloss was among those the model was fitted on (other clips of it)" if truth["gloss_fitted"] else
            "its gloss was never seen in fitting: a sign new to the model")
    values = ", ".join(f"{p} {v or '-'}" for p, v in truth["values"].items())
    return (f"The clip's own sign (from {truth['source']}): {truth['gloss']} = ASL-LEX {truth['entry_id']} "
            f"({values}), ranked "
            f"{_rank_text(rank['phonology+prior'])} of {result['lexicon_entries']:,} by phonology + prior "
            f"(phonology alone {_rank_text(rank['phonology'])}, prior alone {_rank_text(rank['prior'])}); {seen}.")


def _table(header: list[str], rows: list[list[str]]) -> list[str]:
    return ["| " + " | ".join(header) + " |", "|" + "---|" * len(header), *["| " + " | ".join(r) + " |" for r in rows]]


def card_markdown(result: Mapping[str, Any], figure: str | None) -> str:
    """The card: the input, the model, the predicted properties, the top-k signs, the figure."""
    model, info = result["model"], result["input"]
    props = model["properties"]
    lines = [f"# Lookup: {Path(info['file']).name}", "",
             f"- Input: `{info['file']}` ({info['kind']}); {info['frames']} frames, {100 * info['observed']:.0f}% "
             f"of the model's keypoints observed after preprocessing" + "".join(f"; {n}" for n in info["notes"]) + ".",
             f"- Model: `{model['folder']}`: {model['classifier']} per property ({', '.join(props)}) on layout "
             f"{model['layout']} (channels {', '.join(model['channels'])}), fitted on {model['fitted_clips']} clips of "
             f"{model['fitted_glosses']} glosses: {model['fitted_on']}.",
             f"- Score of a sign: phonology ({'likelihood ratio' if model['likelihood'] == 'ratio' else 'posterior'}, "
             f"smoothing {model['smoothing']:g}) + {model['prior_weight']:g} x log frequency prior (softmax of "
             f"SignFrequency(Z)) over all {result['lexicon_entries']:,} {model['lexicon']} entries; "
             f"{model['chosen_how']}.",
             "", "## Predicted properties", "",
             *_table(["property", "predicted", "probability", "next"], _property_rows(result)),
             "", f"## Top {len(result['top'])} ASL-LEX signs", "",
             *_table(["rank", "gloss (EntryID)", *[SHORT.get(p, p) for p in props], "frequency Z", "score"],
                     _top_rows(result)),
             "", _truth_line(result) + (" (marked *)" if result.get("truth") and any(
                 t["entry_id"] == result["truth"]["entry_id"] for t in result["top"]) else ""), ""]
    if figure:
        lines += ["## Keypoints", "", f"![the keypoint sequence]({figure})", ""]
    return "\n".join(lines)


def card_html(result: Mapping[str, Any], figure: str | None) -> str:
    """The same card as a standalone HTML page."""
    import html
    import re

    def table(header, rows):
        head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
        body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows)
        return f"<table><thead><tr>{head}</tr></thead><tbody>{body}</tbody></table>"

    markdown = card_markdown(result, None).splitlines()
    bullets = "".join("<li>" + re.sub(r"`([^`]*)`", r"<code>\1</code>", html.escape(line[2:])) + "</li>"
                      for line in markdown if line.startswith("- "))
    props = result["model"]["properties"]
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>{html.escape(markdown[0][2:])}</title>",
             "<style>body{font-family:sans-serif;max-width:60em;margin:2em auto}table{border-collapse:collapse}"
             "td,th{border:1px solid #ccc;padding:.2em .5em}</style></head><body>",
             f"<h1>{html.escape(markdown[0][2:])}</h1><ul>{bullets}</ul>",
             "<h2>Predicted properties</h2>", table(["property", "predicted", "probability", "next"],
                                                   _property_rows(result)),
             f"<h2>Top {len(result['top'])} ASL-LEX signs</h2>",
             table(["rank", "gloss (EntryID)", *[SHORT.get(p, p) for p in props], "frequency Z", "score"],
                   _top_rows(result)),
             f"<p>{html.escape(_truth_line(result))}</p>"]
    if figure:
        parts.append(f"<h2>Keypoints</h2><img src='{html.escape(figure)}' alt='the keypoint sequence'>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def terminal_lines(result: Mapping[str, Any]) -> list[str]:
    """The short table for the terminal: the properties with their probabilities, the top-k signs."""
    props = result["model"]["properties"]
    out = [f"{Path(result['input']['file']).name}: predicted properties (probability)"]
    for row in _property_rows(result, shown=2):
        out.append(f"  {row[0]:<16} {row[1]:<22} {row[2]}   next: {row[3]}")
    header = ["rank", "gloss", *[SHORT.get(p, p) for p in props], "freq Z", "score"]
    rows = _top_rows(result)
    widths = [max(len(h), *(len(r[i]) for r in rows)) for i, h in enumerate(header)]
    out.append(f"top {len(rows)} of {result['lexicon_entries']:,} ASL-LEX signs (phonology + prior):")
    out.append("  " + "  ".join(h.ljust(w) for h, w in zip(header, widths)).rstrip())
    out += ["  " + "  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in rows]
    truth = result.get("truth")
    if truth:
        out.append(f"own sign {truth['entry_id']}: rank {_rank_text(truth['rank']['phonology+prior'])} "
                   f"(phonology alone {_rank_text(truth['rank']['phonology'])}, prior alone "
                   f"{_rank_text(truth['rank']['prior'])}); "
                   + ("clip fitted on" if truth["clip_fitted"] else "gloss fitted on" if truth["gloss_fitted"]
                      else "gloss never seen"))
    return out
