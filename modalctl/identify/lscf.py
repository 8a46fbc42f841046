"""Poles of close and heavily damped modes: least-squares complex frequency domain (LSCF) on all FRFs.

The common-denominator model of every FRF row ``o`` in a band,

    H_o(w) = N_o(z) / d(z),    z = exp(j w dt),  dt = 1 / (2 f_high),

is linear in the coefficients once multiplied out (``N_o - d H_o = 0``); eliminating the
numerators leaves the reduced normal equations in the denominator alone (Guillaume et al.,
2003, "A poly-reference implementation of the least-squares complex frequency-domain
estimator"). Their blocks depend only on the difference of the powers (Toeplitz), so one pass
over the data gives every model order at once: the stabilization diagram costs a small eigen
problem per order.

Poles are picked automatically from the diagram: the physical ones (positive damping below
``DAMPING_MAX``) of every order are clustered (:mod:`scipy.cluster.hierarchy`) in frequency and
damping; a cluster present in at least ``SUPPORT`` of the orders is a pole, a smaller one
(at least two orders) is *doubtful*: reported, never returned as a mode. The poles are then
refined by the nonlinear band fit (:func:`~modalctl.identify.estimators.fit_band`), which the
linearized LSCF cannot replace under noise (its damping is biased).

Known limit: ``R`` (monomials on a band's arc of the unit circle) has a condition number of 5e12 at
order 20 and 1e15-1e19 from order 30 to 80, where the poles are picked; round-off (the CPU's BLAS
kernels, the number of BLAS threads, which identification holds at one, a change of 1e-14 in the
data) then decides where the computational poles of those orders fall, and a shoulder of a heavily damped real measurement is
kept or not with it; the modes a clean peak holds do not move. ``benchmarks/identify_real.py`` shows
which modes come and go; docs/identification.md says what a well-conditioned basis did instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.model.modes import ModelError

from .frf import FRF

__all__ = ["Stabilization", "stabilization", "pick_poles", "DAMPING_MAX", "SUPPORT", "DOUBTFUL", "COMPONENTS",
           "SCATTER", "DAMPING_SCATTER"]

DAMPING_MAX = 0.3  # a pole damped more than this is taken as computational
SUPPORT = 0.4  # share of the orders (upper half of the diagram) a pole must appear in to be returned...
DOUBTFUL = 0.25  # ...and to be reported as doubtful (fewer: a computational pole, not reported)
COMPONENTS = 12  # principal FRFs the denominator is fitted on (all rows share the poles)
SCATTER = 0.5  # poles of one cluster lie within this share of their half-power half-width of each other...
DAMPING_SCATTER = 1 / 3  # ...and within this share of each other's damping (a ratio of 1 + it at most)
SIGNIFICANT = 0.05  # principal FRFs below this share of the first are taken as noise
DIRECT_ROWS = 256  # rows up to which the principal FRFs come from the whole Gram matrix (see _principal)
SKETCH_EXTRA = 8  # directions the range of more rows is sketched with beyond the components kept
SKETCH_ITERATIONS = 2  # subspace iterations of that sketch


@dataclass(frozen=True)
class Stabilization:
    """The stabilization diagram of one band.

    Attributes
    ----------
    orders : ndarray of int, shape (n,)
        Denominator orders fitted.
    poles : list of ndarray, shape (m_i, 2)
        Per order, the physical poles ``(f in Hz, zeta)`` inside the band.
    band : tuple of float
        ``(f_low, f_high)`` (Hz).
    """

    orders: np.ndarray
    poles: list
    band: tuple


def _principal(values: np.ndarray, components: int) -> np.ndarray:
    """At most ``components`` principal FRFs of the rows, those above ``SIGNIFICANT`` of the
    first, shape (kept, nf): the poles of every row, less the noise of the other directions.

    Up to ``DIRECT_ROWS`` rows, from the rows' whole Gram matrix; above (a plate's thousands of
    points, whose Gram matrix and its eigen problem grow as rows^2 bins and rows^3), from the
    Gram matrix of the rows projected on their dominant range (:func:`_dominant_range`)."""
    if values.shape[0] <= DIRECT_ROWS:
        power, u = np.linalg.eigh(values @ values.conj().T)  # the rows' Gram matrix: far fewer rows than bins
    else:
        basis = _dominant_range(values, components + SKETCH_EXTRA)
        projected = basis.conj().T @ values
        power, u = np.linalg.eigh(projected @ projected.conj().T)
        values = projected
    s = np.sqrt(np.maximum(power[::-1], 0))
    keep = min(components, int(np.count_nonzero(s > SIGNIFICANT * s[0])))
    return u[:, ::-1][:, :keep].conj().T @ values


def _dominant_range(values: np.ndarray, width: int) -> np.ndarray:
    """Orthonormal basis (rows, width) of the dominant range of ``values`` (rows, nf): subspace
    iteration from a seeded random start (Halko, Martinsson and Tropp 2011, Alg. 4.4), in single
    precision (the basis, not the data it projects, which stays double): ``SKETCH_ITERATIONS``
    passes make the directions above the noise converge to its level."""
    rng = np.random.default_rng(0)
    width = min(width, *values.shape)
    single = values.astype(np.complex64)
    start = (rng.standard_normal((values.shape[1], width)) + 1j * rng.standard_normal((values.shape[1], width)))
    basis = np.linalg.qr(single @ start.astype(np.complex64))[0]
    for _ in range(SKETCH_ITERATIONS):
        across = np.linalg.qr((basis.conj().T @ single).conj().T)[0]  # (rows' range)^H: no conjugated copy
        basis = np.linalg.qr(single @ across)[0]
    return basis.astype(complex)


def stabilization(frf: FRF, f_low: float, f_high: float, max_order: int,
                  components: int = COMPONENTS) -> Stabilization:
    """LSCF denominators of orders 2, 4, ..., ``max_order`` on the bins in ``[f_low, f_high]``.

    Parameters
    ----------
    frf : FRF
        All rows share the poles (any actuator, any point).
    f_low, f_high : float
        Band (Hz).
    max_order : int
        Highest denominator order (twice the number of poles it can hold).
    components : int
        Principal FRFs kept (see :func:`_principal`).
    """
    keep = (frf.frequencies >= f_low) & (frf.frequencies <= f_high)
    if np.count_nonzero(keep) < max_order + 2:
        raise ModelError(f"lscf: {np.count_nonzero(keep)} bins in {f_low:g}-{f_high:g} Hz for order {max_order}")
    freqs, inside = frf.frequencies[keep], np.flatnonzero(keep)
    if inside[-1] - inside[0] + 1 == inside.size:  # sorted lines: the band a view of the rows, not a copy
        keep = slice(inside[0], inside[-1] + 1)
    h = _principal(frf.values[:, keep], components)
    h = h / np.sqrt(np.mean(np.abs(h) ** 2))
    dt = 1 / (2 * freqs[-1])
    lags = np.arange(-max_order, max_order + 1)
    powers = np.exp(1j * 2 * np.pi * np.outer(freqs, lags) * dt)  # (nf, 2n+1): z^lag
    r_lag = powers.sum(axis=0)  # sum_f z^(s - r)
    s_lag = -(h @ powers)  # per row: -sum_f H z^(s - r)
    t_lag = (np.abs(h) ** 2).sum(axis=0) @ powers
    index = np.arange(max_order + 1)
    diff = index[None, :] - index[:, None] + max_order  # lag s - r, as an index into lags
    r_full = r_lag[diff].real
    s_full = s_lag[:, diff].real
    t_full = t_lag[diff].real
    orders = np.arange(2, max_order + 1, 2)
    poles = []
    for n in orders:
        r, s, t = r_full[:n + 1, :n + 1], s_full[:, :n + 1, :n + 1], t_full[:n + 1, :n + 1]
        m = t - np.einsum("oji,ojl->il", s, np.linalg.solve(r, s))  # sum_o (T_o - S_o^T R^-1 S_o)
        # the highest coefficient set to one: the others solve the leading block
        a = np.linalg.solve(m[:n, :n], -m[:n, n])
        roots = np.roots(np.r_[1.0, a[::-1]])
        lam = np.log(roots.astype(complex)) / dt
        lam = lam[lam.imag > 0]
        f = np.abs(lam) / (2 * np.pi)
        zeta = -lam.real / np.abs(lam)
        good = (zeta > 0) & (zeta < DAMPING_MAX) & (f >= f_low) & (f <= f_high)
        poles.append(np.column_stack([f[good], zeta[good]]))
    return Stabilization(orders, poles, (float(f_low), float(f_high)))


def pick_poles(stab: Stabilization, support: float = SUPPORT) -> tuple[np.ndarray, np.ndarray]:
    """Poles that stabilize, and doubtful ones, from a diagram.

    Every physical pole of every order in the upper half of the diagram (the lower orders cannot
    hold all of a band's modes and noise) is a point in ``(f, zeta)``; points closer than
    ``SCATTER`` half-power half-widths (``zeta f``) in frequency and a third in damping are one
    cluster (complete linkage: every pair of a cluster is that close).

    Returns
    -------
    poles : ndarray, shape (k, 2)
        ``(f, zeta)`` medians of the clusters present in at least ``support`` of those orders.
    doubtful : ndarray, shape (m, 2)
        Clusters present in fewer orders, but in ``DOUBTFUL`` of them (and two) at least.
    """
    import scipy.cluster.hierarchy  # here, not at import: the command line's help loads every identifier

    high = stab.orders[stab.orders > stab.orders.max() / 2]  # a band's modes all fit in the upper half only
    points = [(n, f, z) for n, p in zip(stab.orders, stab.poles) if n in high for f, z in p]
    if len(points) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2))
    order, f, z = np.array(points).T
    scale_f = SCATTER * np.maximum(z, 1e-4) * f  # Hz
    df = np.abs(f[:, None] - f[None, :]) / np.minimum(scale_f[:, None], scale_f[None, :])
    dz = np.abs(np.log(z[:, None] / z[None, :])) / np.log(1 + DAMPING_SCATTER)
    distance = np.maximum(df, dz)
    links = scipy.cluster.hierarchy.linkage(distance[np.triu_indices(len(f), 1)], "complete")
    labels = scipy.cluster.hierarchy.fcluster(links, 1.0, "distance")
    poles, doubtful = [], []
    for label in np.unique(labels):
        member = labels == label
        seen = np.unique(order[member]).size
        pole = (float(np.median(f[member])), float(np.median(z[member])))
        if seen >= max(2, support * len(high)):
            poles.append(pole)
        elif seen >= max(2, DOUBTFUL * len(high)):
            doubtful.append(pole)
    as_array = lambda p: np.array(sorted(p)).reshape(-1, 2)  # noqa: E731
    return as_array(poles), as_array(doubtful)
