"""Loops for close modes: one multivariable Kalman observer and LQ feedback per cluster (the ``cluster`` plugin).

Each kept mode is read by a lock-in at its carrier. Two loops whose lock-in bands overlap read each
other: loop j's command moves mode j (and, through the structure, every mode near it), and what
that adds to loop i's reading rotates at the carriers' difference in loop i's frame and passes its
lock-in. :func:`~modalctl.loops.close_modes.find_clusters` says which kept modes do (the rule is in its docstring) and
:class:`ClusterControl` controls each such group as one plant; isolated modes keep the per-mode
LQG loops of :mod:`modalctl.loops.lqg`.

The cluster's model is :func:`~modalctl.loops.design.cluster_model` (the one
:func:`~modalctl.loops.design.cluster_poles` predicts stability with): every mode of the model within
:data:`OBSERVED_NEAR` lock-in corners of the cluster's carriers (unkept modes too; the others as their
static gain) as a state driven by the loops' commands through its
actuator gains, read through each loop's sensor weights, then each loop's lock-in low-pass; the
static leak the runtime removes is taken off after the lock-in, as the runtime does, on the command
last sent (the newest in flight; the plant takes the oldest).

The frame. In each loop's own frame a neighbour's contribution turns at the carriers' difference:
the cluster's model is time-varying there. In one common frame, rotating at the cluster's mean
carrier ``w0``, it is time-invariant: mode m is ``x' = (p_m - j w0) x + ...``, loop i's lock-in is
its Butterworth moved to ``w_i - w0`` (a complex filter), and every loop's command and reading are
turned by ``exp(+- j (w_i - w0) t)`` on the way in and out, at the time the board plays or reads
them (the board's carriers start at phase 0 at the shot's first sample). The board's ramp between
periods is a first-order hold (python-control's ``c2d(..., "foh")``); a command computed after the
reading of period n reaches its value ``lead`` periods later. Each loop integrates its error in its
own frame (a constant error there is what must vanish); in the common frame that integrator is a
resonator at ``w_i - w0``: ``I[m+1] = exp(j (w_i - w0) T) (I[m] + z[m])``.

Not modelled: the touch's coupling ``c phi_k phi_j`` (the finger's damping and place are unknown
to this controller: it would need the touch estimator's, which reads the modes through per-mode
channels: issue 37 item 2), and drift (the observer's process noise stands for it, as per-mode LQG).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import control
import numpy as np
from scipy import sparse
from scipy.linalg import block_diag

from modalctl.forked import beside
from modalctl.model.modes import drift_cases
from modalctl.threads import serial_blas

from . import kernels
from .close_modes import Clusters, find_clusters
from .controller import Controller, LoopDesign, LoopPlant
from .design import _real, _series, cluster_model, design_loops, pi_controller
from .lockin import PeriodTurns
from .lqg import NOISE_FLOOR, LQGControl, observer_loop_radius
from .sensing import feedthrough

__all__ = ["ClusterControl", "drift_radius", "closed_loop_radius"]

INTEGRAL = 1 / 4  # the integrators' weight, times the crossover (rad/s) and the period (as lqg's)
PROCESS = 1.0  # the process noise, in units of lqg's
ALONE = {"lqg": LQGControl, "pi": pi_controller}  # the loops of the modes in no cluster (ClusterControl's alone)
NONE_SENT = np.zeros(0, complex)  # the commands sent before the first update: none (kernels.cluster_period)
BESIDE = 4  # clusters from which half their laws are designed in a forked child (its fork and answer: ~20 ms)
# a law is kept where, at its worst over the drift band, it grows at most this much over the shot's periods (a
# radius of 1.00001 at +1% is x1.005 over a 25 ms shot's 500, and kept: refused at radius 1, plate-glass's tracked
# shot lost its 40 Hz pair's law to per-mode loops, tau 0.967 -> 0.944, margin 0.527 -> 0.604; the tablet's
# 30 mm bump refuses the same 12 groups, the least x1.08 over its 580 periods)
GROWTH = 1.05
# lock-in corners from a cluster's carriers within which its observer keeps a mode's dynamics (beyond, the lock-in
# passes 5^-4 of it): cluster_poles' 20 made panel-rounded's 18 laws 1,132 states, an update 206 us; 5: 654 states,
# 46 us, the finger benchmark's give-back within 0.1 point (3: 87.6% on the panel where 5 and 8 give 88.7, 88.6%)
OBSERVED_NEAR = 5.0


@dataclass(frozen=True)
class _Law:
    """One cluster's observer and LQ law, real I/Q form (complex numbers as interleaved pairs).

    ``A, B, C``: the observed model (plant, then the delay line of the commands), ``M`` the
    current-estimate Kalman gain, ``K, Ki`` the state and integrator feedback, ``turn`` the
    integrators' turn per period, ``offsets`` (k,) each carrier less the frame's (rad/s), ``lead`` the
    periods from a reading to its command's full value.
    """

    loops: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    M: np.ndarray
    K: np.ndarray
    Ki: np.ndarray
    turn: np.ndarray
    offsets: np.ndarray
    lead: int


def _observed_model(plant: LoopPlant, loops: np.ndarray, carrier: float) -> tuple:
    """The cluster's discrete model in the frame of ``carrier`` (Hz), real I/Q form: (A, B, C, G, offsets, lead)
    of the state ``[plant, commands in flight (lead)]``, input the command computed this period,
    output the readings less the runtime's leak; ``G`` puts process noise on the modes' states; ``lead``
    the periods in flight."""
    s, model = plant.schedule, plant.model
    modes = np.asarray(plant.modes)[loops]
    leak = feedthrough(model, modes, np.asarray(s.sensors)[loops], np.asarray(s.weights)[:, loops])
    near, filters, offsets = cluster_model(s, loops, model, carrier, OBSERVED_NEAR)
    sampled = control.c2d(control.ss(*_real(*_series(near, filters))), 1 / s.control_rate, method="foh")
    a, b, c, d = (np.asarray(x, float) for x in (sampled.A, sampled.B, sampled.C, sampled.D))
    k2, n, lead = 2 * loops.size, a.shape[0], max(1, int(round(plant.latency)))
    size = n + lead * k2
    big_a, big_b, big_c = np.zeros((size, size)), np.zeros((size, k2)), np.zeros((k2, size))
    big_a[:n, :n], big_a[:n, size - k2:] = a, b  # the plant takes the oldest command in flight
    big_a[n + k2:, n:size - k2] = np.eye((lead - 1) * k2)  # the delay line moves on
    big_b[n:n + k2] = np.eye(k2)
    big_c[:, :n], big_c[:, size - k2:] = c, d
    # the runtime takes leak x the command last sent (the newest in flight) off the readings, after the lock-in, in
    # each loop's frame: the slot holds it turned to when it is reached, lead - 1 periods after this reading
    unturn = np.exp(-1j * offsets * (lead - 1) / s.control_rate)
    big_c[:, n:n + k2] -= _real(np.diag(leak * unturn))[0]
    g = np.zeros((size, 2 * near[0].shape[0]))
    g[:g.shape[1]] = np.eye(g.shape[1])  # the modes' states come first in the series
    return big_a, big_b, big_c, g, offsets, lead


def _frame(plant: LoopPlant, loops: np.ndarray) -> float:
    """The carrier (Hz) of a cluster's common frame: the mean of its loops'."""
    return float(np.mean(np.asarray(plant.schedule.carriers)[loops]))


def _design(plant: LoopPlant, loops: np.ndarray, crossover: np.ndarray, noise: np.ndarray) -> _Law:
    """The observer and LQ law of the cluster ``loops`` (positions in the kept modes)."""
    period = 1 / plant.control_rate
    a, b, c, g, offsets, lead = _observed_model(plant, loops, _frame(plant, loops))
    size, k2 = a.shape[0], 2 * loops.size
    turn = _real(np.diag(np.exp(1j * offsets * period)))[0]
    big_a = np.block([[a, np.zeros((size, k2))], [turn @ c, turn]])  # I' = turn (I + z)
    big_b = np.vstack([b, np.zeros((k2, k2))])
    wc = np.repeat(2 * np.pi * crossover[loops], 2)
    q = np.zeros((size + k2, size + k2))
    q[:size, :size] = c.T @ c
    q[size:, size:] = np.diag((wc * period * INTEGRAL) ** 2)  # the integrators: slower than the loops (as lqg)
    r = np.diag((0.5 / wc) ** 2)
    gain = np.asarray(_solved(control.dlqr, big_a, big_b, q, r)[0])
    level = np.max(plant.level[loops]) if plant.level is not None else 1.0
    # as lqg's: the detuning a drift makes at the planned level, on each mode's state (twice the velocity
    # envelope: its residue is about a half); the cluster's highest carrier and largest level for all
    w = PROCESS * (2 * 2 * np.pi * plant.drift * np.max(plant.frequencies[loops]) * period * level) ** 2
    v = np.diag(np.repeat(noise[loops] ** 2, 2))
    # the Riccati equation in units of the process noise (its solution scales with both noises): scipy's
    # reordering failed on plate-glass's modes 42-43 at w 1e-10, v 1e-12 (the cluster left to per-mode loops)
    unit = w if w > 0 else 1.0
    prior = unit * np.asarray(_solved(control.dlqe, a, g, c, (w / unit) * np.eye(g.shape[1]), v / unit)[1])
    m = prior @ c.T @ np.linalg.inv(c @ prior @ c.T + v)
    return _Law(loops, a, b, c, m, gain[:, :size], gain[:, size:], turn, offsets, lead)


def _solved(riccati, *matrices):
    """``riccati(*matrices)`` (python-control's dlqr or dlqe); scipy's failed reordering of an
    ill-conditioned pencil (a ValueError, panel-rounded's modes 30-31) raised as the LinAlgError a
    pencil without a solution gives: the cluster keeps per-mode loops. Any other error is a fault."""
    try:
        return riccati(*matrices)
    except ValueError as error:
        if "Reordering" not in str(error):
            raise
        raise np.linalg.LinAlgError(str(error)) from error


def _subplant(plant: LoopPlant, loops: np.ndarray) -> LoopPlant:
    """What per-mode LQG needs of ``plant``'s loops ``loops`` (positions in the kept modes)."""
    pick = lambda x: None if x is None else np.asarray(x)[loops]  # noqa: E731
    return LoopPlant(plant.frequencies[loops], plant.damping[loops], plant.bandwidths[loops], plant.control_rate,
                     plant.latency, pick(plant.noise), pick(plant.level), plant.drift, pick(plant.detuning))


def closed_loop_radius(law: _Law) -> float:
    """Largest |eigenvalue| of the cluster's nominal model under its observer-based law (below 1: stable):
    :func:`~modalctl.loops.lqg.observer_loop_radius` with the integrators' turn (each loop integrates in its
    own frame, which turns in the common one)."""
    return observer_loop_radius(law.A, law.B, law.C, law.K, law.Ki, law.M, law.turn)


def drifted_plants(plant: LoopPlant) -> list[tuple[float, LoopPlant]]:
    """``(shift, plant)`` with the plant's model drifted uniformly by each of
    :func:`~modalctl.model.modes.drift_cases` (``plant.drift``): made once for every cluster (a model's
    checks on its shapes took 41% of the drift checks on the tablet when made per cluster)."""
    return [(shift, replace(plant, model=plant.model.drifted(shift))) for shift in drift_cases(plant.drift)]


def drift_radius(plant: LoopPlant, law: _Law, drifted: list | None = None) -> tuple[float, float]:
    """The cluster's closed loop at its worst over the drift band: ``(radius, drift)``, the largest
    |eigenvalue| (below 1: stable) of the structure drifted uniformly by each of
    :func:`~modalctl.model.modes.drift_cases` (``plant.drift``) under the law designed on the model, and
    the drift (a fraction) where it is; ``(0, 0)`` with no band (the nominal loop is
    :func:`closed_loop_radius`'s).

    A cluster's observer predicts its modes' beating from their carriers' spacing: a drift moves the modes
    from the carriers, and where two of them are close and their loops' gains high, the prediction's error
    turns the loop unstable (the tablet's 30 mm bump, 1% drift: 12 of its 37 linked groups, radius 1.0001 to
    261; the shot had been stopped by the supervisor). Per-mode loops hold there. :class:`ClusterControl`
    keeps a law whose radius here grows at most ``GROWTH`` over the shot's periods. ``drifted``:
    :func:`drifted_plants` of ``plant``, if made."""
    worst, frame = (0.0, 0.0), _frame(plant, law.loops)
    for shift, truth in drifted_plants(plant) if drifted is None else drifted:
        at, bt, ct = _observed_model(truth, law.loops, frame)[:3]
        radius = observer_loop_radius(law.A, law.B, law.C, law.K, law.Ki, law.M, law.turn, truth=(at, bt, ct))
        worst = max(worst, (radius, shift))
    return worst


def _judged(plant: LoopPlant, loops: np.ndarray, crossover: np.ndarray, noise: np.ndarray, drifted: list,
            periods: int) -> tuple:
    """A cluster's law and nominal radius, ``(law, radius, None)``, or ``(None, None, why)``: no law, unstable on
    the model, or growing more than ``GROWTH`` over the shot's ``periods`` at the drift band's worst
    (:func:`drift_radius`)."""
    try:
        law = _design(plant, loops, crossover, noise)
    except np.linalg.LinAlgError as error:  # no observer or LQ law (_solved): per-mode loops
        return None, None, f"no law ({error})"
    stable = closed_loop_radius(law)
    if stable >= 1:  # unstable on the model: no drift to check
        return None, None, f"its law unstable on the model (spectral radius {stable:.5f})"
    radius, drift = drift_radius(plant, law, drifted)  # its growth over the shot, log10 (inf: radius not a number)
    decades = periods * np.log10(max(radius, np.finfo(float).tiny)) if np.isfinite(radius) else np.inf
    if decades <= np.log10(GROWTH):
        return law, stable, None
    grows = f"x{10 ** decades:.3g}" if decades < 300 else f"x1e{decades:.0f}"
    return None, None, (f"its law unstable at {100 * drift:+g}% drift (spectral radius {radius:.5f}: {grows} "
                        f"over the shot's {periods} periods)")


def _judged_beside(groups: tuple, judge) -> list:
    """``judge(group)`` for every group, in order, BLAS on one thread (the laws' matrices are small: its threads
    only spin), from :data:`BESIDE` groups on about half the work (sizes cubed) in a forked child
    (:func:`modalctl.forked.beside`). The tablet's 20 mm bump, 41 laws: 6.9 s so far, 5.5 s on two Python threads
    (the Python around LAPACK holds the lock), 3.0 s on one BLAS thread, 2.0 s so in two processes."""
    here, there, loads = [], [], [0, 0]
    for i in sorted(range(len(groups)), key=lambda i: -len(groups[i])):  # the largest first, to the lighter side
        side = int(loads[1] < loads[0]) if len(groups) >= BESIDE else 0
        (there if side else here).append(i)
        loads[side] += len(groups[i]) ** 3
    with serial_blas():  # a forked child keeps it
        child = beside(lambda: [judge(groups[i]) for i in there]) if there else None
        try:
            answers = dict(zip(here, (judge(groups[i]) for i in here)))
        except BaseException:  # an error or Ctrl-C here: no child designing on behind it
            if child is not None:
                child.stop()
            raise
    if child is not None:
        answers.update(zip(there, child.result()))
    return [answers[i] for i in range(len(groups))]


class ClusterControl(Controller):
    """Per-mode loops (LQG or PI: ``alone``), and one multivariable observer and LQ law per cluster of close modes.

    Without the plant's ``model`` (and ``schedule``) there is no cluster to model: the controller is the
    isolated modes' loops (``alone``) on every mode, and so it is where :func:`find_clusters` finds none.

    Parameters
    ----------
    plant : LoopPlant
        With ``model``, ``modes`` and ``schedule`` (as :func:`~modalctl.loops.shot.parts_for` makes it).
    clusters : Clusters, optional
        The groups to control together (default: :func:`find_clusters` on the LQG loops' crossovers, and
        their gain margins with ``rule`` "margin"; "band": the lock-in corners' rule).
    rule : {"margin", "band"}
    alone : {"lqg", "pi"}
        The loops of the modes in no cluster: per-mode LQG (:mod:`~modalctl.loops.lqg`) or the PI loops
        (:func:`~modalctl.loops.design.pi_controller`; what the default closed loop runs).

    Attributes
    ----------
    clusters : Clusters
        The groups controlled together.
    refused : list of (tuple, str)
        The groups asked for whose observer or LQ law has no solution, whose law is unstable on the
        model, or grows more than ``GROWTH`` over the shot at the drift band's worst
        (:func:`drift_radius`), and why: their modes keep per-mode loops.
    inner : Controller or None
        The per-mode loops of the modes in no cluster (``alone``; None when every mode is in one).
    spectral_radius : ndarray, shape (c,)
        Each cluster's nominal closed loop (:func:`closed_loop_radius`; below 1: stable).
    innovation : ndarray, shape (c,)
        The last innovation of each loop in a cluster (in ``clusters.groups``' order), complex, in its own
        frame: the reading less the observer's one-period prediction (zero where the model is the structure).
    """

    # to know the period (the frames turn with time) and the commands the supervisor let through; as another
    # controller's inner one not told (the touch controller tells it), it counts its updates and takes its own
    # commands for those sent
    observes = True

    def __init__(self, plant: LoopPlant, clusters: Clusters | None = None, rule: str = "margin", alone: str = "lqg"):
        if rule not in ("margin", "band"):  # a misspelt rule would otherwise be the corners' rule, unsaid
            raise ValueError(f"cluster controller: rule must be 'margin' or 'band', got {rule!r}")
        if alone not in ALONE:
            raise ValueError(f"cluster controller: alone must be one of {sorted(ALONE)}, got {alone!r}")
        pi = design_loops(plant.frequencies, plant.damping, plant.bandwidths, plant.control_rate,
                          latency=plant.latency)  # the crossovers the LQ loops aim at (as per-mode LQG's design)
        nan = np.full(plant.frequencies.size, np.nan)
        self.design = LoopDesign(nan, nan, pi.crossover_hz, pi.phase_margin_deg, pi.gain_margin_db)
        modelled = plant.model is not None and plant.schedule is not None and plant.modes is not None
        if clusters is None:
            margins = self.design.gain_margin_db if rule == "margin" else None
            clusters = find_clusters(plant.frequencies, plant.bandwidths, self.design.crossover_hz, margins) \
                if modelled else Clusters((), ())
        if clusters.groups and not modelled:
            raise ValueError("cluster controller: clusters need the plant's model, modes and schedule")
        level = np.ones(plant.frequencies.size) if plant.level is None else plant.level
        noise = np.maximum(level * NOISE_FLOOR, 0 if plant.noise is None else plant.noise)  # as lqg's
        self.laws, self.refused = [], []  # refused: (group, why) of the clusters left to per-mode loops
        drifted = drifted_plants(plant) if clusters.groups else []
        periods = max(plant.schedule.reference.shape[1], 1) if modelled else 0  # how long a law must hold
        nominal = []  # the kept laws' nominal radii
        judged = _judged_beside(clusters.groups, lambda group: _judged(
            plant, np.array(group), self.design.crossover_hz, noise, drifted, periods))
        for group, (law, stable, why) in zip(clusters.groups, judged):
            if law is None:
                self.refused.append((group, why))
            else:
                self.laws.append(law)
                nominal.append(stable)
        self.clusters = replace(clusters, groups=tuple(tuple(law.loops.tolist()) for law in self.laws),
                                refused=tuple(self.refused))
        clustered = np.concatenate([law.loops for law in self.laws] or [np.zeros(0, int)])
        self._alone = np.setdiff1d(np.arange(plant.frequencies.size), clustered)  # the alone loops' modes
        self.inner = ALONE[alone](_subplant(plant, self._alone)) if self._alone.size else None
        self.spectral_radius = np.array(nominal)
        self._stack(1 / plant.control_rate)
        self.reset()

    def _stack(self, period: float) -> None:
        """Every cluster's law as one block-diagonal law: a period is a dozen products, not a dozen per cluster."""
        laws = self.laws
        self._idx = np.concatenate([law.loops for law in laws]) if laws else np.zeros(0, int)
        lead = {law.lead for law in laws}.pop() if laws else 1
        self._angle = np.concatenate([law.offsets for law in laws] or [np.zeros(0)]) * period  # rad a period
        spin = np.exp(1j * self._angle)
        self._ahead, self._sent_ahead = spin ** lead, spin ** (lead - 1)
        # sparse: the laws' blocks, and within them the modes' states (a 2 x 2 block each) and the delay line,
        # are mostly zeros (panel-rounded's 18 laws: 578 states, 8,132 of A's 334,084 entries; A x 31 -> 7 us);
        # compiled (kernels.cluster_period), a sparse product costs its work alone, and a small law's as little as a
        # dense one's (within 1.5 us below 256 states, 2026-11-30)
        # (B is not stacked: it puts the command computed into the delay line's first slot, the rows _slot)
        self._A, self._C, self._M, self._K, self._Ki = (
            sparse.csr_array(block_diag(*(getattr(law, name) for law in laws))) for name in ("A", "C", "M", "K", "Ki"))
        self._turn = PeriodTurns(self._angle)  # spin ** period: the frames' turn at a period
        self._join()
        slots, start = [], 0  # where each law's newest command in flight sits in the stacked state
        for law in laws:
            size, k2 = law.A.shape[0], 2 * law.loops.size
            slots.append(start + np.arange(size - law.lead * k2, size - (law.lead - 1) * k2))
            start += size
        self._slot = np.concatenate(slots) if slots else np.zeros(0, int)

    def _join(self) -> None:
        """A period in three products (:func:`~modalctl.loops.kernels.cluster_period`): ``[C; K; A] x`` (the
        prediction's reading, its feedback and next state), ``[K; A] M`` times the surprise (the same of the
        observer's correction ``M s``), and ``Ki`` times the integrals."""
        if not self.laws:  # nothing stacked (block_diag of none is (1, 0))
            return
        ka = sparse.vstack([self._K, self._A])
        cka, kam = sparse.csr_array(sparse.vstack([self._C, ka])), sparse.csr_array(ka @ self._M)
        self._laws = tuple((m.data, m.indices.astype(np.int64), m.indptr.astype(np.int64))  # one compiled signature,
                           for m in (cka, kam, sparse.csr_array(self._Ki)))  # whatever scipy's index type
        self._scratch = np.empty(cka.shape[0]), np.empty(kam.shape[0])

    def reset(self) -> None:
        if self.inner is not None:
            self.inner.reset()
        self._n, self._sent = 0, None
        self._x = np.zeros(sum(law.A.shape[0] for law in self.laws))  # every cluster's predicted state, real I/Q
        self._integral = np.zeros(self._idx.size, complex)  # in each loop's own frame
        self.innovation = np.zeros(self._idx.size, complex)  # the last period's, each loop's frame

    def hand_over(self, amount: np.ndarray) -> None:
        """The isolated loops' share of ``amount`` (k,) taken off their integrals. The clusters' laws keep
        theirs: moving each law's integrals through its ``Ki`` so that the period's command gave that much
        less measured plate-glass's 30 mm bump at 1% drift at margin 0.649, against 0.573 without (an
        observer-based law's integrals do not hold the drift's share alone)."""
        if self.inner is not None:
            self.inner.hand_over(np.asarray(amount)[self._alone])

    def scale(self, factor: float) -> None:
        """Multiply every feedback gain, the clusters' and the isolated loops' (a stability test)."""
        if self.inner is not None:
            self.inner.scale(factor)
        self._K, self._Ki = self._K * factor, self._Ki * factor
        self._join()

    def observe(self, period: int, envelope: np.ndarray, sent: np.ndarray) -> None:
        """The period (its reading's) and the commands sent (k,) before it. Readings lost since the last
        update (the runtime skipped it and held ``sent``): each law's state moves on by its model, the held
        command going out every period lost, as a period without a reading would."""
        sent = np.array(sent, complex)
        if self.laws and period > self._n:
            held, x = sent[self._idx], self._x
            for lost in range(self._n, period):
                now = self._turn(lost + 1)  # as update's: the frames' turn at that period's reading
                x[self._slot] = (held * now * self._sent_ahead).view(float)
                x = self._A @ x  # its rows of the delay line's first slot are zero: the held command enters
                x[self._slot] += (held * now * self._ahead).view(float)
            self._x = x
        self._n, self._sent = period, sent

    def update(self, error: np.ndarray, limit: np.ndarray) -> np.ndarray:
        """Commands (k,): the isolated modes' from per-mode LQG, the clusters' from their own laws."""
        command = np.zeros(error.shape, complex)
        if self.inner is not None:
            command[self._alone] = self.inner.update(error[self._alone], limit[self._alone])
        if not self.laws:
            self._n += 1
            return command
        now = self._turn(self._n + 1)  # the frames' turn now: the reading of period n is the model's (n + 1) T
        kernels.cluster_period(self._laws, (self._x, self._slot, NONE_SENT if self._sent is None else self._sent),
                               (now, self._ahead, self._sent_ahead), (error, np.asarray(limit, float), self._idx),
                               (self._integral, self.innovation), self._scratch, command)
        self._n += 1  # the next period's, unless observe says otherwise (a lost reading)
        return command
