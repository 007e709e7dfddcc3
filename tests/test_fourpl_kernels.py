"""The compiled sums of the 4PL likelihood (numba) against numpy's: the same bits."""

import os
import subprocess
import sys

import numpy as np
import pytest
from conftest import draw_4pl

from gnss_citygml.model import fourpl, fourpl_kernels, interval, likelihood


@pytest.fixture
def numpy_only(monkeypatch):
    """Sum in numpy, as without numba."""
    monkeypatch.setattr(fourpl_kernels, "COMPILED", False)


def test_numba_is_installed():
    """The dev extra installs numba: without it every other test would run the numpy path only
    and this file's comparisons would compare numpy with itself."""
    assert fourpl_kernels.COMPILED and fourpl_kernels._loops() is not None


def test_a_numba_that_does_not_import_leaves_the_fits_to_numpy(rng, monkeypatch):
    """Installed but broken (e.g. built for another numpy): a warning, and numpy's sums."""
    x, y, w, g, v = _samples(rng, [30, 500])
    theta = np.array([[1.0, 0.0, 30.0, -1.0], [0.5, -1.0, 20.0, 0.0]])
    active = np.ones(2, dtype=bool)
    expected = likelihood.evaluate(theta, x, y, w, g, v, 2, active)
    monkeypatch.setattr(fourpl_kernels, "_LOOPS", [])  # not loaded yet
    monkeypatch.setitem(sys.modules, "numba", None)  # its import fails
    with pytest.warns(UserWarning, match="numba does not work"):
        got = likelihood.evaluate(theta, x, y, w, g, v, 2, active)
    assert all(np.array_equal(a, b) for a, b in zip(got, expected, strict=True))


def _samples(rng, sizes):
    """Groups of the given sizes, sorted by group: soft and hard labels, zero and positive
    weights and errors in x."""
    g = np.repeat(np.arange(len(sizes)), sizes)
    x = rng.uniform(0.0, 60.0, g.size)
    y = np.where(rng.random(g.size) < 0.5, rng.random(g.size) < 0.5, rng.random(g.size))
    w = np.where(rng.random(g.size) < 0.1, 0.0, rng.uniform(0.2, 2.0, g.size))
    v = np.where(rng.random(g.size) < 0.3, 0.0, rng.uniform(0.0, 4.0, g.size))
    return x, y.astype(float), w, g, v


@pytest.mark.parametrize("ll_only", [False, True])
@pytest.mark.parametrize("labels", ["hard", "soft"])
def test_the_compiled_sums_are_numpys_bit_for_bit(rng, monkeypatch, ll_only, labels):
    """Groups packed in blocks and one larger than a block; some groups inactive; parameters
    from gentle to so steep that exp overflows and p is clipped; labels 0 or 1 (one logarithm
    a sample), or some fractions (both)."""
    sizes = [1, 2, 40, 3000, likelihood.BLOCK + 17, 5, 700]
    x, y, w, g, v = _samples(rng, sizes)
    if labels == "hard":
        y = np.round(y)
    n = len(sizes)
    theta = np.column_stack(
        [rng.normal(0, 3, n), rng.uniform(-7, 5, n), rng.uniform(0, 60, n), rng.normal(0, 3, n)]
    )
    theta[1] = [9.0, np.log(100.0), 30.0, -9.0]  # on the box: p clipped at eps
    active = np.array([True, True, False, True, True, True, True])
    compiled = likelihood.evaluate(theta, x, y, w, g, v, n, active.copy(), ll_only=ll_only)
    monkeypatch.setattr(fourpl_kernels, "COMPILED", False)
    numpy = likelihood.evaluate(theta, x, y, w, g, v, n, active.copy(), ll_only=ll_only)
    for ours, theirs in zip(compiled, numpy, strict=True):
        assert np.array_equal(ours, theirs)
    assert np.all(np.isfinite(compiled[0])) and np.all(compiled[0][~active] == 0.0)


def test_a_fit_and_its_interval_do_not_depend_on_numba(rng, monkeypatch):
    """A whole fit (starts, Levenberg-Marquardt, likelihood interval) of many groups."""
    xs, ys, gs = [], [], []
    slopes, roofs = rng.uniform(0.1, 5.0, 60), rng.uniform(10, 50, 60)
    for k, (b, c) in enumerate(zip(slopes, roofs, strict=True)):
        x, y = draw_4pl(rng, int(rng.integers(5, 400)), 0.9, b, c, 0.1)
        xs.append(x)
        ys.append(y)
        gs.append(np.full(x.size, k))
    x, y, g = np.concatenate(xs), np.concatenate(ys), np.concatenate(gs)
    sd = rng.uniform(0.0, 2.0, x.size)

    def fit():
        result = fourpl.fit_4pl(x, y, groups=g, sd=sd)
        return result, interval.c_interval(result, x, y, g, sd=sd)

    compiled, c_range = fit()
    monkeypatch.setattr(fourpl_kernels, "COMPILED", False)
    numpy, numpy_range = fit()
    for name in ("a", "b", "c", "d", "loglik", "converged", "n_iter"):
        assert np.array_equal(getattr(compiled, name), getattr(numpy, name), equal_nan=True)
    assert all(np.array_equal(a, b) for a, b in zip(c_range, numpy_range, strict=True))


def test_without_numba_the_fit_runs_in_numpy():
    """The ``fast`` extra is optional: without numba the package imports and fits."""
    code = (
        "import sys; sys.modules['numba'] = None\n"  # as if not installed: import fails
        "import numpy as np\n"
        "from gnss_citygml.model import fourpl_kernels\n"
        "from gnss_citygml.model.fourpl import fit_4pl\n"
        "assert not fourpl_kernels.COMPILED\n"
        "x = np.linspace(0, 60, 400)\n"
        "fit = fit_4pl(x, (x > 30) ^ (np.arange(400) % 7 == 0))\n"
        "assert fit.converged[0] and abs(fit.c[0] - 30) < 1, fit\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


_FIT = (
    "import warnings\n"
    "import numpy as np\n"
    "from gnss_citygml.model.fourpl import fit_4pl\n"
    "x = np.linspace(0, 60, 400)\n"
    "with warnings.catch_warnings(record=True) as seen:\n"
    "    warnings.simplefilter('always')\n"
    "    for _ in range(2):\n"
    "        fit = fit_4pl(x, (x > 30) ^ (np.arange(400) % 7 == 0))\n"
    "assert fit.converged[0] and abs(fit.c[0] - 30) < 1, fit\n"
    "print('|'.join(str(w.message) for w in seen if 'numpy' in str(w.message)))\n"
)


@pytest.mark.parametrize(
    "error",
    [
        "OSError('libllvmlite.so: cannot open shared object file')",  # llvmlite's
        "RuntimeError('llvmlite: LLVM version mismatch')",
        "ValueError('Number of threads specified must be > 0.')",
    ],
)
def test_a_numba_that_fails_otherwise_than_importerror_leaves_the_fits_to_numpy(tmp_path, error):
    """A numba package that raises another error than ImportError on import (llvmlite's
    OSError or RuntimeError, numba's ValueError on a bad NUMBA_NUM_THREADS): one warning naming
    the error, and the fits in numpy."""
    fake = tmp_path / "numba"
    fake.mkdir()
    (fake / "__init__.py").write_text(f"raise {error}\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    run = subprocess.run(
        [sys.executable, "-c", _FIT], env=env, capture_output=True, text=True, check=True
    )
    message = error.split("(")[0]
    warned = run.stdout.strip().split("|")
    assert len(warned) == 1 and message in warned[0], run.stdout + run.stderr


def test_a_numba_that_fails_to_compile_leaves_the_fits_to_numpy(tmp_path):
    """A numba that imports but cannot compile (numba's own errors at the first call): one
    warning, and numpy's sums."""
    fake = tmp_path / "numba"
    fake.mkdir()
    (fake / "__init__.py").write_text(
        "class NumbaError(Exception): pass\n"
        "def njit(**options):\n"
        "    def jit(function):\n"
        "        def compiled(*args):\n"
        "            raise NumbaError('Failed in nopython mode pipeline')\n"
        "        return compiled\n"
        "    return jit\n"
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tmp_path), *sys.path])}
    run = subprocess.run(
        [sys.executable, "-c", _FIT], env=env, capture_output=True, text=True, check=True
    )
    warned = run.stdout.strip().split("|")
    assert len(warned) == 1 and "NumbaError" in warned[0], run.stdout + run.stderr


@pytest.mark.parametrize("value", ["0", "-1", "abc"])
def test_a_bad_numba_num_threads_is_no_internal_error(value):
    """The real numba under a NUMBA_NUM_THREADS it refuses (0, negative: ValueError on import)
    or cannot parse: the fits run (in numpy, with a warning, where numba does not import)."""
    env = {**os.environ, "NUMBA_NUM_THREADS": value}
    run = subprocess.run([sys.executable, "-c", _FIT], env=env, capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    if value != "abc":  # (numba takes an unparsable value as unset, with its own warning)
        assert "NUMBA_NUM_THREADS" in run.stdout or "threads" in run.stdout, run.stdout
