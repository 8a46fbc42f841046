"""Mass-weighted projection onto modes, reconstruction, cross-talk and re-orthogonalization.

All functions take mode shapes as an array (k, n) and the grid's mass weights (n,) in kg,
and use the inner product ``<f, g> = sum_i m_i f_i g_i`` (Eq 2.11 sampled, Eq 3.21).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import scipy.linalg

from .modes import ModalModel, ModelError

__all__ = ["gram", "crosstalk", "project", "reconstruct", "mass_normalize", "orthonormalize",
           "orthonormalize_model"]


def gram(shapes: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Gram matrix ``<phi_k, phi_l>`` of the modes, shape (k, k); identity for mass-normalized modes."""
    return (shapes * mass) @ shapes.T


def crosstalk(shapes: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Cross-talk factors ``<phi_k, phi_l> / sqrt(<phi_k, phi_k> <phi_l, phi_l>)``, shape (k, k).

    Ones on the diagonal; off the diagonal, the cosine of the mass-weighted angle between two
    modes (thesis Fig 3.11). Zero everywhere off the diagonal means an orthogonal basis.
    """
    g = gram(shapes, mass)
    d = np.sqrt(np.diag(g))
    return g / np.outer(d, d)


def project(field: np.ndarray, shapes: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Modal coefficients ``c_k = <field, phi_k>`` (Eq 2.22).

    Parameters
    ----------
    field : ndarray, shape (n,) or (f, n)
        One field or a batch of fields on the grid (e.g. velocity, m/s).
    shapes : ndarray, shape (k, n)
        Mass-normalized mode shapes (1/sqrt(kg)).
    mass : ndarray, shape (n,)

    Returns
    -------
    ndarray, shape (k,) or (f, k)
        Coefficients (m/s sqrt(kg) for a velocity field).
    """
    return (np.asarray(field) * mass) @ shapes.T


def reconstruct(coefficients: np.ndarray, shapes: np.ndarray) -> np.ndarray:
    """Field ``sum_k c_k phi_k`` on the grid, shape (n,) or (f, n) (Eq 2.21 truncated)."""
    return np.asarray(coefficients) @ shapes


def mass_normalize(shapes: np.ndarray, mass: np.ndarray) -> np.ndarray:
    """Scale each mode to ``<phi, phi> = 1``, keeping its sign, shape (k, n)."""
    norms = np.sqrt(np.einsum("kn,n,kn->k", shapes, mass, shapes))
    if np.any(norms == 0):
        raise ModelError(f"shapes: mode {int(np.argmin(norms))} is zero on the grid")
    return shapes / norms[:, None]


def orthonormalize(shapes: np.ndarray, mass: np.ndarray, rtol: float = 1e-8) -> tuple[np.ndarray, np.ndarray]:
    """Gram-Schmidt with the mass-weighted inner product (Eqs 3.16-3.18), done stably.

    The modes are orthonormalized in order, as in classical Gram-Schmidt, but through a
    Householder QR factorization of ``sqrt(M) Phi^T``, which keeps orthogonality at machine
    precision even for nearly dependent (noisy, aliased) identified modes.

    Returns
    -------
    orthonormal : ndarray, shape (k, n)
        ``phi_dagger`` with ``gram(phi_dagger, mass) = I``; mode k spans the same space as the
        first k input modes and keeps a positive component along its input mode.
    r : ndarray, shape (k, k)
        Upper-triangular factor: ``shapes = r.T @ orthonormal``.

    Raises
    ------
    ModelError
        If a mode is (numerically) a combination of the modes before it.
    """
    if np.any(mass <= 0):
        raise ModelError("mass: orthonormalization needs positive mass weights at every point")
    root = np.sqrt(mass)
    q, r = scipy.linalg.qr((shapes * root).T, mode="economic")
    signs = np.where(np.diag(r) < 0, -1.0, 1.0)
    q, r = q * signs, r * signs[:, None]
    diag = np.abs(np.diag(r))
    weak = np.flatnonzero(diag < rtol * diag.max())
    if weak.size:
        raise ModelError(f"shapes: mode {int(weak[0])} is linearly dependent on the modes before it "
                         f"(residual norm {diag[weak[0]]:.3g}); remove it before orthonormalizing")
    return q.T / root, r


def orthonormalize_model(model: ModalModel) -> ModalModel:
    """Return ``model`` with re-orthonormalized shapes and the matching actuator and sensor gains.

    With ``Phi = R^T Phi_dagger`` a field ``sum eta_k phi_k`` has coordinates ``eta_dagger = R eta``
    in the new basis, so actuator gains become ``R B`` and point-sensor gains (the shapes at the
    sensors) ``R^-T C``. Frequencies and damping are kept: this assumes, as the thesis does,
    that the identified modes are nearly orthogonal already (R close to diagonal).
    """
    ortho, r = orthonormalize(model.shapes, model.grid.mass)
    sensors = scipy.linalg.solve_triangular(r, model.sensor_gains, trans="T") if model.sensor_gains.size \
        else model.sensor_gains
    return replace(model, shapes=ortho, actuator_gains=r @ model.actuator_gains, sensor_gains=sensors,
                   meta=dict(model.meta, orthonormalized=True))
