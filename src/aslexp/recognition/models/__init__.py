"""The built-in classifiers, registered by name (:mod:`aslexp.recognition.registry`):
``build_classifier(name, params, ...)`` builds any registered one.

A built-in's accepted keys and their defaults are its ``conf/classifier/NAME.yaml`` (``params``),
the one place they live; a builder reads the keys it is given. ``params`` may override any of them
and nothing else (an unknown key is an error, so a typo in a config or a sweep space cannot go
unnoticed).

The defaults there fit a 2-core CPU and a few hundred clips: ST-GCN with 5 blocks of [32, 32, 64, 64, 128]
channels (0.32 M parameters with the 33-node pose, vs 1.2 M for [64, 64, 128, 128, 256] and 3.1 M
for the classic 10-block ST-GCN: far too many for ~200 training clips, and ~4x / ~10x the
compute per epoch), and ``frame_stride`` 2 for the sequence models (25 fps -> 12.5 fps halves
the cost; the stride-2 blocks of ST-GCN subsample time anyway). ``slgcn`` is SL-GCN with the
authors' sizes (10 blocks up to 256 channels: a GPU model); ``rf`` and ``hgb`` are the feature
baseline on pooled summary statistics.
"""

from __future__ import annotations

from typing import Any

import torch

from aslexp.data.dataset import KeypointLayout
from aslexp.recognition.models.base import Classifier, ClassifierSpec, TorchClassifier, to_tensors
from aslexp.recognition.models.classical import (
    DummyBaseline,
    GradientBoostingFeatureClassifier,
    LogisticRegressionClassifier,
    RandomForestFeatureClassifier,
    SklearnClassifier,
    SVMClassifier,
    clip_features,
)
from aslexp.recognition.models.cnn3d import HeatmapCNN3D, HeatmapRenderer
from aslexp.recognition.models.graph import PARTITIONS, spatial_partition_adjacency
from aslexp.recognition.registry import (
    BUILT_IN,
    DefaultParams,
    get_classifier,
    register_classifier,
    resolve_params,
)
from aslexp.recognition.models.sequence import MLP, RecurrentClassifier
from aslexp.recognition.models.slgcn import SLGCN, spatial_graph
from aslexp.recognition.models.stgcn import STGCN

def _stride(name: str, params: dict[str, Any]) -> int:
    stride = int(params["frame_stride"])
    if stride < 1:
        raise ValueError(f"classifier '{name}': frame_stride must be >= 1, got {params['frame_stride']}")
    return stride


def _layout(spec: ClassifierSpec) -> KeypointLayout:
    if spec.layout is None:
        raise ValueError(f"classifier '{spec.name}' needs the keypoint layout (its edges and center)")
    return spec.layout


# -- the chance baselines and the feature models (scikit-learn) -----------------------------------------
@register_classifier("majority", baseline=True, summary="the most frequent class")
def _majority(spec: ClassifierSpec) -> Classifier:
    return DummyBaseline(spec, strategy="most_frequent")


@register_classifier("stratified", baseline=True, summary="classes drawn at their rates")
def _stratified(spec: ClassifierSpec) -> Classifier:
    return DummyBaseline(spec, strategy="stratified")


@register_classifier("logreg", summary="logistic regression on pooled features")
def _logreg(spec: ClassifierSpec) -> Classifier:
    p = spec.params
    return LogisticRegressionClassifier(spec, C=p["C"], max_iter=p["max_iter"], pooling=p["pooling"],
                                        standardize=p["standardize"], solver=p["solver"], multi_class=p["multi_class"])


@register_classifier("svm", summary="support vector machine on pooled features")
def _svm(spec: ClassifierSpec) -> Classifier:
    p = spec.params
    return SVMClassifier(spec, C=p["C"], kernel=p["kernel"], gamma=p["gamma"], pooling=p["pooling"],
                         standardize=p["standardize"], degree=p["degree"],
                         decision_function_shape=p["decision_function_shape"], max_iter=p["max_iter"])


@register_classifier("rf", summary="random forest on summary statistics")
def _rf(spec: ClassifierSpec) -> Classifier:
    p = spec.params
    return RandomForestFeatureClassifier(spec, pooling=p["pooling"], n_estimators=p["n_estimators"],
                                         max_depth=p["max_depth"], min_samples_leaf=p["min_samples_leaf"],
                                         max_features=p["max_features"], n_jobs=p["n_jobs"])


@register_classifier("hgb", summary="gradient-boosted trees on summary statistics")
def _hgb(spec: ClassifierSpec) -> Classifier:
    p = spec.params
    return GradientBoostingFeatureClassifier(spec, pooling=p["pooling"], learning_rate=p["learning_rate"],
                                             max_iter=p["max_iter"], max_leaf_nodes=p["max_leaf_nodes"],
                                             min_samples_leaf=p["min_samples_leaf"],
                                             l2_regularization=p["l2_regularization"], n_threads=p["n_threads"])


# -- the networks (torch modules: aslexp's trainer trains them) -----------------------------------------
@register_classifier("mlp", summary="multi-layer perceptron over the flattened clip")
def _mlp(spec: ClassifierSpec) -> torch.nn.Module:
    p = spec.params
    hidden = list(p["hidden_sizes"]) if p["num_layers"] is None else [int(p["hidden_size"])] * int(p["num_layers"])
    return MLP(spec.num_channels * spec.num_frames * spec.num_nodes, spec.num_classes, hidden_sizes=hidden,
               dropout=p["dropout"])


def _recurrent(spec: ClassifierSpec) -> torch.nn.Module:
    p = spec.params
    return RecurrentClassifier(
        spec.name, spec.num_channels * spec.num_nodes + spec.num_nodes, spec.num_classes,
        hidden_size=int(p["hidden_size"]), num_layers=int(p["num_layers"]), bidirectional=bool(p["bidirectional"]),
        dropout=float(p["dropout"]), frame_stride=_stride(spec.name, p), head_layers=int(p["head_layers"]),
        head_size=None if p["head_size"] is None else int(p["head_size"]),
        head_dropout=None if p["head_dropout"] is None else float(p["head_dropout"]),
    )


register_classifier("lstm", summary="LSTM over the frames")(_recurrent)
register_classifier("gru", summary="GRU over the frames")(_recurrent)


@register_classifier("stgcn", summary="spatial-temporal graph convolution (ST-GCN)")
def _stgcn(spec: ClassifierSpec) -> torch.nn.Module:
    p = spec.params
    return STGCN(
        spec.num_channels, spec.num_classes, torch.from_numpy(spatial_partition_adjacency(_layout(spec))),
        channels=[int(c) for c in p["channels"]], temporal_kernel=int(p["temporal_kernel"]),
        dropout=float(p["dropout"]), residual=bool(p["residual"]), edge_importance=bool(p["edge_importance"]),
        adaptive=bool(p["adaptive"]), mask_channel=bool(p["mask_channel"]), frame_stride=_stride(spec.name, p),
    )


@register_classifier("slgcn", summary="SL-GCN with the authors' sizes (a GPU model)")
def _slgcn(spec: ClassifierSpec) -> torch.nn.Module:
    p, layout = spec.params, _layout(spec)
    return SLGCN(
        spec.num_channels, spec.num_classes, spatial_graph(layout), center=int(layout.center),
        channels=[int(c) for c in p["channels"]], groups=int(p["groups"]), block_size=int(p["block_size"]),
        keep_prob=float(p["keep_prob"]), keep_prob_epochs=int(p["keep_prob_epochs"]),
        drop_from_block=int(p["drop_from_block"]), freeze_graph_epochs=int(p["freeze_graph_epochs"]),
        attention=bool(p["attention"]), temporal_kernel=int(p["temporal_kernel"]), normalize=bool(p["normalize"]),
        mask_channel=bool(p["mask_channel"]), frame_stride=_stride(spec.name, p),
    )


@register_classifier("cnn3d", summary="3D CNN over rendered joint heatmaps")
def _cnn3d(spec: ClassifierSpec) -> torch.nn.Module:
    p = spec.params
    xy = tuple(int(c) for c in p["xy_channels"])
    if len(xy) != 2 or not all(0 <= c < spec.num_channels for c in xy):
        raise ValueError(f"classifier 'cnn3d': xy_channels must be two channel indices < {spec.num_channels}, "
                         f"got {p['xy_channels']}")
    return HeatmapCNN3D(
        spec.num_nodes, spec.num_classes, channels=[int(c) for c in p["channels"]], dropout=float(p["dropout"]),
        heatmap_size=int(p["heatmap_size"]), sigma=float(p["sigma"]), sum_joints=bool(p["sum_joints"]),
        xy_channels=xy, frame_stride=_stride(spec.name, p),
    )


DEFAULT_PARAMS = DefaultParams()  # every classifier's defaults by name, read from the registry
CLASSIFIER_NAMES = BUILT_IN  # the built-in classifiers, in table order
BASELINE_NAMES = ("majority", "stratified")  # chance baselines: every run reports the better one
FEATURE_MODELS = ("logreg", "svm", "rf", "hgb")  # fitted once on pooled features: no epochs


def build_classifier(
    name: str,
    params: dict[str, Any] | None,
    num_channels: int,
    num_frames: int,
    num_nodes: int,
    num_classes: int,
    layout: KeypointLayout | None = None,
    module: str | None = None,
) -> Classifier:
    """A fresh, untrained classifier for clips of shape (C, T, V, 1) and ``num_classes`` classes
    (``module``: the module that registers ``name``, when it is not built in).

    ``layout`` is required by the graph models (the skeleton graph) and checked against ``num_nodes``.
    Torch weights are initialised from torch's global RNG: seed before building.
    """
    resolved = resolve_params(name, params, module)
    if num_classes < 2:
        raise ValueError(f"classifier '{name}': need at least 2 classes, got {num_classes}")
    if layout is not None and layout.num_nodes != num_nodes:
        raise ValueError(f"classifier '{name}': layout '{layout.name}' has {layout.num_nodes} nodes, data has {num_nodes}")
    spec = ClassifierSpec(name, resolved, num_channels, num_frames, num_nodes, num_classes, layout)
    built = get_classifier(name, module).build(spec)
    return TorchClassifier(spec, built) if isinstance(built, torch.nn.Module) else built


def rebuild_classifier(spec: ClassifierSpec) -> Classifier:
    """A fresh classifier with the same architecture as ``spec`` (used to load checkpoints)."""
    return build_classifier(
        spec.name, spec.params, spec.num_channels, spec.num_frames, spec.num_nodes, spec.num_classes, spec.layout
    )


__all__ = [
    "BASELINE_NAMES",
    "CLASSIFIER_NAMES",
    "DEFAULT_PARAMS",
    "FEATURE_MODELS",
    "PARTITIONS",
    "Classifier",
    "ClassifierSpec",
    "HeatmapRenderer",
    "SklearnClassifier",
    "TorchClassifier",
    "build_classifier",
    "get_classifier",
    "register_classifier",
    "clip_features",
    "rebuild_classifier",
    "resolve_params",
    "spatial_partition_adjacency",
    "to_tensors",
]
