"""The options of the stages, as small frozen dataclasses: each defined once, with its defaults.

Options that travel together are one object, so that a new option is one field here instead of
a keyword passed through every function on its way to the stage that uses it. The command line,
the Python API and the QGIS plugin build these objects; :func:`gnss_citygml.pipeline.estimate`
takes them:

- :class:`Rays`: which signals are cast (the elevation mask) and how (range, Earth's curvature);
- :class:`ReceiverHeights`: where the antenna's height comes from;
- :class:`Estimator`: the height estimator (4PL-B, 4PL or a baseline) and its settings, with
  :class:`Acceptance`, what a 4PL-B estimate must satisfy to count as converged;
- :class:`PositionError`: how far the receiver positions may be off, for the fits to model;
- :class:`Calibration`: the self-calibration of the receivers' offsets;
- :class:`Tiling`: a run cut into tiles on a Dask cluster.

Each object checks its own values when it is made (one-line
:class:`~gnss_citygml.errors.InputError`, or :class:`~gnss_citygml.errors.ModelError` for a
method or option the estimator does not have), so a bad value is refused before any work. This
module imports nothing heavy: a command can build its settings before loading a stage.
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field

from .errors import InputError, ModelError
from .model import METHODS

__all__ = [
    "DEFAULT_POSITION_SD",
    "DEFAULT_TILE_SIZE",
    "HEIGHT_RULES",
    "RECEIVER_HEIGHTS",
    "TILE_SIZES",
    "WEIGHTINGS",
    "Acceptance",
    "Calibration",
    "Estimator",
    "PositionError",
    "ReceiverHeights",
    "Rays",
    "Tiling",
    "check_tile_size",
]

#: Reweighting schemes of the 4PL height fit (:func:`~gnss_citygml.model.fourplb.height_weights`).
WEIGHTINGS = ("none", "height", "balanced", "looks")

#: How a 4PL's height is read off it: its inflection point c, or the paper's c + 1.5/b. Both
#: are measured in the README (benchmarks/scenes.py: c was nearer the truth in every regime);
#: both are in every output (``c`` and ``height_paper``).
HEIGHT_RULES = ("inflection", "paper")

#: Where receiver heights come from: the DEM plus an antenna height, or the log's own heights.
RECEIVER_HEIGHTS = ("dem", "log")

#: Side of a tile of a run in tiles (m): the OS 1 km square.
DEFAULT_TILE_SIZE = 1000.0
#: The tile sizes a run takes (m): from a few buildings' width (a tile's work is its rays'
#: reach around it: smaller tiles only repeat it; see also :func:`gnss_citygml.tiles.check_reach`)
#: to the OS 100 km square (a larger one has too few tiles to share among workers).
TILE_SIZES = (50.0, 100_000.0)

#: Position error (m per axis) of an observation that does not say (its ``position_sd`` empty):
#: a point placed by hand on a large-scale map, as the paper's receivers were ("an estimated
#: location error of below 2 metres", taken as two standard deviations).
DEFAULT_POSITION_SD = 1.0


def _finite(value) -> bool:
    return isinstance(value, numbers.Real) and math.isfinite(value)


def _count(value) -> bool:
    """A whole number, 1 or more."""
    return isinstance(value, numbers.Integral) and int(value) >= 1


def _positive(value) -> bool:
    return _finite(value) and value > 0


def check_tile_size(size: float) -> None:
    """Refuse a tile size that is not a whole number of metres (tiles are named by their
    south-west corner to the metre) within :data:`TILE_SIZES`."""
    low, high = TILE_SIZES
    if not (_finite(size) and low <= size <= high and float(size).is_integer()):
        raise InputError(
            f"a tile size must be a whole number of metres from {low:g} to {high:,.0f}, "
            f"not {size!r}",
            fix="give --tile-size in metres, e.g. 1000",
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
        band = (self.min_elevation, self.max_elevation)
        if not (all(map(_finite, band)) and -90.0 <= band[0] < band[1] <= 90.0):
            raise InputError(
                f"elevation mask {band[0]}..{band[1]} deg is not a band of elevations",
                fix="give -90 <= min_elevation < max_elevation <= 90, e.g. 10 and 85",
            )
        if not _positive(self.max_range):
            raise InputError(
                f"max_range must be a positive number of metres, not {self.max_range}",
                fix="e.g. 500",
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
        if not _finite(self.antenna_height):
            raise InputError(
                f"antenna_height must be a number of metres, not {self.antenna_height}",
                fix="e.g. 1 for a phone held in the hand",
            )


@dataclass(frozen=True)
class Acceptance:
    """What a 4PL-B estimate must satisfy to count as converged (see
    :func:`~gnss_citygml.model.fourplb.fourplb`).

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
        in quadrature (:func:`~gnss_citygml.model.fourplb.fourplb`). The default, 10 m, keeps the
        estimate within 5 m of both ends of its range: CityGML's accuracy class for LOD1, the
        benchmark the paper measures itself against.
    """

    label_tol: float = 0.01
    min_signals: int = 10
    min_separation: float = 0.3
    max_uncertainty: float = 10.0

    def __post_init__(self):
        if not (_finite(self.label_tol) and 0.0 <= self.label_tol <= 1.0):
            raise InputError(
                f"label_tol must be a fraction from 0 to 1, not {self.label_tol}", fix="e.g. 0.01"
            )
        if not _count(self.min_signals):
            raise InputError(
                f"min_signals must be a whole number, 1 or more, not {self.min_signals}",
                fix="e.g. 10",
            )
        if not (_finite(self.min_separation) and 0.0 <= self.min_separation <= 1.0):
            raise InputError(
                f"min_separation must be a probability from 0 to 1, not {self.min_separation}",
                fix="e.g. 0.3",
            )
        if not _positive(self.max_uncertainty):
            raise InputError(
                f"max_uncertainty must be a positive number of metres, not {self.max_uncertainty}",
                fix="e.g. 10",
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
        With the intersections' ``signal`` and ``order``: a signal blocked by another building at
        the current estimates is left out for this one.
    max_iter
        Most iterations of 4PL-B's loop.
    height_rule
        How the height is read off a building's 4PL, one of :data:`HEIGHT_RULES`:
        ``inflection`` (default), its inflection point ``c``, where the chance that a signal is
        received is halfway between its values below and above the roof line; ``paper``,
        ``c + 1.5/b``. The range is the 3/b-wide transition centred on the height.
    acceptance
        What an estimate must satisfy to count as converged.

    The baselines use ``init_threshold`` and ``acceptance.min_signals`` only: any other setting
    away from its default is refused with them, rather than silently ignored.
    """

    method: str = "4PL-B"
    init_threshold: float = 30.0
    weighting: str = "none"
    visibility: bool = True
    max_iter: int = 10
    height_rule: str = "inflection"
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
        if not _finite(self.init_threshold):
            raise ModelError("init_threshold must be a finite C/N0 in dB-Hz", fix="e.g. 30")
        if not _count(self.max_iter):
            raise InputError(
                f"max_iter must be a whole number, 1 or more, not {self.max_iter}", fix="e.g. 10"
            )
        if not self.fourpl:
            plain = Estimator(acceptance=Acceptance(min_signals=self.acceptance.min_signals))
            unused = [
                name
                for name in ("weighting", "visibility", "max_iter", "height_rule", "acceptance")
                if getattr(self, name) != getattr(plain, name)
            ]
            if unused:
                raise ModelError(
                    f"option(s) {', '.join(unused)} not used by method {self.method}",
                    fix="leave them out, or use method 4PL-B or 4PL",
                )

    @property
    def fourpl(self) -> bool:
        """Whether the method fits 4PLs (4PL-B or 4PL), whose settings all apply."""
        return self.method in ("4PL-B", "4PL")


@dataclass(frozen=True)
class PositionError:
    """How far the receiver positions may be off, for the height fits to model.

    By default the errors come from the data: each observation's ``position_sd`` (a phone
    fix's accuracy, a surveyed point's ``sd``), :data:`DEFAULT_POSITION_SD` where it is empty.
    The fits then model each signal's resulting height error, and the ranges carry the roof
    line's position uncertainty (:func:`~gnss_citygml.pipeline.intersections`).

    Parameters
    ----------
    sd
        Metres per axis for every position, overriding the data's, e.g. 1 for points placed by
        hand on a map. ``0``: the positions are taken as exact, as in the paper (no error is
        modelled). ``None`` (default): from the data.
    window
        How long (s) one error of a moving receiver (a phone's fixes, a walker's traced path)
        lasts: its rows share an error within windows of this length (windows of each recording
        from its own first epoch). ``None`` (default): its whole recording, as the street around
        it biases a phone's fixes (the reflections it receives) for as long as it is there. A
        receiver standing at one reported point (a point placed by hand) shares one error over
        its stay either way (:func:`~gnss_citygml.recordings.position_groups`).
    """

    sd: float | None = None
    window: float | None = None

    def __post_init__(self):
        if self.sd is not None and not (_finite(self.sd) and self.sd >= 0):
            raise InputError(
                f"the position error must be a number of metres, 0 or more, not {self.sd}",
                fix="give --position-sd, e.g. 1 m for points placed by hand (0: exact positions)",
            )
        if self.window is not None and not _positive(self.window):
            raise InputError(
                f"the position window must be a positive number of seconds, not {self.window}",
                fix="give --position-window, e.g. 30 for a walker's traced path",
            )

    @property
    def exact(self) -> bool:
        """Whether the positions are taken as exact (``sd=0``): no error is modelled."""
        return self.sd == 0


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
    """

    prior_sd: float | None = None
    window: float | None = None
    rounds: int = 3

    def __post_init__(self):
        if self.prior_sd is not None and not _positive(self.prior_sd):
            raise InputError(
                f"the calibration prior must be a positive number of metres, not {self.prior_sd}",
                fix="give --calibration-sd, e.g. 1 m for hand-placed points, 5 m for phone fixes",
            )
        if self.window is not None and self.prior_sd is None:
            raise InputError(
                "a calibration window without self-calibration",
                fix="give the calibration prior (--calibration-sd) too, e.g. 5 m for phone fixes",
            )
        if self.window is not None and not _positive(self.window):
            raise InputError(
                f"the calibration window must be a positive number of seconds, not {self.window}",
                fix="give --calibration-window, e.g. 30 for phone fixes",
            )
        if not _count(self.rounds):
            raise InputError(
                f"calibration rounds must be a whole number, 1 or more, not {self.rounds}",
                fix="e.g. 3",
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
class Tiling:
    """A run cut into square tiles of British National Grid on a Dask cluster
    (:mod:`gnss_citygml.tiled`, the ``[dask]`` extra), with the single process's heights.

    Parameters
    ----------
    scheduler
        ``None`` (default): one process, no tiles. ``"local"``: a Dask ``LocalCluster`` on
        this machine. ``"tcp://host:port"``: a running Dask scheduler and its workers.
    workers
        With ``"local"``: how many worker processes (default: one per core).
    size
        Side of a tile (m, whole metres, :data:`TILE_SIZES`). ``None`` (default):
        :data:`DEFAULT_TILE_SIZE`, the OS 1 km square (tiles are named by OS grid reference,
        ``TQ2982``), or a partition's own.
    """

    scheduler: str | None = None
    workers: int | None = None
    size: float | None = None

    def __post_init__(self):
        if self.scheduler is not None and not (
            self.scheduler == "local" or self.scheduler.startswith(("tcp://", "tls://"))
        ):
            raise InputError(
                f"unknown scheduler {self.scheduler!r}",
                fix="give --scheduler local, or the address of a Dask scheduler (tcp://host:port)",
            )
        if self.workers is not None and (self.scheduler != "local" or not _count(self.workers)):
            raise InputError(
                f"--workers {self.workers} is for --scheduler local, a whole number 1 or more",
                fix="leave it out: a running scheduler has its own workers",
            )
        if self.size is not None:
            check_tile_size(self.size)
        if self.scheduler is None and self.size is not None:
            raise InputError(
                "a tile size is for a run on a Dask scheduler",
                fix="give --scheduler local (or tcp://host:port) too, or leave out --tile-size",
            )

    @property
    def on(self) -> bool:
        """Whether the run is cut into tiles on a Dask cluster."""
        return self.scheduler is not None

    @property
    def side(self) -> float:
        """The tile size of a run from observations in memory (a partition has its own)."""
        return DEFAULT_TILE_SIZE if self.size is None else float(self.size)

    def check(self, estimator: Estimator, calibration: Calibration) -> None:
        """Refuse what a run in tiles cannot do: a method other than 4PL-B or 4PL (the
        baselines have no parts), and self-calibration (its offsets move rays across tiles)."""
        if self.on and not estimator.fourpl:
            raise InputError(
                f"a run on a Dask scheduler runs 4PL-B or 4PL, not {estimator.method}",
                fix="use --method 4PL-B, or leave out --scheduler",
            )
        if self.on and calibration.on:
            raise InputError(
                "self-calibration is not available in a run on a Dask scheduler",
                fix="leave out --calibration-sd, or --scheduler",
            )
