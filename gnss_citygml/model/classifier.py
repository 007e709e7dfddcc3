"""The C/N0 signal classifier: Pr(open | C/N0) as a 4PL in C/N0.

A signal is *open* when its line of sight to the satellite is clear (LOS, or multipath with a LOS
component) and *closed* otherwise (blocked, NLOS). A blocked signal (no signal received, C/N0
NaN) is always closed. The classifier belongs to one dataset (one device): its parameters are
device and place specific, which is why 4PL-B re-learns them from the map.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import numpy.typing as npt

from .fourpl import fit_4pl, logistic4

__all__ = ["Cn0Counts", "SignalClassifier"]

#: C/N0 values are pooled to this resolution (dB-Hz) when the classifier is fitted: receivers
#: report C/N0 to 0.1 dB-Hz at best, and pooling makes the fit cost independent of the
#: number of signals.
CN0_RESOLUTION = 0.1


@dataclass(frozen=True)
class SignalClassifier:
    """A 4PL in C/N0 (dB-Hz). The defaults are the paper's initial classifier with c = 30.

    Examples
    --------
    >>> clf = SignalClassifier(c=30.0)
    >>> clf.label(np.array([25.0, 35.0, np.nan])).tolist()
    [False, True, False]
    """

    a: float = 0.9
    b: float = 0.2
    c: float = 30.0
    d: float = 0.1

    @classmethod
    def initial(cls, threshold: float) -> SignalClassifier:
        """The paper's initial classifier: a = 0.9, b = 0.2, d = 0.1, c = ``threshold``."""
        return cls(c=float(threshold))

    @property
    def threshold(self) -> float:
        """The C/N0 at which Pr(open) = 0.5 (NaN when the curve never reaches 0.5)."""
        if not self.d < 0.5 < self.a:
            return float("nan")
        return self.c - np.log((self.a - 0.5) / (0.5 - self.d)) / self.b

    def prob(self, cn0: npt.ArrayLike) -> np.ndarray:
        """Pr(open) of each signal; 0 for blocked signals (NaN C/N0)."""
        cn0 = np.asarray(cn0, dtype=float)
        p = logistic4(cn0, self.a, self.b, self.c, self.d)
        return np.where(np.isnan(cn0), 0.0, p)

    def label(self, cn0: npt.ArrayLike, e: npt.ArrayLike = 0.0) -> np.ndarray:
        """The most likely class of each signal: True (open) where Pr(open) > 0.5 (``e``, the
        elevations, are not used: the paper's classifier knows C/N0 only)."""
        return self.prob(cn0) > 0.5

    def refit(self, cn0: npt.ArrayLike, labels: npt.ArrayLike) -> SignalClassifier:
        """The maximum-likelihood classifier for received signals labelled by the map.

        Blocked signals carry no C/N0 and stay closed whatever the classifier, so they are left
        out. The fit starts both from the current classifier and from the best single threshold
        and keeps the likelier. When the labels cannot place a threshold (one class only, or a
        best fit that never reaches Pr(open) = 0.5), the current classifier is kept: co-training
        cannot continue from a classifier that gives every signal the same label.
        """
        return self.refit_counts(Cn0Counts.of(cn0, labels))

    def refit_counts(self, counts: Cn0Counts) -> SignalClassifier:
        """:meth:`refit` from the signals' pooled counts: the same fit, so that parts of a run
        (tiles) can each count their signals and one sum refits the classifier exactly."""
        n, k = counts.n.astype(float), counts.k.astype(float)
        if n.size == 0 or k.sum() in (0.0, n.sum()):
            return self
        x, frac = counts.key * CN0_RESOLUTION, k / n
        fits = [fit_4pl(x, frac, n, init=[[self.a, self.b, self.c, self.d]]), fit_4pl(x, frac, n)]
        best = max(fits, key=lambda f: f.loglik[0] if np.isfinite(f.loglik[0]) else -np.inf)
        new = replace(
            self, a=float(best.a[0]), b=float(best.b[0]), c=float(best.c[0]), d=float(best.d[0])
        )
        return new if np.isfinite(new.threshold) else self


@dataclass(frozen=True)
class Cn0Counts:
    """The received signals pooled by C/N0 (to :data:`CN0_RESOLUTION`): for each C/N0 ``key``
    (C/N0 / resolution, rounded; ascending) how many signals there are (``n``) and how many of
    them the map labels open (``k``). All the classifier's fit needs, and summable."""

    key: np.ndarray
    n: np.ndarray
    k: np.ndarray

    @classmethod
    def of(cls, cn0: npt.ArrayLike, labels: npt.ArrayLike) -> Cn0Counts:
        """The counts of signals with C/N0 ``cn0`` (NaN: blocked, left out) and map labels."""
        cn0 = np.asarray(cn0, dtype=float)
        labels = np.asarray(labels, dtype=bool)
        received = ~np.isnan(cn0)
        key = np.round(cn0[received] / CN0_RESOLUTION).astype(np.int64)
        return cls._pooled(key, np.ones(key.size, dtype=np.int64), labels[received])

    def __add__(self, other: Cn0Counts) -> Cn0Counts:
        """The counts of both sets of signals together."""
        return Cn0Counts._pooled(
            np.concatenate([self.key, other.key]),
            np.concatenate([self.n, other.n]),
            np.concatenate([self.k, other.k]),
        )

    def plus(self, added: Cn0Counts, removed: Cn0Counts) -> Cn0Counts:
        """These counts with ``added``'s signals in and ``removed``'s (counted here) out:
        exact, as the counts are whole numbers; a C/N0 left without a signal is dropped, as
        :meth:`of` would have it."""
        both = Cn0Counts._pooled(
            np.concatenate([self.key, added.key, removed.key]),
            np.concatenate([self.n, added.n, -removed.n]),
            np.concatenate([self.k, added.k, -removed.k]),
        )
        keep = both.n != 0
        return Cn0Counts(both.key[keep], both.n[keep], both.k[keep])

    @classmethod
    def _pooled(cls, key: np.ndarray, n: npt.ArrayLike, k: npt.ArrayLike) -> Cn0Counts:
        uniq, inverse = np.unique(key, return_inverse=True)
        total = np.bincount(inverse, weights=n, minlength=uniq.size).astype(np.int64)
        opened = np.bincount(inverse, weights=k, minlength=uniq.size).astype(np.int64)
        return cls(uniq, total, opened)
