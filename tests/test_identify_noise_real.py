"""The noise of an exported FRF from its coherence when the file gives no number of averages (issue 38)."""

import numpy as np
import pytest

from modalctl.identify.frf import FRF, mobility
from modalctl.identify.noise import AVERAGES_MAX, SCATTER_SOURCE, coherence_noise, scatter_noise, with_noise_estimate


def h1_shots(averages, noise=0.02, seed=0):
    """An H1 estimate over ``averages`` hammer-like shots of a 2-mode structure on 6 points, lines
    every 0.25 Hz; output noise of a known variance. Returns the FRF as a file exports it (values,
    coherence; averages not given) and the true standard deviation of each value."""
    rng = np.random.default_rng(seed)
    freqs = np.arange(50.0, 250.0, 0.25)
    h = mobility(freqs, [100.0, 180.0], [0.02, 0.015], rng.standard_normal((2, 6)))
    sigma_y = noise * np.abs(h).max()
    suu, syu, syy = np.zeros(h.shape), np.zeros(h.shape, complex), np.zeros(h.shape)
    for _ in range(averages):
        u = (rng.standard_normal(freqs.size) + 1j * rng.standard_normal(freqs.size)) / np.sqrt(2)
        y = h * u + sigma_y * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)) / np.sqrt(2)
        suu, syu, syy = suu + np.abs(u) ** 2, syu + y * u.conj(), syy + np.abs(y) ** 2
    coherence = np.abs(syu) ** 2 / (suu * syy)
    true_std = sigma_y / np.sqrt(suu)  # the H1 estimate's scatter for this force's energy
    return FRF(freqs, syu / suu, coherence, np.arange(6.0)[:, None], input_unit="N"), true_std


@pytest.mark.parametrize("averages", [4, 16])
def test_the_noise_from_coherence_matches_the_known_noise(averages):
    frf, true_std = h1_shots(averages)
    got = with_noise_estimate(frf)
    assert "coherence" in got.noise_source
    ratio = np.median(got.noise_std / true_std)
    assert 0.7 < ratio < 1.4, ratio
    # the coherence's shape across lines and points, not a flat level: it follows the force's energy
    assert np.corrcoef(np.log(got.noise_std).ravel(), np.log(true_std).ravel())[0, 1] > 0.5
    # with the averages known, the coherence gives it alone (H1's own formula)
    exact = np.median(coherence_noise(frf.values, frf.coherence, averages) / true_std)
    assert 0.7 < exact < 1.4
    # two averages, the least a coherence below one needs, bound it from above
    assert np.median(coherence_noise(frf.values, frf.coherence, 2) / true_std) > 0.9 * np.sqrt(averages - 1)


def test_without_coherence_the_scatter_between_lines():
    frf, true_std = h1_shots(8)
    got = with_noise_estimate(FRF(frf.frequencies, frf.values, np.ones(frf.values.shape), frf.points))
    assert got.noise_source == SCATTER_SOURCE
    assert 0.5 < np.median(got.noise_std / true_std) < 2.0


def test_a_scatter_that_misses_the_noise_gives_the_coherence_s_level_at_most_averages():
    # the output noise smoothed across lines (a window, leakage): the second difference between
    # neighbouring lines sees almost none of it, so matching the scatter asks for thousands of
    # averages; the noise must then be the coherence's at AVERAGES_MAX, not the scatter's level
    averages, rng = 16, np.random.default_rng(4)
    freqs = np.arange(50.0, 250.0, 0.25)
    h = mobility(freqs, [100.0, 180.0], [0.02, 0.015], rng.standard_normal((2, 6)))
    sigma_y, kernel = 0.02 * np.abs(h).max(), np.hanning(41) / np.sqrt(np.sum(np.hanning(41) ** 2))
    suu, syu, syy = np.zeros(h.shape), np.zeros(h.shape, complex), np.zeros(h.shape)
    for _ in range(averages):
        u = (1 + 0.2 * rng.standard_normal()) * np.exp(-2j * np.pi * freqs * rng.uniform(0, 1e-3))  # a hammer's
        white = sigma_y * (rng.standard_normal(h.shape) + 1j * rng.standard_normal(h.shape)) / np.sqrt(2)
        y = h * u + np.array([np.convolve(row, kernel, mode="same") for row in white])
        suu, syu, syy = suu + np.abs(u) ** 2, syu + y * u.conj(), syy + np.abs(y) ** 2
    frf = FRF(freqs, syu / suu, np.abs(syu) ** 2 / (suu * syy), np.arange(6.0)[:, None], input_unit="N")
    got = with_noise_estimate(frf)
    assert f"n = {AVERAGES_MAX}" in got.noise_source and "would match the scatter" in got.noise_source
    least = coherence_noise(frf.values, frf.coherence, AVERAGES_MAX)
    assert np.allclose(got.noise_std, np.maximum(least, scatter_noise(frf.values) * 1e-3 / np.sqrt(AVERAGES_MAX - 1)))
    # the scatter's level is far below what the coherence says (before: noise_std was it, n = 2.7e5)
    assert np.median(got.noise_std / scatter_noise(frf.values)) > 3
    # against the true noise (kernel of unit energy: sigma_y a line): sqrt(15 / 99) of it, not a hundredth
    ratio = np.median(got.noise_std / (sigma_y / np.sqrt(suu)))
    assert 0.25 < ratio < 1.0, ratio


def test_one_average_is_refused():
    frf, _ = h1_shots(4)
    with pytest.raises(ValueError, match="fewer than 2"):
        coherence_noise(frf.values, frf.coherence, 1)
    with np.errstate(all="raise"):  # two averages: finite, no division by zero
        assert np.all(np.isfinite(coherence_noise(frf.values, frf.coherence, 2)))
