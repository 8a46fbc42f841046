"""The board's truth and lock-in one control period at a time, exactly, as a few matrix products.

The HIL board plays the plant in chunks of one control period (``d`` samples). Run sample by
sample (``lfilter``, ``sosfilt``) that costs one call per mode per period; here each period is
one batched product with precomputed powers of each recursion, exact to round-off:

* :class:`Recursions`: each row's ``z[n] = e z[n-1] + g0 f[n-1] + g1 f[n]`` (the exact hold
  discretization of :mod:`modalctl.model.propagate`) over ``b`` samples is ``z = e^(1..b) z_prev + T h``,
  ``T[i, j] = e^(i - j)`` for ``i >= j``. :class:`BlockPlant` runs the modes with it (velocities
  ``2 Re(r z)``); the finger's plant runs its eigen-coordinates with it. Retuning keeps each mode's
  displacement and velocity continuous, like :meth:`modalctl.model.propagate.Plant.retune`.
* :class:`BlockLockIn`: each mode's Butterworth as a state space ``x' = A x + B m``, ``y = C x + D m``
  at the sample rate; a period needs only its last output and the next state.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import numpy as np

from modalctl.loops.lockin import lowpass
from modalctl.model.modes import ModalModel
from modalctl.model.propagate import hold_coefficients, phasors_of, poles

__all__ = ["Recursions", "BlockPlant", "BlockLockIn", "clip_rails"]


class _Kernels:
    """The products that advance a block of ``b`` samples (see :class:`Recursions`)."""

    def __init__(self, e: np.ndarray, g0: np.ndarray, g1: np.ndarray, b: int):
        i, j = np.arange(b)[:, None], np.arange(b + 1)[None, :]  # state i of a block, input j of its window

        def power(lag):
            return np.where(lag >= 0, e[:, None, None] ** np.maximum(lag, 0), 0)

        window = g0[:, None, None] * power(i - j) + g1[:, None, None] * np.where(j >= 1, power(i + 1 - j), 0)
        self.window = np.ascontiguousarray(window.transpose(0, 2, 1))  # (k, b + 1, b), for complex inputs
        self.carry = e[:, None, None] ** np.arange(1, b + 1)  # e^(i + 1), (k, 1, b)
        # For real inputs, one real product: inputs (the window's samples, then the real and imaginary
        # parts of the state before the block), outputs each state's real and imaginary parts
        # interleaved, so that the result is read as complex without a copy.
        carry = self.carry[:, 0, :]
        full = np.concatenate([window, carry[:, :, None], 1j * carry[:, :, None]], axis=2)  # (k, b, b + 3)
        self.real = np.ascontiguousarray(
            np.stack([full.real, full.imag], axis=2).reshape(full.shape[0], 2 * b, b + 3).transpose(0, 2, 1))
        self.ends = np.ascontiguousarray(np.stack([window[:, -1].real, window[:, -1].imag], axis=2))  # (k, b + 1, 2)


class Recursions:
    """Exact first-order complex recursions ``z' = p z + f`` under a sampled, held input, one per
    row, advanced a chunk at a time by products with precomputed powers.

    A chunk of up to ``SINGLE`` samples (a control period, usually) is one block: one batched
    product of its samples (with the one before it, for the hold) and its starting state gives
    every state, ``M[i, j] = g0 e^(i - j) + g1 e^(i + 1 - j)`` and ``e^(i + 1)``. A longer chunk is
    cut into blocks of ``SUB`` samples: one product gives every block's states from rest, the states
    carried from block to block are themselves a recursion, in ``e^SUB``, solved by one more product
    (``U[b, c] = e^(SUB (b - c))``), and each block adds ``e^(i + 1)`` times the state before it. A
    few array operations per chunk, whatever its length (up to ``BLOCKS`` blocks per product).

    Parameters
    ----------
    poles : ndarray, shape (k,)
        Complex poles (1/s).
    sample_rate : float
        Hz.
    hold : {"zoh", "foh"}
    """

    SUB = 16  # samples per block: the product's cost per sample grows with it
    BLOCKS = 32  # blocks per product: the carry's matrix grows with its square
    SINGLE = 64  # chunks up to this long are one block

    def __init__(self, poles: np.ndarray, sample_rate: float, hold: str):
        self.e, self.g0, self.g1 = hold_coefficients(poles, 1 / sample_rate, hold)
        self._kernels: dict[int, _Kernels] = {}
        self._carries = None  # (U, e^(SUB (b + 1))) for chunks of several blocks, made when first needed
        self.reset()

    def carries(self) -> tuple[np.ndarray, np.ndarray]:
        """``U[b, c] = e^(SUB (b - c))`` (k, BLOCKS, BLOCKS) and ``e^(SUB (b + 1))`` (k, BLOCKS)."""
        if self._carries is None:
            big = self.e[:, None] ** (self.SUB * np.arange(self.BLOCKS + 1))  # e^(SUB m), (k, BLOCKS + 1)
            lag = np.arange(self.BLOCKS)[:, None] - np.arange(self.BLOCKS)[None, :]
            self._carries = np.where(lag >= 0, big[:, np.maximum(lag, 0)], 0), big[:, 1:]
        return self._carries

    def reset(self) -> None:
        self.z = np.zeros(self.e.size, complex)
        self.last = None  # the input before the first sample: the system starts at rest

    def kernels(self, b: int) -> _Kernels:
        if b not in self._kernels:
            self._kernels[b] = _Kernels(self.e, self.g0, self.g1, b)
        return self._kernels[b]

    def run(self, force: np.ndarray) -> np.ndarray:
        """States (k, n) at the samples of the next chunk of inputs ``force`` (k, n)."""
        k, n = force.shape
        if not n:
            return np.zeros((k, 0), complex)
        if self.last is None:  # at rest at the first sample: z[0] = e z + (g0 + g1) f[0] = 0
            self.last, self.z = force[:, 0], -(self.g0 + self.g1) * force[:, 0] / self.e
        if n <= self.SINGLE:
            return self._chunk(force, n)
        z = np.empty((k, n), complex)
        step = self.SUB * self.BLOCKS
        for i in range(0, n, step):
            z[:, i:i + step] = self._chunk(force[:, i:i + step], self.SUB)
        return z

    def _chunk(self, force: np.ndarray, b: int) -> np.ndarray:
        """States over at most ``b * BLOCKS`` samples of ``force`` in blocks of ``b``, from ``self.z``
        and ``self.last``."""
        k, n = force.shape
        kernels = self.kernels(b)
        nb = -(-n // b)
        real = not np.iscomplexobj(force)
        windows = np.zeros((k, nb, b + 3 if real else b + 1), force.dtype)  # each block's samples after the
        flat = np.zeros((k, nb * b), force.dtype)                         # one before it (then its state)
        flat[:, :n] = force
        windows[:, :, 1:b + 1] = flat.reshape(k, nb, b)
        windows[:, 0, 0] = self.last
        windows[:, 1:, 0] = windows[:, :-1, b]
        if nb == 1:
            before = self.z[:, None]
        else:
            if real:
                ends = np.matmul(windows[:, :, :b + 1], kernels.ends)  # each block's last state from rest
                ends = ends[:, :, 0] + 1j * ends[:, :, 1]
            else:
                local = np.matmul(windows, kernels.window)  # each block's states from rest, (k, nb, b)
                ends = local[:, :, -1]
            between, from_start = self.carries()
            after = np.matmul(between[:, :nb, :nb], ends[:, :, None])[:, :, 0] \
                + from_start[:, :nb] * self.z[:, None]  # the state after each block, (k, nb)
            before = np.concatenate([self.z[:, None], after[:, :-1]], axis=1)
        if real:
            windows[:, :, b + 1], windows[:, :, b + 2] = before.real, before.imag
            z = np.matmul(windows, kernels.real).view(complex)
        else:
            local = local if nb > 1 else np.matmul(windows, kernels.window)
            z = local + kernels.carry * before[:, :, None]
        z = z.reshape(k, nb * b)[:, :n]
        self.z, self.last = z[:, -1], force[:, -1]
        return z


def clip_rails(plant, voltages: np.ndarray) -> np.ndarray:
    """``voltages`` (a, n) clipped to ``plant.voltage_limit``, counted in ``plant.clipped``."""
    u = np.atleast_2d(np.asarray(voltages, float))
    if plant.voltage_limit is not None:
        plant.clipped += int(np.count_nonzero(np.abs(u) > plant.voltage_limit))
        u = np.clip(u, -plant.voltage_limit, plant.voltage_limit)
    return u


class BlockPlant:
    """The modal truth propagated a chunk at a time (the interface of :class:`modalctl.model.propagate.Plant`).

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


def _biquad(section: np.ndarray):
    """State space ``(A, B, C, D)`` of one second-order section ``[b0 b1 b2 a0 a1 a2]``, in the
    controllable canonical form of scipy's ``tf2ss``, whose normalization would drop numerator
    coefficients below 1e-14 as zeros (a narrow corner's: 4e-15 at 80 Hz and 1 MHz) and the
    filter's gain and delay with them."""
    b0, b1, b2, a1, a2 = np.asarray(section[[0, 1, 2, 4, 5]], float) / section[3]
    return (np.array([[-a1, -a2], [1.0, 0.0]]), np.array([[1.0], [0.0]]),
            np.array([[b1 - a1 * b0, b2 - a2 * b0]]), np.array([[b0]]))


def _cascade(sos: np.ndarray):
    """State space ``(A, B, C, D)`` of second-order sections in series, section by section (a single
    polynomial's companion form loses digits when the poles crowd near 1)."""
    a_, b_, c_, d_ = np.zeros((0, 0)), np.zeros((0, 1)), np.zeros((1, 0)), np.ones((1, 1))
    for section in sos:
        a2, b2, c2, d2 = _biquad(section)
        n1, n2 = a_.shape[0], a2.shape[0]
        a_ = np.block([[a_, np.zeros((n1, n2))], [b2 @ c_, a2]])
        b_ = np.vstack([b_, b2 @ d_])
        c_ = np.hstack([d2 @ c_, c2])
        d_ = d2 @ d_
    return a_, b_, c_, d_


def first_order(poles: np.ndarray, kicks: np.ndarray) -> np.ndarray:
    """``x[..., p] = poles x[..., p - 1] + kicks[..., p]`` from rest along the last axis of ``kicks``
    (..., P), ``poles`` (...) one per row: every row at once by doubling (after the step of span
    ``s`` each ``x[..., p]`` sums the last ``2 s`` kicks), ``log2 P`` array operations instead of
    one ``lfilter`` call per row (~40 us each, beside which a row of a few hundred periods is nothing)."""
    x, power, span = np.array(kicks), np.asarray(poles)[..., None], 1
    while span < x.shape[-1]:
        x[..., span:] += power * x[..., :-span]  # the product is made before the sum is stored
        power, span = power * power, 2 * span
    return x


@lru_cache(maxsize=256)
def _lowpass_state_space(order: int, bandwidth: float, sample_rate: float):
    """:func:`_cascade` of the lock-in's low-pass, made once per (order, corner, rate) and kept
    read-only (every shot of a sweep builds the same filters)."""
    matrices = _cascade(lowpass(order, bandwidth, sample_rate))
    for m in matrices:
        m.setflags(write=False)
    return matrices


class BlockLockIn:
    """Per-mode lock-in that returns the envelope at the last sample of each period.

    Same filter and scaling as :class:`modalctl.loops.lockin.LockIn` with ``closing=True``.

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
        mats = [_lowpass_state_space(int(order), float(b), float(sample_rate)) for b in np.atleast_1d(bandwidths)]
        a = np.array([m[0] for m in mats])  # (k, o, o)
        b = np.array([m[1][:, 0] for m in mats])  # (k, o)
        c = np.array([m[2][0] for m in mats])  # (k, o)
        d = np.array([m[3][0, 0] for m in mats])  # (k,)
        self.modes, self.order = a.shape[0], a.shape[1]
        powers = [np.broadcast_to(np.eye(order), a.shape)]
        for _ in range(samples):
            powers.append(a @ powers[-1])
        powers = np.array(powers)  # (d + 1, k, o, o)
        # x_d = A^d x_0 + sum_j A^(d-1-j) B m_j ;  y_(d-1) = C A^(d-1) x_0 + sum_(j<d-1) C A^(d-2-j) B m_j + D m_(d-1)
        inputs = np.einsum("jkab,kb->kaj", powers[samples - 1::-1], b)  # (k, o, d)
        read_state = np.einsum("ka,kab->kb", c, powers[samples - 1])
        read_inputs = np.concatenate([np.einsum("ka,kaj->kj", c, inputs[:, :, 1:]),  # C A^(d-2-j) B, j < d-1
                                      d[:, None]], axis=1)  # (k, d)
        # one product a period: the next state and the output together, rows (o states, 1 output)
        self.from_state = np.concatenate([powers[samples], read_state[:, None, :]], axis=1).astype(complex)
        self.from_inputs = np.concatenate([inputs, read_inputs[:, None, :]], axis=1).astype(complex)
        # A^d = V diag(poles) V^-1 per mode (the Butterworth's poles are distinct), for :meth:`demodulate`
        self._poles, vectors = np.linalg.eig(self.from_state[:, :-1])
        self._to_poles = np.linalg.inv(vectors).transpose(0, 2, 1)  # right-multiplies a row of states
        self._read_poles = np.einsum("ka,kab->kb", self.from_state[:, -1], vectors)  # C A^(d-1) V (k, o)
        self.samples = int(samples)
        self.reset()

    def reset(self) -> None:
        """Filters at rest."""
        self.state = np.zeros((self.modes, self.order), complex)

    def process(self, signals: np.ndarray, phases: np.ndarray) -> np.ndarray:
        """Envelope (k,) complex at the last of ``samples`` samples of ``signals`` (k, d) mixed with ``phases``."""
        return self.filter(2 * signals * np.exp(-1j * phases))

    def demodulate(self, signals: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """The outputs (k, P) at the last sample of each period of the real ``signals`` (k, P d)
        mixed with twice the conjugate of carriers of ``steps`` (k,) rad a sample starting at
        phase 0, from rest; the filters' own state is left as it is (a pure function).

        Period p's carriers are its start's phasor times one period's table, so its pushes on the
        filters are the signals times one real matrix (the mixing folded into the per-period input
        map), turned back by that phasor: one batched real product for every period at once. The
        state then runs from period to period in the eigenvectors of each mode's ``A^d`` (the
        Butterworth's poles are distinct), one first-order recursion per pole, all at once
        (:func:`first_order`)."""
        k, n = signals.shape
        d = self.samples
        p = n // d
        weights = 2 * np.exp(-1j * steps[:, None] * np.arange(d))[:, :, None] * self.from_inputs.transpose(0, 2, 1)
        parts = np.matmul(signals[:, :p * d].reshape(k, p, d), np.concatenate([weights.real, weights.imag], axis=2))
        o = self.order
        starts = np.exp(-1j * np.mod(steps[:, None] * d * np.arange(p), 2 * np.pi))  # (k, P)
        pushed = (parts[:, :, :o + 1] + 1j * parts[:, :, o + 1:]) * starts[:, :, None]  # (k, P, o + 1)
        kicks = np.matmul(pushed[:, :, :-1], self._to_poles)  # (k, P, o), in V's coordinates
        # the state after each period
        after = first_order(self._poles, kicks.transpose(0, 2, 1)).transpose(0, 2, 1)  # in V's coordinates
        before = np.concatenate([np.zeros_like(after[:, :1]), after[:, :-1]], axis=1)  # at each period's start
        return np.matmul(before, self._read_poles[:, :, None])[:, :, 0] + pushed[:, :, -1]

    def filter(self, mixed: np.ndarray) -> np.ndarray:
        """The low-pass of already mixed signals (k, d): the output at the last sample, complex (k,)."""
        both = (np.matmul(self.from_state, self.state[:, :, None])
                + np.matmul(self.from_inputs, mixed[:, :, None]))[:, :, 0]  # (k, o + 1)
        self.state = both[:, :-1]
        return both[:, -1]
