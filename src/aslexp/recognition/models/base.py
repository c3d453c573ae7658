"""The one interface every recognition classifier shares, for torch and scikit-learn alike.

Inputs are the arrays of :class:`aslexp.data.dataset.RecognitionDataset`:
``X`` (N, C, T, V, 1) float32 in [-1, 1] (0 where missing) and ``mask`` (N, T, V) bool.
Every classifier answers ``predict_proba(X, mask) -> (N, num_classes)`` and ``predict``.
How a classifier learns differs: scikit-learn ones have ``fit``; torch ones expose ``module``
and are driven by :mod:`aslexp.recognition.train`.
"""

from __future__ import annotations

import logging
from abc import ABC, abstractmethod
from dataclasses import asdict, dataclass, field
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from aslexp.data.dataset import KeypointLayout

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ClassifierSpec:
    """Everything needed to build a classifier again (stored in checkpoints)."""

    name: str
    params: dict[str, Any]
    num_channels: int
    num_frames: int
    num_nodes: int
    num_classes: int
    layout: KeypointLayout | None = None

    def to_dict(self) -> dict[str, Any]:
        layout = None
        if self.layout is not None:
            layout = {
                "name": self.layout.name,
                "names": list(self.layout.names),
                "edges": [list(edge) for edge in self.layout.edges],
                "center": int(self.layout.center),
            }
        return {
            "name": self.name,
            "params": dict(self.params),
            "num_channels": self.num_channels,
            "num_frames": self.num_frames,
            "num_nodes": self.num_nodes,
            "num_classes": self.num_classes,
            "layout": layout,
        }

    @classmethod
    def from_saved(cls, values: dict[str, Any]) -> ClassifierSpec:
        """The spec a checkpoint stored (:meth:`to_dict`): a record aslexp wrote, not configuration."""
        layout = values.get("layout")
        if layout is not None:
            layout = KeypointLayout(
                name=layout["name"],
                names=tuple(layout["names"]),
                edges=tuple((int(i), int(j)) for i, j in layout["edges"]),
                center=int(layout["center"]),
            )
        return cls(
            name=values["name"],
            params=dict(values["params"]),
            num_channels=int(values["num_channels"]),
            num_frames=int(values["num_frames"]),
            num_nodes=int(values["num_nodes"]),
            num_classes=int(values["num_classes"]),
            layout=layout,
        )


def check_inputs(X: np.ndarray, mask: np.ndarray, spec: ClassifierSpec) -> None:
    """Fail early, naming the array and the expected shape, when inputs do not fit the model."""
    expected = (spec.num_channels, spec.num_frames, spec.num_nodes, 1)
    if X.ndim != 5 or tuple(X.shape[1:]) != expected:
        raise ValueError(
            f"classifier '{spec.name}': X has shape {tuple(X.shape)}, expected (N, C, T, V, 1) "
            f"= (N, {', '.join(map(str, expected))})"
        )
    if tuple(mask.shape) != (X.shape[0], spec.num_frames, spec.num_nodes):
        raise ValueError(
            f"classifier '{spec.name}': mask has shape {tuple(mask.shape)}, expected (N, T, V) = "
            f"({X.shape[0]}, {spec.num_frames}, {spec.num_nodes})"
        )


class Classifier(ABC):
    """A trained or trainable classifier of clips into ``spec.num_classes`` classes."""

    kind: ClassVar[str]  # "torch" or "sklearn"
    checkpoint_suffix: ClassVar[str]

    def __init__(self, spec: ClassifierSpec) -> None:
        self.spec = spec

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def uses_seed(self) -> bool:
        """Whether the seed can change what it learns from fixed data (random initial weights,
        shuffled batches, sampled trees); False where fitting draws no random number at all."""
        return True

    @abstractmethod
    def predict_proba(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Class probabilities, (N, num_classes)."""

    def predict(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        """Class ids, (N,) int64."""
        return self.predict_proba(X, mask).argmax(axis=1).astype(np.int64)


class TorchClassifier(Classifier):
    """A torch module ``module(x (N, C, T, V), mask (N, T, V) float) -> logits`` plus its spec."""

    kind = "torch"
    checkpoint_suffix = ".pt"

    def __init__(self, spec: ClassifierSpec, module: nn.Module, eval_batch_size: int = 128) -> None:
        super().__init__(spec)
        self.module = module
        self.eval_batch_size = eval_batch_size
        self.precision = "32"  # set by the trainer: inference runs as training did

    def num_parameters(self) -> int:
        """Every learnt parameter (also those a schedule freezes for a while, e.g. SL-GCN's graph)."""
        return sum(p.numel() for p in self.module.parameters())

    @property
    def device(self) -> torch.device:
        parameter = next(self.module.parameters(), None)
        return parameter.device if parameter is not None else torch.device("cpu")

    @torch.no_grad()
    def logits(self, X: np.ndarray, mask: np.ndarray) -> torch.Tensor:
        """Logits (float32, on the CPU) in eval mode, computed in batches of ``eval_batch_size``
        on the module's device."""
        from aslexp.recognition.device import autocast

        check_inputs(X, mask, self.spec)
        was_training = self.module.training
        self.module.eval()
        device = self.device
        try:
            outputs = []
            for start in range(0, len(X), self.eval_batch_size):
                x, m = to_tensors(X[start : start + self.eval_batch_size], mask[start : start + self.eval_batch_size])
                with autocast(device, self.precision):
                    outputs.append(self.module(x.to(device), m.to(device)).float().cpu())
        finally:
            self.module.train(was_training)
        if not outputs:
            return torch.zeros(0, self.spec.num_classes)
        return torch.cat(outputs)

    def predict_proba(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        return torch.softmax(self.logits(X, mask), dim=1).numpy()


def to_tensors(X: np.ndarray, mask: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """(N, C, T, V, 1) and (N, T, V) arrays -> float tensors (N, C, T, V) and (N, T, V)."""
    x = torch.as_tensor(np.ascontiguousarray(X[..., 0]), dtype=torch.float32)
    m = torch.as_tensor(np.ascontiguousarray(mask), dtype=torch.float32)
    return x, m


@dataclass
class SklearnFitInfo:
    """What the last ``fit`` of a scikit-learn classifier saw (for logs and reports)."""

    num_samples: int = 0
    num_features: int = 0
    classes_seen: list[int] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)
