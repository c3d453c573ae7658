"""scikit-learn classifiers: the chance baselines and the linear/kernel models on flat features."""

from __future__ import annotations

import logging
from typing import Any

import numpy as np
from sklearn.dummy import DummyClassifier
from sklearn.linear_model import LogisticRegression
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC

from aslexp.recognition.models.base import Classifier, ClassifierSpec, SklearnFitInfo, check_inputs

log = logging.getLogger(__name__)

POOLINGS = ("none", "mean_std")


def clip_features(X: np.ndarray, mask: np.ndarray, pooling: str) -> np.ndarray:
    """Flat per-clip features.

    ``none``: every coordinate, (N, C*T*V). ``mean_std``: mean and standard deviation over the
    observed frames of every joint-channel, (N, 2*C*V); a joint never observed gets 0 and 0.
    """
    if pooling == "none":
        return X.reshape(len(X), -1).astype(np.float32, copy=False)
    if pooling == "mean_std":
        x = X[..., 0].astype(np.float64)  # (N, C, T, V)
        weight = mask[:, None, :, :].astype(np.float64)  # (N, 1, T, V)
        count = np.maximum(weight.sum(axis=2), 1.0)  # (N, 1, V)
        mean = (x * weight).sum(axis=2) / count  # (N, C, V)
        var = (((x - mean[:, :, None, :]) ** 2) * weight).sum(axis=2) / count
        features = np.concatenate([mean, np.sqrt(var)], axis=1)
        return features.reshape(len(X), -1).astype(np.float32)
    raise ValueError(f"pooling must be one of {POOLINGS}, got {pooling!r}")


class SklearnClassifier(Classifier):
    """A scikit-learn estimator on :func:`clip_features`.

    ``predict_proba`` always has ``num_classes`` columns: classes absent from the training data
    get probability 0.
    """

    kind = "sklearn"
    checkpoint_suffix = ".joblib"

    def __init__(self, spec: ClassifierSpec, pooling: str = "none") -> None:
        super().__init__(spec)
        if pooling not in POOLINGS:
            raise ValueError(f"classifier '{spec.name}': pooling must be one of {POOLINGS}, got {pooling!r}")
        self.pooling = pooling
        self.estimator: Any = None
        self.fit_info = SklearnFitInfo()

    def make_estimator(self, seed: int, class_weight: str | None) -> Any:
        raise NotImplementedError

    def fit(self, X: np.ndarray, mask: np.ndarray, y: np.ndarray, *, seed: int = 0, class_weights: bool = False) -> SklearnClassifier:
        """Fit on (X, mask, y); ``class_weights`` weighs classes by inverse frequency ('balanced')."""
        check_inputs(X, mask, self.spec)
        features = clip_features(X, mask, self.pooling)
        self.estimator = self.make_estimator(seed, "balanced" if class_weights else None)
        self.estimator.fit(features, np.asarray(y, dtype=np.int64))
        self.fit_info = SklearnFitInfo(
            num_samples=len(features), num_features=features.shape[1], classes_seen=sorted(int(c) for c in np.unique(y))
        )
        return self

    def _classes(self) -> np.ndarray:
        return np.asarray(self.estimator.classes_, dtype=np.int64)

    def predict_proba(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        if self.estimator is None:
            raise RuntimeError(f"classifier '{self.name}' is not fitted")
        check_inputs(X, mask, self.spec)
        features = clip_features(X, mask, self.pooling)
        proba = np.zeros((len(X), self.spec.num_classes), dtype=np.float64)
        proba[:, self._classes()] = self.estimator.predict_proba(features)
        return proba

    def predict(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        if self.estimator is None:
            raise RuntimeError(f"classifier '{self.name}' is not fitted")
        check_inputs(X, mask, self.spec)
        return np.asarray(self.estimator.predict(clip_features(X, mask, self.pooling)), dtype=np.int64)


class DummyBaseline(SklearnClassifier):
    """Chance baselines: ``majority`` (most frequent class) or ``stratified`` (random by prior)."""

    def __init__(self, spec: ClassifierSpec, strategy: str) -> None:
        super().__init__(spec, pooling="mean_std")  # features are ignored; keep them small
        self.strategy = strategy

    def make_estimator(self, seed: int, class_weight: str | None) -> Any:
        return DummyClassifier(strategy=self.strategy, random_state=seed)


class LogisticRegressionClassifier(SklearnClassifier):
    def __init__(self, spec: ClassifierSpec, *, C: float, max_iter: int, pooling: str, standardize: bool) -> None:
        super().__init__(spec, pooling)
        self.C, self.max_iter, self.standardize = float(C), int(max_iter), bool(standardize)

    def make_estimator(self, seed: int, class_weight: str | None) -> Pipeline:
        model = LogisticRegression(C=self.C, max_iter=self.max_iter, class_weight=class_weight, random_state=seed)
        return make_pipeline(StandardScaler(), model) if self.standardize else make_pipeline(model)


class SVMClassifier(SklearnClassifier):
    """SVC on clip features. It has no probabilities (Platt scaling is deprecated in
    scikit-learn 1.9 and costs an inner 5-fold fit): ``predict_proba`` is the one-hot prediction."""

    def __init__(self, spec: ClassifierSpec, *, C: float, kernel: str, gamma: str | float, pooling: str, standardize: bool) -> None:
        super().__init__(spec, pooling)
        self.C, self.kernel, self.gamma, self.standardize = float(C), str(kernel), gamma, bool(standardize)

    def make_estimator(self, seed: int, class_weight: str | None) -> Pipeline:
        model = SVC(C=self.C, kernel=self.kernel, gamma=self.gamma, class_weight=class_weight, random_state=seed)
        return make_pipeline(StandardScaler(), model) if self.standardize else make_pipeline(model)

    def predict_proba(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        proba = np.zeros((len(X), self.spec.num_classes), dtype=np.float64)
        proba[np.arange(len(X)), self.predict(X, mask)] = 1.0
        return proba
