"""Identifiers for close and heavily damped modes: LSCF poles refined by a band fit, and ``auto``.

``mdof_fit`` needs no peak: the measured band is cut into overlapping half octaves, each gets its
stabilization diagram (:mod:`.lscf`), the poles picked from it are refined by the nonlinear
band fit with their neighbours (:func:`~.estimators.fit_band`), and the modal constants come by
least squares with residual terms (LSFD, :func:`~.estimators.constants_of`). ``auto_fit``
keeps what the SDOF fit resolves (it is faster and holds better under noise) and takes the
MDOF fit's modes elsewhere: in the bands of unresolved peaks and on shoulders no peak shows.
"""

from __future__ import annotations

import numpy as np

from modalctl.model.modes import ModelError

from .estimators import (
    FAIR_ERROR,
    NOISE,
    Modes,
    constants_of,
    half_width,
    modes_from_rows,
    sdof_fit,
)
from .band_fit import fit_band
from .coarse import coarse_rows, joint_reach
from .frf import FRF, mobility
from .lscf import DAMPING_SCATTER, SCATTER, pick_poles, stabilization

EDGE_OF_BAND = "too few bins between the pole and the edge of the measurement"
DOUBTFUL = "doubtful: stable in too few LSCF orders"
HIDDEN = "its own response at its resonance is a small share of the measured one: the band's response is another's"
UNSEEN = "only the noise test holds it (misfit above the fair limit) and no LSCF order shows a pole there"

__all__ = ["mdof_fit", "auto_fit", "bands", "refine", "MAX_ORDER", "OVERLAP"]

MAX_ORDER = 80  # highest LSCF order per band
RATIO = 2 ** 0.5  # bands are half octaves: few modes each, even on a plate
OVERLAP = 0.25  # each band is analysed this share wider on each side; its poles are kept in the band only
EDGE = 0.005  # relative slack of a band's core (the poles found twice are merged by distinct)
DOMINANCE = 0.8  # a pole's own response at its resonance is at least this share of the measured at one row at
# least (own_share): less, LSCF stabilized a computational pole (the wheel's 244 and 364 Hz at 0.05% damping,
# 0.40 and 0.60; the tool-tip's 902, 1000, 1808 and 1917 Hz, 0.10-0.52, each returned or not as a change of
# 1e-13 in the file fell); the five real sets' modes returned 0.97-6.0 (benchmarks/identify_real.py)
BAND = 3.0  # the refining fit covers this many half-power half-widths around each pole


def bands(f_low: float, f_high: float) -> list[tuple[float, float, float, float]]:
    """Bands in the ratio ``RATIO`` covering ``[f_low, f_high]`` (Hz): ``(core_low, core_high,
    low, high)`` each, the analysed band ``OVERLAP`` wider than its core on each side (within
    the measurement)."""
    f_low = max(f_low, f_high / 2**12)
    edges = f_low * RATIO ** np.arange(0, np.ceil(np.log(f_high / f_low) / np.log(RATIO)) + 1)
    edges[-1] = f_high
    return [(a, b, max(f_low, a / (1 + OVERLAP)), min(f_high, b * (1 + OVERLAP))) for a, b in zip(edges, edges[1:])]


def refine(frf: FRF, poles: np.ndarray) -> np.ndarray:
    """Poles ``(f, zeta)`` refined by the band fit, groups of overlapping bands fitted together, shape (k, 2),
    by frequency; a group whose fit leaves the diagram's clusters keeps LSCF's poles (:func:`_within_cluster`)."""
    df = frf.line_spacing
    poles = np.asarray(poles, float).reshape(-1, 2)
    poles = poles[np.argsort(poles[:, 0])]
    halves = np.array([half_width(poles[:, 0], poles[:, 1], i, df, BAND) for i in range(len(poles))])
    refined = poles.copy()
    start = 0
    while start < len(poles):
        stop = start + 1
        while stop < len(poles) and poles[stop, 0] - halves[stop] < poles[stop - 1, 0] + halves[stop - 1]:
            stop += 1
        lo, hi = poles[start, 0] - halves[start], poles[stop - 1, 0] + halves[stop - 1]
        others = np.delete(poles, np.arange(start, stop), axis=0)
        group = fit_band(frf, poles[start:stop], (lo + hi) / 2, (hi - lo) / 2, fixed=others, general=True)
        refined[start:stop] = _within_cluster(group, poles[start:stop])
        start = stop
    return refined


def _within_cluster(refined: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """``refined`` (k, 2), one group's fit, or LSCF's ``poles`` for the whole group where the fit moved any
    pole out of the diagram's cluster: by more than ``SCATTER`` of its half-power half-width, or its damping
    by more than a third (the tolerances the picker's clusters hold, :func:`~.lscf.pick_poles`), or out of
    the band (the same, a fortiori). A group's fit is as right as the poles it is given: where the diagram
    put one pole for two modes (the aircraft's 125.21 and 125.58 Hz, split later by :mod:`.multiref`), the
    group's other poles take up what that one leaves (135.52 Hz to 134.59 Hz at a damping of 2.5%, from
    0.95%, and 130.04 Hz to 129.85 Hz with it), which the diagram, stable over many orders, does not show."""
    f, zeta = poles[:, 0], poles[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        near = np.abs(refined[:, 0] - f) <= SCATTER * zeta * f
        ratio = refined[:, 1] / zeta
    kept = near & (ratio >= 1 / (1 + DAMPING_SCATTER)) & (ratio <= 1 + DAMPING_SCATTER)  # not finite: not kept
    return refined if kept.all() else poles


def _rows(frf: FRF, poles: np.ndarray) -> list:
    """``(f, zeta, constants, misfit, resolved, reason)`` of each stable, converged pole.

    The misfit is that of the pole with any shape (complex ones too: non-proportional
    damping), :func:`~.estimators.modal_constants` with ``general``; a pole is returned when
    it explains its band at least fairly (``FAIR_ERROR``; LSCF counted the poles) or to within
    the measurement noise, and that noise fixes its frequency.
    """
    rows = []
    for k, (f, z) in enumerate(poles):
        try:
            fit = constants_of(frf, poles[:, 0], poles[:, 1], k, BAND, general=True, counted=True)
        except ModelError:  # at the edge of the measurement
            rows.append((f, z, np.zeros(frf.values.shape[0]), np.inf, False, EDGE_OF_BAND))
            continue
        share = own_share(frf, f, z, fit.constants)
        if fit.resolved and not share >= DOMINANCE:  # a share not a number: left out too
            rows.append((f, z, fit.constants, fit.misfit, False, f"{HIDDEN} ({share:.2f}, at least {DOMINANCE:g})"))
            continue
        rows.append((f, z, fit.constants, fit.misfit, fit.resolved, fit.reason))
    return rows


def own_share(frf: FRF, f: float, zeta: float, constants: np.ndarray) -> float:
    """The pole's own response at the line nearest its resonance over the measured one there, at the
    row where it is largest: about one or more where it is a mode (at the points it moves most it makes
    the response), small where every row's response there is another's."""
    k = int(np.argmin(np.abs(frf.frequencies - f)))
    own = np.abs(mobility(frf.frequencies[k:k + 1], np.array([f]), np.array([zeta]), np.asarray(constants)[None, :]))
    measured = np.abs(frf.values[:, k])
    return float(np.max(own[:, 0] / np.maximum(measured, np.finfo(float).tiny)))


def band_poles(frf: FRF, core_low: float, core_high: float, low: float, high: float) -> tuple[np.ndarray, np.ndarray]:
    """Poles and doubtful poles (``(f, zeta)`` rows) that LSCF stabilizes in ``[low, high]``,
    those inside ``[core_low, core_high)`` (Hz, ``EDGE`` wider) only."""
    bins = int(np.count_nonzero((frf.frequencies >= low) & (frf.frequencies <= high)))
    order = min(MAX_ORDER, 2 * ((bins - 2) // 4))
    if order < 4:
        return np.zeros((0, 2)), np.zeros((0, 2))
    poles, doubtful = pick_poles(stabilization(frf, low, high, order))
    slack = 1 + EDGE  # a pole on the edge of two bands may be estimated just outside either core
    inside = lambda p: p[(p[:, 0] >= core_low / slack) & (p[:, 0] < core_high * slack)]  # noqa: E731
    return inside(poles), inside(doubtful)


def distinct(poles: np.ndarray) -> np.ndarray:
    """Poles ``(f, zeta)`` by frequency, one of each pair closer than a quarter of a half-power
    half-width (a pole on the edge of two bands is found by both)."""
    poles = poles[np.argsort(poles[:, 0])]
    keep = np.ones(len(poles), bool)
    for i in range(1, len(poles)):
        if poles[i, 0] - poles[i - 1, 0] < 0.25 * poles[i, 1] * poles[i, 0]:
            keep[i] = False
    return poles[keep]


def mdof_fit(frf: FRF, threshold_db: float = 3.0, min_frequency: float | None = None) -> Modes:
    """Modes from LSCF stabilization over half-octave bands, refined, with LSFD constants.

    Parameters
    ----------
    frf : FRF
    threshold_db : float
        Unused (no peaks are picked); kept for the identifier interface.
    min_frequency : float, optional
        Ignore poles below this (Hz).
    """
    f_low = max(frf.frequencies[0], min_frequency or 0.0)
    found, doubtful = [], []
    for band in bands(f_low, frf.frequencies[-1]):
        p, d = band_poles(frf, *band)
        found.append(p)
        doubtful.append(d)
    poles, doubtful = distinct(np.vstack(found)), np.vstack(doubtful)
    rows = []
    if len(poles):
        rows += _rows(frf, refine(frf, poles))
    returned = np.array([r[0] for r in rows if r[4]])
    for f, z in doubtful:
        if returned.size == 0 or np.min(np.abs(returned - f)) > z * f:
            rows.append((f, z, np.zeros(frf.values.shape[0]), np.inf, False, DOUBTFUL))
    return modes_from_rows(rows, frf.values.shape[0], "mdof")


def auto_fit(frf: FRF, threshold_db: float = 3.0, min_frequency: float | None = None) -> Modes:
    """The SDOF fit where it resolves a peak, the MDOF fit everywhere else.

    A mode (or a doubtful pole) of the MDOF fit is taken when no resolved SDOF mode lies within
    its half-power half-width; an unresolved SDOF peak is dropped when a mode taken from the MDOF
    fit lies within its half-power band, and reported otherwise. An SDOF mode that only the noise
    test holds (its misfit above ``FAIR_ERROR``) is left out, said why, unless the MDOF fit saw a
    pole there too: in a cluster of heavily damped modes hidden in the noise, one pole fits the
    noise as well as three and lands between them.
    """
    single = sdof_fit(frf, threshold_db, min_frequency)
    try:
        multi = mdof_fit(frf, threshold_db, min_frequency)
    except ModelError:
        return single
    sure = single.frequencies[single.resolved]

    def seen_by_sdof(i: int) -> bool:
        f, z = multi.frequencies[i], multi.damping[i]
        return sure.size > 0 and bool(np.min(np.abs(sure - f)) <= z * f)

    new = [i for i in range(multi.n_modes)
           if (multi.resolved[i] or multi.reasons[i] == DOUBTFUL) and not seen_by_sdof(i)]
    kept = [i for i in new if multi.resolved[i]]
    taken, taken_damping = multi.frequencies[kept], multi.damping[kept]

    def replaced(i: int) -> bool:  # within its half-power band; a fit's damping of zero, negative or not a number
        f, z = single.frequencies[i], single.damping[i]  # says nothing of its band: then within the taken mode's
        reach = 2 * z * f if np.isfinite(z) and z > 0 else 2 * taken_damping * taken
        return not single.resolved[i] and bool(np.any(np.abs(taken - f) <= reach))

    def unseen_by_lscf(i: int) -> bool:  # held only by the noise test, and no LSCF order shows a pole there
        f, z = single.frequencies[i], single.damping[i]
        weak = single.resolved[i] and single.misfit[i] > FAIR_ERROR
        return weak and not (multi.n_modes and np.min(np.abs(multi.frequencies - f)) <= z * f)

    rows = [(*single.row(i)[:4], False, UNSEEN) if unseen_by_lscf(i) else single.row(i)
            for i in range(single.n_modes) if not replaced(i)]
    rows = coarse_rows(frf, rows + [multi.row(i) for i in new], skip=(NOISE,))
    return modes_from_rows(rows + _unsaid(multi, rows, frf.line_spacing), frf.values.shape[0], "auto")


def _unsaid(multi: Modes, rows: list, df: float) -> list:
    """The MDOF fit's poles left out for a reason of their own (not doubtful: those are weighed above)
    that no row stands for already (none within the pole's half-power half-width, or the lines a joint
    fit searches, :func:`~.coarse.coarse_rows`): left out and said so, not dropped (the aircraft's
    26.4 Hz, one pole explaining its band poorly, was in no list; the tool-tip's 900.7 Hz is said by a
    doubtful pole at 898.1 Hz)."""
    said = np.array([r[0] for r in rows])
    out = []
    for i in np.flatnonzero(~multi.resolved):
        f, z = multi.frequencies[i], multi.damping[i]
        reach = max(z * f if np.isfinite(z) and z > 0 else 0.0, joint_reach(df))
        if multi.reasons[i] != DOUBTFUL and not (said.size and np.nanmin(np.abs(said - f)) <= reach):
            out.append(multi.row(i))
    return out
