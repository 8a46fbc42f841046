"""Accuracy metrics of a synthesized field against its reference, over the grid samples.

Fields are arrays of shape (n,) (one field) or (f, n) (a batch, metric per row).
"""

from __future__ import annotations

import numpy as np

__all__ = ["tau", "tau_norm", "nrmse", "focus_contrast", "margin_ratio"]

_BLOCK = 256  # grid points per block of the margin's search (a few MB of samples)


def _centred(a):
    a = np.asarray(a, dtype=float)
    return a - a.mean(axis=-1, keepdims=True)


def tau(reference, measured):
    """Covariance criterion ``cov(w_R, w_E) / var(w_R)`` (thesis Eq 4.2).

    1 for identical fields; it also counts amplitude: a field at half the reference gives 0.5.
    """
    r, m = _centred(reference), _centred(measured)
    return np.sum(r * m, axis=-1) / np.sum(r * r, axis=-1)


def _unit_max(a):
    a = np.asarray(a, dtype=float)
    peak = np.take_along_axis(a, np.argmax(np.abs(a), axis=-1)[..., None], axis=-1)
    return a / peak


def tau_norm(reference, measured):
    """:func:`tau` after scaling both fields to a unit value at their largest magnitude (shape only)."""
    return tau(_unit_max(reference), _unit_max(measured))


def nrmse(reference, measured):
    """Root-mean-square error normalized by the RMS of the reference: ``||w_E - w_R|| / ||w_R||``."""
    r, m = np.asarray(reference, float), np.asarray(measured, float)
    return np.sqrt(np.sum((m - r) ** 2, axis=-1) / np.sum(r * r, axis=-1))


def focus_contrast(field, target_mask):
    """Largest ``|w|`` inside the target zone over the largest ``|w|`` outside it.

    Above 1 the stimulus is strongest where it is meant to be felt; infinite when the field
    is zero everywhere outside the zone.
    """
    a, mask = np.abs(np.asarray(field, float)), np.asarray(target_mask, bool)
    inside = np.max(np.where(mask, a, 0.0), axis=-1)
    outside = np.max(np.where(mask, 0.0, a), axis=-1)
    with np.errstate(divide="ignore"):
        return np.where(outside > 0, inside / np.where(outside > 0, outside, 1.0), np.inf)


def margin_ratio(field, times, focus_time: float, target_mask, peak: float | None = None):
    """Transient margin ratio: the largest ``|w|`` outside the target zone over the largest ``|w(x, T_F)|``.

    The thesis's criterion (chapter 5) asks for at most 0.5 over the transient and the
    post-transient: every time sample given.

    Parameters
    ----------
    field : ndarray, shape (n, nt)
        Velocity on the grid over time (m/s).
    times : ndarray, shape (nt,)
        Sample times (s).
    focus_time : float
        T_F (s); the field at the sample nearest to it gives the peak.
    target_mask : ndarray of bool, shape (n,)
    peak : float, optional
        Focus peak to divide by (m/s); by default ``max |field(:, T_F)|``.

    Returns
    -------
    ratio : float
    worst : tuple of (int, float)
        Grid index and time (s) of the largest off-target velocity.
    """
    field, times = np.asarray(field), np.asarray(times, float)  # float32 records read as they are
    if peak is None:
        peak = float(np.max(np.abs(field[:, np.argmin(np.abs(times - focus_time))])))
    outside = np.flatnonzero(~np.asarray(target_mask, bool))
    if outside.size == 0 or peak <= 0:
        return (0.0 if peak > 0 else np.inf), (-1, float(focus_time))
    best, worst = -1.0, (-1, float(focus_time))
    for start in range(0, outside.size, _BLOCK):  # a plate's scan is 10^7 samples: no copy of it whole
        rows = outside[start:start + _BLOCK]
        block = np.abs(field[rows])
        i, j = np.unravel_index(np.argmax(block), block.shape)
        if block[i, j] > best:
            best, worst = float(block[i, j]), (int(rows[i]), float(times[j]))
    return best / peak, worst
