"""What a keypoint array means: node names, skeleton edges, centre node, channel names.

A layout is plain data. :meth:`KeypointLayout.from_spec` reads one from a mapping, the same for a
``layout.json`` beside a folder of arrays and for a ``conf/pose/*.yaml`` entry, so a new keypoint
format is a few lines of configuration::

    name: my_hands
    nodes: [wrist, thumb_tip, index_tip]     # names, or a count (node_0, node_1, ...)
    edges: [[wrist, thumb_tip], [0, 2]]      # pairs of names or of indices
    center: wrist                            # a name or an index (default 0)
    channels: [x, y, z]
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

from aslexp.errors import DataError


@dataclass(frozen=True)
class KeypointLayout:
    """A named set of keypoints and the skeleton graph over them.

    ``edges`` are undirected (i, j) index pairs into ``names``; ``center`` is the node the
    ST-GCN spatial partition measures distances from. ``channels`` names the last axis of the
    keypoint arrays (e.g. ``("x", "y", "z", "visibility")``); empty when not known.
    """

    name: str
    names: tuple[str, ...]
    edges: tuple[tuple[int, int], ...]
    center: int = 0
    channels: tuple[str, ...] = ()

    @property
    def num_nodes(self) -> int:
        return len(self.names)

    def to_spec(self) -> dict[str, Any]:
        """The layout as plain JSON/YAML data (the keys :meth:`from_spec` reads)."""
        return {"name": self.name, "names": list(self.names), "edges": [list(e) for e in self.edges],
                "center": self.center, "channels": list(self.channels)}  # fmt: skip

    @classmethod
    def from_spec(cls, spec: Mapping[str, Any], origin: str = "layout") -> KeypointLayout:
        """A layout from a mapping with ``name``, ``names`` (or ``nodes``: names or a count),
        ``edges`` (index or name pairs), ``center`` (index or name) and ``channels``.

        Any mistake is a :class:`DataError` naming ``origin``, the field and what was expected.
        """
        if not isinstance(spec, Mapping):
            raise DataError(f"{origin}: expected a mapping with name, nodes, edges, center, channels; "
                            f"got {type(spec).__name__}")  # fmt: skip
        nodes = spec.get("names", spec.get("nodes"))
        if isinstance(nodes, int) and not isinstance(nodes, bool) and nodes > 0:
            names = tuple(f"node_{i}" for i in range(nodes))
        elif isinstance(nodes, (list, tuple)) and nodes and all(isinstance(n, str) for n in nodes):
            names = tuple(nodes)
        else:
            raise DataError(f"{origin}: field 'nodes' (or 'names') = {nodes!r}; expected a list of node "
                            "names or a positive node count")  # fmt: skip
        if len(set(names)) != len(names):
            raise DataError(f"{origin}: field 'nodes' repeats a name: "
                            f"{sorted({n for n in names if names.count(n) > 1})}")  # fmt: skip
        index = {n: i for i, n in enumerate(names)}

        def node(value, field: str) -> int:
            if isinstance(value, str) and value in index:
                return index[value]
            if isinstance(value, int) and not isinstance(value, bool) and 0 <= value < len(names):
                return value
            raise DataError(f"{origin}: field {field!r} refers to node {value!r}; expected a node name "
                            f"or an index in 0..{len(names) - 1}")  # fmt: skip

        raw_edges = spec.get("edges") or []
        if not isinstance(raw_edges, (list, tuple)):
            raise DataError(f"{origin}: field 'edges' = {raw_edges!r}; expected a list of [i, j] pairs")
        edges = []
        for edge in raw_edges:
            if not isinstance(edge, (list, tuple)) or len(edge) != 2:
                raise DataError(f"{origin}: field 'edges' has {edge!r}; expected a pair [i, j]")
            i, j = node(edge[0], "edges"), node(edge[1], "edges")
            if i == j:
                raise DataError(f"{origin}: field 'edges' has a self-loop {list(edge)}")
            edges.append((i, j))
        channels = spec.get("channels")
        if not isinstance(channels, (list, tuple)) or not channels or not all(isinstance(c, str) for c in channels):
            raise DataError(f"{origin}: field 'channels' = {channels!r}; expected a list of channel "
                            "names, e.g. [x, y, z]")  # fmt: skip
        name = spec.get("name")
        if not isinstance(name, str) or not name:
            raise DataError(f"{origin}: field 'name' = {name!r}; expected a non-empty string")
        return cls(name=name, names=names, edges=tuple(edges), center=node(spec.get("center", 0), "center"),
                   channels=tuple(channels))  # fmt: skip


def generic_layout(num_nodes: int, channels: Iterable[str], name: str = "generic") -> KeypointLayout:
    """A layout without a skeleton (no edges), for arrays whose node order is not known here."""
    return KeypointLayout(name=name, names=tuple(f"node_{i}" for i in range(num_nodes)),
                          edges=(), center=0, channels=tuple(channels))  # fmt: skip


def induced_edges(edges, keep: tuple[int, ...]) -> tuple[tuple[int, int], ...]:
    """Edges among ``keep`` (re-indexed 0..len(keep)-1), contracting paths through dropped nodes."""
    position = {node: i for i, node in enumerate(keep)}
    neighbours: dict[int, set[int]] = {}
    for i, j in edges:
        neighbours.setdefault(i, set()).add(j)
        neighbours.setdefault(j, set()).add(i)
    result = set()
    for start in keep:
        seen, queue = {start}, deque(neighbours.get(start, ()))
        while queue:
            node = queue.popleft()
            if node in seen:
                continue
            seen.add(node)
            if node in position:
                a, b = sorted((position[start], position[node]))
                result.add((a, b))
            else:  # a dropped node: walk through it
                queue.extend(neighbours.get(node, ()))
    return tuple(sorted(result))


def restrict(layout: KeypointLayout, keep: tuple[int, ...], name: str) -> KeypointLayout:
    """``layout`` on the nodes ``keep`` only (edges contracted through dropped nodes)."""
    center = keep.index(layout.center) if layout.center in keep else 0
    return KeypointLayout(name=name, names=tuple(layout.names[i] for i in keep),
                          edges=induced_edges(layout.edges, keep), center=center,
                          channels=layout.channels)  # fmt: skip
