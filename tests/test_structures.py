"""Analytic structures checked against textbook constants and independent computations."""

import numpy as np
import pytest
from scipy.integrate import quad

from modalctl.model.modes import ModelError
from modalctl.model.projection import gram
from modalctl.model.structures import BOUNDARIES, Beam, BeamPatch, Piezo, Plate, PlatePatch


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_beam_modes_orthonormal_on_grid(boundary):
    beam = Beam(0.105, 0.007, 0.001, 69e9, 2700, boundary)
    grid = beam.grid(1001)
    shapes = beam.shapes(grid.x, 21)
    assert np.abs(gram(shapes, grid.mass) - np.eye(21)).max() < 1e-6


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_beam_modes_orthonormal_by_adaptive_quadrature(boundary):
    """Independent of the grid: scipy's adaptive quadrature of rho A phi_k phi_l."""
    beam = Beam(0.105, 0.007, 0.001, 69e9, 2700, boundary)
    half = beam.length / 2
    for k, l in [(1, 1), (1, 2), (5, 7), (20, 20), (19, 21)]:
        value, _ = quad(lambda x: beam.mass_per_length * np.prod(beam.shapes([x], [k, l])), -half, half,
                        limit=200, epsabs=1e-12)
        assert value == pytest.approx(float(k == l), abs=1e-8)


@pytest.mark.parametrize("boundary, first", [
    ("clamped-clamped", [4.730041, 7.853205, 10.995608]),
    ("free-free", [4.730041, 7.853205, 10.995608]),
    ("clamped-free", [1.875104, 4.694091, 7.854757]),
    ("pinned-pinned", [np.pi, 2 * np.pi, 3 * np.pi]),
])
def test_wavenumbers_match_textbook(boundary, first):
    beam = Beam(1.0, 0.01, 0.01, 1.0, 1.0, boundary)
    assert beam.wavenumbers(3) == pytest.approx(first, rel=1e-6)


@pytest.mark.parametrize("boundary", BOUNDARIES)
def test_shapes_solve_the_beam_equation(boundary):
    """EI phi'''' = rho A w^2 phi at interior points, for the highest mode too."""
    beam = Beam(0.105, 0.007, 0.001, 69e9, 2700, boundary)
    x = np.linspace(-0.05, 0.05, 9)
    ei = beam.modulus * beam.width * beam.thickness**3 / 12
    w = 2 * np.pi * beam.frequencies(21)
    lhs, rhs = ei * beam.shapes(x, 21, 4), beam.mass_per_length * w[:, None] ** 2 * beam.shapes(x, 21)
    assert np.abs(lhs - rhs).max() < 1e-9 * np.abs(lhs).max()


@pytest.mark.parametrize("boundary, left, right", [
    ("clamped-clamped", (0, 1), (0, 1)), ("pinned-pinned", (0, 2), (0, 2)),
    ("free-free", (2, 3), (2, 3)), ("clamped-free", (0, 1), (2, 3)),
])
def test_boundary_conditions(boundary, left, right):
    beam = Beam(0.105, 0.007, 0.001, 69e9, 2700, boundary)
    inner = np.linspace(-0.05, 0.05, 51)
    for end, orders in [(-beam.length / 2, left), (beam.length / 2, right)]:
        for d in orders:
            scale = np.abs(beam.shapes(inner, 21, d)).max()
            assert np.abs(beam.shapes([end], 21, d)).max() < 1e-9 * scale, (end, d)


def test_free_free_rigid_modes_orthonormal_to_elastic():
    beam = Beam(0.1, 0.006, 0.002, 69e9, 2700, "free-free")
    grid = beam.grid(1001)
    both = np.vstack([beam.rigid_shapes(grid.x), beam.shapes(grid.x, 9)])
    assert np.abs(gram(both, grid.mass) - np.eye(11)).max() < 1e-6
    assert beam.modal_model(5).rigid_shapes.shape == (2, 1001)
    assert Beam(0.1, 0.006, 0.002, 69e9, 2700, "clamped-clamped").modal_model(5).rigid_shapes.shape == (0, 1001)


def test_patch_gain_is_moment_times_slope_difference(al_beam):
    """Pin force: the generalized force of end moments equals the integral of M phi'' over the patch."""
    patch, piezo = BeamPatch(-0.02, -0.01), Piezo()
    gains = al_beam.patch_gains([patch], 12, piezo)[:, 0]
    moment = piezo.moment_per_volt(al_beam.modulus, al_beam.thickness) * al_beam.width
    for k in range(12):
        integral, _ = quad(lambda x: al_beam.shapes([x], [k + 1], 2)[0, 0], patch.start, patch.stop, limit=200)
        assert gains[k] == pytest.approx(moment * integral, rel=1e-7)


def test_pin_force_moment_per_volt():
    # psi = E_h t_h / (E_p t_p) = 4 halves the free-strain force; moment arm t_h / 2
    piezo = Piezo(d31=100e-12, modulus=50e9, thickness=1e-3)
    assert piezo.moment_per_volt(200e9, 1e-3) == pytest.approx(50e9 * 100e-12 * 0.5 * 0.5e-3)


def test_plate_modes_and_frequencies():
    plate = Plate(0.1, 0.07, 0.001, 70e9, 2500, 0.22)
    grid = plate.grid(101, 71)
    idx = plate.mode_indices(21)
    assert np.abs(gram(plate.shapes(grid.points, idx), grid.mass) - np.eye(21)).max() < 1e-6
    freqs = plate.frequencies(idx)
    assert np.all(np.diff(freqs) >= 0)
    d = 70e9 * 1e-9 / (12 * (1 - 0.22**2))
    f11 = np.pi / 2 * (1 / 0.1**2 + 1 / 0.07**2) * np.sqrt(d / (2500 * 0.001))  # textbook f_11
    assert freqs[0] == pytest.approx(f11, rel=1e-12)


def test_plate_patch_gain_matches_area_integral_of_laplacian():
    """Independent: the moment line density times the integral of the Laplacian over the patch."""
    plate, piezo = Plate(0.1, 0.07, 0.001, 70e9, 2500), Piezo()
    patch = PlatePatch((-0.03, -0.018), (0.005, 0.017))
    idx = plate.mode_indices(8)
    gains = plate.patch_gains([patch], idx, piezo)[:, 0]
    xs, ys = np.linspace(*patch.xlim, 401), np.linspace(*patch.ylim, 401)
    xx, yy = np.meshgrid(xs, ys)
    pts = np.column_stack([xx.ravel(), yy.ravel()])
    km, kn = np.pi * idx[:, 0] / plate.a, np.pi * idx[:, 1] / plate.b
    lap = -(km**2 + kn**2)[:, None] * plate.shapes(pts, idx)  # exact Laplacian of the sine product
    integral = np.trapezoid(np.trapezoid(lap.reshape(len(idx), 401, 401), xs, axis=2), ys, axis=1)
    moment = piezo.moment_per_volt(plate.modulus, plate.thickness)
    assert gains == pytest.approx(moment * integral, rel=1e-4)


def test_bad_structures_name_the_field():
    with pytest.raises(ModelError, match="boundary"):
        Beam(0.1, 0.01, 0.001, 1e9, 1000, "glued")
    with pytest.raises(ModelError, match="beam.length"):
        Beam(-0.1, 0.01, 0.001, 1e9, 1000)
    with pytest.raises(ModelError, match="plate.poisson"):
        Plate(0.1, 0.1, 0.001, 1e9, 1000, 0.7)
