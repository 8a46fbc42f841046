"""The noise of FRFs that carry no estimate of it (a file exported without coherence, or without its averages).

An FRF sampled finely is smooth between its lines: the second difference along frequency,
``d_k = H_{k-1} - 2 H_k + H_{k+1}``, removes the structure's response (its curvature is small
where a half-power band spans several lines) and keeps the noise, which is independent from
line to line: for noise of variance ``sigma^2`` (complex, ``E|n|^2 = sigma^2``) the difference
has variance ``6 sigma^2`` and ``|d|^2 / (6 sigma^2)`` is exponentially distributed, of median
``ln 2``. The median over blocks of lines ignores the few lines of a sharp peak, where the
curvature is not small; the blocks' values are interpolated between their centres, so that a
noise that changes across the band (a hammer's roll-off, a sensor's floor) is followed.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from .frf import FRF

__all__ = ["scatter_noise", "coherence_noise", "with_noise_estimate", "noise_weights", "noise_figures", "NoiseFigures",
           "within_noise",
           "BLOCK", "SCATTER_SOURCE", "NOISE_EXCESS", "SIGNIFICANCE"]

# a mode whose one pole leaves more than UNRESOLVED_ERROR of it unexplained is resolved all the same...
NOISE_EXCESS = 3.0  # ...when the residual is within this many times the measurement noise...
SIGNIFICANCE = 25.0  # ...and the mode's energy this many times what a fit to noise alone gives

BLOCK = 64  # lines per block whose median gives the noise there
SECOND_DIFFERENCE = 6.0  # variance of H_{k-1} - 2 H_k + H_{k+1} over that of one line's noise
SCATTER_SOURCE = "estimated from the scatter between neighbouring lines (the file gives no noise)"
AVERAGES_MAX = 100  # averages no test takes: a match above says the scatter misses noise; the level is taken here
COHERENCE_FLOOR = 1e-3  # a coherence below this counts as this (the noise is then a thousand times |H|)


def scatter_noise(values: np.ndarray, block: int = BLOCK) -> np.ndarray:
    """Standard deviation of each value's noise from the scatter between neighbouring lines.

    Parameters
    ----------
    values : ndarray, shape (n_points, nf)
        Complex FRFs on evenly spaced lines (any unit), ``nf >= 3``.
    block : int
        Lines per block: the median over each gives the noise at its centre.

    Returns
    -------
    ndarray, shape (n_points, nf)
        Same unit as ``values``; positive (a noise-free FRF gets its rounding's scale).
    """
    values = np.atleast_2d(values)
    d = values[:, :-2] - 2 * values[:, 1:-1] + values[:, 2:]
    power = np.abs(d) ** 2
    n = power.shape[1]
    blocks = max(1, n // block)
    edges = np.linspace(0, n, blocks + 1).round().astype(int)
    medians = np.column_stack([np.median(power[:, a:b], axis=1) for a, b in zip(edges[:-1], edges[1:])])
    centres = 0.5 * (edges[:-1] + edges[1:]) + 1  # in lines of ``values`` (d_k sits at line k + 1)
    lines = np.arange(values.shape[1])
    variance = np.array([np.interp(lines, centres, m) for m in medians]) / (SECOND_DIFFERENCE * np.log(2))
    floor = np.finfo(float).eps * np.max(np.abs(values), axis=1, keepdims=True) + np.finfo(float).tiny
    return np.maximum(np.sqrt(variance), floor)


def coherence_noise(values: np.ndarray, coherence: np.ndarray, averages: float) -> np.ndarray:
    """Standard deviation of an H1 estimate from its coherence and number of averages ``n``:
    ``|H| sqrt((1 - g^2) / (g^2 (n - 1)))`` (the scatter of the response that ``H`` does not
    explain, per shot, over the force's energy: what :class:`~.frf.H1` computes from its spectra).

    Parameters
    ----------
    values, coherence : ndarray, shape (n_points, nf)
        FRFs (any unit) and their coherence in [0, 1].
    averages : float
        Shots averaged, at least 2 (one shot's coherence is one everywhere).

    Raises
    ------
    ValueError
        Fewer than 2 averages.

    Returns
    -------
    ndarray, shape (n_points, nf)
        Same unit as ``values``.
    """
    if not averages >= 2:
        raise ValueError(f"coherence_noise: {averages} average(s): the coherence of fewer than 2 is one everywhere "
                         f"and says nothing of the noise")
    g2 = np.clip(coherence, COHERENCE_FLOOR, 1.0)
    return np.abs(values) * np.sqrt((1 - g2) / (g2 * (averages - 1)))


def with_noise_estimate(frf: FRF) -> FRF:
    """``frf`` itself when its noise is known (measured), else with an estimate, ``noise_source``
    saying which.

    With a coherence but no number of averages (a file's export), the coherence gives the
    noise's shape over frequency and points (:func:`coherence_noise`; largest, an upper bound,
    for two averages) and the scatter between neighbouring lines (:func:`scatter_noise`) its
    level: the averages are those that make the two agree (median over every value), at most
    ``AVERAGES_MAX``. More than that says the scatter misses most of the noise (it sees only
    what is independent between lines): the level is then the coherence's at ``AVERAGES_MAX``
    averages, the least noise the coherence allows a real test, not the scatter's (which makes
    every test against the noise over-confident). Not the bound of two averages: where the
    scatter sees so little, much of the coherence's loss is a bias (leakage, a window, a
    nonlinearity), not random noise, and n = 2 would count all of it as noise, ``sqrt(AVERAGES_MAX
    - 1)``, ten, times the level at ``AVERAGES_MAX``: of the levels a real test allows, the
    one nearest the data's own scatter is taken. Without a coherence, the scatter alone.
    """
    if frf.noise_std is not None or frf.values.shape[1] < 3:
        return frf
    scatter = scatter_noise(frf.values)
    if frf.averages > 1 or np.all(frf.coherence >= 1):  # averages known (and then noise_std too), or no coherence
        return replace(frf, noise_std=scatter, noise_source=SCATTER_SOURCE)
    bound = np.maximum(coherence_noise(frf.values, frf.coherence, 2), scatter * 1e-3)
    more = max(1.0, float(np.median((bound / scatter) ** 2)))  # n - 1
    median_bound = np.median(bound / np.maximum(np.abs(frf.values), np.finfo(float).tiny))
    found = f"n = {1 + more:.3g} matches the scatter between neighbouring lines"
    if 1 + more > AVERAGES_MAX:  # the scatter misses noise: the least the coherence allows a real test
        more, found = AVERAGES_MAX - 1.0, (
            f"n = {1 + more:.3g} would match the scatter between neighbouring lines, more averages than a test "
            f"takes: the coherence's loss is mostly not random noise independent between lines (a window that "
            f"smooths it, leakage, a nonlinearity), which the scatter does not see; taken at n = {AVERAGES_MAX}, the "
            f"least noise the coherence allows a real test")
    return replace(frf, noise_std=bound / np.sqrt(more),
                   noise_source=f"from the coherence, |H| sqrt((1 - g^2) / (g^2 (n - 1))), the file giving no number "
                                f"of averages n: {found} (the coherence alone bounds the random error by "
                                f"{median_bound:.2g} of |H| in the median, for n = 2)")


def noise_weights(noise: np.ndarray) -> np.ndarray:
    """Per point, one over its noise variance over the band (``noise`` (n_points, nb) standard
    deviations): one shot's scatter is itself noisy; a silent point gets no infinity."""
    variance = np.mean(noise**2, axis=1)
    return 1 / np.maximum(variance, 1e-6 * np.mean(variance) + np.finfo(float).tiny)


@dataclass(frozen=True)
class NoiseFigures:
    """How a band's fit compares with the FRFs' noise (:func:`noise_figures`).

    Attributes
    ----------
    excess : float
        RMS of the residual over the noise, each point by its own noise.
    significance : float
        Energy of the mode's part over what fitting it to noise alone gives (one noise variance
        per coefficient at each point).
    level : float
        RMS noise over the band's largest RMS response of a point (the mode's scale).
    """

    excess: float
    significance: float
    level: float

    @property
    def within(self) -> bool:
        """The residual is the noise (``NOISE_EXCESS``) and the mode stands out of it (``SIGNIFICANCE``)."""
        return bool(self.excess <= NOISE_EXCESS and self.significance >= SIGNIFICANCE)


def noise_figures(resid: np.ndarray, mode_part, noise: np.ndarray, general: bool = False) -> NoiseFigures:
    """A band's residual ``resid`` (nb, n_points) and the mode's part (``mode_part``, an array
    of that shape or its RMS) against the noise (``noise`` (n_points, nb) standard deviations);
    each point counts by its own variance over the band: a quiet point is not drowned by a
    loud one."""
    weight = noise_weights(noise)
    excess = float(np.sqrt(np.mean(np.abs(resid) ** 2 * weight)))
    part = np.broadcast_to(np.abs(mode_part) ** 2, resid.shape)  # an RMS counts at every value
    coefficients = resid.shape[1] * (2 if general else 1)
    level = np.sqrt(np.mean(noise**2)) / max(float(np.sqrt(np.max(np.mean(part, axis=0)))), np.finfo(float).tiny)
    return NoiseFigures(excess, float(np.sum(part * weight) / coefficients), float(level))


def within_noise(resid: np.ndarray, mode_part, noise: np.ndarray, general: bool = False) -> bool:
    """Whether a band's residual is the measurement's noise (within ``NOISE_EXCESS`` times it)
    and the mode stands out of it: the energy of its part (``mode_part``, an array or its RMS)
    at least ``SIGNIFICANCE`` times what fitting it to noise alone would give (see
    :func:`noise_figures`)."""
    return noise_figures(resid, mode_part, noise, general).within
