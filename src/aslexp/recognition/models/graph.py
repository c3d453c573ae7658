"""Skeleton adjacency with the ST-GCN spatial partition (Yan et al., AAAI 2018).

Convention here: ``A[k, i, j]`` is the weight with which node ``j`` feeds node ``i``'s output in
partition ``k`` (rows receive). Partitions, by hop distance ``d(.)`` from ``layout.center``:

    0 'self':    the root node itself, plus neighbours as far from the centre as the root
                 (the reference implementation puts equal-distance neighbours here, too)
    1 'closer':  neighbours closer to the centre than the root   (centripetal)
    2 'farther': neighbours farther from the centre than the root (centrifugal)

Nodes unreachable from the centre count as infinitely far. The weights are the row-normalised
``D^-1 (A + I)`` split across partitions, so for every node the partitions' row sums add up to 1
(mean aggregation over the node and its neighbours).
"""

from __future__ import annotations

import numpy as np

from aslexp.data.dataset import KeypointLayout

PARTITIONS = ("self", "closer", "farther")


def hop_distances(num_nodes: int, edges: tuple[tuple[int, int], ...] | list, source: int) -> np.ndarray:
    """Breadth-first hop distance from ``source`` to every node (inf where unreachable)."""
    neighbours: list[list[int]] = [[] for _ in range(num_nodes)]
    for i, j in edges:
        neighbours[i].append(j)
        neighbours[j].append(i)
    distance = np.full(num_nodes, np.inf)
    distance[source] = 0
    frontier = [source]
    while frontier:
        next_frontier = []
        for node in frontier:
            for other in neighbours[node]:
                if np.isinf(distance[other]):
                    distance[other] = distance[node] + 1
                    next_frontier.append(other)
        frontier = next_frontier
    return distance


def spatial_partition_adjacency(layout: KeypointLayout) -> np.ndarray:
    """(3, V, V) float32 adjacency of ``layout`` with the spatial partition (see module doc)."""
    num_nodes = layout.num_nodes
    for i, j in layout.edges:
        if not (0 <= i < num_nodes and 0 <= j < num_nodes) or i == j:
            raise ValueError(f"layout '{layout.name}': bad edge ({i}, {j}) for {num_nodes} nodes")
    if not 0 <= layout.center < num_nodes:
        raise ValueError(f"layout '{layout.name}': center {layout.center} is not a node index (0..{num_nodes - 1})")

    connected = np.eye(num_nodes, dtype=np.float64)
    for i, j in layout.edges:
        connected[i, j] = connected[j, i] = 1.0
    normalised = connected / connected.sum(axis=1, keepdims=True)

    distance = hop_distances(num_nodes, layout.edges, layout.center)
    root = distance[:, None]  # d(i), the receiving node
    neighbour = distance[None, :]  # d(j)
    # inf == inf counts as equal (both unreachable): no NaNs from inf - inf.
    same = (root == neighbour) | (np.isinf(root) & np.isinf(neighbour))
    closer = ~same & (neighbour < root)
    farther = ~same & (neighbour > root)
    adjacency = np.stack([normalised * same, normalised * closer, normalised * farther])
    return adjacency.astype(np.float32)
