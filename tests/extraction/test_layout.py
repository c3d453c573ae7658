"""The holistic keypoint layout and its subsets, as the recognition data layer reads them."""

from __future__ import annotations

import json

import pytest

from aslexp.keypoints import read_layout
from aslexp.keypoints import holistic as H
from aslexp.pose.extract import write_layout_json


def _connected(num_nodes: int, edges) -> bool:
    neighbours = {i: set() for i in range(num_nodes)}
    for i, j in edges:
        neighbours[i].add(j)
        neighbours[j].add(i)
    seen, stack = {0}, [0]
    while stack:
        for n in neighbours[stack.pop()] - seen:
            seen.add(n)
            stack.append(n)
    return len(seen) == num_nodes


def test_full_layout_names_edges_and_centre():
    layout = H.holistic_layout("all")
    assert len(layout["names"]) == 75 == len(set(layout["names"]))
    assert layout["names"][H.LEFT_HAND_OFFSET] == "left_hand_wrist"
    assert layout["names"][H.RIGHT_HAND_OFFSET + 20] == "right_hand_pinky_tip"
    assert layout["names"][layout["center"]] == "nose"
    assert all(0 <= i < 75 and 0 <= j < 75 and i != j for i, j in layout["edges"])
    assert _connected(75, layout["edges"])


@pytest.mark.parametrize("name, size", [("all", 75), ("upper_body", 61)])
def test_subsets_are_connected_skeletons(name, size):
    indices = H.holistic_subset(name)
    layout = H.holistic_layout(name)
    assert len(indices) == len(set(indices)) == size == len(layout["names"])
    assert layout["names"] == [H.NAMES[i] for i in indices]
    assert _connected(size, layout["edges"])


def test_unknown_subset_is_a_clear_error():
    with pytest.raises(ValueError, match="upper_body"):
        H.holistic_subset("thesis")


def test_layout_json_is_read_by_the_data_layer(tmp_path):
    path = write_layout_json(tmp_path)
    layout = read_layout(path)  # the recognition data layer's own reader
    assert layout.name == "mediapipe_holistic" and layout.num_nodes == 75
    assert layout.channels == ("x", "y", "z", "visibility")
    raw = json.loads(path.read_text())
    assert raw["subsets"]["upper_body"]["indices"] == H.holistic_subset("upper_body")
