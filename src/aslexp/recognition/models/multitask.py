"""One model, six properties: one encoder over the keypoint sequence, a head per
ASL-LEX property (optionally a gloss head), each head's probabilities calibrated on the validation
clips by temperature scaling, with the expected calibration error (ECE) per head.

The encoder reads every joint's coordinates plus its observed-mask per frame (``frame_stride`` 2)
and averages its outputs over the observed frames: ``encoder: conv`` (default) is ``num_layers``
temporal convolutions (kernel 5, BatchNorm, ReLU) of ``hidden_size`` channels, about 30x cheaper on
2 CPU cores than ``encoder: gru`` (the GRU of :class:`RecurrentClassifier`: ~70 s per multi-task
fit on 285 clips vs a few seconds). Each head is dropout and a linear layer on the pooled encoding.

Two ways in:

- ``classifier=multitask`` (registered here, ``conf/classifier/multitask.yaml``): the encoder with
  ONE head, trained by aslexp's trainer in the single-label ``aslexp recognize`` pipeline (a sweep
  space tunes it there: ``sweeps/classifier_multitask.yaml``). This is also the per-property model
  "with the same encoder" that the multi-task model is compared with.
- :func:`fit_multitask`: several labels per clip, ``codes`` (N, H) with -1 where a clip's value is
  unknown (that head's loss is masked for the clip). The single-label pipeline carries one label
  vector per dataset, so the multi-label fit lives here, on the clips that
  :func:`aslexp.jobs.retrieve.retrieval_clips` aligns across the properties' builds by video id
  (``bench/multitask_compare.py`` runs it over seeded phoneme and gloss splits).

Temperature scaling: per head one T > 0 minimising the NLL of softmax(logits / T) on the
validation clips (a bounded 1-D search over log T; T = 1 is kept unless it lowers the NLL, so the
validation NLL after is never above the NLL before). ECE: 10 equal-width bins of the top-class
confidence, sum over bins of (bin share) * |accuracy - confidence|.
"""

from __future__ import annotations

import copy
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import torch
from torch import nn

from aslexp.recognition.registry import register_classifier

ENCODERS = ("conv", "gru")
DEFAULTS: dict[str, Any] = {"encoder": "conv", "hidden_size": 128, "num_layers": 2, "bidirectional": True,
                            "dropout": 0.5, "frame_stride": 2, "kernel_size": 5}
# the multi-label fit's own keys (gloss_head: one more head over the training glosses, trained as
# an auxiliary task; it never chooses the epoch and is not reported)
FIT_DEFAULTS: dict[str, Any] = {"lr": 1e-3, "weight_decay": 1e-4, "batch_size": 32, "max_epochs": 40, "patience": 12,
                                "head_weights": None, "gloss_head": False}
GLOSS = "gloss"
ECE_BINS = 10


class MultiTaskNet(nn.Module):
    """``forward(x (N, C, T, V), mask (N, T, V)) -> [logits (N, K_h) for each head]``."""

    def __init__(self, num_channels: int, num_nodes: int, head_classes: Sequence[int], *, encoder: str = "conv",
                 hidden_size: int, num_layers: int, bidirectional: bool, dropout: float, frame_stride: int,
                 kernel_size: int = 5) -> None:
        super().__init__()
        self.frame_stride = frame_stride
        self.encoder = encoder
        inputs = num_channels * num_nodes + num_nodes
        if encoder == "gru":
            self.rnn = nn.GRU(inputs, hidden_size, num_layers=num_layers, batch_first=True,
                              bidirectional=bidirectional, dropout=dropout if num_layers > 1 else 0.0)
            width = hidden_size * (2 if bidirectional else 1)
        else:  # temporal convolutions over the frames (same length, ReLU, BatchNorm)
            layers: list[nn.Module] = []
            for i in range(num_layers):
                layers += [nn.Conv1d(inputs if i == 0 else hidden_size, hidden_size, kernel_size, padding=kernel_size // 2),
                           nn.BatchNorm1d(hidden_size), nn.ReLU(inplace=True)]
            self.conv = nn.Sequential(*layers)
            width = hidden_size
        self.heads = nn.ModuleList(nn.Sequential(nn.Dropout(dropout), nn.Linear(width, int(k))) for k in head_classes)

    def encode(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        x, mask = x[:, :, :: self.frame_stride], mask[:, :: self.frame_stride]
        n, c, t, v = x.shape
        frames = torch.cat([x.permute(0, 2, 1, 3).reshape(n, t, c * v), mask], dim=2)
        if self.encoder == "gru":
            outputs, _ = self.rnn(frames)  # (N, T, H)
        else:
            outputs = self.conv(frames.transpose(1, 2)).transpose(1, 2)  # (N, T, H)
        observed = (mask.sum(dim=2) > 0).to(outputs.dtype).unsqueeze(2)
        return (outputs * observed).sum(dim=1) / observed.sum(dim=1).clamp(min=1.0)

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> list[torch.Tensor]:
        encoded = self.encode(x, mask)
        return [head(encoded) for head in self.heads]


class OneHead(nn.Module):
    """The multi-task encoder with one head, as a single-label torch classifier (``classifier=multitask``)."""

    def __init__(self, net: MultiTaskNet) -> None:
        super().__init__()
        self.net = net

    def forward(self, x: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        return self.net(x, mask)[0]


def check_params(params: Mapping[str, Any]) -> dict[str, Any]:
    """Defaults updated with ``params``; an unknown key or a bad value is one ValueError line."""
    params = dict(params or {})
    unknown = sorted(set(params) - set(DEFAULTS) - set(FIT_DEFAULTS))
    if unknown:
        raise ValueError(f"classifier 'multitask': unknown params {unknown}; accepted: "
                         f"{sorted(set(DEFAULTS) | set(FIT_DEFAULTS))}")
    resolved = {**DEFAULTS, **FIT_DEFAULTS, **params}
    if resolved["encoder"] not in ENCODERS:
        raise ValueError(f"classifier 'multitask': encoder must be one of {list(ENCODERS)}, got {resolved['encoder']!r}")
    for key in ("hidden_size", "num_layers", "frame_stride", "kernel_size", "batch_size", "max_epochs"):
        if not isinstance(resolved[key], int) or isinstance(resolved[key], bool) or resolved[key] < 1:
            raise ValueError(f"classifier 'multitask': {key} must be an integer >= 1, got {resolved[key]!r}")
    if not 0.0 <= float(resolved["dropout"]) < 1.0:
        raise ValueError(f"classifier 'multitask': dropout must be in [0, 1), got {resolved['dropout']!r}")
    if float(resolved["lr"]) <= 0:
        raise ValueError(f"classifier 'multitask': lr must be > 0, got {resolved['lr']!r}")
    return resolved


def build_net(num_channels: int, num_nodes: int, head_classes: Sequence[int], params: Mapping[str, Any]) -> MultiTaskNet:
    p = check_params({k: v for k, v in params.items() if k in DEFAULTS})
    if not head_classes or any(int(k) < 2 for k in head_classes):
        raise ValueError(f"classifier 'multitask': every head needs at least 2 classes, got {list(head_classes)}")
    return MultiTaskNet(num_channels, num_nodes, head_classes, encoder=p["encoder"], hidden_size=p["hidden_size"],
                        num_layers=p["num_layers"], bidirectional=bool(p["bidirectional"]), dropout=float(p["dropout"]),
                        frame_stride=p["frame_stride"], kernel_size=p["kernel_size"])


@register_classifier("multitask", DEFAULTS, summary="the multi-task encoder (conv or GRU over frames), one head")
def build(spec) -> nn.Module:
    return OneHead(build_net(spec.num_channels, spec.num_nodes, [spec.num_classes], spec.params))


# --------------------------------------------------------------------------- calibration

def softmax(logits: np.ndarray, temperature: float = 1.0) -> np.ndarray:
    z = np.asarray(logits, dtype=np.float64) / float(temperature)
    z = z - z.max(axis=1, keepdims=True)
    e = np.exp(z)
    return e / e.sum(axis=1, keepdims=True)


def nll(logits: np.ndarray, y: np.ndarray, temperature: float = 1.0) -> float:
    """Mean negative log-likelihood of classes ``y`` (every y a column of ``logits``)."""
    if len(y) == 0:
        return math.nan
    z = np.asarray(logits, dtype=np.float64) / float(temperature)
    z = z - z.max(axis=1, keepdims=True)
    log_p = z - np.log(np.exp(z).sum(axis=1, keepdims=True))
    return float(-log_p[np.arange(len(y)), y].mean())


def fit_temperature(logits: np.ndarray, y: np.ndarray, bounds: tuple[float, float] = (0.05, 20.0)) -> float:
    """The T minimising the NLL of ``softmax(logits / T)`` on (validation) classes ``y``; 1 when
    there is nothing to fit on or no T in ``bounds`` beats T = 1."""
    from scipy.optimize import minimize_scalar

    if len(y) == 0:
        return 1.0
    result = minimize_scalar(lambda s: nll(logits, y, math.exp(s)), bounds=(math.log(bounds[0]), math.log(bounds[1])),
                             method="bounded", options={"xatol": 1e-4})
    best = math.exp(float(result.x))
    return best if nll(logits, y, best) < nll(logits, y, 1.0) else 1.0


def expected_calibration_error(proba: np.ndarray, y_true: np.ndarray, bins: int = ECE_BINS) -> float:
    """ECE of the top-class confidence over ``bins`` equal-width bins of [0, 1]; ``y_true`` may hold
    classes outside ``proba``'s columns (-1 or any id: always wrong). NaN for no clips."""
    proba = np.asarray(proba, dtype=np.float64)
    if len(proba) == 0:
        return math.nan
    confidence = proba.max(axis=1)
    correct = (proba.argmax(axis=1) == np.asarray(y_true)).astype(np.float64)
    which = np.minimum((confidence * bins).astype(int), bins - 1)
    ece = 0.0
    for b in range(bins):
        inside = which == b
        if inside.any():
            ece += inside.mean() * abs(correct[inside].mean() - confidence[inside].mean())
    return float(ece)


# --------------------------------------------------------------------------- the multi-label fit

@dataclass
class Head:
    """One head: its name, the codes it predicts (the values seen in training, ascending) and its
    temperature (fitted on the validation clips)."""

    name: str
    classes: np.ndarray
    temperature: float = 1.0

    def targets(self, codes: np.ndarray) -> np.ndarray:
        """Column ids of ``codes``; -1 for an unknown value or one the head never trained on."""
        position = np.searchsorted(self.classes, codes)
        position = np.clip(position, 0, len(self.classes) - 1)
        return np.where((codes >= 0) & (self.classes[position] == codes), position, -1)


@dataclass
class MultiTaskModel:
    net: MultiTaskNet
    heads: list[Head]
    params: dict[str, Any]
    history: list[dict[str, float]] = field(default_factory=list)
    best_epoch: int = 0
    calibration: dict[str, dict[str, float]] = field(default_factory=dict)

    @torch.no_grad()
    def logits(self, X: np.ndarray, mask: np.ndarray, batch_size: int = 128) -> list[np.ndarray]:
        self.net.eval()
        outputs: list[list[np.ndarray]] = [[] for _ in self.heads]
        for start in range(0, len(X), batch_size):
            x = torch.as_tensor(np.ascontiguousarray(X[start:start + batch_size, ..., 0]), dtype=torch.float32)
            m = torch.as_tensor(np.ascontiguousarray(mask[start:start + batch_size]), dtype=torch.float32)
            for h, out in enumerate(self.net(x, m)):
                outputs[h].append(out.float().numpy())
        return [np.concatenate(o) if o else np.zeros((0, len(head.classes))) for o, head in zip(outputs, self.heads)]

    def predict_proba(self, X: np.ndarray, mask: np.ndarray, calibrated: bool = True) -> list[np.ndarray]:
        """Per head (N, K_h) probabilities over ``head.classes``; each row sums to 1."""
        return [softmax(z, head.temperature if calibrated else 1.0) for z, head in zip(self.logits(X, mask), self.heads)]

    def calibrate(self, X: np.ndarray, mask: np.ndarray, codes: np.ndarray) -> dict[str, dict[str, float]]:
        """Fit each head's temperature on these (validation) clips; returns per head T and NLL before/after."""
        report = {}
        for h, (z, head) in enumerate(zip(self.logits(X, mask), self.heads)):
            y = head.targets(codes[:, h])
            known = y >= 0
            head.temperature = fit_temperature(z[known], y[known])
            report[head.name] = {"temperature": head.temperature, "nll_before": nll(z[known], y[known]),
                                 "nll_after": nll(z[known], y[known], head.temperature), "clips": int(known.sum())}
        return report

    def evaluate(self, X: np.ndarray, mask: np.ndarray, codes: np.ndarray) -> dict[str, dict[str, float]]:
        """Per head on these (held-out) clips whose value is known: MCC, accuracy, ECE and NLL
        before and after calibration (NLL over the clips whose value the head knows)."""
        from aslexp.recognition.metrics import mcc

        result = {}
        for h, (z, head) in enumerate(zip(self.logits(X, mask), self.heads)):
            truth = codes[:, h]
            known = truth >= 0
            y = head.targets(truth[known])  # -1: a value never seen in training (always wrong)
            raw, cal = softmax(z[known]), softmax(z[known], head.temperature)
            predicted = head.classes[raw.argmax(axis=1)] if known.any() else np.zeros(0, dtype=np.int64)
            seen = y >= 0
            result[head.name] = {
                "clips": int(known.sum()), "mcc": mcc(truth[known], predicted) if known.any() else math.nan,
                "accuracy": float(np.mean(predicted == truth[known])) if known.any() else math.nan,
                "ece_before": expected_calibration_error(raw, y), "ece_after": expected_calibration_error(cal, y),
                "nll_before": nll(z[known][seen], y[seen]), "nll_after": nll(z[known][seen], y[seen], head.temperature),
                "temperature": head.temperature,
            }
        return result


def fit_multitask(X: np.ndarray, mask: np.ndarray, codes: np.ndarray, names: Sequence[str], train_idx: np.ndarray,
                  val_idx: np.ndarray, params: Mapping[str, Any] | None = None, *, seed: int = 0,
                  calibrate: bool = True, glosses: Sequence[str] | None = None,
                  select: Sequence[str] | None = None) -> MultiTaskModel:
    """Train one encoder with a head per column of ``codes`` (N, H) (-1: unknown, its loss masked)
    on ``train_idx``; keep the epoch of the best mean validation MCC over the heads named in
    ``select`` (None: every head; ties: lower validation loss over them), stop after ``patience``
    epochs without a better one; then fit each head's temperature on ``val_idx``. ``params``: the
    encoder's (:data:`DEFAULTS`) and the fit's (:data:`FIT_DEFAULTS`) keys; with ``gloss_head`` the
    clips' ``glosses`` label one more head (named ``gloss``, last), which neither chooses the epoch
    nor is calibrated. With ``select`` naming only some heads, the others are auxiliary tasks: they
    shape the encoder through their loss and never choose the epoch (seen-gloss classification with
    phonology heads: :mod:`aslexp.recognition.seen_glosses`)."""
    p = check_params(params or {})
    train_idx, val_idx = np.asarray(train_idx, dtype=np.int64), np.asarray(val_idx, dtype=np.int64)
    codes, names, heads, chooses = _heads(np.asarray(codes, dtype=np.int64).reshape(len(X), -1), list(names),
                                          train_idx, glosses, p, select)
    weights = p["head_weights"] or [1.0] * len(heads)
    if len(weights) != len(heads):
        raise ValueError(f"multitask: head_weights has {len(weights)} values for {len(heads)} heads")
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    net = build_net(X.shape[1], X.shape[3], [len(head.classes) for head in heads], p)
    model = MultiTaskModel(net, heads, p)
    targets = np.stack([head.targets(codes[:, h]) for h, head in enumerate(heads)], axis=1)  # (N, H)
    x_all = torch.as_tensor(np.ascontiguousarray(X[..., 0]), dtype=torch.float32)
    m_all = torch.as_tensor(np.ascontiguousarray(mask), dtype=torch.float32)
    t_all = torch.as_tensor(targets)
    optimizer = torch.optim.Adam(net.parameters(), lr=float(p["lr"]), weight_decay=float(p["weight_decay"]))
    loss_fn = nn.CrossEntropyLoss(ignore_index=-1, reduction="sum")
    best = (-math.inf, math.inf)
    best_state, waited = copy.deepcopy(net.state_dict()), 0
    for epoch in range(int(p["max_epochs"])):
        net.train()
        order = rng.permutation(train_idx)
        batches = [order[i:i + p["batch_size"]] for i in range(0, len(order), p["batch_size"])]
        if len(batches) > 1 and len(batches[-1]) == 1:
            batches[-2] = np.concatenate([batches[-2], batches.pop()])
        total = 0.0
        for batch in batches:
            outputs = net(x_all[batch], m_all[batch])
            loss = x_all.new_zeros(())
            for h, out in enumerate(outputs):
                target = t_all[batch, h]
                count = int((target >= 0).sum())
                if count:
                    loss = loss + weights[h] * loss_fn(out, target) / count
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            total += float(loss.detach()) * len(batch)
        score, val_loss = _validation(model, X[val_idx], mask[val_idx], codes[val_idx], targets[val_idx], chooses)
        model.history.append({"epoch": epoch + 1, "train_loss": total / max(1, len(train_idx)), "val_mcc": score,
                              "val_loss": val_loss})
        if (score, -val_loss) > (best[0], -best[1]):
            best, best_state, waited, model.best_epoch = (score, val_loss), copy.deepcopy(net.state_dict()), 0, epoch + 1
        else:
            waited += 1
            if waited >= int(p["patience"]):
                break
    net.load_state_dict(best_state)
    net.eval()
    if p["gloss_head"]:  # the auxiliary head has served its purpose
        net.heads = net.heads[:-1]
        model.heads = heads[:-1]
        codes = codes[:, :-1]
    if calibrate:
        model.calibration = model.calibrate(X[val_idx], mask[val_idx], codes[val_idx])
    return model


def _heads(codes: np.ndarray, names: list[str], train_idx: np.ndarray, glosses: Sequence[str] | None,
           p: Mapping[str, Any], select: Sequence[str] | None):
    """:func:`fit_multitask`'s heads: the label columns (the gloss head's appended with ``gloss_head``),
    their names, a :class:`Head` per column (its classes: the training clips' values) and the heads
    that choose the epoch."""
    if len(names) != codes.shape[1]:
        raise ValueError(f"multitask: {len(names)} head names for {codes.shape[1]} label columns")
    if p["gloss_head"]:
        if glosses is None or len(glosses) != len(codes):
            raise ValueError("multitask: gloss_head=true needs every clip's gloss (glosses=...)")
        vocabulary = {g: i for i, g in enumerate(sorted(set(glosses)))}
        codes = np.concatenate([codes, np.array([[vocabulary[g]] for g in glosses], dtype=np.int64)], axis=1)
        names = names + [GLOSS]
    heads = []
    for h, name in enumerate(names):
        column = codes[train_idx, h]
        classes = np.unique(column[column >= 0])
        if len(classes) < 2:
            raise ValueError(f"multitask: head {name!r} has {len(classes)} class(es) among the training clips; need 2")
        heads.append(Head(name, classes))
    chooses = [h for h, name in enumerate(names) if not (name == GLOSS and p["gloss_head"])]
    if select is not None:
        missing = sorted(set(select) - set(names))
        if missing or not select:
            raise ValueError(f"multitask: select={list(select)} names no head or unknown heads {missing}; heads: {names}")
        chooses = [h for h, name in enumerate(names) if name in set(select)]
    return codes, names, heads, chooses


def _validation(model: MultiTaskModel, X: np.ndarray, mask: np.ndarray, codes: np.ndarray, targets: np.ndarray,
                chooses: Sequence[int]) -> tuple[float, float]:
    """The epoch's validation: the mean MCC and mean NLL over the heads that choose the epoch."""
    from aslexp.recognition.metrics import mcc

    scores, losses = [], []
    for h, (z, head) in enumerate(zip(model.logits(X, mask), model.heads)):
        if h not in chooses:
            continue
        truth = codes[:, h]
        known = truth >= 0
        if known.any():
            scores.append(mcc(truth[known], head.classes[z[known].argmax(axis=1)]))
        y = targets[:, h]
        if (y >= 0).any():
            losses.append(nll(z[y >= 0], y[y >= 0]))
    return (float(np.mean(scores)) if scores else 0.0), (float(np.mean(losses)) if losses else math.inf)
