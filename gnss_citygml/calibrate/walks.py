"""A walk's windows hold each other's shifts: the posterior of each window's shift of its fixes
given the shadows of every window of its recording.

A phone's fix error drifts: the reflections that push it come from the same facades for tens of
seconds, so the error of one window of a walk is most of the next window's. Each window alone
often cannot tell where it was (along a street the shadows are the same a few metres on); its
neighbours, a street corner later, can. The shifts of a recording's windows are taken as a
Gaussian first-order autoregressive process in time: stationary at each window's prior
``N(0, sd^2)`` per axis, correlated by ``exp(-dt / tau)`` between windows ``dt`` seconds apart.
On each window's grid of candidate shifts (:mod:`.shadows`) this is a hidden Markov chain whose
transitions factor into the two axes, so the forward-backward pass costs two small matrix
products a window. With ``tau`` 0 each window stands alone (the prior times its own
likelihood).

The forward pass also gives the log marginal likelihood of the shadows, by which the prior's
scale (how far phones understate their errors) and ``tau`` are chosen among a few values from
the data themselves (:func:`walk_offsets`).
"""

from __future__ import annotations

import numpy as np

__all__ = ["walk_offsets"]

#: The correlation times (s) of the fixes' errors tried: a pedestrian passes a facade in tens of
#: seconds, and a phone's filter holds its error for some seconds more; 0 (every window alone)
#: is always among them.
TAUS = (0.0, 10.0, 30.0, 100.0)

#: The factors on the phones' claimed accuracy tried as the prior's standard deviation: phones
#: state their 68 % radius from their own error model, which reflections in streets break
#: (their errors 1.1-2 times what they claim in the published walks and in docs/issue-48-harsh.md).
SCALES = (1.0, 1.5, 2.0)


def walk_offsets(
    score: np.ndarray,
    axis: np.ndarray,
    half: np.ndarray,
    sd: np.ndarray,
    walk: np.ndarray,
    time: np.ndarray,
) -> tuple[np.ndarray, dict[str, float]]:
    """Each window's shift (east, north; m), the posterior mean given its walk's shadows, with
    the prior's scale and correlation time that explain the shadows best.

    Parameters
    ----------
    score
        ``(windows, g * g)``: each window's log-likelihood of its signals at each candidate
        (-inf where ruled out), candidates ordered north-major (``north * g + east``).
    axis
        The ``g`` candidate offsets of one axis in half-widths (-1 .. 1).
    half
        Per window: its grid's half-width (m).
    sd
        Per window: the claimed standard deviation of its shift (m per axis).
    walk, time
        Per window: its recording (an integer) and its time (s).

    Returns
    -------
    (offsets, chosen)
        ``(windows, 2)`` shifts and the chosen ``scale`` and ``tau`` with their log marginal
        likelihood.
    """
    chain = _Chain(score, axis, half, walk, time)
    best = None
    for scale in SCALES:
        for tau in TAUS:
            alpha, evidence = chain.forward(scale * sd, tau)
            if best is None or evidence > best[0] + 1e-9:
                best = (evidence, scale, tau, alpha)
    assert best is not None
    evidence, scale, tau, alpha = best
    post = chain.posterior(alpha, scale * sd, tau)
    g = axis.size
    grid = post.reshape(-1, g, g)
    east = half * np.einsum("wne,e->w", grid, axis)
    north = half * np.einsum("wne,n->w", grid, axis)
    return np.column_stack([east, north]), {"scale": scale, "tau": tau, "evidence": evidence}


class _Chain:
    """The windows ordered along their walks, and each one's likelihood on its grid."""

    def __init__(self, score, axis, half, walk, time):
        self.axis, self.half = axis, half
        self.order = np.lexsort((time, walk))
        w = walk[self.order]
        first = np.r_[True, w[1:] != w[:-1]]
        start = np.maximum.accumulate(np.where(first, np.arange(w.size), 0))
        self.step = np.arange(w.size) - start  # a window's place in its walk
        self.gap = np.where(first, np.inf, np.diff(time[self.order], prepend=0.0))
        peak = np.max(score, axis=1, keepdims=True)
        lik = np.exp(score - np.where(np.isfinite(peak), peak, 0.0))
        lik[~np.isfinite(peak[:, 0])] = 1.0  # every candidate ruled out: no evidence
        self.lik = lik[self.order].reshape(-1, axis.size, axis.size)

    def _prior(self, sd):
        """Each window's stationary prior on its grid, per axis ``(windows, g)``."""
        x = self.half[self.order, None] * self.axis
        p = np.exp(-0.5 * (x / sd[self.order, None]) ** 2)
        return p / p.sum(axis=1, keepdims=True)

    def _moves(self, sd, tau, at):
        """Per axis, the transition ``(n, g, g)`` from the windows before those at ``at`` (in
        walk order) to them: ``x' = rho (sd' / sd) x + N(0, (1 - rho^2) sd'^2)``."""
        rho = np.exp(-self.gap[at] / tau) if tau > 0 else np.zeros(at.size)
        s0, s1 = sd[self.order[at - 1]], sd[self.order[at]]
        x0 = self.half[self.order[at - 1], None] * self.axis
        x1 = self.half[self.order[at], None] * self.axis
        spacing = self.half[self.order[at]] * (self.axis[1] - self.axis[0])
        # the carried shift, not finer than the grid it is carried on
        spread = np.sqrt((1.0 - rho**2) * s1**2 + rho**2 * spacing**2 / 12.0)
        mean = (rho * s1 / s0)[:, None] * x0
        t = np.exp(-0.5 * ((x1[:, None, :] - mean[:, :, None]) / spread[:, None, None]) ** 2)
        return t / t.sum(axis=2, keepdims=True)

    def forward(self, sd, tau):
        """The filtered chances ``(windows, g, g)`` in walk order and the log marginal
        likelihood of every window's shadows."""
        prior = self._prior(sd)
        alpha = np.empty_like(self.lik)
        evidence = 0.0
        for k in range(int(self.step.max(initial=-1)) + 1):
            at = np.flatnonzero(self.step == k)
            if k == 0:
                pred = prior[at][:, :, None] * prior[at][:, None, :]
            else:
                t = self._moves(sd, tau, at)
                pred = np.einsum("wab,wac,wbd->wcd", alpha[at - 1], t, t)
            a = pred * self.lik[at]
            total = a.sum(axis=(1, 2))
            alpha[at] = a / np.maximum(total, 1e-300)[:, None, None]
            evidence += float(np.sum(np.log(np.maximum(total, 1e-300))))
        return alpha, evidence

    def posterior(self, alpha, sd, tau):
        """Each window's posterior chances ``(windows, g * g)``, in the windows' own order,
        from the filtered chances ``alpha`` of :meth:`forward` with the same ``sd`` and
        ``tau``."""
        beta = np.ones_like(alpha)
        last = int(self.step.max(initial=-1))
        for k in range(last, 0, -1):
            at = np.flatnonzero(self.step == k)
            t = self._moves(sd, tau, at)
            b = beta[at] * self.lik[at]
            b = np.einsum("wcd,wac,wbd->wab", b, t, t)
            beta[at - 1] = b / np.maximum(b.sum(axis=(1, 2)), 1e-300)[:, None, None]
        post = alpha * beta
        post /= np.maximum(post.sum(axis=(1, 2)), 1e-300)[:, None, None]
        out = np.empty_like(post)
        out[self.order] = post
        return out.reshape(len(out), -1)
