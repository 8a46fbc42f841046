import numpy as np
import pytest

from modalctl.model.metrics import focus_contrast, nrmse, tau, tau_norm


def test_tau_is_one_on_identical_fields(rng):
    w = rng.normal(size=500)
    assert tau(w, w) == pytest.approx(1.0)
    assert nrmse(w, w) == 0.0


def test_tau_matches_numpy_covariance(rng):
    """Independent: Eq 4.2 with numpy's cov and var (same normalization)."""
    r, m = rng.normal(size=300), rng.normal(size=300)
    assert tau(r, m) == pytest.approx(np.cov(r, m)[0, 1] / np.var(r, ddof=1))


def test_tau_counts_amplitude_tau_norm_does_not(rng):
    r = np.sin(np.linspace(0, 3, 200)) + 0.1
    assert tau(r, 0.5 * r) == pytest.approx(0.5)
    assert tau_norm(r, 0.5 * r) == pytest.approx(1.0)
    assert tau(r, r + 3.0) == pytest.approx(1.0)  # an offset is not a shape difference


def test_nrmse_and_batches(rng):
    r = rng.normal(size=(3, 100))
    m = r + 0.1 * r
    assert nrmse(r, m) == pytest.approx([0.1, 0.1, 0.1])
    assert tau(r, m) == pytest.approx([1.1, 1.1, 1.1])


def test_focus_contrast():
    field = np.array([0.1, 0.2, 1.0, 0.9, -0.5])
    mask = np.array([False, False, True, True, False])
    assert focus_contrast(field, mask) == pytest.approx(2.0)
    assert focus_contrast(np.array([0.0, 1.0]), np.array([False, True])) == np.inf
