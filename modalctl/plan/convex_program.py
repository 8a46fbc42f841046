"""The convex planner's quadratic program: :class:`Program` (the equalities at T_F, the margin,
voltage and slew rows found by constraint generation on the exact plant, the robust band's drifted
copies, and the bisection to the smallest reachable ratio) and what it finds, :class:`Solution`.
The method's notes: :mod:`modalctl.plan.convex`; its columns: :mod:`.convex_basis`; its solvers:
:mod:`.qp`."""

from __future__ import annotations

import concurrent.futures
import os
import time as _time
from dataclasses import dataclass, field, replace

import numpy as np
from tqdm.auto import tqdm

from modalctl.model.modes import ModalModel, drift_cases
from modalctl.model.propagate import Plant
from modalctl.options import PlanOptions

from .convex_basis import Basis, Responses
from .convex_cover import Cover
from .dispatch import dispatch
from .qp import OUT_OF_TIME, QP, solve_qp

__all__ = ["Program", "Solution", "OUT_OF_TIME", "PROOFS"]

PROOFS = ("infeasible", "infeasible or past the energy bound", "past the energy bound")  # the solvers' proofs
FAR = 3.0  # a drive whose field passes this many times the check's floor is far over the margin
THREADS = 2  # threads working on a robust program's plants at once (their tables, a round's checks)
PEAKS = 64  # time-local peaks whose field is searched for lobes at once (the points-by-peaks array)


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
    order: list = field(default_factory=list)  # the keys, row by row

    def add(self, key, row: np.ndarray, lower: float, upper: float) -> None:
        if key in self.keys:
            return
        self.keys.add(key)
        self.order.append(key)
        self.a.append(row)
        self.lower.append(lower)
        self.upper.append(upper)

    def __len__(self):
        return len(self.a)


class Program:
    """The quadratic program of one focus, solved by constraint generation (see :mod:`modalctl.plan.convex`).

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
        self.basis = Basis.build(model.omega[self.modes], weights, self.samples, self.focus, self.fs, options.convex,
                                 band=float(model.frequencies.max()))
        self.outside = np.flatnonzero(~np.asarray(target_mask, bool))
        self.cover = Cover(model.shapes[:, self.outside], model.grid.points[self.outside])
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
        self.plants = [model] + [model.drifted(s) for s in drift_cases(options.robust_drift)]
        with _PlantPool(len(self.plants)) as pool:  # each plant's tables on a thread of its own
            self.responses = list(pool.map(lambda m: Responses(m, self.basis, self.fs, self.focus_time), self.plants))
        self.offset = None if offset is None else np.asarray(offset, float)[:, :self.samples]
        driven = [r.driven(self.offset) for r in self.responses] if offset is not None else None
        self.offset_velocity = None if driven is None else [v for v, _ in driven]  # (K, N + 1) per plant
        self.offset_displacement = None if driven is None else driven[0][1][:, self.focus]
        self.seconds = {"tables": _time.perf_counter() - tic, "solve": 0.0, "check": 0.0, "rows": 0.0}
        self.cuts = {}  # every margin row found so far, per unit margin: later solves start from them
        self.cut_offsets = {}  # the offset's part of each, in the same units
        self.limit_cuts = {}  # and every voltage and slew row
        self.limit_offsets = {}
        self.certified = None  # what the last smallest_ratio did and proved
        self._multipliers = None  # the last optimal round's DAQP multipliers: equalities, and by row key
        self._carriers = None  # the kept modes' carriers on the shot's samples (m, N)

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
            row = responses.rows(self.focus, weights[None, :])[0]
            rows.add(("floor", s), row, 1.0 - self._offset(s, weights, self.focus), np.inf)

    def _margin_bound(self, plant: int, margin: float) -> float:
        """The off-target bound on ``plant``: ``margin`` of the focus peak (of its floor, drifted)."""
        share = 1.0 if plant == 0 else self.options.convex.robust_focus
        return margin * self.peak * share

    # -- the check ---------------------------------------------------------------------------------
    def play(self, x: np.ndarray) -> tuple[np.ndarray, list]:
        """The drive's voltages (a, N) and every plant's modal velocities (K, N) on it."""
        volts = self.voltages(x)
        return volts, [Plant(m, self.fs).simulate(volts) for m in self.plants]

    def voltages(self, x: np.ndarray) -> np.ndarray:
        """The drive's voltages (a, N)."""
        return self.correction(x) if self.offset is None else self.offset + self.correction(x)

    def _check_plant(self, s: int, volts: np.ndarray, margin: float, last: float | None = None) -> tuple:
        """Plant ``s`` on ``volts``: its modal velocities (K, N), the level above which its field is
        found exactly, and its largest off-target ``|w|`` at every sample (N,). ``last``: the largest its check
        of the round before found (None in a first round; :meth:`_floor`)."""
        velocity = Plant(self.plants[s], self.fs).simulate(volts)
        floor = self._floor(velocity, self.options.convex.aim * self._margin_bound(s, margin), last)
        return velocity, floor, self.off_target(velocity, floor)  # exact where rows may be

    def correction(self, x: np.ndarray) -> np.ndarray:
        """The basis's voltages (a, N) for the columns ``x``: the whole drive, or what the program
        adds to its offset."""
        drive = self.basis.drive(x, self.focus_time, self.fs)
        t = np.arange(self.samples) / self.fs + 0.5 / self.fs
        if self._carriers is None:  # the same every round: kept
            self._carriers = drive.carriers(t)
        forces = np.real(drive.envelopes(t) * self._carriers)
        return self.basis.weights @ forces + drive.channels(t, self.basis.weights.shape[0])

    def off_target(self, velocity: np.ndarray, floor: float = 0.0) -> np.ndarray:
        """The largest off-target |w| at every sample, shape (N,), exactly wherever it exceeds
        ``floor``; elsewhere a bound on it, at most ``floor``, stands in (:meth:`Cover.top
        <.convex_cover.Cover.top>`: the field is computed only where the bound of the off-target
        points' boxes exceeds ``floor``)."""
        return self.cover.top(velocity, floor)

    def _new_margin_rows(self, rows: _Rows, velocities: list, tops: list, margin: float, floors=None) -> int:
        """Rows ``|w| <= aim * bound`` at every lobe above it, at each time-local peak above it, on
        every plant, the worst first and at most ``ConvexOptions.rows_per_round`` of them (a first
        drive far over the margin has tens of thousands: on a 254-mode panel, 29,462 rows that
        DAQP took 200 s and 8 GB over); returns how many were added (each is also kept in
        :attr:`cuts`). ``floors``: where each plant's check found the field exactly (default ``aim``
        of the margin); the rows lie above it."""
        aim = self.options.convex.aim
        found = []  # (|w| over the bound, plant, point, sample)
        for s, (velocity, top) in enumerate(zip(velocities, tops)):
            bound = self._margin_bound(s, margin)
            peaks = _local_peaks(top)
            over = peaks[top[peaks] > max(aim * bound, 0.0 if floors is None else floors[s])]
            for first in range(0, over.size, PEAKS):  # exact where |w| may exceed aim * bound, zero elsewhere
                block = over[first:first + PEAKS]
                fields = np.abs(self.cover.field(velocity[:, block], aim * bound))
                for c, n in enumerate(block):
                    lobes = self.cover.lobes(fields[:, c], aim * bound)
                    if lobes.size == 0:
                        lobes = np.array([int(np.argmax(fields[:, c]))])
                    found += [(fields[i, c] / bound, s, int(i), int(n)) for i in lobes if (s, int(i), int(n))
                              not in rows.keys]
        limit = self.options.convex.rows_per_round
        found = sorted(found, reverse=True)[:limit] if limit is not None and len(found) > limit else found
        return self._cuts(rows, sorted(((s, n, i) for _, s, i, n in found), key=lambda p: p[:2]), margin)

    def _cuts(self, rows: _Rows, places: list, margin: float) -> int:
        """The rows ``|w| <= aim * bound`` at ``places`` ``(plant, sample, point)`` (points: positions in
        :attr:`outside`) the program does not have yet, added in that order (each plant's made in one
        call: :meth:`Responses.rows <.convex_basis.Responses.rows>`); returns how many."""
        new = {}  # plant: its new keys (plant, point, sample), in order
        for s, n, i in places:
            if (s, i, n) not in rows.keys:
                new.setdefault(s, {})[(s, i, n)] = None
        for s, keys in new.items():
            points, samples = np.array([[i, n] for _, i, n in keys]).T
            shapes = self.model.shapes[:, self.outside[points]]  # (K, l)
            cuts = self.responses[s].rows(samples, shapes.T) / self._margin_bound(s, 1.0)
            for key, weights, cut in zip(keys, shapes.T, cuts):
                if key not in self.cuts:
                    self.cuts[key] = cut
                    self.cut_offsets[key] = self._offset(s, weights, key[2]) / self._margin_bound(s, 1.0)
                self._add_margin_row(rows, key, margin)
        return sum(len(keys) for keys in new.values())

    def _new_limit_rows(self, rows: _Rows, volts: np.ndarray) -> int:
        """Voltage and slew rows at each channel's time-local peaks that break the limits (each
        channel's own: a channel over the limit under a larger one is held too); returns how many."""
        opts, aim = self.options, self.options.convex.aim
        added = 0
        checks = []
        if opts.voltage_limit is not None:
            checks.append(("volts", np.abs(volts), opts.voltage_limit, 0))
        if opts.slew_limit is not None:
            checks.append(("slew", np.abs(np.diff(volts, axis=1)), opts.slew_limit / self.fs, 1))
        for kind, size, limit, step in checks:
            for channel, n in [(c, n) for c, each in enumerate(size) for n in _local_peaks(each) if each[n] > limit]:
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
    def solve(self, margin: float | None = None, deadline: float | None = None, progress: bool = False) -> Solution:
        """The least-energy drive under ``margin`` (default: the options'; inf: none) and the
        limits, by constraint generation from every row an earlier solve found. Returns the last
        iterate and how far it got; past ``deadline`` (``time.perf_counter``'s), it stops at the
        next round, or within a later round's DAQP call, with the status :data:`OUT_OF_TIME` (the
        last round's iterate, checked). ``progress``: a bar over the rounds with
        the ratio each reached and the rows so far (a tablet panel's plan takes a minute)."""
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
        qp = QP(self.basis.energy(self.fs), np.zeros(self.basis.size), a_eq, b_eq, rows)
        bound = opts.energy_bound * self.focus_energy(qp)
        history, status, x, duals = [], "not solved", np.zeros(self.basis.size), None
        if self._multipliers is not None:  # the last solve's active set, row by row
            eq, known = self._multipliers
            duals = np.r_[eq, [known.get(key, 0.0) for key in rows.order]]
        played, tops = None, None  # tops: the last round's largest |w| per sample, on each plant
        with _PlantPool(len(self.plants)) as plants, tqdm(total=opts.rounds, desc="margin program", unit="round",
                                                         disable=not progress, leave=False) as bar:
            for round_ in range(1, opts.rounds + 1):
                if deadline is not None and round_ > 1 and _time.perf_counter() > deadline:
                    status = OUT_OF_TIME  # x: the last round's, checked
                    break
                tic = _time.perf_counter()
                left = None if deadline is None or round_ == 1 else deadline - tic  # a first round always ends
                solved, status, found = solve_qp(opts.solver, qp, bound, duals, left)
                self.seconds["solve"] += _time.perf_counter() - tic
                if status == OUT_OF_TIME:
                    break  # x: the last round's, checked
                x, duals = solved, found
                if status != "optimal":
                    break
                if duals is not None:
                    neq = a_eq.shape[0]
                    self._multipliers = (duals[:neq], dict(zip(rows.order, duals[neq:])))
                tic = _time.perf_counter()
                volts = self.voltages(x)
                last = [None] * len(self.plants) if tops is None else [float(top.max()) for top in tops]
                velocities, floors, tops = (list(a) for a in zip(*plants.map(
                    lambda s: self._check_plant(s, volts, margin, last[s]), range(len(self.plants)))))
                played = (x, volts, velocities, [top.max() if top.max() > floor else None
                                                 for top, floor in zip(tops, floors)])
                ratios = [float(top.max()) / self._margin_bound(s, 1.0) for s, top in enumerate(tops)]
                self.seconds["check"] += _time.perf_counter() - tic
                history.append({"round": round_, "ratio": ratios[0], "peak_voltage": float(np.abs(volts).max()),
                                "rows": len(rows)})
                bar.set_postfix_str(f"ratio {max(ratios):.3f} for {margin:g}, {len(rows)} rows, "
                                    f"{_time.perf_counter() - start:.0f} s")
                bar.update()
                tic = _time.perf_counter()
                within = self._new_limit_rows(rows, volts) == 0
                if max(ratios) <= margin and within:
                    break
                self._new_margin_rows(rows, velocities, tops, margin, floors)
                self.seconds["rows"] += _time.perf_counter() - tic
        return self._solution(x, status, history, len(rows), start, played)

    def _floor(self, velocity: np.ndarray, floor: float, last: float | None = None) -> float:
        """Where the check of ``velocity`` needs the field exactly: above ``floor`` (``aim`` of the
        margin: every row lies there); but on a drive far over the margin (the field somewhere
        past :data:`FAR` times the floor), above half of what it reaches there: the rows a round
        adds are the worst (``rows_per_round``), and the search below that level would take the
        whole grid at every sample (27 s a round on a 254-mode panel). ``last``: the largest field the
        plant's check of the round before found; under half of ``FAR`` times the floor, the drive is taken
        as near and the search for what it reaches is spared (a round's new rows do not take a drive near
        the margin far past it; were one to, its check would be slower, not wrong: the field is then
        exact above ``floor``, as on any drive near the margin)."""
        if last is not None and last <= 0.5 * FAR * floor:
            return floor
        reached = self.cover.at_least(velocity)
        return 0.5 * reached if reached > FAR * floor else floor

    def focus_energy(self, qp: QP) -> float:
        """The least energy of the focus alone on the basis (the scale of ``energy_bound``): with an
        offset, of the whole drive, not of a correction the offset may almost spare."""
        if self.offset is None:
            return qp.least_energy()
        whole = np.r_[self.velocity_at_focus[self._still()], np.zeros(self.modes.size)] / np.max(np.abs(self.targets))
        return replace(qp, b_eq=whole).least_energy()

    def _still(self) -> np.ndarray:
        """The modes whose velocity at T_F the equalities fix: every one, or the kept ones with a leak."""
        return np.arange(self.model.n_modes) if self.options.convex.leak is None else self.modes

    def _solution(self, x, status, history, rows, start, played=None) -> Solution:
        """``played``: the last round's ``(x, volts, velocities, largest)``, ``largest`` each plant's
        largest off-target ``|w|`` where the round found it exactly (above its floor), else None."""
        if played is not None and played[0] is x:
            _, volts, velocities, known = played
        else:
            volts, velocities = self.play(x)
            known = [None] * len(velocities)
        peaks = [float(np.max(np.abs(self.model.shapes.T @ v[:, self.focus]))) for v in velocities]
        ratios = [float(self.cover.largest(v) if top is None else top) / p if p > 0 else np.inf
                  for v, p, top in zip(velocities, peaks, known)]  # each plant's over its own focus peak, exact
        self.seconds["total"] = _time.perf_counter() - start + self.seconds["tables"]
        slew = float(np.abs(np.diff(volts, axis=1)).max() * self.fs) if volts.shape[1] > 1 else 0.0
        return Solution(x, ratios[0], ratios[1:], float(np.abs(volts).max()), slew, len(history), rows,
                        dict(self.seconds), status, history)

    def smallest_ratio(self, low: float, rel_tol: float = 0.01, progress: bool = False,
                       seconds: float | None = None) -> tuple[Solution | None, float]:
        """The smallest margin a drive within the limits (and ``energy_bound``) holds, by bisection
        on the margin program from ``low`` (refused there) to the least-energy drive's own ratio.
        Returns that drive's solution (None when none was found) and the largest margin refused.
        ``progress``: a bar over the bisection's programs. ``seconds``: the time it may take; once
        past, the bisection stops where it is (no program starts after it, a program running then
        stops at its next round). What it did and proved is in :attr:`certified`: ``complete``,
        ``programs``, ``seconds``, ``free`` (the least-energy program's status), ``held`` (the
        smallest ratio a drive was found to hold), ``refused`` (the largest margin refused),
        ``proven`` (whether every refusal in the bisection was the solver's proof, infeasible or
        past the energy bound, rather than its rounds running out)."""
        start = _time.perf_counter()
        deadline = None if seconds is None else start + seconds
        info = {"complete": False, "programs": 1, "free": None, "held": None, "refused": low, "proven": True}
        self.certified = info
        free = self.solve(np.inf, deadline)
        info.update(free=free.status, seconds=_time.perf_counter() - start)
        if not free.holds(np.inf, self.options):
            info["complete"] = free.status != OUT_OF_TIME
            return None, low
        best, high = free, max([free.ratio, *free.robust_ratios])
        steps = max(0, int(np.ceil(np.log2(max(high - low, 1e-300) / (rel_tol * high)))))
        with tqdm(total=steps, desc="margin refused: the smallest ratio", unit="program", disable=not progress,
                  leave=False) as bar:
            while high - low > rel_tol * high:
                if deadline is not None and _time.perf_counter() > deadline:
                    break
                middle = 0.5 * (low + high)
                found = self.solve(middle, deadline)
                info["programs"] += 1
                if found.holds(middle, self.options):
                    best, high = found, min(middle, max([found.ratio, *found.robust_ratios]))
                elif found.status == OUT_OF_TIME:
                    break
                else:
                    low = middle
                    info["proven"] &= found.status in PROOFS
                bar.set_postfix_str(f"{low:.3f} refused, {high:.3f} held, {_time.perf_counter() - start:.0f} s")
                bar.update()
            else:
                info["complete"] = True
        info.update(held=high, refused=min(low, high), seconds=_time.perf_counter() - start)
        return best, min(low, high)


class _PlantPool:
    """Where the program works on its plants: the robust program's five (the model and its drifted
    copies) on two threads, each plant's work being mostly numpy and BLAS calls that release the
    interpreter's lock: a round's checks (the simulation and the cover's descent; the panel's
    closed-loop check 2.7-3.1 s to 2.1-2.4 s, the same drive) and the response tables (the tablet's
    20 mm closed loop's five: 2.3-3.1 s to 1.6-1.9 s, the panel's 0.26 to 0.20 s); one plant here."""

    def __init__(self, plants: int):
        workers = min(plants, os.cpu_count() or 1, THREADS)
        self.pool = concurrent.futures.ThreadPoolExecutor(workers) if workers > 1 else None

    def map(self, work, items):
        return map(work, items) if self.pool is None else self.pool.map(work, items)

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown()

    def __enter__(self) -> "_PlantPool":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _local_peaks(values: np.ndarray) -> np.ndarray:
    """Indices of the local maxima of ``values`` (1-D), its ends included."""
    if values.size < 3:
        return np.arange(values.size)
    inner = np.flatnonzero((values[1:-1] >= values[:-2]) & (values[1:-1] >= values[2:])) + 1
    ends = [i for i, ok in ((0, values[0] >= values[1]), (values.size - 1, values[-1] >= values[-2])) if ok]
    return np.union1d(inner, ends).astype(int)
