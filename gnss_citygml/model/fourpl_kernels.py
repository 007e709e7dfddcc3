"""The 4PL likelihood's per-group sums as compiled loops (numba, the optional ``fast`` extra).

:func:`~.fourpl.fit_4pl` spends most of its time summing, per group, each sample's
log-likelihood term, gradient and Fisher information (:func:`~.likelihood._block_sums`). In numpy
every intermediate is a whole array and each of the 15 sums a ``bincount`` pass, about 80 ns a
sample; a compiled loop that gathers each group's parameters and adds into its sums in one
pass takes about a quarter of that.

The sums are the numpy path's bit for bit, so a fit does not depend on whether numba is
installed: every product and sum is taken in the same order (IEEE arithmetic rounds each the
same way), each group's samples are added in order from zero as ``bincount`` adds them, and the
only functions that are not exactly rounded, ``exp`` and ``log``, are numpy's own, called on
whole arrays between the loops (:func:`likelihood_sums`). ``tests/test_fourpl_kernels.py`` holds the
two paths to that.

Without numba, :data:`COMPILED` is False and :mod:`.fourpl` sums in numpy.
"""

from __future__ import annotations

import numpy as np

try:
    import numba
except ImportError:  # the optional ``fast`` extra is not installed
    numba = None  # type: ignore[assignment]

__all__ = ["COMPILED", "likelihood_sums"]

#: Whether the compiled sums are available (numba is installed).
COMPILED = numba is not None

#: pi / 8 of the probit approximation's slope shrinkage (:mod:`.fourpl`).
_PROBIT = np.pi / 8.0


def _compiled(func):
    """``func`` compiled once per machine (numba's cache), releasing the GIL."""
    return numba.njit(cache=True, nogil=True)(func) if COMPILED else func


@_compiled
def _exponents(x, v, g, b_g, c_g, out):
    """Each sample's ``-b kappa (x - c)``, the logistic's exponent (a loop without branches:
    the compiler makes it vector instructions)."""
    for i in range(x.size):
        b = b_g[g[i]]
        kappa = 1.0 / np.sqrt(1.0 + _PROBIT * b * b * v[i])
        out[i] = -(b * kappa * (x[i] - c_g[g[i]]))


@_compiled
def _probabilities(e, y, g, a_g, d_g, eps, p, q, chosen):
    """Each sample's ``p = d + (a - d) s`` (``s = 1 / (1 + e)``) clipped to ``[eps, 1 - eps]``,
    ``q = 1 - p``, and the one its label ``y`` (0 or 1) picks (``p`` for 1, ``q`` for 0); the
    number of samples whose label is a fraction, for which both are needed."""
    n_soft = 0
    for i in range(e.size):
        a, d = a_g[g[i]], d_g[g[i]]
        pi = min(max(d + (a - d) * (1.0 / (1.0 + e[i])), eps), 1 - eps)
        p[i] = pi
        q[i] = 1 - pi
        chosen[i] = pi if y[i] == 1.0 else 1 - pi
        n_soft += (y[i] != 0.0) & (y[i] != 1.0)
    return n_soft


@_compiled
def _sums(x, y, w, v, g, sel, params, e, p, q, log_p, log_q, ll, grad, fisher, ll_only):
    """Add each selected sample's log-likelihood term (and, unless ``ll_only``, its gradient
    and Fisher information in theta) to its group's, in the samples' order (sorted by group:
    each group's sums are kept in registers until its last sample)."""
    a_g, d_g, b_g, c_g, r_g = params
    jac = np.zeros(4)
    acc = np.zeros(15)  # ll, the gradient's 4, the information's upper triangle's 10
    n_rows = x.size
    for i in range(n_rows):
        k = g[i]
        if not sel[k]:
            continue
        yi, wi = y[i], w[i]
        acc[0] += wi * (yi * log_p[i] + (1 - yi) * log_q[i])
        if not ll_only:
            a, d, b, r = a_g[k], d_g[k], b_g[k], r_g[k]
            x_c = x[i] - c_g[k]
            kappa = 1.0 / np.sqrt(1.0 + _PROBIT * b * b * v[i])
            s = 1.0 / (1.0 + e[i])
            s_low = 1 - s
            dsb = (a - d) * s * s_low * b * kappa
            jac[0] = a * (1 - a) * (s + s_low * r)
            jac[1] = dsb * (kappa * kappa) * x_c
            jac[2] = -dsb
            jac[3] = s_low * a * r * (1 - r)
            info = wi / (p[i] * q[i])
            resid = info * (yi - p[i])
            at = 5
            for m in range(4):
                acc[1 + m] += resid * jac[m]
                weighted = info * jac[m]
                for n in range(m, 4):
                    acc[at] += weighted * jac[n]
                    at += 1
        if i + 1 == n_rows or g[i + 1] != k:  # the group's last sample: its sums are done
            ll[k] += acc[0]
            at = 5
            for m in range(4):
                grad[k, m] += acc[1 + m]
                for n in range(m, 4):
                    fisher[k, m, n] += acc[at]
                    fisher[k, n, m] = fisher[k, m, n]
                    at += 1
            acc[:] = 0.0


def likelihood_sums(x, y, w, v, g, sel, per_group, eps, ll, grad, fisher, ll_only):
    """Add the samples of the groups in ``sel`` to their groups' log-likelihoods ``ll`` (and,
    unless ``ll_only``, gradients ``grad`` and Fisher informations ``fisher``), as
    :func:`~.likelihood._block_sums` sums them. ``per_group``: each group's ``(a, d, b, c, r)``
    (:func:`~.likelihood.evaluate`); ``v``: the variances of ``x``; ``eps``: the clip of
    probabilities."""
    a_g, d_g, b_g, c_g, r_g = per_group
    e = np.empty(x.size)
    _exponents(x, v, g, b_g, c_g, e)
    with np.errstate(over="ignore"):  # exp(large) = inf makes s = 0, as in numpy's path
        np.exp(e, out=e)
    p, q, chosen = np.empty(x.size), np.empty(x.size), np.empty(x.size)
    if _probabilities(e, y, g, a_g, d_g, eps, p, q, chosen):
        log_p, log_q = np.log(p), np.log(q)
    else:  # labels 0 or 1: y log(p) + (1 - y) log(q) is the chosen one's log, to the bit
        log_p = log_q = np.log(chosen)  # (the other term is a signed zero)
    _sums(x, y, w, v, g, sel, per_group, e, p, q, log_p, log_q, ll, grad, fisher, ll_only)
