"""The HIL plant: exact against independent discretizations and integrations."""

import control
import numpy as np
import pytest
from scipy.integrate import solve_ivp
from scipy.signal import cont2discrete, dlsim

from modalctl.hil.plant import Plant, truncation
from modalctl.model.scenes import load_scene


@pytest.fixture(scope="module")
def beam():
    return load_scene("thesis-al-cc", 101)


def state_space(model):
    k = model.n_modes
    a = np.block([[np.zeros((k, k)), np.eye(k)], [-np.diag(model.omega**2), -np.diag(2 * model.damping * model.omega)]])
    b = np.vstack([np.zeros_like(model.actuator_gains), model.actuator_gains])
    c = np.hstack([np.zeros((k, k)), np.eye(k)])
    return a, b, c


def drive(rng, n, channels):
    t = np.arange(n) / 1e6
    u = rng.normal(size=(channels, n)) * 2
    u[0] += 20 * np.sin(2 * np.pi * 963 * t)
    return u


def test_zoh_matches_an_independent_discretization(beam, rng):
    u = drive(rng, 4000, beam.actuator_gains.shape[1])
    a, b, c = state_space(beam)
    ad, bd, cd, dd, _ = cont2discrete((a, b, c, np.zeros((c.shape[0], b.shape[1]))), 1e-6, "zoh")
    _, expected, _ = dlsim((ad, bd, cd, dd, 1e-6), u.T)
    ours = Plant(beam, 1e6, hold="zoh").simulate(u)
    assert np.max(np.abs(ours - expected.T)) < 1e-9 * np.max(np.abs(expected))


def test_foh_matches_forced_response_within_1e6(beam, rng):
    u = drive(rng, 4000, beam.actuator_gains.shape[1])
    t = np.arange(u.shape[1]) / 1e6
    a, b, c = state_space(beam)
    expected = control.forced_response(control.ss(a, b, c, 0), t, u).outputs
    ours = Plant(beam, 1e6, hold="foh").simulate(u)
    assert np.max(np.abs(ours - expected)) < 1e-6 * np.max(np.abs(expected))


def test_matches_fine_step_integration_of_the_held_input(beam):
    """Adaptive Runge-Kutta on the continuous modes with the DAC's staircase input."""
    model = beam.select([0, 1, 2])
    fs, n = 1e5, 400
    rng = np.random.default_rng(5)
    u = rng.normal(size=(model.actuator_gains.shape[1], n))
    a, b, c = state_space(model)
    sol = solve_ivp(lambda t, x: a @ x + b @ u[:, min(int(t * fs), n - 1)], [0, (n - 1) / fs], np.zeros(6),
                    t_eval=np.arange(n) / fs, rtol=1e-11, atol=1e-16, max_step=0.1 / fs)
    expected = c @ sol.y
    ours = Plant(model, fs, hold="zoh").simulate(u)
    assert np.max(np.abs(ours - expected)) < 1e-6 * np.max(np.abs(expected))


def test_amplifier_bandwidth_equals_a_series_filter(beam, rng):
    u = drive(rng, 3000, beam.actuator_gains.shape[1])
    t = np.arange(u.shape[1]) / 1e6
    a, b, c = state_space(beam)
    bw = 2 * np.pi * 50e3
    amp = control.ss(-bw * np.eye(u.shape[0]), bw * np.eye(u.shape[0]), np.eye(u.shape[0]), 0)
    expected = control.forced_response(control.series(amp, control.ss(a, b, c, 0)), t, u).outputs
    ours = Plant(beam, 1e6, hold="foh", amplifier_bandwidth=50e3).simulate(u)
    assert np.max(np.abs(ours - expected)) < 1e-6 * np.max(np.abs(expected))


def test_chunks_continue_exactly(beam, rng):
    u = drive(rng, 5000, beam.actuator_gains.shape[1])
    plant = Plant(beam, 1e6, hold="foh")
    whole = plant.simulate(u)
    plant.reset()
    pieces = np.hstack([plant.step(u[:, i:i + 777]) for i in range(0, u.shape[1], 777)])
    assert np.max(np.abs(pieces - whole)) <= 1e-12 * np.max(np.abs(whole))


def test_rails_clip_and_are_counted(beam):
    u = np.zeros((beam.actuator_gains.shape[1], 100))
    u[0, 10:20] = 50.0
    plant = Plant(beam, 1e6, voltage_limit=10.0)
    clipped = plant.simulate(u)
    assert plant.clipped == 10
    np.testing.assert_allclose(clipped, Plant(beam, 1e6).simulate(np.clip(u, -10, 10)))


def test_truncation_bound_covers_the_dropped_modes(beam, rng):
    fs, n = 1e6, 20000
    t = np.arange(n) / fs
    u = np.zeros((beam.actuator_gains.shape[1], n))
    u[0] = 10 * np.sin(2 * np.pi * 963 * t) * np.exp(-((t - 0.01) / 0.003) ** 2)
    kept, bounds, dropped = truncation(beam, u, fs, tol=1e-3)
    assert 1 in kept and kept.size < beam.n_modes
    velocity = Plant(beam, fs).simulate(u)
    others = np.setdiff1d(np.arange(beam.n_modes), kept)
    actual = np.max(np.abs(beam.shapes[others].T @ velocity[others]))
    assert actual <= dropped


def test_retune_keeps_displacement_and_velocity_continuous():
    """Resonances +1% and damping +30% mid-run: matches an adaptive integration switching parameters there."""
    from scipy.integrate import solve_ivp
    from scipy.interpolate import interp1d

    from modalctl.model.propagate import Plant as CorePlant
    from modalctl.model.scenes import load_scene

    m = load_scene("thesis-al-cc", 101).select([0, 1, 2])
    fs = 200e3
    t = np.arange(4000) / fs
    u = np.vstack([np.sin(2 * np.pi * 900 * t) * np.exp(-((t - 0.008) / 0.004) ** 2)] * m.actuator_gains.shape[1])
    plant = CorePlant(m, fs, hold="foh")
    first = plant.step(u[:, :2000])
    new_f, new_z = m.frequencies * 1.01, m.damping * 1.3
    plant.retune(new_f, new_z)
    ours = np.hstack([first, plant.step(u[:, 2000:])])
    ui = interp1d(t, u, axis=1)

    def rhs(tt, x, w, z):
        eta, vel = x[:3], x[3:]
        return np.r_[vel, m.actuator_gains @ ui(tt) - 2 * z * w * vel - w**2 * eta]

    opts = dict(rtol=1e-10, atol=1e-14, max_step=1 / fs)
    s1 = solve_ivp(rhs, (0, t[1999]), np.zeros(6), args=(m.omega, m.damping), t_eval=t[:2000], **opts)
    s2 = solve_ivp(rhs, (t[1999], t[-1]), s1.y[:, -1], args=(2 * np.pi * new_f, new_z), t_eval=t[1999:], **opts)
    ref = np.hstack([s1.y[3:], s2.y[3:, 1:]])
    assert np.max(np.abs(ours - ref)) < 1e-7 * np.max(np.abs(ref))
