"""Share each mode's drive among the actuators and check that modes stay decoupled (Eq 2.30).

Mode j answers a drive ``f(t) = Re{F e^{s t}}`` with the velocity ``Re{H_j(s) F e^{s t}}``,
``H_j(s) = s / (s^2 + 2 zeta_j w_j s + w_j^2)``. Mode k's drive has the complex frequency
``s_k = kappa_k zeta_k w_k + j w_k``, so the leakage of mode k's drive into mode j, relative to
what it does to mode k itself, is ``|H_j(s_k) b_j . g_k| / |H_k(s_k) b_k . g_k|`` for the
actuator weights ``g_k``. That single number is the thesis's decoupling condition made
quantitative: it is small when the envelope is slow next to the spacing of the modes, or when
the actuators cancel mode j's share.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np

from modalctl.model.modes import ModalModel

__all__ = ["DecouplingWarning", "mobility", "dispatch", "Decoupling", "decoupling"]


class DecouplingWarning(UserWarning):
    """A mode's envelope is too fast for the spacing to a neighbour (Eq 2.30 does not hold)."""


def mobility(s, omega, zeta):
    """Velocity per unit modal force ``s / (s^2 + 2 zeta w s + w^2)`` (broadcasting)."""
    return s / (s**2 + 2 * zeta * omega * s + omega**2)


def _exponents(model: ModalModel, modes, kappa):
    w, z = model.omega[modes], model.damping[modes]
    return np.asarray(kappa, float) * z * w + 1j * w


def dispatch(model: ModalModel, modes, kappa=1.0, cancel: float = 100.0) -> np.ndarray:
    """Actuator weights that drive each kept mode and spare its neighbours.

    For kept mode k, the weights ``g`` minimize ``|g|^2 |b_k|^2 + cancel * sum_j (w_jk b_j . g)^2``
    subject to ``b_k . g = 1``, where ``b_j`` is mode j's row of actuator gains and
    ``w_jk = |H_j(s_k)| / |H_k(s_k)|`` weighs how strongly mode j answers mode k's carrier
    (every other mode of the model, kept or not). With one actuator this is ``1 / alpha_k``;
    with as many actuators as significant neighbours it cancels them.

    Parameters
    ----------
    model : ModalModel
    modes : sequence of int
        Kept modes (positional indices).
    kappa : float or array_like
        Envelope rates of the kept modes.
    cancel : float
        Weight of cancellation against drive norm.

    Returns
    -------
    ndarray, shape (a, m)
        Volts on each actuator per unit modal force of each kept mode (V s^2 sqrt(kg) / m).
    """
    modes = np.asarray(modes, int)
    b = model.actuator_gains
    s = _exponents(model, modes, np.broadcast_to(kappa, modes.shape))
    weights = np.empty((b.shape[1], modes.size))
    for i, k in enumerate(modes):
        own = np.abs(mobility(s[i], model.omega[k], model.damping[k]))
        w = np.abs(mobility(s[i], model.omega, model.damping)) / own
        w[k] = 0.0
        bk = b[k]
        if not np.any(bk):
            raise ValueError(f"mode {model.labels[k]}: no actuator drives it (all gains zero)")
        m = np.eye(b.shape[1]) * (bk @ bk) + cancel * (b.T * w**2) @ b
        x = np.linalg.solve(m, bk)
        weights[:, i] = x / (bk @ x)
    return weights


@dataclass(frozen=True)
class Decoupling:
    """Leakage of each kept mode's drive into every mode of the model.

    Attributes
    ----------
    leakage : ndarray, shape (k_model, m)
        ``|H_j(s_k) b_j . g_k| / |H_k(s_k) b_k . g_k|`` (0 on the driven mode itself).
    spurious : ndarray, shape (k_model, m)
        Leakage times ``|c_k|`` over the largest ``|c|``: the velocity each drive puts in mode j,
        relative to the strongest target.
    worst : tuple
        ``(j, k, value)`` of the largest spurious share (positional model indices).
    """

    leakage: np.ndarray
    spurious: np.ndarray
    worst: tuple


def decoupling(model: ModalModel, modes, kappa, weights, targets, threshold: float = 0.1,
               warn: bool = True) -> Decoupling:
    """Quantify Eq 2.30 for a plan and warn when a drive leaks more than ``threshold``."""
    modes = np.asarray(modes, int)
    s = _exponents(model, modes, np.broadcast_to(kappa, modes.shape))
    h = mobility(s[None, :], model.omega[:, None], model.damping[:, None])  # (k_model, m)
    forces = model.actuator_gains @ weights  # (k_model, m)
    response = np.abs(h * forces)
    own = response[modes, np.arange(modes.size)]
    leakage = response / own
    leakage[modes, np.arange(modes.size)] = 0.0
    spurious = leakage * np.abs(targets)[None, :] / np.max(np.abs(targets))
    j, k = np.unravel_index(np.argmax(spurious), spurious.shape)
    worst = (int(j), int(modes[k]), float(spurious[j, k]))
    if warn and worst[2] > threshold:
        warnings.warn(f"mode {model.labels[worst[1]]}'s envelope leaks {100 * worst[2]:.0f}% of the strongest "
                      f"target into mode {model.labels[worst[0]]} (Eq 2.30): slow its envelope (smaller kappa) "
                      f"or add actuators that can cancel it", DecouplingWarning, stacklevel=2)
    return Decoupling(leakage, spurious, worst)
