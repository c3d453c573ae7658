"""Lexicon retrieval for unseen glosses: rank every lexicon entry for a clip by its predicted
phonology, with or without the lexicon's frequency prior (pure numpy; no torch, no Hydra).

Definitions (docs/recognition.md, "Lexicon retrieval"):

* **The lexicon table** (:func:`lexicon_table`): per entry and property the code of its value in the
  lexicon's vocabulary (-1 where missing), and ``log_prior``, the log of the frequency prior
  ``p(sign) = softmax(SignFrequency(Z))`` over the whole lexicon (temperature 1). Its temperature is
  not a parameter of its own: a ranking by the prior alone does not depend on it, and in the
  combination ``phonology + w * log_prior`` only ``w / temperature`` matters, so ``w`` (chosen on
  validation) is the one knob. An entry without a frequency gets the lowest Z of the lexicon.
* **Phonology** (:func:`phonology_scores`): per property, the classifier's probabilities over the
  vocabulary smoothed as ``p~ = (1 - eps) p + eps / |V|``. The smoothing is the probability floor: a
  value the classifier never saw in training (probability 0) gets ``eps / |V|``, never log 0, and
  every entry keeps a finite score. Two scores of a sign from them (``likelihood``):

  - ``posterior``: ``sum over properties of log p~(property = the sign's value | clip)``;
  - ``ratio`` (the default): the same minus ``log pi(value)``, ``pi`` the value's share among the
    training clips (add-one smoothed): Bayes' rule, ``p(clip | value) ∝ p(value | clip) / pi(value)``,
    so that a sign is not favoured for having the values that were frequent in training (the
    posterior counts the training prior once per property on top of the lexicon's own counts). With
    a uniform prior over signs this ranks by ``p(clip | sign)``; the frequency prior is then added
    on its own. It ranks better than the posterior on the validation glosses (docs/recognition.md,
    "Lexicon retrieval for unseen glosses", has the comparison).

  A missing value (a blank in the lexicon) scores what knowing nothing scores: ``log 1 / |V|``
  (posterior), ``0`` (ratio: the expected likelihood ratio under ``pi`` is 1).
* **Ranks with ties** (:func:`rank_of_true`): the true entry's rank is its *expected* position when
  ties are broken at random: with ``a`` entries scoring higher and ``t`` scoring the same (itself
  included) it is uniform on ``a+1 .. a+t``; expected rank ``a + (t+1)/2``, expected recall@k
  ``clip((k - a) / t, 0, 1)``, expected reciprocal rank ``(H(a+t) - H(a)) / t``. So chance (every
  score equal) gives recall@k = k / N exactly, and the oracle's figures are the counts the lexicon
  gives (:func:`oracle_lexicon`).
* **The oracle**: the true properties known: the entries that share all of the true entry's values
  (a missing value counting as a value of its own) come first, in random order (or by the prior:
  oracle + prior), the rest after.
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

DEFAULT_PROPERTIES = ("sign_type", "major_location", "minor_location", "movement")  # what a body-only pose shows
RECALL_AT = (1, 10, 50)
METHODS = ("chance", "prior", "phonology", "phonology+prior", "oracle", "oracle+prior")
METHOD_LABELS = {
    "chance": "chance (random order)",
    "prior": "frequency prior alone",
    "phonology": "phonology alone",
    "phonology+prior": "phonology + prior",
    "oracle": "oracle (true properties known)",
    "oracle+prior": "oracle + prior",
}


@dataclass(frozen=True)
class LexiconTable:
    """The lexicon as retrieval sees it: ``codes[i, j]`` = index of entry i's value of
    ``properties[j]`` in ``vocab[j]`` (-1: missing); ``log_prior`` (N,) sums to 1 in probability."""

    entry_ids: tuple[str, ...]
    properties: tuple[str, ...]
    vocab: tuple[tuple[str, ...], ...]
    codes: np.ndarray  # (N, P) int64
    frequency_z: np.ndarray  # (N,) float64
    log_prior: np.ndarray  # (N,) float64

    def __len__(self) -> int:
        return len(self.entry_ids)

    def index(self, entry_id: str) -> int:
        return self._positions()[entry_id]

    def _positions(self) -> dict[str, int]:
        cached = self.__dict__.get("_index")
        if cached is None:
            cached = {entry: i for i, entry in enumerate(self.entry_ids)}
            object.__setattr__(self, "_index", cached)
        return cached


def log_softmax(values: np.ndarray) -> np.ndarray:
    values = np.asarray(values, dtype=np.float64)
    shifted = values - values.max()
    return shifted - math.log(float(np.exp(shifted).sum()))


def lexicon_table(entries: Sequence, properties: Sequence[str], vocab: Mapping[str, Sequence[str]]) -> LexiconTable:
    """The table of ``entries`` (:class:`aslexp.data.lexicon.LexiconEntry`: ``entry_id``,
    ``properties``, ``frequency_z``) over ``properties``, each value coded by ``vocab[property]``."""
    properties = tuple(properties)
    vocabs = tuple(tuple(vocab[p]) for p in properties)
    codes = np.full((len(entries), len(properties)), -1, dtype=np.int64)
    for j, (prop, values) in enumerate(zip(properties, vocabs)):
        position = {value: k for k, value in enumerate(values)}
        for i, entry in enumerate(entries):
            value = entry.properties.get(prop)
            if value is not None:
                codes[i, j] = position[value]
    z = np.array([np.nan if e.frequency_z is None else float(e.frequency_z) for e in entries], dtype=np.float64)
    if np.isnan(z).all():
        z = np.zeros(len(entries))
    z = np.where(np.isnan(z), np.nanmin(z), z)
    return LexiconTable(entry_ids=tuple(e.entry_id for e in entries), properties=properties, vocab=vocabs,
                        codes=codes, frequency_z=z, log_prior=log_softmax(z))


# --------------------------------------------------------------------------- scores


def smooth(proba: np.ndarray, eps: float) -> np.ndarray:
    """``(1 - eps) p + eps / |V|`` over the last axis (the probability floor, see the module docstring)."""
    proba = np.asarray(proba, dtype=np.float64)
    return (1.0 - eps) * proba + eps / proba.shape[-1]


LIKELIHOODS = ("ratio", "posterior")


def value_prior(codes: np.ndarray, vocab_size: int) -> np.ndarray:
    """``pi``: the add-one smoothed share of each value among ``codes`` (the training clips' values
    of one property; -1, missing, not counted), (vocab_size,)."""
    codes = np.asarray(codes, dtype=np.int64)
    counts = np.bincount(codes[codes >= 0], minlength=vocab_size).astype(np.float64)
    return (counts + 1.0) / (counts.sum() + vocab_size)


def phonology_scores(table: LexiconTable, proba: Sequence[np.ndarray], eps: float,
                     priors: Sequence[np.ndarray] | None = None) -> np.ndarray:
    """(n_clips, N) phonology scores of every entry: ``proba[j]`` is (n_clips, |vocab[j]|), property
    j's probabilities over its whole vocabulary (0 for values the classifier never saw); with
    ``priors`` (per property ``pi``, :func:`value_prior`) the likelihood ratio, else the posterior
    (see the module docstring)."""
    if len(proba) != len(table.properties):
        raise ValueError(f"{len(proba)} probability arrays for {len(table.properties)} properties")
    n = len(proba[0]) if len(proba) else 0
    scores = np.zeros((n, len(table)), dtype=np.float64)
    for j, p in enumerate(proba):
        p = np.asarray(p, dtype=np.float64)
        if p.shape != (n, len(table.vocab[j])):
            raise ValueError(f"property {table.properties[j]!r}: probabilities of shape {p.shape}, expected "
                             f"({n}, {len(table.vocab[j])})")
        logp = np.log(smooth(p, eps))
        if priors is None:
            missing = np.full((n, 1), -math.log(len(table.vocab[j])))  # a blank value: 1 / |V|
        else:
            logp = logp - np.log(np.asarray(priors[j], dtype=np.float64))[None, :]
            missing = np.zeros((n, 1))  # a blank value: ratio 1
        scores += np.concatenate([logp, missing], axis=1)[:, table.codes[:, j]]  # code -1 -> the last column
    return scores


def one_hot(table: LexiconTable, entry: int) -> list[np.ndarray]:
    """Per property, a (1, |V|) probability array putting all mass on ``entry``'s value (uniform where
    the entry's value is missing): the classifiers' output when they are certain and right."""
    out = []
    for j, values in enumerate(table.vocab):
        row = np.zeros((1, len(values)))
        code = table.codes[entry, j]
        if code >= 0:
            row[0, code] = 1.0
        else:
            row[0, :] = 1.0 / len(values)
        out.append(row)
    return out


def oracle_scores(table: LexiconTable, true_index: int, with_prior: bool = False) -> np.ndarray:
    """(N,): entries sharing every value (missing included) of entry ``true_index`` score 0 (or their
    log prior), the others -inf."""
    same = (table.codes == table.codes[true_index]).all(axis=1)
    if with_prior:
        return np.where(same, table.log_prior, -np.inf)
    return np.where(same, 0.0, -np.inf)


# --------------------------------------------------------------------------- ranks and metrics


@dataclass(frozen=True)
class Rank:
    """Where the true entry lands: ``above`` entries score higher, ``tied`` score the same (itself
    included); ties are broken at random."""

    above: int
    tied: int

    @property
    def expected(self) -> float:
        return self.above + (self.tied + 1) / 2.0

    def recall_at(self, k: int) -> float:
        return float(min(1.0, max(0.0, (k - self.above) / self.tied)))

    @property
    def reciprocal(self) -> float:
        return float((_harmonic(self.above + self.tied) - _harmonic(self.above)) / self.tied)


def _harmonic(n: int) -> float:
    if n < 1:
        return 0.0
    if n < 10_000:
        return float(np.sum(1.0 / np.arange(1, n + 1)))
    return math.log(n) + 0.5772156649015329 + 1.0 / (2 * n)


def rank_of_true(log_scores: np.ndarray, true_index: int) -> Rank:
    """The rank of entry ``true_index`` among ``log_scores`` (N,), higher first, ties at random."""
    scores = np.asarray(log_scores, dtype=np.float64)
    true = scores[true_index]
    if np.isnan(true):
        raise ValueError("the true entry's score is NaN")
    return Rank(above=int(np.sum(scores > true)), tied=int(np.sum(scores == true)))


def rank_metrics(ranks: Sequence[Rank], recall_at: Sequence[int] = RECALL_AT) -> dict[str, float]:
    """recall@k (expected, mean over clips), mrr, median_rank and mean_rank (of the expected ranks),
    mean_log_rank (mean of log expected rank: the smooth criterion validation selects by)."""
    if not ranks:
        return {**{f"recall@{k}": math.nan for k in recall_at}, "mrr": math.nan, "median_rank": math.nan,
                "mean_rank": math.nan, "mean_log_rank": math.nan, "n": 0}
    expected = np.array([r.expected for r in ranks])
    out = {f"recall@{k}": float(np.mean([r.recall_at(k) for r in ranks])) for k in recall_at}
    out.update(mrr=float(np.mean([r.reciprocal for r in ranks])), median_rank=float(np.median(expected)),
               mean_rank=float(expected.mean()), mean_log_rank=float(np.mean(np.log(expected))), n=len(ranks))
    return out


def recall_curve(ranks: Sequence[Rank], ks: Sequence[int]) -> list[float]:
    """Expected recall@k for every k of ``ks`` (mean over ``ranks``)."""
    return [float(np.mean([r.recall_at(int(k)) for r in ranks])) if ranks else math.nan for k in ks]


def curve_ks(n: int, points: int = 60) -> list[int]:
    """About ``points`` k from 1 to ``n``, evenly spaced on a log scale (1, 10 and 50 included)."""
    grid = np.unique(np.round(np.geomspace(1, n, points)).astype(int))
    return sorted({int(k) for k in grid} | {k for k in RECALL_AT if k <= n} | {n})


def chance_rank(n: int) -> Rank:
    """Every entry scores the same: uniform over 1..n."""
    return Rank(above=0, tied=n)


# --------------------------------------------------------------------------- the lexicon's own figures


def oracle_lexicon(table: LexiconTable, recall_at: Sequence[int] = RECALL_AT) -> dict[str, float]:
    """The oracle over every lexicon entry (each ranked among the entries sharing its values, ties at
    random): recall@k = mean over entries of min(1, k / group size); and chance's k / N."""
    groups = Counter(map(tuple, table.codes.tolist()))
    sizes = np.array([groups[tuple(row)] for row in table.codes.tolist()], dtype=np.float64)
    out = {f"recall@{k}": float(np.mean(np.minimum(1.0, k / sizes))) for k in recall_at}
    out.update({f"chance_recall@{k}": float(min(1.0, k / len(table))) for k in recall_at})
    out.update(median_rank=float(np.median((sizes + 1) / 2)), groups=len(groups),
               unique=int(np.sum(sizes == 1)), entries=len(table), properties=list(table.properties))
    return out


# --------------------------------------------------------------------------- one set of clips


def method_ranks(table: LexiconTable, proba: Sequence[np.ndarray], true_index: Sequence[int], eps: float,
                 eps_combined: float, weight: float, priors: Sequence[np.ndarray] | None = None) -> dict[str, list[Rank]]:
    """Per method of :data:`METHODS`, the rank of each clip's true entry: ``proba[j]`` (n_clips, |V_j|),
    ``true_index`` the clips' entry rows; phonology alone with smoothing ``eps``, combined with
    smoothing ``eps_combined`` and prior weight ``weight``; ``priors`` as :func:`phonology_scores`."""
    empty = np.zeros((0, len(table)))
    alone = phonology_scores(table, proba, eps, priors) if len(true_index) else empty
    both = phonology_scores(table, proba, eps_combined, priors) + weight * table.log_prior if len(true_index) else empty
    out: dict[str, list[Rank]] = {m: [] for m in METHODS}
    for row, true in enumerate(true_index):
        out["chance"].append(chance_rank(len(table)))
        out["prior"].append(rank_of_true(table.log_prior, true))
        out["phonology"].append(rank_of_true(alone[row], true))
        out["phonology+prior"].append(rank_of_true(both[row], true))
        out["oracle"].append(rank_of_true(oracle_scores(table, true), true))
        out["oracle+prior"].append(rank_of_true(oracle_scores(table, true, with_prior=True), true))
    return out


SELECT_BY = {"mean_log_rank": -1, "mean_rank": -1, "median_rank": -1, "mrr": 1,
             **{f"recall@{k}": 1 for k in (1, 5, 10, 20, 50, 100)}}


def choose(table: LexiconTable, proba: Sequence[np.ndarray], true_index: Sequence[int], smoothing: Sequence[float],
           weights: Sequence[float], select_by: str, priors: Sequence[np.ndarray] | None = None) -> dict[str, object]:
    """The smoothing (for phonology alone) and the smoothing and prior weight (combined) that score
    best by ``select_by`` on these clips (the validation glosses'); ties go to the earlier grid value.
    ``priors`` as :func:`phonology_scores`."""
    if select_by not in SELECT_BY:
        raise ValueError(f"select_by={select_by!r}; expected one of {sorted(SELECT_BY)}")
    sign = SELECT_BY[select_by]
    alone, combined = [], []
    for eps in smoothing:
        phonology = phonology_scores(table, proba, eps, priors)
        ranks = [rank_of_true(phonology[r], t) for r, t in enumerate(true_index)]
        alone.append({"smoothing": float(eps), "metrics": rank_metrics(ranks)})
        for w in weights:
            ranks = [rank_of_true(phonology[r] + w * table.log_prior, t) for r, t in enumerate(true_index)]
            combined.append({"smoothing": float(eps), "weight": float(w), "metrics": rank_metrics(ranks)})
    best_alone = max(alone, key=lambda c: sign * c["metrics"][select_by])  # max() keeps the first of equals
    best_combined = max(combined, key=lambda c: sign * c["metrics"][select_by])
    return {"phonology": best_alone, "phonology+prior": best_combined, "select_by": select_by}


# --------------------------------------------------------------------------- the true sign's frequency


# Bands of the true entry's rank by SignFrequency(Z) among all lexicon entries (1 = the most frequent;
# the prior's own rank): WLASL's glosses are common words (the median of the 47 is about 91 of
# 2,723), so lexicon terciles would put nearly all of them in the top third.
FREQUENCY_BAND_EDGES = (100, 500)
BAND_METHODS = ("prior", "phonology", "phonology+prior")


def frequency_rank(table: LexiconTable, entries: Sequence[int]) -> np.ndarray:
    """The expected rank (ties at random) of each of ``entries`` by SignFrequency(Z), highest first."""
    return np.array([rank_of_true(table.log_prior, int(e)).expected for e in entries], dtype=np.float64)


def frequency_band_names(edges: Sequence[int] = FREQUENCY_BAND_EDGES) -> list[str]:
    bounds = [0, *edges]
    return [f"rank {low + 1}-{high}" for low, high in zip(bounds, bounds[1:])] + [f"rank > {edges[-1]}"]


def lexicon_terciles(table: LexiconTable, entries: Sequence[int]) -> dict[str, int]:
    """How many of ``entries`` fall in the low, mid and high third of the lexicon's SignFrequency(Z)."""
    low, high = np.quantile(table.frequency_z, [1 / 3, 2 / 3])
    z = table.frequency_z[np.asarray(entries, dtype=np.int64)]
    return {"low": int(np.sum(z < low)), "mid": int(np.sum((z >= low) & (z < high))), "high": int(np.sum(z >= high))}


def frequency_bands(table: LexiconTable, entries: Sequence[int], ranks: Mapping[str, Sequence[Rank]],
                    recall_at: Sequence[int] = RECALL_AT,
                    edges: Sequence[int] = FREQUENCY_BAND_EDGES) -> list[dict[str, object]]:
    """Per band of the true entry's frequency rank, :func:`rank_metrics` of each method of
    :data:`BAND_METHODS` over the clips whose true entry is in it: ``entries`` are the clips' entry
    rows and ``ranks[method]`` their ranks, in the same order (clips of every split pooled)."""
    entries = np.asarray(entries, dtype=np.int64)
    band = np.searchsorted(np.asarray(edges, dtype=np.float64), frequency_rank(table, entries), side="left")
    out = []
    for b, name in enumerate(frequency_band_names(edges)):
        rows = np.flatnonzero(band == b)
        out.append({"band": name, "clips": int(len(rows)), "glosses": int(len(set(entries[rows].tolist()))),
                    "methods": {m: rank_metrics([ranks[m][r] for r in rows], recall_at) for m in BAND_METHODS}})
    return out
