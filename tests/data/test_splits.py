import numpy as np
import pytest

from aslexp.data.dataset import DataError
from aslexp.data.splits import make_splits


def _labels(counts):
    return [label for label, n in counts.items() for _ in range(n)]


def test_phoneme_proportions_and_determinism():
    labels = _labels({"a": 100, "b": 40, "c": 20})
    result = make_splits(labels, "phoneme", seed=3)
    again = make_splits(labels, "phoneme", seed=3)
    other = make_splits(labels, "phoneme", seed=4)
    assert all(np.array_equal(result.splits[k], again.splits[k]) for k in ("train", "val", "test"))
    assert not np.array_equal(result.splits["test"], other.splits["test"])
    parts = [set(result.splits[k].tolist()) for k in ("train", "val", "test")]
    assert sum(map(len, parts)) == len(labels) == len(set.union(*parts))
    for k, share in (("train", 0.70), ("val", 0.15), ("test", 0.15)):
        y = result.y[result.splits[k]]
        for label_id, n in enumerate((100, 40, 20)):
            assert abs((y == label_id).sum() / n - share) <= 0.05


def test_gloss_split_has_no_leakage():
    rng = np.random.default_rng(0)
    glosses, labels = [], []
    for g in range(60):
        label = "abc"[g % 3]
        for _ in range(rng.integers(1, 8)):
            glosses.append(f"g{g}")
            labels.append(label)
    result = make_splits(labels, "gloss", groups=glosses, seed=0)
    names = {k: {glosses[result.keep[i]] for i in result.splits[k]} for k in ("train", "val", "test")}
    assert not names["train"] & names["val"] and not names["train"] & names["test"]
    assert not names["val"] & names["test"]
    assert len(names["test"]) == 3 * 3 and len(names["val"]) == 3 * 3  # 15% of 20 glosses per label
    with pytest.raises(DataError, match="one label per gloss"):
        make_splits(["a", "b"], "gloss", groups=["g", "g"])


def test_cv5_folds():
    labels = _labels({"a": 40, "b": 12})
    result = make_splits(labels, "cv5", seed=1)
    train_val = set(result.splits["train+val"].tolist())
    assert not train_val & set(result.splits["test"].tolist())
    folds = result.splits["folds"]
    assert len(folds) == 5
    vals = [set(v.tolist()) for _, v in folds]
    assert set.union(*vals) == train_val and sum(map(len, vals)) == len(train_val)
    for train, val in folds:
        assert set(train.tolist()) | set(val.tolist()) == train_val
        assert set(np.unique(result.y[val]).tolist()) == {0, 1}


def test_rare_class_rules():
    labels = _labels({"a": 30, "b": 30, "r1": 2, "r2": 1})
    dropped = make_splits(labels, "phoneme")
    assert dropped.label_names == ["a", "b"] and dropped.dropped == 3
    assert dropped.rare == {"r1": 2, "r2": 1} and dropped.y.max() == 1
    merged = make_splits(labels, "phoneme", rare_classes="merge")
    assert merged.label_names == ["Other", "a", "b"] and merged.dropped == 0
    train_only = make_splits(labels, "phoneme", rare_classes="train_only")
    rare_ids = {train_only.label_names.index("r1"), train_only.label_names.index("r2")}
    for k in ("val", "test"):
        assert not rare_ids & set(train_only.y[train_only.splits[k]].tolist())
    assert len(train_only.keep) == len(labels)
    with pytest.raises(DataError, match="rare_classes"):
        make_splits(labels, "phoneme", rare_classes="keep")
