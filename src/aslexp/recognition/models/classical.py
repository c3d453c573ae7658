"""scikit-learn classifiers: the chance baselines, the linear/kernel models and the tree ensembles
(the feature baseline: random forest, histogram gradient boosting) on flat per-clip features."""

from __future__ import annotations

import logging
import warnings
from typing import Any

import numpy as np
from sklearn.dummy import DummyClassifier
from sklearn.exceptions import ConvergenceWarning
from sklearn.ensemble import HistGradientBoostingClassifier, RandomForestClassifier
from sklearn.linear_model import LogisticRegression
from sklearn.multiclass import OneVsRestClassifier
from sklearn.pipeline import Pipeline, make_pipeline
from sklearn.preprocessing import StandardScaler
from sklearn.svm import SVC
from threadpoolctl import threadpool_limits

from aslexp.recognition.models.base import Classifier, ClassifierSpec, SklearnFitInfo, check_inputs

log = logging.getLogger(__name__)

POOLINGS = ("none", "mean_std", "summary")
SUMMARY_STATISTICS = ("mean", "std", "min", "max", "range", "speed_mean", "velocity_std", "speed_max")


def clip_features(X: np.ndarray, mask: np.ndarray, pooling: str) -> np.ndarray:
    """Flat per-clip features.

    ``none``: every coordinate, (N, C*T*V). ``mean_std``: mean and standard deviation over the
    observed frames of every joint-channel, (N, 2*C*V); a joint never observed gets 0 and 0.
    ``summary``: per joint and channel over its observed frames the statistics of
    ``SUMMARY_STATISTICS`` (mean, std, min, max, range = max - min, and of the frame-to-frame
    velocity between consecutive observed frames: mean |v|, std of v, max |v|), plus per joint the
    share of frames it was observed in: (N, 8*C*V + V). Zeros where a joint has no such frames.
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
    if pooling == "summary":
        return _summary_features(X[..., 0].astype(np.float64), mask.astype(bool))
    raise ValueError(f"pooling must be one of {POOLINGS}, got {pooling!r}")


def _masked_stats(values: np.ndarray, weight: np.ndarray) -> list[np.ndarray]:
    """mean, std, min, max over axis 2 of values (N, C, T, V) where weight (N, 1, T, V) is 1."""
    count = weight.sum(axis=2)
    safe = np.maximum(count, 1.0)
    mean = (values * weight).sum(axis=2) / safe
    std = np.sqrt((((values - mean[:, :, None, :]) ** 2) * weight).sum(axis=2) / safe)
    present = weight > 0
    low = np.where(present, values, np.inf).min(axis=2)
    high = np.where(present, values, -np.inf).max(axis=2)
    empty = np.broadcast_to(count == 0, low.shape)
    return [mean, std, np.where(empty, 0.0, low), np.where(empty, 0.0, high)]


def _summary_features(x: np.ndarray, mask: np.ndarray) -> np.ndarray:
    n, _, _, v = x.shape
    weight = mask[:, None].astype(np.float64)  # (N, 1, T, V)
    mean, std, low, high = _masked_stats(x, weight)
    velocity = np.diff(x, axis=2)  # (N, C, T-1, V)
    both = (mask[:, 1:] & mask[:, :-1])[:, None].astype(np.float64)
    speed_mean, _, _, speed_max = _masked_stats(np.abs(velocity), both)
    _, velocity_std, _, _ = _masked_stats(velocity, both)
    features = [mean, std, low, high, high - low, speed_mean, velocity_std, speed_max]
    observed_share = mask.mean(axis=1)  # (N, V)
    return np.concatenate([f.reshape(n, -1) for f in features] + [observed_share.reshape(n, v)], axis=1).astype(np.float32)


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

    @property
    def uses_seed(self) -> bool:
        return self.strategy == "stratified"  # the majority class is drawn from nothing


# LogisticRegression's random_state shuffles the data for these solvers only; lbfgs, newton-cg and
# newton-cholesky are deterministic (scikit-learn's documentation of ``random_state``).
SHUFFLING_SOLVERS = ("sag", "saga", "liblinear")


class LogisticRegressionClassifier(SklearnClassifier):
    """Logistic regression; ``multi_class`` = multinomial (one softmax) or ovr (one binary model
    per class, scikit-learn's OneVsRestClassifier: ``multi_class`` left LogisticRegression in 1.7)."""

    def __init__(self, spec: ClassifierSpec, *, C: float, max_iter: int, pooling: str, standardize: bool,
                 solver: str = "lbfgs", multi_class: str = "multinomial") -> None:  # fmt: skip
        super().__init__(spec, pooling)
        if multi_class not in ("multinomial", "ovr"):
            raise ValueError(f"classifier 'logreg': multi_class must be multinomial or ovr, got {multi_class!r}")
        if multi_class == "multinomial" and solver == "liblinear" and spec.num_classes > 2:
            raise ValueError("classifier 'logreg': solver liblinear has no multinomial backend (use multi_class=ovr)")
        self.C, self.max_iter, self.standardize = float(C), int(max_iter), bool(standardize)
        self.solver, self.multi_class = str(solver), str(multi_class)

    def make_estimator(self, seed: int, class_weight: str | None) -> Pipeline:
        model: Any = LogisticRegression(C=self.C, max_iter=self.max_iter, class_weight=class_weight,
                                        random_state=seed, solver=self.solver)  # fmt: skip
        if self.multi_class == "ovr":
            model = OneVsRestClassifier(model)
        return make_pipeline(StandardScaler(), model) if self.standardize else make_pipeline(model)

    @property
    def uses_seed(self) -> bool:
        return self.solver in SHUFFLING_SOLVERS


class SVMClassifier(SklearnClassifier):
    """SVC on clip features. It has no probabilities (Platt scaling is deprecated in
    scikit-learn 1.9 and costs an inner 5-fold fit): ``predict_proba`` is the one-hot prediction."""

    def __init__(self, spec: ClassifierSpec, *, C: float, kernel: str, gamma: str | float, pooling: str, standardize: bool,
                 degree: int = 3, decision_function_shape: str = "ovr", max_iter: int = -1) -> None:  # fmt: skip
        super().__init__(spec, pooling)
        self.C, self.kernel, self.gamma, self.standardize = float(C), str(kernel), gamma, bool(standardize)
        self.degree, self.decision_function_shape, self.max_iter = int(degree), str(decision_function_shape), int(max_iter)

    def make_estimator(self, seed: int, class_weight: str | None) -> Pipeline:
        model = SVC(C=self.C, kernel=self.kernel, gamma=self.gamma, degree=self.degree, class_weight=class_weight,
                    decision_function_shape=self.decision_function_shape, max_iter=self.max_iter,
                    random_state=seed)  # fmt: skip
        return make_pipeline(StandardScaler(), model) if self.standardize else make_pipeline(model)

    def fit(self, X: np.ndarray, mask: np.ndarray, y: np.ndarray, *, seed: int = 0, class_weights: bool = False) -> SklearnClassifier:
        with warnings.catch_warnings():  # a capped max_iter (thesis Table 3.1) stops early by design
            warnings.filterwarnings("ignore", category=ConvergenceWarning)
            return super().fit(X, mask, y, seed=seed, class_weights=class_weights)

    def predict_proba(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        proba = np.zeros((len(X), self.spec.num_classes), dtype=np.float64)
        proba[np.arange(len(X)), self.predict(X, mask)] = 1.0
        return proba

    @property
    def uses_seed(self) -> bool:
        return False  # SVC's random_state only drives Platt scaling (probability=True), never used here


class RandomForestFeatureClassifier(SklearnClassifier):
    """The feature baseline: a random forest on pooled summary statistics (``pooling: summary``)."""

    def __init__(self, spec: ClassifierSpec, *, pooling: str, n_estimators: int, max_depth: int | None,
                 min_samples_leaf: int, max_features: str | float, n_jobs: int) -> None:  # fmt: skip
        super().__init__(spec, pooling)
        self.n_estimators, self.max_depth, self.min_samples_leaf = int(n_estimators), max_depth, int(min_samples_leaf)
        self.max_features, self.n_jobs = max_features, int(n_jobs)

    def make_estimator(self, seed: int, class_weight: str | None) -> RandomForestClassifier:
        return RandomForestClassifier(
            n_estimators=self.n_estimators, max_depth=None if self.max_depth is None else int(self.max_depth),
            min_samples_leaf=self.min_samples_leaf, max_features=self.max_features, class_weight=class_weight,
            n_jobs=self.n_jobs, random_state=seed,
        )


class GradientBoostingFeatureClassifier(SklearnClassifier):
    """The feature baseline: histogram gradient boosting on pooled summary statistics.

    ``n_threads`` caps its OpenMP threads (threadpoolctl): on a loaded 2-core machine one fit took
    5 s with 1 thread and 42 s with 2; give it more on a quiet many-core node."""

    def __init__(self, spec: ClassifierSpec, *, pooling: str, learning_rate: float, max_iter: int,
                 max_leaf_nodes: int, min_samples_leaf: int, l2_regularization: float, n_threads: int = 1) -> None:  # fmt: skip
        super().__init__(spec, pooling)
        self.learning_rate, self.max_iter, self.max_leaf_nodes = float(learning_rate), int(max_iter), int(max_leaf_nodes)
        self.min_samples_leaf, self.l2_regularization = int(min_samples_leaf), float(l2_regularization)
        self.n_threads = int(n_threads)

    def make_estimator(self, seed: int, class_weight: str | None) -> HistGradientBoostingClassifier:
        return HistGradientBoostingClassifier(
            learning_rate=self.learning_rate, max_iter=self.max_iter, max_leaf_nodes=self.max_leaf_nodes,
            min_samples_leaf=self.min_samples_leaf, l2_regularization=self.l2_regularization,
            class_weight=class_weight, early_stopping=False, random_state=seed,
        )

    def fit(self, X: np.ndarray, mask: np.ndarray, y: np.ndarray, *, seed: int = 0, class_weights: bool = False) -> SklearnClassifier:
        with threadpool_limits(limits=self.n_threads):
            return super().fit(X, mask, y, seed=seed, class_weights=class_weights)

    @property
    def uses_seed(self) -> bool:
        # Early stopping is off, so random_state only subsamples the rows the bins are found on,
        # and only beyond 200,000 of them (scikit-learn's binning subsample).
        return self.fit_info.num_samples > 200_000

    def predict_proba(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        with threadpool_limits(limits=self.n_threads):
            return super().predict_proba(X, mask)

    def predict(self, X: np.ndarray, mask: np.ndarray) -> np.ndarray:
        with threadpool_limits(limits=self.n_threads):
            return super().predict(X, mask)
