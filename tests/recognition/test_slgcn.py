"""SL-GCN against the authors' construction, DropGraph, its schedule, and the 27-point layout."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from recognition_data import TINY_PARAMS

from aslexp.data.dataset import KeypointLayout
from aslexp.keypoints import slgcn27
from aslexp.keypoints.holistic import holistic_layout
from aslexp.keypoints import MEDIAPIPE_POSE, subset_layout
from aslexp.recognition.models import DEFAULT_PARAMS, build_classifier
from aslexp.recognition.models.slgcn import DropGraphSpatial, DropGraphTemporal, spatial_graph
from aslexp.recognition.train import ArraySplit, fit

# SL-GCN's sign_27 graph exactly as jackyjsy/CVPR21Chal-SLR SL-GCN/graph/sign_27.py lists it
# (COCO-WholeBody-based numbering, minus 5 in the code).
AUTHORS_INWARD = [(5, 6), (5, 7), (6, 8), (8, 10), (7, 9), (9, 11), (12, 13), (12, 14), (12, 16), (12, 18), (12, 20),
                  (14, 15), (16, 17), (18, 19), (20, 21), (22, 23), (22, 24), (22, 26), (22, 28), (22, 30), (24, 25),
                  (26, 27), (28, 29), (30, 31), (10, 12), (11, 22)]  # fmt: skip


def _authors_graph(num_node: int, inward: list[tuple[int, int]]) -> np.ndarray:
    """graph/tools.py get_spatial_graph, written out as the authors do."""

    def edge2mat(link):
        A = np.zeros((num_node, num_node))
        for i, j in link:
            A[j, i] = 1
        return A

    def normalize_digraph(A):
        Dl = np.sum(A, 0)
        Dn = np.zeros((num_node, num_node))
        for i in range(num_node):
            if Dl[i] > 0:
                Dn[i, i] = Dl[i] ** (-1)
        return np.dot(A, Dn)

    outward = [(j, i) for (i, j) in inward]
    return np.stack((edge2mat([(i, i) for i in range(num_node)]), normalize_digraph(edge2mat(inward)),
                     normalize_digraph(edge2mat(outward))))  # fmt: skip


def test_graph_equals_the_authors_sign_27_graph():
    expected = _authors_graph(27, [(i - 5, j - 5) for i, j in AUTHORS_INWARD])
    np.testing.assert_allclose(spatial_graph(slgcn27.SIGN27), expected, atol=1e-7)
    # Listed in another order and direction, the orientation from the centre restores it.
    shuffled = KeypointLayout("shuffled", slgcn27.NAMES, tuple((j, i) for i, j in reversed(slgcn27.EDGES)), center=0)
    np.testing.assert_allclose(spatial_graph(shuffled), expected, atol=1e-7)


def test_the_27_points_on_pose_holistic_and_hrnet():
    pose, indices = subset_layout(MEDIAPIPE_POSE, "slgcn27")
    coverage = slgcn27.coverage("mediapipe_pose")
    assert len(coverage["exact"]) == 7 and len(coverage["approximate"]) == 6
    assert len(coverage["missing"]) == 12 and coverage["duplicate"] == ["left_hand_root", "right_hand_root"]
    assert pose.num_nodes == 13 and pose.name == "mediapipe_pose_slgcn27"
    assert [MEDIAPIPE_POSE.names[i] for i in indices] == [
        "nose", "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
        "left_thumb", "left_index", "left_pinky", "right_thumb", "right_index", "right_pinky"]  # fmt: skip
    # The hand points hang from the wrist once the hand root (= the wrist in Pose) is contracted away.
    names = pose.names
    edges = {(names[i], names[j]) for i, j in pose.edges}
    assert ("left_wrist", "left_hand_index_mcp") in edges and ("right_wrist", "right_hand_thumb_tip") in edges
    assert len(pose.edges) == pose.num_nodes - 1  # still a tree rooted at the nose

    raw = holistic_layout("all")
    holistic = KeypointLayout(raw["name"], tuple(raw["names"]), tuple(map(tuple, raw["edges"])), raw["center"], ("x", "y"))
    full, hand_indices = subset_layout(holistic, "slgcn27")
    assert full.num_nodes == 27 and set(full.edges) == set(slgcn27.EDGES)
    assert holistic.names[hand_indices[7]] == "left_hand_wrist" and holistic.names[hand_indices[26]] == "right_hand_pinky_tip"
    same, identity = subset_layout(slgcn27.SIGN27, "slgcn27")
    assert identity == tuple(range(27)) and set(same.edges) == set(slgcn27.EDGES)


def test_dropgraph_drops_whole_joints_and_blocks_of_frames():
    torch.manual_seed(0)
    adjacency = torch.from_numpy(spatial_graph(slgcn27.SIGN27).sum(axis=0))
    x = torch.rand(8, 4, 30, 27) + 0.1
    spatial, temporal = DropGraphSpatial(adjacency), DropGraphTemporal(block_size=5)
    for module in (spatial, temporal):
        module.eval()
        assert torch.equal(module(x, 0.5), x)  # identity at test time
        module.train()
        assert torch.equal(module(x, 1.0), x)  # and while keep_prob is 1
    dropped = spatial(x, 0.5)
    zero_joints = (dropped == 0).all(dim=1).all(dim=1)  # (N, V): a joint goes all channels and frames
    assert zero_joints.any() and ((dropped == 0) == zero_joints[:, None, None, :]).all()
    kept = ~zero_joints[:, None, None, :].expand_as(x)
    expected = x.shape[0] * 27 / float((~zero_joints).sum())  # the kept joints are rescaled to keep the mean
    torch.testing.assert_close(dropped[kept] / x[kept], torch.full_like(x[kept], expected))
    blocks = temporal(x, 0.5)
    zero_frames = (blocks == 0).all(dim=1).all(dim=2)  # (N, T)
    assert zero_frames.any() and ((blocks == 0) == zero_frames[:, None, :, None]).all()


def test_schedule_keep_prob_and_frozen_graph(gloss_dataset):
    model = build_classifier("slgcn", {}, 3, 24, 33, 4, gloss_dataset.layout)
    module = model.module
    assert model.spec.params == DEFAULT_PARAMS["slgcn"]
    assert [block.tcn.conv.out_channels for block in module.blocks] == [64, 64, 64, 64, 128, 128, 128, 256, 256, 256]
    assert [block.tcn.conv.stride[0] for block in module.blocks] == [1, 1, 1, 1, 2, 1, 1, 2, 1, 1]
    module.on_epoch_start(0)
    assert module.keep_prob == 1.0 and not module.blocks[0].gcn.decoupled_adjacency.requires_grad
    module.on_epoch_start(50)
    assert module.keep_prob == pytest.approx(0.95) and module.blocks[0].gcn.decoupled_adjacency.requires_grad
    module.on_epoch_start(140)
    assert module.keep_prob == pytest.approx(0.9)
    # Groups: channel c of a block uses group c mod 16's adjacency, each column normalised.
    adjacency = module.blocks[4].gcn.normalised_adjacency()
    assert adjacency.shape == (3, 128, 33, 33)
    torch.testing.assert_close(adjacency[:, 3], adjacency[:, 3 + 16])
    with pytest.raises(ValueError, match="not a multiple of groups"):
        build_classifier("slgcn", {"channels": [24]}, 3, 24, 33, 4, gloss_dataset.layout)


def test_slgcn_learns_on_real_keypoints(gloss_dataset):
    data = gloss_dataset
    train, val = (ArraySplit.from_dataset(data, data.splits[s]) for s in ("train", "val"))
    torch.manual_seed(0)
    model = build_classifier("slgcn", TINY_PARAMS["slgcn"], 3, data.X.shape[2], data.X.shape[3], data.num_classes, data.layout)
    trainer = {"optimizer": "sgd", "nesterov": True, "lr": 0.05, "batch_size": 16, "max_epochs": 6, "patience": 10,
               "num_threads": 1, "crop_window": 16, "shift": 0.05}  # fmt: skip
    result = fit(model, train, val, trainer)
    losses = [row["train_loss"] for row in result.history]
    assert all(np.isfinite(losses)) and min(losses[3:]) < losses[0]
    assert model.module.keep_prob < 1.0  # DropGraph was on from epoch 2 (drop_from_block 1)
    proba = model.predict_proba(val.X, val.mask)  # full-length clips at test time (no crop)
    np.testing.assert_allclose(proba.sum(axis=1), 1.0, rtol=1e-5)
