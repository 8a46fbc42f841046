"""Finite-element Kirchhoff plates of any outline, from geometry to mass-normalized modes.

A plate's outline (a polygon, or a rectangle with rounded corners; holes cut out of it), which
:mod:`modalctl.model.plate_geometry` describes with the material and the edges' supports, is
meshed by gmsh with the piezo patches' outlines embedded, so that element edges follow them.
scikit-fem assembles the Kirchhoff bending stiffness ``D [(1 - nu) w,ab v,ab + nu lap(w) lap(v)]``
and the mass ``rho h w v`` on the 15-parameter nonconforming plate triangle (deflection and
its gradient at the vertices, deflection and normal slope at mid-edges: any outline, no
rotated degrees of freedom), and scipy's shift-invert Lanczos gives the lowest modes,
mass-normalized on the FE mass matrix. Supports per edge: clamped (every degree of freedom
on the edge held), simply supported (the deflection held), free, or an elastic rim
(translational and rotational springs per unit length, on the edge's facets).

"No more than a scene needs": the mesh is split (every triangle in four, halving h) until the
kept modes have converged. The element's eigenvalues converge as h^2 (from below), so the
finer mesh's frequency error is Richardson's ``(f_h - f_2h) / 3``; shapes converge when each
of the finer mesh's modes lies in the span of the coarser mesh's modes of its frequency
(a subspace MAC: degenerate pairs, as on a square, turn freely within their span).

Piezo patches act by the pin-force model the analytic structures use: a uniform moment line
density ``m`` (per volt) along the patch's rim, whose generalized force on a mode is
``m * integral over the patch of lap(phi)``. Sensors read the velocity at a point.
"""

from __future__ import annotations

import functools
import time
import warnings
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse
import scipy.spatial

from modalctl.forked import beside

from . import fe_eigen
from .fe_convergence import Convergence, Level, compare_levels
from .modes import Grid, ModalModel, ModelError
from .plate_geometry import (MATERIALS, SUPPORTS, Hole, Material, Outline, Support, distance_to_edges, in_segments,
                             near_segments)
from .structures import Piezo

__all__ = ["ELEMENTS", "Material", "MATERIALS", "Support", "SUPPORTS", "Hole", "Outline", "FEPlate", "Level", "Convergence",
           "FREQUENCY_TOLERANCE", "SHAPE_TOLERANCE", "DOFS_MAX", "MODES_MAX", "GRID_POINTS_MAX"]

SOLVER_VERSION = 1  # bump when a change alters solved models: cached scenes are solved again
FREQUENCY_TOLERANCE = 0.005  # kept modes' frequencies converged to this (relative, Richardson's estimate)...
SHAPE_TOLERANCE = 0.99  # ...and their shapes to this subspace MAC between the last two meshes
MODES_MAX = 500  # at most this many modes in a model
GRID_POINTS_MAX = 1_000_000  # a focus grid of at most this many points (a 1000 x 1000 lattice)
DOFS_MAX = 400_000  # a mesh finer than this is refused: the band needs more than a plate model should cost
ELEMENTS_PER_WAVELENGTH = 2.5  # the first mesh: this many elements per bending wavelength of the highest mode
CURVATURE_ELEMENTS = 48  # an arc gets at least this many elements per turn (a 1 mm radius: 0.2% sagitta)
SAMPLES_PER_CELL = 6  # grid weights: each lattice cell sampled this many times per direction
KIRCHHOFF_WAVELENGTHS = 10  # a bending wavelength shorter than this many thicknesses: shear matters (a few %)
RIGID_FRACTION = 1e-3  # a mode below this fraction of the first elastic estimate is a rigid-body mode
BAND_MARGIN = 1.03  # a band's meshes solve every mode below this much above it: the shape test's 2% window
BAND_SHIFT = 0.45  # a band's Lanczos shift, times its top eigenvalue: the band [0, top] lies within 0.55 top of it
PARTNERS = 4  # modes solved past the N lowest asked: a (near-)degenerate partner of the Nth in each shape test's span
RIM_TOLERANCE = 1e-9  # m: a patch or sensor this near the rim is on it (flush, as lengths in mm round)
PROBE_BLOCK = 16384  # sampling: this many points at a time (the 15-parameter basis: 40 MB per array)
PROBE_NEIGHBOURS = 8  # a point's element sought among this many nearest element centroids

#: Plate triangles of scikit-fem: class name, degrees of freedom per vertex and per edge. The
#: 15-parameter triangle is the default; Morley's (the classic nonconforming one, 6 dofs) is the
#: peer it is measured against (benchmarks/fe_plate.py).
ELEMENTS = {"15-parameter": ("ElementTri15ParamPlate", 3, 2), "morley": ("ElementTriMorley", 1, 1)}


@dataclass(frozen=True)
class FEPlate:
    """A Kirchhoff plate of any outline, thickness (m) and material, held per edge.

    Attributes
    ----------
    outline : Outline
    thickness : float
        m.
    material : Material
    supports : dict
        Edge name (``rim`` for every outer edge not named, ``holes`` for the holes' edges,
        ``edgeN``; ``bottom``, ``right``, ``top``, ``left`` for a rectangle) to :class:`Support`.
        Unnamed: a clamped rim, free holes.
    patches : tuple of PlatePatch
        Rectangular piezo patches on the back (m), wholly on the plate (flush with the rim
        allowed, on any side: :meth:`Outline.covers`).
    sensors : tuple of (x, y)
        Velocity sensors (m), on the plate or its rim.
    piezo : Piezo
    """

    outline: Outline
    thickness: float
    material: Material
    supports: dict = field(default_factory=dict)
    patches: tuple = ()
    sensors: tuple = ()
    piezo: Piezo = Piezo()
    element: str = "15-parameter"

    def __post_init__(self):
        if not (np.isfinite(self.thickness) and self.thickness > 0):
            raise ModelError(f"plate.thickness: must be positive and finite, got {self.thickness!r}")
        if self.element not in ELEMENTS:
            raise ModelError(f"plate.element: {self.element!r} is not one of {', '.join(ELEMENTS)}")
        if self.thickness > 0.2 * np.ptp(self.outline.vertices, axis=0).min():
            raise ModelError("plate.thickness: above a fifth of the plate's width; a Kirchhoff plate is thin")
        names = {n for names in self.outline.edge_names for n in names} | {"rim", "holes"}
        for name, support in self.supports.items():
            if name not in names:
                raise ModelError(f"plate: no edge named {name!r}; edges are {', '.join(sorted(names))}")
            if not isinstance(support, Support):
                raise ModelError(f"plate: the support of {name!r} must be a Support, got {support!r}")
        for i, p in enumerate(self.patches):
            if not self.outline.holds_rectangle(p.xlim, p.ylim, RIM_TOLERANCE):
                raise ModelError(f"plate: patch {p.name or i + 1} {p.xlim} x {p.ylim} m is not wholly on the plate")
        for i, s in enumerate(self.sensors):
            if not self.outline.covers(np.atleast_2d(np.asarray(s, float)), RIM_TOLERANCE)[0]:
                raise ModelError(f"plate: sensor {i + 1} at {tuple(s)} m is not on the plate")

    @property
    def rigidity(self) -> float:
        """Bending rigidity D = E h^3 / 12 (1 - nu^2) (N m)."""
        m = self.material
        return m.modulus * self.thickness**3 / (12 * (1 - m.poisson**2))

    @property
    def mass_per_area(self) -> float:
        return self.material.density * self.thickness

    def wavelength(self, frequency: float) -> float:
        """Bending wavelength (m) at ``frequency`` (Hz): 2 pi (D / rho h)^(1/4) / sqrt(w)."""
        return 2 * np.pi * (self.rigidity / self.mass_per_area) ** 0.25 / np.sqrt(2 * np.pi * frequency)

    def modes_below(self, frequency: float) -> float:
        """Weyl's estimate of the number of modes below ``frequency`` (Hz): A w sqrt(rho h / D) / 4 pi."""
        return self.outline.area * 2 * np.pi * frequency * np.sqrt(self.mass_per_area / self.rigidity) / (4 * np.pi)

    def frequency_of_mode(self, n: int) -> float:
        """Weyl's estimate of the ``n``-th mode's frequency (Hz)."""
        return n / self.modes_below(1.0)

    def dofs_estimate(self, size: float) -> float:
        """Degrees of freedom of a mesh of ``size`` (m) elements: about 2.3 area / size^2 triangles,
        half as many vertices and 1.5 times as many edges."""
        triangles = 2.3 * self.outline.area / size**2
        per_vertex, per_edge = ELEMENTS[self.element][1:]
        return triangles * (per_vertex / 2 + 1.5 * per_edge)

    def support_of(self, name: str) -> Support:
        default = Support("free") if name == "holes" else self.supports.get("rim", Support("clamped"))
        return self.supports.get(name, default)

    # -- meshing and assembly -------------------------------------------------------------------

    def mesh(self, size: float):
        """A gmsh triangulation (skfem ``MeshTri``) with elements no larger than ``size`` (m),
        patch outlines embedded."""
        import gmsh
        from skfem import MeshTri

        gmsh.initialize(readConfigFiles=False, interruptible=False)
        try:
            gmsh.option.setNumber("General.Verbosity", 0)
            gmsh.model.add("plate")
            occ = gmsh.model.occ
            v, r = self.outline.vertices, self.outline.corner_radius
            if self.outline.is_rectangle(v):
                lo, span = v.min(axis=0), np.ptp(v, axis=0)
                surface = occ.addRectangle(lo[0], lo[1], 0, span[0], span[1], roundedRadius=r)
            else:
                points = [occ.addPoint(x, y, 0) for x, y in v]
                lines = [occ.addLine(points[i], points[(i + 1) % len(points)]) for i in range(len(points))]
                surface = occ.addPlaneSurface([occ.addCurveLoop(lines)])
            cuts = []
            for hole in self.outline.holes:
                if hole.size is None:
                    cuts.append((2, occ.addDisk(hole.centre[0], hole.centre[1], 0, hole.radius, hole.radius)))
                else:
                    w, h = hole.size
                    cuts.append((2, occ.addRectangle(hole.centre[0] - w / 2, hole.centre[1] - h / 2, 0, w, h,
                                                     roundedRadius=hole.corner_radius)))
            shape = [(2, surface)]
            if cuts:
                shape, _ = occ.cut(shape, cuts)
            patches = [(2, occ.addRectangle(p.xlim[0], p.ylim[0], 0, p.xlim[1] - p.xlim[0], p.ylim[1] - p.ylim[0]))
                       for p in self.patches]
            if patches:
                occ.fragment(shape, patches)
            occ.synchronize()
            gmsh.option.setNumber("Mesh.MeshSizeMax", size)
            gmsh.option.setNumber("Mesh.MeshSizeFromCurvature", CURVATURE_ELEMENTS)
            gmsh.model.mesh.generate(2)
            tags, coords, _ = gmsh.model.mesh.getNodes()
            _, _, nodes = gmsh.model.mesh.getElements(2)
        finally:
            gmsh.finalize()
        index = np.zeros(int(tags.max()) + 1, int)
        index[tags.astype(int)] = np.arange(tags.size)
        triangles = index[np.concatenate(nodes).astype(int)].reshape(-1, 3)
        points = coords.reshape(-1, 3)[:, :2]
        used = np.unique(triangles)  # gmsh may keep construction points no triangle uses
        renumber = np.full(points.shape[0], -1)
        renumber[used] = np.arange(used.size)
        return MeshTri(np.ascontiguousarray(points[used].T), np.ascontiguousarray(renumber[triangles].T))

    def _edges_of_facets(self, mesh) -> dict[str, np.ndarray]:
        """Boundary facets by the edge they lie on: ``edgeN`` of the outer outline, ``holes``,
        or ``rim`` (a rounded corner)."""
        facets = mesh.boundary_facets()
        mid = mesh.p[:, mesh.facets[:, facets]].mean(axis=1).T
        tol = 1e-6 * self.outline.diameter
        distance = distance_to_edges(mid, self.outline.vertices, each=True)
        on_hole = np.zeros(len(mid), bool)
        for hole in self.outline.holes:
            on_hole |= hole.contains(mid, grow=tol)
        keys = np.where(distance.min(axis=1) <= tol, np.char.add("edge", (np.argmin(distance, axis=1) + 1).astype(str)),
                        np.where(on_hole, "holes", "rim"))
        return {str(k): facets[keys == k] for k in np.unique(keys)}

    def _support_for_group(self, group: str) -> Support:
        if group.startswith("edge"):
            i = int(group[4:]) - 1
            for name in self.outline.edge_names[i]:
                if name in self.supports:
                    return self.supports[name]
            return self.support_of("rim")
        return self.support_of(group)

    def assemble(self, mesh):
        """Stiffness and mass matrices (scipy sparse), the held degrees of freedom and the basis."""
        from skfem import Basis, BilinearForm, FacetBasis
        from skfem.helpers import dd, ddot, dot, eye, grad, trace

        from .fe_element import element  # (scikit-fem: imported when a plate is solved, not at start-up)

        m, h = self.material, self.thickness
        basis = Basis(mesh, element(ELEMENTS[self.element][0]))

        @BilinearForm
        def bending(u, v, _):
            def moment(t):
                return m.modulus / (1 + m.poisson) * (t + m.poisson / (1 - m.poisson) * eye(trace(t), 2))
            return h**3 / 12 * ddot(moment(dd(u)), dd(v))

        @BilinearForm
        def inertia(u, v, _):
            return m.density * h * u * v

        stiffness, mass = bending.assemble(basis), inertia.assemble(basis)
        held = []
        for group, facets in self._edges_of_facets(mesh).items():
            support = self._support_for_group(group)
            dofs = basis.get_dofs(facets=facets)
            if support.kind == "clamped":
                held.append(dofs.all())
            elif support.kind == "simply-supported":
                held += [dofs.nodal["u"], *([dofs.facet["u"]] if "u" in dofs.facet else [])]
            elif support.kind == "elastic":
                rim = FacetBasis(mesh, basis.elem, facets=facets)

                @BilinearForm
                def springs(u, v, w, k=support.stiffness, kr=support.rotational):
                    return k * u * v + kr * dot(grad(u), w.n) * dot(grad(v), w.n)

                stiffness = stiffness + springs.assemble(rim)
        held = np.unique(np.concatenate(held)) if held else np.zeros(0, int)
        return stiffness, mass, held, basis

    def solve(self, mesh, n_modes: int | None = None, *, below: float | None = None
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, object]:
        """The ``n_modes`` lowest elastic modes on ``mesh``, or every one below ``below`` (Hz):
        frequencies (Hz), mass-normalized FE vectors (N, k), rigid-body vectors (N, r) and the
        basis.

        Shift-invert Lanczos (ARPACK, :mod:`~.fe_eigen`) on superLU's factors of ``K - shift M`` in a
        symmetric minimum-degree ordering without pivoting: a third of the fill and half the solve time
        of the default column ordering. Every mode below ``below`` is counted first by Sylvester's law
        of inertia (the negative pivots of ``K - w^2 M`` factored the same way), so Lanczos asks for as
        many as there are, about the middle of the band (``BAND_SHIFT``; a wide band on a large mesh in
        two slices on two cores, :func:`~.fe_eigen.band`): the band is then the modes nearest the shift,
        and its edge modes lie far apart once inverted, so a Krylov space of 1.5 times the count holds
        them (``fe_eigen.NCV_FACTOR``; 2 is scipy's default), 20% less work than below the lowest mode.
        ARPACK's products are many matrix-vector ones, which BLAS threads only slow down
        (:mod:`modalctl.threads`: 2.7 times as long on 2 loaded cores). When the count is unknown
        (superLU pivoted) it solves from below the lowest mode, asking again for more while the highest
        it found lies below ``below``. The mid-band factors are of an indefinite matrix, unpivoted: a
        tiny pivot would make them unsound, so the band's modes are checked
        (:func:`~.fe_eigen.residual`) and solved again from below the lowest if they fail."""
        if (n_modes is None) == (below is None):
            raise ModelError("fe plate: solve either n_modes or every mode below a frequency")
        stiffness, mass, held, basis = self.assemble(mesh)
        free = basis.complement_dofs(held)
        k, m = stiffness[free][:, free].tocsc(), mass[free][:, free].tocsc()
        rigid = 0 if len(held) else 3  # a plate held nowhere moves as a rigid body: 3 ways
        safe = -(2 * np.pi * self.frequency_of_mode(1)) ** 2 * 0.1  # below zero: K may be singular
        shift, under, top = safe, None, np.inf
        if below is None:
            count = n_modes + rigid + 4
        else:
            top = (2 * np.pi * below) ** 2
            _, under = fe_eigen.factor(k - top * m)  # the modes below `below`, rigid ones included
            count = (under if under is not None else int(np.ceil(1.3 * self.modes_below(below))) + rigid) + 4
            if under is not None and fe_eigen.NCV_FACTOR * count < free.size:  # (else nearly every mode: from below)
                shift = BAND_SHIFT * top
        cut = (2 * np.pi * RIGID_FRACTION * self.frequency_of_mode(1)) ** 2  # below it: a rigid-body mode
        mid_band = shift != safe
        if mid_band:  # the band about its middle (in two slices when wide: fe_eigen.band)
            w2, x = fe_eigen.band(k, m, top, under, shift)
        else:
            w2, x = fe_eigen.lanczos(k, m, shift, count, below, below is not None and under is None, 2 * MODES_MAX)
        kept = np.flatnonzero((w2 > cut) & (w2 < top))[:n_modes]
        if mid_band and not fe_eigen.residual(k, m, w2[kept], x[:, kept]) <= fe_eigen.RESIDUAL_TOLERANCE:
            w2, x = fe_eigen.lanczos(k, m, safe, count)  # (NaN fails too) the count is known: no more asked
            kept = np.flatnonzero((w2 > cut) & (w2 < top))[:n_modes]
        full = np.zeros((basis.N, x.shape[1]))
        full[free] = x
        return np.sqrt(w2[kept]) / (2 * np.pi), full[:, kept], full[:, w2 <= cut], basis

    # -- the model ---------------------------------------------------------------------------

    def grid(self, spacing: float, mesh=None) -> Grid:
        """Focus grid: a lattice of ``spacing`` (m) over the plate. A plain rectangle gets the
        tensor Simpson weights; any other outline the mass of each point's cell of the plate
        (the plate sampled ``SAMPLES_PER_CELL``^2 times per cell, each sample to its nearest
        point on the plate); points off the plate weigh nothing. With a ``mesh``, "on the
        plate" is inside its boundary (a rounded corner as the mesh draws it)."""
        lo, hi, nx, ny = self._lattice(spacing)
        if self.outline.is_rectangle(self.outline.vertices) and not self.outline.corner_radius and not self.outline.holes:
            return Grid.rectangle((lo[0], hi[0]), (lo[1], hi[1]), nx, ny, self.mass_per_area)
        if mesh is None:
            contains = self.outline.contains
        else:
            rim = mesh.p[:, mesh.facets[:, mesh.boundary_facets()]].transpose(2, 1, 0)  # (m, 2 ends, 2)
            clear = 1e-6 * self.outline.diameter  # a point on the rim is off: the mesh may not find it

            def contains(p):
                inside = in_segments(p, rim)
                inside[inside] = ~near_segments(p[inside], rim, clear)
                return inside
        x, y = np.linspace(lo[0], hi[0], nx), np.linspace(lo[1], hi[1], ny)
        xx, yy = np.meshgrid(x, y)
        points = np.column_stack([xx.ravel(), yy.ravel()])
        on = contains(points)
        s = SAMPLES_PER_CELL
        dx, dy = x[1] - x[0], y[1] - y[0]
        sx = np.linspace(lo[0], hi[0], (nx - 1) * s + 1)[:-1] + dx / (2 * s)
        sy = np.linspace(lo[1], hi[1], (ny - 1) * s + 1)[:-1] + dy / (2 * s)
        samples = np.column_stack([a.ravel() for a in np.meshgrid(sx, sy)])
        samples = samples[contains(samples)]
        _, nearest = scipy.spatial.cKDTree(points[on]).query(samples)
        mass = np.zeros(len(points))
        mass[np.flatnonzero(on)] = np.bincount(nearest, minlength=int(on.sum())) * dx * dy / s**2
        return Grid(points, self.mass_per_area * mass, (nx, ny))

    def _lattice(self, spacing: float) -> tuple[np.ndarray, np.ndarray, int, int]:
        """The focus grid's corners and points per side; ModelError above ``GRID_POINTS_MAX`` points."""
        lo, hi = self.outline.vertices.min(axis=0), self.outline.vertices.max(axis=0)
        nx, ny = (np.ceil((hi - lo) / spacing - 1e-9).astype(int) + 1).tolist()  # 70 mm / 1 mm: 71, not 72
        if nx * ny > GRID_POINTS_MAX:
            raise ModelError(f"fe plate: a {spacing * 1e3:g} mm grid over {(hi - lo)[0] * 1e3:g} x {(hi - lo)[1] * 1e3:g} "
                             f"mm has {nx * ny:,} points; at most {GRID_POINTS_MAX:,} (a coarser spacing)")
        return lo, hi, nx, ny

    def _sample(self, basis, vectors: np.ndarray, points: np.ndarray) -> np.ndarray:
        """FE fields (N, k) at points (n, 2) on the plate, shape (k, n), through a sparse matrix of
        a row per point, as scikit-fem's ``probes`` makes, found and evaluated ``PROBE_BLOCK``
        points at a time (:func:`_probes`)."""
        out = np.empty((vectors.shape[1], len(points)))
        for i in range(0, len(points), PROBE_BLOCK):
            out[:, i:i + PROBE_BLOCK] = (_probes(basis, points[i:i + PROBE_BLOCK]) @ vectors).T
        return out

    def patch_loads(self, basis) -> np.ndarray:
        """Per patch, the FE vector of ``m * integral over the patch of lap(v)`` (N, a), with m
        the pin-force moment per volt."""
        from skfem import Basis, LinearForm
        from skfem.helpers import dd, trace

        @LinearForm
        def laplacian(v, _):
            return trace(dd(v))

        mesh = basis.mesh
        centroids = mesh.p[:, mesh.t].mean(axis=1)
        moment = self.piezo.moment_per_volt(self.material.modulus, self.thickness)
        columns = []
        for p in self.patches:
            inside = np.flatnonzero((centroids[0] > p.xlim[0]) & (centroids[0] < p.xlim[1])
                                    & (centroids[1] > p.ylim[0]) & (centroids[1] < p.ylim[1]))
            part = Basis(mesh, basis.elem, elements=inside)
            columns.append(moment * laplacian.assemble(part))
        return np.column_stack(columns) if columns else np.zeros((basis.N, 0))

    def modal_model(self, n_modes: int | None = None, *, band: float | None = None, spacing: float = 1e-3,
                    damping: float = 0.01, tolerance: float = FREQUENCY_TOLERANCE, meta: dict | None = None,
                    progress=None) -> tuple[ModalModel, Convergence]:
        """The lowest ``n_modes`` modes, or every mode below ``band`` (Hz), converged to
        ``tolerance`` on a mesh refined as far as needed; sampled on a lattice of ``spacing``.

        Returns the model (mode shapes, actuator and sensor gains, modal ``damping``) and how
        the mesh converged. Raises :class:`ModelError` when the mesh would need more than
        ``DOFS_MAX`` degrees of freedom.
        """
        wanted = self._modes_to_solve(n_modes, band, tolerance)
        top = band if band is not None else self.frequency_of_mode(wanted) * 1.2
        size = min(self.wavelength(top) / ELEMENTS_PER_WAVELENGTH, self.outline.diameter / 8)
        nx, ny = self._lattice(spacing)[2:]  # the grid's size checked before any mesh is made; with fewer points
        if nx * ny < wanted:  # than modes none tells them apart (scipy's singular matrix, or a mesh past DOFS_MAX)
            raise ModelError(f"fe plate: a {spacing * 1e3:g} mm grid has {nx * ny} points, too coarse to tell "
                             f"{wanted} modes apart; a finer grid (more --points, or a smaller --spacing)")
        if self.dofs_estimate(size) > DOFS_MAX:
            raise ModelError(f"fe plate: {wanted} modes of this plate need elements of {size * 1e3:.2g} mm, about "
                             f"{self.dofs_estimate(size):,.0f} degrees of freedom on the first mesh; at most {DOFS_MAX}")
        mesh = self.mesh(size)  # refining splits triangles: the rim stays the first mesh's
        grid = self.grid(spacing, mesh)
        level = functools.partial(self._level, wanted=wanted, band=band, grid=grid, tolerance=tolerance)
        on = grid.mass > 0

        def coarse():  # what the comparison needs of it: its level, frequencies and shapes on the grid
            done, solved = level(mesh, size)
            return done, solved[:2] + (None, None, None)

        work = beside(coarse)  # the coarse mesh in a child while the fine one is solved here
        first, levels, history = work, [], []
        try:
            while True:
                mesh, size = mesh.refined(), size / 2
                done = level(mesh, size)
                for each, solved in ([] if first is None else [first.result()]) + [done]:
                    levels.append(each)
                    history.append(solved)
                    if progress is not None:
                        progress(each)
                first, freqs = None, history[-1][0]
                keep = min(wanted, len(freqs)) if band is None else max(1, int(np.count_nonzero(freqs <= band)))
                error, mac = compare_levels(history[-2], history[-1], keep, grid.mass)
                if error.max() <= tolerance and mac.min() >= SHAPE_TOLERANCE:
                    break
        except BaseException:  # the fine mesh refused, ARPACK, Ctrl-C: the child must not solve on unheard
            work.stop()
            raise
        freqs, shapes, vectors, rigid, basis = history[-1]
        keep = slice(0, keep)
        shortest = self.wavelength(freqs[keep][-1])
        if shortest < KIRCHHOFF_WAVELENGTHS * self.thickness:
            warnings.warn(f"fe plate: the highest mode kept ({freqs[keep][-1]:.0f} Hz) bends over "
                          f"{shortest * 1e3:.2g} mm, less than {KIRCHHOFF_WAVELENGTHS:g} thicknesses: Kirchhoff's "
                          f"theory (no shear, no rotary inertia) overestimates its frequency", UserWarning, stacklevel=2)
        convergence = Convergence(levels, error, mac, tolerance, True)
        loads = self.patch_loads(basis)
        sensors = np.asarray(self.sensors, float).reshape(-1, 2)
        rigid_shapes = np.zeros((rigid.shape[1], grid.n))
        if rigid.shape[1]:
            rigid_shapes[:, on] = self._sample(basis, rigid, grid.points[on])
        info = self._describe(sensors, convergence)
        info.update(meta or {})
        model = ModalModel(grid=grid, frequencies=freqs[keep], damping=np.full(len(freqs[keep]), damping),
                           shapes=shapes[keep], actuator_gains=(vectors.T @ loads)[keep],
                           sensor_gains=self._sample(basis, vectors, sensors)[keep] if len(sensors) else None,
                           rigid_shapes=rigid_shapes if rigid.shape[1] else None, meta=info)
        return model, convergence

    def _level(self, mesh, size: float, *, wanted: int, band: float | None, grid: Grid, tolerance: float):
        """One mesh's modes: its :class:`Level` and ``(freqs, shapes on the grid, FE vectors,
        rigid vectors, basis)``."""
        start = time.perf_counter()
        dofs = mesh.nvertices * ELEMENTS[self.element][1] + mesh.nfacets * ELEMENTS[self.element][2]
        if dofs > DOFS_MAX:
            edge = self.outline.shortest_edge  # every vertex a node: the rim's elements no longer than its edges
            raise ModelError(f"fe plate: converging {wanted} modes to {tolerance:.2%} needs a mesh above "
                             f"{DOFS_MAX} degrees of freedom (elements of {size * 1e3:.2g} mm): " + (
                                 f"the outline's edges as short as {edge * 1e3:.2g} mm make the mesh that fine along "
                                 f"the rim (each vertex is a node); give fewer vertices" if edge < size / 4 else
                                 "the band is too high for this plate, or the tolerance too tight"))
        if band is None:
            freqs, vectors, rigid, basis = self.solve(mesh, wanted + PARTNERS)  # a pair the cut splits: both
        else:
            freqs, vectors, rigid, basis = self.solve(mesh, below=band * BAND_MARGIN)
            if not len(freqs):  # nothing to converge: the plate's lowest mode named (as this mesh solves it)
                lowest = self.solve(mesh, 1)[0][0]
                raise ModelError(f"fe plate: no mode below the band {band:g} Hz: this plate's lowest is at "
                                 f"{lowest:.0f} Hz; give a higher band or a number of modes")
            if np.count_nonzero(freqs <= band) > MODES_MAX:
                raise ModelError(f"fe plate: the band {band:g} Hz holds more than {MODES_MAX} modes")
        on = grid.mass > 0
        shapes = np.zeros((len(freqs), grid.n))
        shapes[:, on] = self._sample(basis, vectors, grid.points[on])
        return Level(size, dofs, freqs, time.perf_counter() - start), (freqs, shapes, vectors, rigid, basis)

    def _modes_to_solve(self, n_modes: int | None, band: float | None, tolerance: float) -> int:
        """How many modes the first mesh solves for: ``n_modes``, or Weyl's count below ``band``
        with a margin; checks :meth:`modal_model`'s arguments."""
        if (n_modes is None) == (band is None):
            raise ModelError("fe plate: give either a number of modes or a band")
        if n_modes is not None and not 1 <= n_modes <= MODES_MAX:
            raise ModelError(f"fe plate: between 1 and {MODES_MAX} modes, got {n_modes}")
        if band is not None and not (np.isfinite(band) and band > 0):
            raise ModelError(f"fe plate: the band must be a positive frequency, got {band!r}")
        if not (np.isfinite(tolerance) and 1e-5 <= tolerance <= 0.2):
            raise ModelError(f"fe plate: the tolerance must lie in [1e-5, 0.2], got {tolerance!r}")
        wanted = n_modes if n_modes is not None else max(1, int(np.ceil(1.3 * self.modes_below(band))) + 4)
        if wanted > MODES_MAX:
            raise ModelError(f"fe plate: the band {band:g} Hz holds about {int(self.modes_below(band))} modes, "
                             f"{wanted} to solve with a margin to find them all; at most {MODES_MAX}")
        return wanted

    def _describe(self, sensors: np.ndarray, convergence: Convergence) -> dict:
        """The model's ``meta``: the plate (outline, holes, supports, thickness, material), its
        actuators and sensors, and how the mesh converged."""
        return {"structure": "plate", "model": f"finite-element Kirchhoff (scikit-fem, {self.element} triangle)",
                "outline_m": self.outline.vertices.tolist(), "corner_radius_m": self.outline.corner_radius,
                "holes": [{"centre_m": list(h.centre), "radius_m": h.radius,
                           "size_m": list(h.size) if h.size else None, "corner_radius_m": h.corner_radius}
                          for h in self.outline.holes],
                "supports": {name: vars(s) for name, s in self.supports.items()},
                "thickness_m": self.thickness, "modulus_Pa": self.material.modulus,
                "density_kg_m3": self.material.density, "poisson": self.material.poisson,
                "actuators": [{"name": p.name or f"patch{i + 1}", "xlim_m": list(p.xlim), "ylim_m": list(p.ylim)}
                              for i, p in enumerate(self.patches)],
                "sensors": [{"name": f"sensor{i + 1}", "position_m": list(map(float, s))}
                            for i, s in enumerate(sensors)], **self.piezo.voltage_meta(),
                "convergence": convergence.to_dict()}


def _probes(basis, points: np.ndarray):
    """scikit-fem's ``basis.probes(points.T)`` (CSR, a row per point): the element under each point
    is the first of its ``PROBE_NEIGHBOURS`` nearest centroids (a k-d tree) to hold it, tested on
    those alone (skfem's finder tests every point of a call against every candidate of the call,
    a (points x candidates) array), any point none holds found by skfem's finder; the element's
    basis evaluated there."""
    mesh, mapping, n = basis.mesh, basis.mapping, len(points)
    near = min(PROBE_NEIGHBOURS, mesh.nelements)
    _, candidates = scipy.spatial.cKDTree(mesh.p[:, mesh.t].mean(axis=1).T).query(points, near)
    candidates = candidates.reshape(n, near)
    local = mapping.invF(np.repeat(points.T, near, axis=1)[:, :, None], tind=candidates.ravel())
    x, y = local[0, :, 0].reshape(n, near), local[1, :, 0].reshape(n, near)
    eps = np.finfo(float).eps
    inside = (x >= -eps) & (y >= -eps) & (1 - x - y >= -2 * eps)  # skfem's test
    cells = candidates[np.arange(n), inside.argmax(axis=1)]
    missed = ~inside.any(axis=1)
    if missed.any():
        cells[missed] = mesh.element_finder(mapping=mapping)(*points[missed].T)
    local = mapping.invF(points.T[:, :, None], tind=cells)
    values = np.array([np.asarray(basis.elem.gbasis(mapping, local, i, tind=cells)[0]).ravel()
                       for i in range(basis.Nbfun)])
    rows = np.tile(np.arange(n), basis.Nbfun)
    return scipy.sparse.coo_matrix((values.ravel(), (rows, basis.element_dofs[:, cells].ravel())),
                                   shape=(n, basis.N)).tocsr()
