"""The finger: a local damper coupling the modes, propagated exactly."""

import numpy as np
from scipy.signal import lsim

from modalctl.hil.finger import Finger, FingerPlant, added_damping
from modalctl.model.propagate import Plant
from modalctl.model.scenes import load_scene

FS = 200e3


def _drive(model, n=4000, seed=3):
    rng = np.random.default_rng(seed)
    return rng.standard_normal((model.actuator_gains.shape[1], n))


def test_without_a_finger_it_is_the_plant():
    model = load_scene("thesis-al-cc", 105)
    u = _drive(model)
    for hold in ("zoh", "foh"):
        ours = FingerPlant(model, Finger(52, 0.0), FS, hold=hold).step(u)
        plant = Plant(model, FS, hold=hold).step(u)
        assert np.max(np.abs(ours - plant)) < 1e-9 * np.max(np.abs(plant))


def test_finger_matches_an_independent_integration_of_the_coupled_system():
    """scipy's lsim (linear interpolation between samples, its own matrix exponential) on the
    second-order modal system with the finger's full damping matrix."""
    model = load_scene("thesis-al-cc", 105)
    finger = Finger(40, 0.5)
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
    free = FingerPlant(model, Finger(40, 0.0), FS, hold="foh").step(u)
    assert np.max(np.abs(free - y.T)) > 1e-2 * np.max(np.abs(y))


def test_light_touch_adds_the_first_order_damping():
    model = load_scene("thesis-al-cc", 105)
    finger = Finger(30, 0.02)
    plant = FingerPlant(model, finger, FS)
    upper = plant.values[plant.values.imag > 0]
    zeta = -upper.real / np.abs(upper)
    order = np.argsort(np.abs(upper))
    expected = model.damping + added_damping(model, finger)
    assert np.allclose(zeta[order], expected, rtol=0.02)
