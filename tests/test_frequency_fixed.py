"""Where the FRFs' noise is measured, a mode is returned only when that noise fixes its frequency
to 1% (``estimators.frequency_fixed``, the profile likelihood of the band's fit).

Checked against an independent computation, the Cramer-Rao bound of one mode's frequency
(the inverse Fisher information of every parameter of the band's model, by finite
differences), and on a cluster of heavily damped modes hidden in the noise, where one pole
fits as well as three and lands between them: no method may return such a pole.
"""

from __future__ import annotations

import numpy as np
import pytest

from modalctl.identify.estimators import CONFIDENCE, FREQUENCY_TOLERANCE, UNCERTAIN, frequency_fixed
from modalctl.identify.frf import FRF, mobility
from modalctl.plugin.manager import get_identifier

F, ZETA = 1000.0, 0.02
FREQS = np.arange(940.0, 1060.0, 0.5)


def band_model(theta: np.ndarray) -> np.ndarray:
    """One point's mobility in the band: a mode (complex constant) plus a complex constant and
    slope, written out here rather than taken from ``pole_basis``. ``theta`` = f, zeta, then
    the real and imaginary parts of the three coefficients."""
    f, zeta, a_re, a_im, c_re, c_im, d_re, d_im = theta
    w, wk = 2 * np.pi * FREQS, 2 * np.pi * f
    mode = 1j * w / (wk**2 - w**2 + 2j * zeta * wk * w)
    return (a_re + 1j * a_im) * mode + (c_re + 1j * c_im) + (d_re + 1j * d_im) * (FREQS / F - 1)


def cramer_rao_f(theta: np.ndarray, sigma: float) -> float:
    """Standard deviation (Hz) of an unbiased estimate of the frequency, all other parameters
    unknown too, under complex noise of variance ``sigma**2`` per value."""
    steps = np.maximum(np.abs(theta), 1e-3) * 1e-6
    jac = []
    for i, h in enumerate(steps):
        up, down = theta.copy(), theta.copy()
        up[i] += h
        down[i] -= h
        d = (band_model(up) - band_model(down)) / (2 * h)
        jac.append(np.concatenate([d.real, d.imag]))
    jac = np.array(jac).T
    fisher = jac.T @ jac / (sigma**2 / 2)  # each real part has half the complex variance
    return float(np.sqrt(np.linalg.inv(fisher)[0, 0]))


@pytest.mark.parametrize("margin, fixed", [(1.5, True), (0.6, False)])
def test_the_check_agrees_with_the_cramer_rao_bound(margin, fixed):
    """Noise-free FRFs weighted by a stated noise: the frequency counts as fixed exactly when
    the tolerance is ``sqrt(CONFIDENCE)`` Cramer-Rao deviations wide, give or take the
    curvature of the likelihood over 1% (here half a half-power bandwidth)."""
    theta = np.array([F, ZETA, 2.0, 0.0, 0.01, 0.0, 0.005, 0.0])
    h = band_model(theta)[:, None]
    sigma_at_1 = cramer_rao_f(theta, 1.0)  # the bound scales with the noise's deviation
    wanted = FREQUENCY_TOLERANCE * F / (np.sqrt(CONFIDENCE) * margin)
    sigma = wanted / sigma_at_1
    assert cramer_rao_f(theta, sigma) == pytest.approx(wanted, rel=1e-6)
    assert frequency_fixed(FREQS, h, np.array([1 / sigma**2]), F, ZETA) is fixed


def test_a_mode_off_the_likelihoods_minimum_is_not_fixed():
    """A pole 2% from where the data put it (as a peak of a noisy magnitude may be) is refused
    however clean the data: its frequency is fixed, but not there."""
    theta = np.array([F, ZETA, 2.0, 0.0, 0.0, 0.0, 0.0, 0.0])
    h = band_model(theta)[:, None]
    assert frequency_fixed(FREQS, h, np.array([1e6]), F, ZETA)
    assert not frequency_fixed(FREQS, h, np.array([1e6]), F * 1.02, ZETA)


def hidden_cluster(seed: int) -> tuple[FRF, np.ndarray]:
    """A separated 1.5% mode at 100 Hz and three modes of 7-8% damping at 240, 290 and 345 Hz
    (about one bandwidth apart) on 5 points, noise 40 dB below each row's peak: the cluster
    sits near the noise, as in sdypy-EMA's synthetic case."""
    freqs = np.linspace(20, 800, 2400)
    poles = np.array([[100, 0.015], [240, 0.072], [290, 0.08], [345, 0.07]])
    rng = np.random.default_rng(seed)
    shapes = rng.uniform(-1, 1, (4, 5)) * np.array([[1], [0.4], [0.4], [0.4]])
    h = mobility(freqs, poles[:, 0], poles[:, 1], shapes)
    sigma = np.abs(h).max(axis=1, keepdims=True) * 10 ** (-40 / 20)
    noise = sigma * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)) / np.sqrt(2)
    return FRF(freqs, h + noise, np.ones(h.shape), np.arange(5.0)[:, None], 0, 4, 0.0,
               np.broadcast_to(sigma, h.shape)), poles


@pytest.mark.parametrize("method", ["peaks", "sdof", "mdof", "auto"])
def test_no_mode_more_than_one_percent_off_from_a_cluster_in_the_noise(method):
    uncertain = 0
    for seed in range(4):
        frf, poles = hidden_cluster(seed)
        modes = get_identifier(method).identify(frf)
        good = modes.only_resolved()
        error = np.min(np.abs(good.frequencies[:, None] / poles[None, :, 0] - 1), axis=1)
        assert np.all(error <= FREQUENCY_TOLERANCE), (method, seed, good.frequencies)
        assert np.min(np.abs(good.frequencies / 100 - 1)) < 1e-3  # the separated mode stays
        uncertain += sum(why == UNCERTAIN for why in modes.reasons)
    if method in ("peaks", "sdof"):  # their single poles land in the cluster: the check is what refuses them
        assert uncertain > 0
