"""The convex planner: the whole drive as a quadratic program on the exact plant.

The plant is linear in the voltages, so once the modal state at T_F is fixed (the focus is then
exactly the planned one), the drives that keep ``|w(x, t)| <= margin * peak`` at every off-target
grid point and DAC sample form a convex polytope, and the least-energy drive inside it is a
quadratic program.

**Variables** (a :class:`~modalctl.plan.drive.SplineDrive`): each kept mode's complex envelope on
its carrier, along its dispatch direction (the plan's weights), as Hann bumps, coarse early in the
shot and finer near T_F; and every channel's voltage on hats near T_F, the fast turn the margin
needs (the focus state, left to itself, dephases to two thirds of its peak off target within tens
of microseconds). Each column is scaled to volts.

**Predictions, exact**: every basis function of a family is a time-shifted copy of one prototype
(with a phase for the carriers), so the response of every mode of the model to a whole family is
one table per prototype: the zero-order-hold recursion of :mod:`modalctl.model.propagate` over the
prototype's support, and its free decay after, in closed form. The modal state at any sample is
then a lookup per column (:class:`Responses`); the plan's field on the plant matches it to round-off.

**Constraints**: the modal state at T_F (every mode's velocity: the kept modes' targets, zero
for the others; the kept modes' displacement zero, each at its velocity peak); the margin on
every off-target point and sample of the whole model, and the voltage and slew limits at every
sample, by constraint generation: the exact plant plays the drive, and the time-local peaks that
break a limit (for the margin, every lobe of the field above ``aim`` of it) join the program
until none does. With a robust band the same margin rows hold on drifted copies of the model,
each of which must still reach a share of the focus at the target's peak.

**Objective**: the drive's energy, each basis function's own energy on the actuators times its
coefficient squared (the cross terms of overlapping functions left out): the smoothest drive,
least dissipated in the amplifiers and exciting least of what the model does not know; the peak
voltage is held by the voltage limit when one is given.

**Infeasibility** is a result. The field at T_F is fixed by the focus state, so the focus's own
side lobes there bound every drive's ratio from below: a margin under them is refused with that
proof (with ``ConvexOptions.leak`` the left-out modes may move at T_F, and the bound is theirs
less). Otherwise, once the margin program fails (infeasible, or its least energy provably past
``ConvexOptions.energy_bound`` times the focus's own: DAQP's dual bound), a bisection on the
margin program finds the smallest margin a drive within the limits holds: that drive's ratio,
above the margin, is the answer, with the largest margin refused beside it.

Solver: DAQP (a dual active-set method for dense QPs, warm-started from each round's multipliers),
chosen by ``benchmarks/margin_planner.py``; Clarabel and OSQP can be asked for
(``ConvexOptions.solver``). HiGHS's QP solver was tried and dropped: it stops on the free
columns ("Non-convex") and takes over ten minutes once they are boxed.
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass, field, replace

import numpy as np
from scipy.signal import lfilter
from tqdm.auto import tqdm

from modalctl.model.modes import ModalModel
from modalctl.model.propagate import Plant, hold_coefficients, poles
from modalctl.options import ConvexOptions, PlanOptions

from .decompose import Decomposition
from .dispatch import dispatch
from .drive import BumpFamily, HatFamily, SplineDrive, hann, hat
from .envelope import plan_envelopes
from .planner import Plan, PlanError, Planner, controllable

__all__ = ["ConvexPlanner", "Basis", "Responses", "Program", "Solution", "plan_convex", "SOLVERS"]

SOLVERS = ("daqp", "clarabel", "osqp")  # HiGHS's QP: "Non-convex" on free columns, >10 min when boxed
CHUNK = 2048  # samples of the field scanned at once (the whole shot's field at once is hundreds of MB)


class ConvexPlanner(Planner):
    """The ``convex`` planner plugin (see the module's notes)."""

    name = "convex"
    summary = "the whole drive as a quadratic program on the exact plant (least energy, DAQP)"

    def plan(self, dec, focus_time, options, progress=False):
        return plan_convex(dec, focus_time, options, progress)

    def feasible(self, dec, focus_time, options):
        """The margin program alone, without the refusal's bisection."""
        if not focus_time > 0:
            return False
        modes = np.asarray(dec.modes_used, int)
        program = Program(dec.model, modes, dec.coefficients[modes], dec.shape.target_mask, focus_time, options)
        return program.solve().holds(program.margin, options)


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


@dataclass
class Solution:
    """What the program found.

    Attributes
    ----------
    x : ndarray
        The columns (volt-scaled).
    ratio : float
        Whole-model margin ratio on every off-target point and DAC sample (of the nominal model).
    robust_ratios : list of float
        The same on each drifted copy, over its own focus peak.
    peak_voltage, peak_slew : float
        V, V/s over every sample.
    rounds, rows : int
        Constraint-generation rounds; rows in the last program.
    seconds : dict
        ``tables``, ``solve``, ``check``, ``rows``, ``total``.
    status : str
    history : list of dict
    """

    x: np.ndarray
    ratio: float
    robust_ratios: list
    peak_voltage: float
    peak_slew: float
    rounds: int
    rows: int
    seconds: dict
    status: str
    history: list = field(default_factory=list)

    def holds(self, margin: float, options: PlanOptions) -> bool:
        """Solved, and within ``margin`` on every plant and within the voltage and slew limits on
        every sample."""
        within = [(self.peak_voltage, options.voltage_limit), (self.peak_slew, options.slew_limit)]
        return (self.status == "optimal" and max([self.ratio, *self.robust_ratios]) <= margin * (1 + 1e-4)
                and all(limit is None or value <= limit * (1 + 1e-9) for value, limit in within))


@dataclass
class _Rows:
    """The program's inequality rows ``lower <= A x <= upper``, and what each stands for."""

    a: list = field(default_factory=list)
    lower: list = field(default_factory=list)
    upper: list = field(default_factory=list)
    keys: set = field(default_factory=set)

    def add(self, key, row: np.ndarray, lower: float, upper: float) -> None:
        if key in self.keys:
            return
        self.keys.add(key)
        self.a.append(row)
        self.lower.append(lower)
        self.upper.append(upper)

    def __len__(self):
        return len(self.a)


class Program:
    """The quadratic program of one focus, solved by constraint generation (see the module's notes).

    Parameters
    ----------
    model : ModalModel
        The planned model (every mode it knows).
    modes, targets : ndarray, shape (m,)
        Kept modes (positional) and their velocities at T_F (m/s sqrt(kg)).
    target_mask : ndarray of bool, shape (n,)
    focus_time : float
    options : PlanOptions
    offset : ndarray, shape (a, N), or None
        Voltages the program corrects (the drive is ``offset`` plus the basis's); None: the basis
        is the whole drive.
    """

    def __init__(self, model: ModalModel, modes, targets, target_mask, focus_time: float, options: PlanOptions,
                 offset: np.ndarray | None = None):
        tic = _time.perf_counter()
        self.model, self.options = model, options
        self.margin = np.inf if options.margin is None else float(options.margin)  # none: no margin rows
        self.modes, self.targets = np.asarray(modes, int), np.asarray(targets, float)
        self.focus_time, self.fs = float(focus_time), float(options.sample_rate)
        self.samples = int(round((focus_time + options.after) * self.fs))
        self.focus = int(round(focus_time * self.fs))
        weights = dispatch(model, self.modes, np.ones(self.modes.size))
        self.basis = Basis.build(model.omega[self.modes], weights, self.samples, self.focus, self.fs, options.convex)
        self.outside = np.flatnonzero(~np.asarray(target_mask, bool))
        velocity = np.zeros(model.n_modes)
        velocity[self.modes] = self.targets
        self.velocity_at_focus = velocity  # every mode's: the kept modes' targets, zero for the others
        self.focus_field = model.shapes.T @ velocity
        self.peak = float(np.max(np.abs(self.focus_field)))
        self.peak_point = int(np.argmax(np.abs(self.focus_field)))
        outside = self.focus_field[~np.asarray(target_mask, bool)]
        lobes = float(np.abs(outside).max()) / self.peak if outside.size else 0.0
        if options.convex.leak is not None:  # the left-out modes' own share at T_F, at most
            lobes -= options.convex.leak * (model.n_modes - self.modes.size)
        self.focus_lobes = max(lobes, 0.0)  # every drive's ratio is at least this
        self.plants = [model] + [_drifted(model, s) for s in _drifts(options.robust_drift)]
        self.responses = [Responses(m, self.basis, self.fs, self.focus_time) for m in self.plants]
        self.offset = None if offset is None else np.asarray(offset, float)[:, :self.samples]
        driven = [r.driven(self.offset) for r in self.responses] if offset is not None else None
        self.offset_velocity = None if driven is None else [v for v, _ in driven]  # (K, N + 1) per plant
        self.offset_displacement = None if driven is None else driven[0][1][:, self.focus]
        self.seconds = {"tables": _time.perf_counter() - tic, "solve": 0.0, "check": 0.0, "rows": 0.0}
        self.cuts = {}  # every margin row found so far, per unit margin: later solves start from them
        self.cut_offsets = {}  # the offset's part of each, in the same units
        self.limit_cuts = {}  # and every voltage and slew row
        self.limit_offsets = {}

    # -- rows ------------------------------------------------------------------------------------
    def equality(self) -> tuple[np.ndarray, np.ndarray]:
        """``A x = b``: the kept modes' velocity at T_F (their targets) and displacement (times
        their resonance, in velocity units) zero, and, without a ``leak``, every other mode's
        velocity zero; rows scaled by the largest target."""
        nominal = self.responses[0]
        scale = np.max(np.abs(self.targets))
        still = self._still()
        displacement = nominal.displacement(self.focus)[self.modes] * self.model.omega[self.modes, None]
        a = np.vstack([nominal.velocity(self.focus)[still], displacement]) / scale
        b = np.r_[self.velocity_at_focus[still], np.zeros(self.modes.size)] / scale
        if self.offset is not None:  # what the offset already does at T_F
            b = b - np.r_[self.offset_velocity[0][still, self.focus],
                          self.offset_displacement[self.modes] * self.model.omega[self.modes]] / scale
        return a, b

    def _offset(self, plant: int, weights: np.ndarray, n: int) -> float:
        """``weights @`` the offset's modal velocity on ``plant`` at sample ``n`` (0 without one)."""
        return 0.0 if self.offset is None else float(weights @ self.offset_velocity[plant][:, n])

    def _add_margin_row(self, rows: _Rows, key, margin: float) -> None:
        """The cut ``key`` as the row ``|cut x + its offset| <= aim margin`` (units of the bound)."""
        scale = self.options.convex.aim * margin
        shift = self.cut_offsets.get(key, 0.0) / scale
        rows.add(key, self.cuts[key] / scale, -1.0 - shift, 1.0 - shift)

    def _add_limit_row(self, rows: _Rows, key) -> None:
        shift = self.limit_offsets.get(key, 0.0)
        rows.add(key, self.limit_cuts[key], -1.0 - shift, 1.0 - shift)

    def _fixed_rows(self, rows: _Rows) -> None:
        """The rows every round has: with a ``leak``, each left-out mode's share of the field at T_F
        within it; with a robust band, each drifted copy still reaching ``robust_focus`` of the
        focus at the target's peak."""
        opts = self.options.convex
        if opts.leak is not None:
            left = np.setdiff1d(np.arange(self.model.n_modes), self.modes)
            reach = np.abs(self.model.shapes[left]).max(axis=1)
            scale = reach / (opts.leak * self.peak)
            velocity = self.responses[0].velocity(self.focus)[left] * scale[:, None]
            fixed = 0.0 if self.offset is None else self.offset_velocity[0][left, self.focus] * scale
            for k, row, shift in zip(left, velocity, np.broadcast_to(fixed, left.shape)):
                rows.add(("leak", int(k)), row, -1.0 - shift, 1.0 - shift)
        sign = np.sign(self.focus_field[self.peak_point])
        for s, responses in enumerate(self.responses[1:], start=1):
            weights = sign * self.model.shapes[:, self.peak_point] / (opts.robust_focus * self.peak)
            row = weights @ responses.velocity(self.focus)
            rows.add(("floor", s), row, 1.0 - self._offset(s, weights, self.focus), np.inf)

    def _margin_bound(self, plant: int, margin: float) -> float:
        """The off-target bound on ``plant``: ``margin`` of the focus peak (of its floor, drifted)."""
        share = 1.0 if plant == 0 else self.options.convex.robust_focus
        return margin * self.peak * share

    # -- the check ---------------------------------------------------------------------------------
    def play(self, x: np.ndarray) -> tuple[np.ndarray, list]:
        """The drive's voltages (a, N) and every plant's modal velocities (K, N) on it."""
        volts = self.correction(x) if self.offset is None else self.offset + self.correction(x)
        return volts, [Plant(m, self.fs).simulate(volts) for m in self.plants]

    def correction(self, x: np.ndarray) -> np.ndarray:
        """The basis's voltages (a, N) for the columns ``x``: the whole drive, or what the program
        adds to its offset."""
        drive = self.basis.drive(x, self.focus_time, self.fs)
        t = np.arange(self.samples) / self.fs + 0.5 / self.fs
        return self.basis.weights @ drive.forces(t) + drive.channels(t, self.basis.weights.shape[0])

    def off_target(self, velocity: np.ndarray, floor: float = 0.0) -> np.ndarray:
        """The largest off-target |w| at every sample, shape (N,), exactly wherever it may exceed
        ``floor``: elsewhere (where ``sum_k max_x |phi_k(x)| |eta'_k|``, an upper bound, does not)
        that bound stands in for it."""
        shapes = self.model.shapes[:, self.outside]
        top = np.abs(velocity).T @ np.abs(shapes).max(axis=1)  # the bound, every sample
        near = np.flatnonzero(top > floor)
        for start in range(0, near.size, CHUNK):
            n = near[start:start + CHUNK]
            top[n] = np.abs(shapes.T @ velocity[:, n]).max(axis=0)
        return top

    def _new_margin_rows(self, rows: _Rows, velocities: list, tops: list, margin: float) -> int:
        """Rows ``|w| <= aim * bound`` at every lobe above it, at each time-local peak above it, on
        every plant; returns how many were added (each is also kept in :attr:`cuts`)."""
        aim = self.options.convex.aim
        added = 0
        shapes = self.model.shapes[:, self.outside]
        for s, (velocity, top) in enumerate(zip(velocities, tops)):
            bound = self._margin_bound(s, margin)
            peaks = _local_peaks(top)
            over = peaks[top[peaks] > aim * bound]
            if over.size == 0:
                continue
            fields = np.abs(shapes.T @ velocity[:, over])  # (n_out, peaks)
            for c, n in enumerate(over):
                lobes = _local_peaks(fields[:, c])
                lobes = lobes[fields[lobes, c] > aim * bound]
                if lobes.size == 0:
                    lobes = np.array([int(np.argmax(fields[:, c]))])
                velocity_rows = self.responses[s].velocity(int(n))
                for i in lobes:
                    key = (s, int(i), int(n))
                    if key in rows.keys:
                        continue
                    self.cuts[key] = shapes[:, i] @ velocity_rows / self._margin_bound(s, 1.0)
                    self.cut_offsets[key] = self._offset(s, shapes[:, i], int(n)) / self._margin_bound(s, 1.0)
                    self._add_margin_row(rows, key, margin)
                    added += 1
        return added

    def _new_limit_rows(self, rows: _Rows, volts: np.ndarray) -> int:
        """Voltage and slew rows at the time-local peaks that break the limits; returns how many."""
        opts, aim = self.options, self.options.convex.aim
        added = 0
        checks = []
        if opts.voltage_limit is not None:
            checks.append(("volts", np.abs(volts), opts.voltage_limit, 0))
        if opts.slew_limit is not None:
            checks.append(("slew", np.abs(np.diff(volts, axis=1)), opts.slew_limit / self.fs, 1))
        for kind, size, limit, step in checks:
            top = size.max(axis=0)
            peaks = _local_peaks(top)
            for n in peaks[top[peaks] > limit]:
                channel = int(np.argmax(size[:, n]))
                row = self.basis.voltage_rows(channel, np.array([n + step]), self.fs, self.focus_time)[0]
                fixed = 0.0 if self.offset is None else self.offset[channel, n + step]
                if step:
                    row = row - self.basis.voltage_rows(channel, np.array([n]), self.fs, self.focus_time)[0]
                    fixed -= 0.0 if self.offset is None else self.offset[channel, n]
                key = (kind, channel, int(n))
                if key not in rows.keys:
                    self.limit_cuts[key] = row / (aim * limit)
                    self.limit_offsets[key] = fixed / (aim * limit)
                    self._add_limit_row(rows, key)
                    added += 1
        return added

    # -- the solve ---------------------------------------------------------------------------------
    def solve(self, margin: float | None = None) -> Solution:
        """The least-energy drive under ``margin`` (default: the options'; inf: none) and the
        limits, by constraint generation from every row an earlier solve found. Returns the last
        iterate and how far it got."""
        opts = self.options.convex
        margin = self.margin if margin is None else float(margin)
        start = _time.perf_counter()
        a_eq, b_eq = self.equality()
        rows = _Rows()
        self._fixed_rows(rows)
        for key in self.cuts if np.isfinite(margin) else ():  # true of every program of this focus:
            self._add_margin_row(rows, key, margin)  # start from them
        for key in self.limit_cuts:
            self._add_limit_row(rows, key)
        qp = _QP(self.basis.energy(self.fs), np.zeros(self.basis.size), a_eq, b_eq, rows)
        bound = opts.energy_bound * self.focus_energy(qp)
        history, status, x, duals = [], "not solved", np.zeros(self.basis.size), None
        for round_ in range(1, opts.rounds + 1):
            tic = _time.perf_counter()
            x, status, duals = _solve_qp(opts.solver, qp, bound, duals)
            self.seconds["solve"] += _time.perf_counter() - tic
            if status != "optimal":
                break
            tic = _time.perf_counter()
            volts, velocities = self.play(x)
            tops = [self.off_target(v, 0.5 * opts.aim * self._margin_bound(s, margin))
                    for s, v in enumerate(velocities)]
            ratios = [float(top.max()) / self._margin_bound(s, 1.0) for s, top in enumerate(tops)]
            self.seconds["check"] += _time.perf_counter() - tic
            history.append({"round": round_, "ratio": ratios[0], "peak_voltage": float(np.abs(volts).max()),
                            "rows": len(rows)})
            tic = _time.perf_counter()
            within = self._new_limit_rows(rows, volts) == 0
            if max(ratios) <= margin and within:
                break
            self._new_margin_rows(rows, velocities, tops, margin)
            self.seconds["rows"] += _time.perf_counter() - tic
        return self._solution(x, status, history, len(rows), start)

    def focus_energy(self, qp: _QP) -> float:
        """The least energy of the focus alone on the basis (the scale of ``energy_bound``): with an
        offset, of the whole drive, not of a correction the offset may almost spare."""
        if self.offset is None:
            return qp.least_energy()
        whole = np.r_[self.velocity_at_focus[self._still()], np.zeros(self.modes.size)] / np.max(np.abs(self.targets))
        return replace(qp, b_eq=whole).least_energy()

    def _still(self) -> np.ndarray:
        """The modes whose velocity at T_F the equalities fix: every one, or the kept ones with a leak."""
        return np.arange(self.model.n_modes) if self.options.convex.leak is None else self.modes

    def _solution(self, x, status, history, rows, start) -> Solution:
        volts, velocities = self.play(x)
        peaks = [float(np.max(np.abs(self.model.shapes.T @ v[:, self.focus]))) for v in velocities]
        ratios = [float(self.off_target(v, 0.25 * p).max()) / p if p > 0 else np.inf
                  for v, p in zip(velocities, peaks)]  # each plant's ratio over its own focus peak
        self.seconds["total"] = _time.perf_counter() - start + self.seconds["tables"]
        slew = float(np.abs(np.diff(volts, axis=1)).max() * self.fs) if volts.shape[1] > 1 else 0.0
        return Solution(x, ratios[0], ratios[1:], float(np.abs(volts).max()), slew, len(history), rows,
                        dict(self.seconds), status, history)

    def smallest_ratio(self, low: float, rel_tol: float = 0.01,
                       progress: bool = False) -> tuple[Solution | None, float]:
        """The smallest margin a drive within the limits (and ``energy_bound``) holds, by bisection
        on the margin program from ``low`` (refused there) to the least-energy drive's own ratio.
        Returns that drive's solution (None when no drive reaches the focus within the limits)
        and the largest margin refused. ``progress``: a bar over the bisection's programs."""
        free = self.solve(np.inf)
        if not free.holds(np.inf, self.options):
            return None, low
        best, high = free, max([free.ratio, *free.robust_ratios])
        steps = max(0, int(np.ceil(np.log2(max(high - low, 1e-300) / (rel_tol * high)))))
        with tqdm(total=steps, desc="margin refused: the smallest ratio", unit="program", disable=not progress,
                  leave=False) as bar:
            while high - low > rel_tol * high:
                middle = 0.5 * (low + high)
                found = self.solve(middle)
                if found.holds(middle, self.options):
                    best, high = found, min(middle, max([found.ratio, *found.robust_ratios]))
                else:
                    low = middle
                bar.set_postfix_str(f"{low:.3f} refused, {high:.3f} held")
                bar.update()
        return best, min(low, high)


def _drifts(band: float) -> list:
    """The drifted copies the robust margin holds on: both edges of the band and its middle points."""
    return [] if not band else [-band, -band / 2, band / 2, band]


def _drifted(model: ModalModel, shift: float) -> ModalModel:
    return replace(model, frequencies=model.frequencies * (1 + shift))


def _local_peaks(values: np.ndarray) -> np.ndarray:
    """Indices of the local maxima of ``values`` (1-D), its ends included."""
    if values.size < 3:
        return np.arange(values.size)
    inner = np.flatnonzero((values[1:-1] >= values[:-2]) & (values[1:-1] >= values[2:])) + 1
    ends = [i for i, ok in ((0, values[0] >= values[1]), (values.size - 1, values[-1] >= values[-2])) if ok]
    return np.union1d(inner, ends).astype(int)


@dataclass
class _QP:
    """``min 1/2 x' diag(hessian) x + linear' x`` s.t. ``a_eq x = b_eq`` and ``rows``."""

    hessian: np.ndarray
    linear: np.ndarray
    a_eq: np.ndarray
    b_eq: np.ndarray
    rows: _Rows

    def matrices(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every row, equalities first: ``(A, lower, upper)``."""
        a = np.vstack([self.a_eq] + [np.atleast_2d(r) for r in self.rows.a]) if len(self.rows) else self.a_eq
        lower = np.r_[self.b_eq, np.asarray(self.rows.lower, float)]
        upper = np.r_[self.b_eq, np.asarray(self.rows.upper, float)]
        return a, lower, upper

    def objective(self, x: np.ndarray) -> float:
        return float(0.5 * x @ (self.hessian * x) + self.linear @ x)

    def least_energy(self) -> float:
        """The objective under the equalities alone (the focus, reached in the least energy)."""
        inverse = 1.0 / self.hessian
        gram = (self.a_eq * inverse) @ self.a_eq.T
        return float(0.5 * self.b_eq @ np.linalg.pinv(gram, hermitian=True) @ self.b_eq)


def _solve_qp(solver: str, qp: _QP, energy_bound: float = np.inf, duals=None) -> tuple[np.ndarray, str, object]:
    """Solve ``qp``; returns ``(x, status, duals)``, status ``optimal``, ``infeasible``, ``past the
    energy bound`` or the solver's word. ``duals`` (DAQP's multipliers) warm-start the next round,
    whose rows extend this one's."""
    a, lower, upper = qp.matrices()
    neq = qp.a_eq.shape[0]
    if solver == "daqp":
        return _daqp(qp, a, lower, upper, energy_bound, duals)
    try:
        if solver == "clarabel":
            x, status = _clarabel(qp.hessian, qp.linear, a, lower, upper, neq)
        elif solver == "osqp":
            x, status = _osqp(qp.hessian, qp.linear, a, lower, upper)
        else:
            raise PlanError(f"unknown QP solver {solver!r}; known: {', '.join(SOLVERS)}")
    except ImportError as missing:
        raise PlanError(f"the {solver} solver is not installed ({missing}): pip install 'modalctl[solvers]'") \
            from missing
    if status == "optimal" and qp.objective(x) > energy_bound:
        status = "past the energy bound"
    return x, status, None


def _daqp(qp: _QP, a, lower, upper, energy_bound, duals):
    import daqp

    neq = qp.a_eq.shape[0]
    sense = np.r_[np.full(neq, 5), np.zeros(len(qp.rows))].astype(np.int32)
    start = None if duals is None else np.r_[duals, np.zeros(a.shape[0] - duals.size)]
    x, _, flag, info = daqp.solve(np.diag(qp.hessian), qp.linear, a, np.where(np.isfinite(upper), upper, 1e30),
                                  np.where(np.isfinite(lower), lower, -1e30), sense,
                                  fval_bound=min(energy_bound, 1e30), dual_start=start)
    words = {1: "optimal", 2: "optimal",
             -1: "infeasible" if not np.isfinite(energy_bound) else "infeasible or past the energy bound"}
    return np.asarray(x), words.get(flag, f"daqp exit flag {flag}"), np.asarray(info["lam"])


def _clarabel(hessian, linear, a, lower, upper, neq):
    import clarabel
    import scipy.sparse as sp

    ineq = a[neq:]
    hi, lo = np.isfinite(upper[neq:]), np.isfinite(lower[neq:])
    blocks = [a[:neq], ineq[hi], -ineq[lo]]
    rhs = np.r_[upper[:neq], upper[neq:][hi], -lower[neq:][lo]]
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    solver = clarabel.DefaultSolver(sp.diags(hessian).tocsc(), linear, sp.csc_matrix(np.vstack(blocks)), rhs,
                                    [clarabel.ZeroConeT(neq), clarabel.NonnegativeConeT(int(hi.sum() + lo.sum()))],
                                    settings)
    solution = solver.solve()
    status = str(solution.status)
    return np.asarray(solution.x), "optimal" if status.endswith("Solved") else (
        "infeasible" if "Infeasible" in status else status)


def _osqp(hessian, linear, a, lower, upper):
    import osqp
    import scipy.sparse as sp

    problem = osqp.OSQP()
    problem.setup(sp.diags(hessian).tocsc(), linear, sp.csc_matrix(a), np.where(np.isfinite(lower), lower, -1e30),
                  np.where(np.isfinite(upper), upper, 1e30), verbose=False, eps_abs=1e-8, eps_rel=1e-8,
                  max_iter=200000, polishing=True)
    result = problem.solve(raise_error=False)
    status = str(result.info.status)
    return np.asarray(result.x), "optimal" if status.startswith("solved") else (
        "infeasible" if "infeasible" in status else status)


def plan_convex(dec: Decomposition, focus_time: float, options: PlanOptions = PlanOptions(),
                progress: bool = False) -> Plan:
    """The least-energy drive that builds ``dec``'s reduced field at ``focus_time`` and holds the
    margin on every off-target point and DAC sample of ``dec.model`` (see the module's notes).

    Without a margin, the least-energy drive that reaches the focus state. Raises
    :class:`PlanError` with the smallest reachable ratio (and the program's certificate) when the
    margin cannot be held within the limits.
    """
    start = _time.perf_counter()
    model = dec.model
    modes = np.asarray(dec.modes_used, int)
    controllable(dec, modes)
    if options.convex.solver not in SOLVERS:
        raise PlanError(f"unknown QP solver {options.convex.solver!r}; known: {', '.join(SOLVERS)}")
    targets = dec.coefficients[modes]
    margin = options.margin
    base = _reference(dec, focus_time, options)
    program = Program(model, modes, targets, dec.shape.target_mask, focus_time, options,
                      None if base is None else base.voltages())
    solution = program.solve()
    info = {"planner": "convex", "margin_asked": margin, "voltage_limit": options.voltage_limit,
            "slew_limit": options.slew_limit, "robust_drift": options.robust_drift, "after_s": options.after,
            "reference": options.convex.reference, "program": _summary(program, solution)}
    if solution.status != "optimal":  # infeasible, or a solver that gave up on an infeasible program
        raise _refusal(program, options, solution, progress)
    if not solution.holds(program.margin, options):
        raise PlanError(f"the convex program stopped after {solution.rounds} rounds at a ratio of "
                        f"{solution.ratio:.4f} and {solution.peak_voltage:.1f} V (the margin or the limits not "
                        f"yet held on every sample): raise ConvexOptions.rounds", solution.ratio, margin)
    info.update({"predicted_margin_ratio": solution.ratio, "whole_model_margin_ratio": solution.ratio,
                 "robust_margin_ratios": solution.robust_ratios, "peak_voltage": solution.peak_voltage,
                 "peak_slew_v_per_s": solution.peak_slew, "decoupling_worst": None, "decoupling_warnings": [],
                 "plan_seconds": _time.perf_counter() - start})
    if base is not None:  # the envelope plan, its correction added to its voltages
        return replace(base, correction=program.correction(solution.x), correction_start=0, info=info)
    drive = program.basis.drive(solution.x[:program.basis.size], focus_time, options.sample_rate)
    return Plan(model, modes, targets, focus_time, focus_time + options.after, options.sample_rate,
                program.basis.weights, dec.shape.target_mask, model.shapes[modes].T @ targets, drive, info)


def _reference(dec: Decomposition, focus_time: float, options: PlanOptions) -> Plan | None:
    """The plan a ``reference="envelope"`` program corrects: the thesis's envelopes (kappa = 1, no
    margin, no limits: the program holds them); None for the whole drive."""
    if options.convex.reference is None:
        return None
    return plan_envelopes(dec, focus_time, options.but(planner="envelope", margin=None, voltage_limit=None,
                                                       slew_limit=None, robust_drift=0.0))


def _summary(program: Program, solution: Solution) -> dict:
    basis = program.basis
    return {"solver": program.options.convex.solver, "robust_drift": program.options.robust_drift,
            "status": solution.status, "rounds": solution.rounds,
            "rows": solution.rows, "columns": basis.size, "seconds": solution.seconds,
            "bumps": [int(f.offsets.size) for f in basis.bumps],
            "hats": 0 if basis.hats is None else int(basis.hats.offsets.size), "history": solution.history}


def _refusal(program: Program, options: PlanOptions, failed: Solution, progress: bool = False) -> PlanError:
    """The margin program did not solve: say why, with proof where there is one.

    Every drive that builds the focus has the focus's own side lobes at T_F: a margin below them is
    out of reach whatever the limits (exact). Otherwise the smallest margin a drive within the
    limits and the energy bound holds, by bisection on the margin program, says whether the margin
    was out of reach (the answer above it) or the solver failed (at or below it); without
    ``ConvexOptions.certify`` the refusal is said at once, unproven.
    """
    margin, lobes, solver = options.margin, program.focus_lobes, options.convex.solver
    if not options.convex.certify:
        return PlanError(f"the {margin:g} margin program was refused ({failed.status}; not certified)", None,
                         margin, {"solver": solver, "margin_program": failed.status, "margin": margin,
                                  "focus_lobes": lobes, "status": "not certified"})
    best, refused = program.smallest_ratio(max(margin, lobes), progress=progress)
    limits = ", ".join(f"{name} {value:g} {unit}" for name, value, unit in
                       (("voltage", options.voltage_limit, "V"), ("slew", options.slew_limit, "V/s"))
                       if value is not None) or "no voltage limit"
    reached = None if best is None else max([best.ratio, *best.robust_ratios])
    leak = options.convex.leak
    at_focus = ("the modes left out still at T_F (ConvexOptions.leak lets them move)" if leak is None else
                f"the modes left out moving by at most {leak:g} of the focus peak at T_F")
    certificate = {"solver": solver, "margin_program": failed.status, "margin": margin, "focus_lobes": lobes,
                   "unkept_modes_at_focus": "still" if leak is None else f"leak {leak:g}",
                   "smallest_ratio": reached, "largest_refused": refused, "limits": limits,
                   "energy_bound": options.convex.energy_bound,
                   "peak_voltage_at_smallest": None if best is None else best.peak_voltage}
    if best is None:
        certificate["status"] = "infeasible"
        return PlanError(f"no drive on this basis reaches the focus within {limits}, even without the margin: "
                         f"lengthen the focus time or raise the limits", None, margin, certificate)
    if lobes > margin:
        certificate["status"] = "infeasible"
        return PlanError(f"the {margin:g} margin cannot be held: the focus's own side lobes at T_F are "
                         f"{lobes:.3f} of its peak, on every drive that builds it (the smallest ratio a drive "
                         f"within {limits} reaches: {reached:.3f})", reached, margin, certificate)
    if reached <= margin * (1 + 1e-4):
        certificate["status"] = "solver failure"
        return PlanError(f"{solver} failed on the margin program ({failed.status}) though a drive within "
                         f"{limits} reaches {reached:.3f}: try another solver (ConvexOptions.solver, one of "
                         f"{', '.join(SOLVERS)})", reached, margin, certificate)
    certificate["status"] = "infeasible"
    return PlanError(f"the {margin:g} margin cannot be held within {limits}, {at_focus}: the smallest ratio a "
                     f"drive reaches is {reached:.3f} ({refused:.3f} refused: infeasible, or past "
                     f"{options.convex.energy_bound:g} times the focus's own least energy)", reached, margin,
                     certificate)
