"""WLASL-Lex: WLASL clips labelled with ASL-LEX phonological properties, ready for a model.

Pipeline (``build_wlasl_lex``): lexicon + WLASL -> gloss matching -> which clip each keypoint
file holds (:mod:`aslexp.data.naming`, ``pose.options.names``) -> keep the clips that have
keypoints, a matched gloss and a value for the property -> load keypoints (subset of the layout,
chosen channels) -> fixed length + normalisation -> stratified split -> artefacts on disk (the
thesis' WLASL-Lex layout) and a :class:`RecognitionDataset`. Every skipped clip is counted under
its reason in ``dataset.skipped`` and ``manifest.json``.

Artefacts in the output folder:
  file2gloss.json, gloss2file.json, file_list.txt (dataset order), label2id.json, split.json
  (video ids per split; 'folds' for cv5), clips.json (video_id, gloss, entry_id, signer_id,
  label per clip), layout.json, {train,val,train+val,test}_data_joint_<pose>.npy (N, C, T, V, 1)
  float32, {split}_label.npy (N,) int64, {split}_mask.npy (N, T, V) bool, manifest.json
  (parameters, counts, skip reasons, the build's warnings; written last).
``<pose>`` is the layout name, e.g. ``mediapipe_pose_thesis``.
"""

from __future__ import annotations

import dataclasses
import errno
import hashlib
import json
import logging
import os
import secrets
import shutil
import tempfile
import time
from typing import Any
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from aslexp.config_schema import Section
from aslexp.data.dataset import DataError, KeypointLayout, RecognitionDataset
from aslexp.data.keypoints import open_keypoint_source
from aslexp.data.lexicon import check_property, lexicon_spec, load_lexicon
from aslexp.data.matching import lexicon_keys, match_glosses, match_names
from aslexp.data.naming import resolve_clip_files
from aslexp.data.preprocess import PADDINGS, preprocess_clips
from aslexp.data.root import resolve_data_root
from aslexp.data.splits import RARE_RULES, SPLIT_KINDS, make_splits
from aslexp.data.wlasl import WLASL_JSON, load_wlasl
from aslexp.files import save_npy, write_text
from aslexp.keypoints import SubsetSource, get_source, read_layout, write_layout

log = logging.getLogger(__name__)

# Bump when the artefacts or the built-in layouts (keypoints/layouts.py) change: cached builds are keyed on it.
FORMAT_VERSION = 3  # 3: manifest "warnings" (said again on reuse), skip reason keypoints_not_named
SPLIT_FILES = ("train", "val", "train+val", "test")
MANIFEST = "manifest.json"
INPUTS = "inputs.json"  # size and SHA-256 of every file a cached build read (its staleness check)
SKIP_REASONS = ("no_keypoints", "keypoints_not_in_wlasl", "keypoints_not_named", "gloss_not_in_lexicon",
                "missing_property_value", "bad_keypoint_file", "no_valid_frame", "rare_class")  # fmt: skip
LEXICON_NAMES = {"asllex1": "ASL-LEX 1.0", "asllex2": "ASL-LEX 2.0"}


@dataclass(frozen=True)
class WlaslLexParams(Section):
    """Everything that determines a WLASL-Lex build (and its cache key)."""

    SECTION = "wlasl_lex"

    lexicon: str = "asllex2"  # asllex1 | asllex2
    property: str = "sign_type"  # one of lexicon.PROPERTIES
    source: str = "mediapipe_pose_npy"  # a registered source: aslexp.keypoints.source_names()
    source_path: str | None = None  # folder or array; None = the default of the source
    source_options: dict = field(default_factory=dict)  # e.g. {"ids": ..., "layout": ...}
    subset: str = "all"  # keypoint subset of the layout (aslexp.keypoints.subset_names)
    channels: tuple[str, ...] | None = None  # None = all channels of the source
    split: str = "phoneme"  # phoneme | gloss | cv5
    length: int = 150
    padding: str = "loop"  # loop | zero
    seed: int = 0
    rare_classes: str = "drop"  # drop | merge | train_only
    movement_none_as_missing: bool = False

    def __post_init__(self):
        lexicon_spec(self.lexicon)
        check_property(self.property)
        for name, value, allowed in (("split", self.split, SPLIT_KINDS),
                                     ("padding", self.padding, PADDINGS),
                                     ("rare_classes", self.rare_classes, RARE_RULES)):  # fmt: skip
            if value not in allowed:
                raise DataError(f"WLASL-Lex parameter {name}={value!r}; expected one of {allowed}")
        if self.channels is not None:
            object.__setattr__(self, "channels", tuple(self.channels))

    def to_dict(self) -> dict:
        values = dataclasses.asdict(self)
        values["channels"] = list(self.channels) if self.channels is not None else None
        return values


def params_from_config(cfg: dict[str, Any]) -> WlaslLexParams:
    """The build parameters gathered from a composed ``aslexp recognize`` config's data, pose,
    property and split groups (plain containers: the jobs convert Hydra's)."""
    data, pose, split = cfg["data"], cfg["pose"], cfg["split"]
    options = dict(pose.get("options") or {})
    # names: null (files named by video id, the default every pose config carries so that
    # pose.options.names=... overrides) is left out, so builds made before the key existed keep their key
    if options.get("names", 0) is None:
        del options["names"]
    return WlaslLexParams(
        lexicon=data["lexicon"], property=cfg["property"]["name"], source=pose["source"],
        source_path=pose.get("path"), source_options=options, subset=pose["subset"],
        channels=pose.get("channels"), split=split["name"], length=int(data["num_frames"]),
        padding=data["padding"], seed=int(split["seed"]), rare_classes=split["rare_classes"],
        movement_none_as_missing=bool(data.get("movement_none_as_missing", False)),
    )


def build_wlasl_lex(
    out_dir: str | Path | None,
    params: WlaslLexParams | None = None,
    *,
    root: str | Path | None = None,
    strict: bool = False,
) -> RecognitionDataset:
    """Build WLASL-Lex for ``params`` and, when ``out_dir`` is given, write its artefacts there.

    ``strict=True`` raises on an unreadable keypoint file instead of skipping it (counted as
    ``bad_keypoint_file``). Returns the :class:`RecognitionDataset`.
    """
    params = params or WlaslLexParams()
    data_root = resolve_data_root(root)
    started = time.perf_counter()
    lexicon = load_lexicon(params.lexicon, data_root,
                           movement_none_as_missing=params.movement_none_as_missing)  # fmt: skip
    wlasl = load_wlasl(data_root)
    matched = match_glosses(wlasl, lexicon)
    options = dict(params.source_options)
    names = options.pop("names", None)  # which clip each file holds (aslexp.data.naming); not the source's
    inner = open_keypoint_source(params.source, data_root, params.source_path, **options)
    source = SubsetSource(inner, params.subset)
    layout = source.layout
    channel_index = _channel_index(layout, params.channels)
    channels = [layout.channels[i] for i in channel_index]

    skipped: Counter = Counter({reason: 0 for reason in SKIP_REASONS})
    available = source.available()
    where = _describe_source(params, inner)
    files = resolve_clip_files(available, names, wlasl, lexicon_keys(lexicon), where=where,
                               suffix=getattr(inner, "file_suffix", ""),
                               lexicon_name=LEXICON_NAMES.get(params.lexicon, params.lexicon))  # fmt: skip
    build_warnings = list(files.warnings)
    skipped.update(files.skipped)
    candidates = _labelled_clips(files.clips, matched, lexicon, params.property, skipped)
    clips, loaded, loaded_files = _load_clips(candidates, source, channel_index, strict, skipped, params.source)
    all_zero_frames = _source_messages(inner, loaded_files, len(loaded), build_warnings)

    prepared = preprocess_clips(clips, channels, params.length, params.padding)
    skipped["no_valid_frame"] = len(prepared.skipped_no_valid_frame)
    kept = [loaded[i] for i in prepared.kept]
    labels = [entry.properties[params.property] for _, entry in kept]
    glosses = [instance.gloss for instance, _ in kept]
    split = make_splits(labels, params.split, groups=glosses, seed=params.seed,
                        rare_classes=params.rare_classes)  # fmt: skip
    skipped["rare_class"] = split.dropped
    rows = split.keep
    kept = [kept[i] for i in rows]
    skipped = {reason: int(n) for reason, n in skipped.items()}
    log.info("WLASL-Lex %s/%s: %d clips, %d classes, %d glosses; skipped %s (%.1f s)",
             params.lexicon, params.property, len(kept), len(split.label_names),
             len({i.gloss for i, _ in kept}), skipped, time.perf_counter() - started)  # fmt: skip

    dataset = RecognitionDataset(
        property=params.property,
        label_names=split.label_names,
        X=prepared.X[rows],
        mask=prepared.mask[rows],
        y=split.y,
        video_ids=[instance.video_id for instance, _ in kept],
        glosses=[instance.gloss for instance, _ in kept],
        signer_ids=[instance.signer_id for instance, _ in kept],
        layout=layout,
        channels=channels,
        splits=split.splits,
        skipped=skipped,
    )
    if out_dir is not None:
        counts = {"wlasl_instances": len(wlasl.instances), "keypoint_files": len(available),
                  "matched_glosses": matched.num_glosses, "matched_videos": matched.num_videos,
                  "ambiguous_glosses": len(matched.ambiguous), "clips": len(kept),
                  "glosses": len(set(dataset.glosses)), "classes": dataset.num_classes,
                  "all_zero_frames": all_zero_frames, **{f"preprocess_{k}": v for k, v in prepared.stats.items()}}
        info = {"data_root": str(data_root), "entry_ids": [entry.entry_id for _, entry in kept], "counts": counts,
                "rare_classes": {"rule": params.rare_classes, "classes": split.rare}, "warnings": build_warnings}
        write_wlasl_lex(out_dir, dataset, params, info)
    return dataset


def _source_messages(inner, loaded_files: list[str], clips: int, build_warnings: list[str]) -> int:
    """Log the build's warnings and the source's own messages on the files it read (a warning joins
    ``build_warnings``); returns the all-zero frames (no detection) the source marked missing."""
    for line in build_warnings:
        log.warning("%s", line)
    for level, line in getattr(inner, "build_messages", lambda ids: [])(loaded_files):
        log.log(level, "%s", line)  # e.g. hand files that look like detection order: one line per build
        if level >= logging.WARNING:
            build_warnings.append(line)
    zero_frames = getattr(inner, "zero_frames", {})  # sources that mark all-zero frames
    all_zero_frames = int(sum(zero_frames.get(f, 0) for f in loaded_files))
    if zero_frames:
        log.info("%d all-zero frames (no detection) in %d clips marked missing", all_zero_frames, clips)
    return all_zero_frames


def _labelled_clips(file_clips, matched, lexicon, prop: str, skipped: Counter) -> list[tuple[Any, Any, str]]:
    """(instance, lexicon entry, file id) of every clip whose gloss has a lexicon entry with a value of
    ``prop``; the others counted in ``skipped``."""
    gloss_matches = dict(matched.matches)
    extra = sorted({i.gloss for i, _ in file_clips} - gloss_matches.keys() - set(matched.unmatched))
    gloss_matches.update(match_names(extra, lexicon)[0])  # glosses named by files, not by WLASL
    candidates = []
    for instance, file_id in file_clips:
        match = gloss_matches.get(instance.gloss)
        if match is None:
            skipped["gloss_not_in_lexicon"] += 1
        elif match.entry.properties[prop] is None:
            skipped["missing_property_value"] += 1
        else:
            candidates.append((instance, match.entry, file_id))
    return candidates


def _load_clips(candidates, source, channel_index, strict: bool, skipped: Counter, source_name: str):
    """Each candidate's keypoints (its channels): (arrays, (instance, entry) pairs, file ids). A file
    that cannot be read is skipped, counted and named (raised with ``strict``); when every one is, the
    build stops with one line saying why."""
    clips, loaded, loaded_files = [], [], []
    rejected: list[str] = []
    for instance, entry, file_id in _progress(candidates, desc="keypoints", unit="clip", mininterval=2,
                                              leave=False, disable=len(candidates) < 500):  # fmt: skip
        try:
            clip = source.load(file_id)
        except (DataError, OSError) as error:
            if strict:
                raise
            log.warning("skipping video %s: %s", instance.video_id, error)
            skipped["bad_keypoint_file"] += 1
            rejected.append(str(error))
            continue
        clips.append(clip[..., channel_index])
        loaded.append((instance, entry))
        loaded_files.append(file_id)
    if candidates and not loaded:  # every file is wrong for this source: say why, not "too few clips"
        raise DataError(f"keypoint source {source_name!r}: all {len(candidates)} keypoint files of the "
                        f"labelled clips were rejected, e.g. {rejected[0]} (files in another format need "
                        "their source and layout: conf/pose/array_folder.yaml, pose=mediapipe_hands, ...)")  # fmt: skip
    return clips, loaded, loaded_files


def _describe_source(params: WlaslLexParams, source) -> str:
    """The keypoint folder (or file) of a build, for messages."""
    folder = getattr(source, "directory", None)
    if folder is not None:
        return f"keypoint folder {folder}"
    return f"keypoint source {params.source!r}" + (f" ({params.source_path})" if params.source_path else "")


def _progress(items, **options):
    """tqdm where installed (a bare GPU node may lack it: then no bar)."""
    try:
        from tqdm import tqdm
    except ImportError:
        return items
    return tqdm(items, **options)


def _channel_index(layout: KeypointLayout, wanted) -> list[int]:
    if wanted is None:
        return list(range(len(layout.channels)))
    unknown = [c for c in wanted if c not in layout.channels]
    if unknown:
        raise DataError(f"channel(s) {unknown} not in layout {layout.name!r} channels {layout.channels}: set "
                        "pose.channels to some of them, or pose.channels=null for all")  # fmt: skip
    return [layout.channels.index(c) for c in wanted]


def _write_json(path: Path, payload) -> None:
    write_text(path, json.dumps(payload, indent=1, sort_keys=False))


def write_wlasl_lex(out_dir: str | Path, dataset: RecognitionDataset, params: WlaslLexParams,
                    info: dict) -> Path:  # fmt: skip
    """Write the artefacts of ``dataset`` (see the module docstring); manifest.json last."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ids = dataset.video_ids
    gloss2file: dict[str, list[str]] = {}
    for video_id, gloss in zip(ids, dataset.glosses):
        gloss2file.setdefault(gloss, []).append(video_id)
    _write_json(out / "file2gloss.json", dict(zip(ids, dataset.glosses)))
    _write_json(out / "gloss2file.json", gloss2file)
    write_text(out / "file_list.txt", "".join(f"{i}\n" for i in ids))
    _write_json(out / "label2id.json", {name: i for i, name in enumerate(dataset.label_names)})
    clips = [{"video_id": v, "gloss": g, "entry_id": e, "signer_id": s, "label": int(y)}
             for v, g, e, s, y in zip(ids, dataset.glosses, info["entry_ids"],
                                      dataset.signer_ids, dataset.y)]  # fmt: skip
    _write_json(out / "clips.json", clips)
    write_layout(out, dataset.layout)
    split_ids: dict[str, object] = {name: [ids[i] for i in dataset.splits[name]] for name in SPLIT_FILES}
    if "folds" in dataset.splits:
        split_ids["folds"] = [{"train": [ids[i] for i in tr], "val": [ids[i] for i in va]}
                              for tr, va in dataset.splits["folds"]]  # fmt: skip
    _write_json(out / "split.json", split_ids)
    pose = dataset.layout.name
    files = {}
    for name in SPLIT_FILES:
        idx = np.asarray(dataset.splits[name], dtype=np.int64)
        for kind, array in (("data", dataset.X[idx]), ("label", dataset.y[idx]), ("mask", dataset.mask[idx])):
            filename = f"{name}_data_joint_{pose}.npy" if kind == "data" else f"{name}_{kind}.npy"
            save_npy(out / filename, array)  # a full disk names the file
            files[f"{name}_{kind}"] = filename
    label_counts = {name: {dataset.label_names[k]: int(n) for k, n in
                           zip(*np.unique(dataset.y[np.asarray(dataset.splits[name], dtype=np.int64)],
                                          return_counts=True))}
                    for name in SPLIT_FILES}  # fmt: skip
    manifest = {
        "format_version": FORMAT_VERSION,
        "params": params.to_dict(),
        "data_root": info["data_root"],
        "layout": dataset.layout.name,
        "channels": dataset.channels,
        "shape": {"N": int(dataset.X.shape[0]), "C": int(dataset.X.shape[1]),
                  "T": int(dataset.X.shape[2]), "V": int(dataset.X.shape[3])},  # fmt: skip
        "label_names": dataset.label_names,
        "counts": info["counts"],
        "split_sizes": {name: len(split_ids[name]) for name in SPLIT_FILES},
        "label_counts": label_counts,
        "skipped": dataset.skipped,
        "rare_classes": info["rare_classes"],
        "warnings": info.get("warnings", []),  # repeated when the build is reused
        "files": files,
        "created": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    _write_json(out / MANIFEST, manifest)
    return out


@contextmanager
def _pinned(folder: Path) -> Iterator[Path]:
    """``folder`` held open: every path under the yielded one reads that very directory, even if
    another process renames a new build into ``folder``'s place meanwhile (Linux:
    ``/proc/self/fd/N``; elsewhere ``folder`` itself). FileNotFoundError if it does not exist."""
    fd = os.open(folder, os.O_RDONLY | getattr(os, "O_DIRECTORY", 0))
    try:
        pinned = Path(f"/proc/self/fd/{fd}")
        yield pinned if pinned.is_dir() else folder
    finally:
        os.close(fd)


def load_wlasl_lex(out_dir: str | Path) -> RecognitionDataset:
    """Read a finished build (``manifest.json`` present) back into a RecognitionDataset (every
    file from one folder, also while another build replaces it)."""
    with _pinned(Path(out_dir)) as out:
        return _load_wlasl_lex(out, Path(out_dir))


def _load_wlasl_lex(out: Path, name: Path) -> RecognitionDataset:
    manifest_path = out / MANIFEST
    if not manifest_path.is_file():
        raise DataError(f"{name}: no {MANIFEST}; not a finished WLASL-Lex build")
    manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    clips = json.loads((out / "clips.json").read_text(encoding="utf-8"))
    split_ids = json.loads((out / "split.json").read_text(encoding="utf-8"))
    ids = [clip["video_id"] for clip in clips]
    row = {video_id: i for i, video_id in enumerate(ids)}
    shape = manifest["shape"]
    X = np.zeros((shape["N"], shape["C"], shape["T"], shape["V"], 1), dtype=np.float32)
    mask = np.zeros((shape["N"], shape["T"], shape["V"]), dtype=bool)
    for name in ("train+val", "test"):  # together they hold every clip
        idx = np.array([row[v] for v in split_ids[name]], dtype=np.int64)
        X[idx] = np.load(out / manifest["files"][f"{name}_data"])
        mask[idx] = np.load(out / manifest["files"][f"{name}_mask"])
    splits: dict[str, object] = {name: np.array([row[v] for v in split_ids[name]], dtype=np.int64)
                                 for name in SPLIT_FILES}  # fmt: skip
    if "folds" in split_ids:
        splits["folds"] = [(np.array([row[v] for v in f["train"]], dtype=np.int64),
                            np.array([row[v] for v in f["val"]], dtype=np.int64))
                           for f in split_ids["folds"]]  # fmt: skip
    return RecognitionDataset(
        property=manifest["params"]["property"],
        label_names=list(manifest["label_names"]),
        X=X,
        mask=mask,
        y=np.array([clip["label"] for clip in clips], dtype=np.int64),
        video_ids=ids,
        glosses=[clip["gloss"] for clip in clips],
        signer_ids=[clip["signer_id"] for clip in clips],
        layout=read_layout(out / "layout.json"),
        channels=list(manifest["channels"]),
        splits=splits,
        skipped=dict(manifest["skipped"]),
    )


def cache_key(params: WlaslLexParams, root: str | Path | None = None) -> str:
    """A short hash of the parameters, the data root and the format version (the cache folder).

    What the build read is checked apart, on every reuse: see :func:`input_fingerprint`.
    """
    payload = {"format_version": FORMAT_VERSION, "params": params.to_dict(),
               "data_root": str(resolve_data_root(root))}  # fmt: skip
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()[:16]


def input_files(params: WlaslLexParams, root: str | Path | None = None) -> list[Path]:
    """The files a build with ``params`` reads: the lexicon, the WLASL metadata, and every file
    of the keypoint source (its folder, or its array and id files)."""
    data_root = resolve_data_root(root)
    paths = [data_root / lexicon_spec(params.lexicon).relpath, data_root / WLASL_JSON]
    source_paths = [params.source_path] if params.source_path else []
    default_path = get_source(params.source).default_path
    if not source_paths and default_path is not None:
        source_paths = [data_root / default_path]
    source_paths += [v for v in params.source_options.values()
                     if isinstance(v, (str, os.PathLike)) and Path(v).is_file()]
    for path in map(Path, source_paths):
        if path.is_dir():
            paths += sorted(p for p in path.iterdir() if p.is_file() and not p.name.startswith("."))
        else:
            paths.append(path)
    return paths


def input_fingerprint(params: WlaslLexParams, root: str | Path | None = None) -> dict[str, list]:
    """``{file: [size, sha256]}`` of :func:`input_files` (a missing file: ``[-1, None]``).

    By content: a file damaged, replaced, added or removed changes it, also a rewrite that keeps
    size and mtime (``cp -p`` of other bytes); a ``touch`` or a copy of the same bytes does not.
    Hashing the default build's 293 files (291 keypoint clips, the lexicon, WLASL; 37 MB) takes
    0.05 s (0.1 s from a cold page cache) on this project's 2-core machine, against 0.01 s for
    reading the cached build and 1 s for building it.
    """
    fingerprint: dict[str, list] = {}
    for path in input_files(params, root):
        try:
            with open(path, "rb") as handle:
                size = os.fstat(handle.fileno()).st_size
                digest = hashlib.file_digest(handle, "sha256").hexdigest()
            fingerprint[str(path)] = [size, digest]
        except OSError:
            fingerprint[str(path)] = [-1, None]
    return fingerprint


def _stale_inputs(build: Path, current: dict[str, list]) -> str | None:
    """Why the build in ``build`` no longer matches its inputs (None if it does)."""
    try:
        recorded = json.loads((build / INPUTS).read_text(encoding="utf-8"))["files"]
    except (OSError, ValueError, KeyError, TypeError):
        return f"it records no {INPUTS} (built by an older aslexp)"
    if not all(isinstance(v, list) and len(v) == 2 and (v[1] is None or isinstance(v[1], str))
               for v in recorded.values()):
        return f"its {INPUTS} records no content hashes (built by an older aslexp)"
    changed = sorted(f for f in current.keys() & recorded.keys() if list(recorded[f]) != current[f])
    added = sorted(current.keys() - recorded.keys())
    removed = sorted(recorded.keys() - current.keys())
    if not (changed or added or removed):
        return None
    parts = [f"{len(v)} {k}" for k, v in (("changed", changed), ("added", added),
                                            ("removed", removed)) if v]
    first = (changed or added or removed)[0]
    return f"its input files differ from when it was built ({', '.join(parts)}; e.g. {first})"


def _unusable(build: Path, params: WlaslLexParams, fingerprint: dict[str, list]) -> str | None:
    """Why the finished build in ``build`` cannot be reused (None: it can)."""
    manifest_path = build / MANIFEST
    if not manifest_path.is_file():
        return f"it has no {MANIFEST} (an unfinished build)"
    try:
        manifest = json.loads(manifest_path.read_text(encoding="utf-8"))
    except ValueError as error:
        return f"its {MANIFEST} is not JSON ({error})"
    if manifest.get("format_version") != FORMAT_VERSION or manifest.get("params") != params.to_dict():
        return "its manifest parameters differ from the request"
    return _stale_inputs(build, fingerprint)


def _recorded_warnings(build: Path) -> list[str]:
    """The warnings a build recorded in its manifest (said again each time it is reused)."""
    try:
        warnings = json.loads((build / MANIFEST).read_text(encoding="utf-8")).get("warnings") or []
    except (OSError, ValueError, AttributeError):
        return []
    return [str(w) for w in warnings] if isinstance(warnings, list) else []


def _publish(staging: Path, final: Path, params: WlaslLexParams, fingerprint: dict[str, list]) -> None:
    """Rename the finished build ``staging`` to ``final`` in one step. A build found there that
    is usable (another process's, finished meanwhile) stays and ours is discarded; a stale one is
    first renamed aside, then deleted. Readers (:func:`_pinned`) read the old build or the new one,
    never half of one or a mix."""
    aside = None
    if final.exists():
        try:
            with _pinned(final) as current:
                if _unusable(current, params, fingerprint) is None:
                    return  # another process's fresh build won: keep it (the caller drops ours)
        except OSError:  # gone meanwhile, or not a folder: renamed aside below like a stale one
            pass
        aside = final.with_name(f".{final.name}.old.{os.getpid()}.{secrets.token_hex(4)}")
        try:
            os.rename(final, aside)
        except FileNotFoundError:
            aside = None  # another process moved it aside already
    try:
        os.rename(staging, final)
    except OSError as error:  # another process's build took the place between the two renames
        if error.errno not in (errno.ENOTEMPTY, errno.EEXIST):
            raise
    finally:
        if aside is not None:
            shutil.rmtree(aside, ignore_errors=True)


def build_or_load(
    cache_dir: str | Path,
    params: WlaslLexParams | None = None,
    *,
    root: str | Path | None = None,
    strict: bool = False,
) -> tuple[RecognitionDataset, Path]:
    """Reuse the finished build for these parameters under ``cache_dir``, or build it.

    A build is reused when its parameters match and every input file has the content it was
    built from (:func:`input_fingerprint`). Otherwise it is built in a temporary folder beside
    the target and renamed into place only once complete (manifest written last, see
    :func:`_publish`): an interrupted build is never read, and two processes rebuilding one stale
    build at once both succeed (a fresh build found in place stays). Returns the dataset and its
    folder.
    """
    params = params or WlaslLexParams()
    cache_dir = Path(cache_dir)
    key = cache_key(params, root)
    final = cache_dir / f"wlasl_lex-{params.lexicon}-{params.property}-{params.split}-{key}"
    # Taken before the build reads anything: a file changed during the build shows next time.
    fingerprint = input_fingerprint(params, root)
    why: str | None = None
    for attempt in range(3):
        try:
            with _pinned(final) as build:
                why = _unusable(build, params, fingerprint)
                if why is None:
                    dataset = _load_wlasl_lex(build, final)
                    log.info("reusing WLASL-Lex build %s", final)
                    for line in _recorded_warnings(build):
                        log.warning("%s (found when this build was made)", line)
                    return dataset, final
        except FileNotFoundError as error:
            if not final.exists():
                why = None  # no build yet: build it, quietly
                break
            # Another process moved the build aside while we read it: read what is there now.
            why = f"it could not be read ({error})"
            time.sleep(0.05 * (attempt + 1))
            continue
        except (OSError, ValueError, KeyError, IndexError) as error:
            why = f"it could not be read ({type(error).__name__}: {error})"
        break
    if why is not None:
        log.warning("WLASL-Lex build %s is stale: %s; rebuilding", final, why)
    cache_dir.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{final.name}.", dir=cache_dir))
    try:
        dataset = build_wlasl_lex(staging, params, root=root, strict=strict)
        _write_json(staging / INPUTS, {"files": fingerprint})
        _publish(staging, final, params, fingerprint)
    finally:
        if staging.exists():
            shutil.rmtree(staging, ignore_errors=True)
    return dataset, final
