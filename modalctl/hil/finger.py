"""A finger on the surface, played exactly: the truth with a touch (:mod:`modalctl.model.touch`)
that may land, slide, press harder and lift during the shot.

The touch couples the modes (a rank-one damping matrix, and stiffness and mass for a firm press),
so the structure's modes become complex. :class:`FingerPlant` keeps it exact: the first-order
system ``x' = A x + B u`` of all modes (:func:`~modalctl.model.touch.touched_system`) is
diagonalized, ``A = V diag(lambda) V^-1``, and each eigen-coordinate is propagated by the same
exact hold discretization as :class:`modalctl.model.propagate.Plant`; the modal velocities are read
back through ``V``. When the touch changes between two chunks, the physical state (displacements
and velocities) carries over into the new eigen-coordinates.
"""

from __future__ import annotations

from typing import Callable

import numpy as np

from modalctl.loops.schedule import HOLD
from modalctl.model.modes import ModalModel, ModelError
from modalctl.model.touch import Touch, touched_system

from .block import Recursions, clip_rails

__all__ = ["FingerPlant", "TouchPath"]

#: Where the touch is at time ``t`` (s) of the shot: a :class:`~modalctl.model.touch.Touch` or None.
TouchPath = Callable[[float], "Touch | None"]


class _Settled:
    """The touched system diagonalized: eigenvalues, ``V^-1 B``, the velocity rows of ``V``."""

    def __init__(self, model: ModalModel, touch: Touch | None, sample_rate: float, hold: str):
        a, b = touched_system(model, touch)
        self.values, self.vectors = np.linalg.eig(a)
        if np.any(self.values.real >= 0):
            raise ModelError("finger plant: the touched system is not stable")
        self.entry = np.linalg.solve(self.vectors, b)  # V^-1 B
        self.exit = self.vectors[model.n_modes:]  # modal velocities from eigen-coordinates
        self.coordinates = Recursions(self.values, sample_rate, hold)


class FingerPlant:
    """The truth with a finger on it, with the interface of :class:`modalctl.model.propagate.Plant`.

    Parameters
    ----------
    model : ModalModel
        The structure without the finger.
    touch : Touch, None or TouchPath
        The finger: resting all shot, absent, or where it is at each time (s) of the shot (a
        chunk plays the touch at its middle).
    sample_rate : float
        Hz.
    voltage_limit : float or None
        Amplifier rails (V).
    hold : {"zoh", "foh"}
        The DAC's hold (the board's by default).
    """

    CACHED = 64  # touches kept diagonalized (a finger lifting and landing again, a replayed shot)

    def __init__(self, model: ModalModel, touch, sample_rate: float, voltage_limit: float | None = None,
                 hold: str = HOLD):
        self.path: TouchPath = touch if callable(touch) else (lambda t, fixed=touch: fixed)
        self.model, self.sample_rate, self.voltage_limit, self.hold = model, float(sample_rate), voltage_limit, hold
        self._settled: dict = {}
        self.reset()

    def _settle(self, touch: Touch | None) -> _Settled:
        if touch not in self._settled:
            if len(self._settled) >= self.CACHED:
                self._settled.pop(next(iter(self._settled)))
            self._settled[touch] = _Settled(self.model, touch, self.sample_rate, self.hold)
        return self._settled[touch]

    @property
    def values(self) -> np.ndarray:
        """Eigenvalues (1/s) of the system as touched now, shape (2k,)."""
        return self._now.values

    def reset(self) -> None:
        self.sample, self.clipped = 0, 0
        self.touch = self.path(0.0)
        self._now = self._settle(self.touch)
        self._now.coordinates.reset()
        self._last = None  # the last voltages played (a,)

    def step(self, voltages: np.ndarray) -> np.ndarray:
        """Modal velocities (k, n) for the next chunk of voltages (a, n), V."""
        n = voltages.shape[1]
        touch = self.path((self.sample + n / 2) / self.sample_rate)
        if touch != self.touch:
            self._move(touch)
        u = clip_rails(self, voltages)
        now = self._now
        velocity = (now.exit @ now.coordinates.run(now.entry @ u)).real
        self.sample += n
        if n:
            self._last = u[:, -1]
        return velocity

    def _move(self, touch: Touch | None) -> None:
        """The finger moved, pressed or lifted: the same displacements and velocities, new eigen-coordinates."""
        old, new = self._now, self._settle(touch)
        if old.coordinates.last is None:  # at rest: nothing to carry
            new.coordinates.reset()
        else:
            state = (old.vectors @ old.coordinates.z).real
            new.coordinates.z = np.linalg.solve(new.vectors, state)
            new.coordinates.last = new.entry @ self._last
        self.touch, self._now = touch, new

    def retune(self, frequencies, damping=None) -> None:
        raise ModelError("finger plant: a drifting truth under a finger is not supported; perturb the model first")

    def sensors(self, modal_velocity: np.ndarray) -> np.ndarray:
        return self.model.sensor_gains.T @ modal_velocity

    def field(self, modal_velocity: np.ndarray) -> np.ndarray:
        return self.model.shapes.T @ modal_velocity
