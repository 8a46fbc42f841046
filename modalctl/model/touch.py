"""A touch on the surface: a point impedance (a finger, a stylus, a pressing hand) and what it does
to the modes.

A viscous damper ``c`` (N s/m), a spring ``k`` (N/m) and a mass ``m`` (kg) at one grid point ``x0``
add, in the coordinates of the mass-normalized modes (``phi`` in 1/sqrt(kg)), the rank-one matrices
``c phi(x0) phi(x0)^T`` to the damping, ``k phi phi^T`` to the stiffness and ``m phi phi^T`` to the
mass: the touch couples every mode that moves at ``x0`` (:meth:`Touch.matrices`). The exact touched
system is the first-order ``x' = A x + B u`` of :func:`touched_system`; the HIL's finger
(:mod:`modalctl.hil.finger`) plays it, and the controllers (:mod:`modalctl.loops.touch`) plan and
estimate with the same matrices. To first order a light damper adds ``c phi_k(x0)^2 / 2`` to each
mode's decay rate (:func:`added_decay`): what a mode's envelope loses to it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .modes import ModalModel, ModelError

__all__ = ["Touch", "touch_at", "touched_system", "added_decay", "velocity_residues"]


@dataclass(frozen=True)
class Touch:
    """A point impedance at grid point ``index``.

    Attributes
    ----------
    index : int
        Grid point it rests on.
    damping : float
        Viscous damping (N s/m): a resting fingertip 0.1-1, a firm press up to a few.
    stiffness : float
        N/m (a firm press).
    mass : float
        kg that moves with the surface.
    """

    index: int
    damping: float = 0.0
    stiffness: float = 0.0
    mass: float = 0.0

    def __post_init__(self):
        for name in ("damping", "stiffness", "mass"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value >= 0):
                raise ModelError(f"touch: {name} must be finite and zero or more, got {value!r}")

    def shapes(self, model: ModalModel) -> np.ndarray:
        """Every mode's shape where it rests, shape (k,), 1/sqrt(kg)."""
        return model.shapes[:, self.index]

    def matrices(self, model: ModalModel) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """What it adds to the modal mass (1), damping (1/s) and stiffness (1/s^2) matrices, each (k, k)."""
        phi = self.shapes(model)
        outer = np.outer(phi, phi)
        return self.mass * outer, self.damping * outer, self.stiffness * outer


def touch_at(model: ModalModel, at, damping: float = 0.0, stiffness: float = 0.0, mass: float = 0.0) -> Touch:
    """A touch on the grid point nearest to ``at`` (m, one coordinate per dimension of the grid);
    ModelError when ``at`` has the wrong size or lies off the structure."""
    at = np.atleast_1d(np.asarray(at, float))
    grid = model.grid
    if at.size != grid.dim:
        raise ModelError(f"a touch at {at.size} coordinate(s) on a {grid.dim}-D structure")
    low, high = grid.bounds
    if np.any(at < low - 1e-9) or np.any(at > high + 1e-9):
        raise ModelError(f"a touch at {np.round(at * 1e3, 3).tolist()} mm is off the structure "
                         f"({np.round(low * 1e3, 3).tolist()} to {np.round(high * 1e3, 3).tolist()} mm)")
    index = int(np.argmin(np.linalg.norm(grid.points - at, axis=1)))
    if grid.mass[index] <= 0:  # a lattice point in a hole or past a rounded corner: no mode moves it (issue 39)
        raise ModelError(f"a touch at {np.round(at * 1e3, 3).tolist()} mm is off the structure: in a hole, on its "
                         f"rim or past it (the nearest grid point carries no mass)")
    return Touch(index, damping, stiffness, mass)


def touched_system(model: ModalModel, touch: Touch | None) -> tuple[np.ndarray, np.ndarray]:
    """The structure with ``touch`` as ``x' = A x + B u``: ``x`` the modal displacements then
    velocities (2k,), ``u`` the actuator voltages (a,); A (2k, 2k), B (2k, a). None: untouched."""
    k = model.n_modes
    mass, damping, stiffness = np.eye(k), np.diag(2 * model.damping * model.omega), np.diag(model.omega ** 2)
    gains = model.actuator_gains
    if touch is not None:
        added = touch.matrices(model)
        mass, damping, stiffness = mass + added[0], damping + added[1], stiffness + added[2]
        gains = np.linalg.solve(mass, gains)
        damping, stiffness = np.linalg.solve(mass, damping), np.linalg.solve(mass, stiffness)
    a = np.block([[np.zeros((k, k)), np.eye(k)], [-stiffness, -damping]])
    return a, np.vstack([np.zeros_like(gains), gains])


def added_decay(model: ModalModel, touch: Touch) -> np.ndarray:
    """First-order decay rate (1/s) a light damper adds to each mode, ``c phi_k(x0)^2 / 2``, shape (k,);
    divided by ``omega`` it is the added damping ratio."""
    return touch.damping * touch.shapes(model) ** 2 / 2


def velocity_residues(frequencies, damping) -> np.ndarray:
    """Each mode's velocity residue ``lambda / (lambda - conj(lambda))`` (about one half), shape (k,):
    in its carrier's frame a mode's velocity envelope ``y`` and force envelope ``u`` obey
    ``y' = p y + r u``."""
    w = 2 * np.pi * np.asarray(frequencies, float)
    z = np.asarray(damping, float)
    lam = -z * w + 1j * w * np.sqrt(1 - z ** 2)
    return lam / (lam - lam.conj())
