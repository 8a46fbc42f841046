"""The finite-element plate's sparse eigenproblem ``K x = w2 M x``: factors, Lanczos, checks.

ARPACK's shift-invert Lanczos (scipy's ``eigsh``) on superLU's factors of ``K - shift M``, in a
symmetric minimum-degree ordering without pivoting, so that the factors' negative pivots count the
modes below the shift (Sylvester's law of inertia). A wide band is cut in two slices, each solved
about its own middle, the lower in a forked child (:mod:`modalctl.forked`) while this process solves
the upper: a Krylov space's orthogonalization costs ``n ncv^2``, and the two halves run on two cores.
Measured on the tablet panel's fine mesh (49,671 degrees of freedom, 262 modes below 20.6 kHz, one
process at a time, serial BLAS): one band 27.0-28.3 s; cut at 0.35 of its top eigenvalue, 13.2 s
(149 modes) and 12.2 s (113 modes), the two balanced (at 0.25: 11.5 s and 17.3 s, the upper slice's
eigenvalues spread wider about its shift; at 0.5: 14.8 s and 8.6 s); solved one after the other,
no faster than at once. The slices' frequencies agree with the single band's to 3e-9.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg

from modalctl.forked import beside
from modalctl.threads import serial_blas

from .modes import ModelError

__all__ = ["factor", "lanczos", "band", "residual", "NCV_FACTOR", "RESIDUAL_TOLERANCE", "ROUNDOFF",
           "SLICE_MODES", "SLICE_DOFS"]

NCV_FACTOR = 1.5  # Lanczos vectors per mode sought
RESIDUAL_TOLERANCE = 1e-6  # a relative residual r moves a frequency by about r / 2: above this, 20 times under...
ROUNDOFF = 1e-12  # ...the least tolerance (1e-5), and a backward error above this (sound: 1e-16; a tiny pivot's
# growth g: g 1e-16), a band's mid-band factors were unsound and it is solved again from below (see residual)
SLICE_MODES = 150  # a band of at least this many modes...
SLICE_DOFS = 20_000  # ...on at least this many degrees of freedom is solved in two slices (see the module doc)
SLICE_AT = 0.35  # where the band is cut, times its top eigenvalue: the two slices' times balance (module doc)
EXTRA = 4  # modes each slice asks for past those it holds: its edges' modes found, not guessed


def factor(matrix) -> tuple[object, int | None]:
    """superLU's factors of a symmetric sparse ``matrix`` (symmetric minimum-degree ordering, no
    pivoting: ``P A P^T = L D L^T`` up to the scaling of ``U``) and its inertia, the count of
    negative pivots; None when superLU had to pivot (a zero pivot), and the count means nothing."""
    factors = scipy.sparse.linalg.splu(matrix.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                                       options={"SymmetricMode": True})
    if not np.array_equal(factors.perm_r, factors.perm_c):
        return factors, None
    return factors, int(np.count_nonzero(factors.U.diagonal() < 0))


def lanczos(k, m, shift: float, count: int, below: float | None = None, grow: bool = False,
            most: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """ARPACK's ``count`` eigenpairs of ``K x = w2 M x`` nearest ``shift`` (shift-invert on :func:`factor`'s
    factors, from a fixed start: ARPACK's own moves from call to call, and a model solved afresh differed
    from its cached copy), ascending; with ``grow``, asked again for more while the highest lies below
    ``below`` (Hz), up to ``most`` (ModelError past it)."""
    factors, _ = factor(k - shift * m)
    inverse = scipy.sparse.linalg.LinearOperator(k.shape, matvec=factors.solve, dtype=float)
    size, start = k.shape[0], np.random.default_rng(0).standard_normal(k.shape[0])
    while True:
        if most is not None and count > most:
            raise ModelError(f"fe plate: over {most} modes below {below:g} Hz; a model holds {most // 2}")
        count = min(count, size - 2)
        ncv = min(size - 1, max(int(NCV_FACTOR * count), count + 20))
        with serial_blas():
            w2, x = scipy.sparse.linalg.eigsh(k, count, m, sigma=shift, which="LM", OPinv=inverse, ncv=ncv, v0=start)
        if not grow or w2.max() >= (2 * np.pi * below) ** 2 or count == size - 2:
            break
        count = int(count * 1.5) + 4  # the count fell short (superLU pivoted: Weyl's estimate)
    order = np.argsort(w2)
    return w2[order], x[:, order]


def band(k, m, top: float, under: int, shift: float) -> tuple[np.ndarray, np.ndarray]:
    """Every eigenpair below ``top`` (an eigenvalue, rad^2/s^2), ``under`` of them (the inertia's count),
    and a few past it: in two slices (module doc) when the band is wide and the mesh large, else one
    Lanczos about ``shift``. Ascending."""
    if under < SLICE_MODES or k.shape[0] < SLICE_DOFS:
        return lanczos(k, m, shift, under + EXTRA)
    cut = SLICE_AT * top
    _, lower = factor(k - cut * m)
    if lower is None or not 0 < lower < under:  # superLU pivoted: no count to cut by
        return lanczos(k, m, shift, under + EXTRA)
    child = beside(lambda: lanczos(k, m, cut / 2, lower + EXTRA))
    try:
        w_up, x_up = lanczos(k, m, (cut + top) / 2, under - lower + EXTRA)
        w_low, x_low = child.result()
    except BaseException:
        child.stop()
        raise
    low, up = w_low < cut, w_up >= cut
    if np.count_nonzero(low) != lower or np.count_nonzero(w_up[up] < top) != under - lower:
        return lanczos(k, m, shift, under + EXTRA)  # a slice missed a mode at its edge: the whole band at once
    return np.concatenate([w_low[low], w_up[up]]), np.concatenate([x_low[:, low], x_up[:, up]], axis=1)


def residual(k, m, w2: np.ndarray, x: np.ndarray, block: int = 64) -> float:
    """The largest relative eigen-residual ``||K x - w2 M x|| / ||K x||`` of the pairs (columns of
    ``x``; their sparse products ``block`` columns at a time) whose residual is more than round-off,
    its backward error ``||K x - w2 M x|| / (||K|| + w2 ||M||) ||x||`` above ``ROUNDOFF``; 0 for none,
    NaN for a pair that is not a number. (A sound solve's relative residual grows with the mesh, as
    ``||K||`` does, while its backward error stays at 1e-16: a free 100 x 70 mm plate's band, 1e-8
    on 9k degrees of freedom, 1e-7 on 74k; solved from below the lowest mode, the same.)"""
    norm_k, norm_m = abs(k).sum(axis=0).max(), abs(m).sum(axis=0).max()
    worst = [0.0]
    for i in range(0, len(w2), block):
        part, values = x[:, i:i + block], w2[i:i + block]
        kx = k @ part
        left = np.linalg.norm(kx - (m @ part) * values, axis=0)
        relative = left / np.linalg.norm(kx, axis=0)
        relative[left <= ROUNDOFF * (norm_k + values * norm_m) * np.linalg.norm(part, axis=0)] = 0.0
        worst.append(np.max(relative))
    return float(np.max(worst))
