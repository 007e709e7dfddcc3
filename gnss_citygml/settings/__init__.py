"""The options of the stages, as small frozen dataclasses: each defined once, with its defaults.

Options that travel together are one object, so that a new option is one field here instead of
a keyword passed through every function on its way to the stage that uses it. The command line,
the Python API and the QGIS plugin build these objects; :func:`gnss_citygml.pipeline.run` and
the other entry points take them, bundled as one :class:`RunSettings`:

- :class:`Rays`: which signals are cast (the elevation mask) and how (range, Earth's curvature);
- :class:`ReceiverHeights`: where the antenna's height comes from;
- :class:`Estimator`: the height estimator (4PL-B, 4PL or a baseline) and its settings, with
  :class:`Acceptance`, what a 4PL-B estimate must satisfy to count as converged;
- :class:`PositionError`: how far the receiver positions may be off, for the fits to model;
- :class:`Calibration`: the self-calibration of the receivers' offsets;
- :class:`Tiling`: a run cut into tiles on a Dask cluster;
- :class:`RunSettings`: all of them for one run, with the rules between them.

Each object checks its own values when it is made (one-line
:class:`~gnss_citygml.errors.InputError`, or :class:`~gnss_citygml.errors.ModelError` for a
method or option the estimator does not have), so a bad value is refused before any work. This
module imports nothing heavy: a command can build its settings before loading a stage.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field, fields, replace
from typing import Any

from ..errors import InputError, ModelError
from ..model import METHODS
from .checks import (
    ANTENNA_HEIGHTS,
    CN0S,
    ELEVATIONS,
    FIT_ITERATIONS,
    ITERATIONS,
    MAX_RANGES,
    POSITION_SDS,
    ROUNDS,
    UNCERTAINTIES,
    WINDOWS,
    count,
    count_within,
    finite,
    positive,
    within,
)
from .positions import DEFAULT_POSITION_DISTANCE, DEFAULT_POSITION_SD, NEAR_SDS, PositionError
from .tiling import (
    DEFAULT_TILE_SIZE,
    SCHEDULER_PORT,
    TILE_SIZES,
    WORKERS_PER_CORE,
    Tiling,
    check_tile_size,
    scheduler_address,
)

__all__ = [
    "DEFAULT_POSITION_DISTANCE",
    "DEFAULT_POSITION_SD",
    "DEFAULT_TILE_SIZE",
    "BLAMES",
    "HEIGHT_RULES",
    "NEAR_SDS",
    "MATCHINGS",
    "SIGNAL_MODELS",
    "RECEIVER_HEIGHTS",
    "TILE_SIZES",
    "WEIGHTINGS",
    "Acceptance",
    "Calibration",
    "Estimator",
    "PositionError",
    "ReceiverHeights",
    "Rays",
    "RunSettings",
    "SCHEDULER_PORT",
    "Tiling",
    "WORKERS_PER_CORE",
    "check_elevation_mask",
    "check_tile_size",
    "scheduler_address",
]

#: Reweighting schemes of the 4PL height fit (:func:`~gnss_citygml.model.fourplb.height_weights`).
WEIGHTINGS = ("none", "height", "balanced", "looks")

#: How a 4PL's height is read off it: its inflection point c, or the paper's c + 1.5/b. Both
#: are measured in docs/accuracy.md (benchmarks/scenes.py: c was nearer the truth in every regime);
#: both are in every output (``c`` and ``height_paper``).
HEIGHT_RULES = ("inflection", "paper")
#: How 4PL-B labels the signals: ``paper``, a C/N0 threshold co-trained on the map's hard
#: labels; ``mixture``, C/N0 densities of open and closed signals learnt by EM, anchored by the
#: rays that cross no footprint (:mod:`gnss_citygml.model.mixture`).
SIGNAL_MODELS = ("paper", "mixture")
#: What a closed ray that crosses several buildings tells each one's height fit (the visibility
#: model, :mod:`gnss_citygml.model.blame`): ``ray``, closed evidence weighted by the chance that
#: this building alone blocks it at the current fits; ``drop``, left out wherever another
#: building may block it.
BLAMES = ("ray", "drop")

#: How self-calibration finds each recording's (or window's) offset: ``roof lines``, the
#: labels of its signals against every converged building's fitted 4PL, heights moved to first
#: order; ``shadows``, the rays cast exactly from a grid of candidates against the converged
#: roofs, the rays that cross no footprint included (:mod:`gnss_citygml.calibrate.shadows`).
MATCHINGS = ("roof lines", "shadows")

#: Where receiver heights come from: the DEM plus an antenna height, or the log's own heights.
RECEIVER_HEIGHTS = ("dem", "log")


def check_elevation_mask(min_elevation: float, max_elevation: float) -> None:
    """Refuse an elevation mask (deg) that is not a band of elevations, -90 <= min < max <= 90
    (the rays' and ``observe``'s)."""
    band = (min_elevation, max_elevation)
    if not (all(map(finite, band)) and ELEVATIONS[0] <= band[0] < band[1] <= ELEVATIONS[1]):
        raise InputError(
            f"elevation mask {band[0]}..{band[1]} deg is not a band of elevations",
            fix="give --min-elevation and --max-elevation in degrees, -90 <= min < max <= 90, "
            "e.g. 10 and 85",
        )


@dataclass(frozen=True)
class Rays:
    """Which signals are cast against the footprints, and how.

    Parameters
    ----------
    min_elevation, max_elevation
        Signals outside this elevation band (deg) are left out.
    max_range
        Horizontal length (m) of a ray: buildings farther from the receiver are not crossed.
    earth_curvature
        Add the fall of the ground away from the ray's tangent plane to each intersection
        height (``d^2 (1 - k) / 2R``, standard refraction: 2 cm at 500 m).
    """

    min_elevation: float = 10.0
    max_elevation: float = 85.0
    max_range: float = 500.0
    earth_curvature: bool = False

    def __post_init__(self):
        check_elevation_mask(self.min_elevation, self.max_elevation)
        positive(
            self.max_range,
            MAX_RANGES,
            "max_range",
            "metres",
            "give --max-range in metres, e.g. 500",
        )


@dataclass(frozen=True)
class ReceiverHeights:
    """Where the antenna's height (m ODN) comes from.

    Parameters
    ----------
    source
        ``"dem"``: ``antenna_height`` above the DEM (the paper's choice with phone fixes, whose
        heights are poor); ``"log"``: the observations' ellipsoidal ``h`` converted to ODN.
    antenna_height
        Metres above the DEM, with ``source="dem"``.
    """

    source: str = "dem"
    antenna_height: float = 1.0

    def __post_init__(self):
        if self.source not in RECEIVER_HEIGHTS:
            raise InputError(
                f"unknown receiver height source {self.source!r}",
                fix="use one of " + ", ".join(RECEIVER_HEIGHTS),
            )
        if not within(self.antenna_height, ANTENNA_HEIGHTS):
            raise InputError(
                f"antenna_height must be a number of metres above the ground, "
                f"{ANTENNA_HEIGHTS[0]:g} to {ANTENNA_HEIGHTS[1]:g}, not {self.antenna_height}",
                fix="give --antenna-height in metres, e.g. 1 for a phone held in the hand",
            )


@dataclass(frozen=True)
class Acceptance:
    """What a 4PL-B estimate must satisfy to count as converged (see
    :func:`~gnss_citygml.model.estimate.fourplb`).

    Parameters
    ----------
    label_tol
        4PL-B stops when fewer than this fraction of every building's map labels change between
        two iterations; one still changing by this much at the last iteration has not converged.
    min_signals
        Rows a building needs, and on each side of its roof line (the baselines: in all).
    min_separation
        Smallest difference of the fitted asymptotes (``a - d``): the roof line must change the
        open probability by that much. (The paper's classifier, trained at one site and applied
        to others, still had a - d of about 0.4.)
    max_uncertainty
        Widest height range, in metres, of a converged estimate: the roof line's transition
        3/b wide, widened by the likelihood-ratio interval of ``c`` and the position margin
        in quadrature (:func:`~gnss_citygml.model.estimate.fourplb`). The default, 10 m, keeps the
        estimate within 5 m of both ends of its range: CityGML's accuracy class for LOD1, the
        benchmark the paper measures itself against.
    """

    label_tol: float = 0.01
    min_signals: int = 10
    min_separation: float = 0.3
    max_uncertainty: float = 10.0

    def __post_init__(self):
        if not (finite(self.label_tol) and 0.0 <= self.label_tol <= 1.0):
            raise InputError(
                f"label_tol must be a fraction from 0 to 1, not {self.label_tol}", fix="e.g. 0.01"
            )
        if not count(self.min_signals):
            raise InputError(
                f"min_signals must be a whole number, 1 or more, not {self.min_signals}",
                fix="e.g. 10",
            )
        if not (finite(self.min_separation) and 0.0 <= self.min_separation <= 1.0):
            raise InputError(
                f"min_separation must be a probability from 0 to 1, not {self.min_separation}",
                fix="e.g. 0.3",
            )
        positive(
            self.max_uncertainty,
            UNCERTAINTIES,
            "max_uncertainty",
            "metres",
            "e.g. 10 (CityGML's LOD1 accuracy class: within 5 m)",
        )


@dataclass(frozen=True)
class Estimator:
    """The height estimator and its settings.

    Parameters
    ----------
    method
        ``4PL-B`` (default), ``4PL`` (the paper's one-shot 4PL, without bootstrapping),
        ``hinge`` (Weissman) or ``bayes`` (Irish et al.); one of
        :data:`gnss_citygml.model.METHODS`.
    init_threshold
        C/N0 (dB-Hz) where the initial signal classifier gives Pr(open) = 0.5.
    weighting
        Reweighting of the 4PL height fit, one of :data:`WEIGHTINGS` (``none``: the paper's MLE).
    visibility
        With the intersections' ``signal`` and ``order``: a signal that another building blocks
        at the current estimates tells nothing of this one (``blame``), and teaches the signal
        classifier nothing about it.
    blame
        How the visibility model shares a closed ray among the buildings it crosses, one of
        :data:`BLAMES`: ``drop`` (default), each building's fit leaves it out wherever another
        building may block it (its c + 3/b above the ray); ``ray``, each building's height fit
        counts it closed with the chance that this building alone blocks it given the others'
        current fits (:mod:`gnss_citygml.model.blame`): more right answers in most regimes
        measured, but on a dense city its heights still move by up to 0.1 m with the fits'
        cap (docs/issue-47-blame.md), so it is not yet the default.
    max_iter
        Most iterations of 4PL-B's loop.
    fit_max_iter
        Most Levenberg-Marquardt iterations of one height fit (a building's 4PL, each of 4PL-B's
        iterations): a fit that has not met its tolerance by then stops where it is
        (:func:`~gnss_citygml.model.fourpl.fit_4pl`). With ``max_iter``, it lets anyone check
        that the heights do not depend on where a cap cut the fits.
    height_rule
        How the height is read off a building's 4PL, one of :data:`HEIGHT_RULES`:
        ``inflection`` (default), its inflection point ``c``, where the chance that a signal is
        received is halfway between its values below and above the roof line; ``paper``,
        ``c + 1.5/b``. The range is the 3/b-wide transition centred on the height.
    signal_model
        How 4PL-B labels the signals, one of :data:`SIGNAL_MODELS`: ``paper`` (default), the
        paper's C/N0 threshold co-trained on the map's labels; ``mixture``, each signal's chance
        of being open from C/N0 densities of open and closed signals by elevation, learnt with
        the buildings' 4PLs by expectation-maximisation.
    level_phones
        Put every phone's (``receiver``'s) C/N0 on one level, learnt from its signals whose rays
        cross no footprint, before the signals are classified (:mod:`gnss_citygml.model.offsets`):
        phones differ by a few dB-Hz, which one threshold would read as blocking. 4PL-B only,
        with an open sky (``estimate``, ``update``); ``False``: as recorded, as in the paper.
    acceptance
        What an estimate must satisfy to count as converged.

    The baselines use ``init_threshold`` and ``acceptance.min_signals`` only: any other setting
    away from its default is refused with them, rather than silently ignored.
    """

    method: str = "4PL-B"
    init_threshold: float = 30.0
    weighting: str = "none"
    visibility: bool = True
    blame: str = "drop"
    max_iter: int = 30
    fit_max_iter: int = 200
    height_rule: str = "inflection"
    signal_model: str = "paper"
    level_phones: bool = True
    acceptance: Acceptance = field(default_factory=Acceptance)

    def __post_init__(self):
        if self.method not in METHODS:
            raise ModelError(
                f"unknown method {self.method!r}", fix="use one of " + ", ".join(METHODS)
            )
        if self.weighting not in WEIGHTINGS:
            raise ModelError(
                f"unknown weighting {self.weighting!r}", fix="use one of " + ", ".join(WEIGHTINGS)
            )
        if self.height_rule not in HEIGHT_RULES:
            raise ModelError(
                f"unknown height rule {self.height_rule!r}",
                fix="use one of " + ", ".join(HEIGHT_RULES),
            )
        if self.blame not in BLAMES:
            raise ModelError(f"unknown blame {self.blame!r}", fix="use one of " + ", ".join(BLAMES))
        if self.blame != "drop" and not self.visibility:
            raise ModelError(
                f"blame {self.blame} shares closed rays in the visibility model, which is off",
                fix="leave blame out, or keep visibility on",
            )
        if self.signal_model not in SIGNAL_MODELS:
            raise ModelError(
                f"unknown signal model {self.signal_model!r}",
                fix="use one of " + ", ".join(SIGNAL_MODELS),
            )
        if self.signal_model != "paper" and self.method != "4PL-B":
            raise ModelError(
                f"signal model {self.signal_model} needs method 4PL-B, not {self.method}",
                fix="leave the signal model out, or use method 4PL-B",
            )
        if not within(self.init_threshold, CN0S):
            raise InputError(
                f"init_threshold must be a C/N0 in dB-Hz, {CN0S[0]:g} to {CN0S[1]:g}, "
                f"not {self.init_threshold}",
                fix="give --init-threshold in dB-Hz, e.g. 30",
            )
        for name, bounds, example in (
            ("max_iter", ITERATIONS, 30),
            ("fit_max_iter", FIT_ITERATIONS, 200),
        ):
            if not count_within(getattr(self, name), bounds):
                raise InputError(
                    f"{name} must be a whole number, {bounds[0]} to {bounds[1]}, "
                    f"not {getattr(self, name)}",
                    fix=f"e.g. {example}",
                )
        if not self.fourpl:
            plain = Estimator(acceptance=Acceptance(min_signals=self.acceptance.min_signals))
            unused = [
                name
                for name in (
                    "weighting",
                    "visibility",
                    "blame",
                    "max_iter",
                    "fit_max_iter",
                    "height_rule",
                    "acceptance",
                )
                if getattr(self, name) != getattr(plain, name)
            ]
            if unused:
                raise ModelError(
                    f"option(s) {', '.join(unused)} not used by method {self.method}",
                    fix="leave them out, or use method 4PL-B or 4PL",
                )

    @property
    def levels_phones(self) -> bool:
        """Whether the phones' C/N0 is levelled (``level_phones``): by 4PL-B only, the other
        methods are run as published."""
        return self.level_phones and self.method == "4PL-B"

    @property
    def fourpl(self) -> bool:
        """Whether the method fits 4PLs (4PL-B or 4PL), whose settings all apply."""
        return self.method in ("4PL-B", "4PL")


@dataclass(frozen=True)
class Calibration:
    """The self-calibration of one position offset per recording, jointly with the heights
    (:func:`~gnss_citygml.calibrate.calibrate_receivers`; 4PL-B only).

    Parameters
    ----------
    prior_sd
        Prior standard deviation (m per axis) of a recording's offset, what the positions are
        believed to be worth: about 1 for hand-placed points, 5 for phone fixes. ``None``
        (default): no self-calibration (it costs a few extra casts and fits).
    window
        With ``prior_sd``: one offset per this many seconds of a recording (about 30 for phone
        fixes, whose errors drift) instead of one per recording (windows as for
        :class:`PositionError`).
    rounds
        Rounds of the (heights | offsets) alternation.
    matching
        How each offset is found (:data:`MATCHINGS`): ``roof lines`` (default), or ``shadows``,
        where each window's prior is its fixes' own ``position_sd`` where the data have one
        (about 10 s windows for phone fixes) and, with a window, each window's shift is carried
        along its walk (:mod:`gnss_citygml.calibrate.walks`).
    heights
        With shadow matching: the footprints' field of roof heights above the ground given
        with the map (e.g. OS's ``relh2``, or a previous run's ``relative_height``), matched
        against where it has a positive number instead of the roofs being estimated, which
        inherit the bias the phones in a street share. A prior for the positions only: the
        heights are the signals' own.
    heights_sd
        The standard deviation (m) of those heights: what they are worth as the roofs the
        signals meet (default 2 m: a map's roof heights, a building's roof span included).
    """

    prior_sd: float | None = None
    window: float | None = None
    rounds: int = 3
    matching: str = "roof lines"
    heights: str | None = None
    heights_sd: float = 2.0

    def __post_init__(self):
        if self.prior_sd is not None:
            positive(
                self.prior_sd,
                POSITION_SDS,
                "the calibration prior",
                "metres",
                "give --calibration-sd, e.g. 1 m for hand-placed points, 5 m for phone fixes",
            )
        if self.window is not None and self.prior_sd is None:
            raise InputError(
                "a calibration window without self-calibration",
                fix="give the calibration prior (--calibration-sd) too, e.g. 5 m for phone fixes",
            )
        if self.window is not None:
            positive(
                self.window,
                WINDOWS,
                "the calibration window",
                "seconds",
                "give --calibration-window, e.g. 30 for phone fixes, or leave it out for one "
                "offset per recording",
            )
        if self.matching != "roof lines" and self.prior_sd is None:
            raise InputError(
                f"calibration matching {self.matching!r} without self-calibration",
                fix="give the calibration prior (--calibration-sd) too, e.g. 5 m for phone fixes",
            )
        if self.matching not in MATCHINGS:
            raise InputError(
                f"calibration matching must be one of {', '.join(MATCHINGS)}, "
                f"not {self.matching!r}",
                fix="give --calibration-matching 'roof lines' or shadows",
            )
        self._check_heights()
        if not count_within(self.rounds, ROUNDS):
            raise InputError(
                f"calibration rounds must be a whole number, {ROUNDS[0]} to {ROUNDS[1]}, "
                f"not {self.rounds}",
                fix="e.g. 3",
            )

    def _check_heights(self) -> None:
        if self.heights is not None and self.matching != "shadows":
            raise InputError(
                f"map heights for the calibration ({self.heights!r}) without shadow matching",
                fix="give --calibration-matching shadows too, or leave out --calibration-heights",
            )
        if self.heights is not None and not (isinstance(self.heights, str) and self.heights):
            raise InputError(
                f"the calibration's map heights must name a footprint field, not {self.heights!r}",
                fix="give --calibration-heights FIELD, e.g. relh2",
            )
        positive(
            self.heights_sd,
            UNCERTAINTIES,
            "the calibration's map heights' standard deviation",
            "metres",
            "give --calibration-heights-sd, e.g. 2",
        )

    @property
    def on(self) -> bool:
        """Whether self-calibration is asked for."""
        return self.prior_sd is not None

    def check_method(self, estimator: Estimator) -> None:
        """Refuse self-calibration with a method that cannot use it: the offsets are estimated
        against 4PL-B's fitted roof lines, so any other method would silently ignore them."""
        if self.on and estimator.method != "4PL-B":
            raise InputError(
                f"self-calibration needs method 4PL-B, not {estimator.method}",
                fix="use method 4PL-B (--method 4PL-B), or leave out the calibration "
                "(--calibration-sd)",
            )


@dataclass(frozen=True)
class RunSettings:
    """Every setting of one run, as one object that each entry point takes
    (:func:`gnss_citygml.pipeline.run`, :func:`gnss_citygml.jobs.estimate_file`, ...) and
    hands down whole: a new option is a field of one of its parts, not a keyword passed
    through every function on its way to the stage that uses it.

    Made, it is checked: each part checks its own values, and :meth:`check` the rules between
    them, so a run never starts with settings it would refuse half-way.

    Parameters
    ----------
    rays, receiver_heights, estimator, position_error, calibration, tiling
        The stages' settings (this module's classes).
    grid_dir
        Folder of the OSTN15/OSGM15 grids (:mod:`gnss_citygml.geodesy`; None: the search
        path).
    dem_crs
        CRS of a DEM that has none (e.g. ``"EPSG:27700"`` for an OS Terrain ASCII grid;
        anything pyproj reads).
    """

    rays: Rays = Rays()
    receiver_heights: ReceiverHeights = ReceiverHeights()
    estimator: Estimator = Estimator()
    position_error: PositionError = PositionError()
    calibration: Calibration = Calibration()
    tiling: Tiling = Tiling()
    grid_dir: str | os.PathLike[str] | None = None
    dem_crs: Any = None

    def __post_init__(self):
        self.check()

    def check(self) -> None:
        """Refuse settings that do not go together: self-calibration with a method other than
        4PL-B (:meth:`Calibration.check_method`); in a run in tiles, a method other than 4PL-B
        or 4PL (the baselines have no parts) and self-calibration (its offsets move rays
        across tiles)."""
        for part in fields(self):
            kind = type(part.default)
            if part.default is not None and not isinstance(getattr(self, part.name), kind):
                raise TypeError(
                    f"the run settings' {part.name} must be of type {kind.__name__}, "
                    f"not {getattr(self, part.name)!r}"
                )
        self.calibration.check_method(self.estimator)
        if self.tiling.on and not self.estimator.fourpl:
            raise InputError(
                f"a run on a Dask scheduler runs 4PL-B or 4PL, not {self.estimator.method}",
                fix="use --method 4PL-B, or leave out --scheduler",
            )
        if self.tiling.on and self.calibration.on:
            raise InputError(
                "self-calibration is not available in a run on a Dask scheduler",
                fix="leave out --calibration-sd, or --scheduler",
            )

    @classmethod
    def of(cls, settings: RunSettings | None = None, **changes: Any) -> RunSettings:
        """``settings`` (default: the defaults) with the parts named in ``changes`` replaced,
        checked: what an entry point makes of its ``settings`` and keyword arguments
        (``run(..., estimator=Estimator(method="4PL"))``)."""
        base = cls() if settings is None else settings
        unknown = sorted(set(changes) - {f.name for f in fields(cls)})
        if unknown:
            raise TypeError(f"unknown run settings: {', '.join(unknown)}")
        return replace(base, **changes) if changes else base
