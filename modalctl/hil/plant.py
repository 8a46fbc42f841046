"""The time-domain truth of the HIL: the exact plant and the mode cut-off a drive needs.

The propagator itself is core computation (:mod:`modalctl.model.propagate`, shared with the planner's
predictions); this module chooses how many modes of the truth a shot must carry.
"""

from __future__ import annotations

import numpy as np

from modalctl.model.modes import ModalModel
from modalctl.model.propagate import HOLDS, Plant, hold_coefficients

__all__ = ["Plant", "hold_coefficients", "truncation", "HOLDS"]


def truncation(model: ModalModel, voltages: np.ndarray, sample_rate: float, tol: float = 1e-4, keep=()):
    """Modes a drive excites above ``tol`` and a bound on what the others add.

    The bound is Fourier's ``max_t |y(t)| <= (1/2 pi) int |F(w)| |H(w)| dw`` evaluated on the
    zero-padded spectrum of each mode's force, times the largest ``|phi_k|`` on the grid: the
    velocity a mode can add anywhere, at any time.

    Parameters
    ----------
    model : ModalModel
        Every mode available for the truth.
    voltages : ndarray, shape (a, n)
        The drive (V) at ``sample_rate`` (Hz).
    tol : float
        Relative to the largest bound of all modes.
    keep : sequence of int
        Modes always kept (the planned ones).

    Returns
    -------
    kept : ndarray of int
    bounds : ndarray, shape (k,)
        Largest velocity each mode can add on the grid (m/s).
    dropped_bound : float
        Sum of the bounds of the dropped modes (m/s).
    """
    u = np.atleast_2d(voltages)
    active = np.flatnonzero(np.any(u != 0, axis=1))  # silent channels add nothing
    n = int(2 ** np.ceil(np.log2(4 * u.shape[1])))
    spectrum = np.fft.rfft(u[active], n=n) / sample_rate  # continuous Fourier transform, V s
    w = 2 * np.pi * np.fft.rfftfreq(n, 1 / sample_rate)
    force = np.abs(model.actuator_gains[:, active] @ spectrum)
    bounds = np.empty(model.n_modes)
    for k, (wk, zk) in enumerate(zip(model.omega, model.damping)):  # one mode at a time: no (k, n) temporaries
        gain = w / np.sqrt((wk**2 - w**2) ** 2 + (2 * zk * wk * w) ** 2)  # |H_k(jw)| of the velocity
        bounds[k] = force[k] @ gain
    bounds *= (w[1] - w[0]) / np.pi * np.max(np.abs(model.shapes), axis=1)
    kept = np.flatnonzero(bounds >= tol * bounds.max())
    kept = np.union1d(kept, np.asarray(keep, int))
    dropped = np.setdiff1d(np.arange(model.n_modes), kept)
    return kept, bounds, float(bounds[dropped].sum())
