"""The board's truth and lock-in one control period at a time, exactly, as a few matrix products.

The HIL board plays the plant in chunks of one control period (``d`` samples). Run sample by
sample (``lfilter``, ``sosfilt``) that costs one call per mode per period; here each period is
one batched product with precomputed powers of each recursion, exact to round-off:

* :class:`Recursions`: each row's ``z[n] = e z[n-1] + g0 f[n-1] + g1 f[n]`` (the exact hold
  discretization of :mod:`modalctl.propagate`) over ``b`` samples is ``z = e^(1..b) z_prev + T h``,
  ``T[i, j] = e^(i - j)`` for ``i >= j``. :class:`BlockPlant` runs the modes with it (velocities
  ``2 Re(r z)``); the finger's plant runs its eigen-coordinates with it. Retuning keeps each mode's
  displacement and velocity continuous, like :meth:`modalctl.propagate.Plant.retune`.
* :class:`BlockLockIn`: each mode's Butterworth as a state space ``x' = A x + B m``, ``y = C x + D m``
  at the sample rate; a period needs only its last output and the next state.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from scipy.signal import butter, tf2ss

from modalctl.model import ModalModel
from modalctl.propagate import hold_coefficients, phasors_of, poles

__all__ = ["Recursions", "BlockPlant", "BlockLockIn", "clip_rails"]


class Recursions:
    """Exact first-order complex recursions ``z' = p z + f`` under a sampled, held input, one per
    row, advanced a chunk at a time by products with precomputed powers (``SUB`` samples each).

    Parameters
    ----------
    poles : ndarray, shape (k,)
        Complex poles (1/s).
    sample_rate : float
        Hz.
    hold : {"zoh", "foh"}
    """

    SUB = 16  # samples per product: the cost grows with its square, the Python overhead with their number

    def __init__(self, poles: np.ndarray, sample_rate: float, hold: str):
        self.e, self.g0, self.g1 = hold_coefficients(poles, 1 / sample_rate, hold)
        powers = self.e[:, None] ** np.arange(self.SUB + 1)  # (k, b + 1)
        lag = np.arange(self.SUB)[:, None] - np.arange(self.SUB)[None, :]
        self.toeplitz = np.where(lag >= 0, powers[:, np.maximum(lag, 0)], 0)  # (k, b, b)
        self.carry = powers[:, 1:]  # e^(i + 1), (k, b)
        self.reset()

    def reset(self) -> None:
        self.z = np.zeros(self.e.size, complex)
        self.last = None  # the input before the first sample: the system starts at rest

    def run(self, force: np.ndarray) -> np.ndarray:
        """States (k, n) at the samples of the next chunk of inputs ``force`` (k, n)."""
        n = force.shape[1]
        previous = np.concatenate([(force[:, :1] if self.last is None else self.last[:, None]), force[:, :-1]], axis=1)
        drive = self.g0[:, None] * previous + self.g1[:, None] * force
        if self.last is None and n:
            drive[:, 0] = 0  # the state at the first sample is zero, as in Plant
        z = np.empty(drive.shape, complex)
        state, b = self.z, self.SUB
        for i in range(0, n, b):
            m = min(b, n - i)
            z[:, i:i + m] = self.carry[:, :m] * state[:, None] + \
                np.matmul(self.toeplitz[:, :m, :m], drive[:, i:i + m, None])[:, :, 0]
            state = z[:, i + m - 1]
        if n:
            self.z, self.last = state, force[:, -1]
        return z


def clip_rails(plant, voltages: np.ndarray) -> np.ndarray:
    """``voltages`` (a, n) clipped to ``plant.voltage_limit``, counted in ``plant.clipped``."""
    u = np.atleast_2d(np.asarray(voltages, float))
    if plant.voltage_limit is not None:
        plant.clipped += int(np.count_nonzero(np.abs(u) > plant.voltage_limit))
        u = np.clip(u, -plant.voltage_limit, plant.voltage_limit)
    return u


class BlockPlant:
    """The modal truth propagated a chunk at a time (the interface of :class:`modalctl.propagate.Plant`).

    Parameters
    ----------
    model : ModalModel
    sample_rate : float
        Hz.
    hold : {"zoh", "foh"}
    voltage_limit : float or None
        Amplifier rails (V).
    """

    def __init__(self, model: ModalModel, sample_rate: float, hold: str = "foh", voltage_limit: float | None = None):
        self.sample_rate, self.hold, self.voltage_limit = float(sample_rate), hold, voltage_limit
        self._set(model)
        self.reset()

    def _set(self, model: ModalModel) -> None:
        self.model = model
        self.poles = poles(model)
        self.residues = self.poles / (self.poles - self.poles.conj())
        self.modes = Recursions(self.poles, self.sample_rate, self.hold)

    def reset(self) -> None:
        self.modes.reset()
        self.clipped = 0

    def step(self, voltages: np.ndarray) -> np.ndarray:
        """Modal velocities (k, n) for the next chunk of voltages (a, n), V."""
        z = self.modes.run(self.model.actuator_gains @ clip_rails(self, voltages))
        return 2 * (self.residues[:, None] * z).real

    def modal_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Displacement and velocity of every mode after the last sample, shapes (k,), (k,)."""
        q = 1 / (self.poles - self.poles.conj())
        z = self.modes.z
        return 2 * (z * q).real, 2 * (z * q * self.poles).real

    def retune(self, frequencies, damping=None) -> None:
        """New resonances (Hz) and damping between two steps, displacement and velocity continuous."""
        displacement, velocity = self.modal_state()
        last = self.modes.last
        damping = self.model.damping if damping is None else np.asarray(damping, float)
        self._set(replace(self.model, frequencies=np.asarray(frequencies, float), damping=damping))
        self.modes.z, self.modes.last = phasors_of(self.poles, displacement, velocity), last

    def sensors(self, modal_velocity: np.ndarray) -> np.ndarray:
        return self.model.sensor_gains.T @ modal_velocity

    def field(self, modal_velocity: np.ndarray) -> np.ndarray:
        return self.model.shapes.T @ modal_velocity


def _cascade(sos: np.ndarray):
    """State space ``(A, B, C, D)`` of second-order sections in series, section by section (a single
    polynomial's companion form loses digits when the poles crowd near 1)."""
    a_, b_, c_, d_ = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1))
    for section in sos:
        a2, b2, c2, d2 = tf2ss(section[:3], section[3:])
        n1, n2 = a_.shape[0], a2.shape[0]
        a_ = np.block([[a_, np.zeros((n1, n2))], [b2 @ c_, a2]])
        b_ = np.vstack([b_, b2 @ d_])
        c_ = np.hstack([d2 @ c_, c2])
        d_ = d2 @ d_
    return a_, b_, c_, d_


class BlockLockIn:
    """Per-mode lock-in that returns the envelope at the last sample of each period.

    Same filter and scaling as :class:`modalctl.lockin.LockIn` with ``closing=True``.

    Parameters
    ----------
    bandwidths : array_like, shape (k,)
        Hz.
    sample_rate : float
        Hz.
    samples : int
        Samples per period.
    order : int
    """

    def __init__(self, bandwidths, sample_rate: float, samples: int, order: int = 4):
        mats = [_cascade(butter(order, b, fs=sample_rate, output="sos")) for b in np.atleast_1d(bandwidths)]
        a = np.array([m[0] for m in mats])  # (k, o, o)
        b = np.array([m[1][:, 0] for m in mats])  # (k, o)
        c = np.array([m[2][0] for m in mats])  # (k, o)
        d = np.array([m[3][0, 0] for m in mats])  # (k,)
        powers = [np.broadcast_to(np.eye(order), a.shape)]
        for _ in range(samples):
            powers.append(a @ powers[-1])
        powers = np.array(powers)  # (d + 1, k, o, o)
        # x_d = A^d x_0 + sum_j A^(d-1-j) B m_j ;  y_(d-1) = C A^(d-1) x_0 + sum_(j<d-1) C A^(d-2-j) B m_j + D m_(d-1)
        self.advance = powers[samples]
        self.inputs = np.einsum("jkab,kb->kaj", powers[samples - 1::-1], b)  # (k, o, d)
        self.read_state = np.einsum("ka,kab->kb", c, powers[samples - 1])
        read_inputs = np.einsum("ka,kaj->kj", c, self.inputs[:, :, 1:])  # C A^(d-2-j) B for j < d-1
        self.read_inputs = np.concatenate([read_inputs, d[:, None]], axis=1)  # (k, d)
        self.samples = int(samples)
        self.state = np.zeros((a.shape[0], order), complex)

    def process(self, signals: np.ndarray, phases: np.ndarray) -> np.ndarray:
        """Envelope (k,) complex at the last of ``samples`` samples of ``signals`` (k, d) mixed with ``phases``."""
        return self.filter(2 * signals * np.exp(-1j * phases))

    def filter(self, mixed: np.ndarray) -> np.ndarray:
        """The low-pass of already mixed signals (k, d): the output at the last sample, complex (k,)."""
        out = np.einsum("kb,kb->k", self.read_state, self.state) + np.einsum("kj,kj->k", self.read_inputs, mixed)
        self.state = np.einsum("kab,kb->ka", self.advance, self.state) + np.einsum("kaj,kj->ka", self.inputs, mixed)
        return out
