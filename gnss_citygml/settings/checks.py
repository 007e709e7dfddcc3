"""The checks every setting's value goes through, and the physical range of each option with a
unit: one place, so that the command line, the Python API and the QGIS plugin refuse alike."""

from __future__ import annotations

import math
import numbers

from ..errors import InputError


def finite(value) -> bool:
    """A real number, neither infinite nor NaN."""
    return isinstance(value, numbers.Real) and math.isfinite(value)


def count(value) -> bool:
    """A whole number, 1 or more (not a bool: ``True`` is no count)."""
    return isinstance(value, numbers.Integral) and not isinstance(value, bool) and int(value) >= 1


def within(value, bounds: tuple[float, float], *, above: bool = False) -> bool:
    """A finite number from ``bounds[0]`` (excluded with ``above``) to ``bounds[1]``."""
    lo, hi = bounds
    return finite(value) and (value > lo if above else value >= lo) and value <= hi


#: The physical range of each option with a unit, checked where its object is made (the
#: command line, the Python API and the QGIS plugin all build the objects, so all refuse alike):
#: antenna above the ground (m): not below it, and no higher than the tallest buildings;
ANTENNA_HEIGHTS = (0.0, 500.0)
#: a ray's horizontal length (m, above 0): a building 10 km away rises less than 2 deg;
MAX_RANGES = (0.0, 10_000.0)
#: C/N0 (dB-Hz), as the observations' cn0 (schemas/observations.schema.json); an elevation (deg);
CN0S, ELEVATIONS = (0.0, 100.0), (-90.0, 90.0)
#: a position error or a calibration prior (m per axis), as the observations' position_sd;
POSITION_SDS = (0.0, 1000.0)
#: a position error's or calibration offset's window (s, above 0): at most a day; its distance
#: (m, above 0): at most 100 km (longer: a whole recording, leave them out);
WINDOWS, POSITION_DISTANCES = (0.0, 86_400.0), (0.0, 100_000.0)
#: a converged estimate's widest height range (m, above 0);
UNCERTAINTIES = (0.0, 1000.0)
#: 4PL-B's iterations and the calibration's rounds: each is a full fit of every building.
ITERATIONS = (1, 1000)
ROUNDS = (1, 100)
#: A height fit's Levenberg-Marquardt iterations: each is a pass over its building's signals.
FIT_ITERATIONS = (1, 10_000)


def positive(value, bounds: tuple[float, float], what: str, unit: str, fix: str) -> None:
    """Refuse ``value`` (``what``, in ``unit``) unless it is a positive number up to
    ``bounds[1]``: one message for every such range, e.g. "max_range must be a positive number
    of metres up to 10000, not -1"."""
    if not within(value, bounds, above=True):
        raise InputError(
            f"{what} must be a positive number of {unit} up to {bounds[1]:g}, not {value}", fix=fix
        )


def count_within(value, bounds: tuple[int, int]) -> bool:
    """A whole number from ``bounds[0]`` to ``bounds[1]``."""
    return count(value) and bounds[0] <= int(value) <= bounds[1]
