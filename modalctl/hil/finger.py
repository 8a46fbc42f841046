"""A finger on the surface: a local viscous damper, which couples the modes.

A damper ``c`` (N s/m) at grid point ``x0`` adds the modal damping matrix ``c phi(x0) phi(x0)^T``
(``phi`` mass-normalized, 1/sqrt(kg)): no longer diagonal, so the modes exchange energy and the
structure's modes become complex. :class:`FingerPlant` keeps it exact: the first-order system
``x' = A x + B u`` of all modes (displacements and velocities) is diagonalized once,
``A = V diag(lambda) V^-1``, and each eigen-coordinate is propagated by the same exact hold
discretization as :class:`modalctl.model.propagate.Plant`; the modal velocities are read back through ``V``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.loops.schedule import HOLD
from modalctl.model.modes import ModalModel, ModelError

from .block import Recursions, clip_rails

__all__ = ["Finger", "FingerPlant", "added_damping"]


@dataclass(frozen=True)
class Finger:
    """A touch: viscous ``damping`` (N s/m) at grid point ``index``."""

    index: int
    damping: float

    def matrix(self, model: ModalModel) -> np.ndarray:
        """The modal damping matrix it adds, shape (k, k), 1/s."""
        phi = model.shapes[:, self.index]
        return self.damping * np.outer(phi, phi)


def added_damping(model: ModalModel, finger: Finger) -> np.ndarray:
    """First-order added damping ratio of every mode, ``c phi_k(x0)^2 / (2 w_k)``, shape (k,)."""
    return np.diag(finger.matrix(model)) / (2 * model.omega)


class FingerPlant:
    """The truth with a finger on it, with the interface of :class:`modalctl.model.propagate.Plant`.

    Parameters
    ----------
    model : ModalModel
        The structure without the finger.
    finger : Finger
    sample_rate : float
        Hz.
    voltage_limit : float or None
        Amplifier rails (V).
    hold : {"zoh", "foh"}
        The DAC's hold (the board's by default).
    """

    def __init__(self, model: ModalModel, finger: Finger, sample_rate: float, voltage_limit: float | None = None,
                 hold: str = HOLD):
        k = model.n_modes
        damping = np.diag(2 * model.damping * model.omega) + finger.matrix(model)
        a = np.block([[np.zeros((k, k)), np.eye(k)], [-np.diag(model.omega ** 2), -damping]])
        self.values, self.vectors = np.linalg.eig(a)
        if np.any(self.values.real >= 0):
            raise ModelError("finger plant: the damped system is not stable")
        self.entry = np.linalg.solve(self.vectors, np.vstack([np.zeros((k, model.actuator_gains.shape[1])),
                                                              model.actuator_gains]))  # V^-1 B
        self.exit = self.vectors[k:]  # modal velocities from eigen-coordinates
        self.coordinates = Recursions(self.values, sample_rate, hold)
        self.model, self.finger, self.sample_rate, self.voltage_limit = model, finger, float(sample_rate), voltage_limit
        self.reset()

    def reset(self) -> None:
        self.coordinates.reset()
        self.clipped = 0

    def step(self, voltages: np.ndarray) -> np.ndarray:
        """Modal velocities (k, n) for the next chunk of voltages (a, n), V."""
        return (self.exit @ self.coordinates.run(self.entry @ clip_rails(self, voltages))).real

    def retune(self, frequencies, damping=None) -> None:
        raise ModelError("finger plant: a drifting truth under a finger is not supported; perturb the model first")

    def sensors(self, modal_velocity: np.ndarray) -> np.ndarray:
        return self.model.sensor_gains.T @ modal_velocity

    def field(self, modal_velocity: np.ndarray) -> np.ndarray:
        return self.model.shapes.T @ modal_velocity
