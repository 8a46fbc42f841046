"""The convex planner's columns and their exact responses: :class:`Basis` (the bump and hat
families, scaled to volts) and :class:`Responses` (every mode's state per unit of each column, by
the zero-order hold's recursion). Where the margin is checked is :mod:`.convex_cover`; the program
built on them, :mod:`modalctl.plan.convex`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from modalctl.model.modes import ModalModel
from modalctl.model.propagate import hold_coefficients, poles
from modalctl.options import ConvexOptions

from .drive import BumpFamily, HatFamily, SplineDrive, hann, hat

__all__ = ["Basis", "Responses", "hat_spacing", "HAT_SLACK"]

STRIDE = 32  # lags between the states a response table keeps, at least
TABLE_BYTES = 2**27  # a response table's states, at most (the stride doubles until they fit)
ROW_ENTRIES = 2**21  # margin rows made at once: their modes' decays (K, rows, lags), complex, at most (32 MB)


HAT_SLACK = 1.5  # the hats' Nyquist frequency may pass the model's highest mode by this factor (hat_spacing)


def hat_spacing(hat: float, band: float) -> float:
    """The hats' spacing (s): ``hat``, or the Nyquist interval ``1 / (2 band)`` of the model's highest
    mode (``band``, Hz) when the hats' Nyquist frequency ``1 / (2 hat)`` passes it by more than :data:`HAT_SLACK`.

    Hats spaced ``h`` apart are the straight-line interpolation of voltage samples every ``h``: they
    carry a drive up to ``1 / (2 h)``, and far finer than the model's band needs they put their content
    where the model holds no mode and cannot say what it excites. On plate-glass (21 modes up to 12.0
    kHz, its 30 mm Gaussian at (20, 10) mm, the default closed loop's plan, 40 dB, four noise seeds) the
    default 20 us hats put 3.9e-2 of the drive's energy above its highest mode and measured margin 0.479
    on the model's own truth but **0.873** on a truth with twice its modes (modes 38 and 40, 20.3-20.4
    kHz, rang at the focus; `benchmarks/spillover.py`); at its Nyquist interval (41.8 us) 0.492 and
    0.501; at 27.9 us (1.5x) still 0.660. Within the slack the hats stay: the tablet panel's 254 modes
    to 19.9 kHz, its 30 mm bump, 20 us hats: 1.7e-4 of the drive's energy above 19.9 kHz, and at its
    Nyquist interval (25.1 us) the plan took 100 s instead of 52. Growing plate-glass's model to the
    hats' band instead (48 modes to 24.8 kHz, 20 us hats) held 0.472-0.487 on its own and richer truths
    but lost the closed loop to drift (+1%: margin 0.53 -> 0.59; +2%: the supervisor stopped the shot
    at tau 0.09, where the 21 modes ran to 0.65): its added loops' modes drift past their lock-ins."""
    nyquist = 1 / (2 * float(hat))
    return 1 / (2 * band) if 0 < band and nyquist > HAT_SLACK * band else float(hat)


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
    def build(cls, omega, weights, samples: int, focus: int, sample_rate: float, options: ConvexOptions,
              band: float = np.inf) -> Basis:
        """Bumps every ``early`` until ``late_window`` before T_F (sample ``focus``) and every
        ``late`` after, from the shot's first sample; hats every ``hat`` around T_F, or every
        ``1 / (2 band)`` when that is longer (:func:`hat_spacing`; ``band``: the model's highest mode, Hz)."""
        def span(spacing):
            return max(2, int(round(spacing * sample_rate)))

        late_start = max(0, focus - int(round(options.late_window * sample_rate)))
        early, late = span(options.early), span(options.late)
        families = []
        if late_start > 0:
            families.append(BumpFamily(np.arange(0, late_start, early), 2 * early))
        first = max(0, late_start - late)
        families.append(BumpFamily(np.arange(first, samples, late), 2 * late))
        half = max(2, int(round(hat_spacing(options.hat, band) * sample_rate)))
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
            phase = family.phases(self.omega, sample_rate, focus_time)  # (m, j)
            lag = samples[:, None] - family.offsets[None, :]  # (s, j)
            at, copy = np.nonzero((lag >= 0) & (lag < family.width))  # the bumps the samples are on: a few
            values = np.zeros((self.omega.size,) + lag.shape, complex)
            n = lag[at, copy] + 0.5  # the prototype, as BumpFamily.prototypes, there only
            values[:, at, copy] = (hann(family.width)[lag[at, copy]][None, :]
                                   * np.exp(1j * self.omega[:, None] * n[None, :] / sample_rate)) * phase[:, copy]
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


class _Table:
    """Every mode's states after each lag of one family's prototypes (C rows, for their real and
    imaginary parts), kept every :data:`STRIDE` lags (or a power of two times more, to keep them
    within :data:`TABLE_BYTES`): ``z(l) = e^r z(l0) + g0 sum_{s<r} e^(r-1-s) P(l0 + s)`` from the
    last one kept, ``l0 = l - r``, one small product. The whole recursion's states took 9 GB on 256
    modes and 193 prototypes. Past the prototypes' support the states decay as ``e^l``.

    Parameters
    ----------
    e, g0 : ndarray, shape (K,)
        The zero-order hold's recursion ``z[n] = e z[n-1] + g0 u[n-1]`` of every mode.
    proto : ndarray, shape (C, L)
    """

    def __init__(self, e: np.ndarray, g0: np.ndarray, proto: np.ndarray):
        self.e, self.g0 = np.asarray(e, complex), np.asarray(g0, complex)
        self.log_e = np.log(self.e)
        proto = np.atleast_2d(np.asarray(proto, complex))
        size = 32 * self.e.size * proto.shape[0] * proto.shape[1]  # bytes of the states every lag
        self.stride = stride = STRIDE * 2 ** max(0, int(np.ceil(np.log2(size / STRIDE / TABLE_BYTES))))
        blocks = -(-proto.shape[1] // stride)
        self.end = blocks * stride  # the last state kept: the input is zero from L on
        self.inputs = np.zeros((2, self.end, proto.shape[0]))  # (part, lag, C)
        self.inputs[0, :proto.shape[1]] = proto.real.T
        self.inputs[1, :proto.shape[1]] = proto.imag.T
        self.powers = self.e[:, None] ** np.arange(stride + 1)  # (K, stride + 1)
        weights = self.powers[:, stride - 1::-1] * self.g0[:, None]  # (K, stride): g0 e^(stride-1-s)
        self.kept = np.zeros((2, blocks + 1, self.e.size, proto.shape[0]), complex)  # (part, block, K, C)
        for b in range(blocks):
            for part in range(2):
                step = weights @ self.inputs[part, b * stride:(b + 1) * stride]
                self.kept[part, b + 1] = self.powers[:, stride, None] * self.kept[part, b] + step

    def at(self, lag: np.ndarray) -> list:
        """The states at lags ``lag`` (j,), zero before the first: two arrays (K, C, j)."""
        lag = np.asarray(lag, int)
        shape = (self.e.size, self.kept.shape[3], lag.size)
        out = [np.zeros(shape, complex), np.zeros(shape, complex)]
        after = np.flatnonzero(lag >= self.end)
        if after.size:
            decay = self._decay(lag[after])
            for part in range(2):
                out[part][:, :, after] = self.kept[part, -1][:, :, None] * decay[:, None, :]
        within = np.flatnonzero((lag >= 0) & (lag < self.end))
        for part in range(2):
            if within.size:
                out[part][:, :, within] = self._within(part, lag[within]).transpose(1, 2, 0)
        return out

    def contracted(self, lag: np.ndarray, weights: np.ndarray, gain: np.ndarray) -> list:
        """``sum_k weights[l, k] gain[k, c] z_kc(lag_lj)`` for each part: two arrays (l, c, j), the
        states of :meth:`at` contracted over the modes before they are spread over the lags (not the
        ``K C j`` array :meth:`at` makes, which a margin row at one point and sample took a
        millisecond to fill). ``lag`` (j,), or (l, j): each row's own (a round's margin rows, each
        at its own sample). Past the support, each row's weights times its lags' free decay (K, l j)
        go through one product by BLAS with the last states kept times the gains: made a row at a
        time, the panel's closed-loop rows took 0.8 s of its 6 s plan. ``gain`` (K, c): c = C, or
        any with one prototype (C = 1)."""
        lag = np.broadcast_to(np.asarray(lag, int), (weights.shape[0], np.shape(lag)[-1]))
        (rows, lags), k = lag.shape, self.e.size
        out = [np.zeros((rows, gain.shape[1], lags), complex) for _ in range(2)]
        after = lag >= self.end
        if after.any():
            decay = np.exp(self.log_e[:, None, None] * np.where(after, lag - self.end, 0)[None])  # (K, l, j)
            decay *= weights.T[:, :, None] * after[None]
            for part in range(2):
                spread = (gain * self.kept[part, -1]).T @ decay.reshape(k, rows * lags)  # (c, l j)
                out[part] += spread.reshape(-1, rows, lags).transpose(1, 0, 2)
        at, lagged = np.nonzero((lag >= 0) & (lag < self.end))
        pairs = max(1, ROW_ENTRIES // (k * self.stride))  # at once: their powers (K, pairs, stride)
        for first in range(0, at.size, pairs):
            row, column = at[first:first + pairs], lagged[first:first + pairs]
            for part, within in enumerate(self._contracted_within(lag[row, column], weights[row], gain)):
                out[part][row, :, column] = within
        return out

    def _contracted_within(self, lag: np.ndarray, weights: np.ndarray, gain: np.ndarray) -> list:
        """``sum_k weights[p, k] gain[k, c] z_kc(lag_p)`` at lags ``lag`` (p,) within the support, for
        each part: two arrays (p, c). The recursion of :meth:`_within`, the inputs' share contracted as
        one product by BLAS, the weighted powers (p stride, K) by the gains (a product a lag took twice
        the time)."""
        block, decay, powers, since = self._since_kept(lag)
        powers *= (self.g0[:, None] * weights.T)[:, :, None]
        spread = (powers.reshape(self.e.size, -1).T @ gain).reshape(lag.size, self.stride, -1)  # (p, stride, c)
        decayed = weights * decay  # (p, K): the weights on e^r z(l0)
        return [(spread * self.inputs[part][since]).sum(axis=1)
                + np.einsum("pk,pkc->pc", decayed, self.kept[part, block] * gain) for part in range(2)]

    def _since_kept(self, lag: np.ndarray) -> tuple:
        """What the states at lags ``lag`` (p,) within the support take from the last state kept before
        each, ``l0 = lag - r`` (:meth:`_within`): its block (p,), ``e^r`` (p, K), the powers
        ``e^(r-1-s)`` on the inputs since it (K, p, stride; zero from ``s = r``) and those inputs' lags
        (p, stride)."""
        block, r = np.divmod(lag, self.stride)
        steps = np.arange(self.stride)
        back = r[:, None] - 1 - steps[None, :]  # (p, stride): the power on each input since l0, < 0 past r
        powers = np.where(back >= 0, self.powers[:, np.maximum(back, 0)], 0)
        return block, self.powers[:, r].T, powers, block[:, None] * self.stride + steps[None, :]

    def _decay(self, lag: np.ndarray) -> np.ndarray:
        """``e^(lag - end)`` (K, j): the states' free decay after the prototypes' support (as an
        exponential: numpy's complex power took a third of the rows' time)."""
        return np.exp(self.log_e[:, None] * (lag - self.end)[None, :])

    def _within(self, part: int, lag: np.ndarray) -> np.ndarray:
        """The states (p, K, C) at lags ``lag`` (p,) within the support, from the last state kept before
        each, ``l0 = lag - r``: ``z(l) = e^r z(l0) + g0 sum_{s<r} e^(r-1-s) P(l0 + s)``, one short
        product each (:meth:`_since_kept`)."""
        block, decay, powers, since = self._since_kept(lag)
        return decay[:, :, None] * self.kept[part, block] + self.g0[:, None] * (powers.transpose(1, 0, 2)
                                                                               @ self.inputs[part][since])


class Responses:
    """Every mode's exact response to the basis, on one model (the zero-order hold's recursion).

    For each family's prototype input ``P`` (complex for the carriers' bumps), the partial-fraction
    states of every mode (``z[n] = e z[n-1] + g0 u[n-1]``, velocity ``2 Re(r z)``, displacement
    ``2 Re(q z)``, as :class:`modalctl.model.propagate.Plant`) are tabulated over the prototype's
    support for its real and imaginary parts (every :data:`STRIDE` lags, the rest one short product
    away: :class:`_Table`); after the support they decay as ``e^n``.

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
        self._rgain = 2 * self.r[:, None] * self.mode_gain  # (K, m): velocity's 2 Re(r .) with each mode's gain
        self.tables = []
        for family in basis.bumps:
            proto = family.prototypes(basis.omega, sample_rate)
            self.tables.append((family, family.phases(basis.omega, sample_rate, focus_time), _Table(self.e, g0, proto)))
        self.hat_table = None
        if basis.hats is not None:
            self.hat_table = _Table(self.e, g0, hat(basis.hats.half)[None, :].astype(complex))

    def states(self, n: int) -> np.ndarray:
        """Every mode's state at sample ``n`` per unit of each column, shape (K, columns) complex."""
        blocks = []
        for family, phase, table in self.tables:
            z_re, z_im = table.at(n - family.offsets)  # (K, m, j)
            # a column (a, b) drives Re{(a + j b) phase P}: a -> Re(phase) Re P - Im(phase) Im P, b -> -(...)
            za = (phase.real * z_re - phase.imag * z_im) * self.mode_gain[:, :, None]
            zb = -(phase.real * z_im + phase.imag * z_re) * self.mode_gain[:, :, None]
            blocks.append(np.stack([za, zb], axis=-1).reshape(self.e.size, -1))
        if self.hat_table is not None:
            z_re, _ = self.hat_table.at(n - self.basis.hats.offsets)  # (K, 1, j)
            blocks.append((self.gains[:, :, None] * z_re[:, 0][:, None, :]).reshape(self.e.size, -1))
        return np.hstack(blocks) * self.basis.scale

    def driven(self, volts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Every mode's velocity and displacement at samples 0..N under ``volts`` (a, N) from rest,
        by the same recursion: two arrays (K, N + 1)."""
        force = np.hstack([self.gains @ volts, np.zeros((self.gains.shape[0], 1))])
        z = np.stack([lfilter([0, g], [1, -e], f) for g, e, f in zip(self.g0, self.e, force)])
        return 2 * (self.r[:, None] * z).real, 2 * (self.q[:, None] * z).real

    def velocity(self, n: int) -> np.ndarray:
        """Every mode's velocity at sample ``n`` per unit of each column, shape (K, columns):
        ``2 Re(r z)`` of :meth:`states`, made family by family into one array."""
        return self.rows(n, None)

    def rows(self, n, weights: np.ndarray | None) -> np.ndarray:
        """``weights @ velocity(n)``, shape (l, columns), for ``weights`` (l, K) (the mode shapes at
        l points: the margin rows there, per unit of each column), ``n`` a sample or each row's own
        (l,); None: :meth:`velocity`. The states are contracted over the modes before they are
        spread over the columns (:meth:`_Table.contracted`): the panel's rows, a point or two at each
        sample, 1.1 -> 0.1 ms a sample."""
        at_once = max(1, ROW_ENTRIES // (self.e.size * max(len(f.offsets) for f, _, _ in self.tables)))
        if weights is not None and weights.shape[0] > at_once:
            n = np.broadcast_to(np.asarray(n, int), weights.shape[:1])
            return np.vstack([self.rows(n[i:i + at_once], weights[i:i + at_once])
                              for i in range(0, weights.shape[0], at_once)])
        out = np.empty((self.e.size if weights is None else weights.shape[0], self.basis.size))
        n = np.asarray(n, int)[..., None]  # a sample against each column's offset, per row when given per row
        first = 0
        for family, phase, table in self.tables:
            z_re, z_im = _contracted(table, n - family.offsets, self._rgain, weights)  # (l, m, j)
            a, b = z_re.real, z_im.real  # Re(2 r g z) for the prototype's real part, and its imaginary part
            cols = out[:, first:first + 2 * a.shape[1] * a.shape[2]].reshape(a.shape + (2,))
            np.subtract(phase.real * a, phase.imag * b, out=cols[..., 0])  # Re{(1) phase P}, as states()
            np.add(phase.real * b, phase.imag * a, out=cols[..., 1])  # Re{(j) phase P}, negated below
            np.negative(cols[..., 1], out=cols[..., 1])
            first += 2 * a.shape[1] * a.shape[2]
        if self.hat_table is not None:
            z_re, _ = _contracted(self.hat_table, n - self.basis.hats.offsets, 2 * self.r[:, None] * self.gains,
                                  weights)  # (l, a, j): each channel's hats
            out[:, first:] = z_re.real.reshape(out.shape[0], -1)
        out *= self.basis.scale
        return out

    def displacement(self, n: int) -> np.ndarray:
        """Every mode's displacement at sample ``n`` per unit of each column, shape (K, columns)."""
        return 2 * (self.q[:, None] * self.states(n)).real


def _contracted(table: _Table, lag: np.ndarray, gain: np.ndarray, weights: np.ndarray | None) -> list:
    """``sum_k weights[l, k] gain[k, c] z_kc(lag_j)`` of ``table``'s states, each part (l, c, j);
    ``weights`` None: ``gain[k, c] z_kc(lag_j)`` (K, c, j). A table of one prototype serves every
    column of ``gain`` (the hats: one per channel)."""
    if weights is None:
        return [gain[:, :, None] * z for z in table.at(lag)]
    return table.contracted(lag, np.asarray(weights, float), gain)
