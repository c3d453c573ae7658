"""WLASL v0.3: glosses and their video instances, and the nslt WLASL100/300/1000/2000 subsets."""

from __future__ import annotations

import json
import logging
from dataclasses import dataclass
from pathlib import Path

from aslexp.data.dataset import DataError
from aslexp.data.root import resolve_data_root

log = logging.getLogger(__name__)

WLASL_JSON = "wlasl/WLASL_v0.3.json"
NSLT_SIZES = (100, 300, 1000, 2000)
CLASS_LIST = "wlasl/wlasl_class_list.txt"
SPLITS = ("train", "val", "test")


@dataclass(frozen=True)
class WlaslInstance:
    """One video instance. ``frame_end`` = -1 means "to the end of the video"."""

    gloss: str
    video_id: str
    split: str
    signer_id: int
    fps: int
    frame_start: int
    frame_end: int
    bbox: tuple[int, ...]
    url: str
    instance_id: int
    variation_id: int
    source: str = ""


@dataclass(frozen=True)
class Wlasl:
    glosses: tuple[str, ...]  # in file order (= the WLASL2000 class order)
    instances: tuple[WlaslInstance, ...]

    def by_video_id(self) -> dict[str, WlaslInstance]:
        return {instance.video_id: instance for instance in self.instances}

    def by_gloss(self) -> dict[str, list[WlaslInstance]]:
        groups: dict[str, list[WlaslInstance]] = {gloss: [] for gloss in self.glosses}
        for instance in self.instances:
            groups[instance.gloss].append(instance)
        return groups


_INSTANCE_FIELDS = ("video_id", "split", "signer_id", "fps", "frame_start", "frame_end",
                    "bbox", "url", "instance_id", "variation_id")  # fmt: skip


def load_wlasl(root: str | Path | None = None, *, path: str | Path | None = None) -> Wlasl:
    """Read ``WLASL_v0.3.json`` (a list of ``{"gloss", "instances": [...]}``)."""
    json_path = Path(path) if path is not None else resolve_data_root(root) / WLASL_JSON
    entries = _read_json(json_path)
    if not isinstance(entries, list):
        raise DataError(f"{json_path}: expected a JSON list of gloss entries, got {type(entries).__name__}")
    glosses, instances, seen = [], [], set()
    for position, entry in enumerate(entries):
        gloss = entry.get("gloss") if isinstance(entry, dict) else None
        if not isinstance(gloss, str) or not isinstance(entry.get("instances"), list):
            raise DataError(f"{json_path}: entry {position} needs 'gloss' (str) and 'instances' (list)")
        glosses.append(gloss)
        for raw in entry["instances"]:
            absent = [key for key in _INSTANCE_FIELDS if key not in raw]
            if absent:
                raise DataError(f"{json_path}: gloss {gloss!r}, instance {raw.get('video_id')!r}: "
                                f"missing field(s) {absent}")  # fmt: skip
            if raw["split"] not in SPLITS:
                raise DataError(f"{json_path}: video {raw['video_id']!r}: split {raw['split']!r}, "
                                f"expected one of {SPLITS}")  # fmt: skip
            video_id = str(raw["video_id"])
            if video_id in seen:
                raise DataError(f"{json_path}: duplicate video_id {video_id!r} (gloss {gloss!r})")
            seen.add(video_id)
            instances.append(WlaslInstance(
                gloss=gloss, video_id=video_id, split=raw["split"],
                signer_id=int(raw["signer_id"]), fps=int(raw["fps"]),
                frame_start=int(raw["frame_start"]), frame_end=int(raw["frame_end"]),
                bbox=tuple(int(v) for v in raw["bbox"]), url=str(raw["url"]),
                instance_id=int(raw["instance_id"]), variation_id=int(raw["variation_id"]),
                source=str(raw.get("source", "")),
            ))  # fmt: skip
    log.info("WLASL: %d glosses, %d instances from %s", len(glosses), len(instances), json_path)
    return Wlasl(glosses=tuple(glosses), instances=tuple(instances))


@dataclass(frozen=True)
class NsltItem:
    subset: str  # train | val | test
    label: int  # class index into the class list
    start: int
    end: int


def load_nslt(size: int, root: str | Path | None = None) -> dict[str, NsltItem]:
    """Read ``wlasl/nslt/nslt_<size>.json``: ``{video_id: NsltItem}``."""
    if size not in NSLT_SIZES:
        raise DataError(f"unknown WLASL subset size {size}; expected one of {NSLT_SIZES}")
    json_path = resolve_data_root(root) / f"wlasl/nslt/nslt_{size}.json"
    raw = _read_json(json_path)
    items = {}
    for video_id, item in raw.items():
        try:
            label, start, end = item["action"]
            items[video_id] = NsltItem(item["subset"], int(label), int(start), int(end))
        except (KeyError, TypeError, ValueError):
            expected = '{"subset": str, "action": [class, start, end]}'
            raise DataError(f"{json_path}: video {video_id!r}: expected {expected}, got {item!r}") from None
    return items


def load_class_list(root: str | Path | None = None) -> list[str]:
    """Read ``wlasl_class_list.txt`` (``<index>\\t<gloss>`` lines) as a list indexed by class."""
    path = resolve_data_root(root) / CLASS_LIST
    if not path.is_file():
        raise FileNotFoundError(f"WLASL class list not found: {path}")
    classes = []
    for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
        if not line.strip():
            continue
        index, _, gloss = line.partition("\t")
        if not index.strip().isdigit() or int(index) != len(classes):
            raise DataError(f"{path}: line {number}: expected '<{len(classes)}>\\t<gloss>', got {line!r}")
        classes.append(gloss.strip())
    return classes


def _read_json(path: Path):
    if not path.is_file():
        raise FileNotFoundError(f"WLASL file not found: {path}")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as error:
        raise DataError(f"{path}: invalid JSON: {error}") from None
