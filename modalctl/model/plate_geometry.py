"""A plate's description before any mesh: its outline (a polygon or a rounded rectangle) and the
holes cut out of it, its material and how each edge is held, each checked when made; and the
plane geometry they are checked with (points inside an outline, distances to its edges, a
self-intersecting polygon). The finite-element plate built on them: :mod:`modalctl.model.fe_plate`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .modes import ModelError

__all__ = ["Material", "MATERIALS", "Support", "SUPPORTS", "Hole", "Outline"]

SUPPORTS = ("clamped", "simply-supported", "free", "elastic")


@dataclass(frozen=True)
class Material:
    """An isotropic plate material: Young's modulus (Pa), density (kg/m^3), Poisson's ratio."""

    modulus: float
    density: float
    poisson: float

    def __post_init__(self):
        for name in ("modulus", "density"):
            value = getattr(self, name)
            if not np.isfinite(value) or value <= 0:
                raise ModelError(f"material.{name}: must be positive and finite, got {value!r}")
        if not (np.isfinite(self.poisson) and 0 <= self.poisson < 0.5):
            raise ModelError(f"material.poisson: must lie in [0, 0.5), got {self.poisson!r}")


#: Named materials (handbook values).
MATERIALS = {
    "glass": Material(70e9, 2500.0, 0.22),  # soda-lime, as plate-glass
    "aluminium": Material(69e9, 2700.0, 0.33),
    "steel": Material(200e9, 7850.0, 0.30),
    "pmma": Material(3.2e9, 1190.0, 0.35),
    "polycarbonate": Material(2.4e9, 1200.0, 0.37),
}


@dataclass(frozen=True)
class Support:
    """How an edge is held: ``kind`` one of :data:`SUPPORTS`; an elastic rim's translational
    stiffness (N/m per metre of edge, ``stiffness``) and rotational stiffness (N m/rad per
    metre, ``rotational``)."""

    kind: str = "clamped"
    stiffness: float = 0.0
    rotational: float = 0.0

    def __post_init__(self):
        if self.kind not in SUPPORTS:
            raise ModelError(f"support: {self.kind!r} is not one of {', '.join(SUPPORTS)}")
        for name in ("stiffness", "rotational"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ModelError(f"support.{name}: must be finite and not negative, got {value!r}")
        if self.kind == "elastic" and self.stiffness == 0 and self.rotational == 0:
            raise ModelError("support: an elastic rim needs a stiffness or a rotational stiffness")


@dataclass(frozen=True)
class Hole:
    """A cut-out: a circle of ``radius`` (m) or a rectangle ``size`` = (width, height) (m) with
    rounded corners of ``corner_radius``, centred at ``centre`` (m). Its edge is free."""

    centre: tuple[float, float]
    radius: float = 0.0
    size: tuple[float, float] | None = None
    corner_radius: float = 0.0

    def __post_init__(self):
        values = [*self.centre, self.radius, self.corner_radius, *(self.size or ())]
        if not np.all(np.isfinite(values)):
            raise ModelError(f"hole: every dimension must be finite, got {self}")
        if (self.size is None) == (self.radius <= 0):
            raise ModelError(f"hole: give either a radius > 0 (a circle) or a size (a rectangle), got {self}")
        if self.size is not None and (min(self.size) <= 0 or not 0 <= self.corner_radius < min(self.size) / 2):
            raise ModelError(f"hole: a rectangle needs a positive size and a corner radius below half its "
                             f"smaller side, got {self}")

    def boundary(self, n: int = 96) -> np.ndarray:
        """Points along the hole's edge (m), shape (n, 2)."""
        c = np.asarray(self.centre, float)
        if self.size is None:
            t = np.linspace(0, 2 * np.pi, n, endpoint=False)
            return c + self.radius * np.column_stack([np.cos(t), np.sin(t)])
        return c + _rounded_rectangle(*self.size, self.corner_radius, n)

    def contains(self, points: np.ndarray, grow: float = 0.0) -> np.ndarray:
        """Whether each point (n, 2) lies inside the hole (grown by ``grow`` metres)."""
        d = np.asarray(points, float) - np.asarray(self.centre, float)
        if self.size is None:
            return np.hypot(d[:, 0], d[:, 1]) < self.radius + grow
        return _in_rounded_rectangle(d, self.size[0] + 2 * grow, self.size[1] + 2 * grow, self.corner_radius + grow)


@dataclass(frozen=True)
class Outline:
    """A plate's outline: a polygon (``vertices`` (n, 2), m, in order; edges ``edge1`` from
    vertex 1 to 2 and so on) or a rectangle with ``corner_radius``, and holes.

    Use :meth:`rectangle` for a (rounded) rectangle centred on the origin: its edges are named
    ``bottom``, ``right``, ``top``, ``left`` too.
    """

    vertices: np.ndarray
    corner_radius: float = 0.0
    holes: tuple[Hole, ...] = ()

    def __post_init__(self):
        v = np.asarray(self.vertices, float)
        if v.ndim != 2 or v.shape[1] != 2 or not 3 <= len(v) <= 1000:
            raise ModelError(f"outline: expected 3 to 1000 vertices (x, y), got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise ModelError("outline: every vertex must be finite")
        crossing = _self_intersection(v)
        if crossing is not None:
            raise ModelError(f"outline: edges {crossing[0] + 1} and {crossing[1] + 1} cross (a self-intersecting "
                             f"outline)")
        if abs(_signed_area(v)) <= 1e-12 * np.ptp(v, axis=0).prod():  # edges keep the user's numbering
            raise ModelError("outline: the polygon encloses no area")
        if self.corner_radius and not self.is_rectangle(v):
            raise ModelError("outline: rounded corners are for rectangles (Outline.rectangle)")
        object.__setattr__(self, "vertices", v)
        for i, hole in enumerate(self.holes):
            ring = hole.boundary()
            if not np.all(self.contains_outer(ring)) or distance_to_edges(ring, v).min() <= 0:
                raise ModelError(f"outline: hole {i + 1} at {tuple(hole.centre)} cuts the rim or lies outside "
                                 f"the plate")
            for j, other in enumerate(self.holes[:i]):
                if np.any(other.contains(ring)) or np.any(hole.contains(other.boundary())):
                    raise ModelError(f"outline: holes {j + 1} and {i + 1} overlap")

    @classmethod
    def rectangle(cls, a: float, b: float, corner_radius: float = 0.0, holes=()) -> "Outline":
        """A rectangle ``a`` x ``b`` (m) centred on the origin, corners rounded to ``corner_radius``."""
        if not (np.isfinite(a) and np.isfinite(b) and a > 0 and b > 0):
            raise ModelError(f"outline: a rectangle needs positive finite sides, got {a!r} x {b!r}")
        if not (np.isfinite(corner_radius) and 0 <= corner_radius < min(a, b) / 2):
            raise ModelError(f"outline: the corner radius must lie in [0, {min(a, b) / 2:g}) m, got {corner_radius!r}")
        v = np.array([[-a / 2, -b / 2], [a / 2, -b / 2], [a / 2, b / 2], [-a / 2, b / 2]])
        return cls(v, corner_radius, tuple(holes))

    @staticmethod
    def is_rectangle(v: np.ndarray) -> bool:
        """Whether vertices ``v`` are an axis-aligned rectangle's, counter-clockwise from the lower left."""
        lo, hi = v.min(axis=0), v.max(axis=0)
        return len(v) == 4 and np.allclose(v, [[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])

    @property
    def edge_names(self) -> list[list[str]]:
        """Names of each edge of the outer outline (``edgeN``; and the sides of a rectangle)."""
        names = [[f"edge{i + 1}"] for i in range(len(self.vertices))]
        if self.is_rectangle(self.vertices):
            for n, side in zip(names, ("bottom", "right", "top", "left")):
                n.append(side)
        return names

    @property
    def diameter(self) -> float:
        return float(np.hypot(*np.ptp(self.vertices, axis=0)))

    def contains_outer(self, points: np.ndarray) -> np.ndarray:
        """Whether each point (n, 2) lies inside the outer outline (rounded corners included)."""
        p = np.asarray(points, float)
        if self.corner_radius:
            lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
            return _in_rounded_rectangle(p - (lo + hi) / 2, *(hi - lo), self.corner_radius)
        return _in_polygon(p, self.vertices)

    def contains(self, points: np.ndarray) -> np.ndarray:
        """Whether each point (n, 2) lies on the plate (inside the outline, outside every hole)."""
        inside = self.contains_outer(points)
        for hole in self.holes:
            inside &= ~hole.contains(points)
        return inside

    def covers(self, points: np.ndarray, tolerance: float) -> np.ndarray:
        """Whether each point (n, 2) (m) lies on the plate or on its rim: within ``tolerance`` (m)
        of the outer outline's inside (rounded corners included) and not deeper than ``tolerance``
        inside a hole. Inclusive on every edge alike, where :meth:`contains` (the even-odd rule)
        counts a point on the left or bottom edge of a rectangle in and one on the right or top
        edge out; the grid's lattice relies on that, so it stays."""
        p = np.asarray(points, float).reshape(-1, 2)
        if self.corner_radius:
            lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
            grown = hi - lo + 2 * tolerance
            inside = _in_rounded_rectangle(p - (lo + hi) / 2, *grown, self.corner_radius + tolerance)
        else:
            inside = _in_polygon(p, self.vertices) | (distance_to_edges(p, self.vertices) <= tolerance)
        for hole in self.holes:
            d = p - np.asarray(hole.centre, float)
            if hole.size is None:
                inside &= np.hypot(d[:, 0], d[:, 1]) >= hole.radius - tolerance
            else:
                width, height = hole.size[0] - 2 * tolerance, hole.size[1] - 2 * tolerance
                inside &= ~_in_rounded_rectangle(d, width, height, max(hole.corner_radius - tolerance, 0.0))
        return inside

    def holds_rectangle(self, xlim, ylim, tolerance: float) -> bool:
        """Whether the rectangle ``xlim`` x ``ylim`` (m, (low, high) each) lies wholly on the plate:
        not empty, its edges on the plate or its rim (:meth:`covers`, within ``tolerance``, m), and
        no hole's edge inside it."""
        (x0, x1), (y0, y1) = xlim, ylim
        if not (x0 < x1 and y0 < y1) or not np.all(self.covers(rectangle_ring(xlim, ylim), tolerance)):
            return False
        for hole in self.holes:
            ring = hole.boundary()
            if np.any((ring[:, 0] > x0) & (ring[:, 0] < x1) & (ring[:, 1] > y0) & (ring[:, 1] < y1)):
                return False
        return True

    @property
    def shortest_edge(self) -> float:
        """The outer outline's shortest edge (m); a rectangle's shorter side."""
        return float(np.min(np.linalg.norm(np.roll(self.vertices, -1, axis=0) - self.vertices, axis=1)))

    @property
    def area(self) -> float:
        """Area of the plate (m^2), holes cut out."""
        outer = abs(_signed_area(self.vertices)) - (4 - np.pi) * self.corner_radius**2
        holes = sum(np.pi * h.radius**2 if h.size is None else h.size[0] * h.size[1] - (4 - np.pi) * h.corner_radius**2
                    for h in self.holes)
        return float(outer - holes)


def rectangle_ring(xlim, ylim, n: int = 8) -> np.ndarray:
    """Points along a rectangle's edges, shape (4 n, 2)."""
    t = np.linspace(0, 1, n, endpoint=False)
    (x0, x1), (y0, y1) = xlim, ylim
    return np.vstack([np.column_stack([x0 + (x1 - x0) * t, np.full(n, y0)]),
                      np.column_stack([np.full(n, x1), y0 + (y1 - y0) * t]),
                      np.column_stack([x1 - (x1 - x0) * t, np.full(n, y1)]),
                      np.column_stack([np.full(n, x0), y1 - (y1 - y0) * t])])


def _rounded_rectangle(width: float, height: float, radius: float, n: int) -> np.ndarray:
    """Points along a rounded rectangle centred on the origin, shape (about n, 2)."""
    if radius == 0:
        return rectangle_ring((-width / 2, width / 2), (-height / 2, height / 2), max(2, n // 4))
    t = np.linspace(0, np.pi / 2, max(2, n // 4))
    cx, cy = width / 2 - radius, height / 2 - radius
    quarter = [(cx, cy, 0), (-cx, cy, np.pi / 2), (-cx, -cy, np.pi), (cx, -cy, 1.5 * np.pi)]
    return np.vstack([np.column_stack([x + radius * np.cos(t + a), y + radius * np.sin(t + a)]) for x, y, a in quarter])


def _in_rounded_rectangle(d: np.ndarray, width: float, height: float, radius: float) -> np.ndarray:
    """Whether points ``d`` (n, 2), relative to the centre, lie inside the rounded rectangle."""
    ax, ay = np.abs(d[:, 0]), np.abs(d[:, 1])
    inside = (ax < width / 2) & (ay < height / 2)
    corner = (ax > width / 2 - radius) & (ay > height / 2 - radius)
    far = np.hypot(ax - (width / 2 - radius), ay - (height / 2 - radius)) >= radius
    return inside & ~(corner & far)


def _signed_area(v: np.ndarray) -> float:
    x, y = v[:, 0], v[:, 1]
    return 0.5 * float(np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y))


def _in_polygon(p: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Whether points ``p`` (n, 2) lie inside polygon ``v`` (m, 2)."""
    return in_segments(p, np.stack([v, np.roll(v, -1, axis=0)], axis=1))


def in_segments(p: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Even-odd rule: whether points ``p`` (n, 2) lie inside the closed loops that
    ``segments`` (m, 2 ends, 2) draw (an outline and its holes at once). Each block of points is
    tested against the segments whose height range meets the block's only (the others cannot
    straddle its points): a lattice's block spans a row or two, and meets a few segments of the rim."""
    x, y = p[:, :1], p[:, 1:]
    low, high = segments[:, :, 1].min(axis=1), segments[:, :, 1].max(axis=1)
    inside = np.zeros(len(p), bool)
    for chunk in range(0, len(p), 2048):  # (chunk, m) at a time: bounded memory
        cy, cx = y[chunk:chunk + 2048], x[chunk:chunk + 2048]
        near = segments[(high >= cy.min()) & (low <= cy.max())]
        x1, y1, x2, y2 = (near[None, :, end, axis] for end in (0, 1) for axis in (0, 1))
        straddle = (y1 > cy) != (y2 > cy)
        with np.errstate(divide="ignore", invalid="ignore"):
            cross = cx < x1 + (cy - y1) * (x2 - x1) / (y2 - y1)
        inside[chunk:chunk + 2048] = np.count_nonzero(straddle & cross, axis=1) % 2 == 1
    return inside


def distance_to_edges(p: np.ndarray, v: np.ndarray, each: bool = False) -> np.ndarray:
    """Distance of points ``p`` (n, 2) to the polygon's edges: the nearest (n,), or to each (n, m)."""
    d = distance_to_segments(p, np.stack([v, np.roll(v, -1, axis=0)], axis=1))
    return d if each else d.min(axis=1)


def distance_to_segments(p: np.ndarray, segments: np.ndarray) -> np.ndarray:
    """Distance of points ``p`` (n, 2) to each segment (m, 2 ends, 2), shape (n, m)."""
    a, ab = segments[:, 0], segments[:, 1] - segments[:, 0]
    length2 = np.maximum(np.einsum("mk,mk->m", ab, ab), np.finfo(float).tiny)
    out = np.empty((len(p), len(segments)))
    for i in range(0, len(p), 1024):  # (chunk, m, 2) at a time: bounded memory
        rel = p[i:i + 1024, None, :] - a[None]
        t = np.clip(np.einsum("nmk,mk->nm", rel, ab) / length2, 0, 1)
        out[i:i + 1024] = np.linalg.norm(rel - t[..., None] * ab[None], axis=2)
    return out


def near_segments(p: np.ndarray, segments: np.ndarray, distance: float) -> np.ndarray:
    """Whether each point ``p`` (n, 2) lies within ``distance`` of a segment (m, 2 ends, 2).

    Only the points near some segment's midpoint (half the longest segment and ``distance``
    away, a k-d tree's query) are measured against every segment, a block at a time: a lattice
    of a million points near a rim of a few hundred facets costs a fraction of a second and a
    few megabytes, where :func:`distance_to_segments` on every point holds (n, m) distances."""
    from scipy.spatial import cKDTree

    p = np.asarray(p, float)
    near = np.zeros(len(p), bool)
    if not len(p) or not len(segments):
        return near
    reach = 0.5 * np.linalg.norm(segments[:, 1] - segments[:, 0], axis=1).max() + distance
    gap, _ = cKDTree(segments.mean(axis=1)).query(p, distance_upper_bound=reach * (1 + 1e-9))
    candidates = np.flatnonzero(np.isfinite(gap))
    block = max(1, 2**22 // len(segments))  # (block, m) distances at a time: 32 MB
    for i in range(0, len(candidates), block):
        chunk = candidates[i:i + block]
        near[chunk] = distance_to_segments(p[chunk], segments).min(axis=1) <= distance
    return near


def _self_intersection(v: np.ndarray) -> tuple[int, int] | None:
    """The first pair of non-adjacent edges of polygon ``v`` that cross, or None."""
    n = len(v)

    def orient(a, b, c):
        return np.sign((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))

    for i in range(n):
        a, b = v[i], v[(i + 1) % n]
        for j in range(i + 1, n):
            if j == i or (j + 1) % n == i or j == (i + 1) % n:
                continue
            c, d = v[j], v[(j + 1) % n]
            if orient(a, b, c) * orient(a, b, d) <= 0 and orient(c, d, a) * orient(c, d, b) <= 0:
                if orient(a, b, c) == orient(a, b, d) == 0 and (max(a[0], b[0]) < min(c[0], d[0]) or
                                                                max(c[0], d[0]) < min(a[0], b[0])):
                    continue  # collinear, apart
                return i, j
    return None
