"""Named node subsets of keypoint layouts: ``all``, the subsets a layout offers, and subsets with
a graph of their own (SL-GCN's 27 points, :mod:`aslexp.keypoints.slgcn27`).

Below both the registry (:mod:`aslexp.keypoints.registry`, which registers a layout's subsets with
the layout) and the sources (:class:`~aslexp.keypoints.source.SubsetSource`, a source restricted
to a subset): it imports only :mod:`aslexp.keypoints.layout` and :mod:`aslexp.errors`.
"""

from __future__ import annotations

from collections.abc import Callable

from aslexp.errors import DataError
from aslexp.keypoints.layout import KeypointLayout, restrict

_SUBSETS: dict[str, dict[str, tuple[int, ...]]] = {}
# Subsets with a graph of their own (not the layout's edges among the kept nodes): name ->
# (layouts it maps from, builder(layout) -> (restricted layout, kept indices)).
_SUBSET_BUILDERS: dict[str, tuple[frozenset[str], Callable[[KeypointLayout], tuple[KeypointLayout, tuple[int, ...]]]]] = {}


def register_subsets(layout_name: str, subsets: dict[str, tuple[int, ...]], num_nodes: int | None = None) -> None:
    """Offer named node subsets (indices into the layout) for a layout; 'all' always exists."""
    clean = {}
    for name, indices in subsets.items():
        if name == "all":
            continue
        indices = tuple(int(i) for i in indices)
        bad = [i for i in indices if i < 0 or (num_nodes is not None and i >= num_nodes)]
        if bad or len(set(indices)) != len(indices) or not indices:
            raise DataError(f"subset {name!r} of layout {layout_name!r}: indices {list(indices)} must be "
                            f"distinct node indices in 0..{(num_nodes or 1) - 1}")  # fmt: skip
        clean[name] = indices
    _SUBSETS.setdefault(layout_name, {}).update(clean)


def register_subset_builder(name: str, layouts, builder) -> None:
    """Offer subset ``name`` on each of ``layouts`` (names), built by ``builder(layout) ->
    (restricted layout, kept indices)``: for a target skeleton with its own graph, such as SL-GCN's
    27 points (:mod:`aslexp.keypoints.slgcn27`), which other layouts map onto."""
    _SUBSET_BUILDERS[name] = (frozenset(layouts), builder)


def subset_names(layout: KeypointLayout) -> tuple[str, ...]:
    """Names of the subsets offered for ``layout`` ('all' first)."""
    built = [s for s, (layouts, _) in _SUBSET_BUILDERS.items() if layout.name in layouts]
    return ("all", *[s for s in _SUBSETS.get(layout.name, {}) if s != "all"], *built)


def subset_indices(layout: KeypointLayout, subset: str | None) -> tuple[int, ...]:
    if subset in (None, "all"):
        return tuple(range(layout.num_nodes))
    if subset in _SUBSET_BUILDERS and layout.name in _SUBSET_BUILDERS[subset][0]:
        return _SUBSET_BUILDERS[subset][1](layout)[1]
    options = _SUBSETS.get(layout.name, {})
    if subset not in options:
        # The whole fix in one line: the data layer checks pose.channels after the subset, so a
        # layout from elsewhere (a .pose header) names its channels here too.
        raise DataError(f"layout {layout.name!r} ({layout.num_nodes} nodes, channels "
                        f"{', '.join(layout.channels) or 'unknown'}) has no keypoint subset {subset!r}; expected "
                        f"one of {list(subset_names(layout))}: set pose.subset=all to keep every node (and "
                        "pose.channels to some of its channels, or null for all)")  # fmt: skip
    return options[subset]


def subset_layout(layout: KeypointLayout, subset: str | None) -> tuple[KeypointLayout, tuple[int, ...]]:
    """The layout restricted to a named subset, and the kept node indices into ``layout``."""
    if subset in _SUBSET_BUILDERS and layout.name in _SUBSET_BUILDERS[subset][0]:
        return _SUBSET_BUILDERS[subset][1](layout)
    keep = subset_indices(layout, subset)
    if subset in (None, "all"):
        return layout, keep
    return restrict(layout, keep, f"{layout.name}_{subset}"), keep
