"""The convex planner's columns and their exact responses: :class:`Basis` (the bump and hat
families, scaled to volts) and :class:`Responses` (every mode's state per unit of each column, by
the zero-order hold's recursion). The program built on them: :mod:`modalctl.plan.convex`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from modalctl.model.modes import ModalModel
from modalctl.model.propagate import hold_coefficients, poles
from modalctl.options import ConvexOptions

from .drive import BumpFamily, HatFamily, SplineDrive, hann, hat

__all__ = ["Basis", "Responses"]


@dataclass(frozen=True, eq=False)
class Basis:
    """The program's columns: bump families (each kept mode, real and imaginary parts) then hats
    (each channel), all scaled to volts.

    Attributes
    ----------
    bumps : tuple of BumpFamily
    hats : HatFamily or None
    omega : ndarray, shape (m,)
        The kept modes' carriers (rad/s).
    weights : ndarray, shape (a, m)
        Dispatch: volts per unit modal force of each kept mode on each actuator.
    scale : ndarray, shape (n,)
        Modal force (or volts) per unit of each column: one unit is one volt on the channel the
        column drives hardest.
    """

    bumps: tuple
    hats: HatFamily | None
    omega: np.ndarray
    weights: np.ndarray
    scale: np.ndarray

    @classmethod
    def build(cls, omega, weights, samples: int, focus: int, sample_rate: float, options: ConvexOptions) -> Basis:
        """Bumps every ``early`` until ``late_window`` before T_F (sample ``focus``) and every
        ``late`` after, from the shot's first sample; hats every ``hat`` around T_F."""
        def span(spacing):
            return max(2, int(round(spacing * sample_rate)))

        late_start = max(0, focus - int(round(options.late_window * sample_rate)))
        early, late = span(options.early), span(options.late)
        families = []
        if late_start > 0:
            families.append(BumpFamily(np.arange(0, late_start, early), 2 * early))
        first = max(0, late_start - late)
        families.append(BumpFamily(np.arange(first, samples, late), 2 * late))
        half = max(2, int(round(options.hat * sample_rate)))
        start = max(0, focus - int(round(options.hat_before * sample_rate)) - (half - 1))
        stop = min(samples, focus + int(round(options.hat_after * sample_rate)))
        hats = HatFamily(np.arange(start, stop, half), half) if stop > start else None
        strongest = np.abs(weights).max(axis=0)  # (m,) volts per unit force on the hardest-driven channel
        scale = [np.repeat(1 / strongest, f.offsets.size * 2) for f in families]
        if hats is not None:
            scale.append(np.ones(weights.shape[0] * hats.offsets.size))
        return cls(tuple(families), hats, np.asarray(omega, float), np.asarray(weights, float),
                   np.concatenate(scale))

    @property
    def size(self) -> int:
        return self.scale.size

    def drive(self, x: np.ndarray, focus_time: float, sample_rate: float) -> SplineDrive:
        """The drive the (volt-scaled) columns ``x`` make."""
        c = x * self.scale
        envelope, pos = [], 0
        m = self.omega.size
        for family in self.bumps:
            n = m * family.offsets.size * 2
            block = c[pos:pos + n].reshape(m, family.offsets.size, 2)
            envelope.append(block[..., 0] + 1j * block[..., 1])
            pos += n
        volts = None if self.hats is None else c[pos:].reshape(self.weights.shape[0], self.hats.offsets.size)
        return SplineDrive(self.omega, focus_time, sample_rate, tuple(self.bumps), tuple(envelope), self.hats, volts)

    def energy(self, sample_rate: float) -> np.ndarray:
        """Each column's own energy on the actuators, relative to the largest, shape (n,)."""
        parts = []
        spread = np.sum(self.weights ** 2, axis=0) / np.abs(self.weights).max(axis=0) ** 2  # (m,)
        for family in self.bumps:
            own = 0.5 * np.sum(hann(family.width) ** 2) * spread
            parts.append(np.repeat(own, family.offsets.size * 2))
        if self.hats is not None:
            parts.append(np.full(self.weights.shape[0] * self.hats.offsets.size, np.sum(hat(self.hats.half) ** 2)))
        energy = np.concatenate(parts)
        return energy / energy.max()

    def voltage_rows(self, channel: int, samples: np.ndarray, sample_rate: float, focus_time: float) -> np.ndarray:
        """``d v_channel(n) / d x`` at each of ``samples``, shape (len(samples), n)."""
        samples = np.atleast_1d(samples)
        blocks = []
        for family in self.bumps:
            proto = family.prototypes(self.omega, sample_rate)  # (m, width)
            phase = family.phases(self.omega, sample_rate, focus_time)  # (m, j)
            lag = samples[:, None] - family.offsets[None, :]  # (s, j)
            inside = (lag >= 0) & (lag < family.width)
            values = np.where(inside[None], proto[:, np.clip(lag, 0, family.width - 1)], 0) * phase[:, None, :]
            per_mode = self.weights[channel][:, None, None] * values  # (m, s, j)
            blocks.append(np.stack([per_mode.real, -per_mode.imag], axis=-1).transpose(1, 0, 2, 3)
                          .reshape(samples.size, -1))
        if self.hats is not None:
            shape = hat(self.hats.half)
            lag = samples[:, None] - self.hats.offsets[None, :]
            inside = (lag >= 0) & (lag < shape.size)
            row = np.zeros((samples.size, self.weights.shape[0], self.hats.offsets.size))
            row[:, channel, :] = np.where(inside, shape[np.clip(lag, 0, shape.size - 1)], 0)
            blocks.append(row.reshape(samples.size, -1))
        return np.hstack(blocks) * self.scale


class Responses:
    """Every mode's exact response to the basis, on one model (the zero-order hold's recursion).

    For each family's prototype input ``P`` (complex for the carriers' bumps), the partial-fraction
    states of every mode (``z[n] = e z[n-1] + g0 u[n-1]``, velocity ``2 Re(r z)``, displacement
    ``2 Re(q z)``, as :class:`modalctl.model.propagate.Plant`) are tabulated over the prototype's
    support for its real and imaginary parts; after the support they decay as ``e^n``.

    Parameters
    ----------
    model : ModalModel
        The plant (its frequencies and damping may be a drifted copy of the planned model's).
    basis : Basis
    sample_rate, focus_time : float
    """

    def __init__(self, model: ModalModel, basis: Basis, sample_rate: float, focus_time: float):
        p = poles(model)
        self.e, g0, _ = hold_coefficients(p, 1 / sample_rate, "zoh")
        self.g0 = g0
        self.r, self.q = p / (p - p.conj()), 1 / (p - p.conj())
        self.basis, self.model = basis, model
        gains = model.actuator_gains
        self.mode_gain = gains @ basis.weights  # (K, m): force on each mode per unit force of each kept mode
        self.gains = gains  # (K, a)
        self.tables = []
        for family in basis.bumps:
            proto = family.prototypes(basis.omega, sample_rate)
            self.tables.append((family, family.phases(basis.omega, sample_rate, focus_time), self._table(g0, proto)))
        self.hat_table = None
        if basis.hats is not None:
            self.hat_table = self._table(g0, hat(basis.hats.half)[None, :].astype(complex))

    def _table(self, g0, proto: np.ndarray):
        """States after 0..L samples of each prototype row, for its real and imaginary parts:
        two arrays (K, C, L + 1) complex."""
        pad = np.zeros((proto.shape[0], 1))
        states = []
        for part in (proto.real, proto.imag):
            table = np.empty((self.e.size, proto.shape[0], proto.shape[1] + 1), complex)
            for k in range(self.e.size):
                table[k] = lfilter([0, g0[k]], [1, -self.e[k]], np.hstack([part, pad]), axis=1)
            states.append(table)
        return states

    def _at(self, table, lag: np.ndarray):
        """The tabulated states at lags ``lag`` (j,) from each copy's first sample, decayed past the
        support; zero before it. Two arrays (K, C, j)."""
        re, im = table
        length = re.shape[2] - 1
        out = [np.zeros(re.shape[:2] + (lag.size,), complex) for _ in range(2)]
        inside = (lag >= 0) & (lag <= length)
        after = lag > length
        decay = self.e[:, None] ** (lag[after] - length)[None, :] if after.any() else None
        for o, t in zip(out, (re, im)):
            o[:, :, inside] = t[:, :, lag[inside]]
            if decay is not None:
                o[:, :, after] = t[:, :, -1][:, :, None] * decay[:, None, :]
        return out

    def states(self, n: int) -> np.ndarray:
        """Every mode's state at sample ``n`` per unit of each column, shape (K, columns) complex."""
        blocks = []
        for family, phase, table in self.tables:
            z_re, z_im = self._at(table, n - family.offsets)  # (K, m, j)
            # a column (a, b) drives Re{(a + j b) phase P}: a -> Re(phase) Re P - Im(phase) Im P, b -> -(...)
            za = (phase.real * z_re - phase.imag * z_im) * self.mode_gain[:, :, None]
            zb = -(phase.real * z_im + phase.imag * z_re) * self.mode_gain[:, :, None]
            blocks.append(np.stack([za, zb], axis=-1).reshape(self.e.size, -1))
        if self.hat_table is not None:
            z_re, _ = self._at(self.hat_table, n - self.basis.hats.offsets)  # (K, 1, j)
            blocks.append((self.gains[:, :, None] * z_re[:, 0][:, None, :]).reshape(self.e.size, -1))
        return np.hstack(blocks) * self.basis.scale

    def driven(self, volts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every mode's velocity and displacement at samples 0..N under ``volts`` (a, N) from rest,
        by the same recursion: two arrays (K, N + 1)."""
        force = np.hstack([self.gains @ volts, np.zeros((self.gains.shape[0], 1))])
        z = np.stack([lfilter([0, g], [1, -e], f) for g, e, f in zip(self.g0, self.e, force)])
        return 2 * (self.r[:, None] * z).real, 2 * (self.q[:, None] * z).real

    def velocity(self, n: int) -> np.ndarray:
        """Every mode's velocity at sample ``n`` per unit of each column, shape (K, columns)."""
        return 2 * (self.r[:, None] * self.states(n)).real

    def displacement(self, n: int) -> np.ndarray:
        """Every mode's displacement at sample ``n`` per unit of each column, shape (K, columns)."""
        return 2 * (self.q[:, None] * self.states(n)).real
