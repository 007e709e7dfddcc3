"""Physics of the simulated signals: C/N0 of clear, diffracted and reflected signals, and the
location errors of manual and GNSS positions.

C/N0 (dB-Hz)
    A clear (LOS) signal has the phone's zenith C/N0 less the antenna's loss towards the horizon,
    a device offset and Rayleigh-Rice-like fading. A signal whose line of sight passes near a roof
    edge loses the knife-edge diffraction loss J(v) of ITU-R P.526 (up to 6 dB when grazing
    clear, growing as the ray passes further below the edge). A blocked signal may still arrive
    reflected off another surface (NLOS), weaker by a reflection and path loss. The strongest
    component wins; below the receiver's tracking threshold nothing is received (C/N0 NaN).
    LOS and NLOS C/N0 distributions therefore overlap, as in the paper's figure.

Positions
    Manual positions err by a constant offset per static session (a point picked on a map) or a
    slowly varying one when walking. GNSS fixes are solved: pseudoranges with time-correlated
    noise, plus the extra path of reflected (NLOS) signals, go through a C/N0-weighted least
    squares over the satellites actually received, so errors grow where only a strip of sky is
    visible (across a street canyon) and where reflections dominate.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
from scipy.signal import lfilter

from ..errors import InputError

__all__ = ["SignalModel", "ar1", "diffraction_loss", "gnss_fix_errors"]

#: GPS L1 / Galileo E1 wavelength (m).
WAVELENGTH = 0.1903


@dataclass(frozen=True)
class SignalModel:
    """The physics of the simulated signals and positions (dB-Hz, dB, m). The defaults are
    from smartphone measurement literature; ``benchmarks/scenes.py`` draws others, so that the
    estimator is judged across the physics and not on one simulator's constants."""

    zenith_cn0: float = 45.0  # strong clear signal on a phone
    horizon_loss: float = 8.0  # antenna gain loss from zenith to the horizon
    fading_sd: float = 3.0  # LOS fading and body loss, per signal
    device_sd: float = 2.0  # offset of one device (dataset) against another
    session_sd: float = 1.0  # offset of one recording session (pocket, hand, orientation)
    body_loss: float = 0.0  # mean loss of every signal of a session (a body, a pocket)
    reflection_loss: float = 12.0  # mean loss of a reflected path relative to LOS
    reflection_sd: float = 4.0
    #: Share of the blocked signals that arrive reflected, with a facade behind the receiver
    #: (within 60 m, opposite the satellite) and without one.
    reflected_facade: float = 0.75
    reflected_open: float = 0.25
    tracking_threshold: float = 12.0  # below this nothing is tracked
    manual_sd: float = 1.0  # error of a position placed by hand (m per axis, per session)
    #: Scale (m) of the extra path of a signal that arrives reflected only (NLOS) in the
    #: phone's fix: tens of metres in dense streets, where most of the fix is NLOS.
    nlos_delay: float = 15.0
    #: How many times smaller than its solution's own error estimate a phone claims its fix's
    #: error to be (its AccuracyMeters): 1 as the solution says, more where a chipset's noise
    #: model does not see its reflections (real phones understate 1.3-2x in dense streets).
    understatement: float = 1.0
    #: Seconds a reflected path lasts (0: each epoch draws anew whether a blocked signal
    #: arrives reflected). A walker passes a 10-25 m facade in 7-18 s; its reflections, and
    #: the fix's lean away from the taller side, last that long.
    reflection_seconds: float = 0.0
    #: Seconds over which the phone's own filter smooths its fixes (0: each epoch's solution
    #: as it is); phones' fused locations hold an error for that long.
    fix_seconds: float = 0.0

    def __post_init__(self):
        """Refuse physics that is no physics: every value finite, spreads not negative,
        shares fractions, C/N0s as the observations' (0 to 100 dB-Hz)."""
        values: dict[str, Any] = {name: getattr(self, name) for name in self.__dataclass_fields__}
        bad = [
            name
            for name, value in values.items()
            if not (isinstance(value, numbers.Real) and math.isfinite(value))
            or (name.endswith("_sd") and float(value) < 0)
            or (name.startswith("reflected_") and not 0 <= float(value) <= 1)
            or (name in ("zenith_cn0", "tracking_threshold") and not 0 <= float(value) <= 100)
            or (name in ("nlos_delay", "reflection_seconds", "fix_seconds") and float(value) < 0)
            or (name == "understatement" and float(value) <= 0)
        ]
        if bad:
            raise InputError(
                f"signal model {bad[0]} = {values[bad[0]]!r} is not physical",
                fix="give finite numbers: spreads (_sd), nlos_delay and the _seconds 0 or more, "
                " shares (reflected_) from 0 to 1, C/N0s from 0 to 100 dB-Hz, "
                "understatement above 0",
            )


def diffraction_loss(
    clearance: npt.ArrayLike, distance: npt.ArrayLike, elevation: npt.ArrayLike
) -> np.ndarray:
    """Knife-edge diffraction loss (dB, >= 0) of ITU-R P.526.

    ``clearance`` is how far (m) the line of sight passes *below* the edge, measured vertically
    (negative when it passes above), ``distance`` the horizontal distance (m) from receiver to
    edge and ``elevation`` (deg) the ray's elevation. The Fresnel parameter takes the clearance
    perpendicular to the ray, ``clearance cos(el)``, over the slant path ``distance / cos(el)``:
    a steep ray passes the edge within a wide vertical zone of strong diffraction.
    """
    cos_el = np.maximum(np.cos(np.radians(elevation)), 1e-3)
    perp = np.asarray(clearance, dtype=float) * cos_el
    slant = np.maximum(np.asarray(distance, dtype=float) / cos_el, 1.0)
    v = perp * np.sqrt(2.0 / (WAVELENGTH * slant))
    loss = 6.9 + 20.0 * np.log10(np.sqrt((v - 0.1) ** 2 + 1.0) + v - 0.1)
    return np.where(v > -0.78, np.maximum(loss, 0.0), 0.0)


def ar1(
    rng: np.random.Generator,
    n: int,
    dt: float,
    tau: float,
    sigma: float,
    size: tuple[int, ...] = (),
) -> np.ndarray:
    """A stationary first-order Gauss-Markov process of ``n`` steps (axis 0)."""
    phi = np.exp(-dt / tau)
    innov = rng.normal(0.0, sigma * np.sqrt(1.0 - phi**2), (n, *size))
    innov[0] = rng.normal(0.0, sigma, size)
    return lfilter([1.0], [1.0, -phi], innov, axis=0)


def gnss_fix_errors(
    rng: np.random.Generator,
    az: np.ndarray,
    el: np.ndarray,
    received: np.ndarray,
    nlos: np.ndarray,
    cn0: np.ndarray,
    dt: float = 1.0,
    nlos_delay: float = 15.0,
    understatement: float = 1.0,
    fix_seconds: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """East, north errors (m) of the phone's own position fix, epoch by epoch, and the error
    the phone reports with it (m per axis, as its accuracy over 1.51).

    The fix is a weighted least-squares solution of pseudorange errors (noise, and the extra
    path of reflections). Its reported error is what a chipset can know: the solution's
    covariance under its own noise model, scaled by the residuals' variance factor (not below
    1), so a fix spoilt by reflections says it is worse, though not always by as much as it is;
    a chipset whose noise model does not see its reflections claims ``understatement`` times
    less.

    Parameters
    ----------
    az, el
        ``(n_epochs, n_sat)`` azimuth and elevation (deg); NaN where below the mask.
    received, nlos
        ``(n_epochs, n_sat)`` masks: signal received; received by reflection only.
    cn0
        ``(n_epochs, n_sat)`` C/N0 of the received signals.
    nlos_delay
        Scale (m) of a reflected-only signal's extra path (:class:`SignalModel`).
    understatement
        How many times smaller the claimed error is than the solution's own estimate.
    fix_seconds
        Time constant (s) of the phone's first-order smoothing of its solutions (0: none).
    """
    n_ep, n_sat = az.shape
    # code noise, multipath and atmosphere residuals of a phone's linearly polarised antenna
    noise = ar1(rng, n_ep, dt, 30.0, 5.0, (n_sat,))
    extra = np.abs(ar1(rng, n_ep, dt, 60.0, nlos_delay, (n_sat,)))  # extra path of reflections
    err = noise + np.where(nlos, extra, 0.0)
    a, e = np.radians(np.nan_to_num(az)), np.radians(np.nan_to_num(el))
    h = np.stack([-np.cos(e) * np.sin(a), -np.cos(e) * np.cos(a), -np.sin(e), np.ones_like(e)], -1)
    sigma = 3.0 * 10 ** ((35.0 - np.nan_to_num(cn0, nan=35.0)) / 20.0)
    w = np.where(received, 1.0 / sigma**2, 0.0)
    normal = np.einsum("es,esi,esj->eij", w, h, h) + 1e-9 * np.eye(4)
    rhs = np.einsum("es,esi,es->ei", w, h, err)
    n_used = received.sum(axis=1)
    ok = n_used >= 5
    sol, sd = np.zeros((n_ep, 4)), np.full(n_ep, np.nan)
    sol[ok] = np.linalg.solve(normal[ok], rhs[ok][:, :, None])[:, :, 0]
    residual = err - np.einsum("esi,ei->es", h, sol)
    factor = np.einsum("es,es->e", w, residual**2) / np.maximum(n_used - 4, 1)
    cov = np.linalg.inv(normal[ok]) * np.maximum(factor[ok], 1.0)[:, None, None]
    sd[ok] = np.sqrt((cov[:, 0, 0] + cov[:, 1, 1]) / 2.0) / understatement
    last_fix = np.maximum.accumulate(np.where(ok, np.arange(n_ep), 0))  # hold through outages
    sol, sd = sol[last_fix], sd[last_fix]
    if fix_seconds > 0:
        keep = np.exp(-dt / fix_seconds)
        start = sol[:1] * keep  # the filter starts at the first solution
        sol = lfilter([1.0 - keep], [1.0, -keep], sol, axis=0, zi=start)[0]
    return sol[:, 0], sol[:, 1], sd
