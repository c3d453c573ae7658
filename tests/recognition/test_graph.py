"""ST-GCN adjacency with the spatial partition, from a layout."""

from __future__ import annotations

import numpy as np
import pytest
from recognition_data import POSE_LAYOUT

from aslexp.data.dataset import KeypointLayout
from aslexp.recognition.models import spatial_partition_adjacency
from aslexp.recognition.models.graph import hop_distances

# 0 - 1 - 2 - 3, and 1 - 4; centre 1.
CHAIN = KeypointLayout("chain", ("a", "b", "c", "d", "e"), ((0, 1), (1, 2), (2, 3), (1, 4)), center=1)


def test_chain_partitions_by_distance_to_centre():
    A = spatial_partition_adjacency(CHAIN)
    assert A.shape == (3, 5, 5)
    self_part, closer, farther = A
    # Row-normalised D^-1 (A + I): node 1 has 3 neighbours + itself -> 1/4 each.
    np.testing.assert_allclose(A.sum(axis=0).sum(axis=1), 1.0)
    np.testing.assert_allclose(np.diag(self_part), [1 / 2, 1 / 4, 1 / 3, 1 / 2, 1 / 2])
    # The centre receives only from farther neighbours (0, 2, 4).
    np.testing.assert_allclose(farther[1], [1 / 4, 0, 1 / 4, 0, 1 / 4])
    assert closer[1].sum() == 0
    # Node 3 (distance 2) receives from node 2 (distance 1), which is closer to the centre.
    np.testing.assert_allclose(closer[3], [0, 0, 1 / 2, 0, 0])
    np.testing.assert_allclose(farther[2], [0, 0, 0, 1 / 3, 0])


def test_pose_layout_partitions_are_disjoint_and_consistent():
    A = spatial_partition_adjacency(POSE_LAYOUT)
    V = POSE_LAYOUT.num_nodes
    np.testing.assert_allclose(A.sum(axis=0).sum(axis=1), np.ones(V), rtol=1e-6)
    assert ((A > 0).sum(axis=0) <= 1).all(), "an entry belongs to one partition only"
    distance = hop_distances(V, POSE_LAYOUT.edges, POSE_LAYOUT.center)
    for i, j in zip(*np.nonzero(A[1])):
        assert distance[j] < distance[i]
    for i, j in zip(*np.nonzero(A[2])):
        assert distance[j] > distance[i]
    # Every edge is present in exactly one partition, both directions.
    for i, j in POSE_LAYOUT.edges:
        assert A[:, i, j].sum() > 0 and A[:, j, i].sum() > 0
    # The face (0-10) is not connected to the body in MediaPipe's graph: unreachable nodes
    # only talk to each other through the 'self' partition.
    assert np.isinf(distance[:11]).all() and np.isfinite(distance[11:]).all()
    assert A[1:, :11].sum() == 0


def test_bad_layouts_are_rejected():
    with pytest.raises(ValueError, match="bad edge"):
        spatial_partition_adjacency(KeypointLayout("bad", ("a", "b"), ((0, 2),), center=0))
    with pytest.raises(ValueError, match="center 5"):
        spatial_partition_adjacency(KeypointLayout("bad", ("a", "b"), ((0, 1),), center=5))
