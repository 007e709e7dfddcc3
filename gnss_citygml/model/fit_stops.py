"""How each fit of :func:`~.fourpl.fit_4pl` stopped (``stops=True``): a diagnostic that tells
why a fit did not meet its tolerance (``benchmarks/fit_settling.py``), kept apart from the fit
itself, which only tells it each iteration's steps.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["STOPS_WINDOW", "FitStops", "Trace"]


@dataclass(frozen=True)
class FitStops:
    """How each group's fit of :func:`fit_4pl` stopped, to tell why a fit did not meet its
    tolerance (arrays of length ``n_groups``; ``(n_groups, 4)`` for the parameters ``theta``:
    the logits of ``a`` and ``d / a``, ``log b`` and ``c``)."""

    #: The last step's log-likelihood gain, relative to ``1 + |loglik|`` (the tolerance's
    #: scale), and whether it was accepted.
    gain: np.ndarray
    accepted: np.ndarray
    #: Steps rejected in the last :data:`STOPS_WINDOW` iterations of the cap, and in all.
    rejected_late: np.ndarray
    rejected: np.ndarray
    #: The damping at the end.
    lam: np.ndarray
    #: The parameters on their box's lower and upper end at the end.
    at_lower: np.ndarray
    at_upper: np.ndarray
    #: How far each parameter moved over the second half of the cap's iterations.
    drift: np.ndarray


#: The last iterations of the cap over which :class:`FitStops` counts rejected steps.
STOPS_WINDOW = 20


class Trace:
    """What :class:`FitStops` records, told each iteration's steps by
    :func:`_levenberg_marquardt`."""

    def __init__(self, theta: np.ndarray, max_iter: int):
        n = theta.shape[0]
        self.max_iter, self.k = max_iter, 0
        self.gain, self.accepted = np.zeros(n), np.ones(n, dtype=bool)
        self.rejected_late, self.rejected = np.zeros(n, dtype=int), np.zeros(n, dtype=int)
        self.lam, self.half = np.zeros(n), theta.copy()

    def step(
        self,
        idx: np.ndarray,
        gain: np.ndarray,
        accept: np.ndarray,
        lam: np.ndarray,
        theta: np.ndarray,
    ) -> None:
        """Iteration ``k``'s steps of the groups ``idx`` (their relative gains, whether
        accepted), the damping after it and the parameters."""
        self.k += 1
        self.gain[idx], self.accepted[idx] = gain, accept
        self.rejected[idx[~accept]] += 1
        if self.k > self.max_iter - STOPS_WINDOW:
            self.rejected_late[idx[~accept]] += 1
        self.lam[idx] = lam[idx]
        if self.k == self.max_iter // 2:
            self.half = theta.copy()

    def stops(
        self, theta: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray
    ) -> tuple[np.ndarray, ...]:
        """:class:`FitStops`' fields at the end, given the final parameters and the box."""
        at_lower, at_upper = theta <= box_lo + 1e-9, theta >= box_hi - 1e-9
        own = (self.gain, self.accepted, self.rejected_late, self.rejected, self.lam)
        return (*own, at_lower, at_upper, theta - self.half)
