"""Decompose a target field on a modal model, keep the modes it needs, report what is lost."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from modalctl.errors import InputError
from modalctl.model.metrics import focus_contrast, nrmse, tau, tau_norm
from modalctl.model.modes import ModalModel
from modalctl.model.projection import orthonormalize_model, project, reconstruct
from modalctl.model.shape import Shape, checked_target
from modalctl.options import DEFAULT_TAU

from .reduction import smallest_set

__all__ = ["Decomposition", "decompose"]



@dataclass(frozen=True, eq=False)
class Decomposition:
    """A target field projected on a model's modes, with the reduced mode set.

    Attributes
    ----------
    model : ModalModel
        The model used (re-orthonormalized if asked).
    shape : Shape
        The target.
    coefficients : ndarray, shape (k,)
        ``<w_R, phi_k>`` for every mode of the model (m/s sqrt(kg)).
    modes_used : ndarray of int, shape (m,)
        Positional indices of the kept modes.
    reconstruction : ndarray, shape (n,)
        Field from the kept modes (m/s).
    rule : str
        How the modes were chosen.
    """

    model: ModalModel
    shape: Shape
    coefficients: np.ndarray
    modes_used: np.ndarray
    reconstruction: np.ndarray
    rule: str

    def metrics(self) -> dict:
        """Accuracy of the reduced field, of the full model basis, and what the basis cannot carry."""
        ref, mass = self.shape.values, self.model.grid.mass
        full = reconstruct(self.coefficients, self.model.shapes)
        energy = float(np.sum(ref**2 * mass))
        rigid = project(ref, self.model.rigid_shapes, mass) if self.model.rigid_shapes.size else np.zeros(0)
        kept = self.coefficients[self.modes_used]
        return {
            "tau": float(tau(ref, self.reconstruction)),
            "tau_norm": float(tau_norm(ref, self.reconstruction)),
            "nrmse": float(nrmse(ref, self.reconstruction)),
            "focus_contrast": float(focus_contrast(self.reconstruction, self.shape.target_mask)),
            "energy_left": float(max(0.0, 1 - np.sum(kept**2) / energy)) if energy else 0.0,
            "tau_all_modes": float(tau(ref, full)),
            "nrmse_all_modes": float(nrmse(ref, full)),
            "rigid_body_energy": float(np.sum(rigid**2) / energy) if energy else 0.0,
        }

    def to_dict(self) -> dict:
        """JSON-ready summary: coefficients, modes used (by label), metrics, what the error is."""
        labels = self.model.labels
        m = self.metrics()
        return {
            "scene": self.model.meta.get("name"),
            "rule": self.rule,
            "modes_used": [int(labels[i]) for i in self.modes_used],
            "n_modes_used": int(self.modes_used.size),
            "n_modes_model": int(self.model.n_modes),
            "coefficients": {str(int(labels[i])): float(self.coefficients[i]) for i in self.modes_used},
            "coefficients_all": [float(c) for c in self.coefficients],
            "frequencies_hz": [float(self.model.frequencies[i]) for i in self.modes_used],
            "units": {"coefficients": "m/s*sqrt(kg)", "frequencies_hz": "Hz"},
            **m,
            "error_left": (f"the {self.modes_used.size} kept modes reach tau {m['tau']:.4f} and NRMSE {m['nrmse']:.4f} "
                           f"and leave {100 * m['energy_left']:.2f}% of the field's energy; all "
                           f"{self.model.n_modes} modes of the model would reach tau {m['tau_all_modes']:.4f}"),
        }


def decompose(model: ModalModel, shape: Shape, modes="auto", *, tau_min: float | None = None,
              nrmse_max: float | None = None, orthogonalize: bool = False) -> Decomposition:
    """Project ``shape`` on ``model`` and keep the modes the field needs.

    Parameters
    ----------
    model : ModalModel
    shape : Shape
        Target on the model's grid.
    modes : "auto", "all", int or sequence of int
        ``"auto"``: the smallest set meeting ``tau_min`` (default 0.98) and/or ``nrmse_max``;
        an int N: the N lowest modes; a sequence: those positional indices.
    orthogonalize : bool
        Re-orthonormalize the shapes first (Gram-Schmidt, Eqs 3.16-3.18), for identified modes.
    """
    if shape.values.size != model.grid.n:
        raise ValueError(f"shape has {shape.values.size} points, the model's grid {model.grid.n}")
    checked_target(shape)  # one built by hand (the API) as a generator's
    if orthogonalize:
        model = orthonormalize_model(model)
    coefficients = project(shape.values, model.shapes, model.grid.mass)
    if isinstance(modes, str) and modes == "auto":
        tau_min = DEFAULT_TAU if tau_min is None and nrmse_max is None else tau_min
        chosen = smallest_set(shape.values, model.shapes, model.grid.mass, tau_min=tau_min, nrmse_max=nrmse_max).modes
        targets = [t for t in (f"tau >= {tau_min}" if tau_min is not None else None,
                               f"nrmse <= {nrmse_max}" if nrmse_max is not None else None) if t]
        rule = "smallest set meeting " + " and ".join(targets)
    elif isinstance(modes, str) and modes == "all":
        chosen, rule = np.arange(model.n_modes), "all modes"
    elif np.isscalar(modes):
        count = int(modes)
        if not 1 <= count <= model.n_modes:
            raise InputError(f"modes: N must lie in 1..{model.n_modes}, got {count}")
        chosen, rule = np.sort(np.argsort(model.frequencies, kind="stable")[:count]), f"{count} lowest modes"
    else:
        chosen, rule = np.unique(np.asarray(modes, dtype=int)), "given modes"
    chosen = np.sort(chosen)
    return Decomposition(model, shape, coefficients, chosen,
                         reconstruct(coefficients[chosen], model.shapes[chosen]), rule)
