"""Finite-element plates at scale: the shortcuts that make a tablet panel cheap give what the
plain computations give (issue 36: ``model fe --band 20kHz`` on 49k dofs took 4 min and 16 GB).

- the grid's rim test measures only the points near the rim, and finds the same points;
- the fields are sampled a block of points at a time, each point's element found among its
  nearest ones, and equal one call of scikit-fem's probes;
- the band's modes are counted by Sylvester's law of inertia before the Lanczos run: the count
  equals a dense eigensolution's, and the modes found equal the lowest ones found without it.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse

from modalctl.model import fe_eigen, fe_plate
from modalctl.model.fe_plate import BAND_SHIFT, MATERIALS, FEPlate, Hole, Outline, Support
from modalctl.model.plate_geometry import distance_to_segments, in_segments, near_segments
from modalctl.model.structures import PlatePatch

GLASS = MATERIALS["glass"]


def panel(support: str = "clamped") -> FEPlate:
    """A small rounded panel with a slot and a patch: every kind of rim the grid meets."""
    outline = Outline.rectangle(0.06, 0.04, 5e-3, holes=(Hole((0.015, 0.0), size=(0.012, 0.006), corner_radius=2e-3),))
    return FEPlate(outline, 1e-3, GLASS, {"rim": Support(support)},
                   patches=(PlatePatch((-0.02, -0.01), (-0.01, 0.0)),), sensors=((0.0, 0.005),))


def test_points_near_a_rim_are_the_ones_within_the_distance(rng):
    mesh = panel().mesh(6e-3)
    rim = mesh.p[:, mesh.facets[:, mesh.boundary_facets()]].transpose(2, 1, 0)
    spread = rng.uniform(rim.min(axis=(0, 1)), rim.max(axis=(0, 1)), (20000, 2))
    ends = rim[rng.integers(0, len(rim), 20000)]
    on_rim = ends[:, 0] + rng.uniform(0, 1, (20000, 1)) * (ends[:, 1] - ends[:, 0]) + rng.normal(0, 1e-7, (20000, 2))
    points = np.vstack([spread, on_rim, rim[:, 0]])
    for distance in (0.0, 1e-7, 1e-3):
        expected = distance_to_segments(points, rim).min(axis=1) <= distance
        assert np.array_equal(near_segments(points, rim, distance), expected)
        assert 0 < expected.sum() < len(points)


def test_fields_sampled_in_blocks_equal_one_call_of_the_probes(monkeypatch):
    plate = panel()
    mesh = plate.mesh(6e-3)
    grid = plate.grid(1e-3, mesh)
    points = grid.points[grid.mass > 0]
    freqs, vectors, _, basis = plate.solve(mesh, 8)
    whole = (basis.probes(np.ascontiguousarray(points.T)) @ vectors).T
    one = plate._sample(basis, vectors, points)
    monkeypatch.setattr(fe_plate, "PROBE_BLOCK", 64)  # small blocks: the elements found per block
    blocks = plate._sample(basis, vectors, points)
    assert blocks.shape == (8, len(points)) and len(points) > 10 * 64
    np.testing.assert_allclose(one, blocks, rtol=0, atol=1e-9 * np.abs(whole).max())
    # a point on an edge may be found in either element: the nonconforming field differs there by 1e-11
    np.testing.assert_allclose(blocks, whole, rtol=0, atol=1e-9 * np.abs(whole).max())


@pytest.mark.parametrize("support", ["clamped", "free"])
def test_the_inertia_counts_the_modes_a_dense_solution_finds(support):
    plate = FEPlate(Outline.rectangle(0.06, 0.04), 1e-3, GLASS, {"rim": Support(support)})
    mesh = plate.mesh(8e-3)
    stiffness, mass, held, basis = plate.assemble(mesh)
    free = basis.complement_dofs(held)
    k, m = stiffness[free][:, free], mass[free][:, free]
    w2 = scipy.linalg.eigh(k.toarray(), m.toarray(), eigvals_only=True)
    assert len(w2) > 200
    for f in (2e3, 1e4, 3e4):
        sigma = (2 * np.pi * f) ** 2
        _, count = fe_eigen.factor(k - sigma * m)
        assert count == np.count_nonzero(w2 < sigma), f


@pytest.mark.parametrize("support", ["clamped", "free"])
def test_every_mode_below_a_frequency_is_the_lowest_modes_up_to_it(support):
    plate = panel(support)
    mesh = plate.mesh(6e-3)
    below, every = plate.solve(mesh, below=25e3), plate.solve(mesh, 60)
    n = len(below[0])
    assert 10 < n < 60 and every[0][n - 1] < 25e3 <= every[0][n]
    np.testing.assert_allclose(below[0], every[0][:n], rtol=1e-9)
    # the shapes too (the band is solved about its middle, the lowest modes from below them):
    # each of the band's modes in the span of the lowest modes of its frequency, mass-weighted
    _, mass, _, _ = plate.assemble(mesh)
    for i in range(n):
        near = np.flatnonzero(np.abs(every[0] / below[0][i] - 1) < 1e-6)
        overlap = every[1][:, near].T @ (mass @ below[1][:, i])
        assert abs(np.sum(overlap**2) - 1) < 1e-8, i
    mac = (below[1].T @ every[1][:, :n]) ** 2 / np.outer(np.sum(below[1] ** 2, 0), np.sum(every[1][:, :n] ** 2, 0))
    assert np.all(np.max(mac, axis=1) > 0.999)  # mode by mode (no repeated frequency on this panel)
    assert below[2].shape[1] == (3 if support == "free" else 0)


def test_the_band_solved_about_its_middle_is_checked_and_sound_on_a_clamped_plate(monkeypatch):
    """The mid-band factors are indefinite and unpivoted: the band's modes are checked by their
    residuals, which on a sound factor are round-off, so no second solve."""
    plate = FEPlate(Outline.rectangle(0.06, 0.04), 1e-3, GLASS, {"rim": Support("clamped")})
    mesh = plate.mesh(6e-3)
    residual, factor, seen, factored = fe_eigen.residual, fe_eigen.factor, [], []
    monkeypatch.setattr(fe_eigen, "residual", lambda *pairs: seen.append(residual(*pairs)) or seen[-1])
    monkeypatch.setattr(fe_eigen, "factor", lambda matrix: factored.append(matrix) or factor(matrix))
    monkeypatch.setattr(fe_eigen, "ROUNDOFF", 0.0)  # every residual counted, round-off too
    freqs = plate.solve(mesh, below=25e3)[0]
    assert len(freqs) > 5 and len(seen) == 1 and 0 < seen[0] < 1e-8, seen
    assert len(factored) == 2  # the inertia's and the mid-band shift's: no solve from below


def test_unsound_mid_band_factors_are_solved_again_from_below_the_lowest_mode(monkeypatch):
    """Factors of a matrix 0.1% off (as a tiny pivot's growth leaves them) give modes whose
    residuals fail the check: the band is solved again from below, as the modes counted from
    below give it."""
    plate = FEPlate(Outline.rectangle(0.06, 0.04), 1e-3, GLASS, {"rim": Support("clamped")})
    mesh = plate.mesh(6e-3)
    sound = plate.solve(mesh, below=25e3)[0]
    safe = plate.solve(mesh, len(sound))[0]  # the lowest modes: solved from below them
    residual, factor, seen, factored = fe_eigen.residual, fe_eigen.factor, [], []
    rng = np.random.default_rng(5)

    def unsound(matrix):
        factored.append(matrix)
        if len(factored) == 2:  # the mid-band shift's (the first counts the modes)
            matrix = matrix + scipy.sparse.diags(1e-3 * np.abs(matrix.diagonal()) * rng.uniform(-1, 1, matrix.shape[0]))
        return factor(matrix)

    monkeypatch.setattr(fe_eigen, "residual", lambda *pairs: seen.append(residual(*pairs)) or seen[-1])
    monkeypatch.setattr(fe_eigen, "factor", unsound)
    freqs, vectors, rigid, _ = plate.solve(mesh, below=25e3)
    assert len(seen) == 1 and seen[0] > 100 * fe_eigen.RESIDUAL_TOLERANCE and len(factored) == 3, seen
    np.testing.assert_allclose(freqs, safe, rtol=1e-9)
    np.testing.assert_allclose(freqs, sound, rtol=1e-9)
    assert vectors.shape[1] == len(sound) and rigid.shape[1] == 0


@pytest.mark.parametrize("support", ["clamped", "free"])
def test_a_band_cut_in_two_slices_holds_the_modes_solved_at_once(support, monkeypatch):
    """The tablet's band is solved in two slices, the lower in a forked child: on a panel whose band
    is cut the same way (the thresholds lowered), the same modes, frequencies to 1e-9 and shapes
    mode by mode, as the band solved at once; the rigid ones with the lower slice."""
    plate = panel(support)
    mesh = plate.mesh(6e-3)
    whole = plate.solve(mesh, below=25e3)
    shifts, launched, lanczos, beside = [], [], fe_eigen.lanczos, fe_eigen.beside
    monkeypatch.setattr(fe_eigen, "SLICE_MODES", 5)
    monkeypatch.setattr(fe_eigen, "SLICE_DOFS", 100)
    monkeypatch.setattr(fe_eigen, "lanczos", lambda k, m, shift, *rest: shifts.append(shift) or lanczos(k, m, shift, *rest))
    monkeypatch.setattr(fe_eigen, "beside", lambda job: launched.append(job) or beside(job))
    sliced = plate.solve(mesh, below=25e3)
    top = (2 * np.pi * 25e3) ** 2
    assert len(launched) == 1 and np.allclose(shifts, [(1 + fe_eigen.SLICE_AT) * top / 2]), shifts  # the upper
    # slice here, the lower in the child (whose calls this process does not see)
    np.testing.assert_allclose(sliced[0], whole[0], rtol=1e-9)
    _, mass, _, _ = plate.assemble(mesh)
    overlap = sliced[1].T @ (mass @ whole[1])  # mass-normalized: the identity up to each mode's sign
    np.testing.assert_allclose(np.abs(np.diag(overlap)), 1, atol=1e-8)
    assert sliced[2].shape[1] == whole[2].shape[1] == (3 if support == "free" else 0)


def test_inside_an_outline_with_a_hole_as_matplotlib_s_path_says(rng):
    """The even-odd rule, each block of points against the segments of its heights only, against
    matplotlib's point-in-path on a seven-lobed outline with a hole: a lattice (blocks of a row) and
    scattered points (blocks of every height), those nearer the rim than round-off left out."""
    from matplotlib.path import Path

    t = np.linspace(0, 2 * np.pi, 301)[:-1]
    outer = (1 + 0.3 * np.sin(7 * t))[:, None] * np.c_[np.cos(t), np.sin(t)]
    hole = 0.2 * np.c_[np.cos(t), np.sin(t)]
    segments = np.concatenate([np.stack([loop, np.roll(loop, -1, axis=0)], axis=1) for loop in (outer, hole)])
    x = np.linspace(-1.4, 1.4, 301)
    for points in (np.column_stack([a.ravel() for a in np.meshgrid(x, x)]), rng.uniform(-1.4, 1.4, (20000, 2))):
        clear = ~near_segments(points, segments, 1e-9)
        truth = Path(outer).contains_points(points) & ~Path(hole).contains_points(points)
        got = in_segments(points, segments)
        assert 0.3 < got.mean() < 0.6 and np.array_equal(got[clear], truth[clear])


def test_the_plate_triangle_s_basis_made_at_once_is_scikit_fem_s(rng):
    """Every function's value, gradient and Hessian at the quadrature points of every element, and at
    points sampled on some elements (as the probes ask), equal scikit-fem's own, one at a time."""
    import skfem

    from modalctl.model.fe_element import PlateTriangle

    mesh = panel("free").mesh(6e-3)
    ours, theirs = skfem.Basis(mesh, PlateTriangle()), skfem.Basis(mesh, skfem.ElementTri15ParamPlate())
    cells = rng.integers(0, mesh.nelements, 50)
    local = rng.uniform(0, 0.5, (2, 50, 1))
    for i in range(ours.Nbfun):
        made, own = ours.basis[i][0], theirs.basis[i][0]
        for a, b in ((made, own), (made.grad, own.grad), (made.hess, own.hess)):
            np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-12, atol=1e-12 * np.abs(b).max())
    for i in range(ours.Nbfun):
        made = ours.elem.gbasis(ours.mapping, local, i, tind=cells)[0]
        own = theirs.elem.gbasis(theirs.mapping, local, i, tind=cells)[0]
        np.testing.assert_allclose(np.asarray(made.hess), np.asarray(own.hess), rtol=1e-12,
                                   atol=1e-12 * np.abs(own.hess).max())


def test_a_slice_that_misses_a_mode_at_its_edge_gives_the_band_solved_at_once(monkeypatch):
    """The lower slice made to lose its highest mode (as a slice whose edge mode ARPACK missed): the
    counts disagree with the inertia's, and the band is solved at once, the same modes as untouched."""
    plate = panel("clamped")
    mesh = plate.mesh(6e-3)
    whole = plate.solve(mesh, below=25e3)
    top, lanczos, shifts = (2 * np.pi * 25e3) ** 2, fe_eigen.lanczos, []

    def losing(k, m, shift, *rest):
        shifts.append(shift)
        w2, x = lanczos(k, m, shift, *rest)
        below = w2 < fe_eigen.SLICE_AT * top
        if shift < fe_eigen.SLICE_AT * top:  # the lower slice (in the child): its highest mode lost
            return w2[below][:-1], x[:, below][:, :-1]
        return w2, x

    monkeypatch.setattr(fe_eigen, "SLICE_MODES", 5)
    monkeypatch.setattr(fe_eigen, "SLICE_DOFS", 100)
    monkeypatch.setattr(fe_eigen, "lanczos", losing)
    again = plate.solve(mesh, below=25e3)
    assert np.isclose(shifts[-1], BAND_SHIFT * top)  # the last solve: the whole band about its middle
    np.testing.assert_allclose(again[0], whole[0], rtol=1e-9)
