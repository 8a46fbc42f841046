"""The convex planner's columns and their exact responses: :class:`Basis` (the bump and hat
families, scaled to volts) and :class:`Responses` (every mode's state per unit of each column, by
the zero-order hold's recursion); and where the margin is checked: :class:`Cover` (the off-target
points as nested boxes, each with a proven bound on the field over its points, so that the field
is computed only where the margin may be at stake). The program built on them:
:mod:`modalctl.plan.convex`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import lfilter

from modalctl.model.modes import ModalModel
from modalctl.model.propagate import hold_coefficients, poles
from modalctl.options import ConvexOptions

from .drive import BumpFamily, HatFamily, SplineDrive, hann, hat

__all__ = ["Basis", "Responses", "Cover", "hat_spacing", "HAT_SLACK"]

LEAF = 16  # points in a cover's smallest boxes at most: where the bound is not enough, their field, exactly
SPLITS = 3  # halvings from a box to its children (eight children)
CHUNK = 4096  # samples of the field's bound at once (its memory: the boxes' few rows times this)
SLACK = 1e-10  # the bound's allowance for round-off, relative to sum_k max_i |phi_k(x_i)| |eta'_k|
STRIDE = 32  # lags between the states a response table keeps, at least
TABLE_BYTES = 2**27  # a response table's states, at most (the stride doubles until they fit)


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
        for j in np.flatnonzero((lag >= 0) & (lag < self.end)):
            for part in range(2):
                out[part][:, :, j] = self._within(part, int(lag[j]))
        return out

    def contracted(self, lag: np.ndarray, coefficients: np.ndarray) -> list:
        """``sum_k coefficients[l, k, c] z_kc(lag_j)`` for each part: two arrays (l, c, j), the
        states of :meth:`at` contracted over the modes before they are spread over the lags (the
        free decay's as one product by BLAS: ``l c K j`` operations, not the ``K C j`` array
        :meth:`at` makes, which a margin row at one point and sample took a millisecond to fill).
        ``coefficients`` (l, K, c): c = C, or any with one prototype (C = 1)."""
        lag = np.asarray(lag, int)
        shape = (coefficients.shape[0], coefficients.shape[2], lag.size)
        out = [np.zeros(shape, complex), np.zeros(shape, complex)]
        after = np.flatnonzero(lag >= self.end)
        if after.size:
            decay = self._decay(lag[after])
            for part in range(2):
                out[part][:, :, after] = (coefficients * self.kept[part, -1]).transpose(0, 2, 1) @ decay
        for j in np.flatnonzero((lag >= 0) & (lag < self.end)):
            for part in range(2):
                out[part][:, :, j] = (coefficients * self._within(part, int(lag[j]))).sum(axis=1)
        return out

    def _decay(self, lag: np.ndarray) -> np.ndarray:
        """``e^(lag - end)`` (K, j): the states' free decay after the prototypes' support (as an
        exponential: numpy's complex power took a third of the rows' time)."""
        return np.exp(self.log_e[:, None] * (lag - self.end)[None, :])

    def _within(self, part: int, lag: int) -> np.ndarray:
        """The states (K, C) at ``lag`` within the support: from the last kept, one short product."""
        block, r = divmod(lag, self.stride)
        z = self.powers[:, r, None] * self.kept[part, block]
        if r:
            inputs = self.inputs[part, block * self.stride:block * self.stride + r]  # (r, C)
            z = z + self.g0[:, None] * (self.powers[:, r - 1::-1] @ inputs)
        return z


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

    def rows(self, n: int, weights: np.ndarray | None) -> np.ndarray:
        """``weights @ velocity(n)``, shape (l, columns), for ``weights`` (l, K) (the mode shapes at
        l points: the margin rows there, per unit of each column); None: :meth:`velocity`. The
        states are contracted over the modes before they are spread over the columns
        (:meth:`_Table.contracted`): the panel's rows, a point or two at each sample, 1.1 -> 0.1 ms
        a sample."""
        out = np.empty((self.e.size if weights is None else weights.shape[0], self.basis.size))
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
    return table.contracted(lag, np.asarray(weights, float)[:, :, None] * gain[None])


@dataclass(eq=False)
class _Box:
    """Points ``start:stop`` of a :class:`Cover`'s order, and what bounds the field on each of its
    children: the affine fits' rows ``fit`` ((1 + d) c, K: every child's value at the centre of its
    points' span, then its slope along each axis times the span's half-width) and their largest
    residuals ``residual`` (c, K)."""

    start: int
    stop: int
    children: tuple = ()
    fit: np.ndarray | None = None
    residual: np.ndarray | None = None

    def bounds(self, velocity: np.ndarray, speed: np.ndarray) -> np.ndarray:
        """Each child's bound on ``|w|`` over its points at each column of ``velocity`` (K, s)
        (``speed``: its absolute value), shape (c, s): ``|A| + sum_d |B_d| h_d + R . speed``, the affine
        part's largest size over the span (centre ``A``, each axis's slope times half-width ``B_d h_d``:
        one product and an absolute value, the rows folded so when the box was built)."""
        c = len(self.children)
        y = np.abs(self.fit @ velocity).reshape(-1, c, velocity.shape[1])
        return y.sum(axis=0) + self.residual @ speed


class Cover:
    """The off-target grid points as nested boxes, with a bound on the field over each box's points
    that is proven, not sampled.

    A box (its points halved at the median along its longer side, three times over to its eight
    children, down to :data:`LEAF` points) fits every mode affinely over its own points,
    ``phi_k(x_i) = a_k + b_k . (x_i - x_B) + r_ik``, and keeps ``R_k = max_i |r_ik|`` over them
    and the span ``[low, high]`` of ``x_i - x_B``. At a sample with modal velocities ``eta'_k``,
    with ``A = sum_k a_k eta'_k`` and ``B = sum_k b_k eta'_k``, every point ``i`` of the box has

        ``|w(x_i)| = |A + B . (x_i - x_B) + sum_k r_ik eta'_k|
                   <= max(A + max_d B . d, -(A + min_d B . d)) + sum_k R_k |eta'_k|``

    (``d`` over the span: the affine part's extremes are at its corners). The whole set's bound
    is ``sum_k max_i |phi_k(x_i)| |eta'_k|``. **What it guarantees**: for every off-target grid
    point and every sample, ``|w(x_i, t_n)|`` is at most the bound of every box that holds the
    point (the residuals and spans are the points' own, so nothing is assumed about the modes'
    smoothness; :data:`SLACK` of the whole set's bound is added for round-off). It says nothing
    of the surface between grid points, which the model does not describe. A search goes down
    the boxes only where their bound exceeds the level asked, at the samples where it does; the
    field is computed, by BLAS, only on the smallest boxes reached, at those samples: on a panel of
    8,000 off-target points a few per cent of the points-by-samples the whole grid would take.

    Parameters
    ----------
    shapes : ndarray, shape (K, n)
        Every mode's value at each of the points.
    points : ndarray, shape (n, d)
        Their coordinates (m), d = 1 or 2.
    leaf : int
    """

    def __init__(self, shapes: np.ndarray, points: np.ndarray, leaf: int = LEAF):
        shapes, points = np.asarray(shapes, float), np.asarray(points, float)
        points = points[:, None] if points.ndim == 1 else points
        self.leaf = int(leaf)
        self.reach = np.abs(shapes).max(axis=1) if shapes.size else np.zeros(shapes.shape[0])  # (K,)
        order = []
        self.root = self._build(np.arange(shapes.shape[1]), shapes, points, order)
        self.order = np.concatenate([o[0] for o in order]) if order else np.zeros(0, int)  # position -> point
        self.values = np.ascontiguousarray(shapes[:, self.order].T)  # (n, K), each box's points contiguous
        self.neighbours = _neighbours(points)  # (n, deg), in the given order; n pads

    @property
    def size(self) -> int:
        return self.order.size

    def _build(self, idx: np.ndarray, shapes, points, order: list) -> _Box:
        start = order[-1][1] if order else 0
        if idx.size <= self.leaf:
            order.append((idx, start + idx.size))
            return _Box(start, start + idx.size)
        parts = [idx]
        for _ in range(SPLITS):
            parts = [half for p in parts for half in (_halves(p, points) if p.size > self.leaf else (p,))]
        children = tuple(self._build(p, shapes, points, order) for p in parts)
        fits = [_affine(shapes[:, p], points[p]) for p in parts]
        folded = [_folded(fit, low, high) for fit, _, low, high in fits]
        fit = np.concatenate([np.stack([f[j] for f in folded]) for j in range(points.shape[1] + 1)])
        return _Box(start, start + idx.size, children, fit, np.stack([f[1] for f in fits]))

    def _descend(self, box: _Box, velocity, speed, slack, cols, floor: float, leaf, pruned) -> None:
        """Down from ``box`` at the columns ``cols`` whose bound on it exceeds ``floor``: ``leaf(box,
        cols, field)`` on the smallest boxes reached, ``pruned(cols, bound)`` with the largest bound
        of the children it stops at (-inf where none)."""
        if not box.children:
            leaf(box, cols, self.values[box.start:box.stop] @ velocity)
            return
        bounds = box.bounds(velocity, speed) + slack
        overs = bounds > floor
        if pruned is not None and not overs.all():
            pruned(cols, np.where(overs, -np.inf, bounds).max(axis=0))
        for child, over in zip(box.children, overs):
            if over.all():
                self._descend(child, velocity, speed, slack, cols, floor, leaf, pruned)
            elif over.any():
                self._descend(child, velocity[:, over], speed[:, over], slack[over], cols[over], floor, leaf, pruned)

    def top(self, velocity: np.ndarray, floor: float = 0.0) -> np.ndarray:
        """The largest ``|w|`` over the points at each column of ``velocity`` (K, N), shape (N,):
        exact (to round-off) wherever it exceeds ``floor``; elsewhere a bound on it, at most
        ``floor``, stands in."""
        velocity = np.asarray(velocity, float)
        out = np.zeros(velocity.shape[1])
        if self.size == 0:
            return out
        for first in range(0, velocity.shape[1], CHUNK):
            v = velocity[:, first:first + CHUNK]
            speed = np.abs(v)
            whole = self.reach @ speed
            top = out[first:first + CHUNK]
            top[:] = whole
            near = np.flatnonzero(whole > floor)
            if near.size == 0:
                continue
            top[near] = 0.0

            def leaf(box, cols, field, top=top):
                top[cols] = np.maximum(top[cols], np.abs(field).max(axis=0))

            def pruned(cols, bound, top=top):
                top[cols] = np.maximum(top[cols], bound)

            self._descend(self.root, v[:, near], speed[:, near], SLACK * whole[near], near, floor, leaf, pruned)
        return out

    def largest(self, velocity: np.ndarray) -> float:
        """The largest ``|w|`` over every point and column of ``velocity`` (K, N), exactly: the field
        on every point at the few columns whose bound is largest gives a floor, and :meth:`top`
        above it the rest."""
        velocity = np.asarray(velocity, float)
        if self.size == 0 or velocity.shape[1] == 0:
            return 0.0
        if not self.root.children:  # a few points
            return float(np.abs(self.values @ velocity).max())
        found = self.at_least(velocity)
        return max(found, float(self.top(velocity, found).max()))

    def at_least(self, velocity: np.ndarray, columns: int = 8) -> float:
        """A value the largest ``|w|`` over the points and columns of ``velocity`` (K, N) reaches:
        the field on every point at the ``columns`` columns whose bound is largest."""
        velocity = np.asarray(velocity, float)
        if self.size == 0 or velocity.shape[1] == 0:
            return 0.0
        if not self.root.children:
            rough = self.reach @ np.abs(velocity)
        else:
            rough = np.concatenate([self.root.bounds(velocity[:, i:i + CHUNK], np.abs(velocity[:, i:i + CHUNK]))
                                    .max(axis=0) for i in range(0, velocity.shape[1], CHUNK)])
        return float(np.abs(self.values @ velocity[:, np.argsort(rough)[-columns:]]).max())

    def lobes(self, size: np.ndarray, level: float) -> np.ndarray:
        """The points where ``size`` (n,: a field's absolute value, in the points' order) exceeds
        ``level`` and is at least its value at each of the point's neighbours (along a line, the
        points before and after; on a plate, those within 1.5 grid spacings): each lobe's crest."""
        above = np.flatnonzero(size > level)
        padded = np.append(size, -np.inf)
        return above[size[above] >= padded[self.neighbours[above]].max(axis=1)]

    def field(self, velocity: np.ndarray, floor: float = 0.0) -> np.ndarray:
        """The field at each column of ``velocity`` (K, s) on every point (in their given order),
        shape (n, s): exact wherever the bound exceeds ``floor`` (every point whose ``|w|`` does),
        zero elsewhere. Ask for a few columns at a time: it is the points-by-columns array."""
        velocity = np.asarray(velocity, float)
        out = np.zeros((self.size, velocity.shape[1]))
        if self.size == 0 or velocity.shape[1] == 0:
            return out
        speed = np.abs(velocity)
        whole = self.reach @ speed
        near = np.flatnonzero(whole > floor)

        def leaf(box, cols, field):
            out[box.start:box.stop, cols] = field

        if near.size:
            self._descend(self.root, velocity[:, near], speed[:, near], SLACK * whole[near], near, floor, leaf, None)
        result = np.empty_like(out)
        result[self.order] = out
        return result


def _neighbours(points: np.ndarray) -> np.ndarray:
    """Each point's neighbours, shape (n, deg), padded with n: along a line the points before and
    after it in their order; on a plate the points within 1.5 times the grid's median spacing."""
    n = points.shape[0]
    if points.shape[1] == 1 or n < 3:
        index = np.arange(n)
        return np.stack([np.where(index > 0, index - 1, n), np.where(index < n - 1, index + 1, n)], axis=1)
    from scipy.spatial import cKDTree

    tree = cKDTree(points)
    spacing = float(np.median(tree.query(points, k=2)[0][:, 1]))
    pairs = tree.query_pairs(1.5 * spacing, output_type="ndarray")
    pairs = np.vstack([pairs, pairs[:, ::-1]])
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    counts = np.bincount(pairs[:, 0], minlength=n)
    out = np.full((n, max(int(counts.max()), 1)), n)
    slot = np.arange(pairs.shape[0]) - np.repeat(np.cumsum(counts) - counts, counts)
    out[pairs[:, 0], slot] = pairs[:, 1]
    return out


def _halves(idx: np.ndarray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``idx`` split at the median of its points along their longer side."""
    p = points[idx]
    axis = int(np.argmax(np.ptp(p, axis=0)))
    ranked = idx[np.argsort(p[:, axis], kind="stable")]
    return ranked[:idx.size // 2], ranked[idx.size // 2:]


def _folded(fit: np.ndarray, low: np.ndarray, high: np.ndarray) -> np.ndarray:
    """An affine fit (1 + d, K) about a box's centre, its points' span ``low``..``high`` (d,) about it:
    the fit's value at the span's centre, then each slope times the span's half-width (1 + d, K), so
    that over the span ``a + b . x`` lies within the first row's value +- the others' sizes."""
    centre, half = (low + high) / 2, (high - low) / 2
    return np.vstack([fit[0] + centre @ fit[1:], half[:, None] * fit[1:]])


def _affine(shapes: np.ndarray, points: np.ndarray):
    """Every mode (K, m) fitted affinely over ``points`` (m, d) about their box's centre: the fit
    (1 + d, K), its largest residual on them (K,), and the points' span about the centre, low and
    high (d,)."""
    centre = 0.5 * (points.max(axis=0) + points.min(axis=0))
    offset = points - centre
    reach = np.where(np.ptp(points, axis=0) > 0, 0.5 * np.ptp(points, axis=0), 1.0)
    design = np.hstack([np.ones((points.shape[0], 1)), offset / reach])  # within [-1, 1]: well conditioned
    fit = np.linalg.lstsq(design.T @ design, design.T @ shapes.T, rcond=None)[0]  # (1 + d, K)
    residual = np.abs(shapes.T - design @ fit).max(axis=0)  # whatever the fit, this makes it a bound
    fit[1:] /= reach[:, None]
    return fit, residual, offset.min(axis=0), offset.max(axis=0)
