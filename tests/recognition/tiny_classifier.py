"""A test-only classifier registered from the tests, with no edit to aslexp: one linear layer over
the clip's per-joint means (``conf/classifier/tiny_linear.yaml`` names this module)."""

from __future__ import annotations

import torch

from aslexp.recognition.registry import register_classifier


class MeanLinear(torch.nn.Module):
    def __init__(self, inputs: int, classes: int, scale: float) -> None:
        super().__init__()
        self.scale = scale
        self.linear = torch.nn.Linear(inputs, classes)

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return self.linear(self.scale * x.mean(dim=2).flatten(1))  # (N, C, T, V): the mean over T


@register_classifier("tiny_linear", {"scale": 1.0}, summary="test only: a linear layer on joint means")
def build(spec):
    return MeanLinear(spec.num_channels * spec.num_nodes, spec.num_classes, float(spec.params["scale"]))
