"""Modal parameters from measured FRFs: the thesis's peak picking and a local SDOF fit.

Both estimators return :class:`Modes`: per mode a frequency, a damping ratio and the modal
constant at each measured point, ``A_p = phi(p) b`` with the mobility model

    H_p(w) = sum_k A_pk j w / (w_k^2 - w^2 + 2 j zeta_k w_k w)           (Eq 3.4, velocity)

so that at resonance ``H_p(w_k) = A_pk / (2 zeta_k w_k)`` (Eq 3.9). A mode is *unresolved*
when one pole cannot explain the FRFs around its peak (two modes within their half-power
bandwidths, or a peak with no half-power points): it is reported, never silently fitted.
:func:`modalctl.identify.survey.to_model` turns them into a model.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass

import numpy as np

from modalctl.model.modes import ModelError

from .band_fit import _lstsq, fit_band, pole_basis
from .frf import FRF
from .noise import NOISE_EXCESS, SIGNIFICANCE, NoiseFigures, noise_figures, noise_weights, within_noise

__all__ = ["Identifier", "Modes", "BandFit", "peak_picking", "sdof_fit", "fit_band", "modal_constants", "one_pole_stands",
           "half_width", "neighbours", "constants_of", "UNRESOLVED_ERROR",
           "NOISE_EXCESS", "SIGNIFICANCE", "within_noise", "noise_figures", "NoiseFigures", "noise_weights",
           "FAIR_ERROR", "SPLIT_GAIN", "NOISE_PEAK", "RESOLVED_LINES", "misfit_reason", "modes_from_rows",
           "frequency_fixed", "FREQUENCY_TOLERANCE", "CONFIDENCE", "UNCERTAIN"]

UNRESOLVED_ERROR = 0.1  # relative RMS misfit of one pole below which a mode is resolved whatever the noise...
# ...or when the residual is the noise (NOISE_EXCESS, SIGNIFICANCE in .noise, where the noise is known)...
FAIR_ERROR = 0.3  # ...or, up to this misfit, when a second pole in the band explains no more (one_pole_stands)
SPLIT_GAIN = 2.0  # a second pole explains more when it divides the residual by this
BINS_PER_COLUMN = 3  # a band fit gets at least this many bins per unknown of each point (else it is widened)
NOISE_PEAK = 1.0  # a "mode" leaving more unexplained than itself (misfit above this), where the noise was measured, is a peak of it
RESOLVED_LINES = 3.0  # a half-power band (2 zeta f) over fewer lines than this is under-resolved by the file
FREQUENCY_TOLERANCE = 0.01  # where the noise is measured, a mode is returned only when it fixes its frequency within this...
CONFIDENCE = 9.0  # ...: the noise-weighted chi-square, damping re-fitted, rises by this (3 sigma) before either end

NO_HALF_POWER = "no half-power points with a physical damping: another peak or the band's edge comes first"
RAN_AWAY = "the band fit ran away from the peak (no single pole here)"
NOISE = "a peak of the noise: the fitted mode is smaller than what it leaves unexplained"
UNCERTAIN = (f"the measured noise leaves its frequency uncertain by more than {FREQUENCY_TOLERANCE:.0%} (3 sigma): "
             "one pole fits as well elsewhere (modes hidden in the noise?)")


@dataclass(frozen=True, eq=False)
class Modes:
    """Identified modes.

    Attributes
    ----------
    frequencies : ndarray, shape (k,)
        Hz.
    damping : ndarray, shape (k,)
        Viscous damping ratios.
    constants : ndarray, shape (k, n_points)
        Modal constants ``phi(p) b`` (m/s^2/V), real (proportional damping).
    misfit : ndarray, shape (k,)
        Relative RMS misfit of one pole to the FRFs around the peak.
    resolved : ndarray of bool, shape (k,)
        False when one pole cannot explain the peak: misfit above ``UNRESOLVED_ERROR``, a
        residual not the measurement noise or a mode not standing out of it
        (:func:`within_noise`), and a misfit above ``FAIR_ERROR``; or bettered by two poles
        (:func:`one_pole_stands`); or a doubtful pole.
    method : str
    reasons : tuple of str, length k
        Why each mode left out was left out ("" for a resolved mode).
    poles : tuple, length k
        The joint fit each mode was made of (:class:`~.coarse.JointPole`, a peak the lines
        under-resolve), or None.
    """

    frequencies: np.ndarray
    damping: np.ndarray
    constants: np.ndarray
    misfit: np.ndarray
    resolved: np.ndarray
    method: str
    reasons: tuple = ()
    poles: tuple = ()

    def __post_init__(self):
        if len(self.reasons) != self.frequencies.size:
            why = tuple("" if r else "one pole cannot explain the peak (close modes?)" for r in self.resolved)
            object.__setattr__(self, "reasons", why)
        if len(self.poles) != self.frequencies.size:
            object.__setattr__(self, "poles", (None,) * self.frequencies.size)

    @property
    def n_modes(self) -> int:
        return self.frequencies.size

    def only_resolved(self) -> "Modes":
        """The resolved modes only."""
        return self.select(self.resolved)

    def select(self, keep) -> "Modes":
        """The modes at ``keep`` (a mask or indices), in that order."""
        kept = np.arange(self.n_modes)[keep]
        return Modes(self.frequencies[kept], self.damping[kept], self.constants[kept], self.misfit[kept],
                     self.resolved[kept], self.method, tuple(self.reasons[i] for i in kept),
                     tuple(self.poles[i] for i in kept))

    def row(self, i: int) -> tuple:
        """Mode ``i`` as ``(f, zeta, constants, misfit, resolved, reason)`` (see :func:`modes_from_rows`)."""
        return (self.frequencies[i], self.damping[i], self.constants[i], self.misfit[i], bool(self.resolved[i]),
                self.reasons[i])

    def left_out(self, most: int | None = 10, noise: bool = False) -> list[str]:
        """One line per mode left out, with why, those nearest to being kept (lowest misfit)
        first; peaks of the noise counted in one line (listed too with ``noise``), at most
        ``most`` lines of the others (all with None)."""
        out = [i for i in np.argsort(self.misfit, kind="stable") if not self.resolved[i]]
        lines = [f"{self.frequencies[i]:.1f} Hz left out: {self.reasons[i]}" for i in out
                 if noise or self.reasons[i] != NOISE]
        count = sum(self.reasons[i] == NOISE for i in out)
        shown = lines if most is None else lines[:most]
        more = [f"and {len(lines) - len(shown)} more left out (every one: --left-out, or the JSON)"] \
            if len(shown) < len(lines) else []
        return shown + more + ([f"{count} peak(s) of the noise ignored"] if count and not noise else [])

    def summary(self) -> list[dict]:
        """One row per mode, for tables and JSON."""
        return [{"f_hz": float(f), "zeta": float(z), "misfit": float(e), "resolved": bool(r), "reason": why}
                for f, z, e, r, why in zip(self.frequencies, self.damping, self.misfit, self.resolved, self.reasons)]


@dataclass(frozen=True, eq=False)
class BandFit:
    """What the fit of a band says of one pole (:func:`modal_constants`).

    Attributes
    ----------
    constants : ndarray, shape (n_points,)
        Real modal constants (m/s^2/V).
    misfit : float
        RMS of the residual over RMS of the mode's part of the fit.
    reason : str
        Why the pole is not returned as a mode; "" when it is.
    """

    constants: np.ndarray
    misfit: float
    reason: str = ""

    @property
    def resolved(self) -> bool:
        return not self.reason


class Identifier(ABC):
    """A modal parameter estimator, as plugins provide them (hook ``modalctl_identifiers``): a
    subclass names itself and finds the modes in measured FRFs.

    Attributes
    ----------
    name, summary : str
    """

    name: str = ""
    summary: str = ""

    @abstractmethod
    def identify(self, frf: FRF, threshold_db: float = 3.0) -> "Modes":
        """The modes of ``frf`` (its rows may stack several actuators'): poles, modal constants per
        row, misfit and whether each is resolved; ``threshold_db`` is the peaks' prominence."""


def _columns(others: int, general: bool) -> int:
    """The unknowns per point of a band fit with ``others`` neighbouring poles (:func:`pole_basis`)."""
    return (1 + others) * (2 if general else 1) + 2


def _widened(half_width: float, columns: int, df: float) -> float:
    """A band's half width (Hz), widened to ``BINS_PER_COLUMN`` bins (``df`` apart) per unknown."""
    return max(half_width, BINS_PER_COLUMN * columns * df / 2)


def modal_constants(frf: FRF, f: float, zeta: float, half_width: float,
                    others=(), general: bool = False, counted: bool = False, frequency_check: bool = True) -> BandFit:
    """Real modal constants at every point for a known pole, the relative misfit, and whether
    the pole is a mode.

    The FRFs within ``f +- half_width`` (Hz; widened to ``BINS_PER_COLUMN`` bins per unknown)
    are fitted by least squares with the mode, the
    neighbouring poles ``others`` (``[(f, zeta), ...]``, close modes whose peaks reach into the
    band) and a complex constant and slope per point (the modes outside the band). The
    constants of a normal mode share one phase (zero for an ideal set-up; a DAC hold or a delay
    turns it by ``w`` times the delay): they are rotated by the phase that makes them most
    nearly real, and the misfit counts what one real shape and that phase cannot explain.

    With ``general`` (see :func:`pole_basis`) the mode may have complex shapes (non-proportional
    damping): the misfit is then the residual over what the pole, with any shape, explains
    (the RMS it removes from the fit without it): a pole of the noise explains nothing.

    The pole is a mode when it explains the band (:class:`Modes`, ``resolved``; with
    ``counted``, poles counted by a stabilization diagram, a fair misfit stands without the
    split test) and, where the FRFs' noise is known and the pole leaves more than
    ``UNRESOLVED_ERROR`` of itself unexplained, that noise fixes its frequency to
    ``FREQUENCY_TOLERANCE`` (:func:`frequency_fixed`). Below that misfit, noise and model error
    together are a tenth of the mode over at least ``BINS_PER_COLUMN`` bins per unknown: its
    frequency is fixed far better than 1% (about ``zeta * misfit`` over the root of the bins).
    ``frequency_check`` False skips that check (the constants of a pole already judged).
    """
    columns = _columns(len(others), general)
    half_width = _widened(half_width, columns, frf.line_spacing)
    keep = np.abs(frf.frequencies - f) <= half_width
    if np.count_nonzero(keep) < 2 * columns:  # at the edge of the measurement
        raise ModelError(f"identify: fewer than {2 * columns} FRF bins within {half_width:g} Hz of {f:g} Hz")
    freqs, h = frf.frequencies[keep], frf.values[:, keep].T  # (nb, n_points)
    b = pole_basis(freqs, [(f, zeta), *others], f)
    coef = _lstsq(b, h)
    phase = np.exp(0.5j * np.angle(np.sum(coef[0] ** 2)))
    constants = (coef[0] / phase).real
    if general:  # what the mode explains: the residual without its columns less that with them
        b = pole_basis(freqs, [(f, zeta), *others], f, general)
        resid = h - b @ _lstsq(b, h)
        rest = np.delete(b, [0, 1 + len(others)], axis=1)
        without = h - rest @ _lstsq(rest, h)
        mode_part = np.sqrt(np.maximum(np.mean(np.abs(without) ** 2) - np.mean(np.abs(resid) ** 2), 1e-300))
    else:
        mode_part = np.outer(b[:, 0], constants * phase)
        resid = h - mode_part - b[:, 1:] @ coef[1:]
    # the residual of a least-squares fit is smaller than the noise by its degrees of freedom
    raw, resid = resid, resid * np.sqrt(len(b) / (len(b) - columns))
    misfit = float(np.sqrt(np.mean(np.abs(resid) ** 2) / np.mean(np.abs(mode_part) ** 2)))
    noise = frf.noise(keep)
    seen = None if noise is None else noise_figures(resid, mode_part, noise, general)
    resolved = misfit <= UNRESOLVED_ERROR or (seen is not None and seen.within)
    split = []
    if not resolved and misfit <= fair_limit(frf, seen):
        # a pole the diagram counted stands on a fair misfit; above it (where only the estimated
        # noise's limit lets it be tried) it must pass the split test as any other
        resolved = (counted and misfit <= FAIR_ERROR) or one_pole_stands(frf, f, zeta, half_width, others, raw,
                                                                         split)
    if not resolved:
        near = min(others, key=lambda p: abs(p[0] - f), default=None)
        near = None if near is None else (near[0], abs(near[0] - f) / max(zeta * f, np.finfo(float).tiny))
        lines = 2 * zeta * f / frf.line_spacing
        why = misfit_reason(misfit, noise is not None, seen, near, None if split else half_width, lines)
        if split:
            what = "close modes, or FRFs that disagree on a peak too narrow for the lines?" \
                if 0 < lines < RESOLVED_LINES else "close modes?"
            why = why[:-1] + (f"; two poles, {min(split)[0]:.2f} and {max(split)[0]:.2f} Hz, leave less than half its "
                              f"residual: {what})")
        return BandFit(constants, misfit, why)
    judged = frequency_check and noise is not None and misfit > UNRESOLVED_ERROR
    if judged and not frequency_fixed(freqs, h, noise_weights(noise), f, zeta, others, general):
        return BandFit(constants, misfit, UNCERTAIN)
    return BandFit(constants, misfit)


def fair_limit(frf: FRF, seen: NoiseFigures | None) -> float:
    """The misfit up to which one pole stands when no second pole explains more (the graded rule).

    ``FAIR_ERROR`` where the noise is unknown or measured. Where it is only estimated from the
    scatter between lines (``frf.noise_source``), that estimate misses the noise that grows
    with the response at a sharp peak (a hammer's, a window's): the limit is then the noise's
    own, ``NOISE_PEAK`` (the mode larger than what it leaves), for a mode standing
    ``SIGNIFICANCE`` times above the noise; a peak of the noise does not.
    """
    if seen is not None and frf.noise_source and seen.significance >= SIGNIFICANCE:
        return NOISE_PEAK
    return FAIR_ERROR


def frequency_fixed(freqs: np.ndarray, h: np.ndarray, weight: np.ndarray, f: float, zeta: float,
                    others=(), general: bool = False) -> bool:
    """Whether the noise fixes a mode's frequency to ``FREQUENCY_TOLERANCE`` of ``f``: its
    profile likelihood.

    The chi-square of the band's fit (``h`` (nb, n_points) at ``freqs``; each point weighted by
    ``weight``, one over its noise variance; the constants linear, the poles ``others`` fixed)
    is minimized over the mode's frequency and damping (a complex residual is two real ones of
    half its variance each: twice ``|r|^2 weight``). The frequency is fixed when that
    minimum lies within the tolerance of ``f`` and the chi-square, damping re-fitted, is
    ``CONFIDENCE`` above it at both ends of the tolerance. A single pole fitted to a cluster
    of heavily damped modes hidden in the noise explains the band to the noise, as the cluster
    does, and lands anywhere between them: its frequency is not fixed.
    """
    import scipy.optimize  # here, not at import: the command line's help loads every identifier

    tol, log_z = FREQUENCY_TOLERANCE, np.log(zeta)
    scaled = h * np.sqrt(weight)  # the residual of a projection is what the basis's span leaves of the data
    total = np.sum(np.abs(scaled) ** 2)

    def chi2(shift: float, lz: float) -> float:
        q, _ = np.linalg.qr(pole_basis(freqs, [(f * (1 + tol * shift), np.exp(lz)), *others], f, general))
        return float(2 * (total - np.sum(np.abs(q.conj().T @ scaled) ** 2)))

    best = scipy.optimize.minimize(lambda x: chi2(x[0], log_z + x[1]), np.zeros(2), method="Nelder-Mead",
                                   options={"initial_simplex": [[0, 0], [0.25, 0], [0, 0.3]], "xatol": 0.01,
                                            "fatol": 0.1})
    if abs(best.x[0]) >= 1:
        return False
    for end in (-1.0, 1.0):
        rise = scipy.optimize.minimize_scalar(lambda lz: chi2(end, lz), bounds=(log_z - 2, log_z + 2),
                                              method="bounded", options={"xatol": 0.01}).fun - best.fun
        if rise < CONFIDENCE:
            return False
    return True


def one_pole_stands(frf: FRF, f: float, zeta: float, half_width: float, others, resid: np.ndarray,
                    split: list | None = None) -> bool:
    """Whether one pole is the best account of a band it explains only fairly: the graded rule
    in place of a cliff on the misfit.

    A second pole is started where the residual ``resid`` (nb, n_points) of the first peaks and
    both are fitted (:func:`fit_band`); one pole stands unless the two divide the residual by
    ``SPLIT_GAIN`` with the second inside the band, against the first with any residue (a
    turned one is no second mode). When they do, the two poles ``(f, zeta)``
    are appended to ``split`` (a list, if given).
    """
    if not 0 < zeta < 0.5:  # no physical pole to start from
        return False
    keep = np.abs(frf.frequencies - f) <= half_width
    freqs = frf.frequencies[keep]
    seed = float(freqs[np.argmax(np.mean(np.abs(resid), axis=1))])
    if abs(seed - f) < freqs[1] - freqs[0]:
        return True
    poles = fit_band(frf, [(f, zeta), (seed, zeta), *others], f, half_width)
    if not all(abs(p - f) <= half_width and 0 < z < 0.5 for p, z in poles[:2]):
        return True
    h = frf.values[:, keep].T
    b = pole_basis(freqs, poles, f)
    coef = _lstsq(b, h)
    one = pole_basis(freqs, [(f, zeta), *others], f, general=True)  # one pole, any residue: as many columns
    alone = min(np.linalg.norm(resid), np.linalg.norm(h - one @ _lstsq(one, h)))
    stands = bool(np.linalg.norm(h - b @ coef) * SPLIT_GAIN > alone)
    if not stands and split is not None:
        split.extend(tuple(map(float, p)) for p in poles[:2])
    return stands


def _half_power(freqs: np.ndarray, mag: np.ndarray, peak: int, level: float, others: np.ndarray):
    """Frequencies where ``mag`` falls below ``level`` on each side of bin ``peak``, linearly
    interpolated (Eq 3.6); None when another peak comes first (the modes are not resolved)."""
    sides = []
    for step in (-1, 1):
        i = peak
        while 0 <= i + step < mag.size and mag[i + step] >= level:
            i += step
        j = i + step
        between = (others > min(peak, j)) & (others < max(peak, j))
        if not 0 <= j < mag.size or np.any(between):
            return None
        sides.append(freqs[i] + (level - mag[i]) * (freqs[j] - freqs[i]) / (mag[j] - mag[i]))
    return sides


def _top(mag: np.ndarray, p: int, fraction: float = 0.9) -> np.ndarray:
    """Contiguous bins around peak ``p`` above ``fraction`` of it, at least ``p - 1 .. p + 1``."""
    lo = p
    while lo > 0 and mag[lo - 1] >= fraction * mag[p]:
        lo -= 1
    hi = p
    while hi < mag.size - 1 and mag[hi + 1] >= fraction * mag[p]:
        hi += 1
    return np.arange(min(lo, p - 1), max(hi, p + 1) + 1)


def peak_picking(frf: FRF, threshold_db: float = 3.0, min_frequency: float | None = None,
                 frequency_check: bool = True) -> Modes:
    """The thesis's method (3.1.2-3.1.3): peaks of the mean FRF, half-power damping, shapes at the peaks.

    Parameters
    ----------
    frf : FRF
    threshold_db : float
        A peak must stand this much above the valleys around it (prominence, dB).
    min_frequency : float, optional
        Ignore peaks below this (Hz).
    frequency_check : bool
        Whether a peak must have its frequency fixed by the noise (:func:`modal_constants`);
        off for the SDOF fit's starting points, which it checks once refined.

    Notes
    -----
    The peak is refined between bins by a least-squares parabola through ``1 / |H|^2`` over the
    bins above 90% of the peak (at least three): nearly exact for an isolated mode, whose
    inverse squared magnitude is quadratic near resonance, and robust to noise on broad peaks. Damping is ``(f2 - f1) / (2 f)`` from the interpolated half-power
    points (Eq 3.6), the modal constants ``2 zeta w Re H(w_k)`` (Eq 3.9) from the FRF
    interpolated at the refined frequency.
    """
    import scipy.signal  # here, not at import: the command line's help loads every identifier

    mag = frf.mean_magnitude()
    freqs = frf.frequencies
    level_db = 20 * np.log10(np.maximum(mag, np.finfo(float).tiny))
    peaks, _ = scipy.signal.find_peaks(level_db, prominence=threshold_db)
    if min_frequency is not None:
        peaks = peaks[freqs[peaks] >= min_frequency]
    rows = []
    for p in peaks:
        if p == 0 or p == mag.size - 1:
            continue
        top = _top(mag, p)
        inv = 1 / mag[top] ** 2
        c2, c1, c0 = np.polyfit(freqs[top] - freqs[p], inv, 2)
        df = freqs[1] - freqs[0]
        shift = -c1 / (2 * c2) if c2 > 0 else 0.0
        f = freqs[p] + float(np.clip(shift, freqs[top[0]] - freqs[p], freqs[top[-1]] - freqs[p]))
        peak_inv = c0 + c1 * (f - freqs[p]) + c2 * (f - freqs[p]) ** 2
        peak_mag = 1 / np.sqrt(peak_inv) if peak_inv > 0 else mag[p]
        sides = _half_power(freqs, mag, p, peak_mag / np.sqrt(2), np.setdiff1d(peaks, [p]))
        if sides is None:
            rows.append((f, np.nan, np.zeros(frf.values.shape[0]), np.inf, False, NO_HALF_POWER))
            continue
        zeta = (sides[1] - sides[0]) / (2 * f)
        if not 0 < zeta < 0.5:  # half-power points of a peak of the noise
            rows.append((f, zeta, np.zeros(frf.values.shape[0]), np.inf, False, NO_HALF_POWER))
            continue
        h_at = np.array([np.interp(f, freqs[top], row.real) for row in frf.values[:, top]])
        constants = 2 * zeta * 2 * np.pi * f * h_at
        try:
            fit = modal_constants(frf, f, zeta, max(3 * zeta * f, 4 * df), frequency_check=frequency_check)
        except ModelError:
            fit = BandFit(constants, np.inf, misfit_reason(np.inf, frf.noise_std is not None))
        rows.append((f, zeta, constants, fit.misfit, fit.resolved, fit.reason))
    return modes_from_rows(rows, frf.values.shape[0], "peaks")


def sdof_fit(frf: FRF, threshold_db: float = 3.0, min_frequency: float | None = None,
             band: float = 3.0) -> Modes:
    """Peak picking refined by a local least-squares fit of each mode with its close neighbours.

    Parameters
    ----------
    band : float
        Half width of the fitted band in half-power half-widths (``zeta f``). Neighbouring
        modes whose peaks reach into it are fitted with it (their poles too), so that close
        modes do not bias each other.
    """
    start = peak_picking(frf, threshold_db, min_frequency, frequency_check=False)  # checked once refined
    df = frf.line_spacing
    rows = []
    for i, (f, zeta) in enumerate(zip(start.frequencies, start.damping)):
        if not start.resolved[i] or not 0 < zeta < 0.5:
            rows.append((f, zeta, start.constants[i], start.misfit[i], False, start.reasons[i] or RAN_AWAY))
            continue
        half = half_width(start.frequencies, start.damping, i, df, band)
        near = [j for j in neighbours(start.frequencies, start.damping, i, half) if start.resolved[j]]
        poles = fit_band(frf, [(f, zeta), *[(start.frequencies[j], start.damping[j]) for j in near]], f, half)
        f_fit, z_fit = poles[0]
        if abs(f_fit - f) > half or not 0 < z_fit < 0.5:  # the fit ran away: no single pole here
            rows.append((f, zeta, start.constants[i], np.inf, False, RAN_AWAY))
            continue
        fit = modal_constants(frf, f_fit, z_fit, half, poles[1:])
        rows.append((f_fit, z_fit, fit.constants, fit.misfit, fit.resolved, fit.reason))
    return modes_from_rows(rows, frf.values.shape[0], "sdof")


def half_width(frequencies: np.ndarray, damping: np.ndarray, i: int, df: float, band: float = 3.0) -> float:
    """Half width (Hz) of the band fitted around mode ``i``: ``band`` half-power half-widths
    (``zeta f``), at least four bins."""
    return max(band * damping[i] * frequencies[i], 4 * df)


def neighbours(frequencies: np.ndarray, damping: np.ndarray, i: int, half: float) -> np.ndarray:
    """Modes other than ``i`` whose half-power band reaches into ``f_i +- half``."""
    reach = np.abs(frequencies - frequencies[i]) - 2 * damping * frequencies < half
    reach[i] = False
    return np.flatnonzero(reach)


def lines_read(lines: np.ndarray, frequencies: np.ndarray, damping: np.ndarray, band: float = 3.0) -> np.ndarray:
    """Which of the FRF's ``lines`` (nf,) (Hz, evenly spaced) :func:`constants_of` reads for any of the
    modes ``frequencies``, ``damping`` (k,) (a general shape's fit included), shape (nf,) of bool: a scan
    kept there only gives the same constants (a plate's 7,171 points x 26,224 lines were 6 GB)."""
    lines = np.asarray(lines, float)
    df = lines[1] - lines[0]
    read = np.zeros(lines.size, bool)
    for k in range(np.size(frequencies)):
        half = half_width(frequencies, damping, k, df, band)
        columns = _columns(neighbours(frequencies, damping, k, half).size, general=True)  # the widest fit's
        read |= np.abs(lines - frequencies[k]) <= _widened(half, columns, df)
    return read


def constants_of(frf: FRF, frequencies: np.ndarray, damping: np.ndarray, k: int, band: float = 3.0,
                 general: bool = False, counted: bool = False, frequency_check: bool = True) -> BandFit:
    """:func:`modal_constants` of mode ``k`` of a known set, in its band, with its neighbours."""
    df = frf.line_spacing
    half = half_width(frequencies, damping, k, df, band)
    near = neighbours(frequencies, damping, k, half)
    return modal_constants(frf, frequencies[k], damping[k], half, list(zip(frequencies[near], damping[near])),
                           general, counted, frequency_check)


def misfit_reason(misfit: float, noise_known: bool, seen: NoiseFigures | None = None, nearest=None,
                  half_width: float | None = None, lines: float | None = None) -> str:
    """Why a pole that does not explain its band was left out, saying what was seen.

    A peak of the noise (``NOISE``) when the FRFs' noise is known and the mode is smaller than
    what it leaves unexplained, unless it stands ``SIGNIFICANCE`` times above that noise (a peak
    the noise cannot make); else one pole explaining its band poorly: its misfit, the residual
    against the noise (``seen``, when known), the nearest other pole fitted with it (``nearest``:
    its frequency in Hz and its distance in this mode's half-power half-widths), or that none lies
    within ``half_width`` (Hz): then close modes are not what was seen; and, when its half-power
    band spans fewer than ``RESOLVED_LINES`` lines (``lines``, ``2 zeta f`` over the line spacing),
    that the file under-resolves it: one pole cannot be fixed on a peak of one or two lines.
    """
    if misfit > NOISE_PEAK and noise_known and (seen is None or seen.significance < SIGNIFICANCE):
        return NOISE
    what = [f"misfit {misfit:.2f}"]
    if seen is not None:
        what.append(f"residual {seen.excess:.1f} times the noise (at most {NOISE_EXCESS:g}), noise "
                    f"{seen.level:.1%} of the mode, which stands {seen.significance:.3g} times above it "
                    f"(at least {SIGNIFICANCE:g})")
    else:
        what.append(f"above {FAIR_ERROR:g} with no measured noise to judge it by")
    if nearest is not None:
        what.append(f"nearest pole {nearest[0]:.1f} Hz, {nearest[1]:.1f} half-power half-widths away")
    elif half_width is not None:
        what.append(f"no other pole within {half_width:.3g} Hz: not close modes")
    if lines is not None and 0 < lines < RESOLVED_LINES:
        what.append(f"its half-power band spans {lines:.1f} lines (at least {RESOLVED_LINES:g} resolve a pole): "
                    f"the file's lines are too coarse for its damping")
    return f"one pole explains its band poorly ({'; '.join(what)})"


def modes_from_rows(rows, n_points: int, method: str) -> Modes:
    """:class:`Modes` from rows ``(f, zeta, constants, misfit, resolved, reason)``, by frequency."""
    rows = sorted(rows, key=lambda r: r[0])
    if not rows:
        empty = np.zeros(0)
        return Modes(empty, empty, np.zeros((0, n_points)), empty, np.zeros(0, bool), method, ())
    f, z, c, e, r, why = zip(*(row[:6] for row in rows))
    return Modes(np.array(f), np.array(z), np.array(c), np.array(e), np.array(r, bool), method, tuple(why),
                 tuple(getattr(row, "pole", None) for row in rows))
