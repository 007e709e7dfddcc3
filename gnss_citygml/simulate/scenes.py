"""Simulated scenes: buildings with true 2.5D roofs, and where the receivers stand or walk.

A building is a footprint made of *parts*, each a polygon with a flat top (ODN, m). Flat roofs
are one part, multi-part buildings several, and a pitched roof is a stack of thin strips
stepping up to the ridge. A rising ray entering a flat-topped part below its top is blocked,
which makes the true visibility test exact for these roofs. The *true height* of a building is
its representative LOD1 height, the middle of its main roof's height range, as in the paper
(eaves to ridge for a pitched roof). Its *roof span* (issue 27) is the lowest and the highest
point of its whole roof: by that an estimate is judged (its distance to the span, 0 inside),
as LOD1 height references range from the one to the other.

The presets mirror the paper's sites: ``ucl`` (a tall complex building seen from an open
square), ``goodchild`` (a 16 m block in a narrow pedestrian canyon), ``hermitage`` (a 10 m
pitched terrace seen from across the street) and ``city`` (dozens of buildings, walking
receivers). Positions are local grid metres around a London origin.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import shapely
from shapely.geometry import Polygon, box
from shapely.geometry.base import BaseGeometry

__all__ = [
    "PRESETS",
    "Building",
    "Scene",
    "Session",
    "city_scene",
    "city_walks",
    "make_scene",
    "street_scene",
]


@dataclass(frozen=True)
class Building:
    """A footprint of flat-topped parts with its true representative height (ODN, m).

    ``span`` is the roof's lowest and highest point (ODN, m) where the parts only approximate
    it (a pitched roof's strips, whose tops lie between its eaves and ridge); without it the
    span is the parts' lowest and highest top."""

    id: str
    parts: tuple[tuple[Polygon, float], ...]
    ground: float
    true_height: float
    span: tuple[float, float] | None = None

    @property
    def footprint(self) -> BaseGeometry:
        return shapely.union_all([p for p, _ in self.parts]).normalize()

    @property
    def roof_span(self) -> tuple[float, float]:
        """The lowest and highest roof point (ODN, m): a flat roof's height twice, a pitched
        roof's eaves and ridge, a multi-part building's lowest and highest part's top."""
        if self.span is not None:
            return self.span
        tops = [top for _, top in self.parts]
        return min(tops), max(tops)


@dataclass(frozen=True)
class Session:
    """A recording: a receiver standing at ``path[0]`` or walking along ``path``."""

    receiver: str
    start: float  # s after the scene epoch
    duration: float  # s
    path: tuple[tuple[float, ...], ...]  # (x, y) points
    walking: bool = False


@dataclass(frozen=True)
class Scene:
    """Buildings, recording sessions and the site's constants."""

    name: str
    lat: float
    lon: float
    ground: float
    buildings: tuple[Building, ...]
    sessions: tuple[Session, ...]
    #: Elevation mask (deg) of the site's data processing; the paper's 10 deg or 0 deg.
    min_elevation: float = 10.0
    max_elevation: float = 85.0
    #: Buildings whose heights the site is judged on (all when empty).
    targets: tuple[str, ...] = field(default_factory=tuple)


def flat(id_, polygon, ground, rel):
    return Building(id_, ((polygon, ground + rel),), ground, ground + rel)


def pitched(id_, x0, y0, x1, y1, ground, eave, ridge, strips=8):
    """A pitched roof with its ridge along the longer side of the rectangle."""
    along_x = (x1 - x0) >= (y1 - y0)
    lo, hi = (y0, y1) if along_x else (x0, x1)
    edges = np.linspace(lo, hi, strips + 1)
    parts = []
    for a, b in zip(edges[:-1], edges[1:], strict=True):
        mid = 0.5 * (a + b)
        rise = 1.0 - abs(2.0 * (mid - lo) / (hi - lo) - 1.0)  # 0 at the eaves, 1 at the ridge
        top = ground + eave + (ridge - eave) * rise
        poly = box(x0, a, x1, b) if along_x else box(a, y0, b, y1)
        parts.append((poly, top))
    span = (ground + eave, ground + ridge)  # the strips' tops lie between the two
    return Building(id_, tuple(parts), ground, ground + 0.5 * (eave + ridge), span)


def multipart(id_, parts_rel, ground, truth_rel=None):
    """Parts at different heights. The truth is ``truth_rel`` when a representative part is
    named (as the paper did for UCL), else the middle of the parts' height range (the paper's
    rule for every other building)."""
    parts = tuple((poly, ground + rel) for poly, rel in parts_rel)
    if truth_rel is None:
        rels = [rel for _, rel in parts_rel]
        truth_rel = 0.5 * (min(rels) + max(rels))
    return Building(id_, parts, ground, ground + truth_rel)


def _static_sessions(rng, site, starts, duration, place):
    """One static recording per start time (s), at the point ``place(rng)`` draws."""
    return tuple(
        Session(f"{site}_{k}", float(start), duration, (tuple(map(float, place(rng))),))
        for k, start in enumerate(starts)
    )


def _ucl(rng):
    g = 26.0
    main = multipart(
        "ucl_main",
        [
            (box(-40, 40, 0, 70), 18.5),  # main range, west half
            (box(0, 40, 40, 70), 21.5),  # main range, east half
            (box(-8, 32, 8, 40), 32.0),  # portico and dome
            (box(-40, 0, -28, 40), 19.0),  # west wing
            (box(28, 0, 40, 40), 19.0),  # east wing
        ],
        g,
        20.0,
    )
    neighbours = (
        flat("gower_east", box(75, -10, 95, 70), g, 15.0),
        flat("south_range", box(-45, -60, 45, -45), g, 12.0),
    )
    sessions = _static_sessions(
        rng,
        "ucl",
        [0.0, 3 * 3600.0 + 1234.0],
        1800.0,
        lambda r: (r.uniform(-18, 18), r.uniform(8, 28)),  # in the quad, facing the portico
    )
    return Scene(
        "ucl", 51.5246, -0.1340, g, (main, *neighbours), sessions, 10.0, 85.0, ("ucl_main",)
    )


def _goodchild(rng):
    g = 31.0
    block = flat("goodchild_block", box(0, 0, 40, 15), g, 16.0)
    opposite = flat("opposite_block", box(-5, 22, 45, 37), g, 15.0)
    ends = (
        flat("west_block", box(-30, -5, -8, 20), g, 14.0),
        flat("east_block", box(48, -5, 70, 20), g, 14.0),
    )
    sessions = _static_sessions(
        rng,
        "goodchild",
        [2400.0 * k + 777.0 * (k % 2) for k in range(6)],
        1350.0,
        lambda r: (r.uniform(4, 36), 18.5 + r.uniform(-1.0, 1.0)),  # mid-street, 3.5 m out
    )
    return Scene(
        "goodchild",
        51.5660,
        -0.0946,
        g,
        (block, opposite, *ends),
        sessions,
        10.0,
        85.0,
        ("goodchild_block",),
    )


def _hermitage(rng):
    g = 24.0
    terrace = pitched("hermitage_terrace", 0, 0, 60, 9, g, 9.0, 11.0)
    across = pitched("across_terrace", -10, 26, 70, 35, g, 8.5, 11.0)
    behind = pitched("behind_terrace", -10, -40, 70, -31, g, 8.5, 11.0)
    sessions = _static_sessions(
        rng,
        "hermitage",
        [2900.0 * k + 400.0 for k in range(5)],
        1670.0,
        lambda r: (r.uniform(8, 52), 22.5 + r.uniform(-1.0, 1.0)),  # far pavement
    )
    return Scene(
        "hermitage",
        51.5770,
        -0.0900,
        g,
        (terrace, across, behind),
        sessions,
        0.0,
        85.0,
        ("hermitage_terrace",),
    )


#: Spacing (m) of :func:`city_scene`'s blocks: its streets are this less a block's size wide.
BLOCK_PITCH = 60.0


def city_scene(
    rng: np.random.Generator,
    columns: int = 6,
    rows: int = 5,
    walkers: int = 8,
    walk_seconds: float = 300.0,
    walk_length: float | None = None,
) -> Scene:
    """A grid of ``columns`` x ``rows`` blocks, 60 m apart, one building each (flat, pitched or
    multi-part, 8-45 m), and ``walkers`` people each walking ``walk_seconds`` along a street:
    the whole street, or a stretch of ``walk_length`` metres of it."""
    g = 20.0
    buildings = []
    pitch = BLOCK_PITCH
    for i in range(columns):
        for j in range(rows):
            x0, y0 = i * pitch, j * pitch
            w, d = rng.uniform(28, 42), rng.uniform(28, 42)
            kind = rng.choice(["flat", "flat", "pitched", "multi"])
            rel = float(rng.uniform(8.0, 45.0))
            bid = f"city_{i}_{j}"
            if kind == "flat":
                buildings.append(flat(bid, box(x0, y0, x0 + w, y0 + d), g, rel))
            elif kind == "pitched":
                rel = min(rel, 16.0)
                buildings.append(pitched(bid, x0, y0, x0 + w, y0 + d, g, rel - 1.5, rel + 1.5))
            else:
                tower = float(rng.uniform(0.2, 0.35))
                buildings.append(
                    multipart(
                        bid,
                        [
                            (box(x0, y0, x0 + w, y0 + d * (1 - tower)), rel),
                            (
                                box(x0, y0 + d * (1 - tower), x0 + w * 0.4, y0 + d),
                                rel + rng.uniform(4, 10),
                            ),
                            (box(x0 + w * 0.4, y0 + d * (1 - tower), x0 + w, y0 + d), rel),
                        ],
                        g,
                    )
                )
    sessions = city_walks(rng, columns, rows, walkers, walk_seconds, walk_length)
    return Scene("city", 51.5200, -0.1000, g, tuple(buildings), sessions, 10.0, 85.0, ())


def city_walks(
    rng: np.random.Generator,
    columns: int,
    rows: int,
    walkers: int,
    walk_seconds: float = 300.0,
    walk_length: float | None = None,
    name: str = "walker",
) -> tuple[Session, ...]:
    """``walkers`` people walking ``walk_seconds`` each, one after another (25 min apart),
    along the streets of :func:`city_scene`'s grid of ``columns`` x ``rows`` blocks: the whole
    street, or a stretch of ``walk_length`` metres of it. Another day's walks of the same
    district are another draw with another ``name`` (``day2_walker``), so that each day's
    receivers are its own."""
    pitch = BLOCK_PITCH
    sessions = []
    for k in range(walkers):
        if k % 2 == 0:  # walk west-east along a street between block rows
            y = int(rng.integers(0, rows)) * pitch + 51.0  # mid-street: blocks end by 42 m
            ends = (-10.0, columns * pitch - 20.0)
            path = [(x, y) for x in _stretch(rng, ends, walk_length)]
        else:  # walk south-north along a street between block columns
            x = int(rng.integers(0, columns)) * pitch + 51.0
            ends = (-10.0, rows * pitch - 20.0)
            path = [(x, y) for y in _stretch(rng, ends, walk_length)]
        sessions.append(Session(f"{name}_{k}", 1500.0 * k, walk_seconds, tuple(path), True))
    return tuple(sessions)


def street_scene(
    rng: np.random.Generator,
    width: float,
    offset: float,
    *,
    buildings: int = 6,
    walkers: int = 4,
    walk_seconds: float = 300.0,
    walking: bool = True,
) -> Scene:
    """A straight street ``width`` m wide between two rows of ``buildings`` each (8-25 m wide
    frontages, 15-30 m deep, 8-45 m high; flat, pitched or stepped roofs), and ``walkers``
    receivers ``offset`` m from the south row's wall (inside the street): walking the street's
    length, or standing at points along it (``walking=False``).

    For judging an estimator across regimes (issue 14): a narrow canyon (receivers 3-8 m from
    a wall), a wide street, a square (a street 80-240 m wide)."""
    if not 0.0 < offset < width:
        raise ValueError(f"the receivers must be inside the street: 0 < offset {offset} < {width}")
    g = 20.0
    placed = []
    for side, (y0, y1) in (("s", (-rng.uniform(15, 30), 0.0)), ("n", (width, width + 25.0))):
        x = 0.0
        for k in range(buildings):
            w = float(rng.uniform(8.0, 25.0))
            bid = f"street_{side}{k}"
            rel = float(rng.uniform(8.0, 45.0))
            kind = rng.choice(["flat", "flat", "pitched", "stepped"])
            if kind == "flat":
                placed.append(flat(bid, box(x, y0, x + w, y1), g, rel))
            elif kind == "pitched":
                rel = min(rel, 16.0)
                placed.append(pitched(bid, x, y0, x + w, y1, g, rel - 1.5, rel + 1.5))
            else:  # a setback: the street side lower than the back
                mid = 0.5 * (y0 + y1)
                front = (
                    (box(x, mid, x + w, y1), rel) if side == "s" else (box(x, y0, x + w, mid), rel)
                )
                back = (
                    (box(x, y0, x + w, mid), rel + 6)
                    if side == "s"
                    else (box(x, mid, x + w, y1), rel + 6)
                )
                placed.append(multipart(bid, [front, back], g))
            x += w + float(rng.uniform(0.0, 3.0))
    length, y = x, float(offset)
    sessions = []
    for k in range(walkers):
        if walking:
            path = ((5.0, y), (length - 5.0, y)) if k % 2 == 0 else ((length - 5.0, y), (5.0, y))
        else:
            path = ((float(rng.uniform(5.0, length - 5.0)), y),)
        sessions.append(Session(f"street_{k}", 900.0 * k, walk_seconds, path, walking))
    return Scene("street", 51.5200, -0.1000, g, tuple(placed), tuple(sessions), 10.0, 85.0, ())


def _stretch(rng, ends, length):
    """Start and end of a walk along a street from ``ends[0]`` to ``ends[1]``."""
    if length is None or length >= ends[1] - ends[0]:
        return ends
    start = float(rng.uniform(ends[0], ends[1] - length))
    return start, start + length


def _city(rng):
    return city_scene(rng)


#: Scene factories by preset name; each takes a numpy Generator.
PRESETS = {"ucl": _ucl, "goodchild": _goodchild, "hermitage": _hermitage, "city": _city}


def make_scene(preset: str, rng: np.random.Generator) -> Scene:
    """The scene of a preset, with receiver placements drawn from ``rng``."""
    return PRESETS[preset](rng)
