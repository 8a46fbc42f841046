"""Choosing the modes a scene needs, and saying what error the choice leaves.

Two rules:

* :func:`twenty_percent_rule`, the thesis's (section 4.3.3): keep a mode when its coefficient
  exceeds 20% of the largest coefficient of the whole pulse set for most pulses of the set.
* :func:`smallest_set`, a distortion target: the fewest modes with which every field meets a
  tau or NRMSE target. Modes are added by decreasing relative coefficient, which for
  mass-orthonormal modes removes the most mass-weighted error per mode (Parseval).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.model.metrics import nrmse, tau
from modalctl.model.projection import project, reconstruct

__all__ = ["ReductionError", "Fit", "fit", "twenty_percent_rule", "smallest_set"]


class ReductionError(ValueError):
    """No mode set meets the requested accuracy."""


@dataclass(frozen=True)
class Fit:
    """How well a mode set reproduces a batch of fields.

    Attributes
    ----------
    modes : ndarray of int, shape (m,)
        Positional indices of the modes used, ascending.
    tau, nrmse : ndarray, shape (f,)
        Per field, reconstruction against reference (:mod:`modalctl.model.metrics`).
    energy_left : ndarray, shape (f,)
        Fraction of each field's mass-weighted energy ``<w, w>`` the mode set does not carry.
    """

    modes: np.ndarray
    tau: np.ndarray
    nrmse: np.ndarray
    energy_left: np.ndarray


def fit(fields, shapes, mass, modes) -> Fit:
    """Evaluate mode set ``modes`` on ``fields`` (f, n) with ``shapes`` (k, n) and ``mass`` (n,)."""
    fields = np.atleast_2d(fields)
    modes = np.unique(np.asarray(modes, dtype=int))
    coefficients = project(fields, shapes[modes], mass)
    approx = reconstruct(coefficients, shapes[modes])
    energy = np.sum(fields**2 * mass, axis=1)
    left = 1 - np.sum(coefficients**2, axis=1) / energy
    return Fit(modes, tau(fields, approx), nrmse(fields, approx), np.clip(left, 0, 1))


def twenty_percent_rule(coefficients, fraction: float = 0.2, quorum: float = 0.5,
                        contiguous: bool = False) -> np.ndarray:
    """The thesis's reduction rule over a set of pulses.

    Parameters
    ----------
    coefficients : ndarray, shape (f, k)
        Modal coefficients of each pulse of the set.
    fraction : float
        Threshold relative to the largest ``|c|`` over the whole set (thesis: 20%).
    quorum : float
        A mode is kept when it passes for more than this fraction of the pulses ("most").
    contiguous : bool
        Keep every mode up to the highest one kept, as the thesis's experiments did (modes 1..N).

    Returns
    -------
    ndarray of int
        Positional indices of the kept modes, ascending.
    """
    c = np.abs(np.atleast_2d(coefficients))
    passes = c > fraction * c.max()
    kept = np.flatnonzero(passes.mean(axis=0) > quorum)
    if contiguous and kept.size:
        kept = np.arange(kept.max() + 1)
    return kept


def smallest_set(fields, shapes, mass, *, tau_min: float | None = None, nrmse_max: float | None = None,
                 order: str = "magnitude") -> Fit:
    """The fewest modes with which every field meets ``tau >= tau_min`` and ``nrmse <= nrmse_max``.

    Parameters
    ----------
    fields : ndarray, shape (f, n) or (n,)
    shapes : ndarray, shape (k, n)
        Mass-normalized (orthonormal) modes.
    mass : ndarray, shape (n,)
    tau_min, nrmse_max : float, optional
        Targets (at least one).
    order : {"magnitude", "frequency"}
        Add modes by decreasing relative coefficient, or lowest modes first (a band 1..N).

    Raises
    ------
    ReductionError
        When even all modes miss the target; the message gives what all modes reach.
    """
    if tau_min is None and nrmse_max is None:
        raise ValueError("smallest_set: give tau_min or nrmse_max")
    fields = np.atleast_2d(fields)
    c = project(fields, shapes, mass)
    if order == "magnitude":
        relative = np.abs(c) / np.abs(c).max(axis=1, keepdims=True)
        ranking = np.argsort(-relative.max(axis=0), kind="stable")
    elif order == "frequency":
        ranking = np.arange(shapes.shape[0])
    else:
        raise ValueError(f"order: 'magnitude' or 'frequency', got {order!r}")
    approx = np.zeros_like(fields, dtype=float)
    for count, k in enumerate(ranking, start=1):
        approx += np.outer(c[:, k], shapes[k])
        ok_tau = tau_min is None or np.all(tau(fields, approx) >= tau_min)
        ok_err = nrmse_max is None or np.all(nrmse(fields, approx) <= nrmse_max)
        if ok_tau and ok_err:
            return fit(fields, shapes, mass, ranking[:count])
    best = fit(fields, shapes, mass, ranking)
    why = _missing_parity(fields, shapes, mass) or ("the shape is finer than the model's modes can draw; widen it, "
                                                    "lower the target, or choose the modes yourself")
    raise ReductionError(
        f"no mode set meets the target (tau >= {tau_min}, nrmse <= {nrmse_max}): all {shapes.shape[0]} modes "
        f"reach worst tau {best.tau.min():.4f} and worst nrmse {best.nrmse.max():.4f}: {why}")


def _missing_parity(fields: np.ndarray, shapes: np.ndarray, mass: np.ndarray) -> str | None:
    """Why the target cannot be drawn when every mode has one parity about the grid's centre (the
    reversed grid order: a mirror on a beam, a point reflection on a plate) and the target has a
    share of the other: no set of these modes draws that share, and widening the shape does not
    help (issue 26: thesis-al-ff's symmetric modes under an off-centre pulse). None otherwise."""
    if not np.allclose(mass, mass[::-1]):
        return None
    scale = np.abs(shapes).max(axis=1, keepdims=True)
    for parity, name, other in ((1, "symmetric", "antisymmetric"), (-1, "antisymmetric", "symmetric")):
        if np.all(np.abs(shapes - parity * shapes[:, ::-1]) <= 1e-6 * scale):
            part = (fields - parity * fields[:, ::-1]) / 2  # the share of the parity the modes lack
            share = float(np.max((part ** 2 @ mass) / np.maximum(fields ** 2 @ mass, 1e-300)))
            if share > 0.01:
                return (f"every mode of the model is {name} about the middle, and {100 * share:.0f}% of the target's "
                        f"energy is {other}: no mode can draw that part (widening does not help); centre the shape, "
                        f"or use a model with {other} modes")
    return None
