"""One control period of the HIL board's feedback path as one real product (a lifted system).

Without drift of the truth, amplifier rails or a ramp to zero, the board of
:mod:`modalctl.hil.phasor_board` and its structure are linear. The feed-forward and the sensor noise are
known before the shot, so their share of every reading is computed once, for the whole shot
(:meth:`~modalctl.hil.block.BlockLockIn.demodulate`); what the loops add depends on the commands
only. Seen from each carrier's own frame at the start of a period (the commands turned forward by
the carrier's phase there, ``rho_n = exp(j w n d / fs)``; the lock-in's state turned the same way),
one period of that share is the same linear map every period:

    [x_(n+1); y_n] = M [x_n; u_n; b_n]

with ``x`` the truth's complex mode states, the force at the period's last sample (the hold needs
it) and the lock-in filters' states; ``u`` and ``b`` the per-channel phasors of the last period
and of this one, turned by ``rho_n``; ``y`` the lock-in outputs at the period's end, which turned
back by ``rho_n`` and added to the open-loop share are the board's readings. ``M`` is built once
per shot from the board's equations over one period's samples (the hold's recursion of
:mod:`modalctl.model.propagate`, the straight-line phasor ramp, the sensors' combinations and the
lock-in's Butterworth at the sample rate), so the readings agree with the board's
sample-by-sample path to round-off (tested). A period then costs one product instead of a dozen
array operations on every sample. Phasors that are the dispatch's weights times per-mode commands
(every period the host writes) go through a smaller map, the weights folded in (``4 k`` phasor
columns instead of ``4 a k``); the per-channel map (a CAN board's rows) is built when first needed.
"""

from __future__ import annotations

import numpy as np

from modalctl.loops.lockin import Oscillators
from modalctl.loops.schedule import ramp_in

__all__ = ["PeriodMap"]


class PeriodMap:
    """The feedback path of one control period (``d`` samples) as a real matrix.

    Parameters
    ----------
    plant : BlockPlant
        The truth (its recursions' ``e, g0, g1``, residues, actuator and sensor gains).
    lockin : BlockLockIn
        The board's lock-in (its per-period form: the state after a period and the output at its
        last sample, from its state and from its inputs), built for ``samples`` samples a period.
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
    weights : ndarray, shape (a, k), optional
        The dispatch of each mode's command to the channels. With it, :meth:`step_commands` plays
        a period whose phasors are ``weights`` times per-mode commands by a matrix with ``4 k``
        phasor columns instead of ``4 a k`` (the same map, the weights folded in).
    """

    def __init__(self, plant, lockin, carriers, sensors, channels: int, samples: int, sample_rate: float,
                 weights: np.ndarray | None = None):
        if lockin.samples != samples:
            raise ValueError(f"period map: a lock-in built for {lockin.samples} samples a period, not {samples}")
        rec = plant.modes
        self.e, self.g0, self.g1 = rec.e, rec.g0, rec.g1
        self.gains = plant.model.actuator_gains  # (K, a)
        self.k, self.o, self.a, self.K = lockin.modes, lockin.order, int(channels), self.e.size
        self.states = 3 * self.K + 2 * self.k * self.o
        self.steps = Oscillators(carriers, sample_rate).steps  # rad per sample
        self.samples = int(samples)
        self._parts = (plant.residues, np.asarray(sensors) @ plant.model.sensor_gains.T, lockin)
        self._matrix = None
        if weights is not None:  # channel a's phasor of mode m is w = weights[a, m] times the command v:
            w = np.asarray(weights, complex)  # Re and Im of it are Re w Re v - Im w Im v, Im w Re v + Re w Im v
            as_real = np.stack([np.stack([w.real, w.imag], -1), np.stack([-w.imag, w.real], -1)], -2)  # (a, k, q, p)
            self.folded, self._folded_samples = self._build(
                *self._parts, np.einsum("ma,acqp->mcqp", self.gains, as_real)[:, None])
            self._folded_input = np.zeros(self.folded.shape[1])
            n, k2 = self.states, 2 * self.k
            self._last_command = self._folded_input[n:n + k2].view(complex)
            self._this_command = self._folded_input[n + k2:].view(complex)

    @property
    def matrix(self) -> np.ndarray:
        """The map for any per-channel phasors (built when first needed: the per-mode commands'
        :attr:`folded` map is the one a shot usually plays)."""
        return self._channels()[0]

    def _channels(self) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """The per-channel map and its velocities at the samples (see :meth:`_build`), built once."""
        if self._matrix is None:
            unit = np.eye(2)[None, None, None] * np.ones((1, 1, self.k, 1, 1))  # (1, 1, k, 2, 2)
            self._matrix, self._samples = self._build(*self._parts, self.gains[:, :, None, None, None] * unit)
            self._input = np.zeros(self._matrix.shape[1])
            ak, n = self.a * self.k, self.states
            self._last = self._input[n:n + 2 * ak].view(complex).reshape(self.a, self.k)
            self._this = self._input[n + 2 * ak:].view(complex).reshape(self.a, self.k)
        return self._matrix, self._samples

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

    def step(self, state: np.ndarray, last: np.ndarray, this: np.ndarray, turn: np.ndarray,
             keep: np.ndarray | None = None):
        """One period: ``state`` (real), the phasors of the last and this period (a, k) and each
        carrier's turn at the period's start (k,); returns the next state and the lock-in outputs at
        the period's end (k,), complex, still turned. ``keep``: a row (width) that receives the
        period's input vector, for :meth:`velocities`."""
        n, matrix = self.states, self.matrix
        self._input[:n] = state
        np.multiply(last, turn, out=self._last)
        np.multiply(this, turn, out=self._this)
        if keep is not None:
            keep[:] = self._input
        out = matrix @ self._input
        return out[:n], out[n:].view(complex)

    def step_commands(self, state: np.ndarray, last: np.ndarray, this: np.ndarray, turn: np.ndarray,
                      keep: np.ndarray | None = None):
        """As :meth:`step` for phasors that are the weights times per-mode commands: ``last`` and
        ``this`` are the commands (k,) of the last period and of this one."""
        n = self.states
        self._folded_input[:n] = state
        np.multiply(last, turn, out=self._last_command)
        np.multiply(this, turn, out=self._this_command)
        if keep is not None:
            keep[:] = self._folded_input
        out = self.folded @ self._folded_input
        return out[:n], out[n:].view(complex)

    def velocities(self, inputs: np.ndarray, commands: bool = True) -> np.ndarray:
        """The truth's modal velocities at every sample of periods played by the map from the inputs
        it multiplied, shape (K, P d) (m/s sqrt(kg), the share of the commands and of the state the
        periods started from).

        Parameters
        ----------
        inputs : ndarray, shape (P, width)
            Each period's input vector (the state and the turned phasors, as :meth:`step_commands`
            or :meth:`step` set them; a row of zeros for a period played by the other map).
        commands : bool
            The rows are the per-mode commands' map's (:attr:`folded`), else the per-channel map's.
        """
        from_state, from_phasors = self._folded_samples if commands else self._channels()[1]
        K, periods = self.K, inputs.shape[0]
        state = inputs[:, :3 * K].reshape(periods, 3, K).transpose(2, 0, 1)  # (K, P, 3)
        velocity = np.matmul(state, from_state)  # (K, P, d): each mode from its own state
        velocity += np.matmul(inputs[:, self.states:], from_phasors)  # (P, width - states) by (K, width - states, d)
        return velocity.reshape(K, periods * self.samples)

    def _build(self, residues, reading, lockin, drive) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray]]:
        """One period's response to every basis vector of (state, last, this), from the board's
        equations over the period's samples: the hold's recursion of each mode, the straight-line
        phasor ramp on the carriers, the sensors' combinations, the lock-in's Butterworth.
        Returns the map and the truth's velocities at each of the period's samples: from each
        mode's own state (K, 3, d) and from the phasor columns (K, width - states, d).

        ``drive`` (K, h, k, 2, 2) says how a unit input column (one of ``h`` channels, carrier c,
        real or imaginary part q) drives mode m through each force pattern's part p: ``G[m, a]``
        when q is p for per-channel phasors (``h = a``), the dispatch's weights folded in for
        per-mode commands (``h = 1``). A phasor's force depends on (this or last, carrier, part) only, so each mode is
        run once per such pattern (``4 k`` of them, one pass over the samples) rather than once per
        basis vector; the lock-in is linear and time-invariant per sample, so its state at the
        period's end is a sum over the samples with the powers of its matrix."""
        K, k, o, d, h = self.K, self.k, self.o, self.samples, drive.shape[1]
        n = self.states
        e, g0, g1, r = self.e, self.g0, self.g1, residues
        carrier = np.exp(1j * np.outer(np.arange(d), self.steps))  # (d, k), the carriers at each sample
        ramp = ramp_in(d)[:, None, None]
        # the force patterns (d, 2 (last, this), k, 2 (real, imaginary part of the phasor))
        unit = np.stack([carrier.real, -carrier.imag], axis=-1)  # Re(c), Re(j c)
        force = np.stack([(1 - ramp) * unit, ramp * unit], axis=1)
        flat = force.reshape(d, 1, 4 * k)
        # each mode's state after each sample, per unit force pattern: z_i = e z_(i-1) + g0 f_(i-1) + g1 f_i
        mode = g1[:, None] * flat + g0[:, None] * np.concatenate([np.zeros_like(flat[:1]), flat[:-1]])
        carried = np.empty(mode.shape[1:], complex)
        for i in range(1, d):
            mode[i] += np.multiply(e[:, None], mode[i - 1], out=carried)
        mode = mode.reshape(d, K, 2, k, 2)
        width = n + 4 * h * k  # the input columns: (which, channel, carrier, part) after the state
        mixed = np.zeros((k, d, width), complex)  # what each basis vector puts into each lock-in at each sample
        turn = 2 * carrier.T.conj()[:, :, None]  # (k, d, 1)
        after = e[None, :] ** (np.arange(d) + 1)[:, None]  # (d, K): a mode's own state after each sample
        shares = [2 * (r * after).real, -2 * (r * after).imag, 2 * (r * g0 * after / e).real]  # its velocity
        for column, share in enumerate(shares):
            mixed[:, :, column * K:(column + 1) * K] = turn * (reading[:, None, :] * share[None])
        answer = 2 * (r[None, :, None, None, None] * mode).real  # each mode's velocity, (d, K, 2, k, 2)
        from_state = np.stack(shares, axis=0).transpose(2, 0, 1).copy()  # (K, 3, d)
        # from_phasors[m, i, (w, h, c, q)] = sum_p drive[m, h, c, q, p] answer[i, m, w, c, p]: one product per (m, c)
        per_part = np.matmul(answer.transpose(1, 3, 0, 2, 4).reshape(K, k, 2 * d, 2),
                             drive.transpose(0, 2, 4, 1, 3).reshape(K, k, 2, 2 * h))  # (m, c, (i w), (h q))
        from_phasors = per_part.reshape(K, k, d, 2, h, 2).transpose(0, 3, 4, 1, 5, 2).reshape(K, width - n, d)
        # what each lock-in sees of each input column: sum over modes m and parts p, one product per carrier
        seen_by = np.einsum("lm,mhcqp->chlqmp", reading, drive).reshape(k, h * k * 2, K * 2)
        seen = np.matmul(seen_by, answer.transpose(3, 1, 4, 0, 2).reshape(k, K * 2, d * 2))  # (c, h l q, i w)
        seen = seen.reshape(k, h, k, 2, d, 2).transpose(2, 4, 5, 1, 0, 3)  # (l, i, w, h, c, q)
        mixed[:, :, n:] = turn * seen.reshape(k, d, width - n)
        # the lock-in, from the basis's own lock-in state: its state after the period's last sample
        # (rows :o) and its output at that sample (row o), one product of its per-period form
        q = np.matmul(lockin.from_inputs, mixed)  # (k, o + 1, width)
        for j in range(k):
            q[j, :, 3 * K + j * o:3 * K + (j + 1) * o] += lockin.from_state[j]
            q[j, :, 3 * K + (k + j) * o:3 * K + (k + j + 1) * o] += 1j * lockin.from_state[j]
        q, y = q[:, :o], q[:, o]
        q = (q * np.exp(1j * self.steps * d)[:, None, None]).reshape(k * o, width)  # into the next period's frame
        z_end = np.zeros((K, width), complex)
        z_end[:, :K] = np.diag(after[-1])
        z_end[:, K:2 * K] = np.diag(1j * after[-1])
        z_end[:, 2 * K:3 * K] = np.diag(g0 * after[-2] if d > 1 else g0)
        z_end[:, n:] = np.einsum("mhcqp,mwcp->mwhcq", drive, mode[-1]).reshape(K, width - n)
        force_end = np.zeros((K, width))
        force_end[:, n:] = np.einsum("mhcqp,wcp->mwhcq", drive, force[-1]).reshape(K, width - n)
        matrix = np.vstack([z_end.real, z_end.imag, force_end, q.real, q.imag,
                            np.stack([y.real, y.imag], axis=1).reshape(2 * k, -1)])
        return matrix, (from_state, from_phasors)
