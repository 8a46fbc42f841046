"""Modes whose peak the file's lines under-resolve: one pole on all FRFs at once, judged by their agreement.

Where a mode's half-power band ``2 zeta f`` spans fewer than ``RESOLVED_LINES`` lines, the
peak is one or two lines: the band fit's misfit says little (the noise grows with the
response at the peak, and a peak between two lines is fitted as well by two poles on them,
as LSCF does), and a local optimizer started at a line stays there. Such a pole is fitted
instead by least squares on every FRF jointly, each with its own complex constant (any
residue: a window or a record that truncates the response turns it), a complex constant and
slope: the frequency is searched on a grid of a twentieth of a line over the peak's lines
before it is polished, so no line traps it. It is judged by what the FRFs themselves say:
the jackknife over the FRFs (the fit again with each left out) gives its frequency's standard
error, which holds every cause of their disagreement (noise, a hit that differs, a peak too
narrow for the lines). A pole is a mode when it stands out of the FRFs' noise (``SIGNIFICANCE``,
where the noise is known or estimated) and three of those errors are within
``FREQUENCY_TOLERANCE`` of it (with fewer than ``JACKKNIFE_ROWS`` FRFs there is no jackknife:
the noise alone must fix the frequency, as for a resolved mode); else it is left out, saying
which failed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.model.modes import ModelError

from .estimators import (FREQUENCY_TOLERANCE, NO_HALF_POWER, RESOLVED_LINES, UNRESOLVED_ERROR, constants_of,
                         frequency_fixed, modal_constants)
from .frf import FRF
from .noise import SIGNIFICANCE, noise_weights

__all__ = ["JointPole", "joint_pole", "coarse_rows", "joint_reach", "CoarseRow", "under_resolved", "file_notes",
           "LINES_SEARCHED", "HALF_LINES", "AGREE", "JACKKNIFE_ROWS"]

LINES_SEARCHED = 1.0  # the frequency is searched this many lines either side of the start
HALF_LINES = 3  # the band fitted spans this many lines either side of the pole (at least)
GRID = 20  # frequency grid steps per line
DAMPING_GRID = np.geomspace(1e-4, 0.1, 31)
JACKKNIFE_ROWS = 3  # fewer FRFs than this give no jackknife: the noise alone judges the frequency


@dataclass(frozen=True)
class JointPole:
    """One pole fitted on all FRFs jointly (:func:`joint_pole`).

    Attributes
    ----------
    f_hz : float
        Frequency (Hz).
    zeta : float
        Viscous damping ratio.
    sigma_hz : float
        Jackknife standard error of ``f_hz`` over the FRFs (Hz); inf with fewer than
        ``JACKKNIFE_ROWS`` FRFs.
    spread_hz : tuple of float
        Lowest and highest frequency of one pole fitted on each FRF alone (Hz).
    lines : float
        Its half-power band ``2 zeta f`` in lines.
    significance : float
        Energy the pole explains over what fitting it to noise alone gives (inf: noise unknown).
    rows : int
        FRFs fitted jointly.
    noise_fixed : bool or None
        With fewer than ``JACKKNIFE_ROWS`` FRFs, whether the noise fixes its frequency within
        ``FREQUENCY_TOLERANCE`` (:func:`~.estimators.frequency_fixed`); None otherwise, or when
        the noise is unknown.
    """

    f_hz: float
    zeta: float
    sigma_hz: float
    spread_hz: tuple
    lines: float
    significance: float = np.inf
    rows: int = JACKKNIFE_ROWS
    noise_fixed: bool | None = None

    @property
    def jackknifed(self) -> bool:
        """Whether there were FRFs enough (``JACKKNIFE_ROWS``) for a jackknife."""
        return self.rows >= JACKKNIFE_ROWS

    @property
    def fixed(self) -> bool:
        """Whether it stands out of the noise (``SIGNIFICANCE``) and its frequency is fixed within
        ``FREQUENCY_TOLERANCE``: by the FRFs' agreement (3 jackknife sigma) or, with fewer than
        ``JACKKNIFE_ROWS`` FRFs, by the noise alone (:attr:`noise_fixed`)."""
        if self.significance < SIGNIFICANCE:
            return False
        if not self.jackknifed:
            return bool(self.noise_fixed)
        return bool(3 * self.sigma_hz <= FREQUENCY_TOLERANCE * self.f_hz)

    def reason(self, rows: int | None = None) -> str:
        """Why it is left out (when not :attr:`fixed`): what the FRFs said (``rows``: their
        number, :attr:`rows` by default)."""
        rows = self.rows if rows is None else rows
        if self.significance < SIGNIFICANCE:
            return (f"a peak of the noise: one pole on all {rows} FRFs jointly explains {self.significance:.3g} times "
                    f"what it would of noise alone (at least {SIGNIFICANCE:g})")
        if not self.jackknifed:
            judged = ("no noise is known to judge it by" if self.noise_fixed is None else
                      f"the noise leaves its frequency uncertain by more than {FREQUENCY_TOLERANCE:.0%} (3 sigma)")
            return (f"its peak spans {self.lines:.1f} lines; too few FRFs ({rows}, at least {JACKKNIFE_ROWS}) for a "
                    f"jackknife, and {judged}: one pole on all jointly at {self.f_hz:.2f} Hz")
        return (f"its peak spans {self.lines:.1f} lines and the {rows} FRFs disagree on it: one pole fitted on each "
                f"alone lands between {self.spread_hz[0]:.2f} and {self.spread_hz[1]:.2f} Hz (searched within a "
                f"line), on all jointly at "
                f"{self.f_hz:.2f} Hz +- {self.sigma_hz:.2f} Hz (jackknife over the FRFs; 3 sigma at most "
                f"{FREQUENCY_TOLERANCE:.0%})")

    def note(self) -> str:
        """What it says of its mode's frequency, for :func:`file_notes`."""
        if not self.fixed:
            return f"mode at {self.f_hz:.2f} Hz: one pole on all FRFs jointly does not fix it: {self.reason()}"
        head = f"mode at {self.f_hz:.2f} Hz: its peak spans {self.lines:.1f} lines; one pole on all {self.rows} FRFs"
        if not self.jackknifed:
            return (f"{head} jointly fixes its frequency within {FREQUENCY_TOLERANCE:.0%} (3 sigma) by the noise alone "
                    f"(too few FRFs for a jackknife)")
        return f"{head} jointly fixes its frequency to +- {self.sigma_hz:.3f} Hz (jackknife over the FRFs)"


def _chi(freqs: np.ndarray, h: np.ndarray, f, zeta, centre: float) -> np.ndarray:
    """Joint residual energy of ``h`` (nb, rows) for each pole ``(f, zeta)`` (arrays of one
    shape; each pole with its two general columns, a constant and a slope), that shape.

    The basis of each pole is :func:`~.estimators.pole_basis` ``(freqs, [(f, zeta)], centre,
    general=True)``, built here for all poles at once: that function takes the poles of one
    basis (its columns from :func:`~.frf.mobility` through an identity of one row per pole),
    so a grid of a thousand poles would be a thousand calls or a thousand-square identity per
    call, and the grid search and jackknife call this some forty times per mode. The two must
    agree (``tests/test_identify_coarse.py`` checks that they do).

    Parameters
    ----------
    freqs : ndarray, shape (nb,)
        Hz.
    h : ndarray, shape (nb, rows)
        FRFs (any unit).
    f, zeta : array_like
        Poles' frequencies (Hz) and damping ratios, broadcast together.
    centre : float
        Hz: the slope's origin.

    Returns
    -------
    ndarray, shape of ``f`` and ``zeta`` broadcast
        Residual energy, the unit of ``h`` squared.
    """
    return _row_chi(freqs, h, f, zeta, centre).sum(axis=-1)


def _row_chi(freqs: np.ndarray, h: np.ndarray, f, zeta, centre: float) -> np.ndarray:
    """:func:`_chi` of each row alone, shape of ``f`` and ``zeta`` broadcast, then rows: the rows'
    fits share the basis and nothing else, so any set of rows' residual is the sum of theirs
    (the jackknife's leave-one-out fits are the total less one row's)."""
    f, zeta = np.broadcast_arrays(np.asarray(f, float), np.asarray(zeta, float))
    w, wk, z = 2 * np.pi * freqs, 2 * np.pi * f.reshape(-1, 1), zeta.reshape(-1, 1)
    den = wk**2 - w**2 + 2j * z * wk * w  # (poles, nb)
    ones = np.ones_like(den)
    b = np.stack([1j * w / den, wk**2 / den, ones, ones * (freqs / centre - 1)], axis=-1)  # (poles, nb, 4)
    q, _ = np.linalg.qr(b)
    inside = np.einsum("pnk,nr->pkr", q.conj(), h)
    row = np.sum(np.abs(h) ** 2, axis=0) - np.sum(np.abs(inside) ** 2, axis=1)  # (poles, rows)
    return row.reshape(*f.shape, h.shape[1])


def _fit(freqs: np.ndarray, h: np.ndarray, f0: float, z0: float, df: float, search: bool = True) -> tuple[float, float]:
    """The pole ``(f, zeta)`` minimizing the joint residual of ``h`` (nb, rows): with ``search``
    a grid over ``f0 +- LINES_SEARCHED`` lines and ``DAMPING_GRID`` first, then polished from
    the best point (or from ``(f0, z0)``) by Nelder-Mead on the frequency in lines and log zeta."""
    import scipy.optimize  # here, not at import: the command line's help loads every identifier

    centre = float(np.mean(freqs))
    if search:
        grid = f0 + df * np.arange(-LINES_SEARCHED * GRID, LINES_SEARCHED * GRID + 1) / GRID
        chi = _chi(freqs, h, grid[:, None], DAMPING_GRID[None, :], centre)
        i, j = np.unravel_index(np.argmin(chi), chi.shape)
        f0, z0 = float(grid[i]), float(DAMPING_GRID[j])
    step = np.log(DAMPING_GRID[1] / DAMPING_GRID[0])
    cost = lambda x: float(_chi(freqs, h, f0 + x[0] * df, z0 * np.exp(x[1] * step), centre))  # noqa: E731
    sol = scipy.optimize.minimize(cost, np.zeros(2), method="Nelder-Mead",
                                  options={"initial_simplex": [[0, 0], [1 / GRID, 0], [0, 1]], "xatol": 1e-4,
                                           "fatol": 0.0})
    return float(f0 + sol.x[0] * df), float(z0 * np.exp(sol.x[1] * step))


def _grid_best(freqs: np.ndarray, h: np.ndarray, f0: float, df: float) -> np.ndarray:
    """The frequency of the best pole on the search grid around ``f0`` (no polish) for each row of
    ``h`` (nb, rows) alone, Hz, shape (rows,)."""
    grid = f0 + df * np.arange(-LINES_SEARCHED * GRID, LINES_SEARCHED * GRID + 1) / GRID
    chi = _row_chi(freqs, h, grid[:, None], DAMPING_GRID[None, :], float(np.mean(freqs)))  # (grid, damping, rows)
    return grid[np.argmin(np.min(chi, axis=1), axis=0)]


def _left_out_best(freqs: np.ndarray, h: np.ndarray, f0: float, z0: float, df: float) -> np.ndarray:
    """The best frequency near a known optimum ``(f0, z0)`` (a line either side, the damping
    within a factor 1.6) of all rows of ``h`` (nb, rows) but one, for each row left out, Hz,
    shape (rows,): a parabola through each profile's three lowest grid values."""
    offsets = np.linspace(-1.0, 1.0, 4 * GRID + 1)
    rows = _row_chi(freqs, h, (f0 + df * offsets)[:, None], z0 * np.exp(np.linspace(-0.5, 0.5, 11))[None, :],
                    float(np.mean(freqs)))  # (offsets, damping, rows)
    profiles = np.min(rows.sum(axis=2, keepdims=True) - rows, axis=1)  # (offsets, rows): each row left out
    best = np.empty(h.shape[1])
    for r, profile in enumerate(profiles.T):
        i = int(np.clip(np.argmin(profile), 1, offsets.size - 2))
        a, b, c = profile[i - 1:i + 2]
        shift = 0.5 * (a - c) / (a - 2 * b + c) if a - 2 * b + c > 0 else 0.0
        best[r] = f0 + df * (offsets[i] + np.clip(shift, -1, 1) * (offsets[1] - offsets[0]))
    return best


def joint_pole(frf: FRF, f: float, zeta: float) -> JointPole:
    """One pole near ``f`` (Hz; ``zeta`` its first damping ratio) fitted on every row of ``frf``
    jointly, with its frequency's jackknife standard error over the rows.

    The band is ``f +- max(3 zeta f, HALF_LINES lines)``; the damping is searched on
    ``DAMPING_GRID``. Rows are the FRFs (any input, any point). With fewer than
    ``JACKKNIFE_ROWS`` rows there is no jackknife (one or two values leave none or no spread to
    speak of): the error is inf and the noise alone says whether the frequency is fixed
    (:func:`~.estimators.frequency_fixed`, as for a resolved mode).
    """
    df = frf.line_spacing
    half = max(3 * zeta * f, HALF_LINES * df) + LINES_SEARCHED * df
    keep = np.abs(frf.frequencies - f) <= half
    freqs, h = frf.frequencies[keep], frf.values[:, keep].T
    f_fit, z_fit = _fit(freqs, h, f, zeta, df)
    rows = h.shape[1]
    # the noise estimated between lines misses what grows with the response at a sharp peak: it
    # weights the test of the pole against noise alone (each FRF by its own), not the fit
    noise = frf.noise(keep)
    weight = None if noise is None else noise_weights(noise)
    scaled = h if weight is None else h * np.sqrt(weight)[None, :]
    rest = np.column_stack([np.ones(freqs.size), freqs / np.mean(freqs) - 1])
    base = np.sum(np.abs(scaled - rest @ np.linalg.lstsq(rest, scaled, rcond=None)[0]) ** 2)
    explained = base - float(_chi(freqs, scaled, f_fit, z_fit, float(np.mean(freqs))))
    significance = np.inf if noise is None else explained / (2 * rows)  # two coefficients a row
    alone = _grid_best(freqs, h, f_fit, df)
    spread = (float(alone.min()), float(alone.max()))
    if rows < JACKKNIFE_ROWS:  # no jackknife: the noise alone, where it is known, judges the frequency
        by_noise = None if weight is None else frequency_fixed(freqs, h, weight, f_fit, z_fit, general=True)
        return JointPole(f_fit, z_fit, np.inf, spread, 2 * z_fit * f_fit / df, significance, rows, by_noise)
    left = _left_out_best(freqs, h, f_fit, z_fit, df)
    sigma = float(np.sqrt((rows - 1) / rows * np.sum((left - left.mean()) ** 2)))
    return JointPole(f_fit, z_fit, sigma, spread, 2 * z_fit * f_fit / df, significance, rows)


def under_resolved(f: float, zeta: float, df: float) -> bool:
    """Whether a pole's half-power band spans fewer than ``RESOLVED_LINES`` lines of ``df`` (Hz)."""
    return bool(np.isfinite(zeta) and 0 < zeta and 2 * zeta * f / df < RESOLVED_LINES)


class CoarseRow(tuple):
    """A row ``(f, zeta, constants, misfit, resolved, reason)`` as every identifier gives it, with
    the :class:`JointPole` it was fitted as (:attr:`pole`) carried along."""

    pole: JointPole

    def __new__(cls, row, pole: JointPole):
        self = super().__new__(cls, row)
        self.pole = pole
        return self


def _same_peak(r, f: float, near: float):
    """Row ``r`` left out as the peak of the mode returned at ``f`` (Hz), within ``near`` (Hz) of it."""
    return (*r[:4], False, f"the peak of the mode at {f:.2f} Hz (within {near:g} Hz, {LINES_SEARCHED + 1:g} lines, "
                           f"of it): the same peak, not a second mode")


def joint_reach(df: float) -> float:
    """How far (Hz) a joint fit's peak reaches on lines ``df`` apart: the lines it searches and one more;
    rows within it are one peak (:func:`coarse_rows`)."""
    return (LINES_SEARCHED + 1) * df


def coarse_rows(frf: FRF, rows: list, skip=()) -> list:
    """Rows ``(f, zeta, constants, misfit, resolved, reason)`` with every under-resolved pole the
    band fit did not explain (misfit above ``UNRESOLVED_ERROR``) fitted again by :func:`joint_pole`.

    Such poles within ``LINES_SEARCHED + 1`` lines of each other are one peak (LSCF's pair on
    the lines either side of it, a peak-picked pole and a doubtful one): fitted once, from the
    one of lowest misfit, as one row; one near a pole the band fit explained is that pole's; a
    group of poles no band fit was made of (LSCF's doubtful ones, misfit infinite) is left as it
    is. A peak whose half-power points came out the wrong way round (:data:`~.estimators.NO_HALF_POWER`,
    a damping of zero or less: the level half a power below the peak its parabola reaches lies above
    the lines beside it, the peak falling between them) is such a pole too, started at the damping
    whose half-power band is one line (the strip's 184.3 Hz, 0.1% damping on lines every 0.5 Hz, was
    left out so where LSCF put no pole on it). Poles whose reason is in ``skip`` (peaks of the noise)
    are not fitted. A pole
    :attr:`JointPole.fixed` is returned at the joint fit with its constants by
    :func:`modal_constants` (a :class:`CoarseRow`, carrying its pole); a pole not fixed is left
    out with :meth:`JointPole.reason`. Every row left out within those lines of a mode returned
    (a sure pole, a joint one fixed) is left out as that mode's peak, not for a reason of its
    own: none is dropped unsaid, and none contradicts the mode.
    """
    df = frf.line_spacing
    near = joint_reach(df)

    def sharp(r) -> bool:  # a peak between the lines: its half-power points the wrong way round
        return r[5] == NO_HALF_POWER and bool(np.isfinite(r[1]) and r[1] <= 0)

    def candidate(r) -> bool:
        unexplained = under_resolved(r[0], r[1], df) and (not r[4] or r[3] > UNRESOLVED_ERROR)
        return r[5] not in skip and (sharp(r) or unexplained)

    def start(r) -> tuple:  # where its joint fit starts: a sharp peak at a half-power band of one line
        return (r[0], df / (2 * r[0])) if sharp(r) else r[:2]

    sure = np.array([r[0] for r in rows if r[4] and not candidate(r)])
    out = [r for r in rows if not candidate(r)]
    groups = []
    for r in sorted((r for r in rows if candidate(r)), key=lambda r: r[0]):
        if sure.size and np.min(np.abs(sure - r[0])) <= near:  # the sure pole's peak: said so below
            out.append((*r[:4], False, r[5]))
        elif groups and r[0] - groups[-1][-1][0] <= near:
            groups[-1].append(r)
        else:
            groups.append([r])
    joint = []
    for group in groups:
        if not any(np.isfinite(r[3]) or sharp(r) for r in group):  # LSCF's doubtful poles only: no peak there
            out.extend(group)
            continue
        f, zeta = start(min(group, key=lambda r: (r[3], not sharp(r))))
        pole = joint_pole(frf, f, zeta)
        try:
            fit = modal_constants(frf, pole.f_hz, pole.zeta, max(3 * pole.zeta * pole.f_hz, HALF_LINES * df),
                                  frequency_check=False)
        except ModelError:  # at the edge of the measurement: each as it came, left out
            out.extend((*r[:4], False, r[5] or "at the measurement's edge: too few lines to fit its peak jointly")
                       for r in group)
            continue
        joint.append(CoarseRow((pole.f_hz, pole.zeta, fit.constants, fit.misfit, pole.fixed,
                                "" if pole.fixed else pole.reason()), pole))
    kept = np.array([r[0] for r in [*out, *joint] if r[4]])
    if kept.size:  # a row left out near a mode returned is that mode's peak, not left out for a reason of its own
        out = [_same_peak(r, float(kept[np.argmin(np.abs(kept - r[0]))]), near)
               if not r[4] and np.min(np.abs(kept - r[0])) <= near else r for r in out]
    return out + joint


AGREE = 0.9  # MAC below which two inputs' shapes of one mode are said to disagree


def file_notes(frfs: list, frequencies: np.ndarray, damping: np.ndarray, poles=()) -> list[str]:
    """What the FRFs say of the returned modes ``(frequencies, damping)``: for each whose peak the
    lines under-resolve, its frequency's jackknife standard error over the FRFs
    (:meth:`JointPole.note` of ``poles[k]``, the joint fit :func:`coarse_rows` made the mode of,
    :attr:`~.estimators.Modes.poles`; fitted here where there is none); with several inputs, each mode
    whose shapes from the two inputs that drive it most agree to a MAC below ``AGREE`` (the same mode:
    they should agree)."""
    frf = frfs[0] if len(frfs) == 1 else FRF.stack(frfs)
    df = frf.line_spacing
    poles = list(poles) + [None] * (len(frequencies) - len(poles))
    notes = []
    for k, (f, zeta) in enumerate(zip(frequencies, damping)):
        if under_resolved(f, zeta, df):
            notes.append((poles[k] or joint_pole(frf, f, zeta)).note())
        if len(frfs) > 1:
            c = [constants_of(x, frequencies, damping, k, frequency_check=False).constants for x in frfs]
            a, b = np.argsort([-np.sqrt(np.mean(x**2)) for x in c])[:2]
            agree = float(np.dot(c[a], c[b]) ** 2 / max(np.dot(c[a], c[a]) * np.dot(c[b], c[b]), 1e-300))
            if agree < AGREE:
                notes.append(f"mode at {f:.2f} Hz: the shapes inputs {a} and {b} give agree to MAC {agree:.2f} only "
                             f"(the same mode: they should agree): its shape is uncertain")
    return notes
