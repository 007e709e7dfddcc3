"""The mixture signal model: how open and closed signals' C/N0 are distributed, learnt by EM.

The paper's signal classifier is a threshold on C/N0 refitted to the map's hard labels, which
feed back on themselves: where most signals below a roof arrive reflected, a threshold that
climbs labels more of them closed, which moves the roof lines up, which labels more closed.
This model is generative instead. A signal is *open* (its line of sight clears every building)
or *closed*; each class has its own chance of being received and, when received, a Gaussian
C/N0 whose mean changes linearly with elevation (the antenna's gain pattern, the longer path
through the atmosphere at low elevation)::

    open:   received with chance q_o;  C/N0 ~ N(alpha_o + beta_o e, sigma_o^2)
    closed: received with chance q_c;  C/N0 ~ N(alpha_c + beta_c e, sigma_c^2)

with ``e`` the elevation in units of 90 degrees (0 without elevations). A building's 4PL in
intersection height is the *prior* chance that a signal clears it; the posterior chance that
a signal is open weighs that prior by the two classes' likelihoods of what was received
(:meth:`Cn0Mixture.posterior`). 4PL-B then fits each building's 4PL to these soft labels and
the classes' parameters to the signals weighted by them (expectation-maximisation), and the
rays that cross no footprint, open as far as the map knows, pin the open class: a training
set that needs no map label, so the open class cannot run away.

A signal is open only if it clears every building it crosses: a closed one is blamed on each
building in proportion to the chance that this building is the one that blocks it
(:meth:`Cn0Mixture.row_labels`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.special import expit

from .fourpl import logistic4

__all__ = ["Cn0Mixture", "Cn0Moments", "clear_chance", "clears_all", "elevation_units"]

#: Smallest standard deviation (dB-Hz) of a class's C/N0 about its elevation trend: the fading
#: of a clear line of sight and receivers' 0.1-1 dB-Hz reporting keep it above this.
MIN_SIGMA = 1.0
#: A class's chance of being received stays this far from 0 and 1: a single reflected signal
#: of a class never seen received must not be impossible.
MIN_CHANCE = 1e-3
#: A prior chance stays this far from 0 and 1, so that a received signal can overrule it.
PRIOR_EPS = 1e-6
#: 4PL-B goes on while the mixture moves by more than this (dB) or :data:`SETTLED_CHANCE`
#: between iterations: a tenth of a dB is the C/N0 receivers report.
SETTLED_DB = 0.1
SETTLED_CHANCE = 0.01
#: The elevation (model units: 45 degrees) at which the model is drawn and summed up in one
#: threshold for a reader (:attr:`Cn0Mixture.threshold`).
MID_ELEVATION = 0.5
#: Received signals crossing no footprint the mixture needs to start from them alone.
MIN_SKY = 30
#: Sums kept per class (:class:`Cn0Moments`): over received signals the weight and its
#: products with e, e^2, C/N0, e C/N0 and C/N0^2; then the weight of those not received.
_SUMS = 7


def clear_chance(
    h: np.ndarray,
    g: np.ndarray,
    sd: np.ndarray | None,
    a: np.ndarray,
    b: np.ndarray,
    c: np.ndarray,
    d: np.ndarray,
) -> np.ndarray:
    """Each row's prior chance of clearing its building ``g`` at height ``h``: the building's
    4PL (``a``-``d`` per building; 0.5 where it has no fit), its slope blurred by the row's
    height error ``sd`` as in the errors-in-variables fit (:mod:`.fourpl`)."""
    slope = b[g] if sd is None else b[g] / np.sqrt(1.0 + np.pi * (b[g] * sd) ** 2 / 8.0)
    p = logistic4(h, a[g], slope, c[g], d[g])
    return np.where(np.isfinite(p), p, 0.5)


def clears_all(prior: np.ndarray, signal: np.ndarray) -> np.ndarray:
    """Each row's chance that its ray clears every building it crosses: the product of the
    ``prior`` chances of the rows of its ``signal`` (each kept :data:`PRIOR_EPS` from 0
    and 1)."""
    p = np.clip(prior, PRIOR_EPS, 1 - PRIOR_EPS)
    n_sig = int(signal.max(initial=-1)) + 1
    return np.exp(np.bincount(signal, np.log(p), n_sig))[signal]


def elevation_units(elevation_deg: npt.ArrayLike) -> np.ndarray:
    """Elevations (degrees) in the model's units (90 degrees = 1; unknown: 0)."""
    return np.nan_to_num(np.asarray(elevation_deg, dtype=float) / 90.0, copy=False)


@dataclass(frozen=True)
class Cn0Moments:
    """Weighted sums of the signals of each class (row 0 open, row 1 closed), all the
    mixture's fit needs; parts of a run (tiles) add theirs up exactly."""

    sums: np.ndarray

    @classmethod
    def of(cls, cn0: npt.ArrayLike, e: npt.ArrayLike, open_chance: npt.ArrayLike) -> Cn0Moments:
        """The sums of signals with C/N0 ``cn0`` (NaN: not received), elevations ``e`` (model
        units) and chance ``open_chance`` of being open (1/0 for hard labels)."""
        s = np.asarray(cn0, dtype=float)
        e = np.broadcast_to(np.asarray(e, dtype=float), s.shape)
        r = np.broadcast_to(np.asarray(open_chance, dtype=float), s.shape)
        got = np.isfinite(s)
        sums = np.empty((2, _SUMS))
        for row, w in enumerate((r, 1.0 - r)):
            wg, eg, sg = w[got], e[got], s[got]
            sums[row] = [
                wg.sum(),
                (wg * eg).sum(),
                (wg * eg * eg).sum(),
                (wg * sg).sum(),
                (wg * eg * sg).sum(),
                (wg * sg * sg).sum(),
                w[~got].sum(),
            ]
        return cls(sums)

    @classmethod
    def empty(cls) -> Cn0Moments:
        """No signals."""
        return cls(np.zeros((2, _SUMS)))

    def __add__(self, other: Cn0Moments) -> Cn0Moments:
        """Both sets of signals together."""
        return Cn0Moments(self.sums + other.sums)

    @property
    def seen(self) -> bool:
        """Whether the open class has enough received signals to start the mixture from them
        (:meth:`Cn0Mixture.initial`): at least :data:`MIN_SKY`."""
        return bool(self.sums[0, 0] >= MIN_SKY)

    def __sub__(self, other: Cn0Moments) -> Cn0Moments:
        """These signals less ``other``, some of them (a run's signals less those that cross
        a footprint: those that cross none)."""
        return Cn0Moments(self.sums - other.sums)


@dataclass(frozen=True)
class Cn0Mixture:
    """The two classes' parameters: ``alpha`` + ``beta`` e (dB-Hz), ``sigma`` (dB-Hz) and the
    chance of being received ``q``, each ``(open, closed)``."""

    alpha: tuple[float, float]
    beta: tuple[float, float]
    sigma: tuple[float, float]
    q: tuple[float, float]

    @classmethod
    def initial(cls, open_sky: Cn0Moments) -> Cn0Mixture:
        """Where 4PL-B with the mixture starts when the sky is seen: the open class fitted to
        the signals that cross no footprint, the closed class below it by twice the open
        class's spread (where few of the open signals are), as widely spread, and received
        half the time. No C/N0 threshold is needed: the map's first fits and the EM that
        follows place the closed class where the data put it."""
        sky = cls.fitted(open_sky)
        alpha, beta, sigma, q = sky.alpha[0], sky.beta[0], sky.sigma[0], sky.q[0]
        return cls((alpha, alpha - 2.0 * sigma), (beta, beta), (sigma, sigma), (q, 0.5))

    @classmethod
    def fitted(cls, moments: Cn0Moments) -> Cn0Mixture:
        """The maximum-likelihood parameters for the weighted signals (weighted least squares
        of C/N0 on elevation per class; where the elevations do not spread, a flat mean).

        The closed class's mean is kept below the open one's at every elevation of the model's
        range (a reflection loses power, a blocked ray does not gain any): where the weights
        say otherwise, the classes are not separated and the closed class takes the open one's
        mean less its own spread, so that it cannot take the open signals' place.
        """
        alpha, beta, sigma, q = [], [], [], []
        for w, we, wee, ws, wes, wss, w_lost in moments.sums:
            if w <= 0:
                a0, b0, var = np.nan, 0.0, np.nan
            else:
                e_mean, s_mean = we / w, ws / w
                e_var = wee / w - e_mean**2
                b0 = (wes / w - e_mean * s_mean) / e_var if e_var > 1e-6 else 0.0
                a0 = s_mean - b0 * e_mean
                var = wss / w - s_mean**2 - b0 * (wes / w - e_mean * s_mean)
            alpha.append(a0)
            beta.append(b0)
            sigma.append(float(np.sqrt(max(var, MIN_SIGMA**2))) if np.isfinite(var) else np.nan)
            total = w + w_lost
            q.append(float(np.clip(w / total, MIN_CHANCE, 1 - MIN_CHANCE)) if total > 0 else 0.5)
        if np.isnan(alpha[0]):  # nothing received is open: the model cannot say anything
            alpha[0], beta[0], sigma[0] = np.inf, 0.0, MIN_SIGMA
        ends = np.array([0.0, 1.0])
        if np.isnan(alpha[1]) or np.any(alpha[1] + beta[1] * ends > alpha[0] + beta[0] * ends):
            spread = sigma[1] if np.isfinite(sigma[1]) else sigma[0]
            alpha[1], beta[1], sigma[1] = alpha[0] - spread, beta[0], spread
        return cls(
            (float(alpha[0]), float(alpha[1])),
            (float(beta[0]), float(beta[1])),
            (float(sigma[0]), float(sigma[1])),
            (q[0], q[1]),
        )

    def settled(self, before: Cn0Mixture | object) -> bool:
        """Whether the model moved less than :data:`SETTLED_DB` in each class's mean (at both
        ends of the elevations) and spread, and :data:`SETTLED_CHANCE` in its chances of being
        received, since ``before`` (anything else: it has not settled)."""
        if not isinstance(before, Cn0Mixture):
            return False
        ends = np.array([0.0, 1.0])
        now, then = np.array(
            [[m.alpha[k] + m.beta[k] * ends for k in (0, 1)] for m in (self, before)]
        )
        spread = np.abs(np.subtract(self.sigma, before.sigma))
        chance = np.abs(np.subtract(self.q, before.q))
        return bool(
            np.all(np.abs(now - then) < SETTLED_DB)
            and np.all(spread < SETTLED_DB)
            and np.all(chance < SETTLED_CHANCE)
        )

    def log_ratio(self, cn0: npt.ArrayLike, e: npt.ArrayLike) -> np.ndarray:
        """log of (likelihood if open / likelihood if closed) of each signal."""
        s = np.asarray(cn0, dtype=float)
        got = np.isfinite(s)
        logs = []
        for k in (0, 1):
            z = (np.where(got, s, 0.0) - self.alpha[k] - self.beta[k] * np.asarray(e)) / self.sigma[
                k
            ]
            received = np.log(self.q[k]) - np.log(self.sigma[k]) - 0.5 * z * z
            logs.append(np.where(got, received, np.log1p(-self.q[k])))
        return logs[0] - logs[1]

    def posterior(self, cn0: npt.ArrayLike, e: npt.ArrayLike, prior: npt.ArrayLike) -> np.ndarray:
        """The chance that each signal is open given what was received and the ``prior``
        chance that its ray is clear."""
        p = np.clip(np.asarray(prior, dtype=float), PRIOR_EPS, 1 - PRIOR_EPS)
        return expit(np.log(p) - np.log1p(-p) + self.log_ratio(cn0, e))

    def row_labels(
        self, cn0: np.ndarray, e: np.ndarray, prior: np.ndarray, signal: np.ndarray
    ) -> np.ndarray:
        """The chance that each row's ray clears its building (soft labels for the building's
        4PL), rows of one ``signal`` being one ray: it is open with the :meth:`posterior` of
        the chance that it clears them all (the product of the rows' ``prior``), and closed
        otherwise, when a building clears it with chance ``(prior - all) / (1 - all)``."""
        p = np.clip(prior, PRIOR_EPS, 1 - PRIOR_EPS)
        clear_all = clears_all(p, signal)
        is_open = self.posterior(cn0, e, clear_all)
        clears_if_closed = (p - clear_all) / np.maximum(1.0 - clear_all, PRIOR_EPS)
        return is_open + (1.0 - is_open) * np.clip(clears_if_closed, 0.0, 1.0)

    def prob(self, cn0: npt.ArrayLike, e: npt.ArrayLike = MID_ELEVATION) -> np.ndarray:
        """The chance that each signal is open with an even prior (elevations ``e`` in the
        model's units, by default :data:`MID_ELEVATION`), as the paper's classifier gives it."""
        return self.posterior(cn0, e, 0.5)

    @property
    def threshold(self) -> float:
        """The C/N0 where a received signal at :data:`MID_ELEVATION` is as likely open as
        closed with an even prior (NaN where it never is, between the classes' means)."""
        lo = self.alpha[1] + self.beta[1] * MID_ELEVATION
        hi = self.alpha[0] + self.beta[0] * MID_ELEVATION
        grid = np.linspace(lo, hi, 2001) if np.isfinite(hi) and hi > lo else np.empty(0)
        ratio = self.log_ratio(grid, MID_ELEVATION)
        up = np.flatnonzero((ratio[:-1] <= 0) & (ratio[1:] > 0))
        return float(grid[up[-1] + 1]) if up.size else float("nan")

    def label(self, cn0: npt.ArrayLike, e: npt.ArrayLike = 0.0) -> np.ndarray:
        """The likelier class of each signal (elevations ``e`` in the model's units) with an
        even prior: True (open) where the open class explains it better."""
        return self.log_ratio(cn0, e) > 0
