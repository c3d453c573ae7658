"""The registry of keypoint layouts and keypoint sources (a layout's named subsets are kept by
:mod:`aslexp.keypoints.subsets`, below both this registry and the sources).

A new keypoint format is a registration, not a patch::

    from aslexp.keypoints import KeypointLayout, register_layout, register_source

    register_layout(KeypointLayout(name="openpose_body25", names=(...), edges=(...),
                                   channels=("x", "y", "score")), subsets={"arms": (1, 2, 3, ...)})

    @register_source("my_format", summary="<dir>/<id>.json from my tracker")
    def open_my_format(path, **options) -> KeypointSource: ...

or, for arrays, no code at all: the ``array_folder`` source reads ``(T, V*C)`` or ``(T, V, C)``
``.npy`` files with a layout given in YAML (``conf/pose/mediapipe_hands.yaml``).

Installed packages can register too, through the entry-point group ``aslexp.keypoints``: each
entry point names a module (imported) or a callable (called without arguments) that makes its
registrations; they are loaded the first time a name is not found or the names are listed.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

from aslexp.errors import DataError
from aslexp.keypoints.layout import KeypointLayout
from aslexp.keypoints.source import KeypointSource
from aslexp.keypoints.subsets import register_subsets
from aslexp.plugins import load_entry_points


ENTRY_POINT_GROUP = "aslexp.keypoints"

_LAYOUTS: dict[str, KeypointLayout] = {}
_SOURCES: dict[str, SourceSpec] = {}


@dataclass(frozen=True)
class SourceSpec:
    """How to open one kind of keypoint source.

    ``factory(path, **options)`` returns a :class:`~aslexp.keypoints.source.KeypointSource`.
    ``default_path`` (relative to the data root) is used when no path is given; None means the
    source needs a path.
    """

    name: str
    factory: Callable[..., KeypointSource]
    default_path: str | None = None
    summary: str = ""


def _load_entry_points() -> None:
    load_entry_points(ENTRY_POINT_GROUP, "keypoint")


# ----------------------------------------------------------------------------- layouts


def register_layout(layout: KeypointLayout, subsets: dict[str, tuple[int, ...]] | None = None,
                    *, replace: bool = False) -> KeypointLayout:  # fmt: skip
    """Make ``layout`` known by its name (and its named node subsets); returns it.

    Registering an equal layout again is a no-op; a different layout under a taken name is an
    error unless ``replace``.
    """
    known = _LAYOUTS.get(layout.name)
    if known is not None and known != layout and not replace:
        raise DataError(f"keypoint layout {layout.name!r} is already registered with other nodes or "
                        "edges; choose another name or pass replace=True")  # fmt: skip
    _LAYOUTS[layout.name] = layout
    if subsets:
        register_subsets(layout.name, subsets, num_nodes=layout.num_nodes)
    return layout


def get_layout(name: str) -> KeypointLayout:
    if name not in _LAYOUTS:
        _load_entry_points()
    try:
        return _LAYOUTS[name]
    except KeyError:
        raise DataError(f"unknown keypoint layout {name!r}; expected one of {layout_names()}") from None


def resolve_layout(layout: KeypointLayout | str | Mapping[str, Any], origin: str) -> KeypointLayout:
    """A layout given as an object, a registered name or an inline mapping (from YAML or JSON)."""
    if isinstance(layout, KeypointLayout):
        return layout
    if isinstance(layout, str):
        return get_layout(layout)
    if isinstance(layout, Mapping):
        return KeypointLayout.from_spec(layout, origin)
    raise DataError(f"{origin}: layout = {layout!r}; expected a registered layout name or a mapping "
                    "{name, nodes, edges, center, channels}")  # fmt: skip


def layout_names() -> list[str]:
    _load_entry_points()
    return sorted(_LAYOUTS)


# ----------------------------------------------------------------------------- sources


def register_source(name: str, factory: Callable[..., Any] | None = None, *, default_path: str | None = None,
                    summary: str = "", replace: bool = False):  # fmt: skip
    """Register a keypoint source kind; usable as ``register_source(name, factory)`` or as a
    decorator ``@register_source(name)``. Returns the factory."""

    def add(func: Callable[..., Any]) -> Callable[..., Any]:
        known = _SOURCES.get(name)
        if known is not None and known.factory is not func and not replace:
            raise DataError(f"keypoint source {name!r} is already registered; pass replace=True")
        _SOURCES[name] = SourceSpec(name, func, default_path, summary or (func.__doc__ or "").strip().split("\n")[0])
        return func

    return add(factory) if factory is not None else add


def get_source(name: str) -> SourceSpec:
    if name not in _SOURCES:
        _load_entry_points()
    try:
        return _SOURCES[name]
    except KeyError:
        raise DataError(f"unknown keypoint source {name!r}; expected one of {source_names()}") from None


def source_names() -> list[str]:
    _load_entry_points()
    return sorted(_SOURCES)


def open_source(kind: str, path: str | None = None, **options: Any) -> KeypointSource:
    """Open a registered source on ``path`` (a folder or a file) with its options."""
    spec = get_source(kind)
    if path is None:
        raise DataError(f"keypoint source {kind!r} needs a path (pose.path=...)")
    try:  # an option the source does not take is the user's mistake: say which
        inspect.signature(spec.factory).bind(path, **options)
    except TypeError as error:
        raise DataError(f"keypoint source {kind!r}: options {sorted(options)} do not fit ({error})") from None
    return spec.factory(path, **options)
