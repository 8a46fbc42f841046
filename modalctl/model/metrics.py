"""Accuracy metrics of a synthesized field against its reference, over the grid samples.

Fields are arrays of shape (n,) (one field) or (f, n) (a batch, metric per row).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["tau", "tau_norm", "nrmse", "focus_contrast", "margin_ratio", "Extremes", "largest_each_instant"]

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


def largest_each_instant(field, rows: np.ndarray) -> np.ndarray:
    """``max |field[rows]|`` at each instant, shape (nt,) (zeros without rows), a block of rows at
    a time: a plate's scan is 10^7 samples and more, never copied whole."""
    field = np.asarray(field)
    parts = [np.abs(field[rows[start:start + _BLOCK]]).max(axis=0) for start in range(0, rows.size, _BLOCK)]
    return np.max(parts, axis=0) if parts else np.zeros(field.shape[1], field.dtype)


@dataclass(frozen=True)
class Extremes:
    """The largest ``|w|`` (m/s) inside and outside a target zone at each instant of a scan, shape
    (nt,) each: what the margin is measured from, and what a run's picture draws (one pass over a
    plate's field, not one for each)."""

    inside: np.ndarray
    outside: np.ndarray

    @classmethod
    def of(cls, field, target_mask) -> Extremes:
        mask = np.asarray(target_mask, bool)
        inside, outside = (largest_each_instant(field, np.flatnonzero(rows)) for rows in (mask, ~mask))
        return cls(inside, outside)


def margin_ratio(field, times, focus_time: float, target_mask, peak: float | None = None,
                 outside: np.ndarray | None = None):
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
    outside : ndarray, shape (nt,), optional
        The largest off-target ``|w|`` at each instant (:attr:`Extremes.outside`), when known.

    Returns
    -------
    ratio : float
    worst : tuple of (int, float)
        Grid index and time (s) of the largest off-target velocity.
    """
    field, times = np.asarray(field), np.asarray(times, float)  # float32 records read as they are
    if peak is None:
        peak = float(np.max(np.abs(field[:, np.argmin(np.abs(times - focus_time))])))
    off = np.flatnonzero(~np.asarray(target_mask, bool))
    if off.size == 0 or peak <= 0:
        return (0.0 if peak > 0 else np.inf), (-1, float(focus_time))
    outside = largest_each_instant(field, off) if outside is None else outside
    j = int(np.argmax(outside))
    i = int(off[np.argmax(np.abs(field[off, j]))])
    return float(outside[j]) / peak, (i, float(times[j]))
