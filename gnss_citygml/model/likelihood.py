"""The 4PL's Bernoulli log-likelihood, its gradient and its Fisher information (in the
parameters ``theta`` of :mod:`.fourpl`), summed per group over samples sorted by group: the hot
loop of every 4PL fit.

Each group is summed the same way whatever groups surround it, bit for bit (:func:`_blocks`), so
a building's fit in a tile is its fit in the whole run. With numba (the ``fast`` extra) the
groups of at most :data:`BLOCK` samples are summed by compiled loops to the same bits
(:mod:`.fourpl_kernels`); the numpy blocks sum the others, and all groups without numba.
"""

from __future__ import annotations

import numpy as np
from scipy.special import expit

from . import fourpl_kernels

__all__ = ["BLOCK", "EPS", "evaluate"]

#: Probabilities are clipped to this distance from 0 and 1 inside logarithms.
EPS = 1e-12

#: Samples per block of :func:`evaluate`: a block's temporaries stay in the CPU cache and in
#: the allocator's heap; whole-array temporaries are slower by 2x on a few million samples.
BLOCK = 1 << 16


def _blocks(g: np.ndarray) -> list[tuple[int, int, bool]]:
    """The blocks of :func:`evaluate` over samples sorted by group: (start, stop, alone).
    Groups of at most :data:`BLOCK` samples are never split: those that start in one
    stretch of ``BLOCK`` samples make a block. A larger group is ``alone``, in blocks of
    ``BLOCK`` samples counted from its own first. So every group is summed the same way
    whichever groups lie around it: a tile's fit of a building is the whole run's, bit for
    bit, not only to rounding (which a flat likelihood would turn into metres)."""
    if g.size == 0:
        return []
    starts = np.flatnonzero(np.r_[True, g[1:] != g[:-1]])
    sizes = np.diff(np.r_[starts, g.size])
    large = sizes > BLOCK
    stretch = starts // BLOCK
    new = np.r_[True, (stretch[1:] != stretch[:-1]) | large[1:] | large[:-1]]
    first = starts[new]
    blocks = []
    for lo, hi, alone in zip(first, np.r_[first[1:], g.size], large[new], strict=True):
        step = BLOCK if alone else hi - lo
        blocks += [(int(k), int(min(k + step, hi)), bool(alone)) for k in range(lo, hi, step)]
    return blocks


def evaluate(
    theta: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    g: np.ndarray,
    v: np.ndarray,
    n_groups: int,
    active: np.ndarray,
    *,
    ll_only: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Log-likelihood, gradient and Fisher information (in theta) of the active groups
    (gradient and information left at zero with ``ll_only``), summed block by block
    (:func:`_blocks`).

    The hot loop of every fit. Samples sorted by group make each block's sums cover a short
    range of groups (:func:`~.fourpl.fit_4pl` sorts them). With numba, the groups of at most
    :data:`BLOCK` samples are summed by compiled loops, to the same bits
    (:mod:`.fourpl_kernels`)."""
    ll = np.zeros(n_groups)
    grad = np.zeros((n_groups, 4))
    fisher = np.zeros((n_groups, 4, 4))
    a_g, r_g = expit(theta[:, 0]), expit(theta[:, 3])
    c_g = np.ascontiguousarray(theta[:, 2])
    per_group = (a_g, a_g * r_g, np.exp(theta[:, 1]), c_g, r_g)
    if fourpl_kernels.COMPILED:
        large = np.zeros(n_groups, dtype=bool)  # groups of more than a block: numpy's products
        if g.size > BLOCK:  # (none among fewer samples: the Levenberg-Marquardt tail's calls)
            large = np.diff(np.searchsorted(g, np.arange(n_groups + 1))) > BLOCK
        small = active & ~large
        sums = (ll, grad, fisher, ll_only)
        if fourpl_kernels.likelihood_sums(x, y, w, v, g, small, per_group, EPS, *sums):
            active = active & large
            if not active.any():  # (as a rule: a group of more than a block is rare)
                return ll, grad, fisher
    sel = active[g]
    if not sel.all():
        x, y, w, g, v = x[sel], y[sel], w[sel], g[sel], v[sel]
    for lo, hi, alone in _blocks(g):
        block = slice(lo, hi)
        gb = g[block]
        first, last = gb[0], gb[-1] + 1
        sums = _block_sums(
            x[block],
            y[block],
            w[block],
            v[block],
            gb - first,
            per_group,
            first,
            last,
            ll_only,
            alone,
        )
        ll[first:last] += sums[0]
        if not ll_only:
            grad[first:last] += sums[1]
            fisher[first:last] += sums[2]
    return ll, grad, fisher


def _block_sums(x, y, w, v, g, per_group, first, last, ll_only, alone):
    """Per-group sums of one block of samples (``g`` counted from group ``first``). A block of
    a large group (``alone``) sums by matrix products, the others by ``bincount``, which adds
    each group's samples in order whatever the other groups in the block."""
    n = last - first
    if alone:
        a, d, b, c, r = (v[first] for v in per_group)
    else:
        a, d, b, c, r = (np.take(v[first:last], g) for v in per_group)
    x_c = x - c
    kappa = 1.0 / np.sqrt(1.0 + (np.pi / 8.0) * b * b * v)  # v: variance of x; d(b kappa)/db
    s = _sigmoid(b * kappa * x_c)  # = kappa^3, hence the kappa^2 in the slope's jacobian
    p = np.clip(d + (a - d) * s, EPS, 1 - EPS)
    q = 1 - p
    terms = w * (y * np.log(p) + (1 - y) * np.log(q))
    ll = terms.sum(keepdims=True) if alone else np.bincount(g, terms, n)
    if ll_only:
        return (ll,)
    s_low = 1 - s
    dsb = (a - d) * s * s_low * b * kappa
    jac = np.stack(
        np.broadcast_arrays(
            a * (1 - a) * (s + s_low * r), dsb * kappa**2 * x_c, -dsb, s_low * a * r * (1 - r)
        )
    )
    info = w / (p * q)
    resid = info * (y - p)
    if alone:
        return ll, (jac @ resid)[None, :], ((jac * info) @ jac.T)[None, :, :]
    grad = np.column_stack([np.bincount(g, resid * j, n) for j in jac])
    fisher = np.empty((n, 4, 4))
    for i in range(4):
        weighted = info * jac[i]
        for j in range(i, 4):
            fisher[:, i, j] = fisher[:, j, i] = np.bincount(g, weighted * jac[j], n)
    return ll, grad, fisher


def _sigmoid(z):
    """The logistic function, faster than scipy's ``expit`` on large arrays."""
    with np.errstate(over="ignore"):
        return 1.0 / (1.0 + np.exp(-z))
