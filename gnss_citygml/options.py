"""The settings a user chooses, each declared once: its name on the command line and in QGIS,
its kind, default, range and words.

The command line's options (:mod:`gnss_citygml.cli.options`) and the QGIS plugin's parameters
are both made from :data:`OPTIONS`, so they cannot disagree: the same default, the same range,
the same choices. The defaults are the settings objects' own (:mod:`gnss_citygml.settings`)
and the ranges those their checks enforce, so the Python API agrees too. A range is not
checked by click or QGIS but once, where the settings object is made: a bad value is the
toolkit's one-line error naming the option (QGIS's spin boxes only stop at the ends).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from .model import METHODS
from .settings import (
    HEIGHT_RULES,
    MATCHINGS,
    RECEIVER_HEIGHTS,
    SIGNAL_MODELS,
    Calibration,
    Estimator,
    PositionError,
    Rays,
    ReceiverHeights,
)
from .settings.checks import (
    ANTENNA_HEIGHTS,
    CN0S,
    ELEVATIONS,
    FIT_ITERATIONS,
    ITERATIONS,
    MAX_RANGES,
    POSITION_DISTANCES,
    POSITION_SDS,
    UNCERTAINTIES,
    WINDOWS,
)

__all__ = ["OPTIONS", "SETTINGS", "Option", "settings_arguments", "settings_objects"]

#: The settings classes, by the name of the jobs' argument each is given as.
SETTINGS = {
    "rays": Rays,
    "receiver_heights": ReceiverHeights,
    "estimator": Estimator,
    "position_error": PositionError,
    "calibration": Calibration,
}

#: The kinds of option: a number, a count (a whole number), one of some choices, a switch (on
#: or off), a field of the footprints (its name; in QGIS chosen from the footprints layer's
#: numeric fields).
KINDS = ("number", "count", "choice", "switch", "field")


@dataclass(frozen=True)
class Option:
    """One setting a user chooses.

    ``setting`` is where it goes: the settings object's argument of the job (``rays``,
    ``estimator``, ...) and its field. ``flag`` is the command line's name (``--min-elevation``;
    the QGIS parameter is :attr:`name`, ``MIN_ELEVATION``). ``label`` is QGIS's short
    description, ``help`` the command line's. Its :attr:`default` is read from the settings
    class, never declared again (None: the option may be left out); ``bounds`` is the range
    the settings' check enforces; ``choices`` the
    values of a choice, and ``words`` how QGIS shows them (default: the values themselves).
    """

    setting: tuple[str, str]
    flag: str
    kind: str
    label: str
    help: str
    bounds: tuple[float, float] | None = None
    choices: tuple[str, ...] = ()
    words: tuple[str, ...] = ()

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"an option's kind is one of {KINDS}, not {self.kind!r}")
        if (self.kind == "choice") != bool(self.choices):
            raise ValueError(f"{self.flag}: choices are for a choice, and a choice needs them")

    @property
    def name(self) -> str:
        """The QGIS parameter's name: ``MIN_ELEVATION`` for ``--min-elevation``."""
        return self.flag.removeprefix("--").replace("-", "_").upper()

    @property
    def dest(self) -> str:
        """The command line's parameter name: ``min_elevation``."""
        return self.name.lower()

    @property
    def default(self) -> Any:
        """The settings object's default (None: the option may be left out)."""
        settings, field = self.setting
        return getattr(SETTINGS[settings], field)

    @property
    def optional(self) -> bool:
        """Whether it may be left out (no default: the settings object's own logic)."""
        return self.default is None


_OPTIONS = (
    Option(
        ("rays", "min_elevation"),
        "--min-elevation",
        "number",
        "Lowest satellite elevation (degrees)",
        "Signals below this elevation (deg) are left out.",
        ELEVATIONS,
    ),
    Option(
        ("rays", "max_elevation"),
        "--max-elevation",
        "number",
        "Highest satellite elevation (degrees)",
        "Signals above this elevation (deg) are left out.",
        ELEVATIONS,
    ),
    Option(
        ("receiver_heights", "source"),
        "--receiver-height",
        "choice",
        "Receiver height from",
        "Antenna height from the DEM (+ --antenna-height) or from the observations' h.",
        choices=RECEIVER_HEIGHTS,
        words=("the DEM + antenna height", "the observations' h (the log)"),
    ),
    Option(
        ("receiver_heights", "antenna_height"),
        "--antenna-height",
        "number",
        "Antenna height above the ground (m)",
        "Metres.",
        ANTENNA_HEIGHTS,
    ),
    Option(
        ("estimator", "init_threshold"),
        "--init-threshold",
        "number",
        "Initial C/N0 threshold (dB-Hz)",
        "C/N0 (dB-Hz) where the initial signal classifier gives 50 %.",
        CN0S,
    ),
    Option(
        ("estimator", "method"),
        "--method",
        "choice",
        "Method",
        "Height estimator: 4PL-B, the paper's one-shot 4PL, or the hinge or Bayes baseline.",
        choices=METHODS,
    ),
    Option(
        ("estimator", "height_rule"),
        "--height-rule",
        "choice",
        "Height rule (c: the 4PL's inflection point; paper: c + 1.5/b)",
        "How the height is read off a building's 4PL: its inflection point c, or the paper's "
        "c + 1.5/b (both are in every output: c and height_paper).",
        choices=HEIGHT_RULES,
    ),
    Option(
        ("estimator", "signal_model"),
        "--signal-model",
        "choice",
        "Signal model (paper: a C/N0 threshold; mixture: open and closed signals' C/N0 by "
        "elevation, learnt by EM; 4PL-B only)",
        "How 4PL-B tells open signals from closed ones: the paper's C/N0 threshold trained "
        "on the map's labels, or a mixture of open and closed signals' C/N0 by elevation learnt "
        "by EM (method 4PL-B only).",
        choices=SIGNAL_MODELS,
    ),
    Option(
        ("estimator", "level_phones"),
        "--level-phones",
        "switch",
        "Level each phone's C/N0 by its signals that cross no footprint (off: as recorded, as in "
        "the paper; 4PL-B only)",
        "Put every phone's C/N0 on one level before the signals are classified, each "
        "phone's offset learnt from its signals that cross no footprint (phones differ by a few "
        "dB-Hz; method 4PL-B). --no-level-phones: the C/N0 as recorded, as in the paper.",
    ),
    Option(
        ("estimator", "max_iter"),
        "--max-iter",
        "count",
        "Most iterations of 4PL-B's loop",
        "Most iterations of 4PL-B's loop (each relabels the signals and refits every "
        "building): a run that has not settled by then stops there.",
        ITERATIONS,
    ),
    Option(
        ("estimator", "fit_max_iter"),
        "--fit-max-iter",
        "count",
        "Most iterations of a height fit (Levenberg-Marquardt)",
        "Most Levenberg-Marquardt iterations of one building's height fit (each 4PL-B "
        "iteration): a fit that has not met its tolerance by then stops where it is. Raise it "
        "(with --max-iter) to check that the heights do not depend on the caps.",
        FIT_ITERATIONS,
    ),
    Option(
        ("rays", "max_range"),
        "--max-range",
        "number",
        "Ray length (m)",
        "Ray length (m).",
        MAX_RANGES,
    ),
    Option(
        ("position_error", "sd"),
        "--position-sd",
        "number",
        "Receiver position error (m per axis; default: the observations', 1 m where empty; "
        "0: exact)",
        "How far every receiver position may be off (m per axis; about 1 for points placed "
        "by hand), overriding the observations' position_sd: the fits model the height errors "
        "that follow and the ranges widen. 0: positions taken as exact, as in the paper. "
        "Default: each observation's position_sd (a phone fix's accuracy), 1 m where it is "
        "empty.",
        POSITION_SDS,
    ),
    Option(
        ("position_error", "distance"),
        "--position-distance",
        "number",
        "Position error of a moving receiver lasts for (m)",
        "Metres a moving receiver (a walker's traced path, a phone's fixes) goes with one "
        "position error: the next begins once its reported position is this far from where the "
        "last began (the next stretch of street has other reflections). A receiver standing at "
        "one point, or a phone lying still, keeps one. Longer than the walk: one per recording.",
        POSITION_DISTANCES,
    ),
    Option(
        ("position_error", "window"),
        "--position-window",
        "number",
        "Instead: position error of a moving receiver lasts (s)",
        "Instead of --position-distance: seconds one position error of a moving receiver "
        "lasts. A receiver standing at one point (a point placed by hand) shares one error over "
        "its stay either way.",
        WINDOWS,
    ),
    Option(
        ("calibration", "prior_sd"),
        "--calibration-sd",
        "number",
        "Self-calibrate receiver offsets with prior (m; 4PL-B only)",
        "Self-calibrate one position offset per recording with this prior (m per axis; "
        "about 1 for hand-placed points, 5 for phone fixes; method 4PL-B only). Off by default.",
        POSITION_SDS,
    ),
    Option(
        ("calibration", "window"),
        "--calibration-window",
        "number",
        "One calibration offset per (s; default: per recording)",
        "With --calibration-sd: one offset per this many seconds of a recording (about 30 "
        "for phone fixes, whose errors drift) instead of one per recording.",
        WINDOWS,
    ),
    Option(
        ("calibration", "matching"),
        "--calibration-matching",
        "choice",
        "Calibration matching (roof lines: each offset against the fitted roof lines; "
        "shadows: the rays cast exactly, open sky included)",
        "With --calibration-sd: how each offset is found: against every converged building's "
        "fitted roof line ('roof lines'), or by shadow matching (shadows: the rays cast "
        "exactly from a grid of candidates against the converged roofs, the open sky included; "
        "each window's prior its fixes' own position_sd where they have one; for phone fixes, "
        "with --calibration-window 10).",
        choices=MATCHINGS,
    ),
    Option(
        ("calibration", "heights"),
        "--calibration-heights",
        "field",
        "Footprints' field of roof heights above the ground, to place the phones by "
        "(shadow matching)",
        "With --calibration-matching shadows: the footprints' field of roof heights above the "
        "ground given with the map (e.g. OS's relh2, a previous run's relative_height), "
        "matched against where it is a positive number instead of the roofs being estimated, "
        "which share the phones' bias in a street. It places the phones only; the heights "
        "are the signals' own.",
    ),
    Option(
        ("calibration", "heights_sd"),
        "--calibration-heights-sd",
        "number",
        "Uncertainty of the map's roof heights (m)",
        "With --calibration-heights: the standard deviation of those heights (m).",
        UNCERTAINTIES,
    ),
)

#: Every option, by its QGIS name (``MIN_ELEVATION``).
OPTIONS: dict[str, Option] = {option.name: option for option in _OPTIONS}


def settings_objects(arguments: dict[str, dict[str, Any]]) -> dict[str, Any]:
    """The settings objects (``{"rays": Rays(...), ...}``) made, and so checked, from their
    ``arguments`` (:func:`settings_arguments`'s, or the QGIS plugin's)."""
    return {key: SETTINGS[key](**fields) for key, fields in arguments.items()}


def settings_arguments(values: dict[str, Any], names: Iterable[str]) -> dict[str, dict[str, Any]]:
    """The settings objects' arguments (``{"rays": {"min_elevation": 10.0}, ...}``) from the
    ``values`` of the options ``names`` (by QGIS name; a value None is left out)."""
    arguments: dict[str, dict[str, Any]] = {}
    for name in names:
        setting, field = OPTIONS[name].setting
        arguments.setdefault(setting, {})
        if values[name] is not None:
            arguments[setting][field] = values[name]
    return arguments
