"""Modes the actuators cannot tell apart: close pairs driven along one direction.

Mode k answers the actuator voltages ``v`` through its row of gains, ``b_k . v``. When two modes'
rows are parallel (``|cos(b_j, b_k)|`` near 1), every drive pushes them in one fixed proportion:
the only thing that tells them apart is their frequency difference, a beat of period
``1 / |f_j - f_k|``. A focus that needs them in another proportion within a shorter time asks
for large, cancelling drives (on a tablet panel with eight patches placed mirror-symmetrically,
18,687 and 18,712 Hz grew to 44 times the largest target before the focus; ``benchmarks/
plate_speed.py``). Symmetric actuator layouts cause it: on a structure with two mirror axes the
modes of one symmetry class see each mirrored set of patches with fixed signs, so eight patches
in two mirrored sets give each class two directions in all.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .modes import ModalModel

__all__ = ["Twins", "twin_modes", "PARALLEL", "CLOSE"]

PARALLEL = 0.99  # |cos| between two modes' actuator gains above which they count as one direction
CLOSE = 0.02  # frequency spacing, relative to the lower mode, below which two modes count as close
UNDRIVEN = 1e-9  # gains below this share of the largest mode's: round-off, the mode not driven at all


@dataclass(frozen=True)
class Twins:
    """Two close modes the actuators push along one direction.

    Attributes
    ----------
    first, second : int
        Positional indices in the model, ``first`` the lower.
    spacing_hz : float
        ``f_second - f_first`` (Hz): the beat that alone tells them apart.
    cosine : float
        ``|cos|`` between their rows of actuator gains.
    """

    first: int
    second: int
    spacing_hz: float
    cosine: float

    def describe(self, model: ModalModel) -> str:
        """``'18687 and 18712 Hz (25 Hz apart, |cos| 1.000)'``."""
        f = model.frequencies
        return (f"{f[self.first]:.0f} and {f[self.second]:.0f} Hz ({self.spacing_hz:.3g} Hz apart, "
                f"|cos| {self.cosine:.3f})")

    def to_dict(self, model: ModalModel) -> dict:
        """JSON-ready: ``modes`` (the model's labels), ``spacing_hz``, ``cosine``."""
        return {"modes": [int(model.labels[self.first]), int(model.labels[self.second])],
                "spacing_hz": self.spacing_hz, "cosine": self.cosine}


def twin_modes(model: ModalModel, modes=None, close: float = CLOSE, parallel: float = PARALLEL) -> list[Twins]:
    """Pairs of modes within ``close`` of each other (relative spacing) whose actuator gains are
    parallel within ``parallel`` (``|cos|``), the closest first.

    Parameters
    ----------
    model : ModalModel
    modes : sequence of int, optional
        Positional indices: only pairs with at least one of them (default: every mode).
    close, parallel : float

    Returns
    -------
    list of Twins
    """
    gains = np.asarray(model.actuator_gains, float)
    if gains.shape[1] < 2 or not gains.size:  # one actuator: every pair parallel by construction, none to name
        return []
    norms = np.linalg.norm(gains, axis=1)
    driven = norms > UNDRIVEN * norms.max()  # a mode on every patch's nodal line has no direction
    unit = np.where(driven[:, None], gains / np.where(driven, norms, 1.0)[:, None], 0.0)
    f = model.frequencies
    first, second = np.triu_indices(f.size, 1)
    lower = np.minimum(f[first], f[second])
    spacing = np.abs(f[second] - f[first])
    cosine = np.abs(np.einsum("pa,pa->p", unit[first], unit[second]))
    pick = (spacing < close * lower) & (cosine >= parallel)
    if modes is not None:
        mine = np.zeros(f.size, bool)
        mine[np.asarray(modes, int)] = True
        pick &= mine[first] | mine[second]
    order = np.flatnonzero(pick)[np.argsort(spacing[pick], kind="stable")]
    return [Twins(*sorted((int(first[p]), int(second[p])), key=lambda k: f[k]), float(spacing[p]),
                  float(cosine[p])) for p in order]
