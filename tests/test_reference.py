"""Per-mode references and their exact drive, checked against independent integrations."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from modalctl.hil.plant import Plant
from modalctl.model.modes import Grid, ModalModel
from modalctl.plan.reference import BLEND, decay, focus_state, modal_response, rise, rise_coefficients

W, Z, TF = 2 * np.pi * 2253.0, 0.02862, 0.025  # mode 3 of the thesis's aluminium beam


def single_mode(gain=3.0):
    grid = Grid.line(0, 1, 3, 1.0)
    return ModalModel(grid, np.array([W / (2 * np.pi)]), np.array([Z]), np.ones((1, 3)),
                      np.array([[gain]]), np.ones((1, 1)))


@pytest.mark.parametrize("kappa,brake", [(1.0, 1.0), (0.3, 1.0), (4.0, 6.0)])
def test_drive_reaches_target_in_an_independent_integration(kappa, brake):
    c = 0.02

    x0, a0 = focus_state(c, W, Z, kappa, TF)

    def drive(t):  # the closed forms on scalars: fast enough for an adaptive integrator
        if t <= TF:
            return rise(t - TF, c, W, Z, kappa, TF)[2]
        return decay(t - TF, c, (x0, a0), W, Z, brake, kappa * Z * W)[2]

    sol = solve_ivp(lambda t, y: [y[1], drive(t) - 2 * Z * W * y[1] - W**2 * y[0]], [0, TF + 0.005], [0, 0],
                    method="DOP853", rtol=1e-11, atol=1e-15, dense_output=True)
    assert sol.sol(TF)[1] == pytest.approx(c, rel=1e-6)
    t = np.linspace(0, TF + 0.005, 3001)
    planned = modal_response(t, [c], [W], [Z], [kappa], [brake], TF)[0][0]
    assert np.max(np.abs(sol.sol(t)[1] - planned)) < 1e-6 * c  # the whole trajectory, rise and decay


def test_single_mode_on_the_sampled_plant_reaches_target_within_1e3():
    """The issue's check: the DAC's zero-order hold at 1 MS/s, the exact plant, the planner's sampling."""
    model, c, fs = single_mode(), 0.02, 1e6
    t = np.arange(int((TF + 0.002) * fs)) / fs
    volts = modal_response(t + 0.5 / fs, [c], [W], [Z], [1.0], [1.0], TF)[1] / model.actuator_gains[0, 0]
    velocity = Plant(model, fs, hold="zoh").simulate(volts)[0]
    assert abs(velocity[int(round(TF * fs))] / c - 1) < 1e-3


def test_reference_starts_at_rest_and_becomes_eq_2_33_for_fast_envelopes():
    c = 0.7
    v, x, _ = rise(np.array([-TF]), c, W, Z, 2.0, TF)
    assert abs(v[0]) < 1e-12 * c and abs(x[0]) < 1e-12 * c / W
    a, b = rise_coefficients(c, W, Z, 40.0, TF)  # kappa zeta w T_F = 405: the start term is negligible
    assert a == pytest.approx(c, rel=1e-12) and abs(b) < 1e-12 * c


def test_drive_is_continuous_at_the_focus():
    c, kappa, brake = 0.01, 5.0, 5.0
    eps = 1e-9
    _, drive = modal_response(np.array([TF - eps, TF + eps]), [c], [W], [Z], [kappa], [brake], TF)
    scale = 2 * (kappa + 1) * Z * W * c  # the drive's amplitude near the focus
    assert abs(drive[0, 1] - drive[0, 0]) < 1e-4 * scale
    assert BLEND > 1  # the blend overshoot stays below 1 / BLEND of the target


def test_free_decay_needs_no_drive_once_the_blend_has_died():
    c, kappa = 0.01, 3.0
    late = TF + 20 / (BLEND * (kappa + 1) * Z * W)
    _, drive = modal_response(np.array([late]), [c], [W], [Z], [kappa], [1.0], TF)
    assert abs(drive[0, 0]) < 1e-6 * 2 * (kappa + 1) * Z * W * c
