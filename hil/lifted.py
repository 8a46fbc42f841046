"""One control period of the HIL board's feedback path as one real product (a lifted system).

Without drift of the truth, amplifier rails or a ramp to zero, the board of
:mod:`modalctl.hil.board` and its structure are linear. The feed-forward and the sensor noise are
known before the shot, so their share of every reading is computed once, for the whole shot
(:func:`open_envelopes`); what the loops add depends on the commands only. Seen from each
carrier's own frame at the start of a period (the commands turned forward by the carrier's phase
there, ``rho_n = exp(j w n d / fs)``; the lock-in's state turned the same way), one period of
that share is the same linear map every period:

    [x_(n+1); y_n] = M [x_n; u_n; b_n]

with ``x`` the truth's complex mode states, the force at the period's last sample (the hold needs
it) and the lock-in filters' states; ``u`` and ``b`` the per-channel phasors of the last period
and of this one, turned by ``rho_n``; ``y`` the lock-in outputs at the period's end, which turned
back by ``rho_n`` and added to the open-loop share are the board's readings. ``M`` is built once
per shot by running one period sample by sample on a basis of states and inputs (the plainest
statement of the board's equations: the hold's recursion of :mod:`modalctl.propagate`, the
straight-line phasor ramp, the sensors' combinations and the lock-in's Butterworth at the sample
rate), so the readings agree with the board's sample-by-sample path to round-off (tested).
A period then costs one product instead of a dozen array operations on every sample.
"""

from __future__ import annotations

import numpy as np

from modalctl.lockin import LockIn, Oscillators

__all__ = ["PeriodMap", "open_envelopes"]


class PeriodMap:
    """The feedback path of one control period (``d`` samples) as a real matrix.

    Parameters
    ----------
    plant : BlockPlant
        The truth (its recursions' ``e, g0, g1``, residues, actuator and sensor gains).
    lockin : BlockLockIn
        The board's lock-in (its per-sample state space ``a, b, c, d``).
    carriers : ndarray, shape (k,)
        Hz.
    sensors : ndarray, shape (k, s)
        Each mode's combination of the sensors.
    channels : int
        Actuator channels a.
    samples : int
        Samples per period d.
    sample_rate : float
        Hz.
    """

    def __init__(self, plant, lockin, carriers, sensors, channels: int, samples: int, sample_rate: float):
        rec = plant.modes
        self.e, self.g0, self.g1 = rec.e, rec.g0, rec.g1
        self.gains = plant.model.actuator_gains  # (K, a)
        self.k, self.o, self.a, self.K = lockin.a.shape[0], lockin.a.shape[1], int(channels), self.e.size
        self.states = 3 * self.K + 2 * self.k * self.o
        self.steps = Oscillators(carriers, sample_rate).steps  # rad per sample
        self.samples = int(samples)
        self.matrix = self._build(plant.residues, np.asarray(sensors) @ plant.model.sensor_gains.T, lockin)
        # the product's input: the state, then both phasor sets as complex views (real and
        # imaginary parts interleaved), written in place
        self._input = np.zeros(self.matrix.shape[1])
        ak, n = self.a * self.k, self.states
        self._last = self._input[n:n + 2 * ak].view(complex).reshape(self.a, self.k)
        self._this = self._input[n + 2 * ak:].view(complex).reshape(self.a, self.k)

    def zero(self) -> np.ndarray:
        """The state at rest (real, ``states``)."""
        return np.zeros(self.states)

    def at_rest(self, first: np.ndarray) -> np.ndarray:
        """The state before the first sample when the first period's phasors are ``first`` (a, k):
        at rest at the first sample whatever its input, as the hold's recursion starts."""
        force = self.gains @ (first.sum(axis=1).real / self.samples)
        z = -(self.g0 + self.g1) * force / self.e
        x = self.zero()
        x[:self.K], x[self.K:2 * self.K], x[2 * self.K:3 * self.K] = z.real, z.imag, force
        return x

    def step(self, state: np.ndarray, last: np.ndarray, this: np.ndarray, turn: np.ndarray):
        """One period: ``state`` (real), the phasors of the last and this period (a, k) and each
        carrier's turn at the period's start (k,); returns the next state and the lock-in outputs at
        the period's end (k,), complex, still turned."""
        n = self.states
        self._input[:n] = state
        np.multiply(last, turn, out=self._last)
        np.multiply(this, turn, out=self._this)
        out = self.matrix @ self._input
        return out[:n], out[n:].view(complex)

    def _build(self, residues, reading, lockin) -> np.ndarray:
        """Run one period sample by sample on every basis vector of (state, last, this)."""
        K, k, o, a, d = self.K, self.k, self.o, self.a, self.samples
        n, ak = self.states, self.a * self.k
        basis = np.eye(n + 4 * ak)
        z = basis[:K] + 1j * basis[K:2 * K]
        force = basis[2 * K:3 * K]
        q = (basis[3 * K:3 * K + k * o] + 1j * basis[3 * K + k * o:n]).reshape(k, o, -1)
        last = (basis[n:n + 2 * ak:2] + 1j * basis[n + 1:n + 2 * ak:2]).reshape(a, k, -1)  # interleaved
        this = (basis[n + 2 * ak::2] + 1j * basis[n + 2 * ak + 1::2]).reshape(a, k, -1)
        e, g0, g1, r = self.e[:, None], self.g0[:, None], self.g1[:, None], residues[:, None]
        for i in range(d):
            carrier = np.exp(1j * self.steps * i)  # (k,)
            ramp = (i + 1) / d  # each phasor moves in a straight line from the last to this one
            volts = (carrier[None, None, :] @ (last * (1 - ramp) + this * ramp))[:, 0, :].real  # (a, columns)
            new = self.gains @ volts
            z = e * z + g0 * force + g1 * new
            force = new
            mixed = 2 * (reading @ (2 * (r * z).real)) * carrier.conj()[:, None]  # (k, columns)
            if i == d - 1:
                y = (lockin.c[:, None, :] @ q)[:, 0] + lockin.d[:, None] * mixed
            q = lockin.a @ q + lockin.b[:, :, None] * mixed[:, None, :]
        q = q * np.exp(1j * self.steps * d)[:, None, None]  # into the next period's frame
        q = q.reshape(k * o, -1)
        return np.vstack([z.real, z.imag, force, q.real, q.imag, np.stack([y.real, y.imag], axis=1).reshape(2 * k, -1)])


def open_envelopes(truth_plant, feedforward: np.ndarray, noise, sensors: np.ndarray, carriers, bandwidths,
                   sample_rate: float, samples: int, periods: int) -> np.ndarray:
    """The readings (k, periods) of the feed-forward and the noise alone, at each period's end.

    Parameters
    ----------
    truth_plant : Plant
        A fresh :class:`modalctl.propagate.Plant` of the truth.
    feedforward : ndarray, shape (a, N)
        V, N at least ``periods * samples``.
    noise : ndarray, shape (s, N) or None
        The sensors' noise (m/s).
    sensors : ndarray, shape (k, s)
    """
    end = periods * samples
    measured = truth_plant.sensors(truth_plant.simulate(feedforward[:, :end]))
    if noise is not None:
        measured = measured + noise[:, :end]
    phases = Oscillators(carriers, sample_rate).advance(end)
    return LockIn(bandwidths, sample_rate, samples, closing=True).process(sensors @ measured, phases)
