"""The touch (modalctl.model.touch) and the HIL's finger that plays it (modalctl.hil.finger)."""

import numpy as np
import pytest
from scipy.linalg import eig
from scipy.optimize import brentq
from scipy.signal import lsim

from modalctl.hil.finger import FingerPlant
from modalctl.hil.scenario import Perturbation
from modalctl.model.modes import ModelError
from modalctl.model.propagate import Plant
from modalctl.model.scenes import load_scene
from modalctl.model.structures import Beam
from modalctl.model.touch import Touch, added_decay, touch_at, touched_system

FS = 200e3


def _drive(model, n=4000, seed=3):
    rng = np.random.default_rng(seed)
    return rng.standard_normal((model.actuator_gains.shape[1], n))


def test_without_a_finger_it_is_the_plant():
    model = load_scene("thesis-al-cc", 105)
    u = _drive(model)
    for hold in ("zoh", "foh"):
        for touch in (Touch(52, 0.0), None):
            ours = FingerPlant(model, touch, FS, hold=hold).step(u)
            plant = Plant(model, FS, hold=hold).step(u)
            assert np.max(np.abs(ours - plant)) < 1e-9 * np.max(np.abs(plant))


def test_touch_matrices_against_a_point_element_assembled_on_the_grid():
    """The touch assembled as a finite element would be: a point damper, spring and mass on one
    node of the grid (n x n physical matrices), projected on the shapes; then the touched
    system's poles from the generalized eigenproblem of that second-order system."""
    model = load_scene("thesis-al-cc", 105)
    touch = Touch(40, damping=0.7, stiffness=3e3, mass=2e-4)
    n = model.grid.points.shape[0]
    node = np.zeros((n, n))
    node[40, 40] = 1.0
    phi = model.shapes.T  # (n, k)
    added = [value * phi.T @ node @ phi for value in (touch.mass, touch.damping, touch.stiffness)]
    for ours, theirs in zip(touch.matrices(model), added):
        assert np.allclose(ours, theirs, rtol=1e-12, atol=0)
    k = model.n_modes
    m = np.eye(k) + added[0]
    c = np.diag(2 * model.damping * model.omega) + added[1]
    s = np.diag(model.omega ** 2) + added[2]
    # (lambda^2 M + lambda C + K) q = 0 as  [[0, I], [-K, -C]] x = lambda [[I, 0], [0, M]] x
    theirs = eig(np.block([[np.zeros((k, k)), np.eye(k)], [-s, -c]]),
                 np.block([[np.eye(k), np.zeros((k, k))], [np.zeros((k, k)), m]]), right=False)
    ours = np.linalg.eigvals(touched_system(model, touch)[0])
    assert ours.size == theirs.size
    gaps = np.abs(ours[:, None] - theirs[None, :]).min(axis=1) / np.abs(ours)
    assert np.max(gaps) < 1e-7  # eigenvalues of matrices spanning 1 to 1e12: round-off


def test_a_spring_at_mid_span_moves_the_symmetric_modes_as_the_exact_beam_says():
    """A pinned-pinned Euler-Bernoulli beam with a point spring k at mid-span: the symmetric
    modes solve 4 EI beta^3 cos(beta L/2) + k (sin(beta L/2) - cos(beta L/2) tanh(beta L/2)) = 0
    (half the span, slope zero at the middle, the spring's force shared by the two halves). The
    modal model with the touch (60 modes) gives the same frequencies; the antisymmetric modes,
    with a node there, do not move."""
    beam = Beam(0.14, 0.006, 0.005, 70e9, 2700.0, "pinned-pinned")
    model = beam.modal_model(60, n_points=1401, damping=1e-4)
    ei = beam.modulus * beam.width * beam.thickness ** 3 / 12
    half = beam.length / 2
    spring = 40 * ei / beam.length ** 3  # stiff enough to move mode 1 by a third
    touch = touch_at(model, [0.0], stiffness=spring)
    assert abs(model.grid.points[touch.index, 0]) < 1e-12

    def exact(beta):
        return 4 * ei * beta ** 3 * np.cos(beta * half) + spring * (np.sin(beta * half)
                                                                   - np.cos(beta * half) * np.tanh(beta * half))

    roots = []
    grid = np.linspace(0.5, 12 * np.pi, 20000) / beam.length
    values = exact(grid)
    for a, b, fa, fb in zip(grid[:-1], grid[1:], values[:-1], values[1:]):
        if fa * fb < 0:
            roots.append(brentq(exact, a, b))
    speed = np.sqrt(ei / beam.mass_per_length)
    symmetric = (np.array(roots[:4]) ** 2 * speed / (2 * np.pi))
    poles = np.linalg.eigvals(touched_system(model, touch)[0])
    touched = np.sort(np.abs(poles[poles.imag > 0])) / (2 * np.pi)
    free = beam.frequencies(12)
    assert symmetric[0] > 1.3 * free[0]  # the spring matters
    for f in symmetric:
        assert np.min(np.abs(touched / f - 1)) < 2e-3
    for f in free[1::2][:4]:  # antisymmetric: untouched
        assert np.min(np.abs(touched / f - 1)) < 1e-6


def test_finger_matches_an_independent_integration_of_the_coupled_system():
    """scipy's lsim (linear interpolation between samples, its own matrix exponential) on the
    second-order modal system with the finger's full damping matrix."""
    model = load_scene("thesis-al-cc", 105)
    finger = Touch(40, 0.5)
    k = model.n_modes
    c = np.diag(2 * model.damping * model.omega) + finger.damping * np.outer(model.shapes[:, 40], model.shapes[:, 40])
    a = np.block([[np.zeros((k, k)), np.eye(k)], [-np.diag(model.omega ** 2), -c]])
    b = np.vstack([np.zeros_like(model.actuator_gains), model.actuator_gains])
    u = _drive(model, 2000)
    t = np.arange(u.shape[1]) / FS
    _, y, _ = lsim((a, b, np.hstack([np.zeros((k, k)), np.eye(k)]), np.zeros((k, b.shape[1]))), u.T, t)
    ours = FingerPlant(model, finger, FS, hold="foh").step(u)  # lsim interpolates linearly between samples
    assert np.max(np.abs(ours - y.T)) < 1e-6 * np.max(np.abs(y))
    # and the finger really couples: the same drive without it differs by far more
    free = FingerPlant(model, Touch(40, 0.0), FS, hold="foh").step(u)
    assert np.max(np.abs(free - y.T)) > 1e-2 * np.max(np.abs(y))


def test_light_touch_adds_the_first_order_damping():
    model = load_scene("thesis-al-cc", 105)
    finger = Touch(30, 0.02)
    plant = FingerPlant(model, finger, FS)
    upper = plant.values[plant.values.imag > 0]
    zeta = -upper.real / np.abs(upper)
    order = np.argsort(np.abs(upper))
    expected = model.damping + added_decay(model, finger) / model.omega
    assert np.allclose(zeta[order], expected, rtol=0.02)


def test_a_finger_landing_and_lifting_is_the_touched_system_in_between():
    """Played in chunks with the finger landing at 5 ms and lifting at 12 ms: lsim of the touched
    system over the touch, from the state the free plant left, and the free plant after it."""
    model = load_scene("thesis-al-cc", 105)
    u = _drive(model, 4000)
    p = Perturbation(finger=0.8, finger_at=(0.0,), finger_lands=5e-3, finger_lifts=12e-3)
    path = p.touch_path(model)
    assert path(1e-3) is None and path(6e-3).damping == 0.8 and path(13e-3) is None
    plant = FingerPlant(model, path, FS, hold="foh")
    ours = np.hstack([plant.step(u[:, i:i + 100]) for i in range(0, u.shape[1], 100)])
    k, t = model.n_modes, np.arange(u.shape[1]) / FS
    state = np.zeros(2 * k)
    pieces, bounds = [], [0, 1000, 2400, 4000]  # 5 ms and 12 ms at 200 kHz
    touches = [None, path(6e-3), None]
    for (i, j), touch in zip(zip(bounds[:-1], bounds[1:]), touches):
        a, b = touched_system(model, touch)
        # lsim from the state at sample i - 1 over samples i - 1 .. j - 1 (the input held linearly)
        start = max(i - 1, 0)
        _, _, x = lsim((a, b, np.eye(2 * k), np.zeros((2 * k, b.shape[1]))), u[:, start:j].T, t[start:j] - t[start],
                       X0=state)
        x = np.atleast_2d(x)
        pieces.append(x[(i - start):, k:].T)
        state = x[-1]
    exact = np.hstack(pieces)
    assert np.max(np.abs(ours - exact)) < 1e-6 * np.max(np.abs(exact))


def test_a_touch_off_the_structure_or_in_the_wrong_dimension_is_refused():
    model = load_scene("thesis-al-cc", 105)
    with pytest.raises(ModelError, match="off the structure"):
        touch_at(model, [0.2], damping=1.0)
    with pytest.raises(ModelError, match="2 coordinate"):
        touch_at(model, [0.0, 0.0], damping=1.0)
    with pytest.raises(ModelError, match="zero or more"):
        Touch(3, damping=-1.0)
