"""What several inputs tell that their FRFs stacked do not: close modes, and modes one input sees.

One mode seen from several inputs (a roving hammer read by three accelerometers, a survey by
several patches) has one shape and one participation per input: around its pole the FRFs of
points ``p`` from inputs ``q`` are ``phi_p L_q / (j w - lambda)``, and the residues a pole fitted
to every input leaves, arranged points x inputs, have rank one. Two modes closer than their
half-power bands, which one pole may explain to a fair misfit, are seen by each input in its own
mix: the residues have a second singular value, the multi-reference counterpart of the second
curve of the complex mode indicator function (Shih et al. 1988). Where it is large, two poles
are fitted jointly on every input (:func:`~.estimators.fit_band`, started half a half-power width
each side) and each is checked as any pole is (:func:`~.estimators.constants_of`).

Measured on the University of Liege's aircraft model (three accelerometers, 68 points; the
benchmark ``identify_real``): the residues' second singular value is 0.22 of the first at the
pole returned between the published 125.21 and 125.58 Hz, at most 0.073 on the other modes the
lines resolve; split, the two poles land at 125.28 and 125.63 Hz. At a threshold of 0.05 its
single 130.0 Hz splits too (129.73 and 130.34 Hz: a spurious pair). The strip's (two
accelerometers) single modes reach 0.148 and 0.104, whose two-pole fits fail: kept as one at any
threshold down to 0.05. :data:`SECOND_SHAPE` stands between those.

The stacked FRFs' stabilization diagram is moved by every input: a mode one input sees clearly and
another hardly (the aircraft's 135.28 Hz, weak at the fin's accelerometer) may be stable in too few
orders to be kept (doubtful). :func:`rescue_by_inputs` gives such a pole a second reading: the band's
diagram of each input alone (the classical single-reference one); a pole it holds stable there, and
that one pole explains on every input to a fair misfit, is kept. On the aircraft, in the runs where
round-off leaves 135.28 Hz doubtful in the stacked diagram, it keeps it at 135.29 Hz (misfit 0.16),
and none of the sixteen doubtful poles below 32 Hz an input also holds (misfits 0.85-2.1).
"""

from __future__ import annotations

import numpy as np

from .coarse import CoarseRow, under_resolved
from .band_fit import _lstsq, fit_band, pole_basis
from .estimators import FAIR_ERROR, Modes, constants_of, half_width, modes_from_rows, neighbours
from .frf import FRF
from .mdof import DOUBTFUL, band_poles, bands

__all__ = ["SECOND_SHAPE", "second_shape", "split_by_inputs", "rescue_by_inputs", "by_inputs"]

NEAR_HALF_WIDTHS, NEAR_LINES = 10.0, 60  # the lines around a pole its fits here read (see _stacked_near)
SECOND_SHAPE = 0.15  # a pole whose residues' second singular value reaches this share of the first is two modes
# (single modes of real multi-input files: up to 0.073 and, with two poles not fitting, 0.148; see the module's doc)


def second_shape(frfs: list[FRF], frequencies: np.ndarray, damping: np.ndarray, k: int,
                 scales: list[float] | None = None) -> float:
    """The second singular value of mode ``k``'s residues over the inputs, as a share of the first.

    Parameters
    ----------
    frfs : list of FRF
        Each input's FRFs on the same points and lines, at least two.
    frequencies, damping : ndarray, shape (m,)
        Every pole found (Hz, ratio); its neighbours in the band are fitted with mode ``k``.
    scales : list of float, optional
        Each input's weight: its unit scale (:meth:`FRF.unit_scale`, as :meth:`FRF.stack` weighs
        them) by default.
    """
    scales = FRF.unit_scales(frfs, scales)
    df = frfs[0].line_spacing
    half = half_width(frequencies, damping, k, df)
    near = neighbours(frequencies, damping, k, half)
    keep = np.abs(frfs[0].frequencies - frequencies[k]) <= half
    basis = pole_basis(frfs[0].frequencies[keep], [(frequencies[k], damping[k]),
                                                   *zip(frequencies[near], damping[near])], frequencies[k])
    residues = np.column_stack([_lstsq(basis, c * f.values[:, keep].T)[0] for f, c in zip(frfs, scales)])
    s = np.linalg.svd(residues, compute_uv=False)
    return float(s[1] / s[0]) if s[0] > 0 else 0.0


def split_by_inputs(frfs: list[FRF], poles: Modes, scales: list[float] | None = None) -> tuple[Modes, list[str]]:
    """``poles`` (found on :meth:`FRF.stack` of ``frfs``) with every resolved pole whose residues
    show a second shape (:func:`second_shape` at least :data:`SECOND_SHAPE`) fitted as two, and a
    note on each. A pole the file's lines under-resolve (:func:`~.coarse.under_resolved`, fitted as a
    joint pole) is left as it is, and so is a pole whose split runs out of its band, loses a physical
    damping or leaves either half unresolved. ``scales``: each input's weight (default: its unit scale).
    """
    if len(frfs) < 2 or not poles.n_modes:
        return poles, []
    scales = FRF.unit_scales(frfs, scales)
    df = frfs[0].line_spacing
    f_all, z_all = poles.frequencies, poles.damping
    split, added, notes = [], [], []
    for k in range(poles.n_modes):
        f, zeta = f_all[k], z_all[k]
        if not poles.resolved[k] or under_resolved(f, zeta, df):
            continue
        share = second_shape(frfs, f_all, z_all, k, scales)
        if share < SECOND_SHAPE:
            continue
        stacked = _stacked_near(frfs, scales, f, half_width(f_all, z_all, k, df))
        pair = _two_poles(stacked, f_all, z_all, k)
        if pair is None:
            best = _best_input(frfs, stacked, f_all, z_all, k)
            said = "" if best is None else (f"; read at {best[1][0]:.2f} Hz on input {best[0]}, whose own FRFs "
                                            f"one pole explains best (misfit {best[2]:.2f} there)")
            notes.append(f"mode at {f:.2f} Hz: the inputs see it with two shapes (second singular value of its "
                         f"residues {share:.2f} of the first) but two poles do not fit its band: kept as one{said}")
            if best is not None:
                split.append(k)
                added.append(best[1])
            continue
        split.append(k)
        added += pair
        notes.append(f"mode at {f:.2f} Hz split into {pair[0][0]:.2f} and {pair[1][0]:.2f} Hz: the inputs see it "
                     f"with two shapes (second singular value of its residues {share:.2f} of the first, at least "
                     f"{SECOND_SHAPE:g})")
    return (_replaced(poles, split, added) if added else poles), notes


def _replaced(poles: Modes, dropped, added: list) -> Modes:
    """``poles`` without the modes ``dropped`` (indices), with the rows ``added``, by frequency
    (:func:`~.estimators.modes_from_rows`; each kept mode's joint pole carried along as a
    :class:`~.coarse.CoarseRow`)."""
    kept = [poles.row(i) if poles.poles[i] is None else CoarseRow(poles.row(i), poles.poles[i])
            for i in range(poles.n_modes) if i not in dropped]
    return modes_from_rows(kept + list(added), poles.constants.shape[1], poles.method)


def _best_input(frfs: list[FRF], stacked: FRF, frequencies: np.ndarray, damping: np.ndarray, k: int):
    """Mode ``k``, which the inputs see with two shapes that two poles do not fit, read on the input
    whose FRFs one pole explains best: ``(input, row, misfit)``, the row ``(f, zeta, constants, misfit,
    True, "")`` with the constants on every input (``stacked``); None when no input's fit resolves it
    within its half-power half-width of the joint pole. What makes the inputs disagree (another mode
    one of them sees, or a weak view through the noise) moves the joint pole: the aircraft's 135.28 Hz
    (published), jointly 135.52 Hz, on the wing tip's accelerometer alone 135.30 Hz at a misfit of
    0.03 (the fin's 0.98). It is as sure as its start and its neighbours: with the file changed by
    1e-13 the stacked diagram puts the pole at 135.27-135.52 Hz, and this reading lands at
    135.30-135.43 Hz."""
    f, zeta = frequencies[k], damping[k]
    half, others = _band_beside(frequencies, damping, k, frfs[0].line_spacing)
    best = None
    for q, frf in enumerate(frfs):
        pole = fit_band(frf, [(f, zeta)], f, half, fixed=others)[0]
        if not (abs(pole[0] - f) <= zeta * f and 0 < pole[1] < 0.5):
            continue
        moved_f, moved_z = frequencies.copy(), damping.copy()
        moved_f[k], moved_z[k] = pole
        fit = constants_of(frf, moved_f, moved_z, k)
        if fit.resolved and (best is None or fit.misfit < best[2]):
            best = (q, (moved_f, moved_z), fit.misfit)
    if best is None:
        return None
    moved_f, moved_z = best[1]
    fit = constants_of(stacked, moved_f, moved_z, k)
    if not fit.resolved:  # on every input together the moved pole is no mode: the joint one stands
        return None
    row = (float(moved_f[k]), float(moved_z[k]), fit.constants, fit.misfit, True, "")
    return best[0], row, best[2]


def _band_beside(frequencies: np.ndarray, damping: np.ndarray, k: int, df: float) -> tuple[float, list]:
    """Mode ``k``'s band half width (Hz) and the poles ``(f, zeta)`` reaching into it, held fixed in its fits."""
    half = half_width(frequencies, damping, k, df)
    near = neighbours(frequencies, damping, k, half)
    return half, list(zip(frequencies[near], damping[near]))


def _two_poles(stacked: FRF, frequencies: np.ndarray, damping: np.ndarray, k: int) -> list | None:
    """Mode ``k`` fitted as two poles on every row of ``stacked`` (its neighbours fixed), as two
    rows ``(f, zeta, constants, misfit, True, "")``; None when they leave the band, lose a
    physical damping, meet, or either is not resolved."""
    f, zeta = frequencies[k], damping[k]
    df = stacked.line_spacing
    half, others = _band_beside(frequencies, damping, k, df)
    pair = fit_band(stacked, [(f - zeta * f / 2, zeta), (f + zeta * f / 2, zeta)], f, half, fixed=others)
    if not all(abs(p - f) <= half and 0 < z < 0.5 for p, z in pair) or abs(pair[0, 0] - pair[1, 0]) < df:
        return None
    both_f = np.r_[np.delete(frequencies, k), pair[:, 0]]
    both_z = np.r_[np.delete(damping, k), pair[:, 1]]
    rows = []
    for j in (both_f.size - 2, both_f.size - 1):
        fit = constants_of(stacked, both_f, both_z, j)
        if not fit.resolved:
            return None
        rows.append((float(both_f[j]), float(both_z[j]), fit.constants, fit.misfit, True, ""))
    return sorted(rows, key=lambda r: r[0])


def by_inputs(frfs: list[FRF], poles: Modes, scales: list[float] | None = None) -> tuple[Modes, list[str]]:
    """``poles`` found on the stacked ``frfs`` read again input by input: doubtful poles one input
    holds (:func:`rescue_by_inputs`), then poles two modes share (:func:`split_by_inputs`); with a
    note on each change. ``scales``: each input's weight in the stack the poles were found on
    (default: its unit scale, as :meth:`FRF.stack`'s). One input: ``poles`` as they are."""
    if len(frfs) < 2:
        return poles, []
    scales = FRF.unit_scales(frfs, scales)
    rescued, kept = rescue_by_inputs(frfs, poles, scales)
    split, parted = split_by_inputs(frfs, rescued, scales)
    return split, kept + parted


def rescue_by_inputs(frfs: list[FRF], poles: Modes, scales: list[float] | None = None) -> tuple[Modes, list[str]]:
    """``poles`` with each doubtful pole (stable in too few orders of the stacked diagram) that the
    band's diagram of one input alone holds stable, within the larger half-power half-width of the
    two, and that one pole explains on every input to a misfit of at most ``FAIR_ERROR``, kept as a
    mode at that input's pole; a note on each. ``scales``: each input's weight (default: its unit scale)."""
    doubtful = [i for i in range(poles.n_modes) if poles.reasons[i] == DOUBTFUL]
    if len(frfs) < 2 or not doubtful:
        return poles, []
    scales = FRF.unit_scales(frfs, scales)
    lines = frfs[0].frequencies
    sure_f, sure_z = poles.frequencies[poles.resolved], poles.damping[poles.resolved]
    diagrams, kept, notes = {}, {}, []
    for i in doubtful:
        f, zeta = poles.frequencies[i], poles.damping[i]
        if not _fair(frfs, scales, sure_f, sure_z, f, zeta):
            continue  # one pole does not explain it where the stack put it: no input's diagram is read
        band = _band_of(f, lines[0], lines[-1])
        hits = [(abs(p[0] - f), q, tuple(p)) for q in range(len(frfs))
                for p in diagrams.setdefault((q, band), band_poles(frfs[q], *band)[0])
                if abs(p[0] - f) <= max(zeta, p[1]) * f]
        if not hits:
            continue
        _, q, (f_q, z_q) = min(hits)
        taken = np.r_[sure_f, [r[0] for r in kept.values()]]
        if taken.size and np.min(np.abs(taken - f_q)) <= z_q * f_q:
            continue  # a mode already returned, or this input's pole kept for another doubtful one
        fit = _fair(frfs, scales, sure_f, sure_z, f_q, z_q)
        if fit:
            kept[i] = (float(f_q), float(z_q), fit.constants, fit.misfit, True, "")
            notes.append(f"{f:.2f} Hz, doubtful on the inputs together, kept at {f_q:.2f} Hz: input {q}'s own "
                         f"diagram holds it stable and one pole explains it on every input (misfit {fit.misfit:.2f})")
    return (_replaced(poles, kept, kept.values()) if kept else poles), notes


def _band_of(f: float, f_low: float, f_high: float) -> tuple:
    """The band of :func:`~.mdof.bands` over ``[f_low, f_high]`` (Hz) whose core holds ``f``: where the
    stacked diagram found it."""
    every = bands(f_low, f_high)
    return next((b for b in every if b[0] <= f < b[1]), every[-1])


def _fair(frfs: list[FRF], scales: list[float], sure_f: np.ndarray, sure_z: np.ndarray, f: float, zeta: float):
    """The band fit of a pole ``(f, zeta)`` beside the modes returned (``sure_f``, ``sure_z``) on every
    input's rows when it resolves the pole to a misfit of at most ``FAIR_ERROR``, else None."""
    if not 0 < zeta < 0.5:
        return None
    trial_f, trial_z = np.r_[sure_f, f], np.r_[sure_z, zeta]
    df = frfs[0].line_spacing
    near = _stacked_near(frfs, scales, f, half_width(trial_f, trial_z, trial_f.size - 1, df))
    fit = constants_of(near, trial_f, trial_z, trial_f.size - 1)
    return fit if fit.resolved and fit.misfit <= FAIR_ERROR else None


def _stacked_near(frfs: list[FRF], scales: list[float], f: float, half: float) -> FRF:
    """Every input's rows stacked, each times its scale (:meth:`FRF.stack`'s layout and weights), on the lines
    a band fit about ``f`` of half width ``half`` (Hz) and its two poles' own fits may read
    (``NEAR_HALF_WIDTHS`` of it, and ``NEAR_LINES`` lines besides): a survey's sparse FRFs stacked whole
    were as large again as themselves (plate-glass's 3.6 GB)."""
    lines = frfs[0].frequencies
    keep = np.abs(lines - f) <= NEAR_HALF_WIDTHS * half + NEAR_LINES * frfs[0].line_spacing
    return FRF.stack([g.lines(keep) for g in frfs], scales)
