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
whole arrays between the loops (:func:`likelihood_sums`). ``tests/test_fourpl_kernels.py``
holds the two paths to that.

Without numba, :data:`COMPILED` is False and :mod:`.fourpl` sums in numpy; so it does where
numba is installed but does not work (:func:`_compiled`).
"""

from __future__ import annotations

import importlib.util
import threading
import warnings
from types import SimpleNamespace

import numpy as np

from ..errors import first_line

__all__ = ["COMPILED", "likelihood_sums"]

#: Whether numba is installed (the loops are compiled at the first fit: importing numba costs
#: half a second and 60 MB that a run pays only when it fits).
COMPILED = importlib.util.find_spec("numba") is not None

#: pi / 8 of the probit approximation's slope shrinkage (:mod:`.fourpl`).
_PROBIT = np.pi / 8.0

_LOCK = threading.Lock()
_LOOPS: list[SimpleNamespace | None] = []


def _loops() -> SimpleNamespace | None:
    """The loops below compiled (once per machine: numba's cache), releasing the GIL; None,
    with one warning, where numba is installed but does not work (:func:`_compiled`)."""
    with _LOCK:  # the first fits may start in several threads at once
        if not _LOOPS:
            _LOOPS.append(_compiled())
        return _LOOPS[0]


def _compiled() -> SimpleNamespace | None:
    """The loops compiled and run once on a few samples of the fits' types, or None with a
    warning naming the error. A numba that is installed but broken fails in many ways:
    ImportError (built for another numpy), llvmlite's OSError or RuntimeError (its LLVM
    library missing or of another version), numba's ValueError on a ``NUMBA_NUM_THREADS`` it
    refuses, numba's own errors when it compiles. The numpy path gives the same bits, so
    each of them leaves the fits to it rather than stop a run."""
    try:
        import numba

        jit = numba.njit(cache=True, nogil=True)
        funcs = (_exponents, _probabilities, _log_likelihoods, _sums)
        loops = SimpleNamespace(**{f.__name__[1:]: jit(f) for f in funcs})
        _trial(loops)
    except Exception as error:  # (whatever a broken install raises: see above)
        warnings.warn(
            f"numba does not work ({type(error).__name__}: {first_line(error)}): the fits "
            "sum in numpy",
            stacklevel=4,
        )
        return None
    return loops


def _trial(loops: SimpleNamespace) -> None:
    """Run (so compile) each loop on two samples of the types :func:`likelihood_sums` gets."""
    x = np.array([1.0, 2.0])
    g = np.zeros(2, dtype=np.intp)
    one = np.ones(1)
    per_group = (one * 0.9, one * 0.1, one, one, one * 0.5)
    sums = (np.zeros(1), np.zeros((1, 4)), np.zeros((1, 4, 4)))
    for ll_only in (True, False):
        _run(loops, x, x * 0 + 1, x, x, g, np.ones(1, dtype=bool), per_group, 1e-9, *sums, ll_only)


def _exponents(x, v, g, b_g, c_g, kappa, out):
    """Each sample's slope shrinkage ``kappa`` and ``-b kappa (x - c)``, the logistic's
    exponent (a loop without branches: the compiler makes it vector instructions)."""
    for i in range(x.size):
        b = b_g[g[i]]
        kappa[i] = 1.0 / np.sqrt(1.0 + _PROBIT * b * b * v[i])
        out[i] = -(b * kappa[i] * (x[i] - c_g[g[i]]))


def _probabilities(e, y, g, a_g, d_g, eps, s, p, q, chosen):
    """Each sample's logistic ``s = 1 / (1 + e)``, ``p = d + (a - d) s`` clipped to
    ``[eps, 1 - eps]``, ``q = 1 - p``, and the one its label ``y`` (0 or 1) picks (``p`` for 1,
    ``q`` for 0); the number of samples whose label is a fraction, for which both are needed."""
    n_soft = 0
    for i in range(e.size):
        a, d = a_g[g[i]], d_g[g[i]]
        s[i] = 1.0 / (1.0 + e[i])
        pi = min(max(d + (a - d) * s[i], eps), 1 - eps)
        p[i] = pi
        q[i] = 1 - pi
        chosen[i] = pi if y[i] == 1.0 else 1 - pi
        n_soft += (y[i] != 0.0) & (y[i] != 1.0)
    return n_soft


def _log_likelihoods(y, w, g, sel, log_p, log_q, ll):
    """Add each selected sample's log-likelihood term to its group's, in the samples' order."""
    for i in range(y.size):
        if sel[g[i]]:
            ll[g[i]] += w[i] * (y[i] * log_p[i] + (1 - y[i]) * log_q[i])


def _sums(x, y, w, g, sel, params, kappa, s, p, q, log_p, log_q, ll, grad, fisher):
    """Add each selected sample's log-likelihood term, gradient and Fisher information (in
    theta) to its group's, in the samples' order (sorted by group: a group's 15 sums stay in
    registers until its last sample)."""
    a_g, d_g, b_g, c_g, r_g = params
    n_rows = x.size
    l0 = g0 = g1 = g2 = g3 = 0.0
    f00 = f01 = f02 = f03 = f11 = f12 = f13 = f22 = f23 = f33 = 0.0
    for i in range(n_rows):
        k = g[i]
        if not sel[k]:
            continue
        yi, wi, pi = y[i], w[i], p[i]
        l0 += wi * (yi * log_p[i] + (1 - yi) * log_q[i])
        a, d, r = a_g[k], d_g[k], r_g[k]
        si, ki = s[i], kappa[i]
        s_low = 1 - si
        dsb = (a - d) * si * s_low * b_g[k] * ki
        j0 = a * (1 - a) * (si + s_low * r)
        j1 = dsb * (ki * ki) * (x[i] - c_g[k])
        j2 = -dsb
        j3 = s_low * a * r * (1 - r)
        info = wi / (pi * q[i])
        resid = info * (yi - pi)
        g0 += resid * j0
        g1 += resid * j1
        g2 += resid * j2
        g3 += resid * j3
        w0, w1, w2, w3 = info * j0, info * j1, info * j2, info * j3
        f00 += w0 * j0
        f01 += w0 * j1
        f02 += w0 * j2
        f03 += w0 * j3
        f11 += w1 * j1
        f12 += w1 * j2
        f13 += w1 * j3
        f22 += w2 * j2
        f23 += w2 * j3
        f33 += w3 * j3
        if i + 1 == n_rows or g[i + 1] != k:  # the group's last sample: its sums are done
            ll[k] += l0
            grad[k, 0] += g0
            grad[k, 1] += g1
            grad[k, 2] += g2
            grad[k, 3] += g3
            upper = (f00, f01, f02, f03, f11, f12, f13, f22, f23, f33)
            at = 0
            for m in range(4):
                for n in range(m, 4):
                    fisher[k, m, n] = fisher[k, n, m] = fisher[k, m, n] + upper[at]
                    at += 1
            l0 = g0 = g1 = g2 = g3 = 0.0
            f00 = f01 = f02 = f03 = f11 = f12 = f13 = f22 = f23 = f33 = 0.0


def likelihood_sums(
    x: np.ndarray,
    y: np.ndarray,
    w: np.ndarray,
    v: np.ndarray,
    g: np.ndarray,
    sel: np.ndarray,
    per_group: tuple[np.ndarray, ...],
    eps: float,
    ll: np.ndarray,
    grad: np.ndarray,
    fisher: np.ndarray,
    ll_only: bool,
) -> bool:
    """Add the samples of the groups in ``sel`` to their groups' log-likelihoods ``ll`` (and,
    unless ``ll_only``, gradients ``grad`` and Fisher informations ``fisher``), as
    :func:`~.likelihood._block_sums` sums them; False (nothing added) where numba does not
    work (:func:`_compiled`). ``per_group``: each group's ``(a, d, b, c, r)``
    (:func:`~.likelihood.evaluate`); ``v``: the variances of ``x``; ``eps``: the clip of
    probabilities."""
    loops = _loops()
    if loops is None:
        return False
    _run(loops, x, y, w, v, g, sel, per_group, eps, ll, grad, fisher, ll_only)
    return True


def _run(loops, x, y, w, v, g, sel, per_group, eps, ll, grad, fisher, ll_only) -> None:
    """:func:`likelihood_sums` with the compiled ``loops``."""
    a_g, d_g, b_g, c_g, r_g = per_group
    kappa, e = np.empty(x.size), np.empty(x.size)
    loops.exponents(x, v, g, b_g, c_g, kappa, e)
    with np.errstate(over="ignore"):  # exp(large) = inf makes s = 0, as in numpy's path
        np.exp(e, out=e)
    s, p, q, chosen = np.empty(x.size), np.empty(x.size), np.empty(x.size), e  # e is done with
    if loops.probabilities(e, y, g, a_g, d_g, eps, s, p, q, chosen):
        log_p, log_q = np.log(p), np.log(q)
    else:  # labels 0 or 1: y log(p) + (1 - y) log(q) is the chosen one's log, to the bit
        log_p = log_q = np.log(chosen)  # (the other term is a signed zero)
    if ll_only:
        loops.log_likelihoods(y, w, g, sel, log_p, log_q, ll)
    else:
        loops.sums(x, y, w, g, sel, per_group, kappa, s, p, q, log_p, log_q, ll, grad, fisher)
