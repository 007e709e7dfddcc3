"""Geometric checks of the solids of CityGML and CityJSON files, vectorised with numpy.

For the solids of both formats (``Solid``, and the members of ``MultiSolid``/``CompositeSolid``):
rings with 3 or more distinct points; planar faces (every vertex within 1 cm of the face's
plane); simple faces (each face, projected on its plane, a valid polygon); closed and 2-manifold
shells (every edge shared by exactly two faces, used once in each direction), connected; outward
faces (positive signed volume, negative for a cavity); members of a ``CompositeSolid`` that do
not overlap. Vertices within 1 mm are the same vertex. Messages quote the matching val3dity
error code. Not checked: vertices where a shell touches itself (a hole touching its exterior at
one point), self-intersecting shells (val3dity 306), surfaces that are not part of a solid;
overlaps within a CompositeSolid are found by testing a point just inside each member against
the others (duplicated and largely overlapping members, not every sliver).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import shapely
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from .report import Issue

__all__ = [
    "BATCH",
    "COORDINATE_LIMIT",
    "PLANARITY_TOLERANCE",
    "SNAP_TOLERANCE",
    "Shell",
    "Shells",
    "coordinate_problem",
]

#: Largest distance (m) of a face's vertex from the face's plane.
PLANARITY_TOLERANCE = 0.01
#: Vertices closer than this (m) are the same vertex.
SNAP_TOLERANCE = 0.001
#: Shells gathered before their geometry is checked at once.
BATCH = 20000
#: Largest coordinate (absolute value) checked: no CRS comes near it, and beyond it the 1 mm
#: snapping (int64) and the volumes would overflow. NaN and infinities are beyond it too.
COORDINATE_LIMIT = 1e12


def coordinate_problem(values: np.ndarray, note: str = "") -> str | None:
    """What is wrong with coordinates not all finite and within :data:`COORDINATE_LIMIT`.

    None when nothing is; ``note`` follows the first wrong value in the message."""
    far = ~(np.abs(values) <= COORDINATE_LIMIT)  # NaN compares False
    if not far.any():
        return None
    return (
        f"{np.count_nonzero(far)} coordinate value(s) non-finite or beyond "
        f"±{COORDINATE_LIMIT:g} (the first: {values[far].flat[0]:g}{note}): geometry not checked"
    )


@dataclass
class Shell:
    """A shell's object, label, sign and CompositeSolid, for the messages about it."""

    object_id: str
    label: str
    sign: int  # +1 an exterior shell, -1 a cavity
    group: str | None  # the CompositeSolid it belongs to


class Shells:
    """Shells gathered from a file, checked together with numpy and shapely.

    ``closed``: each ring repeats its first point at its end (GML), else not (CityJSON).
    """

    def __init__(self, closed: bool):
        self.closed = closed
        self.rings: list[np.ndarray] = []
        self.ring_face: list[int] = []
        self.face_shell: list[int] = []
        self.shells: list[Shell] = []
        self.empty_faces: list[Issue] = []  # faces without a ring: reported, left out

    def __len__(self) -> int:
        return len(self.shells)

    def add(self, shell: Shell, faces: list[list[np.ndarray]]) -> None:
        """Add a shell: faces, each a list of rings (exterior first), each (k, 3) points."""
        index = len(self.shells)
        self.shells.append(shell)
        empty = sum(1 for face in faces if not len(face))
        if empty:
            text = f"{shell.label}: {empty} face(s) without a ring: a face needs an exterior ring"
            self.empty_faces.append(Issue(shell.object_id, "face-empty", text))
        for face in filter(len, faces):
            self.ring_face.extend([len(self.face_shell)] * len(face))
            self.face_shell.append(index)
            self.rings.extend(face)

    def check(self) -> list[Issue]:
        """Every geometric error of the gathered shells.

        A shell with a coordinate out of range (:data:`COORDINATE_LIMIT`, NaN, infinite) gets
        that one error, and is left out of the other checks."""
        if not self.rings:
            return list(self.empty_faces)
        sizes = np.array([len(r) for r in self.rings], dtype=np.int64)
        points = np.concatenate([np.asarray(r, dtype=float).reshape(-1, 3) for r in self.rings])
        far = ~(np.abs(points) <= COORDINATE_LIMIT).all(axis=1)
        if not far.any():
            return self.empty_faces + _Geometry(self, points, sizes).issues
        ring_shell = np.array(self.face_shell, dtype=np.int64)[self.ring_face]
        point_shell = np.repeat(ring_shell, sizes)
        issues = []
        for shell in np.unique(point_shell[far]):
            meta = self.shells[shell]
            problem = coordinate_problem(points[point_shell == shell])
            issues.append(Issue(meta.object_id, "coordinate-range", f"{meta.label}: {problem}"))
        return self.empty_faces + issues + self._without(set(point_shell[far].tolist())).check()

    def _without(self, dropped: set[int]) -> Shells:
        """These shells but ``dropped``: each kept shell added again with its faces."""
        faces: list[list[np.ndarray]] = [[] for _ in self.face_shell]
        for ring, face in zip(self.rings, self.ring_face, strict=True):
            faces[face].append(ring)
        per_shell: list[list[list[np.ndarray]]] = [[] for _ in self.shells]
        for face, shell in enumerate(self.face_shell):
            per_shell[shell].append(faces[face])
        kept = Shells(self.closed)
        for shell, meta in enumerate(self.shells):
            if shell not in dropped:
                kept.add(meta, per_shell[shell])
        return kept


def _group_ids(*keys: np.ndarray) -> np.ndarray:
    """One id per row, the same for rows with equal integer keys (numbered in sorted order)."""
    order = np.lexsort(keys[::-1])
    new = np.zeros(len(order), dtype=bool)
    new[:1] = True
    for key in keys:
        new[1:] |= np.diff(key[order]) != 0
    ids = np.empty(len(order), dtype=np.int64)
    ids[order] = np.cumsum(new) - 1
    return ids


_AXES = np.array([[1, 2], [2, 0], [0, 1]])  # the plane axes kept when dropping axis k


class _Geometry:
    """The checks of :class:`Shells`, vectorised over all their points, rings and faces."""

    def __init__(self, shells: Shells, points: np.ndarray, sizes: np.ndarray):
        self.meta = shells.shells
        self.issues: list[Issue] = []
        n_shells = len(self.meta)
        ring_shell = np.array(shells.face_shell, dtype=np.int64)[shells.ring_face]
        broken = np.zeros(n_shells, dtype=bool)
        if shells.closed:
            points, sizes = self._open(points, sizes, ring_shell, broken)
        self.ring_face = np.array(shells.ring_face, dtype=np.int64)
        self.face_shell = np.array(shells.face_shell, dtype=np.int64)
        self.ring_shell = self.face_shell[self.ring_face]
        self.start = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        self.sizes = sizes
        self.point_ring = np.repeat(np.arange(len(sizes)), sizes)
        self.point_shell = self.ring_shell[self.point_ring]
        first = np.searchsorted(self.point_shell, np.arange(n_shells))
        self.origin = points[np.minimum(first, len(points) - 1)]
        self.q = points - self.origin[self.point_shell]  # shell-local: precise cross products
        i = np.arange(len(points))
        ring_end = self.start[self.point_ring] + sizes[self.point_ring] - 1
        self.following = np.where(i == ring_end, self.start[self.point_ring], i + 1)

        broken |= self._rings()
        self._faces()
        broken |= self.bad_face_shell
        closed = self._topology(~broken)
        self._volume(closed)
        self._composites(closed)

    def _open(self, points, sizes, ring_shell, broken):
        """Check that each ring ends on its first point, then drop that closing point."""
        end = np.cumsum(sizes) - 1
        start = end - sizes + 1
        closed = sizes >= 2
        closed[closed] = (points[start[closed]] == points[end[closed]]).all(axis=1)
        for ring in np.flatnonzero(~closed):
            broken[ring_shell[ring]] = True
            x, y, z = points[start[ring]] if sizes[ring] else (np.nan,) * 3
            self._report(
                ring_shell[ring],
                "ring-not-closed",
                f"a ring's last point is not its first, near ({x:.3f}, {y:.3f}, {z:.3f}) "
                "(val3dity 103)",
            )
        keep = np.ones(len(points), dtype=bool)
        keep[end[closed]] = False
        return points[keep], sizes - closed

    def _report(self, shell: int | np.integer, rule: str, text: str) -> None:
        meta = self.meta[shell]
        self.issues.append(Issue(meta.object_id, rule, f"{meta.label}: {text}"))

    def _near(self, point: int) -> str:
        x, y, z = self.q[point] + self.origin[self.point_shell[point]]
        return f"near ({x:.3f}, {y:.3f}, {z:.3f})"

    def _rings(self) -> np.ndarray:
        """Rings with fewer than 3 points or repeated consecutive points."""
        few = self.sizes < 3
        step = np.linalg.norm(self.q[self.following] - self.q, axis=1)
        repeats = np.bincount(
            self.point_ring, weights=step < SNAP_TOLERANCE, minlength=len(self.sizes)
        )
        repeated = (repeats > 0) & ~few
        for ring in np.flatnonzero(few):
            self._report(
                self.ring_shell[ring],
                "ring-too-few-points",
                f"a ring has {self.sizes[ring]} distinct point(s), 3 needed (val3dity 101)",
            )
        for ring in np.flatnonzero(repeated):
            self._report(
                self.ring_shell[ring],
                "ring-duplicate-vertex",
                f"a ring repeats a point {self._near(self.start[ring])} (val3dity 102)",
            )
        self.bad_ring = few | repeated
        bad = np.zeros(len(self.meta), dtype=bool)
        bad[self.ring_shell[self.bad_ring]] = True
        return bad

    def _faces(self) -> None:
        """Normals, planarity and simplicity of every face."""
        q, nxt = self.q, self.following
        terms = np.column_stack(
            [
                (q[:, 1] - q[nxt, 1]) * (q[:, 2] + q[nxt, 2]),
                (q[:, 2] - q[nxt, 2]) * (q[:, 0] + q[nxt, 0]),
                (q[:, 0] - q[nxt, 0]) * (q[:, 1] + q[nxt, 1]),
            ]
        )
        n_rings, n_faces = len(self.sizes), len(self.face_shell)
        ring_normal = np.column_stack(
            [np.bincount(self.point_ring, weights=terms[:, k], minlength=n_rings) for k in range(3)]
        )
        exterior = np.searchsorted(self.ring_face, np.arange(n_faces))
        normal = ring_normal[exterior]
        length = np.linalg.norm(normal, axis=1)
        self.area = length / 2
        unit = normal / np.where(length > 0, length, 1.0)[:, None]
        sizes = np.maximum(self.sizes[exterior], 1)
        centroid = np.column_stack(
            [
                np.bincount(self.point_ring, weights=q[:, k], minlength=n_rings)[exterior] / sizes
                for k in range(3)
            ]
        )
        point_face = self.ring_face[self.point_ring]
        distance = np.abs(np.einsum("ij,ij->i", q - centroid[point_face], unit[point_face]))
        worst = np.zeros(n_faces)
        np.maximum.at(worst, point_face, distance)
        bad_ring_face = np.zeros(n_faces, dtype=bool)
        bad_ring_face[self.ring_face[self.bad_ring]] = True
        degenerate = (length <= 1e-12) & ~bad_ring_face
        non_planar = (worst > PLANARITY_TOLERANCE) & ~degenerate & ~bad_ring_face
        for face in np.flatnonzero(degenerate):
            self._report(
                self.face_shell[face],
                "polygon-degenerate",
                f"a face has no area {self._near(self.start[exterior[face]])} (val3dity 105)",
            )
        for face in np.flatnonzero(non_planar):
            self._report(
                self.face_shell[face],
                "polygon-non-planar",
                f"a face's vertices lie up to {worst[face]:.3f} m from its plane "
                f"{self._near(self.start[exterior[face]])} (tolerance {PLANARITY_TOLERANCE} m, "
                "val3dity 203)",
            )
        self.unit, self.centroid = unit, centroid
        self.axis = np.abs(unit).argmax(axis=1)
        good = ~(bad_ring_face | degenerate)
        self.polygons = np.full(n_faces, None, dtype=object)
        self.polygons[good] = self._projected(np.flatnonzero(good))
        simple = np.ones(n_faces, dtype=bool)
        simple[good] = shapely.is_valid(self.polygons[good])
        for face in np.flatnonzero(~simple):
            reason = shapely.is_valid_reason(self.polygons[face]).split("[")[0]
            self._report(
                self.face_shell[face],
                "polygon-not-simple",
                f"a face is not a simple polygon ({reason}) "
                f"{self._near(self.start[exterior[face]])} (val3dity 104, 201)",
            )
        bad_face = degenerate | non_planar | ~simple
        self.bad_face_shell = np.zeros(len(self.meta), dtype=bool)
        self.bad_face_shell[self.face_shell[bad_face]] = True

    def _projected(self, faces: np.ndarray) -> np.ndarray:
        """The faces as 2D shapely polygons on the plane of their dominant axes."""
        rings = np.flatnonzero(np.isin(self.ring_face, faces))
        sizes = self.sizes[rings]
        closed = sizes + 1  # each ring's first point repeated at its end
        position = np.arange(closed.sum()) - np.repeat(np.cumsum(closed) - closed, closed)
        order = np.repeat(self.start[rings], closed) + np.where(
            position == np.repeat(sizes, closed), 0, position
        )
        axes = _AXES[self.axis[self.ring_face[self.point_ring[order]]]]
        xy = np.take_along_axis(self.q[order], axes, axis=1)
        ring_offsets = np.concatenate([[0], np.cumsum(closed)])
        per_face = np.bincount(self.ring_face[rings], minlength=len(self.face_shell))[faces]
        face_offsets = np.concatenate([[0], np.cumsum(per_face)])
        return shapely.from_ragged_array(
            shapely.GeometryType.POLYGON, xy, (ring_offsets, face_offsets)
        )

    def _topology(self, usable: np.ndarray) -> np.ndarray:
        """Closed, 2-manifold, consistently oriented, connected shells."""
        points = np.flatnonzero(usable[self.point_shell])
        closed = usable.copy()
        if not points.size:
            return closed
        snapped = np.rint(self.q[points] / SNAP_TOLERANCE).astype(np.int64)
        shell = self.point_shell[points]
        vertex = _group_ids(shell, snapped[:, 0], snapped[:, 1], snapped[:, 2])
        vertex_of = np.full(len(self.q), -1)
        vertex_of[points] = vertex
        a, b = vertex_of[points], vertex_of[self.following[points]]
        edge = _group_ids(np.minimum(a, b), np.maximum(a, b))
        counts = np.bincount(edge)
        forward = np.bincount(edge, weights=a < b)
        edge_shell = np.zeros(len(counts), dtype=np.int64)
        edge_shell[edge] = shell
        rules = (
            (counts == 1, "shell-not-closed", "edge(s) bound one face only: holes (val3dity 302)"),
            (counts > 2, "shell-non-manifold", "edge(s) shared by 3 faces or more (val3dity 303)"),
            (
                (counts == 2) & (forward != 1),
                "shell-orientation",
                "edge(s) used twice in the same direction: faces oriented inconsistently "
                "(val3dity 307)",
            ),
        )
        for mask, rule, text in rules:
            per_shell = np.bincount(edge_shell[mask], minlength=len(self.meta))
            for s in np.flatnonzero(per_shell):
                self._report(s, rule, f"{per_shell[s]} {text}")
                closed[s] = False
        n_vertices = int(vertex.max()) + 1
        # a face joins its holes to its exterior: link each ring's first vertex to the exterior's
        rings = np.flatnonzero(usable[self.ring_shell] & (self.sizes > 0))
        exterior = np.searchsorted(self.ring_face, self.ring_face[rings])
        a = np.concatenate([a, vertex_of[self.start[rings]]])
        b = np.concatenate([b, vertex_of[self.start[exterior]]])
        graph = coo_matrix((np.ones(len(a)), (a, b)), shape=(n_vertices, n_vertices))
        _, component = connected_components(graph, directed=False)
        vertex_shell = np.zeros(n_vertices, dtype=np.int64)
        vertex_shell[vertex_of[points]] = shell
        pairs = np.unique(np.column_stack([vertex_shell, component]), axis=0)
        pieces = np.bincount(pairs[:, 0], minlength=len(self.meta))
        for s in np.flatnonzero(pieces > 1):
            self._report(
                s, "shell-not-connected", f"the shell has {pieces[s]} separate parts (val3dity 305)"
            )
            closed[s] = False
        return closed

    def _volume(self, closed: np.ndarray) -> None:
        """Signed volume (divergence theorem): faces point out of the solid."""
        q = self.q
        i = np.arange(len(q))
        position = i - self.start[self.point_ring]
        fan = (position >= 1) & (position <= self.sizes[self.point_ring] - 2)
        i = i[fan]
        apex = q[self.start[self.point_ring[i]]]
        triple = np.einsum("ij,ij->i", apex, np.cross(q[i], q[i + 1]))
        volume = np.bincount(self.point_shell[i], weights=triple, minlength=len(self.meta))
        self.volume = volume.astype(float) / 6  # bincount of nothing counts in integers
        for s in np.flatnonzero(closed):
            sign = self.meta[s].sign
            if self.volume[s] * sign <= 0:
                kind = "exterior shell" if sign > 0 else "cavity"
                self._report(
                    s,
                    "solid-inward",
                    f"the faces of the {kind} point the wrong way "
                    f"(signed volume {self.volume[s]:.3f} m³, val3dity 308)",
                )
                closed[s] = False

    def _composites(self, valid: np.ndarray) -> None:
        """Members of one CompositeSolid whose interiors overlap (val3dity 501, 502)."""
        groups: dict[str, list[int]] = {}
        for s, meta in enumerate(self.meta):
            if meta.group is not None and valid[s] and meta.sign > 0:
                groups.setdefault(meta.group, []).append(s)
        for members in groups.values():
            for k, first in enumerate(members):
                for second in members[k + 1 :]:
                    if self._inside(first, second) or self._inside(second, first):
                        self._report(
                            first,
                            "composite-overlap",
                            "two solids of a CompositeSolid overlap (val3dity 501, 502)",
                        )

    def _inside(self, solid: int, other: int) -> bool:
        """Whether a point just inside ``solid`` (under its largest face) is inside ``other``."""
        faces = np.flatnonzero(self.face_shell == solid)
        face = faces[self.area[faces].argmax()]
        kept = _AXES[self.axis[face]]
        flat = shapely.get_coordinates(shapely.point_on_surface(self.polygons[face]))[0]
        point = self.centroid[face].copy()
        point[kept] = flat
        drop, n = self.axis[face], self.unit[face]
        point[drop] -= (n[kept] @ (flat - self.centroid[face][kept])) / n[drop]
        size = np.ptp(self.q[self.point_shell == solid], axis=0).max()
        point = point - 1e-3 * size * n + self.origin[solid] - self.origin[other]
        targets = np.flatnonzero(self.face_shell == other)
        ray = np.array([0.5377, 0.3821, 0.7514])
        along = self.unit[targets] @ ray
        reach = np.einsum("ij,ij->i", self.unit[targets], self.centroid[targets] - point)
        t = np.divide(reach, along, out=np.full(len(targets), -1.0), where=np.abs(along) > 1e-12)
        hit = t > 0
        where = point + t[hit, None] * ray
        axes = _AXES[self.axis[targets[hit]]]
        flat = np.take_along_axis(where, axes, axis=1)
        inside = shapely.contains_xy(self.polygons[targets[hit]], flat[:, 0], flat[:, 1])
        return bool(inside.sum() % 2)
