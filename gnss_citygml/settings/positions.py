"""How far the receiver positions may be off (:class:`PositionError`), for the height fits to
model, with its defaults."""

from __future__ import annotations

from dataclasses import dataclass

from ..errors import InputError
from .checks import POSITION_DISTANCES, POSITION_SDS, WINDOWS, positive, within

#: Position error (m per axis) of an observation that does not say (its ``position_sd`` empty):
#: a point placed by hand on a large-scale map, as the paper's receivers were ("an estimated
#: location error of below 2 metres", taken as two standard deviations).
DEFAULT_POSITION_SD = 1.0
#: How far (m) a moving receiver goes with one position error (``PositionError.distance``): a
#: phone's fix is biased by the reflections of the facades around it, which stay while it
#: stays in one stretch of street and change when it reaches the next (a London block is
#: 50-100 m long; measured in docs/issue-28-positions.md).
DEFAULT_POSITION_DISTANCE = 50.0
#: How far across a ray (in its position's standard deviations per axis) a footprint the ray
#: passes without entering still gives an intersection row (``PositionError.crossing``): three,
#: beyond which the chance that the error moved the ray across it is below 0.14 %.
NEAR_SDS = 3.0


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
    distance
        How far (m) a moving receiver (a phone's fixes, a walker's traced path) goes with one
        error: until its reported position is this far from where the error began
        (:data:`DEFAULT_POSITION_DISTANCE`). ``None``: its whole recording. A receiver standing
        at one point, or a phone lying still, keeps one error
        (:func:`~gnss_citygml.recordings.position_groups`).
    window
        Instead of ``distance``: how long (s) one error of a moving receiver lasts, its rows
        sharing an error within windows of this length (windows of each recording from its own
        first epoch).
    crossing
        Give each intersection its chance that the ray crosses the footprint at all, given the
        position error across the ray (column ``crossing``), and a row for each footprint a ray
        passes within :data:`NEAR_SDS` standard deviations of without entering it (``order``
        -1): a position error may move a ray past a footprint's corner, into a building it
        missed or out of one that blocked it (issue 47). The height fits weigh each row by it.
    """

    sd: float | None = None
    window: float | None = None
    distance: float | None = DEFAULT_POSITION_DISTANCE
    crossing: bool = False

    def __post_init__(self):
        if self.sd is not None and not within(self.sd, POSITION_SDS):
            raise InputError(
                f"the position error must be a number of metres, {POSITION_SDS[0]:g} to "
                f"{POSITION_SDS[1]:g}, not {self.sd}",
                fix="give --position-sd, e.g. 1 m for points placed by hand (0: exact positions)",
            )
        if self.window is not None:
            positive(
                self.window,
                WINDOWS,
                "the position window",
                "seconds",
                "give --position-window, e.g. 30 for a walker's traced path, or leave it out for "
                "the whole recording",
            )
        if self.distance is not None:
            positive(
                self.distance,
                POSITION_DISTANCES,
                "the position error's distance",
                "metres",
                f"give --position-distance in metres, e.g. {DEFAULT_POSITION_DISTANCE:g}",
            )

    @property
    def exact(self) -> bool:
        """Whether the positions are taken as exact (``sd=0``): no error is modelled."""
        return self.sd == 0
